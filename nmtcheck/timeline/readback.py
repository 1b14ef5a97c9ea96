"""Which nodes' compacted error-control runs must be read back whole, once the timeline
is built: `ec_compact` drops the interior of steady runs before any limit is known, and
a run that a rule could tell apart from its summary must not stay dropped.

`unsafe_nodes` names a node whose runs a limit cuts, or that produces heartbeats too; the
channel's master with a run across a command that reaches it
(`_masters_spanning_commands`); and a node with a run inside one of its OFFLINE
intervals (`_runs_while_offline`).
"""

from __future__ import annotations

import numpy as np

from nmtcheck.protocol.nmt import GUARD, HEARTBEAT, OFFLINE, REQUEST, STATES
from nmtcheck.timeline.ec_compact import EPS
from nmtcheck.timeline.model import InputModel


def unsafe_nodes(model: InputModel, tolerance: float, silence_min: float = 0.1) -> set[int]:
    """Node keys whose dropped runs a rule could tell apart: a run that reaches an early
    or timeout limit, leaves the producer-time tolerance, crosses a segment bound or
    a change of configuration, or a node that is guarded too (requests and responses are
    told apart frame by frame); and guarding runs that `_unsafe_guarding` names
    (`silence_min`: the causes' shortest silence on a channel, `[timeline]`)."""
    bad: set[int] = (_unsafe_guarding(model, silence_min) | _masters_spanning_commands(model)
                      | _runs_while_offline(model))
    factor_t, factor_e = model.timeline.timeout_factor, model.timeline.early_factor
    for m in model.nodes():
        runs = m.ec.runs
        if runs is None or not len(runs.pos):
            continue
        ec = m.ec
        a_pos, b_pos = runs.pos - 1, runs.pos
        if (ec.count(REQUEST) or ec.count(GUARD) or ec.guard_runs is not None
                or not bool((ec.kind[a_pos] == HEARTBEAT).all())
                or not bool((ec.kind[b_pos] == HEARTBEAT).all())):
            bad.add(m.key)
            continue
        ta, tb = ec.ts[a_pos], ec.ts[b_pos]
        with np.errstate(invalid="ignore"):
            lim_a = m.hb_timeouts_at(ta, factor_t)
            lim_b = m.hb_timeouts_at(tb, factor_t)
            per_a, per_b = m.periods_at(ta), m.periods_at(tb)
            hb_a = m.config_series(ta, lambda cfg: cfg.heartbeat_ms)
            hb_b = m.config_series(tb, lambda cfg: cfg.heartbeat_ms)
            same = ((lim_a == lim_b) | (np.isnan(lim_a) & np.isnan(lim_b)))
            same &= (per_a == per_b) | (np.isnan(per_a) & np.isnan(per_b))
            same &= (hb_a == hb_b) | (np.isnan(hb_a) & np.isnan(hb_b))
            ok = same & ~(runs.gmax > lim_a + EPS)
            ok &= ~(runs.gmin < factor_e * per_a - EPS)
            conf = hb_a > 0
            c = hb_a / 1000.0
            ok &= ~conf | ((runs.gmax <= c * (1 + tolerance) + EPS)
                           & (runs.gmin >= c * (1 - tolerance) - EPS))
            seg = m.seg_bounds
            seg_a = np.searchsorted(seg, ta, side="right")
            ok &= seg_a == np.searchsorted(seg, tb, side="right")
        # the runs of one span share their value counts: with timestamps that go backwards
        # a bound's time may fall between two of them although its frame does not
        if not bool(ok.all()) or not all(_one_per_span(runs.span, x)
                                          for x in (seg_a, hb_a, lim_a, per_a)):
            bad.add(m.key)
    return bad


def _masters_spanning_commands(model: InputModel) -> set[int]:
    """The channel masters with a dropped run (of either kind) across a valid NMT command
    that reaches them: whether a master obeyed its own broadcast is read from its next
    reports (timeline._master_obeyed), which the run would hide behind later commands.
    The decoder cannot tell a master from a slave; the timeline can."""
    bad: set[int] = set()
    for cm in model.channels:
        m = cm.nodes.get(cm.master.node) if cm.master is not None else None
        if m is None:
            continue
        nmt = cm.nmt
        reach = np.sort(nmt.idx[nmt.valid & ((nmt.target == 0) | (nmt.target == m.node))])
        for runs in (m.ec.runs, m.ec.guard_runs):
            if runs is not None and len(runs.pos) and len(reach):
                a, b = m.ec.idx[runs.pos - 1], m.ec.idx[runs.pos]
                if bool((np.searchsorted(reach, a) != np.searchsorted(reach, b)).any()):
                    bad.add(m.key)
    return bad


def _runs_while_offline(model: InputModel) -> set[int]:
    """Nodes with a dropped run (of either kind) inside one of their OFFLINE intervals:
    the timeline leaves OFFLINE at the first report that is evidence, and a report
    within the obey time after a repeated command that changed nothing is not (it may
    have been queued before the command), so the report that ends it can lie inside a
    run (a master repeating a stop faster than the obey time)."""
    offline = STATES.index(OFFLINE)
    bad: set[int] = set()
    for m in model.nodes():
        iv = m.intervals
        off = iv.state == offline
        if not off.any():
            continue
        lo, hi = iv.start[off], iv.end[off]
        for runs in (m.ec.runs, m.ec.guard_runs):
            if runs is None or not len(runs.pos):
                continue
            a, b = m.ec.ts[runs.pos - 1], m.ec.ts[runs.pos]
            k = np.searchsorted(lo, b, side="left") - 1  # the last one to begin before b
            if bool(((k >= 0) & (hi[np.maximum(k, 0)] > a)).any()):  # (in time order)
                bad.add(m.key)
    return bad


def _unsafe_guarding(model: InputModel, silence_min: float) -> set[int]:
    """Node keys whose dropped guarding runs a rule could tell apart: a node that also
    produces heartbeats (its answers are told from heartbeats by toggle bit and timing),
    a run whose neighbours are not an answer before and a request after, whose longest
    wait reaches the response timeout (G002), or whose longest interval between requests
    exceeds the node life time, or that a change of guard time or life time factor
    divides (G003); or a run with a pause as long as the shortest silence the causes
    report on its channel (max(silence_min, 2 x the shortest heartbeat period there):
    a guarded node has no period of its own to keep its pauses below it)."""
    bad: set[int] = set()
    timeout = model.timeline.response_timeout_s
    silence: dict[int, float] = {}
    for cm in model.channels:
        periods = [o.period_s for o in cm.nodes.values() if o.period_s]
        silence[cm.chan] = max(silence_min, 2 * min(periods)) if periods else np.inf
    for m in model.nodes():
        g = m.ec.guard_runs
        if g is None or not len(g.pos):
            continue
        if bool((g.gmax >= silence.get(m.chan, 0.0) - EPS).any()):
            bad.add(m.key)
            continue
        ec = m.ec
        a, b = g.pos - 1, g.pos
        life_a = m.config_series(ec.ts[a], lambda cfg: cfg.life_time_s)
        life_b = m.config_series(ec.ts[b], lambda cfg: cfg.life_time_s)
        with np.errstate(invalid="ignore"):
            ok = (life_a == life_b) | (np.isnan(life_a) & np.isnan(life_b))
            ok &= ~(g.request_gap > life_a + EPS)
        if (m.kind_counts()[HEARTBEAT] or m.ec.runs is not None or not bool(ok.all())
                or not bool((ec.kind[a] == GUARD).all())
                or not bool((ec.kind[b] == REQUEST).all())
                or bool((g.latency > timeout + EPS).any())):
            bad.add(m.key)
    return bad


def _one_per_span(span: np.ndarray, values: np.ndarray) -> bool:
    """Whether every span's runs have one value (NaN counts as a value)."""
    v = np.where(np.isnan(values), np.inf, values) if values.dtype.kind == "f" else values
    order = np.lexsort((v, span))
    s, v = span[order], v[order]
    return not bool(((s[1:] == s[:-1]) & (v[1:] != v[:-1])).any())
