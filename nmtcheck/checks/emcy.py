"""EMCY rules E001-E003 (SPEC §9.2.3): each node's EMCYs of `nmtcheck/processes/emcy.py`
judged. They judge frames, not a state: exempt from the UNKNOWN rule.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from nmtcheck.checks.base import Param, Params, Problem, flagged_runs, input_rule
from nmtcheck.checks.bus_wait import bus_waits
from nmtcheck.processes import emcy as emcy_stage
from nmtcheck.processes.emcy import EmcyNode
from nmtcheck.protocol import emcy
from nmtcheck.timeline.model import InputModel
from nmtcheck.timeline.moments import at

EPS = 1e-9
MAX_CODES_LISTED = 10  # E003's message names this many codes, then counts the rest


def _nodes(model: InputModel) -> Iterator[EmcyNode]:
    analysis = emcy_stage.of(model)
    if analysis is not None:
        yield from analysis.nodes.values()


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """(first, length) of each run of equal non-zero values."""
    same = np.zeros(len(flags), bool)
    same[1:] = flags[1:] == flags[:-1]
    return flagged_runs(same, flags != 0)


@input_rule("E001", "emcy-inhibit-violation", "warning", exempt_from_unknown=True, scope="node")
def emcy_inhibit_violation(model: InputModel, params: Params) -> Iterator[Problem]:
    """Two EMCYs of a node closer than its EMCY inhibit time (1015h).

    **What it checks.** Consecutive EMCYs F1, F2 of node N with t(F2) - t(F1) shorter
    than 1015h x 100 us less the timestamp resolution and less the time F1 may have
    waited for the bus (a back-to-back run of frames before it), with no boot-up or reset
    of N and no confirmed write of its 1015h between them. 1015h comes from a confirmed
    SDO write in the trace, else `[nodes.N] emcy_inhibit_100us`, else N's device file.
    One finding per run of violating pairs, at the first F2.

    **Why it matters.** CANopenNode and Lely queue EMCYs until the inhibit time has
    passed, so a shorter spacing on the bus is the device's own: it floods the bus with
    EMCYs its configuration says it holds back.

    **Example.** `emcy_inhibit_100us = 100` (10 ms): `085#1023...` at 10.010 and
    `085#0000...` at 10.012.
    """
    analysis = emcy_stage.of(model)
    r = analysis.resolution_s if analysis is not None else 1e-6
    for e in _nodes(model):
        if len(e) < 2:
            continue
        limit = e.inhibit[1:] * 1e-4  # NaN: unknown; 0: none
        dt = np.diff(e.ts)
        cleared = np.searchsorted(e.clears, e.ts[1:], side="left") != np.searchsorted(
            e.clears, e.ts[:-1], side="right")
        rewritten = e.inhibit_line[1:] != e.inhibit_line[:-1]
        bad = (limit > 0) & (dt < limit - r - EPS) & ~cleared & ~rewritten
        if bad.any():  # less the time F1 may have waited for the bus (q, §9.1.6)
            cm = next(c for c in model.channels if c.name == e.channel)
            close = np.flatnonzero(bad)
            bad[close] = dt[close] < limit[close] - r - bus_waits(model, cm, e.idx[close]) - EPS
        flags = np.append(0, bad.astype(np.int8))
        for k, n in _runs(flags):
            i = float(e.inhibit[k])
            yield Problem(e.channel, e.node, float(e.ts[k]),
                          f"EMCY {int(e.code[k]):04X}h of node {e.node} "
                          f"{(e.ts[k] - e.ts[k - 1]) * 1000:.3f} ms after the previous one "
                          f"(line {int(e.line[k - 1])}); inhibit time 1015h = {i:g} x 100 us "
                          f"= {i / 10:g} ms ({e.inhibit_source(k)})"
                          + (f" ({n} EMCYs)" if n > 1 else ""),
                          int(e.idx[k]), int(e.line[k]))


@input_rule("E002", "emcy-malformed", "warning",
            Param("require_generic_bit", bool, "also report an error code of 0100h or more "
                  "whose error register has bit 0 (generic) clear", False),
            exempt_from_unknown=True, scope="node")
def emcy_malformed(model: InputModel, params: Params) -> Iterator[Problem]:
    """An EMCY frame of a length other than 8, or a remote frame on an EMCY COB-ID.

    **What it checks.** An EMCY of node N (80h + N) that is (a) a remote frame, (b) of
    DLC other than 8, or, with `require_generic_bit`, (c) an error code of 0100h or more
    with error-register bit 0 clear. One finding per run of consecutive EMCYs of N with
    one defect.

    **Why it matters.** All three stacks send 8 bytes; CanFestival consumers drop an
    EMCY of another length, Lely decodes what is there. (c) is off by default:
    CANopenNode sets bit 0 only for its generic-critical errors, although CiA 301 (as
    Lely quotes it) asks for it at every error.

    **Example.** `085#1023`: DLC 2.
    """
    generic = bool(params["require_generic_bit"])
    for e in _nodes(model):
        for k in range(len(e.rtr_ts)):
            yield Problem(e.channel, e.node, float(e.rtr_ts[k]),
                          f"remote frame on the EMCY COB-ID {e.cob_id:03X}h of node {e.node}",
                          int(e.rtr_idx[k]), int(e.rtr_line[k]))
        flags = np.where(e.dlc != 8, 1, 0).astype(np.int16)
        if generic:
            flags[(flags == 0) & (e.code >= 0x100) & ((e.register & 1) == 0)] = 2
        # a run of one DLC: a new DLC is a new defect
        flags = np.where(flags == 1, 100 + e.dlc.astype(np.int16), flags)
        for k, n in _runs(flags):
            if flags[k] == 2:
                text = (f"EMCY {int(e.code[k]):04X}h with error register "
                        f"{int(e.register[k]):02X}h: bit 0 (generic) clear")
            else:
                dlc = int(e.dlc[k])
                text = (f"EMCY of node {e.node} with DLC {dlc}, 8 expected (CanFestival "
                        "consumers drop it)")
            yield Problem(e.channel, e.node, float(e.ts[k]),
                          text + (f" ({n} frames)" if n > 1 else ""), int(e.idx[k]),
                          int(e.line[k]))


@input_rule("E003", "emcy-active-at-end", "info", exempt_from_unknown=True, scope="node")
def emcy_active_at_end(model: InputModel, params: Params) -> Iterator[Problem]:
    """A node is still in error at the end of the trace.

    **What it checks.** Node N's latest EMCY has an error code of 0100h or more, or is an
    error reset (below 0100h) whose error register is not 00h, and no boot-up or reset of
    N follows it. Once per node, at that EMCY.

    **Why it matters.** A device that reported an error and never its reset is still in
    error when the recording stops: the log brought back from the field ends in a fault,
    whatever else it shows.

    **Example.** `085#3081101B00000000` (8130h, CANopenNode's heartbeat consumer) with no
    reset after it.
    """
    for e in _nodes(model):
        if not e.in_error_at_end():
            continue
        pos = np.flatnonzero(e.dlc >= 2)
        k = int(pos[-1])
        since = [j for j in e.since_clear(k).tolist() if e.dlc[j] >= 2]
        codes = list(dict.fromkeys(f"{int(e.code[j]):04X}h" for j in since))
        if len(codes) > MAX_CODES_LISTED:
            codes = [*codes[:MAX_CODES_LISTED], f"and {len(codes) - MAX_CODES_LISTED} more"]
        register = f", error register {int(e.register[k]):02X}h" if e.dlc[k] >= 3 else ""
        detail = emcy.canopennode_detail(e.data_bytes(k), int(e.dlc[k]))
        meaning = e.describe(k).split(",")[0]
        if detail is not None:
            meaning += f" (CANopenNode: {detail['meaning']})"
        yield Problem(e.channel, e.node, float(e.ts[k]),
                      f"node {e.node} still in error at the end of the trace: last {meaning} "
                      f"at {at(float(e.ts[k]), model.start, model.timeline.order_only)} "
                      f"(line {int(e.line[k])}){register}; "
                      f"codes since the last full reset: {', '.join(codes)}",
                      int(e.idx[k]), int(e.line[k]))
