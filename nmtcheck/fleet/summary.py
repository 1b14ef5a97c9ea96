"""`nmtcheck fleet summary`: the fleet at a glance, from the results dataset alone.

Which devices and nodes fail each rule most and since when, findings per day and per
nmtcheck version (did an update change the picture?), and the logs that could not be
checked. Text, CSV (one table with a `section` column) and one self-contained HTML page.
"""

from __future__ import annotations

import csv
import html
import io
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from nmtcheck import __version__


@dataclass
class FleetSummary:
    results: str
    totals: dict[str, Any]
    status: Any  # DataFrame: status, logs
    devices: Any  # DataFrame: rule, device, findings, logs, nodes, first, last
    nodes: Any  # DataFrame: rule, device, channel, node, findings, logs, first, last
    by_day: Any  # DataFrame: date, rule, findings
    by_version: Any  # DataFrame: nmtcheck_version, logs, rule, findings
    failed: Any  # DataFrame: url, status, error


def summarise(results: str, storage_options: dict[str, Any] | None = None,
              rules: list[str] | None = None, top: int = 10,
              latest_only: bool = True) -> FleetSummary:

    from nmtcheck.api import read_results

    res = read_results(results, storage_options=storage_options, latest=latest_only)
    inputs, findings = res.inputs, res.findings
    if rules:
        findings = findings[findings["rule"].isin(rules)]
    f = findings.copy()
    f["device"] = f["device"].fillna(f["url"])  # without --path-pattern: the log is the device
    # "since when": the finding's own date when the log is dated, else its partition's
    f["when"] = f["abs_time"].dt.strftime("%Y-%m-%d").fillna(f["date"].astype(str))
    dev = (f.groupby(["rule", "device"], dropna=False)
           .agg(findings=("rule", "size"), logs=("input_id", "nunique"),
                nodes=("node", "nunique"), first=("when", "min"), last=("when", "max"))
           .reset_index().sort_values(["rule", "findings", "device"],
                                      ascending=[True, False, True])
           .groupby("rule").head(top).reset_index(drop=True))
    nod = (f.dropna(subset=["node"])
           .groupby(["rule", "device", "channel", "node"], dropna=False)
           .agg(findings=("rule", "size"), logs=("input_id", "nunique"),
                first=("when", "min"), last=("when", "max"))
           .reset_index().sort_values(["rule", "findings", "device", "channel", "node"],
                                      ascending=[True, False, True, True, True])
           .groupby("rule").head(top).reset_index(drop=True))
    if len(nod):
        nod["node"] = nod["node"].astype("int64")
    day = (f.groupby(["when", "rule"]).size().rename("findings").reset_index()
           .rename(columns={"when": "date"}).sort_values(["date", "rule"]))
    versions = inputs[["input_id", "batch_id", "nmtcheck_version"]]
    fv = f.merge(versions, on=["input_id", "batch_id"], how="left")
    logs_per_version = inputs.groupby("nmtcheck_version").size().rename("logs")
    ver = (fv.groupby(["nmtcheck_version", "rule"]).size().rename("findings").reset_index()
           .merge(logs_per_version.reset_index(), on="nmtcheck_version", how="left")
           [["nmtcheck_version", "logs", "rule", "findings"]])
    status = inputs.groupby("status").size().rename("logs").reset_index()
    failed = (inputs[inputs["status"].isin(["input_error", "crashed", "unsupported"])]
              [["url", "status", "error"]].sort_values(["status", "url"]).head(top * 10)
              .reset_index(drop=True))
    dated = inputs["date"].astype(str)
    dated = dated[dated != "unknown"]
    totals = {
        "logs": len(inputs), "devices": int(inputs["device"].nunique()),
        "frames": int(inputs["frames"].fillna(0).sum()),
        "bytes": int(inputs["size"].fillna(0).sum()),
        "error": int(inputs["n_error"].fillna(0).sum()),
        "warning": int(inputs["n_warning"].fillna(0).sum()),
        "info": int(inputs["n_info"].fillna(0).sum()),
        "first_date": dated.min() if len(dated) else None,
        "last_date": dated.max() if len(dated) else None,
        "versions": sorted(inputs["nmtcheck_version"].dropna().unique().tolist()),
        "runs": len(res.runs), "latest_only": latest_only,
    }
    return FleetSummary(results, totals, status, dev, nod, day, ver, failed)


def _cell(v: Any) -> str:
    """A value as a table shows it: missing values (None, NaN, pd.NA) empty."""
    import pandas as pd

    return "" if v is None or bool(pd.isna(v)) else str(v)


def _table_text(df: Any, columns: list[str]) -> list[str]:
    rows = [[str(c) for c in columns]] + [[_cell(v)
                                           for v in r] for r in df[columns].itertuples(False)]
    widths = [max(len(r[i]) for r in rows) for i in range(len(columns))]
    return ["  " + "  ".join(v.ljust(w) for v, w in zip(r, widths, strict=True)).rstrip()
            for r in rows]


def render_text(s: FleetSummary) -> str:
    t = s.totals
    span = f"{t['first_date']} .. {t['last_date']}" if t["first_date"] else "no dated logs"
    lines = [f"nmtcheck fleet summary of {s.results}",
             f"{t['logs']} logs, {t['devices']} devices, {t['frames']} frames, {span}; "
             f"nmtcheck {', '.join(t['versions']) or '-'}",
             f"findings: {t['error']} errors, {t['warning']} warnings, {t['info']} info",
             "status: " + ", ".join(f"{r.status} {r.logs}" for r in s.status.itertuples()), ""]
    for rule in sorted(s.devices["rule"].unique()):
        lines.append(f"{rule}: worst devices")
        lines += _table_text(s.devices[s.devices["rule"] == rule],
                             ["device", "findings", "logs", "nodes", "first", "last"])
        nodes = s.nodes[s.nodes["rule"] == rule]
        if len(nodes):
            lines.append(f"{rule}: worst nodes")
            lines += _table_text(nodes, ["device", "channel", "node", "findings", "logs",
                                         "first", "last"])
        lines.append("")
    if len(s.by_version):
        lines.append("findings by nmtcheck version")
        lines += _table_text(s.by_version, ["nmtcheck_version", "logs", "rule", "findings"])
        lines.append("")
    if len(s.failed):
        lines.append("logs not checked")
        lines += _table_text(s.failed, ["status", "url", "error"])
        lines.append("")
    return "\n".join(lines)


def render_csv(s: FleetSummary) -> str:
    """One table: `section` says which part a row belongs to (devices, nodes, by_day,
    by_version, failed), the other columns are those of the part (empty elsewhere)."""
    parts = [("devices", s.devices), ("nodes", s.nodes), ("by_day", s.by_day),
             ("by_version", s.by_version), ("status", s.status), ("failed", s.failed)]
    columns: list[str] = []
    for _name, df in parts:
        columns += [c for c in df.columns if c not in columns]
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(["section", *columns])
    for name, df in parts:
        for rec in df.to_dict("records"):
            w.writerow([name, *[_csv_value(rec.get(c)) for c in columns]])
    return out.getvalue()


def _csv_value(v: Any) -> str:
    from nmtcheck.reporters.common import spreadsheet_safe

    return spreadsheet_safe(_cell(v))


def _table_html(df: Any, columns: list[str]) -> str:
    head = "".join(f"<th>{html.escape(c)}</th>" for c in columns)
    body = "".join("<tr>" + "".join(
        f"<td>{html.escape(_cell(v))}</td>" for v in r) + "</tr>"
        for r in df[columns].itertuples(False))
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _bars(by_day: Any) -> str:
    """Findings per day as an inline SVG bar chart (no script, no CDN)."""
    if not len(by_day):
        return "<p>No findings.</p>"
    per_day = by_day.groupby("date")["findings"].sum()
    top = max(int(per_day.max()), 1)
    w, h = max(8, 600 // max(len(per_day), 1)), 120
    rects = []
    for i, (day, n) in enumerate(per_day.items()):
        bh = max(1, int(h * n / top))
        rects.append(f'<rect x="{i * w}" y="{h - bh}" width="{w - 1}" height="{bh}" '
                     f'fill="#c0392b"><title>{html.escape(str(day))}: {n}</title></rect>')
    return (f'<svg width="{len(per_day) * w}" height="{h}" role="img" '
            f'aria-label="findings per day">{"".join(rects)}</svg>')


def render_html(s: FleetSummary) -> str:
    t = s.totals
    sections = [f"<h1>nmtcheck fleet summary</h1><p>{html.escape(s.results)}: "
                f"{t['logs']} logs, {t['devices']} devices, {t['frames']} frames; "
                f"<b>{t['error']}</b> errors, {t['warning']} warnings, {t['info']} info; "
                f"logs from {t['first_date'] or '-'} to {t['last_date'] or '-'}; "
                f"nmtcheck {html.escape(', '.join(t['versions']) or '-')}</p>",
                _table_html(s.status, ["status", "logs"]),
                "<h2>Findings per day</h2>", _bars(s.by_day)]
    for rule in sorted(s.devices["rule"].unique()):
        sections.append(f"<h2>{html.escape(rule)}</h2><h3>Worst devices</h3>")
        sections.append(_table_html(s.devices[s.devices["rule"] == rule],
                                    ["device", "findings", "logs", "nodes", "first", "last"]))
        nodes = s.nodes[s.nodes["rule"] == rule]
        if len(nodes):
            sections.append("<h3>Worst nodes</h3>")
            sections.append(_table_html(nodes, ["device", "channel", "node", "findings",
                                                "logs", "first", "last"]))
    sections.append("<h2>By nmtcheck version</h2>")
    sections.append(_table_html(s.by_version, ["nmtcheck_version", "logs", "rule", "findings"]))
    if len(s.failed):
        sections.append("<h2>Logs not checked</h2>")
        sections.append(_table_html(s.failed, ["status", "url", "error"]))
    style = ("body{font-family:system-ui,sans-serif;margin:2em;color:#222}"
             "table{border-collapse:collapse;margin:.5em 0}"
             "td,th{border:1px solid #ccc;padding:2px 8px;text-align:left}"
             "th{background:#f4f4f4}")
    return (f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
            f"<title>nmtcheck fleet summary</title><style>{style}</style></head><body>"
            + "\n".join(sections)
            + f"<footer><small>nmtcheck {__version__}</small></footer></body></html>\n")


RENDERERS: dict[str, Callable[[FleetSummary], str]] = {
    "text": render_text, "csv": render_csv, "html": render_html}
