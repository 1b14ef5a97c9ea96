"""The fleet dataset's SPEC_COMM §9.4.2 rows: `sync_stats`, `pdo_stats`, `emcy`, and the
`findings` columns `cob_id`, `causes`, `reactions` and `root_kind`.

Made from the very dicts the JSON report writes (reporters/comm_report.py), flattened
with `_` as the Python API's `Report.sync` and `Report.pdo_streams` are: one source of
truth, so a fleet row and the JSON report of the same log hold the same values. Maps
whose keys vary from log to log (a DLC histogram, findings per rule) become JSON text,
since a Parquet table needs fixed columns.
"""

from __future__ import annotations

from typing import Any

from nmtcheck.reporters import comm_report
from nmtcheck.safe_text import dumps_finite

# paths of the JSON dicts kept as JSON text rather than flattened into columns
_AS_JSON = frozenset({"dlc", "measured_dlc", "findings"})


def flat(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """A JSON dict's fields as columns: `{"period_us": {"value": 1}}` is `period_us_value`;
    the maps of _AS_JSON as JSON text; lists as they are."""
    out: dict[str, Any] = {}
    for k, v in d.items():
        name = f"{prefix}{k}"
        if name in _AS_JSON:
            out[name] = None if v is None else json_text(v)
        elif isinstance(v, dict):
            out.update(flat(v, f"{name}_"))
        else:
            out[name] = v
    return out


def json_text(value: Any) -> str:
    """Compact JSON, as the CSV report writes a finding's causes (no Infinity or NaN)."""
    return dumps_finite(value, separators=(",", ":"))


def sync_rows(res: Any) -> list[dict[str, Any]]:
    """`sync_stats`: one row per channel whose `channels[i].sync` is not null."""
    out = []
    for cm in res.model.channels:
        sync = comm_report.channel_sync(res, cm.name)
        if sync is not None:
            out.append({"channel": cm.name, **flat(sync)})
    return out


def pdo_rows(res: Any) -> list[dict[str, Any]]:
    """`pdo_stats`: one row per entry of `pdo_streams[]` (its `input` index is the
    dataset's `input_id`), its consumers a list of flattened dicts."""
    out = []
    for st in comm_report.pdo_streams(res):
        row = flat({k: v for k, v in st.items() if k not in ("input", "consumers")})
        row["consumers"] = [flat(c) for c in st["consumers"]]
        out.append(row)
    return out


def emcy_rows(res: Any) -> list[dict[str, Any]]:
    """`emcy`: one row per node and EMCY code of `nodes[i].emcy[codes]`, each with the
    node's own fields (`frames`, `in_error_at_end`, ...). A node configured for EMCY that
    sent none has no row."""
    out: list[dict[str, Any]] = []
    for m in res.nodes():
        e = comm_report.node_emcy(res, m.channel, m.node)
        if e is None:
            continue
        node = {"channel": m.channel, "node": m.node,
                **flat({k: v for k, v in e.items() if k != "codes"})}
        out.extend({**node, **code} for code in e["codes"])
    return out


def finding_fields(res: Any, f: Any) -> dict[str, Any]:
    """A finding's §9.4.2 columns: `cob_id` as in the JSON report; `causes` and
    `reactions` as JSON text with their `_omitted` counts where the rule carries causes
    (null elsewhere, as the JSON leaves them out); `root_kind`."""
    out: dict[str, Any] = {"cob_id": comm_report.finding_cob_id(res, f)}
    if f.causes is not None:
        out.update(causes=json_text(f.causes), causes_omitted=f.causes_omitted or 0,
                   reactions=json_text(f.reactions or []),
                   reactions_omitted=f.reactions_omitted or 0,
                   root_kind=root_kind(f.causes))
    return out


def root_kind(causes: list[dict[str, Any]] | None) -> str | None:
    """The kind of the deepest first cause: from the first depth-1 cause down through each
    entry's first child (`parent` is the index of the entry it explains), the last one's
    `kind`. For S005's `emcy` <- `finding` D004 <- `nmt` stop of the producer: `nmt`.
    None without causes."""
    if not causes:
        return None
    at = 0
    while True:
        child = next((j for j in range(at + 1, len(causes))
                      if causes[j].get("parent") == at), None)
        if child is None:
            return str(causes[at]["kind"])
        at = child
