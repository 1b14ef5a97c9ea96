"""Node-guarding rules (G): remote request on 700h+N, answer with toggle bit 7 (legacy)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import NamedTuple

import numpy as np

from nmtcheck.checks.base import Found, NodeContext, Param, Params, count_note, rule, run_starts
from nmtcheck.protocol.nmt import BOOTUP, EPS, GUARD, HEARTBEAT, REQUEST, between
from nmtcheck.timeline.model import EcTable, NodeModel


@rule("G001", "guard-toggle", "error")
def guard_toggle(m: NodeModel, ctx: NodeContext, p: Params) -> Iterator[Found]:
    """A node-guarding response did not alternate its toggle bit.

    **What it checks.** A guarding response of N has the same toggle bit (bit 7) as
    N's previous response, or the first response after N's boot-up (or a reset
    command to N) has toggle bit 1.

    **Why it matters.** The master treats a response with an unchanged toggle as
    not received (CiA 301 §7.2.8.3.2.1): repeated, the master raises a node-guarding
    event and reacts as if the node were gone.

    **Example.** Responses `705#85`, `705#05`, `705#05`: the third repeats toggle 0.
    """
    if not m.kind_counts()[GUARD]:
        return
    ec = m.ec
    pos = ec.where(GUARD, BOOTUP)  # heartbeats and requests play no part
    bad = _toggle_errors(ec, pos, m.commands.reset_idx,
                         _processed_resets(m, pos, ctx.timeline.obey_s))
    # consecutive offending responses within one timeline interval: one finding
    iv = m.interval_indices(ec.ts[[b.pos for b in bad]])
    number = np.asarray([b.number for b in bad])
    join = np.ones(len(bad), bool)
    join[1:] = (number[1:] == number[:-1] + 1) & (iv[1:] == iv[:-1])
    for s, count in zip(*run_starts(join), strict=True):
        f = ec[bad[s].pos]
        yield (f.ts, f"guarding response {f.value:02X}h from node {m.node}: {bad[s].why}"
               f"{count_note(int(count), 'responses')}", f)


class _BadToggle(NamedTuple):
    number: int  # counts responses and boot-ups alike: a boot-up separates runs
    pos: int  # in the node's EcTable
    why: str


def _processed_resets(m: NodeModel, pos: np.ndarray, obey_s: float) -> np.ndarray | None:
    """Per frame at `pos` (guarding responses and boot-ups), how many reset commands to N
    N had processed before it; None where that is every reset before it in the file (no
    stale response: most nodes).

    A stale response (SPEC §2: within `obey_ms` of the latest command to N, reporting the
    state from before it) left N before N processed that command: a reset command whose
    stale window holds the response (or that is its latest command: a log without
    timestamps) comes after it, so the response keeps the toggle sequence of before the
    reset, and the reset counts for the next response (Lely, CANopenNode: `70N#85` 0.1 ms
    after `000#810N`). What was processed before one frame was before the next too. Time
    that goes back: the running maximum of the commands' times."""
    ec, cmds = m.ec, m.commands
    stale = np.flatnonzero(ec.stale[pos] & (ec.kind[pos] == GUARD))
    if not stale.size or not cmds.is_reset.any():
        return None
    r_idx, r_ts = cmds.reset_idx, cmds.reset_ts
    done = np.searchsorted(r_idx, ec.idx[pos], side="left")
    if m.order_only:  # no time: the stale window is up to the report (`_stale_until`)
        at = ec.idx[pos[stale]]
        latest = cmds.idx[np.maximum(np.searchsorted(cmds.idx, at, side="left") - 1, 0)]
        after = np.searchsorted(r_idx, latest, side="left")
    else:
        after = np.searchsorted(np.maximum.accumulate(r_ts), ec.ts[pos[stale]] - obey_s - EPS,
                                side="left")
    done[stale] = np.minimum(done[stale], after)
    processed: np.ndarray = np.maximum.accumulate(done)
    return processed


def _toggle_errors(ec: EcTable, pos: np.ndarray, resets: np.ndarray,
                   processed: np.ndarray | None = None) -> list[_BadToggle]:
    """The guarding responses among `pos` (responses and boot-ups) whose toggle bit is
    wrong. Each response is judged by the frame before it among `pos` and the reset
    commands between them: after a boot-up or reset it must have toggle 0, after a
    response the other toggle than that response's (the first of all is free).
    `resets`: file positions, in file order (`Commands.reset_idx`). `processed`: per
    frame, the resets N processed before it where stale responses make that fewer than
    those before it in the file (`_processed_resets`)."""
    kind, idx, value = ec.kind[pos], ec.idx[pos], ec.value[pos]
    toggle = (value >> 7).astype(np.int64)
    boot = kind == BOOTUP
    resets_before = (np.searchsorted(resets, idx, side="left") if processed is None
                     else processed)
    reset_between = resets_before > np.concatenate([[0], resets_before[:-1]])
    expected = np.full(len(pos), -1, np.int64)  # -1: anything goes
    expected[1:] = np.where(boot[:-1], 0, 1 - toggle[:-1])
    expected[reset_between] = 0
    bad = np.flatnonzero(~boot & (expected >= 0) & (toggle != expected))
    prev_boot = np.concatenate([[True], boot[:-1]])  # before the first: as after a boot-up
    out = []
    for n in bad.tolist():
        t = int(toggle[n])
        why = ("first response after boot-up/reset has toggle 1"
               if expected[n] == 0 and t == 1 and prev_boot[n]
               else f"toggle bit {t} repeats the previous response's")
        out.append(_BadToggle(n, int(pos[n]), why))
    return out


@rule("G002", "guard-no-response", "error",
      Param("response_timeout_ms", float, "how long a guarding request may wait for its answer",
            1000.0))
def guard_no_response(m: NodeModel, ctx: NodeContext, p: Params) -> Iterator[Found]:
    """A node-guarding request went unanswered.

    **What it checks.** A remote request on 700h+N gets no response from N before the
    next request to N or within `response_timeout_ms`. Time = the next request or
    the request's time + `response_timeout_ms`, whichever is earlier. One finding
    per run of unanswered requests; N is OFFLINE from then until its next frame.

    **Why it matters.** This is the node-guarding event: the master assumes N lost
    and applies its error handling.

    **Example.** `705#R` every 100 ms with no `705#..` data frame in between.
    """
    for t in m.timeouts:
        if t.rule == "G002":
            n = f" ({t.requests} requests in a row)" if t.requests > 1 else ""
            yield (t.moment, f"no guarding response from node {m.node} to the remote request "
                   f"at {t.after_ts - ctx.start:.6f} s{n}", t)


@rule("G003", "guard-interval-exceeded", "warning")
def guard_interval_exceeded(m: NodeModel, ctx: NodeContext, p: Params) -> Iterator[Found]:
    """The master guarded a node less often than the node's life time allows.

    **What it checks.** Guard time (100Ch) and life time factor (100Dh) of N are
    known (network file, EDS/DCF, or written by SDO in the trace) and the interval
    between two guarding requests to N exceeds guard time x life time factor.

    **Why it matters.** N runs its life-guarding timer from the requests: past the
    node life time it raises a life-guarding event (EMCY 8130h, 1029h behaviour)
    although nothing is wrong with N. The master is too slow.

    **Example.** 100Ch = 100 ms, 100Dh = 3: requests 0.5 s apart exceed 0.3 s.
    """
    if m.kind_counts()[REQUEST] < 2:
        return
    ec = m.ec
    resets = np.sort(np.concatenate([m.commands.reset_idx, ec.idx[ec.kind == BOOTUP]]))
    reqs = ec.where(REQUEST)
    a, b = reqs[:-1], reqs[1:]
    # node life time in force at each request (files, or 100Ch/100Dh written by SDO)
    life = m.config_series(ec.ts[a], lambda cfg: cfg.life_time_s)
    apart = ec.ts[b] - ec.ts[a]
    for gap in ctx.channel.recording_gaps:  # (SPEC §3 I007) counted again from its end
        cut = (ec.ts[a] <= gap.start + EPS) & (ec.ts[b] >= gap.end - EPS)
        apart = np.where(cut, np.maximum(gap.start - ec.ts[a], ec.ts[b] - gap.end), apart)
    late = (apart > life + EPS) & ~between(resets, ec.idx[a], ec.idx[b])
    if ec.guard_runs is not None:  # a long log: a dropped run between two kept requests
        late &= ~np.isin(b, ec.guard_runs.pos)  # lies within the life time (ec_compact);
    late = np.flatnonzero(late)  # its pair keeps its place, so the pairs around stay apart
    # consecutive late requests within one timeline interval: one finding
    iv = m.interval_indices(ec.ts[b[late]])
    join = np.ones(len(late), bool)
    join[1:] = (late[1:] == late[:-1] + 1) & (iv[1:] == iv[:-1])
    for s, count in zip(*run_starts(join), strict=True):
        fa, fb = ec[a[late[s]]], ec[b[late[s]]]
        cfg = m.config_at(fa.ts)
        gt, ltf = cfg.guard_time_ms or 0.0, cfg.life_time_factor or 0
        yield (fb.ts, f"guarding requests to node {m.node} {fb.ts - fa.ts:.3f} s apart (node "
               f"life time {gt * ltf / 1000.0:.3f} s = {gt:g} ms x {ltf})"
               f"{count_note(int(count), 'requests')}", fb)


@rule("G004", "guarding-with-heartbeat", "warning")
def guarding_with_heartbeat(m: NodeModel, ctx: NodeContext, p: Params) -> Iterator[Found]:
    """A node uses node guarding and heartbeat at the same time.

    **What it checks.** Since its last boot-up, N both answers node-guarding
    requests and produces heartbeats, with no confirmed SDO write of 1017h between
    them (a master that switches N from heartbeat to guarding writes 1017h = 0).

    **Why it matters.** CiA 301 does not allow both error-control methods at once:
    with 1017h non-zero the heartbeat protocol is used and guarding is off. Stacks
    disagree on which wins, so masters and consumers see different things.

    **Example.** `705#05` every 100 ms and `705#R` answered by `705#85`.
    """
    k = m.kind_counts()
    if not k[HEARTBEAT] or not k[GUARD]:
        return
    ec = m.ec
    hb, guard = ec.where(HEARTBEAT), ec.where(GUARD)
    # per stretch between boot-ups and confirmed 1017h writes (a master switching N from
    # heartbeat to guarding writes 1017h = 0 first): the first frame by which N did both
    cuts = np.sort(np.concatenate([ec.idx[ec.where(BOOTUP)],
                                   m.writes.idx[m.writes.index == 0x1017]]))
    seg_hb, first_hb = np.unique(np.searchsorted(cuts, ec.idx[hb]), return_index=True)
    seg_guard, first_guard = np.unique(np.searchsorted(cuts, ec.idx[guard]),
                                       return_index=True)
    _both, i_hb, i_guard = np.intersect1d(seg_hb, seg_guard, return_indices=True)
    for p_ in np.maximum(hb[first_hb[i_hb]], guard[first_guard[i_guard]]).tolist():
        f = ec[p_]
        yield f.ts, f"node {m.node} answers node guarding and produces heartbeats", f
