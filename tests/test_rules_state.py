"""State and communication rules S001 (pdo-while-not-operational), S002
(pdo-to-not-operational), S003 (comm-while-stopped), S004 (command-not-obeyed),
S005 (unexplained-state-change)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from conftest import Checker, candump
from traces import HEALTHY_NET, hb, healthy, profile

from nmtcheck.results import InputResult


def every(t0: float, t1: float, frame: str, period: float = 0.02) -> list[tuple[float, str]]:
    """`frame` every `period` from t0 (inclusive) to t1 (exclusive)."""
    return [(round(t0 + i * period, 6), frame) for i in range(int((t1 - t0) / period) + 1)
            if t0 + i * period < t1 - 1e-9]


def node2(start: float | None = 0.45, stop: float | None = 1.45, end: float = 2.5
          ) -> list[tuple[float, str]]:
    """Node 2: boot-up, heartbeats every 100 ms that follow the start and stop commands."""
    fr = [(0.0, "702#00")]
    for t, f in hb(2, 0.1, end):
        state = "7F"
        if start is not None and t > start:
            state = "05"
        if stop is not None and t > stop:
            state = "04"
        fr.append((t, f[:4] + state))
    fr += [(t, cmd) for t, cmd in ((start, "000#0102"), (stop, "000#0202")) if t is not None]
    return sorted(fr)


def found(res: InputResult) -> list[tuple[str, int | None, float]]:
    return [(f.rule, f.node, round(f.time - 1000.0, 3)) for f in res.findings]


def test_healthy_trace_is_clean(checker: Checker) -> None:
    assert checker.findings(candump(healthy()), select="S") == []
    assert checker.findings(candump(healthy()), select="S", network=HEALTHY_NET) == []


def test_node2_helper_is_clean(checker: Checker) -> None:
    fr = node2() + every(0.46, 1.45, "182#01") + every(0.465, 1.45, "202#01")
    assert checker.findings(candump(sorted(fr))) == []


# --- S001 -------------------------------------------------------------------------------

def test_s001_tpdo_in_pre_operational_complete_list(checker: Checker) -> None:
    fr = node2() + [(0.3, "182#01"), (0.32, "182#01"), (0.34, "182#01")]
    res = checker.run(candump(sorted(fr)))
    assert found(res) == [("S001", 2, 0.3)]
    assert res.findings[0].message == (
        "TPDO 182h sent while node 2 is PRE-OPERATIONAL (3 frames)")


def test_s001_tpdo_in_stopped(checker: Checker) -> None:
    fr = node2() + every(0.46, 1.45, "182#01") + [(1.8, "282#01"), (2.0, "182#01")]
    res = checker.run(candump(sorted(fr)))
    assert found(res) == [("S001", 2, 1.8)]
    assert "while node 2 is STOPPED (2 frames)" in res.findings[0].message


def test_s001_one_counted_run_per_interval(checker: Checker) -> None:
    fr = (node2() + every(0.2, 0.3, "182#01") + every(0.46, 1.45, "182#01")
          + every(1.6, 1.7, "182#01"))
    res = checker.run(candump(sorted(fr)), select="S001")
    assert found(res) == [("S001", 2, 0.2), ("S001", 2, 1.6)]
    assert [f.message[-10:] for f in res.findings] == ["(5 frames)", "(5 frames)"]


@pytest.mark.parametrize(("dt", "expected"), [(0.002, []), (0.005, []),
                                               (0.006, [("S001", 2, 1.456)])])
def test_s001_grace_after_leaving_operational(checker: Checker, dt: Any, expected: Any) -> None:
    fr = node2() + every(0.46, 1.45, "182#01") + [(1.45 + dt, "182#01")]
    assert checker.findings(candump(sorted(fr)), select="S") == expected


def test_s001_grace_ms_from_profile(checker: Checker, tmp_path: Path) -> None:
    fr = node2() + every(0.46, 1.45, "182#01") + [(1.458, "182#01")]
    prof = profile(tmp_path, "[rules.S001]\ngrace_ms = 10\n")
    assert checker.findings(candump(sorted(fr)), select="S") == [("S001", 2, 1.458)]
    assert checker.findings(candump(sorted(fr)), select="S", profile=prof) == []


def test_s001_grace_when_leaving_operational_by_local_control(checker: Checker) -> None:
    # the node itself drops to PRE-OPERATIONAL (heartbeat 7Fh); its last PDO follows 3 ms later
    fr = node2(stop=None) + every(0.46, 1.0, "182#01") + [(1.003, "182#01")]
    fr = [(t, "702#7F" if f.startswith("702") and t > 0.95 else f) for t, f in fr]
    assert checker.findings(candump(sorted(fr)), select="S001") == []


def test_s001_grace_after_stop_then_pre_operational(checker: Checker) -> None:
    # stop and enter pre-operational 1 ms apart: N left OPERATIONAL 4 ms before the PDO
    fr = node2() + every(0.46, 1.45, "182#01") + [(1.451, "000#8002"), (1.454, "182#01")]
    fr = [(t, "702#7F" if f.startswith("702") and t > 1.45 else f) for t, f in fr]
    assert checker.findings(candump(sorted(fr)), select="S001") == []


def test_s001_no_grace_after_bootup(checker: Checker) -> None:
    fr = node2() + [(0.002, "182#01")]
    assert checker.findings(candump(sorted(fr)), select="S001") == [("S001", 2, 0.002)]


def test_s001_not_while_unknown(checker: Checker) -> None:
    # node 3 was never heard from on 703h: its state is UNKNOWN
    fr = node2() + every(0.2, 2.0, "183#01", period=0.1)
    assert checker.findings(candump(sorted(fr))) == []


# --- S002 -------------------------------------------------------------------------------

def test_s002_rpdo_to_pre_operational_node_complete_list(checker: Checker) -> None:
    fr = node2() + [(0.3, "202#0000"), (0.35, "302#0000")] + every(0.46, 1.45, "202#01")
    res = checker.run(candump(sorted(fr)))
    assert found(res) == [("S002", 2, 0.3)]
    assert res.findings[0].severity == "info"
    assert "(2 frames)" in res.findings[0].message


def test_s002_rpdo_to_stopped_node(checker: Checker) -> None:
    fr = node2() + every(0.46, 1.45, "202#01") + [(1.7, "502#00")]
    assert checker.findings(candump(sorted(fr))) == [("S002", 2, 1.7)]


def test_s002_not_for_unknown_or_unseen_nodes(checker: Checker) -> None:
    fr = node2() + [(0.3, "203#00"), (0.4, "184#00"), (0.5, "204#00")]
    assert checker.findings(candump(sorted(fr))) == []


# --- S003 -------------------------------------------------------------------------------

def test_s003_sdo_and_emcy_while_stopped_complete_list(checker: Checker) -> None:
    fr = node2() + [(1.7, "602#4000100000000000"), (1.7005, "582#4300100091010000"),
                    (1.702, "082#0010010000000000")]
    res = checker.run(candump(sorted(fr)))
    # the EMCY (1000h, register 01h) is never reset: the node is still in error (E003)
    assert found(res) == [("S003", 2, 1.701), ("E003", 2, 1.702)]
    assert "(2 frames)" in res.findings[0].message


def test_s003_not_in_pre_operational_or_operational(checker: Checker) -> None:
    fr = node2() + [(0.3, "582#4300100091010000"), (0.31, "082#0010010000000000"),
                    (1.0, "582#4300100091010000"), (1.01, "082#0000000000000000")]
    assert checker.findings(candump(sorted(fr))) == []


@pytest.mark.parametrize(("dt", "expected"), [(0.003, []), (0.005, []),
                                               (0.01, [("S003", 2, 1.46)])])
def test_s003_grace_after_entering_stopped(checker: Checker, dt: Any, expected: Any) -> None:
    fr = node2() + [(1.45 + dt, "582#4300100091010000")]
    assert checker.findings(candump(sorted(fr))) == expected


def test_s003_returning_from_offline_is_no_new_entry(checker: Checker) -> None:
    # node 2 is STOPPED, falls silent (H001 -> OFFLINE) and then sends an EMCY: that EMCY
    # ends OFFLINE, the node is back in STOPPED and the EMCY is not within the grace time
    fr = node2(end=2.0) + [(2.5, "082#0010010000000000")]
    assert checker.findings(candump(sorted(fr))) == [("H001", 2, 2.05), ("E003", 2, 2.5),
                                                     ("S003", 2, 2.5)]


# --- S004 -------------------------------------------------------------------------------

def test_s004_start_not_obeyed_complete_list(checker: Checker) -> None:
    fr = node2(start=None, stop=None) + [(0.4, "000#0102")]
    res = checker.run(candump(sorted(fr)))
    # the heartbeat at 0.5 s is exactly obey_ms after the command: not counted yet
    assert found(res) == [("S004", 2, 0.6)]
    assert res.findings[0].message == (
        "node 2 reports PRE-OPERATIONAL 0.200 s after NMT start (expected OPERATIONAL)")


@pytest.mark.parametrize(("cmd", "expected"), [("000#0202", "STOPPED"),
                                                ("000#0200", "STOPPED"),
                                                ("000#8002", "PRE-OPERATIONAL"),
                                                ("000#8000", "PRE-OPERATIONAL")])
def test_s004_stop_and_preop_not_obeyed(checker: Checker, cmd: Any, expected: Any) -> None:
    fr = node2(stop=None) + [(1.45, cmd)]
    res = checker.run(candump(sorted(fr)), select="S004")
    assert found(res) == [("S004", 2, 1.6)]
    assert res.findings[0].message.endswith(f"(expected {expected})")


def test_s004_obeyed(checker: Checker) -> None:
    fr = node2()
    assert checker.findings(candump(fr)) == []


def test_s004_obeyed_once_then_left_is_not_s004(checker: Checker) -> None:
    fr = node2(stop=None)
    fr = [(t, "702#7F" if f.startswith("702") and t > 0.95 else f) for t, f in fr]
    assert checker.findings(candump(fr)) == [("S005", 2, 1.0)]


def test_s004_late_report_within_obey_ms(checker: Checker) -> None:
    # the first heartbeat after the start still says 7Fh, 50 ms after the command
    fr = node2() + [(0.5, "702#7F")]
    fr = [x for x in fr if x != (0.5, "702#05")]
    assert checker.findings(candump(sorted(fr)), select="S004") == []


def test_s004_newer_command_ends_the_check(checker: Checker) -> None:
    fr = node2(stop=0.47)
    assert checker.findings(candump(fr)) == []


def test_s004_bootup_ends_the_check(checker: Checker) -> None:
    fr = node2(stop=None)
    fr = [(t, "702#7F" if f.startswith("702") and t > 0.45 else f) for t, f in fr]
    fr.append((0.5, "702#00"))
    assert checker.findings(candump(sorted(fr)), select="S004") == []


def test_s004_one_finding_per_command_and_per_node(checker: Checker) -> None:
    # broadcast start: node 2 obeys, node 3 keeps reporting PRE-OPERATIONAL
    fr = (node2(stop=None) + [(0.45, "000#0100"), (0.01, "703#00")] + hb(3, 0.11, 2.5))
    fr.remove((0.45, "000#0102"))
    # node 3 booted last before the broadcast and did not obey it: without a known master
    # it is taken for the master (SPEC §2 inference), which the broadcast does not concern
    assert checker.findings(candump(sorted(fr))) == []
    assert checker.findings(candump(sorted(fr)), network="master = 1\n") == [("S004", 3, 0.61)]


def test_s004_guarding_response_counts(checker: Checker) -> None:
    fr = [(0.0, "705#00"), (0.5, "000#0105")]
    for i, t in enumerate(x / 10 for x in range(1, 15)):
        fr += [(t, "705#R"), (t + 0.002, f"705#{(i % 2) << 7 | 0x7F:02X}")]
    assert checker.findings(candump(sorted(fr)), select="S004") == [("S004", 5, 0.602)]


def test_s004_obey_ms_from_profile(checker: Checker, tmp_path: Path) -> None:
    fr = node2(start=None, stop=None) + [(0.45, "000#0102")]
    fr = [(t, "702#05" if f.startswith("702") and t > 0.75 else f) for t, f in fr]
    prof = profile(tmp_path, "[rules.S004]\nobey_ms = 300\n")
    assert checker.findings(candump(sorted(fr)), select="S004") == [("S004", 2, 0.6)]
    assert checker.findings(candump(sorted(fr)), select="S004", profile=prof) == []


# --- S005 -------------------------------------------------------------------------------

def test_s005_unexplained_change_complete_list(checker: Checker) -> None:
    fr = node2(stop=None)
    fr = [(t, "702#04" if f.startswith("702") and t > 0.95 else f) for t, f in fr]
    res = checker.run(candump(fr))
    assert found(res) == [("S005", 2, 1.0)]
    assert res.findings[0].severity == "info"
    assert res.findings[0].message == (
        "node 2 changed from OPERATIONAL to STOPPED without an NMT command")


def test_s005_each_change_is_a_finding(checker: Checker) -> None:
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 0.5) + hb(2, 0.5, 1.0, "05") + hb(2, 1.0, 1.5)
          + hb(2, 1.5, 2.0, "05"))
    assert checker.findings(candump(fr), select="S005") == [
        ("S005", 2, 0.5), ("S005", 2, 1.0), ("S005", 2, 1.5)]


def test_s005_not_with_a_command_or_bootup_in_between(checker: Checker) -> None:
    with_command = node2()
    with_bootup = ([(0.0, "702#00")] + hb(2, 0.1, 0.5, "05") + [(0.5, "702#00")]
                   + hb(2, 0.6, 1.0))
    assert checker.findings(candump(with_command), select="S005") == []
    assert checker.findings(candump(with_bootup), select="S005") == []


def test_s005_self_start_after_bootup_is_clean(checker: Checker) -> None:
    # CANopenNode's default NMT_CONTROL goes boot-up -> heartbeat 05h by itself
    fr = [(0.0, "702#00")] + hb(2, 0.1, 2.0, "05") + every(0.11, 2.0, "182#01")
    assert checker.findings(candump(sorted(fr))) == []


def test_s005_unknown_state_codes_are_skipped(checker: Checker) -> None:
    fr = [(0.0, "702#00")] + hb(2, 0.1, 0.5, "05") + [(0.5, "702#02")] + hb(2, 0.6, 1.0, "05")
    assert checker.findings(candump(fr), select="S005") == []
