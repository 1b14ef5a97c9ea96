"""Node-guarding rules G001 (guard-toggle), G002 (guard-no-response),
G003 (guard-interval-exceeded), G004 (guarding-with-heartbeat)."""

from __future__ import annotations

from pathlib import Path

from conftest import Checker, candump
from traces import HEALTHY_NET, hb, healthy, profile


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

