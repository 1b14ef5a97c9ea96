"""CAN-ID and frame-format rules C001 (restricted-can-id), C002 (malformed-nmt-command),
C003 (malformed-error-control), C004 (unknown-nmt-state)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from conftest import Checker, candump
from traces import HEALTHY_NET, hb, healthy, profile

from nmtcheck.results import InputResult


def found(res: InputResult) -> list[tuple[str, int | None, float]]:
    return [(f.rule, f.node, round(f.time - 1000.0, 3)) for f in res.findings]


def base() -> list[tuple[float, str]]:
    """Node 2 boots and heartbeats PRE-OPERATIONAL every 100 ms for 2 s."""
    return [(0.0, "702#00")] + hb(2, 0.1, 2.0)


def test_healthy_trace_is_clean(checker: Checker) -> None:
    assert checker.findings(candump(healthy()), select="C") == []
    assert checker.findings(candump(healthy()), select="C", network=HEALTHY_NET) == []


# --- C001 -------------------------------------------------------------------------------

def test_c001_restricted_ids_complete_list(checker: Checker) -> None:
    fr = base() + [(0.21, "123#00"), (0.31, "123#01"), (0.41, "123#R"), (0.51, "050#00"),
                   (0.61, "6E0#11"), (0.71, "780#00")]
    res = checker.run(candump(sorted(fr)))
    assert found(res) == [("C001", None, 0.21), ("C001", None, 0.51), ("C001", None, 0.61),
                          ("C001", None, 0.71)]
    assert res.findings[0].message == "CAN-ID 123h is reserved by CiA 301 (3 frames)"
    assert res.findings[0].frame_index == 3 and res.findings[0].line == 4


@pytest.mark.parametrize("can_id", ["001", "07F", "101", "180", "6E0", "6FF", "780", "7FF"])
def test_c001_range_edges_are_restricted(checker: Checker, can_id: Any) -> None:
    fr = base() + [(0.55, f"{can_id}#00")]
    if can_id == "001":  # global fail-safe command (CiA 304): allowed by default
        assert checker.findings(candump(sorted(fr))) == []
    else:
        assert checker.findings(candump(sorted(fr))) == [("C001", None, 0.55)]


@pytest.mark.parametrize("can_id", ["080", "100", "181", "6DF", "77F", "7E4", "7E5", "071",
                                    "076"])
def test_c001_allowed_and_unrestricted_ids(checker: Checker, can_id: Any) -> None:
    fr = base() + [(0.55, f"{can_id}#00")]
    assert checker.findings(candump(sorted(fr)), select="C001") == []


def test_c001_allow_list_from_profile(checker: Checker, tmp_path: Path) -> None:
    fr = base() + [(0.55, "123#00"), (0.65, "7E5#00")]
    prof = profile(tmp_path, "[rules.C001]\nallow = [0x123]\n")
    assert checker.findings(candump(sorted(fr)), profile=prof) == [("C001", None, 0.65)]


def test_c001_one_finding_per_id_and_channel(checker: Checker) -> None:
    text = candump(sorted(base() + [(0.55, "123#00"), (0.75, "123#00")])) + candump(
        [(1.95, "123#00"), (2.0, "123#00")], channel="can1")
    res = checker.run(text)
    assert [(f.rule, f.channel, round(f.time - 1000.0, 3)) for f in res.findings] == [
        ("C001", "can0", 0.55), ("C001", "can1", 1.95)]


def test_c001_extended_frames_are_not_checked(checker: Checker) -> None:
    fr = base() + [(0.55, "00000123#00"), (0.65, "00000780#00")]
    assert checker.findings(candump(sorted(fr))) == []


# --- C002 -------------------------------------------------------------------------------

def test_c002_malformed_nmt_frames_complete_list(checker: Checker) -> None:
    fr = base() + [(0.21, "000#R"), (0.31, "000#010200"), (0.41, "000#0302"),
                   (0.51, "000#0180"), (0.61, "000#01")]
    res = checker.run(candump(sorted(fr)))
    # only the 2-byte frame with an unknown specifier names a node (node 2)
    assert found(res) == [("C002", None, 0.21), ("C002", None, 0.31), ("C002", 2, 0.41),
                          ("C002", None, 0.51), ("C002", None, 0.61)]
    assert [f.message for f in res.findings] == [
        "malformed NMT frame: remote frame on CAN-ID 000h (NMT commands are data frames)",
        "malformed NMT frame: DLC 3 (an NMT command has DLC 2)",
        "malformed NMT frame: unknown command specifier 03h",
        "malformed NMT frame: node-ID 128 above 127",
        "malformed NMT frame: DLC 1 (an NMT command has DLC 2)",
    ]
    assert all(f.severity == "error" for f in res.findings)


def test_c002_malformed_command_is_not_applied(checker: Checker) -> None:
    # a start with DLC 8: the node keeps PRE-OPERATIONAL, so its 7Fh heartbeats are no S004
    fr = base() + [(0.45, "000#0102000000000000")]
    res = checker.run(candump(sorted(fr)))
    assert found(res) == [("C002", None, 0.45)]
    node = res.model.channels[0].nodes[2]
    assert [iv.state for iv in node.intervals] == ["PRE-OPERATIONAL"]
    assert len(node.commands) == 0


def test_c002_malformed_broadcast_is_not_applied(checker: Checker) -> None:
    fr = base() + [(0.45, "000#8100AA")]  # reset all, DLC 3: no B001 for node 2
    res = checker.run(candump(sorted(fr)))
    assert found(res) == [("C002", None, 0.45)]
    assert [iv.state for iv in res.model.channels[0].nodes[2].intervals] == ["PRE-OPERATIONAL"]


def test_c002_consecutive_frames_one_finding_per_node(checker: Checker) -> None:
    fr = [(0.0, "702#00"), (0.01, "703#00")] + hb(2, 0.1, 2.0) + hb(3, 0.11, 2.0) + [
        (0.45, "000#0302"), (0.46, "000#0302"), (0.47, "000#0303"), (0.48, "000#0303"),
        (0.49, "000#0303")]
    res = checker.run(candump(sorted(fr)))
    assert found(res) == [("C002", 2, 0.45), ("C002", 3, 0.47)]
    assert [f.message[-10:] for f in res.findings] == ["(2 frames)", "(3 frames)"]


def test_c002_not_for_a_node_in_unknown_state(checker: Checker) -> None:
    # SPEC §3: C002 is not exempt from the UNKNOWN rule; broadcasts have no node
    fr = [(0.0, "000#0305"), (0.05, "000#010000")] + base() + [(0.5, "705#00")]
    assert checker.findings(candump(sorted(fr))) == [("C002", None, 0.05)]


# --- C003 -------------------------------------------------------------------------------

def test_c003_wrong_dlc_complete_list(checker: Checker) -> None:
    fr = base() + [(0.55, "702#7F00"), (1.05, "702#")]
    res = checker.run(candump(sorted(fr)))
    assert found(res) == [("C003", 2, 0.55), ("C003", 2, 1.05)]
    assert res.findings[0].message == (
        "malformed error-control frame from node 2: DLC 2 (must be 1)")
    assert res.findings[1].message == (
        "malformed error-control frame from node 2: DLC 0 (must be 1)")


def test_c003_heartbeat_with_bit_7(checker: Checker) -> None:
    fr = [x for x in base() if x[0] != 0.5] + [(0.5, "702#FF")]
    res = checker.run(candump(sorted(fr)))
    assert found(res) == [("C003", 2, 0.5)]
    assert res.findings[0].message.endswith("heartbeat FFh has the reserved bit 7 set")


def test_c003_remote_requests_with_dlc_0_or_1_are_normal(checker: Checker) -> None:
    fr = [(0.0, "705#00"), (0.1, "705#R"), (0.102, "705#7F"), (0.2, "705#R1"),
          (0.202, "705#FF"), (0.3, "705#R0"), (0.302, "705#7F")]
    assert checker.findings(candump(fr)) == []


def test_c003_guarding_response_with_bit_7_is_not_c003(checker: Checker) -> None:
    fr = [(0.0, "705#00"), (0.1, "705#R"), (0.102, "705#7F"), (0.2, "705#R"), (0.202, "705#FF")]
    assert checker.findings(candump(fr), select="C") == []


def test_c003_consecutive_frames_one_finding_per_interval(checker: Checker) -> None:
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 0.5) + [(0.45, "000#0102")] + hb(2, 0.5, 1.0, "85")
          + [(0.95, "000#0202")] + hb(2, 1.0, 1.5, "84"))
    res = checker.run(candump(sorted(fr)), select="C")
    assert found(res) == [("C003", 2, 0.5), ("C003", 2, 1.0)]
    assert [f.message[-10:] for f in res.findings] == ["(5 frames)", "(5 frames)"]


def test_c003_exempt_from_unknown(checker: Checker) -> None:
    # node 3's only error-control frames are malformed: it stays UNKNOWN, C003 still fires
    fr = base() + [(0.55, "703#7F00"), (0.65, "703#7F00")]
    res = checker.run(candump(sorted(fr)))
    assert found(res) == [("C003", 3, 0.55)]
    assert [iv.state for iv in res.model.channels[0].nodes[3].intervals] == ["UNKNOWN"]


# --- C004 -------------------------------------------------------------------------------

def test_c004_unknown_state_complete_list(checker: Checker) -> None:
    fr = [x for x in base() if x[0] not in (0.5, 0.6)] + [(0.5, "702#02"), (0.6, "702#02")]
    res = checker.run(candump(sorted(fr)))
    assert found(res) == [("C004", 2, 0.5)]
    assert res.findings[0].severity == "warning"
    assert res.findings[0].message == "node 2 reports unknown NMT state 02h (2 frames)"
    # the timeline keeps the previous state
    assert [iv.state for iv in res.model.channels[0].nodes[2].intervals] == ["PRE-OPERATIONAL"]


@pytest.mark.parametrize("code", ["00", "04", "05", "7F"])
def test_c004_known_states(checker: Checker, code: Any) -> None:
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0, code)
    assert checker.findings(candump(fr), select="C004") == []


def test_c004_guarding_response(checker: Checker) -> None:
    fr = [(0.0, "705#00"), (0.1, "705#R"), (0.102, "705#7F"), (0.2, "705#R"), (0.202, "705#E0")]
    assert checker.findings(candump(fr)) == [("C004", 5, 0.202)]


def test_c004_exempt_from_unknown(checker: Checker) -> None:
    fr = base() + hb(3, 0.15, 1.0, "60")
    res = checker.run(candump(sorted(fr)))
    assert found(res) == [("C004", 3, 0.15)]
    assert [iv.state for iv in res.model.channels[0].nodes[3].intervals] == ["UNKNOWN"]
