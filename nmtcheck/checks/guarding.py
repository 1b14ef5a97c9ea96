"""Node-guarding rules (G): remote request on 700h+N, answer with toggle bit 7 (legacy)."""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

from nmtcheck.checks.base import Param, Problem, count_note, rule, runs
from nmtcheck.timeline import EPS, EcFrame, InputModel, NodeModel, any_between


@rule("G001", "guard-toggle", "error")
def guard_toggle(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """A node-guarding response did not alternate its toggle bit.

    **What it checks.** A guarding response of N has the same toggle bit (bit 7) as
    N's previous response, or the first response after N's boot-up (or a reset
    command to N) has toggle bit 1.

    **Why it matters.** The master treats a response with an unchanged toggle as
    not received (CiA 301 §7.2.8.3.2.1): repeated, the master raises a node-guarding
    event and reacts as if the node were gone.

    **Example.** Responses `705#85`, `705#05`, `705#05`: the third repeats toggle 0.
    """
    for cm in model.channels:
        for m in cm.nodes.values():
            expected: int | None = None
            resets = sorted([c.idx for c in m.commands if c.is_reset])
            ri = 0
            bad: list[tuple[int, EcFrame, str]] = []  # (position, frame, why)
            n = 0
            for f in m.ec:
                while ri < len(resets) and resets[ri] < f.idx:
                    expected = 0
                    ri += 1
                if f.kind == "bootup":
                    expected = 0
                    n += 1  # a boot-up separates runs
                elif f.kind == "guard":
                    n += 1
                    if expected is not None and f.toggle != expected:
                        why = ("first response after boot-up/reset has toggle 1"
                               if expected == 0 and f.value & 0x80 and _first_after_reset(m.ec, f)
                               else f"toggle bit {f.toggle} repeats the previous response's")
                        bad.append((n, f, why))
                    expected = 1 - f.toggle
            # consecutive offending responses within one timeline interval: one finding
            def next_response(a: tuple[int, EcFrame, str], b: tuple[int, EcFrame, str],
                              m: NodeModel = m) -> bool:
                return b[0] == a[0] + 1 and m.interval_index(a[1].ts) == m.interval_index(b[1].ts)

            for run in runs(bad, next_response):
                _n, f, why = run[0]
                yield Problem(cm.name, m.node, f.ts,
                              f"guarding response {f.value:02X}h from node {m.node}: {why}"
                              f"{count_note(len(run), 'responses')}", f.idx, f.line)


def _first_after_reset(ec: list[EcFrame], f: EcFrame) -> bool:
    before = [g for g in ec if g.idx < f.idx and g.kind in ("guard", "bootup")]
    return not before or before[-1].kind == "bootup"


@rule("G002", "guard-no-response", "error",
      Param("response_timeout_ms", float, "how long a guarding request may wait for its answer"))
def guard_no_response(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """A node-guarding request went unanswered.

    **What it checks.** A remote request on 700h+N gets no response from N before the
    next request to N or within `response_timeout_ms`. Time = the next request or
    the request's time + `response_timeout_ms`, whichever is earlier. One finding
    per run of unanswered requests; N is OFFLINE from then until its next frame.

    **Why it matters.** This is the node-guarding event: the master assumes N lost
    and applies its error handling.

    **Example.** `705#R` every 100 ms with no `705#..` data frame in between.
    """
    for cm in model.channels:
        for m in cm.nodes.values():
            for t in m.timeouts:
                if t.rule == "G002":
                    n = f" ({t.requests} requests in a row)" if t.requests > 1 else ""
                    yield Problem(cm.name, m.node, t.moment,
                                  f"no guarding response from node {m.node} to the remote "
                                  f"request at {t.after_ts:.6f}{n}")


@rule("G003", "guard-interval-exceeded", "warning")
def guard_interval_exceeded(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """The master guarded a node less often than the node's life time allows.

    **What it checks.** Guard time (100Ch) and life time factor (100Dh) of N are
    known (network file, EDS/DCF, or written by SDO in the trace) and the interval
    between two guarding requests to N exceeds guard time x life time factor.

    **Why it matters.** N runs its life-guarding timer from the requests: past the
    node life time it raises a life-guarding event (EMCY 8130h, 1029h behaviour)
    although nothing is wrong with N. The master is too slow.

    **Example.** 100Ch = 100 ms, 100Dh = 3: requests 0.5 s apart exceed 0.3 s.
    """
    for cm in model.channels:
        for m in cm.nodes.values():
            resets = sorted([c.idx for c in m.commands if c.is_reset]
                            + [b.idx for b in m.bootups])
            reqs = [f for f in m.ec if f.kind == "request"]

            def life_s(at: float, m: NodeModel = m) -> float | None:
                """Node life time in force at `at` (files, or 100Ch/100Dh written by SDO)."""
                cfg = m.config_at(at)
                if not cfg.guard_time_ms or not cfg.life_time_factor:
                    return None
                return cfg.guard_time_ms * cfg.life_time_factor / 1000.0

            late = []
            for i, (a, b) in enumerate(zip(reqs, reqs[1:], strict=False)):
                life = life_s(a.ts)
                if (life is not None and b.ts - a.ts > life + EPS
                        and not any_between(resets, a.idx, b.idx)):
                    late.append((i, a, b))
            # consecutive late requests within one timeline interval: one finding
            def next_gap(x: tuple[int, EcFrame, EcFrame], y: tuple[int, EcFrame, EcFrame],
                         m: NodeModel = m) -> bool:
                return y[0] == x[0] + 1 and m.interval_index(x[2].ts) == m.interval_index(y[2].ts)

            for run in runs(late, next_gap):
                _i, a, b = run[0]
                cfg = m.config_at(a.ts)
                gt, ltf = cfg.guard_time_ms or 0.0, cfg.life_time_factor or 0
                yield Problem(cm.name, m.node, b.ts,
                              f"guarding requests to node {m.node} {b.ts - a.ts:.3f} s apart "
                              f"(node life time {gt * ltf / 1000.0:.3f} s = {gt:g} ms x {ltf})"
                              f"{count_note(len(run), 'requests')}", b.idx, b.line)


@rule("G004", "guarding-with-heartbeat", "warning")
def guarding_with_heartbeat(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """A node uses node guarding and heartbeat at the same time.

    **What it checks.** Since its last boot-up, N both answers node-guarding
    requests and produces heartbeats.

    **Why it matters.** CiA 301 does not allow both error-control methods at once:
    with 1017h non-zero the heartbeat protocol is used and guarding is off. Stacks
    disagree on which wins, so masters and consumers see different things.

    **Example.** `705#05` every 100 ms and `705#R` answered by `705#85`.
    """
    for cm in model.channels:
        for m in cm.nodes.values():
            seen_hb = seen_guard = False
            reported = False
            for f in m.ec:
                if f.kind == "bootup":
                    seen_hb = seen_guard = reported = False
                elif f.kind in ("heartbeat", "guard"):
                    seen_hb |= f.kind == "heartbeat"
                    seen_guard |= f.kind == "guard"
                    if seen_hb and seen_guard and not reported:
                        reported = True
                        yield Problem(cm.name, m.node, f.ts,
                                      f"node {m.node} answers node guarding and produces "
                                      f"heartbeats", f.idx, f.line)
