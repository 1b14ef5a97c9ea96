"""Network rules N001 (missing-node) and N002 (duplicate-node-id)."""

from __future__ import annotations

from conftest import Checker, candump
from traces import HEALTHY_NET, hb, healthy

from nmtcheck.results import InputResult


def found(res: InputResult) -> list[tuple[str, int | None, float]]:
    start = res.stats.start or 0.0
    return [(f.rule, f.node, round(f.time - start, 3)) for f in res.findings]


def two_devices(offset: float, t1: float = 1.0, state_a: str = "7F", state_b: str = "7F"
                ) -> list[tuple[float, str]]:
    """Two devices, already running, heartbeating as node 5 every 100 ms, the second `offset`
    s after the first and once less (as many short as long intervals: the median period
    is 50 ms, no heartbeat timeout)."""
    return sorted([(0.0, "080#")] + hb(5, 0.1, t1, state_a)
                  + hb(5, 0.1 + offset, t1 - 0.1 + offset, state_b))


def test_healthy_trace_is_clean(checker: Checker) -> None:
    assert checker.findings(candump(healthy()), select="N") == []
    assert checker.findings(candump(healthy()), select="N", network=HEALTHY_NET) == []
    assert checker.findings(candump(healthy()), network=HEALTHY_NET) == []


# --- N001 -------------------------------------------------------------------------------

def test_n001_missing_node_complete_list(checker: Checker) -> None:
    fr = [(0.2, "702#00"), (0.21, "703#00")] + hb(2, 0.3, 1.0) + hb(3, 0.31, 1.0)
    net = "[nodes.2]\n[nodes.3]\n[nodes.8]\n"
    res = checker.run(candump(sorted(fr)), network=net)
    assert found(res) == [("N001", 8, 0.0)]
    f = res.findings[0]
    assert (f.severity, f.channel, f.frame_index, f.line) == ("error", "can0", 0, 1)
    assert f.time == res.stats.start


def test_n001_addressed_but_silent_node(checker: Checker) -> None:
    # node 8 gets an NMT start, an RPDO and guarding requests, but never transmits
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 1.0)
          + [(0.45, "000#0108"), (0.5, "208#00"), (0.55, "708#R"), (0.65, "708#R")])
    assert checker.findings(candump(sorted(fr)), select="N",
                            network="[nodes.2]\n[nodes.8]\n") == [("N001", 8, 0.0)]


def test_n001_any_transmitted_frame_counts(checker: Checker) -> None:
    # node 3 only sends a TPDO (its NMT state stays UNKNOWN): it is present
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(0.5, "183#00")]
    assert checker.findings(candump(sorted(fr)), network="[nodes.2]\n[nodes.3]\n") == []


def test_n001_every_channel_unless_one_is_named(checker: Checker) -> None:
    can0 = [(0.0, "702#00"), (0.01, "703#00")] + hb(2, 0.1, 1.0) + hb(3, 0.11, 1.0)
    can1 = [(0.02, "702#00")] + hb(2, 0.12, 1.0)
    text = candump(sorted(can0)) + candump(can1, channel="can1")
    res = checker.run(text, network="[nodes.2]\n[nodes.3]\n", select="N")
    assert [(f.rule, f.node, f.channel) for f in res.findings] == [("N001", 3, "can1")]
    res = checker.run(text, network='[nodes.2]\n[nodes.3]\nchannel = "can0"\n', select="N")
    assert res.findings == []
    res = checker.run(text, network='[nodes.2]\nchannel = "can2"\n', select="N")
    assert [(f.rule, f.node, f.channel) for f in res.findings] == [("N001", 2, "can2")]


# --- N002 -------------------------------------------------------------------------------

def test_n002_short_long_alternation_complete_list(checker: Checker) -> None:
    # heartbeats at 0.1, 0.135, 0.2, 0.235, 0.3: intervals 35 / 65 ms alternate
    res = checker.run(candump(two_devices(0.035)))
    assert found(res) == [("N002", 5, 0.3)]
    assert res.findings[0].severity == "warning"
    assert "alternate short/long (0.035, 0.065, 0.035, 0.065 s)" in res.findings[0].message


def test_n002_state_pattern_a_b_a_b(checker: Checker) -> None:
    res = checker.run(candump(two_devices(0.05, state_a="05", state_b="7F")), select="N")
    assert found(res) == [("N002", 5, 0.25)]
    assert "alternates between OPERATIONAL and PRE-OPERATIONAL" in res.findings[0].message


def test_n002_one_finding_per_node(checker: Checker) -> None:
    fr = two_devices(0.035, t1=3.0)
    assert checker.findings(candump(fr), select="N") == [("N002", 5, 0.3)]


def test_n002_state_pattern_split_by_command_or_bootup(checker: Checker) -> None:
    fr = [(0.0, "705#00"), (0.1, "705#05"), (0.2, "705#7F"), (0.25, "000#0105"),
          (0.3, "705#05"), (0.4, "705#7F")]
    assert checker.findings(candump(fr), select="N") == []
    fr = [(0.0, "705#00"), (0.1, "705#05"), (0.2, "705#7F"), (0.25, "705#00"),
          (0.3, "705#05"), (0.4, "705#7F")]
    assert checker.findings(candump(fr), select="N") == []


def test_n002_alternation_needs_four_intervals(checker: Checker) -> None:
    fr = [(0.0, "705#00"), (0.1, "705#7F"), (0.135, "705#7F"), (0.2, "705#7F"),
          (0.235, "705#7F")]
    assert checker.findings(candump(fr), select="N") == []


def test_n002_alternation_needs_long_at_least_1_5_short(checker: Checker) -> None:
    assert checker.findings(candump(two_devices(0.045)), select="N") == []  # 55 / 45 ms
    assert checker.findings(candump(two_devices(0.04)), select="N") == [("N002", 5, 0.3)]
