"""Network rules (N): the expected nodes and node-ID conflicts."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

from nmtcheck.checks.base import Problem, rule
from nmtcheck.timeline import EPS, EcFrame, InputModel, any_between, state_name


@rule("N001", "missing-node", "error", exempt_from_unknown=True)
def missing_node(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """A node of the network description never transmitted.

    **What it checks.** A node listed in the network file (`--network`) never
    transmits on a channel it is expected on: every channel of the trace, unless
    its table names one. One finding per node and channel, at the trace's first
    frame.

    **Why it matters.** A missing node is the most basic integration failure:
    unpowered, wrong node-ID, wrong bit rate, or wiring.

    **Example.** `[nodes.8]` in the network file and no frame from node 8.
    """
    names = [cm.name for cm in model.channels]
    first = model.decoded.first_frame_at_or_after([model.start])[0] if model.expected else None
    line = first[1] if first is not None and first[0] == 0 else None  # frame 0's line
    for node, channel in model.expected:
        for name in [channel] if channel is not None else names:
            cm = next((c for c in model.channels if c.name == name), None)
            m = cm.nodes.get(node) if cm is not None else None
            if m is None or m.first_tx is None:
                yield Problem(name, node, model.start,
                              f"node {node} is in the network description but never transmits "
                              f"on {name}", 0, line)


def _segments(frames: list[EcFrame], cmd_idx: list[int]) -> Iterator[list[EcFrame]]:
    """Heartbeats split at boot-ups and NMT commands."""
    seg: list[EcFrame] = []
    marks = sorted(cmd_idx)
    for f in frames:
        if f.kind == "bootup" or (seg and any_between(marks, seg[-1].idx, f.idx)):
            if len(seg) > 1:
                yield seg
            seg = []
        if f.kind == "heartbeat":
            seg.append(f)
    if len(seg) > 1:
        yield seg


@rule("N002", "duplicate-node-id", "warning")
def duplicate_node_id(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """Two devices seem to share one node-ID.

    **What it checks.** Within N's heartbeats the reported state goes A, B, A, B with
    no NMT command to N or boot-up in between, or over at least 4 consecutive
    intervals N's heartbeat intervals alternate short/long with long >= 1.5 x short.
    One finding per node, at the first evidence.

    **Why it matters.** Two devices with the same node-ID collide on every COB-ID of
    the pre-defined set: SDOs get two answers, PDOs mix, and the heartbeat shows
    whichever device spoke last.

    **Example.** `705#05`, `705#7F`, `705#05`, `705#7F` at 50 ms spacing.
    """
    for cm in model.channels:
        for m in cm.nodes.values():
            hit: tuple[EcFrame, str] | None = None
            for seg in _segments(m.ec, [c.idx for c in m.commands]):
                codes = [f.code for f in seg]
                for i in range(len(seg) - 3):
                    a, b = codes[i], codes[i + 1]
                    if a != b and codes[i + 2] == a and codes[i + 3] == b:
                        hit = hit or (seg[i + 3], f"its heartbeat alternates between "
                                      f"{state_name(a)} and {state_name(b)}")
                        break
                gaps = [y.ts - x.ts for x, y in zip(seg, seg[1:], strict=False)]
                for i in range(len(gaps) - 3):
                    w = gaps[i:i + 4]
                    if min(w) <= 0:
                        continue
                    steps = ["L" if w[k] >= 1.5 * w[k + 1] - EPS
                             else "S" if w[k + 1] >= 1.5 * w[k] - EPS
                             else "" for k in range(3)]
                    alt = all(steps) and steps[0] == steps[2] != steps[1]
                    if alt:
                        f = seg[i + 4]
                        if hit is None or f.idx < hit[0].idx:
                            hit = (f, "its heartbeat intervals alternate short/long "
                                      f"({', '.join(f'{x:.3f}' for x in w)} s)")
                        break
            if hit is not None:
                f, why = hit
                yield Problem(cm.name, m.node, f.ts,
                              f"node-ID {m.node} may be used by two devices: {why}",
                              f.idx, f.line)
