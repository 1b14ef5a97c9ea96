"""PDO timing rules D001-D006 (SPEC §9.2.2): the PDO streams of `nmtcheck/processes/pdo.py`
judged against the parameters their producer and consumers give them. A gap is judged
against a party's state only where the timeline knows it: a party that reports another
state after the gap began, with no command to it, may have left OPERATIONAL on its own
before the limit (its state is not supervised, §9.1.6).
"""

from __future__ import annotations

import functools
from collections.abc import Iterator

import numpy as np

from nmtcheck.checks.base import Param, Params, Problem, flagged_runs, input_rule, windows
from nmtcheck.checks.bus_wait import bus_waits
from nmtcheck.processes import emcy as emcy_stage
from nmtcheck.processes import pdo as pdo_stage
from nmtcheck.processes import pdo_params
from nmtcheck.processes import sync as sync_stage
from nmtcheck.processes.comm_values import Value
from nmtcheck.processes.pdo import EVENT_DRIVEN, SYNCHRONOUS, Party, Stream
from nmtcheck.protocol import sdo
from nmtcheck.protocol.nmt import (
    BOOTUP,
    GUARD,
    HEARTBEAT,
    OFFLINE,
    OPERATIONAL,
    PRE_OPERATIONAL,
    STATE_INDEX,
    STATE_OF_CODE,
)
from nmtcheck.timeline.model import ChannelModel, InputModel, NodeModel
from nmtcheck.timeline.moments import at

EPS = 1e-9
_OP = STATE_INDEX[OPERATIONAL]
_OFFLINE = STATE_INDEX[OFFLINE]
_RECEIVING = np.asarray([STATE_INDEX[PRE_OPERATIONAL], _OP])
_OP_CODES = np.asarray([c for c, state in STATE_OF_CODE.items() if state == OPERATIONAL])


def _streams(model: InputModel) -> Iterator[tuple[ChannelModel, Stream]]:
    analysis = pdo_stage.of(model)
    if analysis is None:
        return
    by_name = {cm.network_name: cm for cm in model.channels}
    for st in analysis.streams:
        cm = by_name.get(st.channel)
        if cm is not None:
            yield cm, st


def _resolution(model: InputModel) -> float:
    analysis = emcy_stage.of(model)
    return analysis.resolution_s if analysis is not None else 1e-6


def _source(v: Value) -> str:
    if v.source == "sdo":
        return f"written by SDO at line {v.line}" if v.line else "written by SDO"
    return "device file" if v.source == "device-file" else str(v.source)


def _event_driven(model: InputModel, value: str
                  ) -> Iterator[tuple[ChannelModel, Stream, Party, NodeModel, float]]:
    """The TPDO streams of type 254/255 whose producer's `value` (the event timer or the
    inhibit time) is known and not 0, with the producer's node model and the value."""
    for cm, st in _streams(model):
        p = st.producer
        if p is None or not _known_in(p.transmission_type, EVENT_DRIVEN):
            continue
        v = getattr(p, value)
        m = cm.nodes.get(p.node)
        if v.known and v.value and m is not None:
            yield cm, st, p, m, float(v.value)


def _at(cm: ChannelModel, t: float, order_only: bool = False) -> str:
    """Seconds from the channel's first frame, or the frame without timestamps."""
    return at(t, cm.start, order_only)


def operational_through(m: NodeModel, t0: np.ndarray, t1: np.ndarray) -> np.ndarray:
    """Whether N is OPERATIONAL from each t0 through t1 in one interval of its timeline."""
    if not len(m.intervals):
        return np.zeros(len(t0), bool)
    a, b = m.interval_indices(t0), m.interval_indices(t1)
    ok: np.ndarray = (a == b) & (m.intervals.state[a] == _OP)
    return ok


def unsupervised(m: NodeModel, t0: np.ndarray) -> np.ndarray:
    """§9.1.6: N's first error-control report after each t0 reports a state other than
    OPERATIONAL with no NMT command to N between: its state in the gap is not known."""
    ec = m.ec
    reports = np.flatnonzero(np.isin(ec.kind, (HEARTBEAT, GUARD)) & ~ec.stale)
    if not len(reports):
        return np.zeros(len(t0), bool)
    rts = ec.ts[reports]
    k = np.searchsorted(rts, t0, side="right")
    has = k < len(rts)
    at = reports[np.minimum(k, len(reports) - 1)]
    other = ~np.isin(ec.value[at] & 0x7F, _OP_CODES)
    cmds = m.commands.ts
    commanded = np.searchsorted(cmds, rts[np.minimum(k, len(rts) - 1)], side="left") > (
        np.searchsorted(cmds, t0, side="right"))
    out: np.ndarray = has & other & ~commanded
    return out


def _first_report_after(m: NodeModel, t0: float) -> float:
    ec = m.ec
    reports = np.flatnonzero(np.isin(ec.kind, (HEARTBEAT, GUARD)) & ~ec.stale
                             & (ec.ts > t0 + EPS))
    return float(ec.ts[reports[0]]) if len(reports) else np.inf


def _fell_silent(m: NodeModel, t0: np.ndarray, nxt: np.ndarray) -> np.ndarray:
    """The producer sent no frame of any kind from t0 until it became OFFLINE on its
    timeline (H001, G002): it fell silent, not its PDO (§9.2.2, D001)."""
    iv = m.intervals
    off = np.flatnonzero(iv.state == _OFFLINE)
    out = np.zeros(len(t0), bool)
    if not len(off):
        return out
    starts = iv.start[off]
    k = np.searchsorted(starts, t0, side="right")
    has = k < len(starts)
    t_off = starts[np.minimum(k, len(starts) - 1)]
    ec_ts = m.ec.ts
    j = np.searchsorted(ec_ts, t0, side="right")
    next_ec = np.where(j < len(ec_ts), ec_ts[np.minimum(j, len(ec_ts) - 1)], np.inf)
    out = has & (next_ec >= t_off - EPS) & (nxt >= t_off - EPS)
    return out


@input_rule("D001", "tpdo-event-timer-exceeded", "warning",
            Param("tolerance", float, "allowed relative lateness over the event timer", 0.10),
            Param("margin_ms", float, "allowed lateness in ms over the event timer (the "
                  "stack's processing tick, a frame waiting for the bus)", 2.0),
            scope="node")
def tpdo_event_timer_exceeded(model: InputModel, params: Params) -> Iterator[Problem]:
    """An event-driven TPDO stays away longer than its event timer.

    **What it checks.** A TPDO of transmission type 254 or 255 whose event timer E
    (1800h+k-1 sub 5) is known: after a frame at t_l no frame of the stream within
    L = E x (1 + `tolerance`) + `margin_ms`, while the producer is OPERATIONAL without
    interruption through t_l + L, its state supervised, and the trace goes on past
    t_l + L. Never for a gap that begins outside OPERATIONAL (the first TPDO after a start),
    in which the producer leaves OPERATIONAL, or in which it sends nothing at all until
    it is OFFLINE (it fell silent: H001 or G002 say so).

    **Why it matters.** The consumers' RPDO deadlines (D004) are set from the producer's
    event timer: a late TPDO is the first step to an RPDO timeout and a consumer leaving
    OPERATIONAL.

    **Example.** `event_timer_ms = 100`: TPDOs at 10.102 and 10.202, the next at 10.500.
    """
    tolerance, margin = float(params["tolerance"]), float(params["margin_ms"]) / 1000
    for cm, st, p, m, event_timer_ms in _event_driven(model, "event_timer_ms"):
        e = event_timer_ms / 1000
        limit = e * (1 + tolerance) + margin
        for _a, ts, nxt, idx in _windows(st):
            due = np.round(ts + limit, 9)  # 10.05 + 0.05 is not above 10.1
            fire = ((nxt > due + EPS) & (cm.end >= due - EPS)
                    & operational_through(m, ts, due) & ~unsupervised(m, ts)
                    & ~_fell_silent(m, ts, nxt))
            for k in np.flatnonzero(fire).tolist():
                gap = (f"{(nxt[k] - ts[k]) * 1000:.3f}" if np.isfinite(nxt[k])
                       else f"at least {(cm.end - ts[k]) * 1000:.3f}")
                yield Problem(cm.name, p.node, float(due[k]),
                              f"no TPDO {st.cob_id:03X}h from node {p.node} for {gap} ms "
                              f"while OPERATIONAL; event timer {p.base_index:04X}h:05 = "
                              f"{e * 1000:g} ms ({_source(p.event_timer_ms)}), limit "
                              f"{limit * 1000:.3f} ms", after=int(idx[k]))


def _windows(st: Stream) -> Iterator[tuple[int, np.ndarray, np.ndarray, np.ndarray]]:
    """The stream's frames a window at a time (base.windows): (the first one's position,
    their ts, the next frame's ts (inf after the last), frame index)."""
    ts, idx, _line = st.frames()
    n = len(ts)
    for a, b in windows(n):
        yield a, ts[a:b], np.append(ts[a + 1:b], ts[b] if b < n else np.inf), idx[a:b]


def _known_in(v: Value, values: range | tuple[int, ...]) -> bool:
    return v.known and int(v.value or 0) in values


@input_rule("D002", "tpdo-inhibit-violation", "error", exempt_from_unknown=True, scope="node")
def tpdo_inhibit_violation(model: InputModel, params: Params) -> Iterator[Problem]:
    """Two TPDOs of an event-driven stream closer than the inhibit time.

    **What it checks.** Consecutive frames F1, F2 of a TPDO of type 254/255 whose inhibit
    time I (1800h+k-1 sub 3, 100 us units) is known, with t(F2) - t(F1) shorter than
    I x 100 us less the timestamp resolution and less the time F1 may have waited for the
    bus (a back-to-back run of frames before it), the producer OPERATIONAL through both.
    One finding per run of violating pairs, at the first F2.

    **Why it matters.** CANopenNode, Lely and CanFestival hold a TPDO until the inhibit
    time since the previous one has passed: a shorter spacing on the bus is the producer
    breaking its own configuration, and the bus load it was set to bound.

    **Example.** `inhibit_100us = 100` (10 ms): TPDOs at 10.010 and 10.013.
    """
    r = _resolution(model)
    for cm, st, p, m, inhibit_100us in _event_driven(model, "inhibit_100us"):
        ts, idx, line = st.frames()
        if len(ts) < 2:
            continue
        inhibit = inhibit_100us * 1e-4
        # the pairs (by their first frame) closer than I less r, a window at a time: a
        # stream that keeps its inhibit time has few (the last frame's next is inf)
        found = [a + np.flatnonzero((t1 - t0 < inhibit - r - EPS)
                                    & operational_through(m, t0, t1))
                 for a, t0, t1, _idx in _windows(st)]
        close = np.concatenate(found) if found else np.zeros(0, np.int64)
        q = bus_waits(model, cm, idx[close])  # one pass over the frame times
        bad = np.zeros(len(ts) - 1, bool)
        bad[close] = ts[close + 1] - ts[close] < inhibit - r - q - EPS
        join = np.zeros(len(bad), bool)
        join[1:] = bad[1:] & bad[:-1]
        for j, n in flagged_runs(join, bad):
            dt = np.diff(ts[j:j + n + 1])
            qj = float(q[int(np.searchsorted(close, j))])
            yield Problem(cm.name, p.node, float(ts[j + 1]),
                          f"TPDO {st.cob_id:03X}h of node {p.node} "
                          f"{dt[0] * 1000:.3f} ms after the previous one (line "
                          f"{int(line[j])}); inhibit time {p.base_index:04X}h:03 = "
                          f"{p.inhibit_100us.value} x 100 us = {inhibit * 1000:g} ms "
                          f"({_source(p.inhibit_100us)}), allowance "
                          f"{(r + qj) * 1000:.3f} ms"
                          + (f" ({n} pairs, the closest {float(dt.min()) * 1000:.3f} ms)"
                             if n > 1 else ""), int(idx[j + 1]), int(line[j + 1]))


@input_rule("D003", "sync-tpdo-count", "warning", exempt_from_unknown=True, scope="node")
def sync_tpdo_count(model: InputModel, params: Params) -> Iterator[Problem]:
    """A synchronous TPDO missing, extra or late per n SYNCs.

    **What it checks.** A TPDO of synchronous type n (0-240, the producer's) with SYNC
    frames on its channel: between consecutive frames of the stream, while the producer is
    OPERATIONAL throughout and both lie in one SYNC segment, the number of SYNCs k must be
    n. A late TPDO (k = n + 1, then n - 1) is one finding; k = m x n (m >= 2) is a missing
    one, at the SYNC that closed the first empty interval; k = 0 is an extra one; any
    other k a slip. After the stream's last frame, n + 1 SYNCs without it while the
    producer stays OPERATIONAL: it stopped. Type 0: only two TPDOs between the same SYNCs
    are judged. The phase of a first TPDO is never judged (the stacks place it apart).

    **Why it matters.** A synchronous consumer samples once per SYNC cycle: a missing or
    late TPDO is a cycle of stale data, a TPDO outside its cycle a wrong sample. Counting
    needs every SYNC and PDO in the log: a logger drop looks the same (I004 says).

    **Example.** type 2: TPDOs at 10.0305 and 10.0705 with four SYNCs between them.
    """
    sync = sync_stage.of(model)
    for cm, st in _streams(model):
        p = st.producer
        sc = sync.channels.get(cm.name) if sync is not None else None
        if p is None or sc is None or not len(sc) or not _known_in(p.transmission_type,
                                                                   SYNCHRONOUS):
            continue
        m = cm.nodes.get(p.node)
        ts, idx, line = st.frames()
        if m is None or not len(ts):
            continue
        yield from _sync_count(cm, st, p, m, sc, int(p.transmission_type.value or 0),
                               ts, idx, line)


def _sync_count(cm: ChannelModel, st: Stream, p: Party, m: NodeModel,
                sc: sync_stage.SyncChannel, n: int, ts: np.ndarray, idx: np.ndarray,
                line: np.ndarray) -> Iterator[Problem]:
    pos = np.searchsorted(sc.ts, ts, side="left")  # SYNCs before each frame
    seg = sc.segment[np.maximum(np.searchsorted(sc.ts, ts, side="right") - 1, 0)]
    k = np.diff(pos)  # SYNCs strictly between consecutive frames (none at equal times)
    judged = operational_through(m, ts[:-1], ts[1:]) & (seg[1:] == seg[:-1]) & (
        np.searchsorted(sc.ts, ts[:-1], side="right") > 0)
    kinds = _count_kinds(k, judged, n)
    oo = m.order_only
    join = np.zeros(len(k), bool)
    join[1:] = (kinds[1:] == kinds[:-1]) & (kinds[1:] > 0)
    for i, count in flagged_runs(join, kinds > 0):
        kind = int(kinds[i])
        more = f" ({count} times)" if count > 1 else ""
        if kind == 2:
            s = int(pos[i]) + n  # the (n+1)-th SYNC after F_{i-1}
            yield Problem(cm.name, p.node, float(sc.ts[s]),
                          f"TPDO {st.cob_id:03X}h (type {n}) missing after SYNC at "
                          f"{_at(cm, float(sc.ts[s - 1]), oo)} (line {int(sc.line[s - 1])}): "
                          f"{int(k[i])} SYNCs between TPDOs at {_at(cm, float(ts[i]), oo)} and "
                          f"{_at(cm, float(ts[i + 1]), oo)}, expected {n}{more}",
                          int(sc.idx[s]), int(sc.line[s]))
            continue
        text = {1: f"TPDO {st.cob_id:03X}h sent after the next SYNC ({n + 1} SYNCs since "
                   f"the previous TPDO, then {n - 1})",
                3: f"two TPDOs {st.cob_id:03X}h between the same SYNCs, expected one per "
                   f"{max(n, 1)} SYNC(s)",
                4: f"{int(k[i])} SYNCs between TPDOs {st.cob_id:03X}h, expected {n}"}[kind]
        yield Problem(cm.name, p.node, float(ts[i + 1]), text + more, int(idx[i + 1]),
                      int(line[i + 1]))
    if n:  # (e): stopped after its last frame
        last = len(ts) - 1
        after = int(pos[last]) if ts[last] < sc.ts[min(int(pos[last]), len(sc) - 1)] else (
            int(np.searchsorted(sc.ts, ts[last], side="right")))
        due, closed = after + n - 1, after + n
        if closed < len(sc) and sc.segment[closed] == seg[last] and bool(operational_through(
                m, ts[last:], sc.ts[due:due + 1])[0]) and not bool(
                unsupervised(m, ts[last:])[0] and _first_report_after(
                    m, float(ts[last])) <= sc.ts[closed]):
            yield Problem(cm.name, p.node, float(sc.ts[closed]),
                          f"no TPDO {st.cob_id:03X}h for {n + 1} SYNCs while node {p.node} "
                          "is OPERATIONAL", int(sc.idx[closed]), int(sc.line[closed]))


def _count_kinds(k: np.ndarray, judged: np.ndarray, n: int) -> np.ndarray:
    """Per pair of consecutive TPDOs: 0 fine, 1 late, 2 missing, 3 extra, 4 slip, tested
    in the order late, missing, extra, slip; the pair after a late one is not judged."""
    if n == 0:  # only two TPDOs between the same SYNCs are judged
        out: np.ndarray = np.where(judged & (k == 0), 3, 0).astype(np.int8)
        return out
    nxt = np.append(k[1:], -1)
    late = judged & (k == n + 1) & (nxt == n - 1)
    after_late = np.zeros(len(k), bool)
    after_late[1:] = late[:-1]
    ok = judged & ~after_late
    out = np.select([late, ok & (k >= 2 * n) & (k % n == 0), ok & (k == 0), ok & (k != n)],
                    [1, 2, 3, 4], 0).astype(np.int8)
    return out


@input_rule("D004", "rpdo-deadline-missed", "error", scope="node")
def rpdo_deadline_missed(model: InputModel, params: Params) -> Iterator[Problem]:
    """An armed RPDO deadline expires while the consumer is OPERATIONAL.

    **What it checks.** A consumer C whose RPDO k of the stream is not synchronous and has
    an event timer E_c (1400h+k-1 sub 5, the deadline): armed by a frame received while C
    is OPERATIONAL and re-armed by every later one, it fires when no frame follows within
    E_c (plus the timestamp resolution) while C stays OPERATIONAL, its state supervised,
    and the trace goes on. A later report of another state does not void the gap when C
    sent EMCY 8250h after the deadline and before that report: C left OPERATIONAL because
    of this timeout. Never before C's first frame of the stream while OPERATIONAL.

    **Why it matters.** CANopenNode raises EMCY 8250h (RPDO timeout) and, with the
    communication bit in its error-register mask, drops to PRE-OPERATIONAL: the machine
    stops because a producer went quiet.

    **Example.** deadline 50 ms: RPDOs at 10.030 and 10.050, the next at 10.200.
    """
    r = _resolution(model)
    emcy = emcy_stage.of(model)
    analysis = pdo_stage.of(model)
    for cm, st in _streams(model):
        @functools.cache
        def period(st: Stream = st) -> float | None:  # the stream's, found at its first gap
            return _stream_period(st, st.frames()[0])

        for c in st.consumers:
            if _known_in(c.transmission_type, SYNCHRONOUS):
                continue
            if not c.event_timer_ms.known or not c.event_timer_ms.value:
                continue
            m = cm.nodes.get(c.node)
            if m is None:
                continue
            e = float(c.event_timer_ms.value) / 1000
            producer = f"node {st.producer.node}" if st.producer else "unknown"
            e_node = emcy.nodes.get((cm.name, c.node)) if emcy is not None else None
            for _a, ts, nxt, idx in _windows(st):
                due = np.round(ts + e, 9)  # 10.05 + 0.05 is not above 10.1
                armed = operational_through(m, ts, ts)
                fire = (armed & (nxt > due + r + EPS) & (cm.end >= due - EPS)
                        & operational_through(m, ts, due))
                confirm = _emcy_8250(emcy, cm.name, c.node, due, nxt)
                fire &= ~unsupervised(m, ts) | (confirm >= 0)
                for k in np.flatnonzero(fire).tolist():
                    gap = (f"{(nxt[k] - ts[k]) * 1000:.3f}" if np.isfinite(nxt[k])
                           else f"at least {(cm.end - ts[k]) * 1000:.3f}")
                    text = (f"no RPDO {st.cob_id:03X}h for node {c.node} for {gap} ms; "
                            f"deadline {c.base_index:04X}h:05 = {e * 1000:g} ms "
                            f"({_source(c.event_timer_ms)}); producer {producer}")
                    j = int(confirm[k])
                    if j >= 0 and e_node is not None:
                        text += (f"; confirmed by EMCY 8250h of node {c.node} at "
                                 f"{_at(cm, float(e_node.ts[j]))} (line "
                                 f"{int(e_node.line[j])})")
                    if analysis is not None:
                        analysis.gaps[(cm.name, c.node, round(float(due[k]), 9))] = (
                            pdo_stage.PdoGap(st.cob_id, float(ts[k]), int(idx[k]),
                                             float(nxt[k]),
                                             st.producer.node if st.producer else None,
                                             period() or e))
                    yield Problem(cm.name, c.node, float(due[k]), text, after=int(idx[k]))


def _stream_period(st: Stream, ts: np.ndarray) -> float | None:
    """The stream's period for t_e of §9.3.2: the producer's event timer (type 254/255),
    else its median interval over at least 3 intervals; None: unknown."""
    p = st.producer
    if p is not None and _known_in(p.transmission_type, EVENT_DRIVEN) and (
            p.event_timer_ms.known and p.event_timer_ms.value):
        return float(p.event_timer_ms.value) / 1000
    return float(np.median(np.diff(ts))) if len(ts) > 3 else None


def _emcy_8250(emcy: emcy_stage.EmcyAnalysis | None, channel: str, node: int,
               due: np.ndarray, nxt: np.ndarray) -> np.ndarray:
    """Per gap, the position of C's first EMCY 8250h at or after the deadline and before
    the stream's next frame (-1: none)."""
    out = np.full(len(due), -1, np.int64)
    e = emcy.nodes.get((channel, node)) if emcy is not None else None
    if e is None or not len(e):
        return out
    rpdo = np.flatnonzero(e.code == 0x8250)
    if not len(rpdo):
        return out
    k = np.searchsorted(e.ts[rpdo], due - EPS, side="left")
    hit = (k < len(rpdo)) & (e.ts[rpdo[np.minimum(k, len(rpdo) - 1)]] < nxt)
    out[hit] = rpdo[k[hit]]
    return out


@input_rule("D005", "pdo-length-mismatch", "error", exempt_from_unknown=True, scope="node")
def pdo_length_mismatch(model: InputModel, params: Params) -> Iterator[Problem]:
    """A PDO's length differs from the mapped length.

    **What it checks.** (a) A frame of a TPDO whose DLC differs from the producer's mapped
    length (1A00h+k-1); (b) a frame received while a consumer C is PRE-OPERATIONAL or
    OPERATIONAL whose DLC differs from C's mapped length (1600h+k-1). The mapped length is
    the sum of the entries' bits, in bytes; a mapping of 0 entries or an MPDO is not
    judged. One finding per stream, party and DLC between the party's boot-ups or resets.

    **Why it matters.** CANopenNode checks the length at reception in every state and
    raises EMCY 8210h (shorter: the frame is discarded) or 8220h (longer) once started;
    Lely discards a short one: producer and consumer disagree on what the PDO carries.

    **Example.** node 4 maps 3 bytes: `204#0F00`.
    """
    for cm, st in _streams(model):
        ts, idx, line = st.frames()
        if not len(ts):
            continue
        dlc = st.dlc.astype(np.int64)
        parties = ([("a", st.producer)] if st.producer is not None else []) + [
            ("b", c) for c in st.consumers]
        for which, party in parties:
            pieces = party.pieces
            if pieces is None or not pieces.known:
                continue
            m = cm.nodes.get(party.node)
            piece = pieces.at(ts)
            wants = pieces.length[piece]
            bad = (wants > 0) & (dlc != wants) & pdo_params.valid_at(
                m, party.base_index, st.cob_id, ts)
            if which == "b":
                if m is None or not len(m.intervals):
                    continue
                bad &= np.isin(m.intervals.state[m.interval_indices(ts)], _RECEIVING)
            epoch = _epochs(m, ts)
            seen: set[tuple[int, int]] = set()
            for k in np.flatnonzero(bad).tolist():
                key = (int(epoch[k]), int(dlc[k]))
                if key in seen:
                    continue
                seen.add(key)
                n = int(np.count_nonzero(bad & (epoch == epoch[k]) & (dlc == dlc[k])))
                more = f" ({n} frames)" if n > 1 else ""
                want, source = int(wants[k]), pieces.source[int(piece[k])]
                if which == "a":
                    text = (f"TPDO {st.cob_id:03X}h of node {party.node} has DLC {dlc[k]}; "
                            f"its mapping {party.map_index:04X}h has {want} bytes "
                            f"({_source(source)}){more}")
                else:
                    what = ("discards it and raises EMCY 8210h" if dlc[k] < want
                            else "raises EMCY 8220h")
                    text = (f"RPDO {st.cob_id:03X}h has DLC {dlc[k]}; node {party.node} maps "
                            f"{want} bytes ({party.map_index:04X}h, {_source(source)}):"
                            f" node {party.node} {what}{more}")
                yield Problem(cm.name, party.node, float(ts[k]), text, int(idx[k]),
                              int(line[k]))


def _epochs(m: NodeModel | None, ts: np.ndarray) -> np.ndarray:
    """Per time, how many of the node's boot-ups and resets came before it."""
    if m is None:
        return np.zeros(len(ts), np.int64)
    marks = np.sort(np.concatenate([m.ec.ts[m.ec.kind == BOOTUP], m.commands.reset_ts]))
    out: np.ndarray = np.searchsorted(marks, ts, side="right")
    return out


@input_rule("D006", "reserved-transmission-type", "warning", exempt_from_unknown=True,
            scope="node")
def reserved_transmission_type(model: InputModel, params: Params) -> Iterator[Problem]:
    """An SDO download writes a reserved PDO transmission type.

    **What it checks.** An SDO download to node N (expedited, or a segmented one's value)
    of sub-index 2 of 1800h-19FFh with 241-251, or of 1400h-15FFh with 241-253. TPDO types
    252 and 253 (RTR-only) are valid. Reported at the download request, with what N did.

    **Why it matters.** Refused, the master's configuration step failed (inside a boot
    process P003 reports it); accepted, the device holds a value CiA 301 reserves, and
    what it does with it is the stack's guess.

    **Example.** `603#2F021802F1000000`: 1802h:02 = 241.
    """
    analysis = pdo_stage.of(model)
    for w in analysis.reserved if analysis is not None else ():
        kind = "241–251 (TPDO)" if w.index >= 0x1800 else "241–253 (RPDO)"
        if w.result == "ok":
            outcome = "accepted it"
        elif w.result in ("refused", "aborted"):
            outcome = (f"refused it (abort {w.abort_code:08X}h: "
                       f"{sdo.abort_text(w.abort_code)})")
        else:
            outcome = "did not answer"
        yield Problem(w.channel, w.node, w.time,
                      f"download {w.index:04X}h:02 = {w.value} to node {w.node}: transmission "
                      f"types {kind} are reserved; node {w.node} {outcome}", w.frame_index,
                      w.line)
