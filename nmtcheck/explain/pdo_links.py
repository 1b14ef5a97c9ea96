"""The causes of D001 and D003 (SPEC §9.3.2-9.3.4): the links `bus_silence`, `bus_errors`,
`frames_lost` and `lss_bit_timing`.

A late event-driven TPDO (D001) or a synchronous TPDO missing at its SYNC (D003 (a), (e))
has no producer link of its own (the producer was OPERATIONAL throughout, the rules
check that): what may explain it is the bus (a silence or error frames that began in
the gap), a logger's drop that hid the frame, or an LSS bit-rate switch that took the
producer to another bit rate. A D003 whose frame came at the wrong SYNC ((b)-(d)) can
only be explained by a drop (`frames_lost`).
"""

from __future__ import annotations

import re
from typing import TYPE_CHECKING, Any

import numpy as np

from nmtcheck.explain import lss_link
from nmtcheck.processes import pdo as pdo_stage
from nmtcheck.processes import sync as sync_stage
from nmtcheck.protocol.nmt import EPS

if TYPE_CHECKING:
    from nmtcheck.processes.pdo import Stream
    from nmtcheck.results import Finding

ROOTS = ("D001", "D003")
_COB = re.compile(r"TPDOs? ([0-9A-F]{3})h")  # both rules name the stream first


def _stream(model: Any, f: Finding) -> Stream | None:
    analysis = pdo_stage.of(model)
    found = _COB.search(f.message)
    if analysis is None or found is None:
        return None
    cob = int(found.group(1), 16)
    return next((s for s in analysis.streams if s.channel == f.channel and s.cob_id == cob),
                None)


def entries(ctx: Any, f: Finding) -> tuple[list[dict[str, Any]], float] | None:
    """A D001 or D003 finding's link causes and t_e: D001 t_l + E (at most t_f); D003
    (a)/(e), whose frame is the SYNC that closed the gap, the SYNC before it (the due one),
    (b)-(d) the TPDO itself (only `frames_lost` then)."""
    cm = ctx.channels.get(str(f.channel))
    st = _stream(ctx.model, f)
    if cm is None or st is None:
        return None
    ts = st.frames()[0]
    tf = f.time
    gap = True
    if f.rule == "D001":
        k = int(np.searchsorted(ts, tf + EPS, side="right"))
        p = st.producer
        if k == 0 or p is None or not p.event_timer_ms.known:
            return None
        tl = float(ts[k - 1])
        te = min(tl + float(p.event_timer_ms.value or 0) / 1000, tf)
    else:
        sync = sync_stage.of(ctx.model)
        sc = sync.channels.get(cm.name) if sync is not None else None
        if sc is None or not len(sc):
            return None
        s = int(np.searchsorted(sc.idx, f.frame_index)) if f.frame_index is not None else -1
        gap = 0 < s < len(sc) and int(sc.idx[s]) == f.frame_index
        te = float(sc.ts[s - 1]) if gap else tf
        # F_{i-1}: the stream's last frame before the due SYNC, or before the TPDO F_i
        k = int(np.searchsorted(ts, te + EPS, side="right") if gap
                else np.searchsorted(ts, tf - EPS, side="left"))
        if k == 0:
            return None
        tl = float(ts[k - 1])
    out: list[dict[str, Any]] = []
    if gap:  # SPEC §9.3.4: D001 and D003 (a)/(e) only
        # a stretch that begins in [t_l, t_e]; it ends after t_e (the gap is its part),
        # so the frames are searched up to the reactions window's end
        out += [dict(c, link="bus_silence") for c in ctx._silence(cm, None,
                                                                  [(tl, tf + ctx.after)])
                if tl - EPS <= c["time"] <= te + EPS]
        out += [dict(c, link="bus_errors") for c in ctx._error_frames(cm, [(tl, te)])]
        out += lss_link.bit_timing_entries(ctx.model, f.channel, te, ctx.before)
    out += [dict(c, link="frames_lost") for c in ctx._frames_lost(cm, [(tl, tf)])]
    return out, te
