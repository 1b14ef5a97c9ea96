"""Boot-up rules B001 (missing-bootup), B002 (unexpected-bootup), B003 (bootup-repeated)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from conftest import SAMPLES, Checker, candump
from test_real_stack_stale import live
from traces import HEALTHY_NET, hb, healthy, profile


def test_healthy_trace_is_clean(checker: Checker) -> None:
    assert checker.findings(candump(healthy()), select="B") == []
    assert checker.findings(candump(healthy()), select="B", network=HEALTHY_NET) == []


# --- B001 (a): after a reset command ---------------------------------------------------

def test_b001_heartbeat_before_bootup_complete_list(checker: Checker) -> None:
    # the heartbeat at 1.1 s is within obey_ms of the reset and reports the state before it:
    # stale (queued before the reset, SPEC §2), so the sign of life is the one at 1.2 s
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.0, "000#8102")] + hb(2, 1.1, 2.0)
    assert checker.findings(candump(fr)) == [("B001", 2, 1.2)]


@pytest.mark.parametrize("sign", ["182#0102", "582#4318100100000000", "082#0010010000000000"])
def test_b001_tpdo_sdo_emcy_before_bootup(checker: Checker, sign: Any) -> None:
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.0, "000#8102"), (1.05, sign),
                                                   (1.2, "702#00")] + hb(2, 1.3, 2.0))
    assert checker.findings(candump(fr), select="B") == [("B001", 2, 1.05)]


def test_b001_guarding_response_before_bootup(checker: Checker) -> None:
    fr = [(0.0, "705#00"), (0.1, "705#R"), (0.102, "705#7F"), (0.2, "705#R"), (0.202, "705#FF"),
          (0.5, "000#8105"), (0.6, "705#R"), (0.602, "705#7F"), (0.7, "705#00")]
    assert checker.findings(candump(fr), select="B001") == [("B001", 5, 0.602)]


def test_b001_broadcast_reset_applies_to_nodes_already_seen(checker: Checker) -> None:
    # nodes 2 and 3 are seen before the broadcast reset; node 4 only after it. The reset
    # comes 1.5 s after the last boot-up, so node 3 is not taken for the master (SPEC §2).
    fr = ([(0.0, "702#00"), (0.01, "703#00")] + hb(2, 0.1, 1.5) + hb(3, 0.11, 1.5)
          + [(1.5, "000#8200"), (1.55, "702#00"), (1.51, "704#00")] + hb(2, 1.65, 3.0)
          + hb(3, 1.61, 3.0) + hb(4, 1.52, 3.0))
    assert checker.findings(candump(sorted(fr)), select="B") == [("B001", 3, 1.61)]


def test_b001_no_bootup_within_timeout(checker: Checker) -> None:
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.0, "000#8102")] + hb(3, 0.05, 7.0)
    assert checker.findings(candump(sorted(fr)), select="B001") == [("B001", 2, 6.0)]


def test_b001_bootup_after_the_timeout(checker: Checker) -> None:
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.0, "000#8102"), (6.5, "702#00")]
          + hb(3, 0.05, 7.0))
    assert checker.findings(candump(sorted(fr)), select="B001") == [("B001", 2, 6.0)]


def test_b001_trace_ends_before_the_timeout(checker: Checker) -> None:
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.0, "000#8102")] + hb(3, 0.05, 5.9)
    assert checker.findings(candump(sorted(fr)), select="B001") == []


def test_b001_bootup_in_time_is_clean(checker: Checker) -> None:
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.0, "000#8102"), (1.4, "702#00")]
          + hb(2, 1.5, 7.0))
    assert checker.findings(candump(fr)) == []


def test_b001_newer_reset_restarts_the_wait(checker: Checker) -> None:
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.0, "000#8102"), (4.0, "000#8102"),
                                                   (8.5, "702#00")] + hb(2, 8.6, 10.0)
          + hb(3, 0.05, 10.0))
    assert checker.findings(candump(sorted(fr)), select="B") == []


def test_b001_bootup_timeout_ms_from_profile(checker: Checker, tmp_path: Path) -> None:
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.0, "000#8102"), (2.5, "702#00")]
          + hb(2, 2.6, 3.0))
    prof = profile(tmp_path, "[rules.B001]\nbootup_timeout_ms = 1000\n")
    assert checker.findings(candump(fr), select="B001", profile=prof) == [("B001", 2, 2.0)]
    assert checker.findings(candump(fr), select="B001") == []


# --- B001 (b): late start without boot-up ----------------------------------------------

def test_b001_late_start_complete_list(checker: Checker) -> None:
    fr = [(0.0, "702#00")] + hb(2, 0.1, 3.0) + hb(3, 1.5, 3.0, "05")
    assert checker.findings(candump(sorted(fr))) == [("B001", 3, 1.5)]


def test_b001_early_first_heartbeat_is_clean(checker: Checker) -> None:
    # recording started while node 3 was running: its first heartbeat within 1 s is fine
    fr = [(0.0, "702#00")] + hb(2, 0.1, 3.0) + hb(3, 0.9, 3.0, "05")
    assert checker.findings(candump(sorted(fr))) == []


def test_b001_late_start_uses_three_heartbeat_periods(checker: Checker) -> None:
    net = "[nodes.3]\nheartbeat_ms = 500\n"  # late_start = 3 x 500 ms = 1.5 s
    early = [(0.0, "702#00")] + hb(2, 0.1, 4.0) + hb(3, 1.4, 4.0, period=0.5)
    late = [(0.0, "702#00")] + hb(2, 0.1, 4.0) + hb(3, 1.6, 4.0, period=0.5)
    assert checker.findings(candump(sorted(early)), select="B001", network=net) == []
    assert checker.findings(candump(sorted(late)), select="B001", network=net) == [
        ("B001", 3, 1.6)]


def test_b001_late_start_not_when_first_frame_is_not_a_heartbeat(checker: Checker) -> None:
    with_bootup = [(0.0, "702#00")] + hb(2, 0.1, 3.0) + [(1.5, "703#00")] + hb(3, 1.6, 3.0)
    with_tpdo = [(0.0, "702#00")] + hb(2, 0.1, 3.0) + [(1.5, "183#00")] + hb(3, 1.6, 3.0)
    assert checker.findings(candump(sorted(with_bootup)), select="B001") == []
    assert checker.findings(candump(sorted(with_tpdo)), select="B001") == []


def test_b001_late_start_late_start_ms_from_profile(checker: Checker, tmp_path: Path) -> None:
    fr = [(0.0, "702#00")] + hb(2, 0.1, 3.0) + hb(3, 1.5, 3.0)
    prof = profile(tmp_path, "[rules.B001]\nlate_start_ms = 2000\n")
    assert checker.findings(candump(sorted(fr)), select="B001", profile=prof) == []


# --- B002 -------------------------------------------------------------------------------

def test_b002_spontaneous_reboot_complete_list(checker: Checker) -> None:
    fr = [(0.0, "702#00")] + hb(2, 0.1, 2.5) + [(2.5, "702#00")] + hb(2, 2.6, 4.0)
    assert checker.findings(candump(fr)) == [("B002", 2, 2.5)]


@pytest.mark.parametrize("reset", ["000#8102", "000#8202", "000#8100", "000#8200"])
def test_b002_bootup_after_reset_is_clean(checker: Checker, reset: Any) -> None:
    fr = [(0.0, "702#00")] + hb(2, 0.1, 2.5) + [(2.5, reset), (2.7, "702#00")] + hb(2, 2.8, 4.0)
    assert checker.findings(candump(fr)) == []


def test_b002_each_reset_explains_one_bootup(checker: Checker) -> None:
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.0, "000#8102"), (1.1, "702#00")]
          + hb(2, 1.2, 3.0) + [(3.0, "702#00")] + hb(2, 3.1, 4.0))
    assert checker.findings(candump(fr)) == [("B002", 2, 3.0)]


def test_b002_reset_older_than_reset_window(checker: Checker) -> None:
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.0, "000#8102"), (11.5, "702#00")]
          + hb(3, 0.05, 12.0))
    assert checker.findings(candump(sorted(fr)), select="B002") == [("B002", 2, 11.5)]


def test_b002_not_for_first_frame_of_node(checker: Checker) -> None:
    # node 3 is powered on during the recording: its boot-up is its first frame
    fr = [(0.0, "702#00")] + hb(2, 0.1, 3.0) + [(1.5, "703#00")] + hb(3, 1.6, 3.0)
    assert checker.findings(candump(sorted(fr))) == []


def test_b002_after_other_traffic_of_the_node(checker: Checker) -> None:
    # node 3 sent a TPDO (state UNKNOWN) before its boot-up: that is a reboot
    fr = [(0.0, "702#00")] + hb(2, 0.1, 3.0) + [(0.3, "183#01"), (1.5, "703#00")] + hb(
        3, 1.6, 3.0)
    assert checker.findings(candump(sorted(fr)), select="B") == [("B002", 3, 1.5)]


def test_b002_never_for_a_b003_repeat(checker: Checker) -> None:
    fr = [(0.0, "702#00")] + hb(2, 0.1, 2.0) + [(2.0, "702#00"), (2.5, "702#00")] + hb(
        2, 2.6, 3.0)
    assert checker.findings(candump(fr), select="B") == [("B002", 2, 2.0), ("B003", 2, 2.5)]


# --- B003 -------------------------------------------------------------------------------

def test_b003_heartbeat_00_complete_list(checker: Checker) -> None:
    fr = hb(2, 0.0, 0.5) + [(0.45, "000#8102")] + hb(2, 0.6, 2.0, "00")
    assert checker.findings(candump(sorted(fr))) == [("B003", 2, 0.7)]


def test_b003_one_finding_per_run_reset_splits_runs(checker: Checker) -> None:
    fr = (hb(2, 0.0, 0.5) + [(0.45, "000#8102")] + hb(2, 0.6, 0.9, "00")
          + [(0.85, "000#8102")] + hb(2, 0.9, 1.5, "00"))
    assert checker.findings(candump(sorted(fr)), select="B") == [("B003", 2, 0.7),
                                                                 ("B003", 2, 1.0)]


def _two_bootups(second: float) -> list[tuple[float, str]]:
    """Node 2's boot-ups at 0 and `second` with no report between (node 3 heartbeats)."""
    return sorted([(0.0, "702#00"), (second, "702#00")] + hb(2, second + 0.1, 3.0)
                  + hb(3, 0.05, 3.0))


def test_b003_window_is_inclusive_and_at_least_one_second(checker: Checker) -> None:
    assert checker.findings(candump(_two_bootups(1.0)), select="B") == [("B003", 2, 1.0)]
    assert checker.findings(candump(_two_bootups(1.2)), select="B") == [("B002", 2, 1.2)]


def test_b003_window_is_three_heartbeat_periods(checker: Checker) -> None:
    net = "[nodes.2]\nheartbeat_ms = 500\n"  # window 1.5 s
    assert checker.findings(candump(_two_bootups(1.4)), select="B", network=net) == [
        ("B003", 2, 1.4)]
    assert checker.findings(candump(_two_bootups(1.6)), select="B", network=net) == [
        ("B002", 2, 1.6)]


def test_b003_repeat_window_ms_from_profile(checker: Checker, tmp_path: Path) -> None:
    prof = profile(tmp_path, "[rules.B003]\nrepeat_window_ms = 500\n")
    assert checker.findings(candump(_two_bootups(1.0)), select="B", profile=prof) == [
        ("B002", 2, 1.0)]
    assert checker.findings(candump(_two_bootups(0.5)), select="B", profile=prof) == [
        ("B003", 2, 0.5)]


@pytest.mark.parametrize("between", [
    [(0.5, "702#7F")],  # a heartbeat: N had come up (a power cycle within the window)
    [(0.5, "702#R"), (0.502, "702#7F")],  # a guarding response
], ids=["heartbeat", "guarding-response"])
def test_b003_not_across_a_report_of_another_state(checker: Checker,
                                                   between: list[tuple[float, str]]) -> None:
    """Two boot-ups 0.9 s apart, within the 1 s window, with a report of N between: N
    did not keep sending 00h, it booted again (B002), however soon."""
    fr = sorted([(0.0, "702#00"), *between, (0.9, "702#00")] + hb(2, 1.0, 3.0)
                + hb(3, 0.05, 3.0))
    assert checker.findings(candump(fr), select="B") == [("B002", 2, 0.9)]


def test_b003_run_ends_at_a_report(checker: Checker) -> None:
    """00h, 00h (a repeat, no report between; a TPDO and an SDO answer are no report of
    its state), then 7Fh, then 00h: one B003 for the run, B002 for the last boot-up."""
    fr = sorted([(0.0, "702#00"), (0.1, "182#01"), (0.15, "582#4318100100000000"),
                 (0.2, "702#00"), (0.3, "702#7F"), (0.6, "702#00")]
                + hb(2, 0.7, 3.0) + hb(3, 0.05, 3.0))
    assert checker.findings(candump(fr), select="B") == [("B003", 2, 0.2), ("B002", 2, 0.6)]


def test_b003_live_ends_a_run_at_a_report_too(checker: Checker, tmp_path: Path) -> None:
    """The live tracker judges B003 and B002 as the offline check does: a report of N
    between two boot-ups ends a run. The CANopenNode slave powered off and on 1.1 s after
    its boot-up, having sent `703#7F` between (samples/canopennode/lss/), is B002 in both."""
    reported = [(0.0, "702#00"), (0.5, "702#7F"), (0.9, "702#00")]
    in_a_row = [(0.0, "702#00"), (0.9, "702#00")]
    for node2, rule in ((reported, "B002"), (in_a_row, "B003")):
        text = candump(sorted(node2 + hb(2, 1.0, 3.0) + hb(3, 0.05, 3.0)))
        assert [r for r, _n, _t in checker.findings(text, select="B")] == [rule]
        assert [f for f in live(text, tmp_path) if f[0].startswith("B")] == [(rule, 2)]
    text = (SAMPLES / "canopennode" / "lss" / "lss_not_adopted.log").read_text()
    assert checker.findings(text, select="B") == [("B002", 3, 1.096)]
    assert [f for f in live(text, tmp_path) if f[0].startswith("B")] == [("B002", 3)]


def test_b001_tpdo_logged_with_the_resets_timestamp_but_after_it(checker: Checker) -> None:
    """A TPDO stamped with the reset's own time but logged after it left the controller
    before the node processed the reset (SPEC §3 B001 `grace_ms`, revised 2026-11-26:
    before, this was a sign of life); one 10 ms later, past the grace, is one."""
    fr = [(0.0, "702#00"), (0.05, "000#0100")] + [(0.1 * i, "702#05") for i in range(1, 10)]
    text = candump(fr) + "(1001.000000) can0 000#8102\n(1001.000000) can0 182#01\n"
    assert checker.findings(text + candump([(1.05, "702#00")]), select="B001") == []
    text += "(1001.010000) can0 182#02\n" + candump([(1.05, "702#00")])
    assert checker.findings(text, select="B001") == [("B001", 2, 1.01)]
