"""Boot-up rules (B): the boot-up message 700h+N / 00h that ends every Initialisation."""

from __future__ import annotations

import bisect
from collections.abc import Iterator
from typing import Any

import numpy as np

from nmtcheck.checks.base import Param, Problem, rule
from nmtcheck.decode import KIND_EC, KIND_NAMES
from nmtcheck.model import EcFrame, InputModel, NodeModel
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
def missing_bootup(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
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
    timeout = p["bootup_timeout_ms"] / 1000.0
    nodes = [m for cm in model.channels for m in cm.nodes.values()]
    # One pass over the node-frame store answers every reset's "first frame after it".
    queries = [(m.key, t, i) for m in nodes for t, i in zip(
        m.commands.reset_ts.tolist(), m.commands.reset_idx.tolist(), strict=True)]
    answers = iter(model.decoded.first_node_frame_after(queries))
    for cm in model.channels:
        for m in cm.nodes.values():
            cmds, ec = m.commands, m.ec
            rpos = np.flatnonzero(cmds.is_reset)  # plain lists: a log may reset a million times
            r_ts, r_idx = cmds.ts[rpos].tolist(), cmds.idx[rpos].tolist()
            bootups = m.bootups if len(rpos) else []
            boot_idx = [b.idx for b in bootups]
            life = ec.where(HEARTBEAT, GUARD, MALFORMED)  # signs of life but the boot-up
            life = life[~ec.stale[life]]  # a report queued before the reset is none
            life_idx = ec.idx[life]
            sign_at = np.searchsorted(life_idx, cmds.idx[rpos], side="right").tolist()
            for i, (c_ts, c_idx) in enumerate(zip(r_ts, r_idx, strict=True)):
                next_reset = r_idx[i + 1] if i + 1 < len(r_idx) else None
                k = bisect.bisect_right(boot_idx, c_idx)
                boot = bootups[k] if k < len(bootups) else None
                limit_idx = min(x for x in (boot.idx if boot else None, next_reset, 1 << 62)
                                if x is not None)
                k = sign_at[i]
                sign = life[k] if k < len(life) and life_idx[k] < limit_idx else None
                other = next(answers)
                if other is not None and other[1] < limit_idx and (
                        sign is None or other[1] < ec.idx[sign]):
                    yield Problem(cm.name, m.node, other[0],
                                  f"{KIND_NAMES[other[3]]} from node {m.node} "
                                  f"{other[0] - c_ts:.3f} s after {cmds.name(rpos[i])} "
                                  f"without a boot-up", other[1], other[2])
                    continue
                if sign is not None:
                    f = ec[sign]
                    yield Problem(cm.name, m.node, f.ts,
                                  f"{f.kind} from node {m.node} {f.ts - c_ts:.3f} s after "
                                  f"{cmds.name(rpos[i])} without a boot-up", f.idx, f.line)
                    continue
                if next_reset is not None and (boot is None or next_reset < boot.idx) and (
                        r_ts[i + 1] - c_ts <= timeout + EPS):
                    continue  # a newer reset restarts the wait
                if (boot is None or boot.ts - c_ts > timeout + EPS) and (
                        model.end > c_ts + timeout + EPS):
                    yield Problem(cm.name, m.node, c_ts + timeout,
                                  f"no boot-up from node {m.node} within {timeout:.3f} s "
                                  f"after {cmds.name(rpos[i])}")
            # (b) the node was already running when it first appeared, without a boot-up
            if m.first_tx is not None and m.first_tx[2] == KIND_EC:
                k = int(np.searchsorted(ec.idx, m.first_tx[0]))
                first = ec[k] if k < len(ec) and ec.idx[k] == m.first_tx[0] else None
                late = _auto_window_s(m, p["late_start_ms"])
                if first is not None and first.kind == "heartbeat" and (
                        first.ts - model.start > late + EPS):
                    yield Problem(cm.name, m.node, first.ts,
                                  f"node {m.node} first appears {first.ts - model.start:.3f} s "
                                  f"into the trace with a heartbeat and no boot-up "
                                  f"(limit {late:.3f} s)", first.idx, first.line)


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
def bootup_repeated(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
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
    for cm in model.channels:
        for m in cm.nodes.values():
            for run in _repeats(m, _auto_window_s(m, p["repeat_window_ms"])):
                first = run[1]
                yield Problem(cm.name, m.node, first.ts,
                              f"node {m.node} sent boot-up (00h) {len(run)} times in a row "
                              f"over {run[-1].ts - run[0].ts:.3f} s without a reset command",
                              first.idx, first.line)


@rule("B002", "unexpected-bootup", "warning",
      Param("reset_window_ms", float, "how long a reset command explains a later boot-up", 10000.0))
def unexpected_bootup(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
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
    repeat_ms = model.timeline.repeat_window_ms  # B003's: its repeats are left to it
    for cm in model.channels:
        for m in cm.nodes.values():
            repeated = {b.pos for run in _repeats(m, _auto_window_s(m, repeat_ms))
                        for b in run[1:]}
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
                if m.first_tx is not None and m.first_tx[0] < b.idx:
                    yield Problem(cm.name, m.node, b.ts,
                                  f"node {m.node} sent a boot-up with no reset command before it "
                                  f"(spontaneous reboot?)", b.idx, b.line)

