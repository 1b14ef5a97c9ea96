"""`--statistics`: one line per rule that fired, with its count, instead of every finding
(as `ruff --statistics`); most frequent first. `--format json` gives a JSON list."""

from __future__ import annotations

import json
from collections import Counter

from nmtcheck.reporters.common import verdict_line
from nmtcheck.results import InputResult


def rule_counts(results: list[InputResult]) -> list[tuple[str, str, str, int]]:
    """(code, name, severity, count) per rule (and configured severity), most first."""
    counts: Counter[tuple[str, str, str]] = Counter(
        (f.rule, f.name, f.severity) for res in results for f in res.findings)
    for res in results:
        for o in res.omitted:  # every finding counts, also those left out of the reports
            counts[(o.rule, o.name, o.severity)] += o.count
    return sorted(((c, n, s, k) for (c, n, s), k in counts.items()),
                  key=lambda row: (-row[3], row[0]))


def render(results: list[InputResult], options: dict[str, object]) -> str:
    rows = rule_counts(results)
    width = max((len(str(k)) for *_x, k in rows), default=1)
    names = max((len(n) for _c, n, _s, _k in rows), default=0)
    lines = [f"{k:>{width}}  {c}  {n:<{names}}  [{s}]" for c, n, s, k in rows]
    lines.append(verdict_line(results, options))
    return "\n".join(lines) + "\n"


def render_json(results: list[InputResult], options: dict[str, object]) -> str:
    return json.dumps([{"code": c, "name": n, "severity": s, "count": k}
                       for c, n, s, k in rule_counts(results)], indent=2) + "\n"
