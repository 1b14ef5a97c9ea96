"""Boot-up rules (B): the boot-up message 700h+N / 00h that ends every Initialisation."""

from __future__ import annotations

import bisect
from collections.abc import Iterator

import numpy as np

from nmtcheck.checks.base import Found, NodeContext, Param, Params, rule
from nmtcheck.decode import KIND_EC, KIND_NAMES
from nmtcheck.model import EcFrame, NodeModel
from nmtcheck.nmt import EPS, GUARD, HEARTBEAT, MALFORMED, any_between


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
      exempt_from_unknown=True)
def missing_bootup(m: NodeModel, ctx: NodeContext, p: Params) -> Iterator[Found]:
    """A node did not announce its (re)start with a boot-up message.

    **What it checks.** (a) After a reset-node or reset-communication command to
    N (direct or broadcast), N shows a sign of life (heartbeat, guarding
    response, TPDO, SDO response, EMCY) before its boot-up, or sends no boot-up
    within `bootup_timeout_ms` while the trace goes on. (b) N's first frame in
    the trace is a heartbeat that arrives more than `late_start_ms` after the
    trace's first frame: N came up during the recording without a boot-up.

    **Why it matters.** CiA 301 makes the boot-up the last act of Initialisation
    on every path (power-on, reset node, reset communication). Masters use it
    to start configuring the slave (CiA 302-2); a node that skips it is never
    configured, and a master cannot tell a reboot from a glitch.

    **Example.** `000#8103` (reset node 3) followed by `703#05` with no `703#00`
    in between.
    """
    yield from _no_bootup_after_reset(m, ctx, p["bootup_timeout_ms"] / 1000.0)
    yield from _late_start(m, ctx, p["late_start_ms"])


def _no_bootup_after_reset(m: NodeModel, ctx: NodeContext, timeout: float) -> Iterator[Found]:
    """B001 (a): per reset command, a sign of life before the boot-up or no boot-up."""
    cmds, ec = m.commands, m.ec
    rpos = np.flatnonzero(cmds.is_reset)  # plain lists: a log may reset a million times
    if not len(rpos):
        return
    r_ts, r_idx = cmds.ts[rpos].tolist(), cmds.idx[rpos].tolist()
    bootups = m.bootups
    boot_idx = [b.idx for b in bootups]
    life = ec.where(HEARTBEAT, GUARD, MALFORMED)  # signs of life but the boot-up
    life = life[~ec.stale[life]]  # a report queued before the reset is none
    life_idx = ec.idx[life]
    sign_at = np.searchsorted(life_idx, cmds.idx[rpos], side="right").tolist()
    others = ctx.model.first_tx_after_resets(m)  # TPDO, SDO response, EMCY
    for i, (c_ts, c_idx) in enumerate(zip(r_ts, r_idx, strict=True)):
        next_reset = r_idx[i + 1] if i + 1 < len(r_idx) else None
        k = bisect.bisect_right(boot_idx, c_idx)
        boot = bootups[k] if k < len(bootups) else None
        limit_idx = min(x for x in (boot.idx if boot else None, next_reset, 1 << 62)
                        if x is not None)
        k = sign_at[i]
        sign = life[k] if k < len(life) and life_idx[k] < limit_idx else None
        other = others[i]
        if other is not None and other.idx < limit_idx and (
                sign is None or other.idx < ec.idx[sign]):
            yield (other.ts, f"{KIND_NAMES[other.kind]} from node {m.node} "
                   f"{other.ts - c_ts:.3f} s after {cmds.name(rpos[i])} without a boot-up", other)
            continue
        if sign is not None:
            f = ec[sign]
            yield (f.ts, f"{f.kind} from node {m.node} {f.ts - c_ts:.3f} s after "
                   f"{cmds.name(rpos[i])} without a boot-up", f)
            continue
        if next_reset is not None and (boot is None or next_reset < boot.idx) and (
                r_ts[i + 1] - c_ts <= timeout + EPS):
            continue  # a newer reset restarts the wait
        if (boot is None or boot.ts - c_ts > timeout + EPS) and (
                ctx.end > c_ts + timeout + EPS):
            yield (c_ts + timeout, f"no boot-up from node {m.node} within {timeout:.3f} s "
                   f"after {cmds.name(rpos[i])}")


def _late_start(m: NodeModel, ctx: NodeContext, late_start_ms: float) -> Iterator[Found]:
    """B001 (b): the node was already running when it first appeared, without a boot-up."""
    if m.first_tx is None or m.first_tx.kind != KIND_EC:
        return
    ec = m.ec
    k = int(np.searchsorted(ec.idx, m.first_tx.idx))
    first = ec[k] if k < len(ec) and ec.idx[k] == m.first_tx.idx else None
    late = _auto_window_s(m, late_start_ms)
    if first is not None and first.kind == "heartbeat" and (
            first.ts - ctx.start > late + EPS):
        yield (first.ts, f"node {m.node} first appears {first.ts - ctx.start:.3f} s into the "
               f"trace with a heartbeat and no boot-up (limit {late:.3f} s)", first)


def _repeats(m: NodeModel, window: float) -> list[list[EcFrame]]:
    """Runs of 00h frames that follow each other within the window with no reset between."""
    runs: list[list[EcFrame]] = []
    prev: EcFrame | None = None
    resets = m.commands.reset_idx.tolist()
    for b in m.bootups:
        if prev is not None and b.ts - prev.ts <= window + EPS and not any_between(
                resets, prev.idx, b.idx):
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
    `repeat_window_ms` with no reset command to N in between. One finding per run.

    **Why it matters.** 00h is the boot-up message, sent once per Initialisation;
    it is never a periodic heartbeat state. A node that heartbeats 00h is stuck in
    (or pretends to be in) Initialisation, and every master re-starts its boot
    procedure on each one. canopen 2.4.1's LocalNode does exactly this after a
    received reset command.

    **Example.** `000#8102`, then `702#00` every 100 ms for the rest of the trace.
    """
    for run in _repeats(m, _auto_window_s(m, p["repeat_window_ms"])):
        yield (run[1].ts, f"node {m.node} sent boot-up (00h) {len(run)} times in a row over "
               f"{run[-1].ts - run[0].ts:.3f} s without a reset command", run[1])


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
    window = p["reset_window_ms"] / 1000.0
    repeat_ms = ctx.timeline.repeat_window_ms  # B003's: its repeats are left to it
    repeated = {b.pos for run in _repeats(m, _auto_window_s(m, repeat_ms)) for b in run[1:]}
    r_ts, r_idx = m.commands.reset_ts.tolist(), m.commands.reset_idx.tolist()
    unanswered: list[float] = []
    ri = 0
    for b in m.bootups:
        while ri < len(r_idx) and r_idx[ri] < b.idx:
            unanswered.append(r_ts[ri])
            ri += 1
        unanswered = [t for t in unanswered if b.ts - t <= window + EPS]
        if unanswered:
            unanswered.pop(0)
            continue
        if b.pos in repeated:
            continue
        if m.first_tx is not None and m.first_tx.idx < b.idx:
            yield (b.ts, f"node {m.node} sent a boot-up with no reset command before it "
                   f"(spontaneous reboot?)", b)
