"""Node-guarding rules G001 (guard-toggle), G002 (guard-no-response),
G003 (guard-interval-exceeded), G004 (guarding-with-heartbeat)."""

from __future__ import annotations

import random
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from conftest import Checker, candump
from traces import HEALTHY_NET, hb, healthy, profile

from nmtcheck.checks.guarding import _BadToggle
from nmtcheck.protocol.nmt import BOOTUP, EPS, GUARD, HEARTBEAT, REQUEST
from nmtcheck.timeline.model import TimelineParams


def guard(node: int, t0: float, toggles: str, state: int = 0x7F, period: float = 0.1,
          dt: float = 0.002) -> list[tuple[float, str]]:
    """A remote request every `period` from t0, each answered after `dt` with the toggle
    bits given as a string of 0/1 ('-' = no answer)."""
    out = []
    for i, tog in enumerate(toggles):
        t = round(t0 + i * period, 6)
        out.append((t, f"{0x700 + node:03X}#R"))
        if tog != "-":
            out.append((round(t + dt, 6), f"{0x700 + node:03X}#{int(tog) << 7 | state:02X}"))
    return out


GUARD_NET = "[nodes.5]\nguard_time_ms = 100\nlife_time_factor = 3\n"  # life time 0.3 s


def test_healthy_trace_is_clean(checker: Checker) -> None:
    assert checker.findings(candump(healthy()), select="G") == []
    assert checker.findings(candump(healthy()), select="G", network=HEALTHY_NET) == []


def test_healthy_guarding_is_clean(checker: Checker) -> None:
    fr = ([(0.0, "705#00")] + guard(5, 0.1, "0101") + [(0.45, "000#0105")]
          + guard(5, 0.5, "010101", state=0x05))
    assert checker.findings(candump(sorted(fr)), network=GUARD_NET) == []


# --- G001 -------------------------------------------------------------------------------

def test_g001_repeated_toggle_complete_list(checker: Checker) -> None:
    fr = [(0.0, "705#00")] + guard(5, 0.1, "0100101")
    res = checker.run(candump(fr))
    assert [(f.rule, f.node, round(f.time - 1000.0, 3)) for f in res.findings] == [
        ("G001", 5, 0.402)]
    assert res.findings[0].message.startswith("guarding response 7Fh from node 5")


def test_g001_stuck_toggle_is_one_finding_with_count(checker: Checker) -> None:
    fr = [(0.0, "705#00")] + guard(5, 0.1, "010000")
    res = checker.run(candump(fr), select="G")
    assert [(f.rule, f.node, round(f.time - 1000.0, 3)) for f in res.findings] == [
        ("G001", 5, 0.402)]
    assert "(3 responses)" in res.findings[0].message


def test_g001_separate_repeats_are_separate_findings(checker: Checker) -> None:
    fr = [(0.0, "705#00")] + guard(5, 0.1, "01100")
    assert checker.findings(candump(fr), select="G") == [("G001", 5, 0.302),
                                                         ("G001", 5, 0.502)]


def test_g001_first_response_after_bootup_has_toggle_1(checker: Checker) -> None:
    fr = [(0.0, "705#00")] + guard(5, 0.1, "1010")
    assert checker.findings(candump(fr), select="G") == [("G001", 5, 0.102)]
    # and again after a later boot-up (reset by the master)
    fr = ([(0.0, "705#00")] + guard(5, 0.1, "0101") + [(0.5, "000#8105"), (0.6, "705#00")]
          + guard(5, 0.7, "10"))
    assert checker.findings(candump(fr), select="G") == [("G001", 5, 0.702)]


def test_g001_first_response_without_bootup_may_have_toggle_1(checker: Checker) -> None:
    fr = [(0.0, "705#R"), (0.002, "705#FF")] + guard(5, 0.1, "0101")
    assert checker.findings(candump(fr), select="G") == []


def test_g001_bootup_separates_findings(checker: Checker) -> None:
    fr = [(0.0, "705#00")] + guard(5, 0.1, "011") + [(0.35, "705#00")] + guard(5, 0.4, "10")
    assert checker.findings(candump(fr), select="G") == [("G001", 5, 0.302),
                                                         ("G001", 5, 0.402)]


# --- G002 -------------------------------------------------------------------------------

def test_g002_run_of_unanswered_requests_complete_list(checker: Checker) -> None:
    # requests at 0.6, 0.7, 0.8 get no answer; the one at 0.9 does
    fr = [(0.0, "705#00")] + guard(5, 0.1, "01010---1")
    res = checker.run(candump(fr))
    assert [(f.rule, f.node, round(f.time - 1000.0, 3)) for f in res.findings] == [
        ("G002", 5, 0.7)]
    assert "(3 requests in a row)" in res.findings[0].message


def test_g002_time_is_request_plus_response_timeout_when_earlier(checker: Checker) -> None:
    fr = [(0.0, "705#00")] + guard(5, 0.1, "01-0", period=2.0)
    assert checker.findings(candump(fr)) == [("G002", 5, 5.1)]


def test_g002_two_runs_two_findings(checker: Checker) -> None:
    fr = [(0.0, "705#00")] + guard(5, 0.1, "0--1--0")
    assert checker.findings(candump(fr)) == [("G002", 5, 0.3), ("G002", 5, 0.6)]


def test_g002_trace_ends_before_the_answer_is_due(checker: Checker) -> None:
    fr = [(0.0, "705#00")] + guard(5, 0.1, "010-") + [(0.9, "080#")]
    assert checker.findings(candump(fr)) == []
    fr = [(0.0, "705#00")] + guard(5, 0.1, "010-") + [(1.5, "080#")]
    assert checker.findings(candump(fr)) == [("G002", 5, 1.4)]


def test_g002_late_answer_does_not_count(checker: Checker) -> None:
    # answered 1.5 s after the request: later than response_timeout_ms (1000)
    fr = [(0.0, "705#00")] + guard(5, 0.1, "01") + [(1.0, "705#R"), (2.5, "705#7F"),
                                                      (3.0, "705#R"), (3.002, "705#FF")]
    assert checker.findings(candump(fr), select="G002") == [("G002", 5, 2.0)]


def test_g002_response_timeout_ms_from_profile(checker: Checker, tmp_path: Path) -> None:
    fr = [(0.0, "705#00")] + guard(5, 0.1, "0101", period=0.2, dt=0.08)
    prof = profile(tmp_path, "[rules.G002]\nresponse_timeout_ms = 50\n")
    assert checker.findings(candump(fr), select="G") == []
    # every answer comes too late: one run of four unanswered requests
    res = checker.run(candump(fr), select="G002", profile=prof)
    assert [(f.rule, f.node, round(f.time - 1000.0, 3)) for f in res.findings] == [
        ("G002", 5, 0.15)]
    assert "(4 requests in a row)" in res.findings[0].message


# --- G003 -------------------------------------------------------------------------------

def test_g003_interval_exceeded_complete_list(checker: Checker) -> None:
    fr = [(0.0, "705#00")] + guard(5, 0.1, "0101") + guard(5, 0.9, "0101")
    res = checker.run(candump(fr), network=GUARD_NET)
    assert [(f.rule, f.node, round(f.time - 1000.0, 3)) for f in res.findings] == [
        ("G003", 5, 0.9)]
    assert res.findings[0].severity == "warning"
    assert "0.500 s apart" in res.findings[0].message


def test_g003_consecutive_late_requests_are_one_finding(checker: Checker) -> None:
    fr = [(0.0, "705#00")] + guard(5, 0.1, "0101") + guard(5, 0.9, "0101", period=0.5)
    res = checker.run(candump(fr), select="G", network=GUARD_NET)
    assert [(f.rule, f.node, round(f.time - 1000.0, 3)) for f in res.findings] == [
        ("G003", 5, 0.9)]
    assert "(4 requests)" in res.findings[0].message


def test_g003_interval_equal_to_life_time_is_clean(checker: Checker) -> None:
    fr = [(0.0, "705#00")] + guard(5, 0.1, "0101010101", period=0.3)
    assert checker.findings(candump(fr), network=GUARD_NET) == []


def test_g003_needs_guard_time_and_life_time_factor(checker: Checker) -> None:
    fr = [(0.0, "705#00")] + guard(5, 0.1, "0101") + guard(5, 0.9, "0101")
    assert checker.findings(candump(fr)) == []
    assert checker.findings(candump(fr), network="[nodes.5]\nguard_time_ms = 100\n") == []


# --- G004 -------------------------------------------------------------------------------

def test_g004_guarding_with_heartbeat_complete_list(checker: Checker) -> None:
    # heartbeat every 100 ms and a guarding response 10 ms after one of them
    fr = [(0.0, "705#00")] + hb(5, 0.1, 1.0) + [(0.505, "705#R"), (0.51, "705#7F"),
                                                  (0.705, "705#R"), (0.71, "705#FF")]
    res = checker.run(candump(sorted(fr)))
    assert [(f.rule, f.node, round(f.time - 1000.0, 3)) for f in res.findings] == [
        ("G004", 5, 0.51)]
    assert res.nodes()[0].error_control == "both"


def test_g004_once_per_bootup(checker: Checker) -> None:
    fr = ([(0.0, "705#00")] + hb(5, 0.1, 1.0) + [(0.505, "705#R"), (0.51, "705#7F"),
                                                   (0.705, "705#R"), (0.71, "705#FF")]
          + [(1.0, "000#8105"), (1.1, "705#00")] + hb(5, 1.2, 2.0)
          + [(1.305, "705#R"), (1.31, "705#7F")])
    assert checker.findings(candump(sorted(fr)), select="G") == [("G004", 5, 0.51),
                                                                 ("G004", 5, 1.31)]


def test_g004_not_for_one_method_only(checker: Checker) -> None:
    guarding = [(0.0, "705#00")] + guard(5, 0.1, "0101010101")
    heartbeat = [(0.0, "705#00")] + hb(5, 0.1, 1.0)
    assert checker.findings(candump(guarding), select="G004") == []
    assert checker.findings(candump(heartbeat), select="G004") == []



def test_the_array_classification_of_guarding_is_the_walks(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """`_classify_guarding` answers with array operations where the walk's other test is
    not reached; on random nodes (guarding, heartbeats, both, boot-ups, time going
    backwards, 1017h = 0 in force) it gives the walk's kinds, frame for frame."""
    from nmtcheck.protocol.nmt import MALFORMED
    from nmtcheck.timeline import error_control as timeline

    walk = timeline._classify_guarding_walk
    walked: list[int] = []

    def spy(*args: object) -> None:
        walked.append(1)
        walk(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(timeline, "_classify_guarding_walk", spy)
    params = TimelineParams(response_timeout_s=0.05, early_factor=0.5)
    fast = 0
    for seed in range(1000):
        rnd = random.Random(seed)
        guarded = rnd.random() < 0.6
        kinds: list[int] = []
        ts: list[float] = []
        t = 0.0
        for _ in range(rnd.randrange(1, 8 if guarded else 40)):
            if guarded:  # request, mostly an answer 1-60 ms later; now and then a boot-up
                step = rnd.choices(((REQUEST, HEARTBEAT), (REQUEST,), (BOOTUP,),
                                    (MALFORMED,), (REQUEST, HEARTBEAT, HEARTBEAT)),
                                   (20, 2, 1, 1, 2))[0]
            else:  # heartbeats and guarding mixed
                step = (rnd.choices((REQUEST, HEARTBEAT, BOOTUP, MALFORMED), (4, 10, 1, 1))[0],)
            for pick in step:
                t += rnd.choice((0.001, 0.01, 0.04, 0.06, 0.1)) * (
                    -0.5 if rnd.random() < 0.05 else 1)
                kinds.append(pick)
                ts.append(round(t, 6))
        n = len(kinds)
        kind = np.asarray(kinds, np.int8)
        ec = SimpleNamespace(ts=np.asarray(ts), value=np.asarray(
            [rnd.choice((0x05, 0x85, 0x7F, 0xFF, 0x04)) for _ in range(n)], np.uint8))
        periods = np.full(n, rnd.choice((np.nan, 0.1, 0.05)))
        disabled = np.asarray([rnd.random() < 0.05 for _ in range(n)])
        # the trace's start: long before, or a request before it may still be pending
        start = rnd.choice((-np.inf, ts[0], ts[0] - 0.05, ts[0] - 0.5))
        rel = np.isin(kind, (REQUEST, BOOTUP, HEARTBEAT))
        start = timeline.request_before_trace(kind[rel], ec.ts[rel], start,
                                              params.response_timeout_s + EPS)
        a, b = kind.copy(), kind.copy()
        before = len(walked)
        timeline._classify_guarding(ec, a, params, periods, disabled,  # type: ignore[arg-type]
                                    start)
        fast += len(walked) == before
        walk(ec, b, params, periods, disabled, start)  # type: ignore[arg-type]
        assert a.tolist() == b.tolist(), seed
    assert 300 < fast < 900, fast  # both ways were taken, and agreed


def _random_guarding(rnd: random.Random) -> tuple[SimpleNamespace, np.ndarray]:
    """A node's error-control rows (requests, responses, boot-ups, heartbeats) as the
    guarding stages see them, and reset commands between them (frame indices)."""
    n = rnd.randrange(1, 40)
    answered = rnd.random() < 0.5  # mostly answered at once: the stretches matter
    kinds: list[int] = []
    for _ in range(n):
        if answered and kinds and kinds[-1] == REQUEST and rnd.random() < 0.9:
            kinds.append(GUARD)
        else:
            kinds.append(rnd.choices((REQUEST, GUARD, BOOTUP, HEARTBEAT), (6, 4, 1, 1))[0])
    n = len(kinds)
    idx = np.cumsum([rnd.choice((1, 2, 3)) for _ in range(n)]) * 2  # even: resets odd
    ts = np.cumsum([rnd.choice((0.002, 0.05, 0.1, 1.5)) for _ in range(n)])
    kind = np.asarray(kinds, np.int8)
    ec = SimpleNamespace(kind=kind, idx=idx, ts=ts, value=np.asarray(
        [rnd.choice((0x05, 0x85, 0x7F, 0xFF)) for _ in range(n)], np.uint8),
        where=lambda *ks: np.flatnonzero(np.isin(kind, ks)))
    odd = range(1, int(idx[-1]) + 2, 2)
    resets = np.asarray(sorted(rnd.sample(odd, min(len(odd), rnd.choice((0, 0, 1, 3))))),
                        np.int64)
    return ec, resets


def _toggle_errors_walk(ec: Any, pos: np.ndarray, resets: list[int]) -> list[_BadToggle]:
    """`_toggle_errors` as it was, frame by frame: the reference it is compared with."""
    expected: int | None = None
    ri = 0
    bad: list[_BadToggle] = []
    prev_boot = True  # the previous guard/boot-up frame is a boot-up (or none)
    # n numbers responses and boot-ups alike: a boot-up separates runs
    for n, (p_, k, idx, value) in enumerate(zip(
            pos.tolist(), ec.kind[pos].tolist(), ec.idx[pos].tolist(),
            ec.value[pos].tolist(), strict=True)):
        while ri < len(resets) and resets[ri] < idx:
            expected = 0
            ri += 1
        if k == BOOTUP:
            expected = 0
        else:
            toggle = value >> 7
            if expected is not None and toggle != expected:
                why = ("first response after boot-up/reset has toggle 1"
                       if expected == 0 and value & 0x80 and prev_boot
                       else f"toggle bit {toggle} repeats the previous response's")
                bad.append(_BadToggle(n, p_, why))
            expected = 1 - toggle
        prev_boot = k == BOOTUP
    return bad


def test_guarding_timeouts_and_toggles_match_their_walks() -> None:
    """G002's stretches and G001's array judgement give what walking every frame gives."""
    from nmtcheck.checks.guarding import _toggle_errors
    from nmtcheck.timeline.error_control import _guard_walk
    from nmtcheck.timeline.error_control import guard_timeouts as _guard_timeouts

    params = TimelineParams(response_timeout_s=1.0)
    timeouts = toggles = 0
    for seed in range(1500):
        rnd = random.Random(seed)
        ec, resets = _random_guarding(rnd)
        end = float(ec.ts[-1]) + rnd.choice((0.0, 0.5, 5.0))
        fast, every = SimpleNamespace(ec=ec, timeouts=[]), SimpleNamespace(ec=ec, timeouts=[])
        _guard_timeouts(fast, params, end)  # type: ignore[arg-type]
        _guard_walk(every, params, end, ec.where(REQUEST, GUARD, BOOTUP))  # type: ignore[arg-type]
        assert fast.timeouts == every.timeouts, seed
        timeouts += bool(every.timeouts)
        pos = ec.where(GUARD, BOOTUP)
        got = _toggle_errors(ec, pos, resets)  # type: ignore[arg-type]
        assert got == _toggle_errors_walk(ec, pos, resets.tolist()), seed
        toggles += bool(got)
    assert 200 < timeouts < 1300 and 200 < toggles < 1300, (timeouts, toggles)
