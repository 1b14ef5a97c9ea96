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
from nmtcheck.safe_text import escape_controls, escape_lines


@dataclass
class FleetSummary:
    results: str
    totals: dict[str, Any]
    status: Any  # DataFrame: status, logs
    rules: Any  # DataFrame: rule, name, findings, logs (most findings first, ties by code)
    devices: Any  # DataFrame: rule, device, log, findings, logs, nodes, first, last
    nodes: Any  # DataFrame: rule, device, log, channel, node, findings, logs, first, last
    by_day: Any  # DataFrame: date, rule, findings
    by_version: Any  # DataFrame: nmtcheck_version, logs, rule, findings
    failed: Any  # DataFrame: url, status, error


def summarise(results: str, storage_options: dict[str, Any] | None = None,
              rules: list[str] | None = None, top: int = 10,
              latest_only: bool = True) -> FleetSummary:
    """The summary's tables. The unit a rule's worst list ranks is the device where the log
    has one (`--path-pattern`), else the log itself: `device` or `log` says which, never a
    path in the `device` column."""
    from nmtcheck.fleet.results import read_results

    res = read_results(results, storage_options=storage_options, latest=latest_only)
    inputs, findings = res.inputs, res.findings
    if rules:
        findings = findings[findings["rule"].isin(rules)]
    f = findings.copy()
    f["log"] = f["url"].where(f["device"].isna())
    f["unit"] = f["device"].fillna(f["url"])
    # "since when": the finding's own date when the log is dated, else its partition's
    f["when"] = f["abs_time"].dt.strftime("%Y-%m-%d").fillna(f["date"].astype(str))
    keep = {"device": ("device", "first"), "log": ("log", "first")}
    dev = (f.groupby(["rule", "unit"], dropna=False)
           .agg(**keep, findings=("rule", "size"), logs=("input_id", "nunique"),
                nodes=("node", "nunique"), first=("when", "min"), last=("when", "max"))
           .reset_index().sort_values(["rule", "findings", "unit"],
                                      ascending=[True, False, True])
           .groupby("rule").head(top).drop(columns="unit").reset_index(drop=True))
    nod = (f.dropna(subset=["node"])
           .groupby(["rule", "unit", "channel", "node"], dropna=False)
           .agg(**keep, findings=("rule", "size"), logs=("input_id", "nunique"),
                first=("when", "min"), last=("when", "max"))
           .reset_index().sort_values(["rule", "findings", "unit", "channel", "node"],
                                      ascending=[True, False, True, True, True])
           .groupby("rule").head(top).drop(columns="unit").reset_index(drop=True)
           [["rule", "device", "log", "channel", "node", "findings", "logs", "first", "last"]])
    if len(nod):
        nod["node"] = nod["node"].astype("int64")
    per_rule = (f.groupby("rule").agg(name=("name", "first"), findings=("rule", "size"),
                                      logs=("input_id", "nunique"))
                .reset_index().sort_values(["findings", "rule"], ascending=[False, True])
                .reset_index(drop=True))
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
        "logs_without_device": int(inputs["device"].isna().sum()),
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
    return FleetSummary(results, totals, status, per_rule, dev, nod, day, ver, failed)


def _units(t: dict[str, Any]) -> str:
    """How many logs and devices: a log without a device (no `--path-pattern`, or one its
    path does not match) is its own unit, and the phrase says so rather than "0 devices"."""
    logs, devices, alone = t["logs"], t["devices"], t["logs_without_device"]
    if not logs:
        return "0 logs"
    if not alone:
        return f"{logs} logs, {devices} devices"
    if not devices:
        return (f"{logs} logs, no device names (each log is its own unit: give "
                "check --results a --path-pattern to name devices)")
    return f"{logs} logs, {devices} devices and {alone} logs without a device"


def _unit_columns(df: Any) -> list[str]:
    """`device`, `log` or both: the columns that name a table's rows."""
    return [c for c in ("device", "log") if df[c].notna().any()] or ["device"]


def _worst(df: Any) -> str:
    return {"device": "devices", "log": "logs"}.get(" ".join(_unit_columns(df)),
                                                     "devices and logs")


def _rule_head(r: Any) -> str:
    return (f"{r.rule} {r.name}: {r.findings} finding{'s' if r.findings != 1 else ''} "
            f"in {r.logs} log{'s' if r.logs != 1 else ''}")


def _cell(v: Any) -> str:
    """A value as a table shows it: missing values (None, NaN, pd.NA) empty, control
    characters of a name (a newline before `::error`) shown as `\\xNN`, never sent."""
    import pandas as pd

    return "" if v is None or bool(pd.isna(v)) else escape_controls(v)


def _html(text: str) -> str:
    """`text` for the page: markup and control characters escaped (the page may be a CI
    job's standard output)."""
    return html.escape(escape_controls(text))


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
             f"{_units(t)}, {t['frames']} frames, {span}; "
             f"nmtcheck {', '.join(t['versions']) or '-'}",
             f"findings: {t['error']} errors, {t['warning']} warnings, {t['info']} info",
             "status: " + ", ".join(f"{r.status} {r.logs}" for r in s.status.itertuples()), ""]
    for r in s.rules.itertuples():  # most findings first
        worst = s.devices[s.devices["rule"] == r.rule]
        lines += [_rule_head(r), f"{r.rule}: worst {_worst(worst)}"]
        lines += _table_text(worst, [*_unit_columns(worst), "findings", "logs", "nodes",
                                     "first", "last"])
        nodes = s.nodes[s.nodes["rule"] == r.rule]
        if len(nodes):
            lines.append(f"{r.rule}: worst nodes")
            lines += _table_text(nodes, [*_unit_columns(nodes), "channel", "node", "findings",
                                         "logs", "first", "last"])
        lines.append("")
    if len(s.by_version):
        lines.append("findings by nmtcheck version")
        lines += _table_text(s.by_version, ["nmtcheck_version", "logs", "rule", "findings"])
        lines.append("")
    if len(s.failed):
        lines.append("logs not checked")
        lines += _table_text(s.failed, ["status", "url", "error"])
        lines.append("")
    return escape_lines(lines)  # a name's newline never starts a line of its own


def render_csv(s: FleetSummary) -> str:
    """One table: `section` says which part a row belongs to (rules, devices, logs, nodes,
    by_day, by_version, status, failed), the other columns are those of the part (empty
    elsewhere). A worst-list row is `devices` when it names a device, `logs` when it names
    a log that has none."""
    worst = s.devices
    parts = [("rules", s.rules), ("devices", worst[worst["device"].notna()]),
             ("logs", worst[worst["device"].isna()]), ("nodes", s.nodes),
             ("by_day", s.by_day), ("by_version", s.by_version), ("status", s.status),
             ("failed", s.failed)]
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
    head = "".join(f"<th>{_html(c)}</th>" for c in columns)
    body = "".join("<tr>" + "".join(
        f"<td>{_html(_cell(v))}</td>" for v in r) + "</tr>"
        for r in df[columns].itertuples(False))
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


MAX_DAYS_FILLED = 92  # a longer span gets a bar per day with findings, not one per day


def _scale(top: int) -> list[int]:
    """Tick values 0, step, 2 step, ... up to at least `top`: the smallest step of 1, 2 or
    5 x 10^k that needs at most 4 ticks above zero."""
    k = 1
    while True:
        for step in (k, 2 * k, 5 * k):
            if step * 4 >= top:
                return list(range(0, -(-top // step) * step + 1, step))
        k *= 10


def _day_span(days: list[str]) -> tuple[list[str], bool]:
    """Every day from the first to the last when they are dates no more than
    MAX_DAYS_FILLED apart (a day without findings shows as one), else the given days."""
    from datetime import date, timedelta

    try:
        first, last = date.fromisoformat(days[0]), date.fromisoformat(days[-1])
        for d in days:
            date.fromisoformat(d)
    except ValueError:
        return days, False
    n = (last - first).days + 1
    if n > MAX_DAYS_FILLED:
        return days, False
    return [str(first + timedelta(days=i)) for i in range(n)], True


def _bars(by_day: Any) -> str:
    """Findings per day as an inline SVG bar chart (no script, no CDN): a y axis with an
    even scale, the date under each bar (every k-th when they would overlap), the count
    on each bar that has room for it, and each bar's count by rule as its tooltip."""
    if not len(by_day):
        return "<p>No findings.</p>"
    per_day = by_day.groupby("date")["findings"].sum()
    days, filled = _day_span(sorted(per_day.index))
    counts = [int(per_day.get(d, 0)) for d in days]
    by_rule = {d: ", ".join(f"{r.rule} {r.findings}" for r in g.itertuples())
               for d, g in by_day.groupby("date")}
    ticks = _scale(max(max(counts), 1))
    bar = max(4, min(48, 960 // len(days)))
    digits = len(str(max(counts)))
    # the counts on the bars: all across, all upright, or (bars too narrow) none
    counts_as = "across" if bar >= 7 * digits else "upright" if bar >= 11 else ""
    left, top, plot_h, bottom = 56, 14 if counts_as != "upright" else 7 * digits + 8, 160, 84
    width, base = left + bar * len(days) + 12, top + plot_h
    label_every = -(-14 // bar)  # rotated dates need about 14 px each

    def y(v: float) -> float:
        return base - plot_h * v / ticks[-1]

    parts = [f'<g class="y-axis"><line x1="{left}" y1="{top}" x2="{left}" y2="{base}" '
             f'stroke="#444"/>']
    parts += [f'<line x1="{left - 4}" y1="{y(t):.1f}" x2="{width - 8}" y2="{y(t):.1f}" '
              f'stroke="{"#444" if t == 0 else "#e4e4e4"}"/>'
              f'<text class="tick" x="{left - 7}" y="{y(t) + 4:.1f}" '
              f'text-anchor="end">{t}</text>' for t in ticks]
    parts.append(f'<text class="axis-title" transform="translate(14 {top + plot_h / 2}) '
                 f'rotate(-90)" text-anchor="middle">findings</text></g>')
    for i, (d, n) in enumerate(zip(days, counts, strict=True)):
        x, mid = left + i * bar, left + i * bar + bar / 2
        what = f"{n} finding{'s' if n != 1 else ''}" + (f" ({by_rule[d]})" if n else "")
        g = [f'<g class="day" data-date="{_html(d)}">'
             f"<title>{_html(f'{d}: {what}')}</title>"]
        if n:
            g.append(f'<rect x="{x + 1}" y="{y(n):.1f}" width="{max(bar - 2, 1)}" '
                     f'height="{base - y(n):.1f}" fill="#c0392b"/>')
            if counts_as == "across":
                g.append(f'<text class="count" x="{mid}" y="{y(n) - 3:.1f}" '
                         f'text-anchor="middle">{n}</text>')
            elif counts_as:
                g.append(f'<text class="count" transform="translate({mid + 4} {y(n) - 3:.1f}) '
                         f'rotate(-90)">{n}</text>')
        if i % label_every == 0:
            g.append(f'<text class="date" transform="translate({mid + 4} {base + 8}) '
                     f'rotate(-60)" text-anchor="end">{_html(d)}</text>')
        parts.append("".join(g) + "</g>")
    parts.append(f'<text class="axis-title" x="{left + bar * len(days) / 2}" '
                 f'y="{base + bottom - 4}" text-anchor="middle">day (UTC)</text>')
    chart = (f'<svg width="{width}" height="{base + bottom}" role="img" font-size="11" '
             f'font-family="system-ui,sans-serif" aria-label="findings per day">'
             f'{"".join(parts)}</svg>')
    total = sum(counts)
    note = (f"{total} findings on {sum(1 for n in counts if n)} days from {days[0]} to "
            f"{days[-1]} (a finding's own date, else its log's); hover a bar for its count "
            "by rule" + ("." if counts_as else " (too many bars to write each count)."))
    if not filled and len(days) > 1:
        note += (f" The span is longer than {MAX_DAYS_FILLED} days: only the days with "
                 "findings are shown.")
    return f"{chart}<p><small>{_html(note)}</small></p>"


def render_html(s: FleetSummary) -> str:
    t = s.totals
    sections = [f"<h1>nmtcheck fleet summary</h1><p>{_html(s.results)}: "
                f"{_html(_units(t))}, {t['frames']} frames; "
                f"<b>{t['error']}</b> errors, {t['warning']} warnings, {t['info']} info; "
                f"logs from {t['first_date'] or '-'} to {t['last_date'] or '-'}; "
                f"nmtcheck {_html(', '.join(t['versions']) or '-')}</p>",
                _table_html(s.status, ["status", "logs"]),
                "<h2>Findings per day</h2>", _bars(s.by_day)]
    for r in s.rules.itertuples():  # most findings first
        worst = s.devices[s.devices["rule"] == r.rule]
        sections.append(f"<h2>{_html(_rule_head(r))}</h2>"
                        f"<h3>Worst {_worst(worst)}</h3>")
        sections.append(_table_html(worst, [*_unit_columns(worst), "findings", "logs",
                                            "nodes", "first", "last"]))
        nodes = s.nodes[s.nodes["rule"] == r.rule]
        if len(nodes):
            sections.append("<h3>Worst nodes</h3>")
            sections.append(_table_html(nodes, [*_unit_columns(nodes), "channel", "node",
                                                "findings", "logs", "first", "last"]))
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
