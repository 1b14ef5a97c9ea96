"""The state intervals of one node: a walk over the few frames that can change its state
(commands that reach it, boot-ups, reports of a state, timeouts), with the stale window
after each command and the evidence that proves a state (SPEC §2)."""

from __future__ import annotations

import bisect
from array import array
from collections.abc import Iterable, Iterator

import numpy as np

from nmtcheck.protocol.nmt import (
    BOOTUP,
    COMMAND_STATE,
    EPS,
    GUARD,
    HEARTBEAT,
    OFFLINE,
    OPERATIONAL,
    PRE_OPERATIONAL,
    REQUEST,
    SOURCE_INDEX,
    STATE_INDEX,
    STATE_OF_CODE,
    UNKNOWN,
)
from nmtcheck.timeline.error_control import CODE_STATE, CODE_STATE_LIST
from nmtcheck.timeline.model import (
    ChannelModel,
    EcTable,
    IntervalTable,
    NmtTable,
    NodeModel,
    SmallEc,
    reset_cs,
)
from nmtcheck.timeline.tables import FewIntervals, shared_column

# state index a data byte reports, -1 if none (boot-up handled apart)
_STATE_OF_BYTE = np.full(256, -1, np.int8)
for _code, _state in STATE_OF_CODE.items():
    _STATE_OF_BYTE[_code] = _STATE_OF_BYTE[_code | 0x80] = STATE_INDEX[_state]


def _evidence(m: NodeModel, windows: list[tuple[float, float]]) -> np.ndarray:
    """Positions (in time order) of the node's error-control frames that can change its
    timeline: a frame that reports the same as the frame before it changes nothing, so
    runs of equal heartbeats reduce to their first. Frames inside a window [lo, hi]
    (after a command or timeout) are kept, and the first one after it."""
    ec = m.ec
    pos = np.flatnonzero(ec.kind != REQUEST)
    pos = pos[np.lexsort((ec.idx[pos], ec.ts[pos]))]
    if not pos.size:
        return pos
    kind = ec.kind[pos]
    target = np.where(kind == BOOTUP, STATE_INDEX[PRE_OPERATIONAL],
                      np.where((kind == HEARTBEAT) | (kind == GUARD),
                               _STATE_OF_BYTE[ec.value[pos] & 0xFF], -1))
    keep = np.ones(len(pos), bool)
    keep[1:] = target[1:] != target[:-1]
    keep |= kind == BOOTUP  # sparse, and each one ends what came before it
    if windows:
        sts = ec.ts[pos]
        w = np.asarray(windows, np.float64)
        lo = np.searchsorted(sts, w[:, 0], side="left")
        hi = np.minimum(np.searchsorted(sts, w[:, 1] + EPS, side="right"), len(pos) - 1)
        mark = np.zeros(len(pos) + 1, np.int64)
        np.add.at(mark, lo, 1)
        np.add.at(mark, hi + 1, -1)
        keep |= np.cumsum(mark[:-1]) > 0
    return pos[keep]


_STATE_OF_BYTE_LIST: list[int] = _STATE_OF_BYTE.tolist()
_PRE_OP = STATE_INDEX[PRE_OPERATIONAL]
_OPERATIONAL = STATE_INDEX[OPERATIONAL]
_EC_SOURCE = {BOOTUP: SOURCE_INDEX["bootup"], HEARTBEAT: SOURCE_INDEX["heartbeat"],
              GUARD: SOURCE_INDEX["guarding"]}
_EV_TIMEOUT, _EV_EC, _EV_BACK = 0, 1, 2  # order of steps at one moment; commands are 1 too
_EV_CMD = 3


STEP_CHUNK = 1 << 16


def reports_by_node(cm: ChannelModel) -> dict[int, np.ndarray]:
    """Each node's heartbeats and guarding answers on the channel, as frame indices."""
    return {n: m.ec.idx[(m.ec.kind == HEARTBEAT) | (m.ec.kind == GUARD)]
            for n, m in cm.nodes.items()}


def _stale_until(m: NodeModel, obey_s: float, reports: dict[int, np.ndarray]) -> np.ndarray:
    """Per command to N, until when a report of N that still says the state from before
    the command was queued before N processed it (stale, SPEC §2): `obey_s` after the
    command; in a log without timestamps, up to N's first report after the command
    (frame numbers are no time, and that report may still be a queued one: CANopenNode's
    heartbeat right after `000#0102` often says 7Fh, its TPDO and 05h come next) if it
    comes before any other node of the channel (`reports`: each node's, frame indices)
    has reported twice after the command: a report a whole heartbeat cycle later was
    not queued before it (B001 missed `703#05` 84 frames after `000#8103`)."""
    cmds = m.commands
    if not m.order_only:
        return cmds.ts + obey_s
    ec = m.ec
    mine = np.flatnonzero((ec.kind == HEARTBEAT) | (ec.kind == GUARD))
    if not mine.size:
        return cmds.ts.astype(np.float64)
    k = np.searchsorted(ec.idx[mine], cmds.idx, side="right")
    first = mine[np.minimum(k, mine.size - 1)]
    cycle = np.full(len(cmds), np.iinfo(np.int64).max)  # another node's second report
    for node, idx in reports.items():
        if node != m.node and idx.size >= 2:
            j = np.searchsorted(idx, cmds.idx, side="right") + 1
            cycle = np.minimum(cycle, np.where(j < idx.size, idx[np.minimum(j, idx.size - 1)],
                                               cycle))
    soon = (k < mine.size) & (ec.idx[first] < cycle)
    return np.where(soon, ec.ts[first].astype(np.float64), cmds.ts)


def mark_power_on_bootups(nmt: NmtTable, nodes: dict[int, NodeModel], obey_s: float) -> None:
    """Mark in `ec.stale` the one kind of stale boot-up (SPEC §2, amended 2026-12-07): N's
    first frame in the trace, at most `obey_s` after a reset command to N (direct or
    broadcast, whether or not N had been seen), with N's next boot-up at most `obey_s`
    after it. A device that powers on while the master's `000#8200` is on the bus
    (CANopenNode) sends its power-on boot-up after the command, then the one that answers
    it: the first is no evidence, and neither is B003 nor B002 (`checks/bootup.py`).
    Boot-ups are final after the first classification pass (`classify`)."""
    if not len(nmt):
        return
    resets = np.flatnonzero(nmt.valid & reset_cs(nmt.cs))
    if not resets.size:
        return
    # the resets by target, each target's in file order: a log may hold a million
    by_target = resets[np.lexsort((nmt.idx[resets], nmt.target[resets]))]
    targets = nmt.target[by_target]
    for n, m in nodes.items():
        if m.first_tx is None or m.kind_counts()[BOOTUP] < 2:
            continue
        ec = m.ec
        boots = ec.where(BOOTUP)
        first, answer = int(boots[0]), int(boots[1])
        if int(ec.idx[first]) != m.first_tx.idx:  # not N's first frame
            continue
        b_ts = float(ec.ts[first])
        if not -EPS <= float(ec.ts[answer]) - b_ts <= obey_s + EPS:
            continue
        latest = -np.inf  # the latest reset to N (direct or broadcast) before it
        for t in (0, n):
            rows = by_target[np.searchsorted(targets, t, side="left"):
                             np.searchsorted(targets, t, side="right")]
            k = int(np.searchsorted(nmt.idx[rows], ec.idx[first], side="left")) - 1
            if k >= 0:
                latest = max(latest, float(nmt.ts[rows[k]]))
        if -EPS <= b_ts - latest <= obey_s + EPS:
            ec.stale[first] = True


def _interval_steps(m: NodeModel, until: np.ndarray) -> Iterator[tuple[float, int, int]]:
    """What the interval walk sees, in order: (time, what, reference) for each evidence
    frame, command, timeout and end of a timeout. At one moment a timeout comes first
    and its end last; the rest in file order."""
    ec, cmds = m.ec, m.commands
    windows = list(zip(cmds.ts.tolist(), until.tolist(), strict=True)) + [
        (t, t) for t in [t.moment for t in m.timeouts]
        + [t.ended_by for t in m.timeouts if t.ended_by is not None]]
    pos = _evidence(m, windows)
    if not len(cmds) and not m.timeouts and not m.self_starts:  # the evidence alone, in
        yield from _in_chunks(ec.ts[pos], np.full(len(pos), _EV_EC, np.int8), pos,
                              np.arange(len(pos)))  # in time order already
        return
    back_of = [i for i, t in enumerate(m.timeouts) if t.ended_by is not None]
    backs = [m.timeouts[i] for i in back_of]
    # the steps as columns: time, order at one moment, file position, what, reference
    ts = np.concatenate([ec.ts[pos], cmds.ts, [t.moment for t in m.timeouts],
                         [t.ended_by for t in backs]]).astype(np.float64)
    order = np.concatenate([np.ones(len(pos) + len(cmds), np.int8),
                            np.zeros(len(m.timeouts), np.int8), np.full(len(backs), 2, np.int8)])
    idx = np.concatenate([ec.idx[pos], cmds.idx,
                          np.full(len(m.timeouts) + len(backs), -1, np.int64)])
    what = np.concatenate([np.full(len(pos), _EV_EC, np.int8),
                           np.full(len(cmds), _EV_CMD, np.int8),
                           np.full(len(m.timeouts), _EV_TIMEOUT, np.int8),
                           np.full(len(backs), _EV_BACK, np.int8)])
    ref = np.concatenate([pos, np.arange(len(cmds)), np.arange(len(m.timeouts)),
                          back_of]).astype(np.int64)
    if m.self_starts:  # a node that started itself: OPERATIONAL from its first TPDO, a
        # step like a command's (references past the commands: see node_intervals)
        ts = np.concatenate([ts, [t for t, _i in m.self_starts]])
        order = np.concatenate([order, np.ones(len(m.self_starts), np.int8)])
        idx = np.concatenate([idx, [i for _t, i in m.self_starts]]).astype(np.int64)
        what = np.concatenate([what, np.full(len(m.self_starts), _EV_CMD, np.int8)])
        ref = np.concatenate([ref, len(cmds) + np.arange(len(m.self_starts))])
    steps = np.lexsort((idx, order, ts))
    yield from _in_chunks(ts, what, ref, steps)


def _small_steps(m: NodeModel, s: SmallEc) -> list[tuple[float, int, int]]:
    """`_interval_steps` for a small node (no command, no request): its evidence (the
    first frame, each change of the reported state, every boot-up, and around each
    timeout's moment and end the frames within and the first one after), its
    timeouts, their ends and its self-starts, sorted as the numpy path sorts them."""
    ts, kind, value, idx = s.ts, s.kind, s.value, s.idx
    pos = sorted(range(len(ts)), key=lambda p: (ts[p], idx[p]))
    sts = [ts[p] for p in pos]
    keep = [False] * len(pos)
    prev = None
    for j, p in enumerate(pos):
        target = _PRE_OP if kind[p] == BOOTUP else _STATE_OF_BYTE_LIST[value[p]]
        keep[j] = j == 0 or target != prev or kind[p] == BOOTUP
        prev = target
    marks = [t.moment for t in m.timeouts] + [
        t.ended_by for t in m.timeouts if t.ended_by is not None]
    for t in marks:  # a window [t, t]: the frames at t, and the first one after
        lo = bisect.bisect_left(sts, t)
        hi = min(bisect.bisect_right(sts, t + EPS), len(pos) - 1)
        for j in range(lo, hi + 1):
            keep[j] = True
    evidence = [p for j, p in enumerate(pos) if keep[j]]
    if not m.timeouts and not m.self_starts:
        return [(ts[p], _EV_EC, p) for p in evidence]
    # (time, order at one moment, file position, what, reference), then stable by the
    # first three as `_interval_steps`' lexsort
    rows: list[tuple[float, int, int, int, int]] = [
        (ts[p], 1, idx[p], _EV_EC, p) for p in evidence]
    rows += [(t.moment, 0, -1, _EV_TIMEOUT, i) for i, t in enumerate(m.timeouts)]
    rows += [(t.ended_by, 2, -1, _EV_BACK, i) for i, t in enumerate(m.timeouts)
             if t.ended_by is not None]
    rows += [(t, 1, i, _EV_CMD, j) for j, (t, i) in enumerate(m.self_starts)]
    rows.sort(key=lambda r: (r[0], r[1], r[2]))
    return [(r[0], r[3], r[4]) for r in rows]


def _in_chunks(ts: np.ndarray, what: np.ndarray, ref: np.ndarray, steps: np.ndarray
               ) -> Iterator[tuple[float, int, int]]:
    """The rows `steps` of the step columns, in that order, as Python numbers a chunk at
    a time: a node may have millions of steps."""
    for lo in range(0, len(steps), STEP_CHUNK):
        part = steps[lo:lo + STEP_CHUNK]
        yield from zip(ts[part].tolist(), what[part].tolist(), ref[part].tolist(), strict=True)


def _walk_inputs(m: NodeModel, until: np.ndarray) -> tuple[
        Iterable[tuple[float, int, int]], array[int] | list[int], array[int] | list[int]]:
    """The steps of `node_intervals`' walk (`until`: each command's stale window's end), and
    each frame's kind and reported state."""
    if m.small is not None:  # a few frames, no command: lists
        return (_small_steps(m, m.small), m.small.kind,
                [CODE_STATE_LIST[v & 0x7F] for v in m.small.value])
    # compact arrays, not lists: one entry per frame, read one at a time
    return (_interval_steps(m, until), array("b", m.ec.kind.astype(np.int8).tobytes()),
            array("b", CODE_STATE[m.ec.value & 0x7F].tobytes()))


def node_intervals(m: NodeModel, start: float, end: float, obey_s: float,
               reports: dict[int, np.ndarray]) -> IntervalTable:
    """Walk the node's evidence in order and cut the timeline into state intervals.

    A heartbeat or guarding response up to `obey_s` after a command that reports the
    state from before the command was queued before the node processed it: it is marked
    stale in `m.ec.stale` and is no evidence (SPEC §2). The walk sees plain ints and
    floats, never objects: a node may change state on every heartbeat.
    """
    ec, cmds = m.ec, m.commands
    stale_until = _stale_until(m, obey_s, reports)
    steps, kind, code_state = _walk_inputs(m, stale_until)
    until = stale_until.tolist()
    # per command, then per self-start (SPEC §2): the state it sets and the source
    cmd_state = [STATE_INDEX[COMMAND_STATE[c]] for c in cmds.cs.tolist()] + [
        STATE_INDEX[OPERATIONAL]] * len(m.self_starts)
    cmd_source = [SOURCE_INDEX["command"]] * len(cmds) + [
        SOURCE_INDEX["self-start"]] * len(m.self_starts)
    ended_by = [t.ended_by for t in m.timeouts]

    unknown, offline, pre_op = STATE_INDEX[UNKNOWN], STATE_INDEX[OFFLINE], STATE_INDEX[
        PRE_OPERATIONAL]
    src_timeout = SOURCE_INDEX["timeout"]
    starts = array("d", [start])  # the intervals so far (8 + 1 + 1 bytes each)
    states = array("b", [unknown])
    sources = array("b", [SOURCE_INDEX["start"]])

    def go(at: float, state: int, source: int) -> None:
        if states[-1] == state:
            return
        if at <= starts[-1]:  # the current interval would be empty: replace it
            starts.pop()
            states.pop()
            sources.pop()
            if states and states[-1] == state:
                return
        starts.append(max(at, start))
        states.append(state)
        sources.append(source)

    saved: tuple[int, int] | None = None  # state and source to return to after OFFLINE
    offline_until: float | None = None
    # the latest command: until when a report may be stale, the state before it
    last_cmd: tuple[float, int] | None = None
    pre_offline: int | None = None  # the state N had when it went OFFLINE
    stale = ec.stale
    for at, w, r in steps:
        cur = states[-1]
        if w == _EV_EC:
            k = kind[r]
            state = code_state[r]
            if k in (HEARTBEAT, GUARD) and last_cmd is not None and (
                    at <= last_cmd[0] + EPS) and state == last_cmd[1]:
                stale[r] = True
                continue
            # a stale boot-up (`mark_power_on_bootups`) is no evidence (SPEC §2): as any
            # frame, it only ends OFFLINE
            if k == BOOTUP and not stale[r]:
                last_cmd = None  # nothing after a boot-up was queued before the command
                go(at, pre_op, _EC_SOURCE[k])
                saved = None
            elif k in (HEARTBEAT, GUARD) and state >= 0:
                go(at, state, _EC_SOURCE[k])
                saved = None
            elif cur == offline and saved is not None:
                go(at, *saved)
                saved = None
        elif w == _EV_CMD:
            last_cmd = (until[r] if r < len(until) else at + obey_s,  # else a self-start
                        pre_offline if cur == offline and pre_offline is not None else cur)
            if cur == offline:
                saved = (cmd_state[r], cmd_source[r])
            else:
                go(at, cmd_state[r], cmd_source[r])
        elif w == _EV_TIMEOUT and cur not in (unknown, offline):
            saved = (cur, sources[-1])
            pre_offline = cur  # what a stale report after a command here would still say
            offline_until = ended_by[r]
            go(at, offline, src_timeout)
        elif w == _EV_BACK and cur == offline and saved is not None and offline_until == at:
            go(at, *saved)
            saved = None
    begin = np.frombuffer(starts, np.float64).copy()
    finish = np.append(begin[1:], max(end, starts[-1]))
    return IntervalTable(begin, finish, np.frombuffer(states, np.int8).copy(),
                         np.frombuffer(sources, np.int8).copy())


def only_bootups(m: NodeModel) -> bool:
    """Whether N's frames are boot-ups only (or none), with no command, timeout or
    self-start: its intervals are `bootups_only`'s."""
    return (not len(m.commands) and not m.timeouts and not m.self_starts
            and m.kind_counts()[BOOTUP] == len(m.ec))


def bootups_only(ec: EcTable, start: float, end: float) -> IntervalTable:
    """What the walk of `node_intervals` makes of a node whose frames are boot-ups only (or
    none), with no command, timeout or self-start: UNKNOWN until its first boot-up,
    PRE-OPERATIONAL from then on (every later boot-up changes nothing). Most nodes of a
    log of many short channels; the walk's set-up costs far more than this."""
    unknown, pre_op = STATE_INDEX[UNKNOWN], STATE_INDEX[PRE_OPERATIONAL]
    evidence = ec.ts[~ec.stale] if ec.stale.any() else ec.ts  # a stale boot-up: none
    if not len(evidence):
        starts, states, sources = [start], [unknown], [SOURCE_INDEX["start"]]
    else:
        first = float(evidence.min())
        if first <= start:  # the UNKNOWN interval would be empty
            starts, states, sources = [start], [pre_op], [_EC_SOURCE[BOOTUP]]
        else:
            starts, states, sources = [start, first], [unknown, pre_op], [
                SOURCE_INDEX["start"], _EC_SOURCE[BOOTUP]]
    return FewIntervals((*starts, max(end, starts[-1])), shared_column(states, np.int8),
                        shared_column(sources, np.int8))
