"""The NMT state timeline (SPEC §2): evidence, broadcasts, OFFLINE, classification, period,
and the UNKNOWN exemption of SPEC §3."""

from __future__ import annotations

import pytest
from conftest import Checker, candump
from traces import hb, healthy

from nmtcheck.results import InputResult


def ivs(res: InputResult, node: int, chan: int = 0) -> list[tuple[str, float, float, str]]:
    """(state, start, end, source) of a node's intervals, times as offsets into the trace."""
    t0 = res.stats.start or 0.0
    return [(iv.state, round(iv.start - t0, 3), round(iv.end - t0, 3), iv.source)
            for iv in res.model.channels[chan].nodes[node].intervals]


def kinds(res: InputResult, node: int, chan: int = 0) -> list[str]:
    return [f.kind for f in res.model.channels[chan].nodes[node].ec]


def found(res: InputResult) -> list[tuple[str, int | None, float]]:
    return [(f.rule, f.node, round(f.time - (res.stats.start or 0.0), 3)) for f in res.findings]


# --- states and evidence ----------------------------------------------------------------

def test_healthy_timeline(checker: Checker) -> None:
    res = checker.run(candump(healthy()))
    assert res.findings == []
    end = round((res.stats.end or 0.0) - (res.stats.start or 0.0), 3)
    assert ivs(res, 2) == [
        ("PRE-OPERATIONAL", 0.0, 0.5, "bootup"),
        ("OPERATIONAL", 0.5, 3.0, "command"),
        ("STOPPED", 3.0, 4.0, "command"),
        ("PRE-OPERATIONAL", 4.0, end, "command"),
    ]
    assert ivs(res, 4)[-2:] == [("INITIALISING", 4.5, 4.56, "command"),
                                ("PRE-OPERATIONAL", 4.56, end, "bootup")]
    assert ivs(res, 5)[:2] == [("UNKNOWN", 0.0, 0.043, "start"),
                               ("PRE-OPERATIONAL", 0.043, 0.5, "heartbeat")]
    assert ivs(res, 6)[:3] == [("UNKNOWN", 0.0, 2.0, "start"),
                               ("PRE-OPERATIONAL", 2.0, 2.2, "bootup"),
                               ("OPERATIONAL", 2.2, 3.0, "command")]
    assert ivs(res, 7)[:2] == [("UNKNOWN", 0.0, 0.03, "start"),
                               ("PRE-OPERATIONAL", 0.03, 0.5, "bootup")]
    nodes = {m.node: m for m in res.nodes()}
    assert {n: m.error_control for n, m in nodes.items()} == {
        2: "heartbeat", 3: "heartbeat", 4: "heartbeat", 5: "heartbeat", 6: "heartbeat",
        7: "guarding"}
    assert nodes[7].period_s is None and nodes[7].period_source == "none"


def test_observed_state_wins_over_command(checker: Checker) -> None:
    # the 7Fh at 0.5 s is 50 ms after the start: it may have been queued before the node
    # processed it (stale, SPEC §2); the one at 0.6 s is evidence
    fr = [(0.0, "702#00")] + hb(2, 0.1, 0.5) + [(0.45, "000#0102")] + hb(2, 0.5, 1.0)
    res = checker.run(candump(sorted(fr)), select="B")
    assert ivs(res, 2) == [("PRE-OPERATIONAL", 0.0, 0.45, "bootup"),
                           ("OPERATIONAL", 0.45, 0.6, "command"),
                           ("PRE-OPERATIONAL", 0.6, 0.9, "heartbeat")]


def test_reset_is_initialising_until_bootup(checker: Checker) -> None:
    fr = [(0.0, "702#00")] + hb(2, 0.1, 0.5) + [(0.45, "000#8202"), (0.6, "702#00")] + hb(
        2, 0.7, 1.0)
    res = checker.run(candump(sorted(fr)))
    assert res.findings == []
    assert ivs(res, 2) == [("PRE-OPERATIONAL", 0.0, 0.45, "bootup"),
                           ("INITIALISING", 0.45, 0.6, "command"),
                           ("PRE-OPERATIONAL", 0.6, 0.9, "bootup")]


def test_unknown_state_codes_keep_the_previous_state(checker: Checker) -> None:
    fr = [(0.0, "702#00")] + hb(2, 0.1, 0.5, "05") + hb(2, 0.5, 1.0, "02")
    res = checker.run(candump(fr), select="C004")
    assert found(res) == [("C004", 2, 0.5)]
    assert ivs(res, 2) == [("PRE-OPERATIONAL", 0.0, 0.1, "bootup"),
                           ("OPERATIONAL", 0.1, 0.9, "heartbeat")]


def test_which_nodes_show_up(checker: Checker) -> None:
    # 702 boot-up, 583 SDO response, 084 EMCY, 186 TPDO, direct command to 8: nodes;
    # an RPDO to 9, a remote request to 10 and a broadcast are not
    fr = [(0.0, "702#00"), (0.1, "583#4300100000000000"), (0.2, "084#0000000000000000"),
          (0.3, "186#00"), (0.4, "000#0108"), (0.5, "209#00"), (0.6, "70A#R"),
          (0.7, "000#0100")]
    res = checker.run(candump(fr))
    assert sorted(res.model.channels[0].nodes) == [2, 3, 4, 6, 8]
    assert ivs(res, 8) == [("UNKNOWN", 0.0, 0.4, "start"), ("OPERATIONAL", 0.4, 0.7, "command")]
    assert ivs(res, 3) == [("UNKNOWN", 0.0, 0.7, "start"), ("OPERATIONAL", 0.7, 0.7, "command")]


# --- broadcast commands -----------------------------------------------------------------

def test_broadcast_applies_only_to_nodes_already_seen(checker: Checker) -> None:
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(0.45, "000#0100")] + [(0.6, "703#00")]
          + hb(3, 0.7, 1.0) + [(0.75, "000#0200")])
    fr = [(t, "702#05" if f == "702#7F" and 0.45 < t < 0.75 else f) for t, f in fr]
    fr = [(t, f[:4] + "04" if f[:3] in ("702", "703") and t > 0.75 else f) for t, f in fr]
    res = checker.run(candump(sorted(fr)))
    assert res.findings == []
    assert ivs(res, 2) == [("PRE-OPERATIONAL", 0.0, 0.45, "bootup"),
                           ("OPERATIONAL", 0.45, 0.75, "command"),
                           ("STOPPED", 0.75, 0.9, "command")]
    # node 3 appeared after the broadcast start: it stays PRE-OPERATIONAL, then is stopped
    assert ivs(res, 3) == [("UNKNOWN", 0.0, 0.6, "start"),
                           ("PRE-OPERATIONAL", 0.6, 0.75, "bootup"),
                           ("STOPPED", 0.75, 0.9, "command")]
    node3 = res.model.channels[0].nodes[3]
    t0 = res.stats.start or 0.0
    assert [(round(c.ts - t0, 3), c.cs, c.broadcast) for c in node3.commands] == [
        (0.75, 0x02, True)]


def test_broadcast_reaches_a_node_seen_only_through_a_direct_command(checker: Checker) -> None:
    fr = [(0.0, "702#00"), (0.1, "000#0108"), (0.2, "000#0200"), (0.3, "702#7F")]
    res = checker.run(candump(fr))
    assert ivs(res, 8) == [("UNKNOWN", 0.0, 0.1, "start"), ("OPERATIONAL", 0.1, 0.2, "command"),
                           ("STOPPED", 0.2, 0.3, "command")]


def test_broadcast_is_per_channel(checker: Checker) -> None:
    text = candump([(0.0, "702#00"), (0.1, "000#0100"), (0.2, "702#05")]) + candump(
        [(0.3, "702#00"), (0.4, "702#7F")], channel="can1")
    res = checker.run(text)
    assert [cm.name for cm in res.model.channels] == ["can0", "can1"]
    assert [iv[0] for iv in ivs(res, 2, chan=0)] == ["PRE-OPERATIONAL", "OPERATIONAL"]
    assert [iv[0] for iv in ivs(res, 2, chan=1)] == ["UNKNOWN", "PRE-OPERATIONAL"]


# --- OFFLINE ----------------------------------------------------------------------------

def test_offline_from_heartbeat_timeout_to_next_frame_then_previous_state(checker: Checker) -> None:
    # node 2 is OPERATIONAL (commanded), stops heartbeating at 0.9 s, sends a TPDO at 1.5 s
    fr = ([(0.0, "702#00"), (0.45, "000#0102")] + hb(2, 0.1, 0.5) + hb(2, 0.5, 1.0, "05")
          + [(1.5, "182#01"), (1.6, "702#05"), (1.7, "702#05")])
    res = checker.run(candump(sorted(fr)))
    assert found(res) == [("H001", 2, 1.05)]
    assert ivs(res, 2) == [("PRE-OPERATIONAL", 0.0, 0.45, "bootup"),
                           ("OPERATIONAL", 0.45, 1.05, "command"),
                           ("OFFLINE", 1.05, 1.5, "timeout"),
                           ("OPERATIONAL", 1.5, 1.7, "command")]


def test_offline_ends_with_the_state_a_frame_reports(checker: Checker) -> None:
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.5, "702#04")] + hb(2, 1.6, 2.0, "04")
    res = checker.run(candump(fr), select="H")
    assert ivs(res, 2) == [("PRE-OPERATIONAL", 0.0, 1.05, "bootup"),
                           ("OFFLINE", 1.05, 1.5, "timeout"),
                           ("STOPPED", 1.5, 1.9, "heartbeat")]


def test_offline_until_the_end_of_the_trace(checker: Checker) -> None:
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + hb(3, 0.05, 2.0) + [(1.5, "202#00")]
    res = checker.run(candump(sorted(fr)))
    assert found(res) == [("H001", 2, 1.05)]  # an RPDO is not node 2's frame
    assert ivs(res, 2)[-1] == ("OFFLINE", 1.05, 1.95, "timeout")


def test_offline_ended_by_sdo_response_or_emcy(checker: Checker) -> None:
    for frame in ("582#4300100000000000", "082#0000000000000000"):
        fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.3, frame)] + hb(2, 1.4, 2.0)
        res = checker.run(candump(fr))
        assert ivs(res, 2) == [("PRE-OPERATIONAL", 0.0, 1.05, "bootup"),
                               ("OFFLINE", 1.05, 1.3, "timeout"),
                               ("PRE-OPERATIONAL", 1.3, 1.9, "bootup")]


def test_offline_from_guarding_timeout(checker: Checker) -> None:
    fr = [(0.0, "705#00"), (0.1, "705#R"), (0.102, "705#7F"), (0.2, "705#R"),
          (0.3, "705#R"), (0.302, "705#FF")]
    res = checker.run(candump(fr))
    assert found(res) == [("G002", 5, 0.3)]
    assert ivs(res, 5) == [("PRE-OPERATIONAL", 0.0, 0.3, "bootup"),
                           ("OFFLINE", 0.3, 0.302, "timeout"),
                           ("PRE-OPERATIONAL", 0.302, 0.302, "guarding")]


def test_offline_after_reset_that_followed_a_timeout(checker: Checker) -> None:
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.3, "000#8102"), (1.5, "702#00")]
          + hb(2, 1.6, 2.0))
    res = checker.run(candump(fr))
    assert found(res) == [("H001", 2, 1.05)]
    assert ivs(res, 2) == [("PRE-OPERATIONAL", 0.0, 1.05, "bootup"),
                           ("OFFLINE", 1.05, 1.5, "timeout"),
                           ("PRE-OPERATIONAL", 1.5, 1.9, "bootup")]


# --- guarding response or heartbeat (SPEC §2) -------------------------------------------

def test_answer_before_two_heartbeats_is_a_guarding_response(checker: Checker) -> None:
    fr = [(0.0, "705#00"), (0.1, "705#R"), (0.15, "705#7F"), (0.2, "705#7F"), (0.3, "705#7F")]
    res = checker.run(candump(fr))
    assert kinds(res, 5) == ["bootup", "request", "guard", "heartbeat", "heartbeat"]


def test_after_two_heartbeats_an_answer_is_a_heartbeat_unless_toggled_or_early(
        checker: Checker) -> None:
    base = [(0.0, "705#00")] + hb(5, 0.1, 0.5)
    on_time = base + [(0.45, "705#R"), (0.5, "705#7F")]
    toggled = base + [(0.45, "705#R"), (0.5, "705#FF")]
    early = base + [(0.42, "705#R"), (0.43, "705#7F"), (0.5, "705#7F")]
    assert kinds(checker.run(candump(sorted(on_time))), 5)[-2:] == ["request", "heartbeat"]
    assert kinds(checker.run(candump(sorted(toggled))), 5)[-2:] == ["request", "guard"]
    assert kinds(checker.run(candump(sorted(early))), 5)[-3:] == ["request", "guard",
                                                                  "heartbeat"]


def test_answer_to_a_stale_request_is_not_a_guarding_response(checker: Checker) -> None:
    # the request is older than G002's response_timeout_ms (1000 ms)
    fr = [(0.0, "705#00"), (0.1, "705#R"), (1.2, "705#7F"), (1.3, "705#7F")]
    res = checker.run(candump(fr), select="G")
    assert kinds(res, 5) == ["bootup", "request", "heartbeat", "heartbeat"]
    assert found(res) == [("G002", 5, 1.1)]


def test_bootup_restarts_the_heartbeat_count(checker: Checker) -> None:
    fr = ([(0.0, "705#00")] + hb(5, 0.1, 0.5) + [(0.5, "705#00"), (0.55, "705#R"),
                                                   (0.6, "705#7F")])
    assert kinds(checker.run(candump(fr)), 5)[-3:] == ["bootup", "request", "guard"]


# --- heartbeat period --------------------------------------------------------------------

def test_period_is_the_configured_producer_time(checker: Checker) -> None:
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0)
    m = checker.run(candump(fr), network="[nodes.2]\nheartbeat_ms = 200\n").nodes()[0]
    assert (m.period_s, m.period_source) == (0.2, "configured")


def test_period_is_the_median_without_bootup_or_reset_intervals(checker: Checker) -> None:
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 0.5) + hb(2, 0.52, 0.6)  # 0.4 -> 0.52: 120 ms
          + [(0.7, "000#8102"), (1.0, "702#00")] + hb(2, 1.05, 1.3, period=0.07)
          + [(1.5, "702#00"), (1.8, "702#7F")])
    m = checker.run(candump(fr)).nodes()[0]
    # 100, 100, 100, 120 ms before the reset; 70, 70, 70 after the boot-up;
    # 520 -> 1050 contains the reset, 1.26 -> 1.8 contains a boot-up
    assert m.period_source == "measured"
    assert m.period_s is not None and round(m.period_s, 6) == 0.1


def test_no_period_without_two_heartbeats(checker: Checker) -> None:
    m = checker.run(candump([(0.0, "702#00"), (0.1, "702#7F")])).nodes()[0]
    assert (m.period_s, m.period_source) == (None, "none")


# --- the UNKNOWN exemption (SPEC §3) ----------------------------------------------------

def test_no_finding_while_the_node_is_unknown(checker: Checker) -> None:
    # node 5 is seen through a TPDO only (UNKNOWN): its unanswered guarding requests are no
    # G002; once a guarding response reported its state, the next unanswered run is
    fr = [(0.0, "185#00"), (0.1, "705#R"), (0.2, "705#R"), (0.3, "705#R"), (0.302, "705#7F"),
          (0.4, "705#R"), (0.5, "705#R"), (0.6, "705#R"), (0.602, "705#FF")]
    res = checker.run(candump(fr))
    assert ivs(res, 5) == [("UNKNOWN", 0.0, 0.302, "start"),
                           ("PRE-OPERATIONAL", 0.302, 0.5, "guarding"),
                           ("OFFLINE", 0.5, 0.602, "timeout"),
                           ("PRE-OPERATIONAL", 0.602, 0.602, "guarding")]
    assert found(res) == [("G002", 5, 0.5)]


def test_exempt_rules_fire_while_unknown(checker: Checker) -> None:
    # C003 and C004 for a node whose state stays UNKNOWN, N001 for a node never seen
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(0.15, "703#7F00"), (0.25, "704#60")]
    res = checker.run(candump(sorted(fr)), network="[nodes.2]\n[nodes.9]\n")
    assert found(res) == [("N001", 9, 0.0), ("C003", 3, 0.15), ("C004", 4, 0.25)]


def test_bootup_while_guarding_request_pending_is_a_bootup(checker: Checker) -> None:
    """Resetting a guarded node: the 00h answering nothing is its boot-up, not a guarding
    response (a node in Initialisation cannot answer), so no G001/B001/G002 false alarm."""
    fr = [(0.0, "705#00")]
    t, toggle = 0.1, 0
    while t < 1.0:
        fr += [(t, "705#R"), (t + 0.005, f"705#{(toggle << 7) | 0x7F:02X}")]
        toggle ^= 1
        t = round(t + 0.1, 3)
    fr += [(1.0, "000#8105"), (1.05, "705#R"), (1.06, "705#00")]
    t, toggle = 1.15, 0
    while t < 2.0:
        fr += [(t, "705#R"), (t + 0.005, f"705#{(toggle << 7) | 0x7F:02X}")]
        toggle ^= 1
        t = round(t + 0.1, 3)
    res = checker.run(candump(sorted(fr)))
    assert [(f.rule, f.node) for f in res.findings] == []
    node = res.model.channels[0].nodes[5]
    assert [f.ts - 1000.0 for f in node.bootups] == pytest.approx([0.0, 1.06])
    assert node.error_control == "guarding"
