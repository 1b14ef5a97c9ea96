"""Each node's error-control frames judged as the timeline needs them: classified
(boot-up, heartbeat, guarding response, request), the heartbeat period found (configured,
else the median interval), heartbeat and guarding timeouts computed, OFFLINE ended by the
node's next frame of any kind, and self-starting nodes recognised. Vectorised per node;
small nodes take list paths."""

from __future__ import annotations

import bisect

import numpy as np

from nmtcheck.protocol.nmt import (
    BOOTUP,
    EPS,
    GUARD,
    HEARTBEAT,
    MALFORMED,
    OPERATIONAL,
    REQUEST,
    STATE_INDEX,
    STATE_OF_CODE,
    between,
    is_one_of,
)
from nmtcheck.readers.frames import node_key
from nmtcheck.timeline.decode import KIND_TPDO, Decoded
from nmtcheck.timeline.model import (
    EcTable,
    NodeModel,
    SmallEc,
    TimelineParams,
    Timeout,
)
from nmtcheck.timeline.tables import next_of

CODE_STATE = np.full(128, -1, np.int8)  # state index a code (data byte & 7Fh) reports
for _code, _state in STATE_OF_CODE.items():
    CODE_STATE[_code] = STATE_INDEX[_state]
CODE_STATE_LIST: list[int] = CODE_STATE.tolist()
_OPERATIONAL = STATE_INDEX[OPERATIONAL]


def ec_columns(ec: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The decoded error-control columns in `EcTable`'s dtypes, with every frame's kind
    as far as it is known without the node's history (request, malformed, boot-up,
    heartbeat: final unless the node has requests, see `classify`) and a stale mark,
    made once for all nodes: each node's table is a view of its rows."""
    rtr, dlc, value = (np.asarray(ec["rtr"], bool), np.asarray(ec["dlc"], np.int16),
                       np.asarray(ec["value"], np.uint8))
    return {"ts": np.asarray(ec["ts"], np.float64), "idx": np.asarray(ec["idx"], np.int64),
            "line": np.asarray(ec["line"], np.int64), "rtr": rtr, "dlc": dlc, "value": value,
            "kind": _plain_kinds(rtr, dlc, value), "stale": np.zeros(len(rtr), bool)}


def _plain_kinds(rtr: np.ndarray, dlc: np.ndarray, value: np.ndarray) -> np.ndarray:
    """Request, malformed (DLC not 1), boot-up (00h) or heartbeat, frame by frame."""
    kind: np.ndarray = np.where(rtr, REQUEST, np.where(
        dlc != 1, MALFORMED, np.where(value == 0, BOOTUP, HEARTBEAT))).astype(np.int8)
    return kind


def node_ec_tables(decoded: Decoded, chan: int, groups: list[tuple[int, slice]],
               cols: dict[str, np.ndarray]) -> dict[int, EcTable]:
    """One column table per node of the channel: views into the columns of
    `ec_columns`, with the node's dropped heartbeat runs when the log was long enough
    to compact them."""
    kind, stale = cols["kind"], cols["stale"]
    tables = {n: EcTable.view(cols, r, kind, stale) for n, r in groups}
    if decoded.ec_runs:
        for n, table in tables.items():
            table.runs = decoded.ec_runs.get(node_key(chan, n))
    if decoded.ec_guard_runs:
        for n, table in tables.items():
            table.guard_runs = decoded.ec_guard_runs.get(node_key(chan, n))
    return tables


def classify(m: NodeModel, params: TimelineParams, with_period: bool, start: float) -> bool:
    """Boot-up, heartbeat or guarding response for each data frame on 700h+N (SPEC §2).

    Without the period (first pass) only boot-ups are final: the period in force needs
    the SDO-written values, which hold until the next boot-up. Returns whether N has
    remote requests: without them the kinds `ec_columns` gave are final, both passes
    alike, and G002 has nothing.
    """
    ec = m.ec
    if not m.kind_counts()[REQUEST]:
        return False
    kind = _plain_kinds(ec.rtr, ec.dlc, ec.value)
    periods = m.periods_at(ec.ts) if with_period else np.full(len(ec), np.nan)
    # a log that starts mid-stream: a request sent before the recording began may be
    # pending at its first frame (order only: no time tells how long before)
    before = -np.inf if params.order_only else start
    _classify_guarding(ec, kind, params, periods, _heartbeat_disabled(m, kind), before)
    ec.kind = kind
    return True


def _heartbeat_disabled(m: NodeModel, kind: np.ndarray) -> np.ndarray:
    """Per error-control frame, whether a confirmed 1017h = 0 write holds (in file order:
    the latest 1017h write before it, with no boot-up or reset command of N between):
    N produces no heartbeat, so an answer to a pending request is a guarding response (a
    master switching N from heartbeat to guarding)."""
    ec, w = m.ec, m.writes
    hb = np.flatnonzero(w.index == 0x1017)
    if not hb.size:
        return np.zeros(len(ec), bool)
    w_idx = w.idx[hb]
    order = np.argsort(w_idx, kind="stable")
    w_idx, w_val = w_idx[order], w.value[hb][order]
    k = np.searchsorted(w_idx, ec.idx, side="left") - 1  # the latest write before
    has = k >= 0
    latest = np.where(has, w_idx[np.maximum(k, 0)], -1)
    ends = np.sort(np.concatenate([ec.idx[kind == BOOTUP], m.commands.reset_idx]))
    ended = between(ends, latest, ec.idx) | is_one_of(ec.idx, ends)
    disabled: np.ndarray = has & (w_val[np.maximum(k, 0)] == 0) & ~ended
    return disabled


def _classify_guarding(ec: EcTable, kind: np.ndarray, params: TimelineParams,
                       periods: np.ndarray, disabled: np.ndarray, start: float) -> None:
    """Where remote requests are pending, a data frame may be a guarding response.

    `periods`: the heartbeat period in force at each frame (NaN: unknown). `start`: the
    trace's first frame, taken for a request sent before the recording began: in a log
    that starts mid-stream, N's first report within the response timeout answers it
    where a request to N comes before N's next report (a guarding answer `704#85` there
    was a heartbeat with bit 7 set, C003, then G004 and H001 "for the rest of the trace").

    A node that only answers guarding (the usual one) is classified with array operations:
    a data frame answers the request right before it (no boot-up or other data frame
    between) within the response timeout. That is the walk's answer wherever the walk's
    other test (a node that also produced two heartbeats since its boot-up: the toggle
    bit and the early limit decide) is not reached, time does not go backwards (a
    request a late heartbeat left pending could then be answered), and no frame with
    toggle 0 follows a request left unanswered (a heartbeat of a node polled while it
    ignores guarding may look like an answer); else the walk decides."""
    timeout = params.response_timeout_s + EPS
    rel = np.flatnonzero((kind == REQUEST) | (kind == BOOTUP) | (kind == HEARTBEAT))
    k = kind[rel]
    ts = ec.ts[rel]
    guard = np.zeros(len(rel), bool)
    if len(rel) > 1:
        guard[1:] = (k[1:] == HEARTBEAT) & (k[:-1] == REQUEST) & (ts[1:] - ts[:-1] <= timeout)
    start = request_before_trace(k, ts, start, timeout)
    if len(rel) and start > -np.inf:  # (no timestamps: the timeout is infinite)
        guard[0] = True
    beat = (k == HEARTBEAT) & ~guard  # counted by the walk's hb_since_boot
    before = np.cumsum(beat) - beat  # heartbeats before each row
    at = np.arange(len(rel))
    last_boot = np.maximum.accumulate(np.where(k == BOOTUP, at, -1))
    since_boot = before - np.where(last_boot >= 0, before[np.maximum(last_boot, 0)], 0)
    after_misses = np.zeros(len(rel), bool)  # MISSED requests unanswered before the pending
    if len(rel) > MISSED + 1:
        run = np.ones(len(rel) - MISSED - 1, bool)
        for j in range(1, MISSED + 2):  # the row j before each
            run &= k[MISSED + 1 - j:len(k) - j] == REQUEST
        after_misses[MISSED + 1:] = run
    values = ec.value[rel]
    toggle0 = guard & (values & 0x80 == 0)
    # the walk's additions can only change something where: an answer with toggle 0
    # follows an unanswered request; N's first report since its boot-up, an answer with
    # toggle 0, is followed by an answer under a 1017h = 0 write; or the trace's first
    # report, taken for an answer, is followed by an answer with its toggle
    data_rows = np.where(k != REQUEST, at, -1)
    prev_data = np.concatenate([[-1], np.maximum.accumulate(data_rows)[:-1]])[:len(rel)]
    first = (prev_data < 0) | (k[np.maximum(prev_data, 0)] == BOOTUP)
    off = guard & disabled[rel]
    off_after = np.flip(np.cumsum(np.flip(off))) > off  # an answer under 1017h = 0 later
    answers = np.flatnonzero(guard)
    start_repeat = (start > -np.inf and len(answers) > 1 and answers[0] == 0
                    and bool((values[answers[1]] ^ values[0]) & 0x80 == 0))
    doubtful = bool((toggle0 & after_misses).any()
                    or (toggle0 & first & ~disabled[rel] & off_after).any() or start_repeat)
    if not bool((guard & (since_boot >= 2) & ~disabled[rel]).any()) and not bool(
            (np.diff(ts) < 0).any()) and not doubtful:
        kind[rel[guard]] = GUARD
        return
    _classify_guarding_walk(ec, kind, params, periods, disabled, start)


def request_before_trace(kind: np.ndarray, ts: np.ndarray, start: float, timeout: float
                         ) -> float:
    """`start` where N's first report (of its requests, boot-ups and reports `kind` at
    `ts`) may answer a request sent before the trace began: it comes within the response
    timeout of the trace's start and a request to N follows it before N's next report;
    else -inf (no such request)."""
    if len(kind) > 1 and kind[0] == HEARTBEAT and kind[1] == REQUEST and (
            -np.inf < start and ts[0] - start <= timeout):
        return start
    return -np.inf


MISSED = 1  # requests a node left unanswered before a frame that may be its heartbeat


def _classify_guarding_walk(ec: EcTable, kind: np.ndarray, params: TimelineParams,
                            periods: np.ndarray, disabled: np.ndarray, start: float) -> None:
    """`_classify_guarding` frame by frame, in order (plain Python ints, no objects): for
    a node that answers guarding and produces heartbeats too.

    Beyond the SPEC's test: of two frames in a row with toggle 0, the second after a
    request N left unanswered (MISSED or more) and the first after one too or N's first
    report since its boot-up, the second is N's heartbeat where, as a response, its
    toggle would repeat the first's, and then so is the first; and such a frame taken for
    the last response was a heartbeat where the first answer after a 1017h = 0 write (the
    master switching N to guarding), or the next answer after the trace's first report
    taken for one, only fits without it. A heartbeat producer that a master polls
    (CANopenNode after a power cycle: 1017h back at its power-on value, which disables its
    guarding slave) sends heartbeats at any phase of the polling, so every one of them
    comes within the response timeout of the latest request, and N never shows the two
    heartbeats the SPEC's test needs: each was a guarding response with toggle 0, then a
    false G001 on it and on the first real response once the master switched N to
    guarding."""
    # ts of the pending request (maybe one before the trace: request_before_trace)
    pending: float | None = start if start > -np.inf else None
    hb_since_boot = 0
    last_hb: float | None = None
    early: float | None = None  # the early limit at the last heartbeat
    timeout = params.response_timeout_s + EPS
    # requests since N's last data frame (before the trace: as if several went unanswered,
    # so that N's first report, taken for an answer, may still turn out a heartbeat)
    requests = MISSED + 1 if pending is not None else 0
    expect: int | None = None  # the next response's toggle (None: either, at the start)
    doubtful: tuple[int, int | None] | None = None  # the last response, if it came after
    # unanswered requests with toggle 0: (its row, the toggle expected before it)
    before_trace = -1  # the row of N's first report, taken for an answer from before it
    first_report = True  # no report of N yet since its boot-up (or the trace's start)
    for i, (k, ts, value, period, off) in enumerate(zip(
            kind.tolist(), ec.ts.tolist(), ec.value.tolist(), periods.tolist(),
            disabled.tolist(), strict=True)):
        if k == REQUEST:
            pending = ts
            requests += 1
        elif k == BOOTUP:
            # Always a boot-up, even with a request pending: a node in Initialisation does
            # not answer guarding, and reading it as a response would raise false G001/B001.
            hb_since_boot = 0
            last_hb = None
            pending = None
            requests = 0
            expect, doubtful = 0, None
            first_report = True
        elif k == HEARTBEAT:
            is_guard = False
            toggle = value >> 7 & 1
            if pending is not None and ts - pending <= timeout:
                repeat = False  # the second of two such frames in a row: heartbeats
                if hb_since_boot >= 2 and not off:
                    is_guard = bool(value & 0x80) or (
                        early is not None and last_hb is not None and ts - last_hb < early)
                else:
                    repeat = (not off and requests > MISSED and toggle == 0 and expect == 1
                              and doubtful is not None)
                    is_guard = not repeat
                if doubtful is not None and (repeat or off or doubtful[0] == before_trace) \
                        and toggle != expect and (doubtful[1] is None or toggle == doubtful[1]):
                    # it was a heartbeat too, or one before the master switched N to
                    # guarding (1017h = 0), or the trace's first: then this answer's fits
                    kind[doubtful[0]] = HEARTBEAT
                    hb_since_boot += 1
                    expect, doubtful = doubtful[1], None
            if is_guard:
                kind[i] = GUARD
                if requests > MISSED and pending == start:
                    before_trace = i
                pending = None
                doubtful = (i, expect) if (requests > MISSED or first_report) and (
                    toggle == 0 and not off) else None
                expect = 1 - toggle
            else:
                hb_since_boot += 1
                last_hb = ts
                early = None if period != period else params.early_factor * period - EPS
            requests = 0
            first_report = False


def find_period(m: NodeModel) -> None:
    """Configured producer time, else the median heartbeat interval (no boot-up/reset inside).

    The median is kept apart too: it is the period where 1017h = 0 is in force.
    """
    if m.small is not None and m.kind_counts()[HEARTBEAT] >= 2:
        m.median_s, m.seg_bounds, m.seg_median = _small_period(m.small)
    elif m.kind_counts()[HEARTBEAT] < 2 and m.ec.runs is None:
        # no interval at all (most nodes of a log of many channels): what the two below
        # find of none, without their set-up
        m.median_s = None
        m.seg_bounds, m.seg_median = _NO_SEGMENTS, _ONE_NAN
    else:
        intervals = m.heartbeat_gaps()
        m.median_s = intervals.median() if intervals.count else None
        m.seg_bounds, m.seg_median = _segment_medians(m)
    if m.config.heartbeat_ms:
        m.period_s, m.period_source = m.config.heartbeat_ms / 1000.0, "configured"
    elif m.median_s is not None:
        m.period_s, m.period_source = m.median_s, "measured"
    else:
        m.period_s, m.period_source = None, "none"


_NO_SEGMENTS, _ONE_NAN = np.zeros(0), np.full(1, np.nan)  # read only: shared by nodes
_NO_SEGMENTS.flags.writeable = _ONE_NAN.flags.writeable = False


SMALL_NODE_FRAMES = 32  # a node of at most this many frames may take the list paths


def small_ec(m: NodeModel, params: TimelineParams) -> SmallEc | None:
    """N's frames as lists when N is a small plain node: a few boot-ups and heartbeats,
    no request, guarding response or malformed frame, no command, no SDO write, no
    dropped run, timestamps. The heartbeat stages (`_small_period`,
    `_small_heartbeat_timeouts`, `_small_self_start`, `_small_steps`) and rules then
    walk a few Python numbers instead of setting up numpy per node; each computes what
    its numpy path does (tests/test_many_channels.py compares them)."""
    ec = m.ec
    if (params.order_only or ec.runs is not None or not 0 < len(ec) <= SMALL_NODE_FRAMES
            or len(m.commands) or len(m.writes) or len(m.consumer_writes)):
        return None
    k = m.kind_counts()
    if k[REQUEST] or k[GUARD] or k[MALFORMED] or not k[HEARTBEAT]:
        return None
    return SmallEc(ec.ts.tolist(), ec.kind.tolist(), ec.value.tolist(), ec.idx.tolist())


def _small_period(s: SmallEc) -> tuple[float | None, np.ndarray, np.ndarray]:
    """`find_period`'s median and `_segment_medians` for a small node: its pairs are
    consecutive heartbeats (no command), its segment bounds its boot-ups' times."""
    ts, kind = s.ts, s.kind
    pairs = [(ts[i], ts[i + 1]) for i in range(len(ts) - 1)
             if kind[i] == HEARTBEAT and kind[i + 1] == HEARTBEAT]
    if not pairs:
        return None, _NO_SEGMENTS, _ONE_NAN
    median = _list_median(sorted(b - a for a, b in pairs))
    bounds = sorted({t for t, k in zip(ts, kind, strict=True) if k == BOOTUP})
    medians = [np.nan] * (len(bounds) + 1)
    per_seg: dict[int, list[float]] = {}
    for a, b in pairs:
        seg = bisect.bisect_right(bounds, a)
        if seg == bisect.bisect_right(bounds, b):  # a pair across a bound belongs to none
            per_seg.setdefault(seg, []).append(b - a)
    for seg, gaps in per_seg.items():
        medians[seg] = _list_median(sorted(gaps))
    return median, np.asarray(bounds, np.float64), np.asarray(medians, np.float64)


def _list_median(gaps: list[float]) -> float:
    """numpy's median of sorted values: the middle one, or the mean of the two."""
    n = len(gaps)
    return (gaps[(n - 1) // 2] + gaps[n // 2]) / 2.0


def _segment_medians(m: NodeModel) -> tuple[np.ndarray, np.ndarray]:
    """The median heartbeat interval of each producer-time segment (SPEC §2): segments
    run between N's boot-ups, reset commands to N and confirmed 1017h writes to N, so
    that heartbeats sent under a power-on producer time never judge those sent under
    the one the master wrote. Returns the segments' bounds and one median per segment
    (NaN: no interval of its own); an interval across a bound belongs to none."""
    ec = m.ec
    a, b = m.heartbeat_pairs()
    if not a.size:  # no interval: every segment's median is NaN, wherever they are bounded
        return np.zeros(0), np.full(1, np.nan)
    bounds = np.unique(np.concatenate([
        ec.ts[ec.kind == BOOTUP], m.commands.reset_ts,
        m.writes.ts[m.writes.index == 0x1017]]).astype(np.float64))
    medians = np.full(len(bounds) + 1, np.nan)
    seg_a = np.searchsorted(bounds, ec.ts[a], side="right")
    seg_b = np.searchsorted(bounds, ec.ts[b], side="right")
    inside = seg_a == seg_b
    seg, gaps = seg_a[inside], (ec.ts[b] - ec.ts[a])[inside]
    if not seg.size:
        return bounds, medians
    if ec.runs is not None:  # a long log: its dropped runs count as their intervals
        for s in np.unique(seg).tolist():
            medians[s] = m.heartbeat_gaps(np.flatnonzero(inside & (seg_a == s))).median()
        return bounds, medians
    order = np.lexsort((gaps, seg))  # by segment, then by length: medians by position
    seg, gaps = seg[order], gaps[order]
    first = np.flatnonzero(np.concatenate([[True], seg[1:] != seg[:-1]]))
    count = np.diff(np.append(first, len(seg)))
    lo = first + (count - 1) // 2
    hi = first + count // 2
    medians[seg[first]] = (gaps[lo] + gaps[hi]) / 2.0
    return bounds, medians


_HB, _BOOT, _RESET, _OFF, _ON = range(5)  # what happens to a heartbeat gap (H001)


def heartbeat_timeouts(m: NodeModel, params: TimelineParams, end: float) -> None:
    """H001: each heartbeat gap that outlasts the timeout in force at its start (SPEC §3).

    A gap starts at a heartbeat, or at a confirmed non-zero 1017h write when none runs
    (a boot-up starts none: a node's power-on producer time is often 0 until the master
    writes 1017h). It ends at the next heartbeat, boot-up, reset command or 1017h = 0;
    a timeout that expired before a reset or a 0 write still counts.
    """
    if not m.is_producer:
        return
    if m.small is not None:
        _small_heartbeat_timeouts(m, m.small, params, end)
        return
    ec = m.ec
    pos = np.flatnonzero((ec.kind == HEARTBEAT) | (ec.kind == BOOTUP))
    resets = m.commands.reset_idx
    writes = m.writes.take(np.flatnonzero(m.writes.index == 0x1017)) if len(
        m.writes) else m.writes
    # the events as columns: heartbeats and boot-ups, reset commands, 1017h writes
    ts = np.concatenate([ec.ts[pos], m.commands.reset_ts, writes.ts])
    idx = np.concatenate([ec.idx[pos], resets, writes.idx])
    what = np.concatenate([np.where(ec.kind[pos] == HEARTBEAT, _HB, _BOOT).astype(np.int8),
                           np.full(len(resets), _RESET, np.int8),
                           np.where(writes.value != 0, _ON, _OFF).astype(np.int8)])
    row = np.concatenate([pos, np.full(len(resets) + len(writes), -1)])  # in ec
    if len(resets) or len(writes):  # else the frames alone, in file order already
        order = np.argsort(idx, kind="stable")
        ts, idx, what, row = ts[order], idx[order], what[order], row[order]
    if not ts.size:
        return
    # A write of a non-zero 1017h starts a gap only when none runs: right after a boot-up,
    # a reset or a 0 write, or first of all. Other such writes change nothing.
    # A heartbeat while 1017h = 0 is in force (disabled by SDO) starts no gap either.
    hb_ms = m.config_series(ts, lambda cfg: cfg.heartbeat_ms)
    silent = (what == _HB) & (hb_ms == 0)
    prev = np.concatenate([[_BOOT], what[:-1]])
    prev_silent = np.concatenate([[False], silent[:-1]])
    opens = ((what == _HB) & ~silent) | ((what == _ON) & (
        is_one_of(prev, (_BOOT, _RESET, _OFF)) | prev_silent))
    ends = np.flatnonzero(what != _ON)  # every event but a non-zero write ends a gap
    gap = np.flatnonzero(opens)
    k = np.searchsorted(ends, gap, side="right")
    closed = k < len(ends)
    until = np.full(len(gap), end, np.float64)
    until[closed] = ts[ends[k[closed]]]
    # A heartbeat sent while a 1017h write is being confirmed already follows the new value
    # (stacks apply it before they answer): its gap is timed by that value.
    # A gap opened by a confirmed write is timed by the value in force after it.
    at = _timed_from(ts[gap], what[gap] == _HB, writes.request_ts, writes.ts)
    limit = m.hb_timeouts_at(at, params.timeout_factor)
    with np.errstate(invalid="ignore"):
        fire = (limit > 0) & (until - ts[gap] > limit + EPS)
    if ec.runs is not None and fire.any() and len(ends):
        # a gap closed by the heartbeat after a dropped run spans the run, whose every
        # interval is within the timeout (`readback.unsafe_nodes` made sure)
        nxt = np.where(closed, ends[np.minimum(k, len(ends) - 1)], -1)
        inner = closed & (what[nxt] == _HB) & (row[nxt] == row[gap] + 1) & (
            ec.runs.at_rows(row[nxt]) >= 0)
        fire &= ~inner
    for g, lim, u, c in zip(gap[fire].tolist(), limit[fire].tolist(), until[fire].tolist(),
                            closed[fire].tolist(), strict=True):
        start = float(ts[g])
        m.timeouts.append(Timeout("H001", start + lim, start, int(idx[g]), lim,
                                  u - start if c else None))


def _small_heartbeat_timeouts(m: NodeModel, s: SmallEc, params: TimelineParams,
                              end: float) -> None:
    """`heartbeat_timeouts` for a small node: no command and no write, so every frame
    ends a gap, each heartbeat opens one (none while 1017h = 0 is configured) and the
    configuration is the files' throughout."""
    cfg = m.config
    hb = np.nan if cfg.heartbeat_ms is None else float(cfg.heartbeat_ms)
    if hb == 0:  # no gap opens, and none would have a limit
        return
    cons = float(cfg.consumer_timeout_ms or np.nan)
    ts, kind = s.ts, s.kind
    last = len(ts) - 1
    for i, k in enumerate(kind):
        if k != HEARTBEAT:
            continue
        at = ts[i]
        period = hb / 1000.0 if hb > 0 else m.measured_period_at(at)
        limit = cons / 1000.0 if cons > 0 else params.timeout_factor * period
        until = ts[i + 1] if i < last else end
        if limit > 0 and until - at > limit + EPS:
            m.timeouts.append(Timeout("H001", at + limit, at, s.idx[i], limit,
                                      until - at if i < last else None))


def _timed_from(start: np.ndarray, by_heartbeat: np.ndarray, req: np.ndarray,
                conf: np.ndarray) -> np.ndarray:
    """The moment whose configuration times each gap: its start, but for a gap opened by a
    heartbeat between a 1017h write's request (`req`) and its confirmation (`conf`), the
    confirmation (the last such write in file order). A binary search when the writes'
    request to confirmation spans do not overlap (always, but in a hostile log), else
    write by write."""
    at: np.ndarray = start.copy()
    if not len(req):
        return at
    order = np.argsort(req, kind="stable")
    if bool((np.diff(order) > 0).all()) and bool((conf[:-1] <= req[1:]).all()):
        k = np.searchsorted(req, start, side="right") - 1
        inside = by_heartbeat & (k >= 0) & (start < conf[np.maximum(k, 0)])
        at[inside] = conf[k[inside]]
        return at
    for r, c in zip(req.tolist(), conf.tolist(), strict=True):
        at[by_heartbeat & (start >= r) & (start < c)] = c
    return at


def guard_timeouts(m: NodeModel, params: TimelineParams, end: float,
                   gaps: list[tuple[float, float]] | None = None) -> None:
    """G002: runs of remote requests to N that got no guarding response in time. `gaps`:
    the channel's recording gaps (SPEC §3 I007), whose time a wait does not count."""
    ec = m.ec
    pos = ec.where(REQUEST, GUARD, BOOTUP)  # heartbeats play no part here
    kind = ec.kind[pos]
    # Only a request not answered by the frame after it can time out, and a response
    # leaves nothing pending: the walk needs only the stretches from the response before
    # such a request to the response after it (none in a node always answered).
    unanswered = kind == REQUEST
    unanswered[:-1] &= kind[1:] != GUARD
    if not unanswered.any():
        return
    at = np.arange(len(kind))
    last_guard = np.maximum.accumulate(np.where(kind == GUARD, at, -1))
    next_guard = np.minimum.accumulate(np.where(kind == GUARD, at, len(kind))[::-1])[::-1]
    walk = np.zeros(len(kind) + 1, np.int64)
    bad = np.flatnonzero(unanswered)
    np.add.at(walk, last_guard[bad] + 1, 1)
    np.add.at(walk, np.minimum(next_guard[bad] + 1, len(kind)), -1)
    _guard_walk(m, params, end, pos[np.cumsum(walk[:-1]) > 0], gaps)


def _guard_walk(m: NodeModel, params: TimelineParams, end: float, pos: np.ndarray,
                gaps: list[tuple[float, float]] | None = None) -> None:
    """`guard_timeouts` over the node's requests, responses and boot-ups at `pos`, in
    order (all of them, or stretches that each begin after a response). A wait that a
    recording gap interrupts counts again from the gap's end; a request superseded before
    then is no finding (its answer may lie in the gap)."""
    limit = params.response_timeout_s
    gaps = gaps or []
    run: Timeout | None = None
    pending: tuple[float, int] | None = None  # ts, idx of the pending request

    def close(request: tuple[float, int], next_request: float | None) -> None:
        nonlocal run
        deadline = request[0] + limit
        # a gap counts only if it began while the wait ran: a request superseded by the
        # next one before the gap timed out then
        ends = deadline if next_request is None else min(deadline, next_request)
        cut = next((b for a, b in gaps if request[0] <= a + EPS and a < ends), None)
        if cut is not None:  # the recorder may have missed the answer: from the gap's end
            deadline = cut + limit
            if next_request is not None and next_request < deadline:
                return
        if next_request is None and deadline > end - EPS:
            return  # the trace ended before the answer was due
        moment = deadline if next_request is None else min(deadline, next_request)
        if run is None:
            run = Timeout("G002", moment, request[0], request[1], limit, None)
            m.timeouts.append(run)
        else:
            run.requests += 1

    ec = m.ec
    for k, ts, idx in zip(ec.kind[pos].tolist(), ec.ts[pos].tolist(), ec.idx[pos].tolist(),
                          strict=True):
        if k == REQUEST:
            if pending is not None:
                close(pending, ts)
            pending = (ts, idx)
        elif k == GUARD:  # classification only accepts answers to a pending request
            pending = None
            run = None
        elif pending is not None:  # boot-up
            # A request still within its wait when the node booted was lost to the restart,
            # which B001/B002 judge; one that had already timed out is a real G002.
            if ts - pending[0] > limit + EPS:
                close(pending, None)
            pending = None
            run = None
    if pending is not None:
        close(pending, None)


def offline_ends(decoded: Decoded, items: list[tuple[NodeModel, Timeout]]) -> None:
    """Each timeout lasts until the node's next frame of any kind after its moment."""
    if not items:
        return
    found = decoded.first_node_frame_after(np.asarray([m.key for m, _t in items]),
                                           np.asarray([t.moment for _m, t in items]),
                                           np.asarray([t.after_idx for _m, t in items]))
    for (m, t), hit_idx, hit_ts in zip(items, found.idx.tolist(), found.ts.tolist(),
                                       strict=True):
        best = hit_ts if hit_idx >= 0 else None
        ec = m.ec
        p = ec.after(t.after_idx)
        step = 16
        while p < len(ec):  # usually the very next frames: look in growing windows
            window = slice(p, p + step)
            ok = np.flatnonzero((ec.kind[window] != REQUEST) & (ec.ts[window] >= t.moment))
            if ok.size:
                ts = float(ec.ts[p + ok[0]])
                if best is None or ts < best:
                    best = ts
                break
            p += step
            step *= 2
        t.ended_by = best


def self_starts(decoded: Decoded, nodes: list[tuple[NodeModel, float]]) -> None:
    """Nodes that entered OPERATIONAL by themselves after a boot-up (SPEC §2 Self-start).

    N's first error-control message after a boot-up (no NMT command to N between)
    reporting OPERATIONAL: N started itself, from its first TPDO after the boot-up, else
    from that message. When a reset command to N or N's next boot-up (or the end of the
    trace) comes before any message and no other command did, nothing shows whether N
    started itself: that span goes to `m.unproven_spans` (its PDOs are no S001).
    """
    queries: list[tuple[NodeModel, int, int, int]] = []  # node, boot pos, boot idx, msg idx
    for m, end in nodes:  # (each node with the end of its channel's trace)
        counts = m.kind_counts()
        if not counts[BOOTUP]:
            continue
        if not counts[HEARTBEAT] and not counts[GUARD] and not len(m.commands):
            m.unproven_spans = _unproven_bootups(m, end)  # most nodes of many channels
            continue
        queries.extend(_self_start_queries(m, end) if m.small is None
                       else _small_self_start(m, m.small, end))
    if not queries:
        return
    found = decoded.first_node_frame_after(
        np.asarray([m.key for m, *_ in queries]),
        np.asarray([float(m.ec.ts[p]) for m, p, _, _ in queries]),
        np.asarray([b for _m, _p, b, _ in queries]), kinds=(KIND_TPDO,))
    for (m, _p, _b, report_idx), t_idx, t_ts in zip(queries, found.idx.tolist(),
                                                   found.ts.tolist(), strict=True):
        if 0 <= t_idx < report_idx:
            m.self_starts.append((t_ts, t_idx))
        else:
            q = int(np.searchsorted(m.ec.idx, report_idx))
            m.self_starts.append((float(m.ec.ts[q]), report_idx))


def _self_start_queries(m: NodeModel, end: float) -> list[tuple[NodeModel, int, int, int]]:
    """`self_starts` for one node with boot-ups: the boot-ups its first message shows it
    started itself after (node, boot-up position, its frame index, the message's), and
    its unproven spans, set on it."""
    ec = m.ec
    boots = ec.where(BOOTUP)
    msgs = ec.where(HEARTBEAT, GUARD)
    msgs = msgs[CODE_STATE[ec.value[msgs] & 0x7F] >= 0]
    b_idx, b_ts = ec.idx[boots], ec.ts[boots]
    never = np.iinfo(np.int64).max
    next_boot = np.append(b_idx[1:], never)
    next_boot_ts = np.append(b_ts[1:], end)
    msg: np.ndarray = next_of(ec.idx[msgs], b_idx, msgs, -1).astype(np.int64)
    msg_idx = np.where(msg >= 0, ec.idx[msg], never)
    cmds = m.commands
    next_cmd = next_of(cmds.idx, b_idx)
    stop = np.minimum(next_boot, next_of(cmds.reset_idx, b_idx))
    answered = (msg_idx < stop) & (msg_idx < next_cmd)
    started = answered & (CODE_STATE[ec.value[msg] & 0x7F] == STATE_INDEX[OPERATIONAL])
    # No message before the next boot-up or command to N: nothing shows whether N started
    # itself (SPEC §2 for a reset or a boot-up; beyond it, for any command): the message
    # after a command reports what the command asked, self-started or not. CANopenNode's
    # master starts a self-starting slave before its first heartbeat, and the slave sends
    # its TPDO right after its boot-up: within S001's grace after the reset only where the
    # slave boots within it (16 us on Linux, a real device's reset may take 100s of ms).
    unknown = msg_idx >= np.minimum(next_boot, next_cmd)
    span_end = np.minimum(next_boot_ts, next_of(cmds.idx, b_idx, cmds.ts, end))
    m.unproven_spans = [(float(a), float(b)) for a, b in zip(
        b_ts[unknown].tolist(), span_end[unknown].tolist(), strict=True)]
    return [(m, int(boots[i]), int(b_idx[i]), int(msg_idx[i]))
            for i in np.flatnonzero(started).tolist()]


def _small_self_start(m: NodeModel, s: SmallEc, end: float
                      ) -> list[tuple[NodeModel, int, int, int]]:
    """`_self_start_queries` for a small node (no command): after each boot-up, its first
    heartbeat with a CiA 301 state before the next boot-up decides; none: unproven."""
    never = np.iinfo(np.int64).max
    ts, kind, value, idx = s.ts, s.kind, s.value, s.idx
    boots = [i for i, k in enumerate(kind) if k == BOOTUP]
    queries, spans = [], []
    for j, p in enumerate(boots):
        nxt = boots[j + 1] if j + 1 < len(boots) else len(kind)
        msg = next((q for q in range(p + 1, len(kind)) if kind[q] == HEARTBEAT
                    and CODE_STATE_LIST[value[q] & 0x7F] >= 0), -1)
        msg_idx = idx[msg] if msg >= 0 else never
        if msg_idx < (idx[nxt] if nxt < len(kind) else never):
            if CODE_STATE_LIST[value[msg] & 0x7F] == _OPERATIONAL:
                queries.append((m, p, idx[p], msg_idx))
        else:
            spans.append((ts[p], min(ts[nxt], end) if nxt < len(kind) else end))
    m.unproven_spans = spans
    return queries


def _unproven_bootups(m: NodeModel, end: float) -> list[tuple[float, float]]:
    """What `_self_start_queries` finds for a node with boot-ups but no message and no
    command: no self-start, and each boot-up to the next (or the end) unproven."""
    b_ts = m.ec.ts[m.ec.kind == BOOTUP].tolist()
    return [(a, min(b, end)) for a, b in zip(b_ts, [*b_ts[1:], end], strict=True)]
