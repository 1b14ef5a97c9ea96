"""CSV: one row per finding, for spreadsheets and pandas."""

from __future__ import annotations

import csv
import io
import json

from nmtcheck.reporters.common import spreadsheet_safe as safe
from nmtcheck.results import InputResult

COLUMNS = ["input", "path", "rule", "name", "severity", "channel", "node", "time", "offset",
           "frame_index", "line", "message", "causes", "reactions"]


def _entries(entries: list[dict[str, object]] | None) -> str:
    """A finding's causes or reactions (SPEC §9.3.6) as one JSON string; empty for a rule
    that has none."""
    return "" if entries is None else safe(json.dumps(entries, separators=(",", ":")))


def render(results: list[InputResult], options: dict[str, object]) -> str:
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(COLUMNS)
    for res in results:
        if res.error is not None:  # named, never dropped (SPEC §4)
            w.writerow([res.index, safe(res.stats.path), "", "", "error", "", "", "", "", "",
                        "", safe(f"cannot be checked: {res.error}"), "", ""])
            continue
        start = res.stats.start or 0.0
        for f in res.findings:
            w.writerow([f.input, safe(res.stats.path), f.rule, f.name, f.severity,
                        safe(f.channel), "" if f.node is None else f.node, f"{f.time:.6f}",
                        f"{f.time - start:.6f}", "" if f.frame_index is None else f.frame_index,
                        f.line or "", safe(f.message), _entries(f.causes),
                        _entries(f.reactions if f.causes is not None else None)])
        for o in res.omitted:  # a row that says how many were left out, not a silent cut
            w.writerow([res.index, safe(res.stats.path), o.rule, o.name, o.severity, "", "",
                        "", "", "", "", f"{o.count} more finding(s) left out of this report "
                        f"(--max-findings {options.get('max_findings')})", "", ""])
    return out.getvalue()
