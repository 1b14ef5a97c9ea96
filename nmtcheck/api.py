"""The Python API: check logs into pandas DataFrames, read a fleet's results dataset.

    report = nmtcheck.check(["run1.log", "run2.asc"], network="net.toml")
    report.findings   # one row per finding: the JSON report's fields (SPEC §7) + path,
                      # time_offset (s from the first frame), time_utc (datetime64, UTC)
    report.timeline   # state intervals (start/end + _offset, _utc);  report.nodes
    report.boot       # one row per CiA 302-2 boot process (SPEC_BOOT §8.5), as the fleet's
                      # `boot` table: status, Lely letter and its text, proving frame
    report.sync       # one row per channel with SYNC; report.pdo_streams: one per stream
    report.lss        # one row per LSS request (CiA 305) with its responses and session
    results = nmtcheck.read_results("results/")   # runs, inputs, findings, node_stats, boot,
                      # sync_stats, pdo_stats, emcy (SPEC_COMM §9.4.2), lss

The columns are the JSON report's field names, so code written against one reads the other.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from os import PathLike
from typing import Any

import pandas as pd

from nmtcheck.errors import optional_text, string_list, whole_number
from nmtcheck.fleet.results import Results, read_results

__all__ = ["Report", "Results", "check", "read_results"]

FINDING_COLUMNS = ["input", "path", "rule", "name", "severity", "channel", "node", "time",
                   "frame_index", "line", "message"]
TIMELINE_COLUMNS = ["input", "path", "channel", "node", "state", "start", "end", "source"]
NODE_COLUMNS = ["input", "path", "channel", "node", "first_seen", "last_seen", "final_state",
                "bootups", "error_control", "heartbeat_period_ms"]


@dataclass(repr=False)
class Report:
    """The result of `check`: DataFrames of the JSON report's lists, and the summary.
    `print(report)` gives a short summary (the verdict, the counts, the tables' sizes),
    as a DataFrame prints a shortened view; the tables themselves are its attributes."""

    findings: pd.DataFrame
    timeline: pd.DataFrame
    nodes: pd.DataFrame
    inputs: pd.DataFrame
    summary: dict[str, int]
    results: list[Any] = field(repr=False)  # the engine's InputResults
    # one row per boot process (the fleet dataset's `boot` columns, with input and path)
    boot: pd.DataFrame = field(default_factory=pd.DataFrame)
    # SPEC §9.4.1: one row per channel with SYNC (`channels[i].sync` flattened), one row
    # per PDO stream (`pdo_streams[]`, its consumers a list)
    sync: pd.DataFrame = field(default_factory=pd.DataFrame)
    pdo_streams: pd.DataFrame = field(default_factory=pd.DataFrame)
    # SPEC §9.4.1 `lss[]`: one row per LSS request (as the fleet's `lss` table), its
    # responses a list; the slaves, sessions and fastscans are in `to_dict()["lss"]`
    lss: pd.DataFrame = field(default_factory=pd.DataFrame)

    def failed(self, fail_on: str = "error") -> bool:
        """What `nmtcheck check --fail-on` would decide: a finding at or above `fail_on`
        (error, warning, info or never)."""
        from nmtcheck.checks.base import SEVERITIES, fails

        if fail_on not in (*SEVERITIES, "never"):
            raise (ValueError if isinstance(fail_on, str) else TypeError)(
                f"fail_on: expected one of {', '.join((*SEVERITIES, 'never'))}, "
                f"got {fail_on!r:.40}")
        return fails(self.summary, fail_on)

    def to_dict(self) -> dict[str, Any]:
        """The JSON report (SPEC §7) as a dict."""
        from nmtcheck.reporters.json import report_dict

        return report_dict(self.results)

    def to_json(self) -> str:
        """The JSON report (SPEC §7) as text, as `nmtcheck check --format json` writes it
        (a string, as pandas' `to_json` returns one; `to_dict` gives the dict)."""
        from nmtcheck.reporters.json import render

        return render(self.results, {})

    def __repr__(self) -> str:
        from nmtcheck.reporters.common import counts_phrase, plural

        word = "FAIL" if self.failed() else "PASS"
        n = len(self.inputs)
        bad = (int(self.inputs["error"].notna().sum())
               if "error" in self.inputs.columns else 0)
        tables = ", ".join(f"{name}: {plural(len(getattr(self, name)), 'row')}"
                           for name in ("findings", "timeline", "nodes", "inputs", "boot",
                                        "sync", "pdo_streams", "lss"))
        return (f"<nmtcheck Report: {word} (--fail-on error): "
                f"{counts_phrase(self.summary)} in {n} input{'s' if n != 1 else ''}"
                + (f", {bad} could not be read" if bad else "") + f"; {tables}>")

    def _repr_html_(self) -> str:
        """A notebook's view: the verdict, the counts and the findings table."""
        from html import escape

        from nmtcheck.reporters.common import counts_phrase

        word = "FAIL" if self.failed() else "PASS"
        head = (f"<p><b>nmtcheck: {word}</b> (--fail-on error): "
                f"{escape(counts_phrase(self.summary))} in {len(self.inputs)} input(s)</p>")
        columns = [c for c in ("path", "rule", "name", "severity", "channel", "node",
                               "time_offset", "line", "message") if c in self.findings.columns]
        table = (self.findings[columns].to_html(index=False, max_rows=50)
                 if len(self.findings) else "<p>No findings.</p>")
        return head + table


def _frame(rows: list[dict[str, Any]], columns: list[str]) -> pd.DataFrame:
    df = pd.DataFrame(rows)
    if df.empty:
        empty: pd.DataFrame = pd.DataFrame({c: pd.Series(dtype="object") for c in columns})
        return empty
    first = [c for c in columns if c in df.columns]
    ordered: pd.DataFrame = df[first + [c for c in df.columns if c not in first]]
    return ordered


def _with_times(df: pd.DataFrame, starts: list[tuple[float, bool]],
                columns: tuple[str, ...]) -> pd.DataFrame:
    """Beside each time column (in the log's own time base: epoch seconds for candump,
    seconds from the measurement's start for ASC) `<col>_offset`, seconds from the input's
    first frame, and `<col>_utc`, a `datetime64[ns, UTC]` where the input's time is
    absolute (SPEC §7 `start_utc`), else NaT."""
    if df.empty or "input" not in df.columns:
        for col in columns:
            df[f"{col}_offset"] = pd.Series(dtype="float64")
            df[f"{col}_utc"] = pd.Series(dtype="datetime64[ns, UTC]")
        return df
    first = df["input"].map(lambda i: starts[int(i)][0]).astype("float64")
    absolute = df["input"].map(lambda i: starts[int(i)][1]).astype(bool)
    for col in columns:
        seconds = df[col].astype("float64")
        df[f"{col}_offset"] = seconds - first
        # to the microsecond, as the logs write them (a float's last bits are no time)
        stamps = pd.to_datetime((seconds.where(absolute) * 1e6).round(), unit="us", utc=True)
        stamps = stamps.astype("datetime64[ns, UTC]")
        df[f"{col}_utc"] = stamps
    return df


def _flat(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}_"))
        else:
            out[f"{prefix}{k}"] = v
    return out


def check(paths: str | PathLike[str] | Sequence[str | PathLike[str]], *,
          network: str | PathLike[str] | None = None, rules: str | None = None,
          select: Sequence[str] = (), ignore: Sequence[str] = (),
          input_format: str | None = None, strict: bool = False, channel: str | None = None,
          topics: Sequence[str] = (), jobs: int = 1,
          max_findings: int | None = None) -> Report:
    """Check logs as `nmtcheck check` does (no configuration file is read: pass what you
    need). Errors are raised as nmtcheck.errors.InputError / UsageError."""
    from nmtcheck.engine import check_inputs, select_rules
    from nmtcheck.reporters.json import report_dict
    from nmtcheck.results import MAX_FINDINGS_PER_RULE, summary
    from nmtcheck.settings.network import load_network
    from nmtcheck.settings.profiles import DEFAULT_PROFILE, load_profile

    names = _paths(paths)
    select, ignore, topics = (string_list("select", select), string_list("ignore", ignore),
                              string_list("topics", topics))
    jobs = whole_number("jobs", jobs, 0, " (0: one per core)") or os.cpu_count() or 1
    if max_findings is not None:
        whole_number("max_findings", max_findings, 0, " (0: all) or None")
    optional_text("network", network, paths=True)
    optional_text("rules", rules, paths=True)
    for name, value in (("input_format", input_format), ("channel", channel)):
        optional_text(name, value)
    if not isinstance(strict, bool):
        raise TypeError(f"strict: expected a bool, got {type(strict).__name__}")
    profile = load_profile(str(rules) if rules is not None else DEFAULT_PROFILE)
    selected = select_rules(profile, select, ignore)
    net = load_network(str(network)) if network is not None else None
    results = check_inputs(names, jobs, profile, selected, network=net,
                           input_format=input_format, strict=strict, channel=channel,
                           reader_options={"topics": topics} if topics else {},
                           max_findings=MAX_FINDINGS_PER_RULE if max_findings is None
                           else max_findings)
    doc = report_dict(results)
    path_of = {i: r["path"] for i, r in enumerate(doc["inputs"])}

    def with_path(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
        return [{**_flat(r), "path": path_of.get(r["input"])} for r in rows]

    inputs = _frame([{"input": i, **r} for i, r in enumerate(doc["inputs"])],
                    ["input", "path", "format", "frames"])
    if "start_utc" in inputs.columns:  # as findings.time_utc: a time, not a string
        inputs["start_utc"] = pd.to_datetime(inputs["start_utc"], utc=True,
                                             format="ISO8601").astype("datetime64[ns, UTC]")
    starts = [(r["start"], r.get("start_utc") is not None) for r in doc["inputs"]]
    return Report(boot=_with_times(_boot_frame(results, path_of), starts, ("start",)),
                  findings=_with_times(_frame(with_path(doc["findings"]), FINDING_COLUMNS),
                                       starts, ("time",)),
                  timeline=_with_times(_frame(with_path(doc["timeline"]), TIMELINE_COLUMNS),
                                       starts, ("start", "end")),
                  nodes=_frame(with_path(doc["nodes"]), NODE_COLUMNS),
                  inputs=inputs, summary=summary(results), results=results,
                  sync=_frame(with_path([{"input": c["input"], "channel": c["name"],
                                          **c["sync"]} for c in doc["channels"]
                                         if c.get("sync")]), ["input", "path", "channel"]),
                  pdo_streams=_frame([{**_flat({k: v for k, v in r.items()
                                                if k != "consumers"}),
                                       "consumers": r["consumers"],
                                       "path": path_of.get(r["input"])}
                                      for r in doc["pdo_streams"]],
                                     ["input", "path", "channel", "cob_id", "kind"]),
                  lss=_lss_frame(results, path_of))


def _lss_frame(results: list[Any], path_of: dict[int, str]) -> pd.DataFrame:
    """One row per LSS request of every channel; `lss_session` a nullable integer."""
    from nmtcheck.reporters.lss_report import exchange_rows

    df = _frame([{**r, "path": path_of.get(r["input"])} for res in results
                 for r in exchange_rows(res)],
                ["input", "path", "channel", "exchange", "lss_session", "time", "cs", "service",
                 "result"])
    if len(df):
        df["lss_session"] = df["lss_session"].astype("Int64")
    return df


def _paths(paths: object) -> list[str]:
    """`check`'s paths as names: one path (str or os.PathLike) or a list of them; an open
    file, bytes or a number is a TypeError naming `paths`, never a name made of it."""
    if isinstance(paths, str | PathLike):
        return [os.fspath(paths)]
    if isinstance(paths, bytes) or not isinstance(paths, Sequence):
        raise TypeError(f"paths: expected a path (str or os.PathLike) or a list of them, "
                        f"got {type(paths).__name__}")
    bad = [p for p in paths if not isinstance(p, str | PathLike)]
    if bad:
        raise TypeError(f"paths: expected a path (str or os.PathLike) or a list of them, "
                        f"the list holds a {type(bad[0]).__name__}")
    if not paths:
        raise ValueError("paths: no log to check (an empty list)")
    return [os.fspath(p) for p in paths]


def _boot_frame(results: list[Any], path_of: dict[int, str]) -> pd.DataFrame:
    """The `boot` rows of every input (fleet/tasks.py `boot_rows`, the dataset's columns),
    with `input` and `path` first."""
    from nmtcheck.fleet.dataset import COLUMNS
    from nmtcheck.fleet.tasks import boot_rows

    names = [n for n, _k in COLUMNS["boot"][6:] if n != "abs_start"]  # no fleet key
    rows = [{"input": i, "path": path_of.get(i), **dict.fromkeys(names), **r}
            for i, res in enumerate(results) for r in boot_rows(res)]
    return _frame(rows, ["input", "path", *names])
