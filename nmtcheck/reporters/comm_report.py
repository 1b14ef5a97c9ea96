"""What the reports show of the SYNC, PDO and EMCY reconstruction (SPEC §9.4.1): the
fields of `channels[i].sync`, `pdo_streams[]`, `nodes[i].emcy`,
`inputs[i].timestamp_resolution_us` and a finding's `cob_id`, made in one place for every
format that carries them."""

from __future__ import annotations

from typing import Any

import numpy as np

from nmtcheck.checks.base import windows
from nmtcheck.processes import emcy as emcy_stage
from nmtcheck.processes import pdo as pdo_stage
from nmtcheck.processes import sync as sync_stage
from nmtcheck.protocol import emcy
from nmtcheck.protocol.nmt import OPERATIONAL, STATE_INDEX
from nmtcheck.results import Finding, InputResult

SYNC_RULES = ("Y001", "Y002", "Y003", "Y004", "Y005")
_OPERATIONAL = STATE_INDEX[OPERATIONAL]


def channel_sync(res: InputResult, channel: str) -> dict[str, Any] | None:
    """`channels[i].sync`: null on a channel with neither SYNC frames nor SYNC
    configuration."""
    analysis = sync_stage.of(res.model)
    sc = analysis.channels.get(channel) if analysis is not None else None
    return None if sc is None else sc.as_dict()


def node_emcy(res: InputResult, channel: str, node: int) -> dict[str, Any] | None:
    """`nodes[i].emcy`: null for a node without EMCY frames or EMCY configuration."""
    analysis = emcy_stage.of(res.model)
    e = analysis.nodes.get((channel, node)) if analysis is not None else None
    return None if e is None else e.as_dict()


def emcy_detail(res: InputResult, channel: str, node: int, idx: int
                ) -> dict[str, object] | None:
    """CANopenNode's `{"error_bit", "info", "meaning"}` of an EMCY event (SPEC §9.1.7)."""
    analysis = emcy_stage.of(res.model)
    e = analysis.nodes.get((channel, node)) if analysis is not None else None
    if e is None:
        return None
    k = int(np.searchsorted(e.idx, idx))
    if k >= len(e) or int(e.idx[k]) != idx:
        return None
    return emcy.canopennode_detail(e.data_bytes(k), int(e.dlc[k]))


def resolution_us(res: InputResult) -> float | None:
    """The timestamp resolution r the time rules allowed for (SPEC §9.1.6)."""
    analysis = emcy_stage.of(res.model)
    return None if analysis is None else round(analysis.resolution_s * 1e6, 6)


def finding_cob_id(res: InputResult, f: Finding) -> str | None:
    """A Y finding's SYNC COB-ID (`"080h"`), a D finding's PDO COB-ID; null for the other
    rules (SPEC §9.2.0)."""
    if f.rule == "Y004" or (f.rule.startswith("D") and f.rule != "D006"):
        cob = _cob_in(f.message)
        return None if cob is None else f"{cob:03X}h"
    if f.rule not in SYNC_RULES or f.channel is None:
        return None
    analysis = sync_stage.of(res.model)
    sc = analysis.channels.get(f.channel) if analysis is not None else None
    return None if sc is None else f"{sc.cob_id:03X}h"


def pdo_streams(res: InputResult) -> list[dict[str, Any]]:
    """`pdo_streams[]` (SPEC §9.4.1): one per stream the files describe, with its producer
    and consumers, the parameters in force and the measured timing."""
    analysis = pdo_stage.of(res.model)
    if analysis is None:
        return []
    model = res.model
    counts = _finding_counts(res)
    out = []
    for st in analysis.streams:
        ts, _idx, _line = st.frames()
        p = st.producer
        out.append({
            "input": res.index, "channel": st.channel, "cob_id": f"{st.cob_id:03X}h",
            "kind": st.kind, "valid": True,
            "producer": None if p is None else {"node": p.node, "pdo": p.pdo,
                                                "source": _party_source(p)},
            "consumers": [{"node": c.node, "pdo": c.pdo, "source": _party_source(c),
                           **_parameters(c)} for c in st.consumers],
            "parameters": _parameters(p) if p is not None else {},
            "measured": _measured(st, ts, model),
            "findings": counts.get((st.channel, st.cob_id), {}),
        })
    return out


def _party_source(p: pdo_stage.Party) -> str | None:
    for v in (p.transmission_type, p.event_timer_ms, p.inhibit_100us, p.mapping):
        if v.known:
            return v.source
    return "default"


def _parameters(p: pdo_stage.Party) -> dict[str, Any]:
    mapping = {"entries": [f"{e >> 16:04X}h:{(e >> 8) & 0xFF:02X}/{e & 0xFF}"
                           for e in p.entries], "bytes": p.mapping.value,
               "source": p.mapping.source}
    return {"transmission_type": p.transmission_type.as_dict(),
            "inhibit_100us": p.inhibit_100us.as_dict() if p.kind == "tpdo" else None,
            "event_timer_ms": p.event_timer_ms.as_dict(), "mapping": mapping}


def _measured(st: pdo_stage.Stream, ts: Any, model: Any) -> dict[str, Any]:
    """Frames, remote requests are not kept (0), DLCs, and the intervals: inside the
    producer's OPERATIONAL intervals when the producer is known, else all."""
    dlcs, counts = np.unique(st.dlc, return_counts=True)
    out: dict[str, Any] = {"frames": len(ts),
                           "dlc": {str(int(d)): int(c) for d, c in zip(dlcs, counts,
                                                                        strict=True)}}
    iv = stream_intervals(st, ts, model)
    if len(iv):
        worst = int(np.argmax(iv))
        out.update({"period_min_ms": round(float(iv.min()) * 1000, 3),
                    "period_median_ms": round(float(np.median(iv)) * 1000, 3),
                    "period_max_ms": round(float(iv.max()) * 1000, 3),
                    "worst_gap_ms": round(float(iv[worst]) * 1000, 3)})
    return out


def stream_intervals(st: pdo_stage.Stream, ts: Any, model: Any) -> np.ndarray:
    """The intervals (s) `measured` reports of a stream with frames at `ts`: inside the
    producer's OPERATIONAL intervals when the producer is known, else all."""
    iv: np.ndarray = np.diff(ts)
    if st.producer is not None and len(iv):
        cm = next((c for c in model.channels if c.network_name == st.channel), None)
        m = cm.nodes.get(st.producer.node) if cm is not None else None
        if m is not None and len(m.intervals):
            inside = np.zeros(len(iv), bool)
            for a, b in windows(len(iv)):  # the index arrays a window at a time
                i, j = m.interval_indices(ts[a:b]), m.interval_indices(ts[a + 1:b + 1])
                inside[a:b] = (i == j) & (m.intervals.state[i] == _OPERATIONAL)
            iv = iv[inside]
    return iv


def pdo_stream_intervals(res: InputResult) -> list[np.ndarray]:
    """Per stream, in `pdo_streams(res)`'s order, the intervals its `measured` counts."""
    analysis = pdo_stage.of(res.model)
    if analysis is None:
        return []
    return [stream_intervals(st, st.frames()[0], res.model) for st in analysis.streams]


def _finding_counts(res: InputResult) -> dict[tuple[str, int], dict[str, int]]:
    """Per (channel, COB-ID), the D and Y004 findings by rule (their messages name the
    COB-ID as `183h`)."""
    out: dict[tuple[str, int], dict[str, int]] = {}
    for f in res.findings:
        if not (f.rule.startswith("D") or f.rule == "Y004") or f.channel is None:
            continue
        cob = _cob_in(f.message)
        if cob is not None:
            counts = out.setdefault((f.channel, cob), {})
            counts[f.rule] = counts.get(f.rule, 0) + 1
    return out


def _cob_in(message: str) -> int | None:
    """The first COB-ID a D or Y004 message names (`TPDO 183h ...`)."""
    for word in message.replace("(", " ").split():
        if len(word) == 4 and word.endswith("h") and all(
                ch in "0123456789ABCDEF" for ch in word[:3]):
            return int(word[:3], 16)
    return None
