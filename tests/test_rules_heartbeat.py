"""Heartbeat rules H001 (heartbeat-timeout) and H002 (heartbeat-too-early)."""

from __future__ import annotations

from conftest import Checker, candump
from traces import HEALTHY_NET, hb, healthy


def test_healthy_trace_is_clean(checker: Checker) -> None:
    assert checker.findings(candump(healthy()), select="H") == []
    assert checker.findings(candump(healthy()), select="H", network=HEALTHY_NET) == []
    assert checker.findings(candump(healthy()), select="H", profile="lenient") == []


# --- H001 -------------------------------------------------------------------------------

def test_h001_gap_complete_list(checker: Checker) -> None:
    # median period 100 ms, timeout 1.5 x 100 ms after the heartbeat at 0.9 s
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + hb(2, 1.5, 2.0)
    res = checker.run(candump(fr))
    assert [(f.rule, f.node, round(f.time - 1000.0, 3)) for f in res.findings] == [
        ("H001", 2, 1.05)]
    f = res.findings[0]
    assert f.severity == "error" and f.name == "heartbeat-timeout"
    assert "0.600 s" in f.message and "timeout 0.150 s" in f.message
    assert f.frame_index == 10  # the first frame at or after the moment: the heartbeat at 1.5 s


def test_h001_one_finding_per_gap(checker: Checker) -> None:
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + hb(2, 1.5, 2.0) + hb(2, 2.5, 3.0)
    assert checker.findings(candump(fr), select="H") == [("H001", 2, 1.05), ("H001", 2, 2.05)]


def test_h001_gap_within_timeout_is_clean(checker: Checker) -> None:
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + hb(2, 1.04, 2.0)
    assert checker.findings(candump(fr), select="H") == []


def test_h001_gap_after_bootup(checker: Checker) -> None:
    fr = [(0.0, "702#00"), (0.1, "702#7F"), (0.2, "702#7F"), (2.0, "702#00")] + hb(2, 2.1, 3.0)
    assert checker.findings(candump(fr), select="H001") == [("H001", 2, 0.35)]


def test_h001_end_of_trace(checker: Checker) -> None:
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + hb(3, 0.05, 2.0)
    assert checker.findings(candump(sorted(fr)), select="H") == [("H001", 2, 1.05)]


def test_h001_trace_ends_before_the_timeout(checker: Checker) -> None:
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + hb(3, 0.05, 1.04)
    assert checker.findings(candump(sorted(fr)), select="H") == []


def test_h001_consumer_time_from_network_file(checker: Checker) -> None:
    gap_140ms = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + hb(2, 1.04, 2.0)
    gap_250ms = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + hb(2, 1.15, 2.0)
    short = "[nodes.2]\nconsumer_timeout_ms = 120\n"
    long = "[nodes.2]\nconsumer_timeout_ms = 300\n"
    assert checker.findings(candump(gap_140ms), select="H") == []
    assert checker.findings(candump(gap_140ms), select="H", network=short) == [
        ("H001", 2, 1.02)]
    assert checker.findings(candump(gap_250ms), select="H") == [("H001", 2, 1.05)]
    assert checker.findings(candump(gap_250ms), select="H", network=long) == []


def test_h001_consumer_time_wins_over_producer_time(checker: Checker) -> None:
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + hb(2, 1.1, 2.0)  # gap 200 ms
    net = "[nodes.2]\nheartbeat_ms = 100\nconsumer_timeout_ms = 250\n"
    assert checker.findings(candump(fr), select="H", network=net) == []
    assert checker.findings(candump(fr), select="H", network="[nodes.2]\nheartbeat_ms = 100\n"
                            ) == [("H001", 2, 1.05)]


def test_h001_configured_producer_time(checker: Checker) -> None:
    # one heartbeat only: a producer because 1017h is configured, timeout 1.5 x 100 ms
    fr = [(0.0, "702#00"), (0.1, "702#7F")] + hb(3, 0.0, 1.0)
    net = "[nodes.2]\nheartbeat_ms = 100\n"
    assert checker.findings(candump(sorted(fr)), select="H", network=net) == [
        ("H001", 2, 0.25)]
    assert checker.findings(candump(sorted(fr)), select="H") == []  # not a known producer


def test_h001_configured_period_beats_measured_one(checker: Checker) -> None:
    # heartbeats every 100 ms but 1017h says 50 ms: timeout 75 ms; the boot-up starts no gap
    fr = [(0.0, "702#00")] + hb(2, 0.1, 0.5)
    net = "[nodes.2]\nheartbeat_ms = 50\n"
    # every interval exceeds that assumed timeout (no consumer time): one finding with the
    # count (issue 38, item 3), at the first gap's expiry
    res = checker.run(candump(fr), select="H001", network=net)
    assert [(f.rule, f.node, round(f.time - 1000.0, 3), f.basis) for f in res.findings] == [
        ("H001", 2, 0.175, "assumed")]
    assert "exceeds the assumed timeout 3 times in a row" in res.findings[0].message


def test_h001_timeout_factor_from_profile(checker: Checker) -> None:
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + hb(2, 1.08, 2.0)  # gap 180 ms
    assert checker.findings(candump(fr), select="H001") == [("H001", 2, 1.05)]
    assert checker.findings(candump(fr), select="H001", profile="lenient") == []


def test_h001_reset_ends_a_gap(checker: Checker) -> None:
    # node 2 is reset 60 ms after its last heartbeat and boots 0.5 s later: no timeout
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(0.96, "000#8102"), (1.5, "702#00")]
          + hb(2, 1.6, 2.0))
    assert checker.findings(candump(sorted(fr))) == []


def test_h001_reset_after_the_timeout_expired(checker: Checker) -> None:
    # the master resets node 2 because its heartbeat was lost: the timeout still counts
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.3, "000#8102"), (1.5, "702#00")]
          + hb(2, 1.6, 2.0))
    assert checker.findings(candump(fr)) == [("H001", 2, 1.05)]


def test_h001_not_a_producer_with_a_single_heartbeat(checker: Checker) -> None:
    fr = [(0.0, "702#00"), (0.1, "702#7F")] + hb(3, 0.0, 2.0)
    assert checker.findings(candump(sorted(fr)), select="H") == []


# --- H002 -------------------------------------------------------------------------------

def test_h002_too_early_complete_list(checker: Checker) -> None:
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.0, "702#7F"), (1.02, "702#7F"),
                                                  (1.04, "702#7F")] + hb(2, 1.1, 2.0)
    res = checker.run(candump(fr))
    assert [(f.rule, f.node, round(f.time - 1000.0, 3)) for f in res.findings] == [
        ("H002", 2, 1.02)]
    assert res.findings[0].severity == "warning"
    assert "(2 heartbeats)" in res.findings[0].message


def test_h002_not_a_heartbeat_stamped_more_than_a_period_back(checker: Checker) -> None:
    """A heartbeat written with a stamp 0.5 s back (time goes on after it) came no earlier
    than the others: I005 counts the step back. One stamped 20 ms back (a merged log's
    reorder within a period) is still too early."""
    fr = [(0.0, "702#00")] + hb(2, 0.1, 2.0)
    back = candump(fr[:11] + [(0.52, "702#7F")] + fr[11:])
    assert checker.findings(back, select="H002") == []
    assert "I005" in {f.rule for f in checker.run(back).findings}
    near = candump(fr[:11] + [(0.98, "702#7F")] + fr[11:])
    assert [r for r, _n, _t in checker.findings(near, select="H002")] == ["H002"]


def test_h002_configured_period(checker: Checker) -> None:
    # 1017h = 300 ms but the node sends every 100 ms: one run from the second heartbeat
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0)
    net = "[nodes.2]\nheartbeat_ms = 300\n"
    res = checker.run(candump(fr), select="H002", network=net)
    assert [(f.rule, f.node, round(f.time - 1000.0, 3)) for f in res.findings] == [
        ("H002", 2, 0.2)]
    assert "(8 heartbeats)" in res.findings[0].message


def test_h002_not_first_heartbeat_after_bootup(checker: Checker) -> None:
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.0, "702#00"), (1.01, "702#7F")] + hb(
        2, 1.11, 2.0)
    assert checker.findings(candump(fr), select="H002") == []


def test_h002_not_first_heartbeat_after_nmt_command(checker: Checker) -> None:
    # enter pre-operational while pre-operational: the stack answers with a heartbeat at once
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(0.905, "000#8002"), (0.91, "702#7F")] + hb(
        2, 1.01, 2.0)
    assert checker.findings(candump(sorted(fr)), select="H002") == []
    broadcast = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(0.905, "000#8000"),
                                                         (0.91, "702#7F")] + hb(2, 1.01, 2.0)
    assert checker.findings(candump(sorted(broadcast)), select="H002") == []


def test_h002_not_for_a_heartbeat_reporting_another_state(checker: Checker) -> None:
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0, "05") + [(0.91, "702#04")] + hb(2, 1.01, 2.0, "04")
    assert checker.findings(candump(sorted(fr)), select="H002") == []


def test_h002_early_factor_boundary(checker: Checker) -> None:
    # exactly 0.5 x 100 ms is not "closer than" the limit
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(0.95, "702#7F")] + hb(2, 1.0, 2.0)
    assert checker.findings(candump(sorted(fr)), select="H002") == []
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(0.949, "702#7F")] + hb(2, 1.0, 2.0)
    assert checker.findings(candump(sorted(fr)), select="H002") == [("H002", 2, 0.949)]
