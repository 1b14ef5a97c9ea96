"""CAN-ID and frame-format rules (C): reserved IDs and malformed NMT / error-control frames."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from nmtcheck.checks.base import (
    Found,
    NodeContext,
    Param,
    Params,
    Problem,
    Problems,
    count_note,
    input_rule,
    rule,
    run_starts,
)
from nmtcheck.protocol.nmt import BOOTUP, GUARD, HEARTBEAT, MALFORMED, STATE_OF_CODE, is_one_of
from nmtcheck.timeline.model import (
    ChannelModel,
    EcFrame,
    EcTable,
    InputModel,
    NmtTable,
    NodeModel,
    known_cs,
)


@input_rule("C001", "restricted-can-id", "error",
            Param("allow", list, "reserved CAN-IDs that legitimate CiA profiles use (LSS, "
                  "flying master, global fail-safe command)",
                  [0x7E4, 0x7E5, 0x071, 0x072, 0x073, 0x074, 0x075, 0x076, 0x001]),
            exempt_from_unknown=True, scope="network")
def restricted_can_id(model: InputModel, p: Params) -> Iterator[Problem]:
    """An 11-bit frame uses a CAN-ID that CiA 301 reserves.

    **What it checks.** Any 11-bit frame on 001h-07Fh, 101h-180h, 6E0h-6FFh or
    780h-7FFh (780h is 1920 decimal), except the IDs in `allow`. One finding per
    CAN-ID and channel, at its first use, with the number of frames.

    **Why it matters.** Table 40 reserves these IDs so that configurable COBs
    never collide with NMT, SYNC, LSS, SRDO or future services. A device using
    one is misconfigured and may collide with a device that uses it correctly.

    **Example.** `123#00` sits in the reserved 101h-180h range.
    """
    allow = {int(x) for x in p["allow"]}
    names = [cm.name for cm in model.channels]
    for (chan, can_id), use in sorted(model.decoded.restricted.items(),
                                      key=lambda kv: kv[1].first_idx):
        if can_id in allow or chan >= len(names):
            continue
        yield Problem(names[chan], None, use.first_ts,
                      f"CAN-ID {can_id:03X}h is reserved by CiA 301{count_note(use.count)}",
                      use.first_idx, use.first_line)


@input_rule("C002", "malformed-nmt-command", "error", scope="network+node")
def malformed_nmt_command(model: InputModel, p: Params) -> Iterator[Problems]:
    """A frame on CAN-ID 000h is not a valid NMT module-control command.

    **What it checks.** A frame on CAN-ID 0 is a remote frame, has DLC other than 2,
    an unknown command specifier, or a node-ID above 127. Such a frame is not
    applied to any node's state. A 2-byte frame (unknown command specifier) is
    attributed to the node its second byte names; frames of the wrong length or
    remote frames belong to the network (node null). Consecutive frames with the
    same defect for the same node (within one of its timeline intervals) give one
    finding with their count.

    **Why it matters.** Stacks disagree on such frames: CANopenNode drops any DLC
    other than 2, Lely accepts longer ones, python-canopen raises on shorter ones.
    Part of the network obeys, the rest does not.

    **Example.** `000#0105000000000000` (DLC 8).
    """
    for cm in model.channels:
        yield from _malformed_runs(cm)


C002_CHUNK = 1 << 20  # NMT frames looked at together: a log may hold nothing else


@dataclass
class _Run:
    """A run of malformed NMT frames with one defect for one node: where it starts, its
    length, and what the next frame must share to continue it."""

    at: int
    length: int
    node: int
    same: tuple[int, int, int]  # defect, its value, the node's timeline interval


def _malformed_runs(cm: ChannelModel) -> Iterator[Problems]:
    """C002's runs on one channel, a chunk of frames at a time; a run may go on across
    chunks, so the last run of each chunk waits for the next."""
    nmt = cm.nmt
    pending: _Run | None = None
    for lo in range(0, len(nmt), C002_CHUNK):
        bad = lo + np.flatnonzero(~nmt.valid[lo:lo + C002_CHUNK])
        if not bad.size:
            continue
        rtr, dlc, cs, target = nmt.rtr[bad], nmt.dlc[bad], nmt.cs[bad], nmt.target[bad]
        # the defect, as nmt_problem names it: (what, value); its text differs iff these do
        what = np.where(rtr, 0, np.where(dlc != 2, 1, np.where(~known_cs(cs), 2, 3)))
        what = what.astype(np.int8)
        value = np.select([what == 0, what == 1, what == 2], [0, dlc, cs], target)
        # Only a 2-byte data frame has a node-ID byte; in a frame of the wrong length the
        # second byte addresses nobody, so the finding belongs to the network (node -1).
        node = np.where((target >= 1) & (target <= 127) & ~rtr & (dlc == 2),
                        target.astype(np.int16), np.int16(-1))
        interval = np.full(len(bad), -1, np.int64)  # a run stays within one interval
        for n in np.unique(node[node >= 0]).tolist():
            m = cm.nodes.get(n)
            if m is not None:
                sel = node == n
                interval[sel] = m.interval_indices(nmt.ts[bad[sel]])
        join = np.ones(len(bad), bool)
        join[1:] = ((what[1:] == what[:-1]) & (value[1:] == value[:-1])
                    & (node[1:] == node[:-1]) & (interval[1:] == interval[:-1]))
        first, length = run_starts(join)
        at, nodes = bad[first], node[first].astype(np.int64)
        if pending is not None and pending.same == (int(what[0]), int(value[0]),
                                                    int(interval[0])) and (
                pending.node == int(node[0])):
            pending.length += int(length[0])  # the first run goes on from the last chunk
            at, length, nodes = at[1:], length[1:], nodes[1:]
        if pending is not None and len(at):
            at = np.concatenate([[pending.at], at])
            length = np.concatenate([[pending.length], length])
            nodes = np.concatenate([[pending.node], nodes])
            pending = None
        if len(at):
            last = int(first[-1]) if len(first) else 0
            pending = _Run(int(at[-1]), int(length[-1]), int(nodes[-1]),
                           (int(what[last]), int(value[last]), int(interval[last])))
            yield from _c002_batch(cm.name, nmt, at[:-1], length[:-1], nodes[:-1])
    if pending is not None:
        yield from _c002_batch(cm.name, nmt, np.asarray([pending.at]),
                               np.asarray([pending.length]), np.asarray([pending.node]))


def _c002_batch(channel: str, nmt: NmtTable, at: np.ndarray, length: np.ndarray,
                nodes: np.ndarray) -> Iterator[Problems]:
    if not len(at):
        return

    def message(i: int) -> str:
        return f"malformed NMT frame: {nmt[int(at[i])].problem}{count_note(int(length[i]))}"

    yield Problems(channel, None, nmt.ts[at], message, nmt.idx[at], nmt.line[at], nodes=nodes)


def _ec_runs(m: NodeModel, bad: Callable[[EcTable, np.ndarray], np.ndarray]
             ) -> Iterator[tuple[EcFrame, int]]:
    """Runs of consecutive error-control frames of the node for which `bad` holds,
    each within one timeline interval: (first frame, length)."""
    ec = m.ec
    frames = ec.where(BOOTUP, HEARTBEAT, GUARD, MALFORMED)  # all but requests
    hit = np.flatnonzero(bad(ec, frames))
    if not hit.size:
        return
    iv = m.interval_indices(ec.ts[frames[hit]])
    join = np.ones(len(hit), bool)
    join[1:] = (hit[1:] == hit[:-1] + 1) & (iv[1:] == iv[:-1])
    for s, n in zip(*run_starts(join), strict=True):
        yield ec[frames[hit[s]]], int(n)


@rule("C003", "malformed-error-control", "error", exempt_from_unknown=True)
def malformed_error_control(m: NodeModel, ctx: NodeContext, p: Params) -> Iterator[Found]:
    """A frame on 701h-77Fh is not a valid boot-up, heartbeat or guarding response.

    **What it checks.** A data frame on 701h-77Fh has DLC other than 1, or is a
    heartbeat with bit 7 (reserved) set. Remote requests with DLC 0 or 1 are
    normal. Malformed frames are not used as state evidence.

    **Why it matters.** CANopenNode's consumer drops frames with DLC other than 1 and
    Lely's drops heartbeats with bit 7 set: those consumers see a heartbeat
    timeout although the producer is sending.

    **Example.** `703#0500` (DLC 2).
    """
    k = m.kind_counts()
    if not k[MALFORMED] and not k[HEARTBEAT]:
        return
    if m.small is not None and not any(v & 0x80 for v in m.small.value):
        return  # a small node (no malformed frame): no heartbeat with bit 7 set
    for f, n in _ec_runs(m, _malformed):
        why = (f"DLC {f.dlc} (must be 1)" if f.kind == "malformed"
               else f"heartbeat {f.value:02X}h has the reserved bit 7 set")
        yield f.ts, f"malformed error-control frame from node {m.node}: {why}{count_note(n)}", f


def _malformed(ec: EcTable, pos: np.ndarray) -> np.ndarray:
    kind = ec.kind[pos]
    bad: np.ndarray = (kind == MALFORMED) | ((kind == HEARTBEAT) & (ec.value[pos] & 0x80 != 0))
    return bad


@rule("C004", "unknown-nmt-state", "warning", exempt_from_unknown=True)
def unknown_nmt_state(m: NodeModel, ctx: NodeContext, p: Params) -> Iterator[Found]:
    """A heartbeat or guarding response reports a state CiA 301 does not define.

    **What it checks.** The state (bits 0..6) of a heartbeat or guarding response is
    not 00h, 04h, 05h or 7Fh. The node's timeline keeps its previous state.

    **Why it matters.** Legacy DS301 v3 codes (01h-03h) and vendor codes (python
    canopen's 50h/60h) are not understood by CiA 301 consumers, which may treat
    the node as failed.

    **Example.** `703#02` (legacy "pre-operational" of DS301 v3).
    """
    k = m.kind_counts()
    if not k[HEARTBEAT] and not k[GUARD]:
        return
    if m.small is not None and all(  # a small node: boot-ups and known states only
            k == BOOTUP or (v & 0x7F) in STATE_OF_CODE
            for k, v in zip(m.small.kind, m.small.value, strict=True)):
        return
    for f, n in _ec_runs(m, _unknown_state):
        yield f.ts, f"node {m.node} reports unknown NMT state {f.code:02X}h{count_note(n)}", f


def _unknown_state(ec: EcTable, pos: np.ndarray) -> np.ndarray:
    kind = ec.kind[pos]
    bad: np.ndarray = (((kind == HEARTBEAT) | (kind == GUARD))
                       & ~is_one_of(ec.code[pos], list(STATE_OF_CODE)))
    return bad
