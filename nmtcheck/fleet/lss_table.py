"""The fleet dataset's `lss` table (SPEC §9.4.2): one row per LSS request of a log, the
fields of the JSON report's `lss[].exchanges[]` (reporters/lss_report.py, the one place
they are made), the answers as a JSON string."""

from __future__ import annotations

import json
from typing import Any

# (name, arrow type), after the dataset's key columns (fleet/dataset.py)
COLUMNS: list[tuple[str, str]] = [
    ("channel", "string"), ("exchange", "int64"), ("lss_session", "int64"), ("time", "float64"),
    ("abs_time", "timestamp"), ("frame_index", "int64"), ("line", "int64"), ("cs", "string"),
    ("service", "string"), ("argument", "int64"), ("cfg", "string"), ("dlc", "int64"),
    ("result", "string"), ("responses", "string")]


def rows(res: Any, key: dict[str, Any], date: str, absolute: bool) -> list[dict[str, Any]]:
    """The log's rows; `abs_time` set where the log's clock is wall-clock time."""
    from nmtcheck.reporters.lss_report import exchange_rows  # (the schema alone is light)

    return [{**key, **{k: v for k, v in r.items() if k != "input"}, "date": date,
             "abs_time": r["time"] if absolute else None,
             "responses": json.dumps(r["responses"])} for r in exchange_rows(res)]
