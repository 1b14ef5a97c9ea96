"""SYNC rules Y001-Y005 (SPEC §9.2.1): the SYNC reconstruction of
`nmtcheck/processes/sync.py` judged. All are exempt from the UNKNOWN rule: they judge
frames, not a node's state. A SYNC frame carries no sender, so a finding's node is the
producer the files name (Y001, Y003, Y005), else none (concise WHO: network).
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from nmtcheck.checks.base import Param, Params, Problem, flagged_runs, input_rule, windows
from nmtcheck.processes import emcy as emcy_stage
from nmtcheck.processes import pdo as pdo_stage
from nmtcheck.processes import sync
from nmtcheck.processes.comm_values import Value
from nmtcheck.processes.sync import SyncChannel
from nmtcheck.protocol.nmt import OPERATIONAL, PRE_OPERATIONAL, STATE_INDEX
from nmtcheck.timeline.model import ChannelModel, InputModel, NodeModel
from nmtcheck.timeline.moments import at

EPS = 1e-9
_CONSUMING = np.asarray([STATE_INDEX[PRE_OPERATIONAL], STATE_INDEX[OPERATIONAL]])


def _channels(model: InputModel) -> Iterator[tuple[ChannelModel, SyncChannel]]:
    analysis = sync.of(model)
    if analysis is None:
        return
    for cm in model.channels:
        sc = analysis.channels.get(cm.name)
        if sc is not None and len(sc):
            yield cm, sc


def _node(sc: SyncChannel) -> int | None:
    return int(sc.producer.value) if sc.producer.known and sc.producer.value else None


def _at(model: InputModel, cm: ChannelModel, t: float) -> str:
    """A moment as the reports give it: seconds from the channel's first frame, or the
    frame without timestamps."""
    return at(t, cm.start, model.timeline.order_only)


def _median(values: np.ndarray) -> float:
    """The median; of an even count the mean of the two middle values (§9.2.1)."""
    return float(np.median(values))


def _source(v: Value) -> str:
    if v.source == "sdo":
        return f"written by SDO at line {v.line}" if v.line else "written by SDO"
    if v.source == "device-file" and v.node is not None:
        return f"node {v.node}'s device file"
    return str(v.source)


@input_rule("Y001", "sync-timeout", "error",
            Param("timeout_factor", float, "the limit as a multiple of the SYNC period "
                  "(CANopenNode: 1006h + 1006h/2)", 1.5),
            Param("min_intervals", int, "SYNC intervals a segment needs before its median "
                  "stands for an unknown period", 5),
            exempt_from_unknown=True, scope="network+node")
def sync_timeout(model: InputModel, params: Params) -> Iterator[Problem]:
    """No SYNC for longer than 1.5 times the communication cycle period.

    **What it checks.** Inside a SYNC segment (from a SYNC frame to the producer's reset,
    boot-up or a write of its 1005h/1006h), after a SYNC frame at t_s no SYNC frame lies
    in (t_s, t_s + T], T = `timeout_factor` x P; P is `[sync] period_us`, else the
    producer's 1006h, else the smallest non-zero 1006h of the other nodes, else the median
    SYNC interval of the segment (at least `min_intervals` intervals; basis `measured`).
    It fires only when, with nodes other than the producer on the channel, at least one
    of them is PRE-OPERATIONAL or OPERATIONAL at t_s + T (a consumer checks SYNC only
    then), and the trace goes on to t_s + T. Never before the first SYNC of a segment,
    across a segment end, with P = 0, or without timestamps.

    **Why it matters.** CANopenNode consumers raise EMCY 8100h (byte 3 = 18h) and, with
    the communication bit in their error-register mask, leave OPERATIONAL: synchronous
    PDOs stop across the network. A stop of the SYNC producer is a common cause.

    **Example.** `[sync] period_us = 10000`: `080#` at 10.000, 10.010, 10.020, 10.050:
    no SYNC in (10.020, 10.035].
    """
    analysis = sync.of(model)
    factor = float(params["timeout_factor"])
    for cm, sc in _channels(model):
        others = [m for n, m in cm.nodes.items() if n != _node(sc)]
        expected = [n for n, ch in model.expected if ch in (None, cm.network_name)
                    and n != _node(sc) and n not in cm.nodes]
        for pos, values in zip(sc.segments(), sc.by_segment, strict=True):
            if values.period.known:
                if not values.period.value:
                    continue  # 1006h = 0: SYNC not used
                period, basis = float(values.period.value) / 1e6, "configured"
                how = f"1006h {period * 1000:.3f} ms ({_source(values.period)})"
            elif len(pos) > int(params["min_intervals"]):
                period, basis = _median(np.diff(sc.ts[pos])), "measured"
                how = (f"median SYNC interval {period * 1000:.3f} ms [limit measured from "
                       "the trace]")
            else:
                continue
            limit = factor * period
            for a, b in windows(len(pos)):  # bounded however many SYNCs there are
                ts = sc.ts[pos[a:b]]
                nxt = np.append(ts[1:], sc.ts[pos[b]] if b < len(pos) else np.inf)
                end = sc.end_of(pos[a:b])
                due = np.round(ts + limit, 9)  # 10.05 + 0.05 is not above 10.1
                fire = (nxt > due + EPS) & (end > due + EPS) & (cm.end >= due - EPS)
                if others or expected:
                    fire &= _consumers_awake(others, due)
                for k in np.flatnonzero(fire).tolist():
                    at = int(pos[a + k])
                    gap = (f"{(nxt[k] - ts[k]) * 1000:.3f}" if np.isfinite(nxt[k])
                           else f"at least {(cm.end - ts[k]) * 1000:.3f}")
                    if analysis is not None:
                        analysis.gaps[(cm.name, round(float(due[k]), 9))] = sync.SyncGap(
                            basis, float(ts[k]), int(sc.idx[at]), float(nxt[k]), period)
                    yield Problem(cm.name, _node(sc), float(due[k]),
                                  f"no SYNC for {gap} ms after "
                                  f"{_at(model, cm, float(ts[k]))} (line {int(sc.line[at])});"
                                  f" timeout {limit * 1000:.3f} ms = {factor:g} x {how}",
                                  after=int(sc.idx[at]))


def _consumers_awake(nodes: list[NodeModel], t: np.ndarray) -> np.ndarray:
    """Per moment, whether one of the nodes is PRE-OPERATIONAL or OPERATIONAL then."""
    awake = np.zeros(len(t), bool)
    for m in nodes:
        if len(m.intervals):
            awake |= np.isin(m.intervals.state[m.interval_indices(t)], _CONSUMING)
    return awake


def _overflow(sc: SyncChannel) -> np.ndarray:
    """Per SYNC frame, C (1019h) in force at it; -1: unknown."""
    if sc.overflow_at is not None:  # int16 (C <= 240): a SYNC's arrays here are its cost
        values = np.asarray([int(v.value or 0) if v.known else -1 for v in sc.overflows],
                            np.int16)
        found: np.ndarray = values[sc.overflow_at] if len(values) else np.full(
            len(sc), -1, np.int16)
        return found
    out = np.full(len(sc), -1, np.int16)
    for pos, seg in zip(sc.segments(), sc.by_segment, strict=True):
        if seg.overflow.known:
            out[pos] = int(seg.overflow.value or 0)
    return out


def _defects(sc: SyncChannel) -> np.ndarray:
    """Per SYNC frame: 0 fine, 1 remote, 2 a DLC 1019h forbids, 3 a DLC other than the
    segment's first frame's (1019h unknown), 4 a counter outside 1..C (or 1..240)."""
    c = _overflow(sc)
    out = np.zeros(len(sc), np.int8)
    dlc, counter = sc.dlc.astype(np.int16), sc.counter.astype(np.int16)
    known = c >= 0
    out[known & (dlc != (c != 0))] = 2
    first = np.zeros(len(sc), np.int16)
    for pos in sc.segments():
        data = pos[~sc.rtr[pos]]
        first[pos] = dlc[data[0]] if len(data) else -1
    out[~known & ((dlc > 1) | ((dlc != first) & (first >= 0)))] = 3
    top = np.where(c > 0, c, np.int16(240))
    bad_counter = (out == 0) & (dlc == 1) & ((counter == 0) | (counter > top))
    out[bad_counter] = 4
    out[sc.rtr] = 1
    return out


@input_rule("Y002", "sync-frame-invalid", "error", exempt_from_unknown=True, scope="network")
def sync_frame_invalid(model: InputModel, params: Params) -> Iterator[Problem]:
    """A SYNC frame whose length or counter does not fit the counter overflow (1019h).

    **What it checks.** A SYNC frame that is (a) a remote frame; (b) of a DLC 1019h
    forbids (C = 0 needs DLC 0, C = 2-240 needs DLC 1; with C unknown: DLC > 1, or a DLC
    other than the segment's first SYNC's); (c) DLC 1 with a counter of 0, above 240, or
    above C. One finding per run of consecutive SYNC frames with the same defect.

    **Why it matters.** CANopenNode consumers drop such a SYNC and raise EMCY 8240h; Lely
    consumers raise 8240h and still process it: synchronous PDOs go out of step.

    **Example.** `[sync] counter_overflow = 0`: `080#05` (one data byte).
    """
    for cm, sc in _channels(model):
        bad = _defects(sc)
        overflow = _overflow(sc)
        same = np.zeros(len(bad), bool)  # continues the run of the frame before it
        same[1:] = ((bad[1:] == bad[:-1]) & (sc.segment[1:] == sc.segment[:-1])
                    & (overflow[1:] == overflow[:-1]))
        runs = flagged_runs(same, bad != 0)
        for k, n in runs:
            d, dlc = int(bad[k]), int(sc.dlc[k])
            c = int(overflow[k]) if overflow[k] >= 0 else None
            source = (sc.overflows[int(sc.overflow_at[k])] if sc.overflow_at is not None
                      else sc.by_segment[int(np.searchsorted(np.unique(sc.segment),
                                                             sc.segment[k]))].overflow)
            if d == 1:
                text = f"remote frame on the SYNC COB-ID {sc.cob_id:03X}h"
            elif d == 2:
                text = (f"SYNC with {dlc} data byte(s); 1019h = {c} "
                        f"({_source(source)}) "
                        f"requires {0 if c == 0 else 1}: CANopenNode consumers drop it, "
                        "CANopenNode and Lely consumers raise EMCY 8240h")
            elif d == 3:
                seg = np.flatnonzero((sc.segment == sc.segment[k]) & ~sc.rtr)
                f0 = int(seg[0])
                text = (f"SYNC DLC {dlc} after DLC {int(sc.dlc[f0])} at "
                        f"{_at(model, cm, float(sc.ts[f0]))} (line {int(sc.line[f0])}) in the "
                        "same segment")
            else:
                text = f"SYNC counter {int(sc.counter[k])} outside 1..{c or 240}"
            if n > 1:
                text += f" ({n} frames)"
            yield Problem(cm.name, None, float(sc.ts[k]), text, int(sc.idx[k]),
                          int(sc.line[k]))


@input_rule("Y003", "sync-counter-sequence", "warning", exempt_from_unknown=True,
            scope="network+node")
def sync_counter_sequence(model: InputModel, params: Params) -> Iterator[Problem]:
    """The SYNC counter repeats, skips or goes back.

    **What it checks.** SYNC frames with a counter (DLC 1) that Y002 passes, within one
    segment: after counter v the next is v + 1, or 1 after C (1019h) or after 240. A
    counter of 1 is always a legal restart (the stacks restart their SYNC service
    invisibly). One finding per segment, at its first break, counting the breaks and the
    missing SYNCs of the segment.

    **Why it matters.** A gap in the counter is a SYNC the consumers never saw (a lossy
    bus, a busy producer, or the logger: I004 and the `frames_lost` cause tell which);
    a repeated counter is a SYNC sent twice.

    **Example.** `080#01`, `080#02`, `080#03`, `080#05`: one SYNC missing.
    """
    for cm, sc in _channels(model):
        bad = _defects(sc)
        for pos, values in zip(sc.segments(), sc.by_segment, strict=True):
            c = values.overflow.value if values.overflow.known else None
            valid = pos[(bad[pos] == 0) & (sc.dlc[pos] == 1)]
            if len(valid) < 2:
                continue
            v = sc.counter[valid].astype(np.int64)
            prev, cur = v[:-1], v[1:]
            top = int(c) if c else 240
            expected = np.where(prev >= top, 1, prev + 1)
            brk = np.flatnonzero((cur != expected) & (cur != 1))
            if not len(brk):
                continue
            repeated = cur[brk] == prev[brk]
            if c:
                missing = np.where(repeated, 0, (cur[brk] - expected[brk]) % int(c))
            else:
                missing = np.where(cur[brk] > expected[brk], cur[brk] - expected[brk], 0)
            j = int(brk[0])
            k = int(valid[j + 1])
            a, e = int(cur[j]), int(expected[j])
            if a == int(prev[j]):
                what = "repeated"
            elif c or a > e:
                what = f"{int(missing[0])} SYNC(s) missing"
            else:
                what = "went back"
            yield Problem(cm.name, _node(sc), float(sc.ts[k]),
                          f"SYNC counter {a} after {int(prev[j])} (expected {e}): {what}; "
                          f"{len(brk)} break(s), {int(missing.sum())} SYNC(s) missing in "
                          "this segment", int(sc.idx[k]), int(sc.line[k]))


@input_rule("Y005", "sync-period-mismatch", "warning",
            Param("tolerance", float, "allowed relative deviation of the median SYNC "
                  "interval from the producer's 1006h", 0.10),
            Param("min_intervals", int, "SYNC intervals needed before the median is "
                  "compared", 5),
            exempt_from_unknown=True, scope="network+node")
def sync_period_mismatch(model: InputModel, params: Params) -> Iterator[Problem]:
    """The median SYNC interval differs from the producer's communication cycle period.

    **What it checks.** Over at least `min_intervals` SYNC intervals inside one segment,
    the median interval differs from P_prod (`[sync] period_us` or the producer's 1006h,
    never a consumer's or a measured one) by more than `tolerance` x P_prod. One finding
    per segment, at the last SYNC counted. The jitter is reported, never judged.

    **Why it matters.** Consumers time out at 1.5 x their own 1006h; a producer running
    slower than the configuration says is one lost frame away from Y001 on every node.

    **Example.** `[sync] period_us = 10000`, six SYNCs 12 ms apart: +20 %.
    """
    tolerance = float(params["tolerance"])
    for cm, sc in _channels(model):
        for pos, values in zip(sc.segments(), sc.by_segment, strict=True):
            pp = values.producer_period
            if not pp.known or not pp.value:
                continue
            period = float(pp.value) / 1e6
            iv = np.diff(sc.ts[pos])
            if len(iv) < int(params["min_intervals"]):
                continue
            med = _median(iv)
            dev = (med - period) / period
            if abs(dev) <= tolerance + EPS:
                continue
            k = int(pos[-1])
            yield Problem(cm.name, _node(sc), float(sc.ts[k]),
                          f"median SYNC interval {med * 1000:.3f} ms over {len(iv)} intervals;"
                          f" the producer's 1006h = {period * 1000:.3f} ms ({_source(pp)}): "
                          f"{dev * 100:+.1f} % (tolerance {tolerance * 100:g} %)",
                          int(sc.idx[k]), int(sc.line[k]))


@input_rule("Y004", "sync-pdo-outside-window", "warning", exempt_from_unknown=True,
            scope="network+node")
def sync_pdo_outside_window(model: InputModel, params: Params) -> Iterator[Problem]:
    """A synchronous PDO comes after the synchronous window.

    **What it checks.** A frame of a synchronous PDO stream (transmission type 0-240: the
    producer's TPDO type, else a consumer's RPDO type, from the network file's
    `[nodes.N.tpdo.K]`/`[nodes.N.rpdo.K]` or the device files) comes more than W (1007h:
    `[sync] window_us`, else the producer's or a consumer's 1007h) plus the timestamp
    resolution after the latest SYNC before it, while the stream's producer, when known,
    is OPERATIONAL. One finding per run of late frames within one OPERATIONAL interval.
    Never before the first SYNC, for streams of unknown or other types, without
    timestamps.

    **Why it matters.** CANopenNode drops pending synchronous TPDOs when the window
    passes and signals a late one with EMCY 8100h (byte 3 = 15h); Lely does not send a
    TPDO sampled after the window, and its consumers drop a synchronous RPDO received
    after it: the consumers lose that cycle's data. A frame queued inside the window can
    still leave late under arbitration, hence a warning.

    **Example.** `window_us = 2000`, TPDO 183h of type 1: `183#0200` 3 ms after `080#`.
    """
    analysis = sync.of(model)
    if analysis is None:
        return
    emcy_analysis = emcy_stage.of(model)
    r = emcy_analysis.resolution_s if emcy_analysis is not None else 1e-6
    by_name = {cm.network_name: cm for cm in model.channels}
    pdos = pdo_stage.of(model)
    for st in pdos.streams if pdos is not None else ():
        cm = by_name.get(st.channel)
        sc = analysis.channels.get(cm.name) if cm is not None else None
        if cm is None or sc is None or not len(sc) or not st.synchronous:
            continue
        if not st.window_known:
            continue
        ts, idx, line = st.frames(model, cm)
        piece, values = st.windows_at(ts)
        w_us = np.asarray([float(v.value) if v.known and v.value else np.nan for v in values])
        window = w_us[piece] / 1e6  # W in force at each frame (NaN: unknown or 0)
        k = np.searchsorted(sc.ts, ts, side="right") - 1
        with np.errstate(invalid="ignore"):
            late = (k >= 0) & (ts - sc.ts[np.maximum(k, 0)] > window + r + EPS)
        producer = cm.nodes.get(st.party) if st.kind == "tpdo" else None
        if producer is not None and len(producer.intervals):
            iv = producer.interval_indices(ts)
            late &= producer.intervals.state[iv] == STATE_INDEX[OPERATIONAL]
        else:
            iv = np.zeros(len(ts), np.int64)
        join = np.zeros(len(ts), bool)
        join[1:] = late[1:] & late[:-1] & (iv[1:] == iv[:-1])
        what = "TPDO" if st.kind == "tpdo" else "RPDO"
        party = f"node {st.party}" if st.kind == "tpdo" else f"consumer node {st.party}"
        for j, n in flagged_runs(join, late):
            s_at = float(sc.ts[int(k[j])])
            yield Problem(cm.name, st.party if st.kind == "tpdo" else None, float(ts[j]),
                          f"{what} {st.cob_id:03X}h ({party}, type "
                          f"{st.transmission_type.value}) {(ts[j] - s_at) * 1000:.3f} ms after "
                          f"SYNC at {_at(model, cm, s_at)} (line {int(sc.line[int(k[j])])}); "
                          f"synchronous window 1007h = {window[j] * 1000:.3f} ms "
                          f"({_source(values[int(piece[j])])})"
                          + (f" ({n} frames)" if n > 1 else ""),
                          int(idx[j]), int(line[j]))
