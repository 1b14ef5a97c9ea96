"""Boot-up rules (B): the boot-up message 700h+N / 00h that ends every Initialisation."""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator

import numpy as np

from nmtcheck.checks.base import Found, NodeContext, Param, Params, batch, rule
from nmtcheck.protocol.nmt import (
    BOOTUP,
    EC_KIND_NAMES,
    EPS,
    GUARD,
    HEARTBEAT,
    MALFORMED,
    is_one_of,
)
from nmtcheck.timeline.decode import KIND_EC, KIND_NAMES, NodeFrames
from nmtcheck.timeline.model import EcFrame, EcTable, NodeModel
from nmtcheck.timeline.moments import at, span

_NEVER = np.iinfo(np.int64).max  # a frame index after every frame


def _auto_window_s(m: NodeModel, value_ms: float) -> float:
    """A window given in ms, or 0 = 3 x the node's heartbeat period, at least 1 s."""
    if value_ms > 0:
        return value_ms / 1000.0
    return max(3 * (m.period_s or 0.0), 1.0)


@rule("B001", "missing-bootup", "error",
      Param("bootup_timeout_ms", float, "how long a reset node may take to send its boot-up",
            5000.0),
      Param("late_start_ms", float,
            "first heartbeat later than this after the trace start without a boot-up "
            "(0 = 3 x the node's heartbeat period, at least 1000 ms)", 0.0),
      Param("grace_ms", float,
            "a frame this soon after the reset command was queued before it: no sign of life",
            5.0),
      exempt_from_unknown=True)
def missing_bootup(m: NodeModel, ctx: NodeContext, p: Params) -> Iterator[Found]:
    """A node did not announce its (re)start with a boot-up message.

    **What it checks.** (a) After a reset-node or reset-communication command to
    N (direct or broadcast), N shows a sign of life (heartbeat, guarding
    response, TPDO, SDO response, EMCY) before its boot-up, or sends no boot-up
    within `bootup_timeout_ms` while the trace goes on. A frame of N within
    `grace_ms` after the command left N's controller before N processed it: no
    sign of life. "Sends none" applies only to a node that transmitted before the
    command or that the network file expects: a CiA 302 manager in keep-alive mode
    resets every node-ID 1-127 one by one, and the absent ones are no missing
    boot-ups (N001 reports expected nodes that never appear). The master's own
    broadcasts are never a finding for it. (b) N's first frame in
    the trace is a heartbeat that arrives more than `late_start_ms` after the
    trace's first frame: N came up during the recording without a boot-up.

    **Why it matters.** CiA 301 makes the boot-up the last act of Initialisation
    on every path (power-on, reset node, reset communication). Masters use it
    to start configuring the slave (CiA 302-2); a node that skips it is never
    configured, and a master cannot tell a reboot from a glitch.

    **Example.** `000#8103` (reset node 3) followed by `703#05` with no `703#00`
    in between.
    """
    yield from _no_bootup_after_reset(m, ctx, p["bootup_timeout_ms"] / 1000.0,
                                      p["grace_ms"] / 1000.0)
    yield from _late_start(m, ctx, p["late_start_ms"])


def _no_bootup_after_reset(m: NodeModel, ctx: NodeContext, timeout: float, grace: float
                           ) -> Iterator[Found]:
    """B001 (a): per reset command, a sign of life before the boot-up or no boot-up.

    Vectorised over the resets (a log may reset a node a million times): one batch, in
    reset order, of findings at a frame (the sign of life) or at a moment (the timeout).
    """
    cmds, ec = m.commands, m.ec
    if not len(cmds):
        return
    rpos = np.flatnonzero(cmds.is_reset)
    if not len(rpos):
        return
    never = _NEVER
    r_ts, r_idx = cmds.ts[rpos], cmds.idx[rpos]
    next_idx = np.append(r_idx[1:], never)
    next_ts = np.append(r_ts[1:], np.inf)
    boot = _following(ec, ec.where(BOOTUP), r_idx)  # the boot-up after each reset
    boot_idx, boot_ts = boot.idx, np.where(boot.idx < never, boot.ts, np.inf)
    limit = np.minimum(boot_idx, next_idx)  # the wait ends at the boot-up or the next reset
    life = ec.where(HEARTBEAT, GUARD, MALFORMED)  # signs of life but the boot-up
    # a report queued before the command (stale, or within the grace) is none
    sign = _following(ec, life[~ec.stale[life]], r_idx, r_ts + grace + EPS)
    has_sign = sign.idx < limit
    other = ctx.model.first_tx_after_resets(m)  # TPDO, SDO response, EMCY (after the grace)
    has_other = (other.idx >= 0) & (other.idx < limit) & (~has_sign | (other.idx < sign.idx))
    if m.order_only:  # no grace without time: a TPDO, SDO or EMCY before the boot-up that
        # answers the reset may have been queued (Lely's TPDOs 2 us after `000#8100`)
        has_other &= boot_idx >= next_idx
    has_sign &= ~has_other
    restarted = ((next_idx < never) & (next_idx < boot_idx)
                 & (next_ts - r_ts <= timeout + EPS))  # a newer reset restarts the wait
    # only a node that transmitted before the command, or one the network file expects,
    # is awaited: a keep-alive manager resets every node-ID, present or not
    awaited = np.full(len(rpos), bool(m.config.expected))
    if m.first_tx is not None:
        awaited |= r_idx > m.first_tx.idx
    # the wait for the boot-up does not count a recording gap (SPEC §3 I007): it counts
    # again from the gap's end
    deadline = r_ts + timeout
    for gap in ctx.channel.recording_gaps:
        cut = (r_ts <= gap.start + EPS) & (gap.start < deadline)
        deadline = np.where(cut, gap.end + timeout, deadline)
    no_boot = (~has_other & ~has_sign & ~restarted & (boot_ts > deadline + EPS)
               & (ctx.end > deadline + EPS) & awaited)
    found = has_other | has_sign | no_boot
    found &= ~is_one_of(r_idx, m.own_command_idx)  # the master's own: never a finding for it
    found = np.flatnonzero(found)
    if not found.size:
        return
    at_other, at_sign = has_other[found], has_sign[found]
    choose = [at_other, at_sign]
    time = np.select(choose, [other.ts[found], sign.ts[found]], deadline[found])
    frame = np.select(choose, [other.idx[found], sign.idx[found]], -1)
    line = np.select(choose, [other.line[found], sign.line[found]], -1)
    # what was seen: a node-frame kind (> 0), -1 - an error-control kind, or 0: nothing
    what = np.select(choose, [other.kind[found].astype(np.int64),
                              -1 - sign.kind[found].astype(np.int64)], 0)
    c_ts, c_pos = r_ts[found], rpos[found]

    def message(i: int) -> str:
        command = cmds.name(int(c_pos[i]))
        if what[i] == 0:
            return (f"no boot-up from node {m.node} within {timeout:.3f} s after {command}")
        kind = KIND_NAMES[int(what[i])] if what[i] > 0 else EC_KIND_NAMES[-1 - int(what[i])]
        gap = time[i] - c_ts[i]  # frames, where the log has no timestamps
        after = f"{int(gap)} frames" if m.order_only else f"{float(gap):.3f} s"
        return f"{kind} from node {m.node} {after} after {command} without a boot-up"

    yield batch(time, message, frame, line)


def _following(ec: EcTable, pos: np.ndarray, after_idx: np.ndarray,
               not_before: np.ndarray | None = None) -> NodeFrames:
    """Per frame index, the first of the node's frames at `pos` later in the file (and,
    with `not_before`, at or after that time), as columns (idx: int64 max if none)."""
    n = len(after_idx)
    if not len(pos):
        return NodeFrames(np.full(n, np.inf), np.full(n, _NEVER), np.zeros(n, np.int64),
                          np.zeros(n, np.int8))
    k = np.searchsorted(ec.idx[pos], after_idx, side="right")
    if not_before is not None:  # times that go back in the file: their running maximum
        k = np.maximum(k, np.searchsorted(np.maximum.accumulate(ec.ts[pos]), not_before,
                                          side="left"))
    ok = k < len(pos)
    rows = pos[np.where(ok, k, 0)]
    return NodeFrames(np.where(ok, ec.ts[rows], np.inf), np.where(ok, ec.idx[rows], _NEVER),
                      ec.line[rows], ec.kind[rows])


def _late_start(m: NodeModel, ctx: NodeContext, late_start_ms: float) -> Iterator[Found]:
    """B001 (b): the node was already running when it first appeared, without a boot-up."""
    if m.first_tx is None or m.first_tx.kind != KIND_EC or not m.kind_counts()[HEARTBEAT]:
        return
    ec = m.ec
    k = int(np.searchsorted(ec.idx, m.first_tx.idx))
    first = ec[k] if k < len(ec) and ec.idx[k] == m.first_tx.idx else None
    late = _auto_window_s(m, late_start_ms)
    if first is not None and first.kind == "heartbeat" and (
            first.ts - ctx.start > late + EPS):
        yield (first.ts, f"node {m.node} first appears {first.ts - ctx.start:.3f} s into the "
               f"trace with a heartbeat and no boot-up (limit {late:.3f} s)", first)


def _time_went_back(between: np.ndarray, ts: float) -> bool:
    """N's frames `between` two of its boot-ups include one later than the second boot-up
    at `ts`: time went back between them (another capture appended to the file), so the
    time from one to the other is unknown."""
    return bool(len(between)) and float(between.max()) > ts + EPS


def _power_on(m: NodeModel) -> tuple[int, int]:
    """N's stale boot-up (SPEC §2: its power-on boot-up, sent after a reset command that
    then made N boot again; the timeline marks it, `intervals.mark_power_on_bootups`)
    and the boot-up that answers that reset, as positions in `m.ec`; (-1, -1): none.
    Neither is B003 nor B002, and the stale one answers no reset."""
    ec = m.ec
    if not ec.stale.any():
        return -1, -1
    boots = ec.where(BOOTUP)
    stale = boots[ec.stale[boots]]
    if not stale.size or stale[0] != boots[0]:  # only N's first frame can be one
        return -1, -1
    return int(boots[0]), int(boots[1])


def _repeats(m: NodeModel, window: float, reset_window: float) -> list[list[EcFrame]]:
    """Runs of 00h frames that follow each other within the window with no reset between.

    Each reset command (within B002's `reset_window_ms`) explains one boot-up, as for
    B002: two resets sent back to back (Lely's `000#8100` then `000#8200`) are answered
    by two boot-ups, no repeat. A repeat is a 00h right after N's previous 00h, with no
    heartbeat or guarding response of N between: a node that reported another state in
    between booted again (a power cycle, a crash: B002), it did not heartbeat 00h. In a
    log without timestamps (no window) that order is all B003 has.
    A stale power-on boot-up (`_power_on`) is left out: the boot-up after it answers the
    reset it came after, it repeats nothing."""
    runs: list[list[EcFrame]] = []
    reports = (m.ec.kind == HEARTBEAT) | (m.ec.kind == GUARD)
    seen = np.cumsum(reports)  # reports of N up to each row
    prev: EcFrame | None = None
    resets = m.commands.reset_idx.tolist()
    reset_ts = m.commands.reset_ts.tolist()
    ri = 0
    unanswered: deque[float] = deque()
    power_on, _answer = _power_on(m)
    for b in m.bootups:
        while ri < len(resets) and resets[ri] < b.idx:
            unanswered.append(reset_ts[ri])
            ri += 1
        if b.pos == power_on:
            continue
        while unanswered and b.ts - unanswered[0] > reset_window + EPS:
            unanswered.popleft()
        explained = bool(unanswered)
        if unanswered:
            unanswered.popleft()
        # time going back (two captures in one file) makes no repeat: "over -0.102 s",
        # nor "over 0.000 s" where N's frames between the two were later than both
        if (prev is not None and -EPS <= b.ts - prev.ts <= window + EPS and not explained
                and seen[b.pos] == seen[prev.pos]
                and not _time_went_back(m.ec.ts[prev.pos + 1:b.pos], b.ts)):
            if runs and runs[-1][-1] is prev:
                runs[-1].append(b)
            else:
                runs.append([prev, b])
        prev = b
    return runs


@rule("B003", "bootup-repeated", "error",
      Param("repeat_window_ms", float,
            "a second 00h within this window is a repeat "
            "(0 = 3 x the node's heartbeat period, at least 1000 ms)", 0.0))
def bootup_repeated(m: NodeModel, ctx: NodeContext, p: Params) -> Iterator[Found]:
    """A node keeps sending state 00h instead of announcing its boot-up once.

    **What it checks.** A second 00h frame from N follows the previous one within
    `repeat_window_ms` with neither a reset command to N nor a heartbeat or guarding
    response of N in between: a node that reported another state between two boot-ups
    rebooted (a power cycle, a crash), which is B002. Each reset command
    explains one boot-up (as for B002): two resets sent back to back, answered by two
    boot-ups, are no repeat. One finding per run.

    **Why it matters.** 00h is the boot-up message, sent once per Initialisation;
    it is never a periodic heartbeat state. A node that heartbeats 00h is stuck in
    (or pretends to be in) Initialisation, and every master re-starts its boot
    procedure on each one. canopen 2.4.1's LocalNode does exactly this after a
    received reset command.

    **Example.** `000#8102`, then `702#00` every 100 ms for the rest of the trace.
    """
    if m.kind_counts()[BOOTUP] < 2:  # a repeat needs two
        return
    untimed = m.order_only
    for run in _repeats(m, _auto_window_s(m, p["repeat_window_ms"]),
                        ctx.timeline.reset_window_s):
        over = span(run[-1].ts - run[0].ts, untimed)
        reset = _answered_reset(m, run[0])
        if reset is None:
            yield (run[1].ts, f"node {m.node} sent boot-up (00h) {len(run)} times in a row "
                   f"over {over} without a reset command", run[1])
            continue
        name, r_ts, r_line = reset
        more = f"{len(run) - 1} more time{'s' if len(run) > 2 else ''}"
        yield (run[1].ts, f"after {name} at {at(r_ts, ctx.start, untimed, 3)} (line {r_line}), "
               f"node {m.node} sent boot-up (00h) {more} in a row over {over} without a reset "
               "command", run[1])


def _answered_reset(m: NodeModel, first: EcFrame) -> tuple[str, float, int] | None:
    """The reset command to N that boot-up `first` answered (the latest one before it, with
    no other boot-up of N between): its name, time and line; None if none."""
    cmds = m.commands
    resets = np.flatnonzero(cmds.is_reset)
    if not resets.size:
        return None
    idx = cmds.idx[resets]
    k = int(np.searchsorted(idx, first.idx)) - 1
    if k < 0:
        return None
    boots = m.ec.idx[m.ec.kind == BOOTUP]
    if bool(((boots > idx[k]) & (boots < first.idx)).any()):
        return None
    pos = int(resets[k])
    return cmds.name(pos), float(cmds.ts[pos]), int(cmds.line[pos])


@rule("B002", "unexpected-bootup", "warning",
      Param("reset_window_ms", float, "how long a reset command explains a later boot-up", 10000.0))
def unexpected_bootup(m: NodeModel, ctx: NodeContext, p: Params) -> Iterator[Found]:
    """A node rebooted on its own: a boot-up no reset command explains.

    **What it checks.** N sends a boot-up after having sent other frames earlier in
    the trace, and no reset command to N (direct or broadcast) within the preceding
    `reset_window_ms` is still unanswered. Each reset explains one boot-up. Boot-ups
    that B003 counts as repeats are left to B003.

    **Why it matters.** This is how spontaneous reboots show up on the bus:
    watchdog resets, brown-outs, crashes. The node lost its configuration and its
    NMT state; the application on it restarted.

    **Example.** `703#05` every 100 ms, then `703#00` with no `000#8103` before it.
    """
    boots = m.kind_counts()[BOOTUP]
    if not boots or m.first_tx is None:  # a finding needs a frame before the boot-up
        return
    window = p["reset_window_ms"] / 1000.0
    repeat_ms = ctx.timeline.repeat_window_ms  # B003's: its repeats are left to it
    repeated = {b.pos for run in _repeats(m, _auto_window_s(m, repeat_ms), window)
                for b in run[1:]} if boots >= 2 else set()
    r_ts: list[float] = m.commands.reset_ts.tolist() if len(m.commands) else []
    r_idx: list[int] = m.commands.reset_idx.tolist() if len(m.commands) else []
    unanswered: list[float] = []
    ri = 0
    ec = m.ec
    pos = ec.where(BOOTUP)  # as columns: a frame is made only for a finding
    power_on, answer = _power_on(m)
    for b_pos, b_ts, b_idx in zip(pos.tolist(), ec.ts[pos].tolist(), ec.idx[pos].tolist(),
                                  strict=True):
        while ri < len(r_idx) and r_idx[ri] < b_idx:
            unanswered.append(r_ts[ri])
            ri += 1
        if b_pos == power_on:  # stale (SPEC §2): it answers no reset, and is N's first
            continue
        unanswered = [t for t in unanswered if b_ts - t <= window + EPS]
        if unanswered:
            unanswered.pop(0)
            continue
        if b_pos in repeated or b_pos == answer:  # the answer to a broadcast reset that
            continue  # came before N had been seen (not applied to N): no B002 either
        if m.first_tx.idx < b_idx:
            yield (b_ts, f"node {m.node} sent a boot-up with no reset command before it "
                   f"(spontaneous reboot?)", ec[b_pos])
