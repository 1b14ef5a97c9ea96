"""Heartbeat rules (H): the periodic 700h+N / state frame of CiA 301 §7.2.8.3.2.2."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from nmtcheck.checks.base import Found, NodeContext, Param, Params, count_note, rule, run_starts
from nmtcheck.protocol.nmt import (
    BOOTUP,
    EPS,
    HEARTBEAT,
    OPERATIONAL,
    PRE_OPERATIONAL,
    STATE_INDEX,
    between,
    state_name,
)
from nmtcheck.timeline.model import NodeModel, SmallEc, Timeout


@rule("H001", "heartbeat-timeout", "error",
      Param("timeout_factor", float,
            "timeout = factor x producer period when no consumer time is configured", 1.5))
def heartbeat_timeout(m: NodeModel, ctx: NodeContext, p: Params) -> Iterator[Found]:
    """A heartbeat producer fell silent for longer than its consumers wait.

    **What it checks.** N produces heartbeats (two or more seen, or a producer time
    configured) and a gap after one of its heartbeats exceeds the timeout in force
    at the gap's start: the consumer time if configured (the smallest non-zero one
    for N), else `timeout_factor` x N's heartbeat period (the producer time in
    force, else the median of N's heartbeat intervals). A boot-up starts no gap:
    a slave's power-on producer time is often 0 until the master writes 1017h, and
    consumers only start monitoring at the first heartbeat. After a boot-up the
    next gap starts at N's first heartbeat or at a confirmed non-zero 1017h write.
    A gap ends at N's next heartbeat or boot-up; a reset command to N or a
    confirmed 1017h = 0 ends it without a finding (a timeout that expired before
    still counts). The trace continuing past the timeout after N's last heartbeat
    counts too. One finding per gap, at the moment the timeout expired; the node
    is OFFLINE from then until its next frame. A timeout made of a configured
    producer time x `timeout_factor`, with no consumer time known, is assumed
    (`basis` assumed: the log does not show what a consumer waits): where every
    interval of a run of N's heartbeats exceeds the same assumed timeout, the run
    is one finding with its count. Time inside a recording gap (I007) does not
    count: the timeout counts again from the gap's end.

    **Why it matters.** This is the heartbeat event of CiA 301: every consumer of
    N raises EMCY 8130h and applies its error behaviour (1029h), CiA 302 masters
    reset the node or stop the whole network.

    **Example.** `703#05` every 100 ms, then nothing for 0.4 s: with the median
    period 0.1 s and factor 1.5 the timeout expires 0.15 s after the last one.
    """
    timeouts = [t for t in m.timeouts if t.rule == "H001"]
    i = 0
    while i < len(timeouts):
        t = timeouts[i]
        cfg = m.config_at(t.after_ts)
        if cfg.consumer_timeout_ms:
            whose = f" of node {cfg.consumer_node}" if cfg.consumer_node is not None else ""
            limit = f"consumer time {t.limit_s:.3f} s{whose}"
        elif cfg.heartbeat_ms is not None and cfg.heartbeat_ms > 0:  # SPEC §7 `assumed`
            limit = (f"timeout {t.limit_s:.3f} s assumed: {p['timeout_factor']:g} x producer "
                     f"time {cfg.heartbeat_ms / 1000.0:.3f} s, no consumer time known")
            run = _assumed_run(m, timeouts, i)
            if run > 1:  # every gap of the node exceeds the same assumed limit: one finding
                last = timeouts[i + run - 1]
                gaps = [x.gap_s for x in timeouts[i:i + run] if x.gap_s is not None]
                yield (t.moment, f"node {m.node}'s heartbeat interval exceeds the assumed "
                       f"timeout {run} times in a row ({_range(gaps)}, every interval from "
                       f"{t.after_ts - ctx.start:.3f} s to {_until(last, ctx)}) ({limit})", t)
                i += run
                continue
        else:
            limit = f"timeout {t.limit_s:.3f} s"
        if t.gap_s is None:
            what = f"no heartbeat from node {m.node} for the rest of the trace"
        else:
            what = f"no heartbeat from node {m.node} for {t.gap_s:.3f} s"
        yield t.moment, f"{what} ({limit})", t
        i += 1


def _assumed_run(m: NodeModel, timeouts: list[Timeout], i: int) -> int:
    """How many timeouts from `timeouts[i]` on are gaps that follow each other (each
    starts at the heartbeat that ended the one before) under the same assumed limit (a
    producer time x the factor, no consumer time): the node's every interval there
    exceeds it, a limit the log cannot confirm (SPEC §7 `assumed`), said once with a
    count as N002 counts repeats."""
    j = i + 1
    while j < len(timeouts):
        a, b = timeouts[j - 1], timeouts[j]
        if (a.gap_s is None or abs(b.after_ts - (a.after_ts + a.gap_s)) > EPS
                or abs(b.limit_s - a.limit_s) > EPS):
            break
        cfg = m.config_at(b.after_ts)
        if cfg.consumer_timeout_ms or not (cfg.heartbeat_ms or 0) > 0:
            break
        j += 1
    return j - i


def _range(gaps: list[float]) -> str:
    lo, hi = min(gaps, default=0.0), max(gaps, default=0.0)
    return f"{lo:.3f} s" if abs(hi - lo) < 0.0005 else f"{lo:.3f} to {hi:.3f} s"


def _until(t: Timeout, ctx: NodeContext) -> str:
    return ("the end of the trace" if t.gap_s is None
            else f"{t.after_ts + t.gap_s - ctx.start:.3f} s")


@rule("H002", "heartbeat-too-early", "warning",
      Param("early_factor", float, "heartbeats closer than factor x period are too early", 0.5))
def heartbeat_too_early(m: NodeModel, ctx: NodeContext, p: Params) -> Iterator[Found]:
    """Two heartbeats of a node come much closer together than its period.

    **What it checks.** Two consecutive heartbeats of N are closer than
    `early_factor` x N's heartbeat period at the first of them (the producer time
    in force when one is known, else the median interval), except the first
    heartbeat after a boot-up, after an NMT command to N, after an SDO write of
    1017h to N (the new period starts a new phase), or one that reports a
    different state (stacks may send one at once on a state change). A heartbeat
    stamped more than a period before the previous one did not come early: the
    log's time went back (I005 counts it; past the cap of captures a logger that
    resets its clock every second would otherwise give a finding per reset).

    **Why it matters.** A producer that sends too often wastes bus bandwidth and
    usually means a misconfigured 1017h, two devices sharing the node-ID, or a
    stack that re-triggers its timer.

    **Example.** Period 100 ms, heartbeats at 0.000, 0.020, 0.100 s.
    """
    if m.kind_counts()[HEARTBEAT] < 2:  # no pair (most nodes of a log of many channels)
        return
    factor = p["early_factor"]
    if m.small is not None and not _small_early(m, m.small, factor):
        return
    ec = m.ec
    pos = ec.where(HEARTBEAT, BOOTUP)
    a, b = pos[:-1], pos[1:]
    # the period in force at the first heartbeat: a confirmed 1017h beats the median
    period = m.periods_at(ec.ts[a])
    limit = factor * period
    with np.errstate(invalid="ignore"):
        early = ((ec.kind[a] == HEARTBEAT) & (ec.kind[b] == HEARTBEAT)
                 & (ec.code[a] == ec.code[b]) & (period > 0)
                 & (ec.ts[b] - ec.ts[a] < limit - EPS)
                 & (ec.ts[b] - ec.ts[a] >= -period - EPS))  # further back: I005's
    early &= ~between(m.commands.idx, ec.idx[a], ec.idx[b])
    # a new producer time starts a new phase: the first heartbeat after a 1017h write is
    # not early either
    writes = np.sort(m.writes.request_idx[m.writes.index == 0x1017])
    early &= ~between(writes, ec.idx[a], ec.idx[b])
    ea, eb, el, ep = a[early], b[early], limit[early], period[early]
    # a run: each early pair starts where the previous one ended, in one interval
    iv = m.interval_indices(ec.ts[eb])
    join = np.ones(len(ea), bool)
    join[1:] = (ea[1:] == eb[:-1]) & (iv[1:] == iv[:-1])
    for s, n in zip(*run_starts(join), strict=True):
        prev_f, f = ec[ea[s]], ec[eb[s]]
        yield (f.ts, f"heartbeat ({state_name(f.code)}) {f.ts - prev_f.ts:.3f} s after the "
               f"previous one (period {ep[s]:.3f} s, limit {el[s]:.3f} s)"
               f"{count_note(int(n), 'heartbeats')}", f)


def _small_early(m: NodeModel, s: SmallEc, factor: float) -> bool:
    """Whether a small node (`timeline._small`: no command, no write) has a pair H002
    finds early, as its numpy path decides it (the findings are that path's)."""
    hb = m.config.heartbeat_ms
    ts, kind, value = s.ts, s.kind, s.value
    for i in range(len(ts) - 1):
        if kind[i] != HEARTBEAT or kind[i + 1] != HEARTBEAT or (
                value[i] & 0x7F) != (value[i + 1] & 0x7F):
            continue
        period = hb / 1000.0 if hb is not None and hb > 0 else m.measured_period_at(ts[i])
        if period > 0 and -period - EPS <= ts[i + 1] - ts[i] < factor * period - EPS:
            return True
    return False


@rule("H003", "heartbeat-period-mismatch", "warning",
      Param("tolerance", float, "allowed relative difference of the median interval", 0.1))
def heartbeat_period_mismatch(m: NodeModel, ctx: NodeContext, p: Params) -> Iterator[Found]:
    """A node's heartbeat period differs from its configured producer time.

    **What it checks.** N's producer time (1017h) is known (network file, EDS/DCF,
    or an SDO write of 1017h confirmed in the trace) and, over at least 5
    heartbeat intervals while that value holds, the median interval differs from
    it by more than `tolerance` (a fraction), or a run of at least 5 consecutive
    intervals is off by more than `tolerance` the same way (a node whose
    application changed its own 1017h later). Intervals containing a boot-up or a
    reset are left out. One finding per configured value, at the last heartbeat
    counted.

    **Why it matters.** Consumers are configured from the producer time: a node
    that ignores its 1017h (or whose DCF is stale) either floods the bus or trips
    its consumers' heartbeat timeouts under load.

    **Example.** 1017h = 100 ms written by the master at boot, heartbeats every
    500 ms afterwards.
    """
    tolerance = p["tolerance"]
    if m.small is not None and not (m.config.heartbeat_ms or 0) > 0:
        return  # a small node (no write) with no producer time from files
    a, b = m.heartbeat_pairs()
    if not a.size:
        return
    ts = m.ec.ts
    value = m.config_series(ts[a], lambda cfg: cfg.heartbeat_ms)
    runs = m.ec.runs
    in_run = runs.at_rows(b) >= 0 if runs is not None else None
    for v in dict.fromkeys(value[(value > 0)].tolist()):  # in order of appearance
        sel = np.flatnonzero(value == v)
        counted = m.heartbeat_gaps(sel)  # a long log's dropped runs count as their intervals
        if counted.count < 5:
            continue
        configured = v / 1000.0
        gaps = ts[b[sel]] - ts[a[sel]]
        if in_run is not None:  # a dropped run lies within the tolerance: it breaks off-runs
            gaps = np.where(in_run[sel], configured, gaps)
        median = counted.median()
        what = f"median of {counted.count} intervals"
        last = sel[-1]
        if abs(median - configured) <= tolerance * configured + EPS:
            # the producer may change its own period later (an application writing its
            # 1017h locally): a run of >= 5 consecutive intervals all off the same way
            # counts too
            run = _longest_off_run(gaps, configured, tolerance)
            if run is None:
                continue
            lo, hi = run
            median = float(np.median(gaps[lo:hi]))
            what = (f"median of {hi - lo} consecutive intervals from "
                    f"{ts[a[sel[lo]]] - ctx.start:.3f} s")
            last = sel[hi - 1]
        f = m.ec[b[last]]
        yield (f.ts, f"node {m.node} heartbeats every {median:.3f} s ({what}) but its producer "
               f"time is {configured:.3f} s (tolerance {tolerance:.0%})", f)


def _longest_off_run(gaps: np.ndarray, configured: float, tolerance: float
                     ) -> tuple[int, int] | None:
    """The longest run of at least 5 consecutive intervals that are all longer (or all
    shorter) than the configured period by more than the tolerance, as [lo, hi)."""
    best: tuple[int, int] | None = None
    for off in (gaps > configured * (1 + tolerance) + EPS,
                gaps < configured * (1 - tolerance) - EPS):
        edges = np.flatnonzero(np.diff(np.concatenate([[0], off.astype(np.int8), [0]])))
        for lo, hi in zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True):
            if hi - lo >= 5 and (best is None or hi - lo > best[1] - best[0]):
                best = (lo, hi)
    return best


@rule("H004", "consumer-without-producer", "warning")
def consumer_without_producer(m: NodeModel, ctx: NodeContext, p: Params) -> Iterator[Found]:
    """A node is configured to watch a heartbeat that never comes.

    **What it checks.** A heartbeat consumer time for producer P is in force on node
    C (C's 1016h entry naming P, from C's device file or written to C by SDO in the
    trace; the network file's `consumer_timeout_ms` names no consumer and does not
    count), and P sends no heartbeat at all while that entry is in force (from the
    moment it took effect or C's boot-up, the later, until a new write of that
    entry, C's reset or boot-up, or the end of the trace), although C is
    PRE-OPERATIONAL or OPERATIONAL for longer than the consumer time in that span.
    One finding per (C, P, entry), at the moment the consumer time expired. A
    producer that starts late is not this rule's business.

    **Why it matters.** CiA 301 consumers start monitoring at the first heartbeat
    they receive, so a compliant C raises no event, but the supervision its
    configuration asks for never runs: P is absent, misnumbered, or producing with
    1017h = 0. Some stacks do time out: in a field log a slave configured to watch a
    master that never produced a heartbeat raised the timeout.

    **Example.** Node 5 is written `1016h:01 = 000107D0h` (watch node 1 at 2000 ms) and
    stays PRE-OPERATIONAL for 10 s; node 1 never sends a heartbeat.
    """
    for start, end, producer, time_ms, how in _consumer_entries(m, ctx):
        pm = ctx.channel.nodes.get(producer)
        if pm is not None:
            hb = pm.ec.ts[pm.ec.kind == HEARTBEAT]
            if bool(((hb >= start - EPS) & (hb < end)).any()):
                continue
            runs = pm.ec.runs  # a long log's dropped heartbeats lie inside their runs
            if runs is not None and bool(((pm.ec.ts[runs.pos - 1] < end)
                                          & (pm.ec.ts[runs.pos] > start)).any()):
                continue
        moment = _watched_for(m, start, end, time_ms / 1000.0)
        if moment is not None:
            yield (moment, f"node {m.node} waits for heartbeats of node {producer} (consumer "
                   f"time {time_ms / 1000.0:.3f} s, {how}) but node {producer} sends none")


def _consumer_entries(m: NodeModel, ctx: NodeContext
                      ) -> Iterator[tuple[float, float, int, float, str]]:
    """C's 1016h entries, each with the span it is in force: (from, until, producer,
    consumer time in ms, where it comes from). A device file's entries hold from the
    start and again after each boot-up or reset, unless SDO writes 1016h to C in the
    trace: then the file holds what the master writes, not the power-on value (SPEC §6)."""
    w = m.writes
    entry = np.flatnonzero(w.index == 0x1016)
    if not entry.size and not m.config.consumes:
        return  # no consumer entry at all (most nodes): no walk over the resets
    ends = np.unique(np.concatenate([m.ec.ts[m.ec.kind == BOOTUP], m.commands.reset_ts]))
    starts = [ctx.start, *ends.tolist()]
    for k, seg_start in enumerate(starts):
        seg_end = ends[k] if k < len(ends) else ctx.end
        in_seg = entry[(w.ts[entry] >= seg_start) & (w.ts[entry] < seg_end)]
        begin = _after_boot(m, seg_start)
        for producer, time_ms in m.config.consumes.items():
            if time_ms and producer != m.node and begin < seg_end and not entry.size:
                yield begin, seg_end, producer, time_ms, "from its device file"
        for j, pos in enumerate(in_seg.tolist()):
            value = int(w.value[pos])
            producer, time_ms = (value >> 16) & 0xFF, float(value & 0xFFFF)
            if not time_ms or not 1 <= producer <= 127 or producer == m.node:
                continue
            later = in_seg[j + 1:]
            same = later[w.sub[later] == w.sub[pos]]
            until = float(w.ts[same[0]]) if same.size else seg_end
            yield max(float(w.ts[pos]), begin), until, producer, time_ms, "written by SDO"


def _after_boot(m: NodeModel, at: float) -> float:
    """`at`, or C's first boot-up at or after it if its state is unknown until then."""
    boots = m.ec.ts[m.ec.kind == BOOTUP]
    later = boots[boots >= at - EPS]
    if m.state_at(at) == "UNKNOWN" and later.size:
        return float(later[0])
    return at


_WATCHING = (STATE_INDEX[PRE_OPERATIONAL], STATE_INDEX[OPERATIONAL])


def _watched_for(m: NodeModel, start: float, end: float, limit: float) -> float | None:
    """The moment C has been PRE-OPERATIONAL or OPERATIONAL for `limit` without a break
    within [start, end), or None."""
    iv = m.intervals
    run_from: float | None = None
    for a, b, st in zip(iv.start.tolist(), iv.end.tolist(), iv.state.tolist(), strict=True):
        a, b = max(a, start), min(b, end)
        if b <= a:
            if a >= end:
                break
            continue
        if st in _WATCHING:
            run_from = a if run_from is None else run_from
            if b - run_from > limit + EPS:
                return run_from + limit
        else:
            run_from = None
    return None
