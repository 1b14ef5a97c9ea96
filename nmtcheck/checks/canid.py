"""CAN-ID and frame-format rules (C): reserved IDs and malformed NMT / error-control frames."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from nmtcheck.checks.base import Param, Problem, count_note, rule, run_starts, runs
from nmtcheck.model import ChannelModel, EcFrame, EcTable, InputModel, NmtFrame
from nmtcheck.nmt import BOOTUP, GUARD, HEARTBEAT, MALFORMED, STATE_OF_CODE


@rule("C001", "restricted-can-id", "error",
      Param("allow", list, "reserved CAN-IDs that legitimate CiA profiles use (LSS, flying "
                           "master, global fail-safe command)",
            [0x7E4, 0x7E5, 0x071, 0x072, 0x073, 0x074, 0x075, 0x076, 0x001]),
      exempt_from_unknown=True, scope="network")
def restricted_can_id(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
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


@rule("C002", "malformed-nmt-command", "error", scope="network+node")
def malformed_nmt_command(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
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
    def node_of(f: NmtFrame) -> int | None:
        # Only a 2-byte data frame has a node-ID byte; in a frame of the wrong length the
        # second byte addresses nobody, so the finding belongs to the network (node null).
        return f.target if 1 <= f.target <= 127 and not f.rtr and f.dlc == 2 else None

    for cm in model.channels:
        bad = [cm.nmt[i] for i in np.flatnonzero(~cm.nmt.valid).tolist()]

        def same_run(a: NmtFrame, b: NmtFrame, cm: ChannelModel = cm) -> bool:
            n = node_of(a)
            if a.problem != b.problem or n != node_of(b):
                return False
            m = cm.nodes.get(n) if n is not None else None
            return m is None or m.interval_index(a.ts) == m.interval_index(b.ts)

        for run in runs(bad, same_run):
            f = run[0]
            node = node_of(f)
            yield Problem(cm.name, node, f.ts,
                          f"malformed NMT frame: {f.problem}{count_note(len(run))}",
                          f.idx, f.line)


def _ec_runs(model: InputModel, bad: Callable[[EcTable, np.ndarray], np.ndarray]
             ) -> Iterator[tuple[str, int, EcFrame, int]]:
    """Runs of consecutive error-control frames of one node for which `bad` holds,
    each within one timeline interval: (channel, node, first frame, length)."""
    for cm in model.channels:
        for m in cm.nodes.values():
            ec = m.ec
            frames = ec.where(BOOTUP, HEARTBEAT, GUARD, MALFORMED)  # all but requests
            hit = np.flatnonzero(bad(ec, frames))
            if not hit.size:
                continue
            iv = m.interval_indices(ec.ts[frames[hit]])
            join = np.ones(len(hit), bool)
            join[1:] = (hit[1:] == hit[:-1] + 1) & (iv[1:] == iv[:-1])
            for s, n in zip(*run_starts(join), strict=True):
                yield cm.name, m.node, ec[frames[hit[s]]], int(n)


@rule("C003", "malformed-error-control", "error", exempt_from_unknown=True)
def malformed_error_control(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """A frame on 701h-77Fh is not a valid boot-up, heartbeat or guarding response.

    **What it checks.** A data frame on 701h-77Fh has DLC other than 1, or is a
    heartbeat with bit 7 (reserved) set. Remote requests with DLC 0 or 1 are
    normal. Malformed frames are not used as state evidence.

    **Why it matters.** CANopenNode's consumer drops frames with DLC other than 1 and
    Lely's drops heartbeats with bit 7 set: those consumers see a heartbeat
    timeout although the producer is sending.

    **Example.** `703#0500` (DLC 2).
    """
    def bad(ec: EcTable, pos: np.ndarray) -> np.ndarray:
        kind = ec.kind[pos]
        return (kind == MALFORMED) | ((kind == HEARTBEAT) & (ec.value[pos] & 0x80 != 0))

    for channel, node, f, n in _ec_runs(model, bad):
        why = (f"DLC {f.dlc} (must be 1)" if f.kind == "malformed"
               else f"heartbeat {f.value:02X}h has the reserved bit 7 set")
        yield Problem(channel, node, f.ts, f"malformed error-control frame from node {node}: "
                      f"{why}{count_note(n)}", f.idx, f.line)


@rule("C004", "unknown-nmt-state", "warning", exempt_from_unknown=True)
def unknown_nmt_state(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """A heartbeat or guarding response reports a state CiA 301 does not define.

    **What it checks.** The state (bits 0..6) of a heartbeat or guarding response is
    not 00h, 04h, 05h or 7Fh. The node's timeline keeps its previous state.

    **Why it matters.** Legacy DS301 v3 codes (01h-03h) and vendor codes (python
    canopen's 50h/60h) are not understood by CiA 301 consumers, which may treat
    the node as failed.

    **Example.** `703#02` (legacy "pre-operational" of DS301 v3).
    """
    def bad(ec: EcTable, pos: np.ndarray) -> np.ndarray:
        kind = ec.kind[pos]
        return (((kind == HEARTBEAT) | (kind == GUARD))
                & ~np.isin(ec.code[pos], list(STATE_OF_CODE)))

    for channel, node, f, n in _ec_runs(model, bad):
        yield Problem(channel, node, f.ts, f"node {node} reports unknown NMT state "
                      f"{f.code:02X}h{count_note(n)}", f.idx, f.line)
