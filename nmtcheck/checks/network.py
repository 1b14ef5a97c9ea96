"""Network rules (N): the expected nodes and node-ID conflicts."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from nmtcheck.checks.base import Found, NodeContext, Params, Problem, input_rule, rule
from nmtcheck.protocol.nmt import BOOTUP, EPS, HEARTBEAT, between, state_name
from nmtcheck.timeline.model import EcFrame, InputModel, NodeModel


@input_rule("N001", "missing-node", "error", exempt_from_unknown=True, scope="node")
def missing_node(model: InputModel, p: Params) -> Iterator[Problem]:
    """A node of the network description never transmitted.

    **What it checks.** A node listed in the network file (`--network`) never
    transmits on a channel it is expected on: every channel of the trace, unless
    its table names one. One finding per node and channel, at the trace's first
    frame.

    **Why it matters.** A missing node is the most basic integration failure:
    unpowered, wrong node-ID, wrong bit rate, or wiring.

    **Example.** `[nodes.8]` in the network file and no frame from node 8.
    """
    # the input's channels by their logged names (`--channel` may have left out some)
    stats = model.stats
    logged = ({stats.log_channel(c) for c in stats.channels} if stats is not None
              else {cm.network_name for cm in model.channels})
    first = model.decoded.first_frame_at_or_after([model.start])[0] if model.expected else None
    line = first.line if first is not None and first.idx == 0 else None  # frame 0's line
    for node, channel in model.expected:
        # a channel of the files is also each of its later captures' (nmtcheck/readers/captures.py)
        on = [c for c in model.channels if channel is None or c.network_name == channel]
        if channel is not None and channel not in logged:  # the log does not have it
            yield Problem(channel, node, model.start, f"node {node} is in the network "
                          f"description but never transmits on {channel}", 0, line)
        for cm in on:
            m = cm.nodes.get(node)
            if m is None or m.first_tx is None:
                at = (0, line) if not cm.first_index else (cm.first_index, cm.first_line)
                yield Problem(cm.name, node, cm.start,
                              f"node {node} is in the network description but never transmits "
                              f"on {cm.name}", *at)


@rule("N002", "duplicate-node-id", "warning")
def duplicate_node_id(m: NodeModel, ctx: NodeContext, p: Params) -> Iterator[Found]:
    """Two devices seem to share one node-ID.

    **What it checks.** Within N's heartbeats the reported state goes A, B, A, B with
    no NMT command to N or boot-up in between (reports queued before a command do
    not count), or over at least 4 consecutive intervals N's heartbeat intervals
    alternate short/long with long >= 1.5 x short, the shorts within 20 % of each
    other and the longs too: two producers with one period, out of phase. A late
    heartbeat and its early catch-up (a fixed-rate producer after a stall) is not
    this. One finding per node, at the first evidence.

    **Why it matters.** Two devices with the same node-ID collide on every COB-ID of
    the pre-defined set: SDOs get two answers, PDOs mix, and the heartbeat shows
    whichever device spoke last.

    **Example.** `705#05`, `705#7F`, `705#05`, `705#7F` at 50 ms spacing.
    """
    hit = _duplicate_evidence(m)
    if hit is not None:
        f, why = hit
        yield f.ts, f"node-ID {m.node} may be used by two devices: {why}", f


def _duplicate_evidence(m: NodeModel) -> tuple[EcFrame, str] | None:
    """The first frame of N's heartbeats that shows two devices, vectorised over segments
    of heartbeats (split at boot-ups and NMT commands to N); at equal frames the state
    alternation wins."""
    ec = m.ec
    hb = ec.where(HEARTBEAT)
    hb = hb[~ec.stale[hb]]  # reports queued before a command are no evidence
    if len(hb) < 4:
        return None
    boots = ec.where(BOOTUP)
    cmd_idx = m.commands.idx
    cut = np.zeros(len(hb), bool)
    cut[1:] = (np.searchsorted(boots, hb[1:]) != np.searchsorted(boots, hb[:-1])) | between(
        cmd_idx, ec.idx[hb[:-1]], ec.idx[hb[1:]])
    seg = np.cumsum(cut)
    code = ec.code[hb]
    ts = ec.ts[hb]
    found: list[tuple[int, int, str]] = []  # (frame position, preference, why)
    # the state pattern: consecutive repeats of one state count once (A, A, B, A, B, B)
    first = np.ones(len(hb), bool)
    first[1:] = (code[1:] != code[:-1]) | (seg[1:] != seg[:-1])
    runs = np.flatnonzero(first)
    rc, rs = code[runs], seg[runs]
    a, b, c, d = rc[:-3], rc[1:-2], rc[2:-1], rc[3:]
    alt = np.flatnonzero((a != b) & (c == a) & (d == b) & (rs[:-3] == rs[3:]))
    if alt.size:
        i = int(alt[0])
        found.append((int(hb[runs[i + 3]]), 0, f"its heartbeat alternates between "
                      f"{state_name(int(a[i]))} and {state_name(int(b[i]))}"))
    if len(hb) >= 5 and not m.order_only:  # intervals of frame numbers mean nothing
        g = np.diff(ts)
        if ec.runs is not None:  # a dropped run's pair: one of its (steady) intervals
            r = ec.runs.at_rows(hb[1:])
            g[r >= 0] = ec.runs.first[r[r >= 0]]
        w = [g[k:len(g) - 3 + k] for k in range(4)]  # windows of four consecutive gaps
        longer = [w[k] >= 1.5 * w[k + 1] - EPS for k in range(3)]
        shorter = [~longer[k] & (w[k + 1] >= 1.5 * w[k] - EPS) for k in range(3)]
        ok = (np.minimum.reduce(w) > 0) & (seg[:-4] == seg[4:])
        ok &= (longer[0] | shorter[0]) & (longer[1] | shorter[1]) & (longer[2] | shorter[2])
        ok &= (longer[0] == longer[2]) & (longer[0] != longer[1])
        # the shorts alike and the longs alike (within 20 %): two producers with one period,
        # not one late heartbeat and its catch-up
        ok &= (np.maximum(w[0], w[2]) <= 1.2 * np.minimum(w[0], w[2]) + EPS)
        ok &= (np.maximum(w[1], w[3]) <= 1.2 * np.minimum(w[1], w[3]) + EPS)
        alt = np.flatnonzero(ok)
        if alt.size:
            i = int(alt[0])
            found.append((int(hb[i + 4]), 1, "its heartbeat intervals alternate short/long "
                          f"({', '.join(f'{x[i]:.3f}' for x in w)} s)"))
    if not found:
        return None
    pos, _pref, why = min(found)
    return ec[pos], why
