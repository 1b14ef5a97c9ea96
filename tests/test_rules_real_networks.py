"""SPEC revision of 2026-11-26 (issue 21): what real stacks and pasted logs showed.

Each behaviour has a trace that makes the rule fire and one, shaped like the real
traffic that raised a false alarm, where it must stay silent. The recorded samples
(tests/test_samples_real_stacks.py) check the same on CANopenNode and Lely traffic.
"""

from __future__ import annotations

from conftest import Checker, candump

# -- the heartbeat period per producer-time segment (SPEC §2) ---------------------------


def _power_on_then_written(period_after: float) -> str:
    """Node 2 heartbeats every 1 s from its power-on, the master writes 1017h = 100 ms at
    2.0 s (confirmed), then node 2 heartbeats every `period_after` s."""
    fr = [(0.0, "702#00")] + [(0.1 + i, "702#7F") for i in range(2)]
    fr += [(2.0, "602#2B17100064000000"), (2.0005, "582#6017100000000000")]
    fr += [(2.001 + period_after * i, "702#7F") for i in range(1, 40)]
    return candump(fr)


def test_power_on_period_is_not_judged_by_the_written_one(checker: Checker) -> None:
    """CANopenNode slaves power on at 1000 ms and are set to 100 ms: the power-on
    heartbeats are no H001 (they were six false errors on a healthy start-up)."""
    assert checker.findings(_power_on_then_written(0.1), select="H") == []


def test_period_segments_still_find_a_silence(checker: Checker) -> None:
    """After the write the node heartbeats at 100 ms, then falls silent for 1 s."""
    fr = [(0.0, "702#00")] + [(0.1 * i, "702#7F") for i in range(1, 30)]
    fr += [(3.0 + 0.1 * i, "702#7F") for i in range(1, 30)]
    got = checker.findings(candump(fr), select="H001")
    assert got == [("H001", 2, 3.05)]  # 2.9 + 1.5 x 0.1 (the segment's own median)


def test_measured_period_per_segment_after_a_boot_up(checker: Checker) -> None:
    """No producer time known: each segment between boot-ups is measured on its own. A
    node at 1 s before its reboot and 100 ms after it gets no H001 from the 1 s part."""
    fr = [(0.0, "703#00")] + [(1.0 * i, "703#7F") for i in range(1, 5)]
    fr += [(4.5, "703#00")] + [(4.5 + 0.1 * i, "703#7F") for i in range(1, 60)]
    assert checker.findings(candump(fr), select="H001") == []


# -- self-start (SPEC §2) ----------------------------------------------------------------


def test_self_starting_node_sends_its_tpdo_before_any_heartbeat(checker: Checker) -> None:
    """CANopenNode's CO_NMT_STARTUP_TO_OPERATIONAL: TPDO 40 us after the boot-up, then
    heartbeats reporting OPERATIONAL: no S001, no S005, the timeline says self-start."""
    fr = [(0.0, "705#00"), (0.00004, "185#01"), (0.1, "705#05"), (0.5, "185#02"),
          (0.2, "705#05")]
    fr = sorted(fr)
    res = checker.run(candump(fr), select="S001,S005")
    assert res.findings == []
    (node,) = res.model.channels[0].nodes.values()
    assert [(iv.state, iv.source) for iv in node.intervals][-1] == ("OPERATIONAL", "self-start")


def test_a_node_that_reports_pre_operational_did_not_start_itself(checker: Checker) -> None:
    fr = [(0.0, "705#00"), (0.00004, "185#01"), (0.1, "705#7F"), (0.2, "705#7F")]
    assert checker.findings(candump(fr), select="S001") == [("S001", 5, 0.0)]


def test_nothing_shows_whether_a_node_started_itself_before_a_reset(checker: Checker) -> None:
    """A reset command to N before N's first report after its boot-up: its PDOs since the
    boot-up are not S001 (nothing shows it did not start itself)."""
    fr = [(0.0, "705#00"), (0.01, "185#01"), (0.02, "185#02"), (0.5, "000#8105"),
          (0.501, "705#00"), (0.6, "705#7F")]
    assert checker.findings(candump(fr), select="S001") == []


# -- the NMT master obeying its own broadcasts, or not (SPEC §2) -------------------------

_CANOPENNODE_START = [
    (0.0, "701#00"), (0.0001, "702#00"), (0.002, "000#8200"),  # the master's reset
    (0.0021, "701#00"), (0.0022, "702#00"),  # both obey it, the master too
    (0.1, "701#7F"), (0.1001, "702#7F"), (0.15, "000#0102"),
    (0.2, "701#7F"), (0.2001, "702#05"), (0.3, "701#7F"), (0.3001, "702#05"),
    (1.0, "000#8000"),  # pre-operational to all: the master's heartbeat stays 7Fh
    (1.1, "701#7F"), (1.1001, "702#7F"), (1.2, "701#7F"), (1.2001, "702#7F"),
]


def test_master_that_obeys_its_own_broadcasts(checker: Checker) -> None:
    """CANopenNode's master boots again after its own 000#8200: with `master = 1` that is
    no B002/B003, and its timeline shows the reset."""
    res = checker.run(candump(_CANOPENNODE_START), select="B,S", network="master = 1\n")
    assert [(f.rule, f.node) for f in res.findings] == []
    master = res.model.channels[0].nodes[1]
    assert "INITIALISING" in [iv.state for iv in master.intervals]


def test_master_that_ignores_its_own_broadcast_reset(checker: Checker) -> None:
    """Lely's master ignores its own 000#8200 and goes on heartbeating: not applied, no
    B001 for it; its own 000#8100 that it obeys (boot-up at once) is applied, no B002."""
    fr = [(0.0, "701#00"), (0.0001, "000#8200"), (0.0002, "702#00")]
    fr += [(0.1 * i + d, f"70{n}#{s}") for i in range(1, 10)
           for d, n, s in ((0.0, 1, "05"), (0.0001, 2, "7F"))]
    fr += [(1.0, "000#8100"), (1.00001, "701#00"), (1.0002, "702#00"),
           (1.1, "701#7F"), (1.1001, "702#7F")]
    res = checker.run(candump(fr), select="B,S", network="master = 1\n")
    assert [(f.rule, f.node) for f in res.findings] == []
    master = res.model.channels[0].nodes[1]
    assert [iv.state for iv in master.intervals].count("INITIALISING") == 1


def test_a_slave_that_ignores_a_broadcast_reset_is_still_b001(checker: Checker) -> None:
    fr = [(0.0, "701#00"), (0.0001, "702#00"), (0.1, "701#05"), (0.1001, "702#05"),
          (1.0, "000#8100"), (1.00001, "701#00"), (1.2, "702#05"), (1.3, "701#05")]
    got = checker.findings(candump(fr), select="B", network="master = 1\n")
    assert got == [("B001", 2, 1.2)]  # (a report within obey_ms would be stale)


def test_master_that_starts_as_the_log_ends_is_not_reset(checker: Checker) -> None:
    """A pasted start-up: `77F#00`, `000#8100`, then nothing from node 127: it is the
    master, the reset does not apply to it (no INITIALISING to the end)."""
    fr = [(0.0, "77F#00"), (0.0001, "000#8100"), (0.0003, "705#00"), (0.1, "705#7F")]
    res = checker.run(candump(fr))
    cm = res.model.channels[0]
    assert cm.master is not None and cm.master.node == 127
    assert [iv.state for iv in cm.nodes[127].intervals] == ["PRE-OPERATIONAL"]


# -- B001's grace and absent nodes (SPEC §3) ---------------------------------------------


def test_keep_alive_manager_resets_absent_node_ids(checker: Checker) -> None:
    """A CiA 302 manager in keep-alive mode sends 000#82NN to every node-ID but its own:
    the absent ones are no missing boot-ups, with or without a network file."""
    fr = [(0.0, "701#00"), (0.00001, "702#00")]
    fr += [(0.0001 + i * 1e-6, f"000#82{n:02X}") for i, n in enumerate(range(2, 128))]
    fr += [(0.0002, "702#00")] + [(0.1 * i, "702#7F") for i in range(1, 80)]
    fr = sorted(fr)
    assert checker.findings(candump(fr), select="B") == []
    assert checker.findings(candump(fr), select="B,N", network="[nodes.2]\n") == []


def test_absent_node_that_the_network_file_expects_is_awaited(checker: Checker) -> None:
    fr = [(0.0, "701#00"), (0.0001, "000#8203"), (0.1, "701#05")] + [
        (0.1 * i, "701#05") for i in range(2, 80)]
    got = checker.findings(candump(fr), select="B001", network="[nodes.3]\n")
    assert got == [("B001", 3, 5.0)]


def test_frames_queued_before_a_reset_are_no_sign_of_life(checker: Checker) -> None:
    """Lely: after 000#8100 two slaves' TPDOs leave their controllers 1 us later."""
    fr = [(0.0, "702#00"), (0.1, "702#05"), (1.0, "000#8100"), (1.000001, "182#01"),
          (1.0003, "702#00"), (1.1, "702#7F")]
    assert checker.findings(candump(fr), select="B") == []
    late = fr[:3] + [(1.01, "182#01")] + fr[4:]
    assert checker.findings(candump(late), select="B") == [("B001", 2, 1.01)]


def test_two_resets_answered_by_two_boot_ups_are_no_repeat(checker: Checker) -> None:
    """Lely's manager after a lost mandatory slave: 000#8100 then 000#8200, each slave
    boots twice. Each reset explains one boot-up: no B003, no B002."""
    fr = [(0.0, "702#00"), (0.1, "702#05"), (1.0, "000#8100"), (1.0001, "000#8200"),
          (1.0002, "702#00"), (1.0003, "702#00"), (1.1, "702#7F")]
    assert checker.findings(candump(fr), select="B") == []
    one_reset = fr[:3] + fr[4:]  # a real repeat is still one: two boot-ups, one reset
    assert checker.findings(candump(one_reset), select="B003") == [("B003", 2, 1.0)]


# -- G001: the toggle against the previous response (SPEC §3) ---------------------------


def test_one_repeated_toggle_is_one_g001(checker: Checker) -> None:
    """Responses 05, 05 (the real repeat), 85: the 85 differs from the previous response
    and is right."""
    fr = [(0.0, "704#00")]
    t = 0.1
    for v in ["05", "85", "05", "05", "85", "05"]:
        fr += [(t, "704#R"), (t + 0.0001, f"704#{v}")]
        t += 0.1
    assert checker.findings(candump(fr), select="G001") == [("G001", 4, 0.4)]


# -- N002's state pattern with repeats (SPEC §3) -----------------------------------------


def test_two_devices_with_one_node_id_by_their_states(checker: Checker) -> None:
    """Two producers of node 3 at 1 s, one OPERATIONAL, one PRE-OPERATIONAL, with equal
    states repeated: 05, 05, 7F, 05, 05, 7F."""
    fr = [(0.0, "703#05"), (0.5, "703#05"), (1.0, "703#7F"), (1.5, "703#05"),
          (2.0, "703#05"), (2.5, "703#7F"), (3.0, "703#05")]
    assert checker.findings(candump(fr), select="N002") == [("N002", 3, 2.5)]


def test_one_state_change_is_no_duplicate(checker: Checker) -> None:
    fr = [(0.1 * i, "703#05") for i in range(10)] + [(1.0 + 0.1 * i, "703#7F")
                                                      for i in range(10)]
    assert checker.findings(candump(fr), select="N002") == []


# -- what a reset does to SDO-written values (SPEC §6) -----------------------------------


def test_written_producer_time_is_unknown_after_a_reset(checker: Checker) -> None:
    """1017h = 100 ms written, then a reset: the node comes back at its power-on 500 ms
    (CANopenNode keeps RAM values, Lely restores; neither is known). No H001/H003 from
    the old written value, nor from the network file's 100 ms."""
    fr = [(0.0, "702#00"), (0.01, "602#2B17100064000000"), (0.0101, "582#6017100000000000")]
    fr += [(0.0101 + 0.1 * i, "702#7F") for i in range(1, 20)]
    fr += [(2.0, "000#8102"), (2.001, "702#00")] + [(2.001 + 0.5 * i, "702#7F")
                                                    for i in range(1, 12)]
    network = "[nodes.2]\nheartbeat_ms = 100\n"
    assert checker.findings(candump(fr), select="H", network=network) == []


def test_file_value_of_an_object_never_written_holds_across_resets(checker: Checker) -> None:
    fr = [(0.0, "702#00")] + [(0.1 * i, "702#7F") for i in range(1, 20)]
    fr += [(2.0, "000#8102"), (2.001, "702#00")] + [(2.001 + 0.5 * i, "702#7F")
                                                    for i in range(1, 12)]
    res = checker.run(candump(fr), select="H001", network="[nodes.2]\nheartbeat_ms = 100\n")
    # each 0.5 s gap exceeds 1.5 x 100 ms, a timeout assumed (no consumer time): one finding
    # with the count (issue 38)
    (f,) = res.findings
    assert (f.rule, f.node, round(f.time - 1000.0, 3), f.basis) == ("H001", 2, 2.651, "assumed")
    assert "exceeds the assumed timeout 10 times in a row" in f.message


# -- H004 (SPEC §3) ----------------------------------------------------------------------

_WATCH_NODE_1 = [(0.0, "705#00"), (0.01, "605#23161001D0070100"),  # 1016h:01 = 1, 2000 ms
                 (0.011, "585#6016100100000000")]


def test_h004_consumer_whose_producer_never_sends(checker: Checker) -> None:
    fr = _WATCH_NODE_1 + [(0.1 + i, "705#7F") for i in range(6)]
    assert checker.findings(candump(fr), select="H004") == [("H004", 5, 2.011)]


def test_h004_silent_when_the_producer_heartbeats(checker: Checker) -> None:
    fr = _WATCH_NODE_1 + [(0.1 + i, "705#7F") for i in range(6)] + [
        (4.0 + 0.5 * i, "701#05") for i in range(4)]  # late, but it does produce
    assert checker.findings(candump(sorted(fr)), select="H004") == []


def test_h004_silent_when_the_consumer_is_not_up_long_enough(checker: Checker) -> None:
    fr = _WATCH_NODE_1 + [(0.1 + 0.5 * i, "705#7F") for i in range(3)]
    assert checker.findings(candump(fr), select="H004") == []


# -- logs without timestamps (SPEC §1, I006) ---------------------------------------------


def test_no_timestamps_order_rules_only(checker: Checker) -> None:
    """`candump can0` screen output: frames in file order, I006 once, the PDO before the
    boot-up's first heartbeat is S001 by order, and no timing finding at all."""
    text = "".join(f"  can0  {cid}   [{len(data) // 2}]  "
                   f"{' '.join(data[i:i + 2] for i in range(0, len(data), 2))}\n"
                   for cid, data in [("702", "00"), ("182", "0102"), ("702", "7F"),
                                     ("702", "7F"), ("000", "0102"), ("702", "05"),
                                     ("704", "05"), ("702", "05")])
    res = checker.run(text, suffix=".txt")
    assert res.stats.order_only
    assert [(f.rule, f.node, f.line) for f in res.findings] == [("I006", None, 1),
                                                                ("S001", 2, 2)]
    node2 = res.model.channels[0].nodes[2]
    assert [iv.state for iv in node2.intervals][-1] == "OPERATIONAL"
    assert node2.period_s is None  # no period of 0 (or of one frame) is shown


def test_equal_timestamps_are_no_timestamps(checker: Checker) -> None:
    fr = [(0.0, "702#00"), (0.0, "182#01"), (0.0, "702#7F")]
    got = checker.findings(candump(fr))
    assert [(r, n) for r, n, _t in got] == [("I006", None), ("S001", 2)]


def test_timestamped_log_gives_no_i006(checker: Checker) -> None:
    fr = [(0.0, "702#00"), (0.1, "702#7F")]
    assert checker.findings(candump(fr), select="I006") == []


def _screen(frames: list[str]) -> str:
    """`candump can0` screen output without timestamps of `ID#DATA` / `ID#R` frames."""
    out = []
    for frame in frames:
        cid, _, data = frame.partition("#")
        if data == "R":
            out.append(f"  can0  {cid}   [0]  remote request\n")
        else:
            pairs = " ".join(data[i:i + 2] for i in range(0, len(data), 2))
            out.append(f"  can0  {cid}   [{len(data) // 2}]  {pairs}\n")
    return "".join(out)


def _codes(checker: Checker, frames: list[str], select: str = "") -> list[tuple[str, int | None]]:
    res = checker.run(_screen(frames), select=select, suffix=".txt")
    assert res.stats.order_only
    return [(f.rule, f.node) for f in res.findings if f.rule != "I006"]


def test_no_timestamps_a_guarding_answer_may_follow_other_frames(checker: Checker) -> None:
    """N's data frame right after a request to 700h+N answers it, whatever other nodes
    sent between (frame numbers are no response time): 85h is toggle 1 + OPERATIONAL, no
    C003, no G001, no G004. A review found every Lely and CANopenNode network with a
    guarded node FAIL so when pasted without timestamps."""
    ok = ["704#R", "704#05", "704#R", "702#05", "704#85", "704#R", "702#05", "703#05",
          "704#05"]
    assert _codes(checker, ok) == []
    repeated = ["704#R", "704#05", "704#R", "702#05", "704#05"]  # the toggle not flipped
    assert _codes(checker, repeated) == [("G001", 4)]


def test_no_timestamps_the_report_right_after_a_command_may_be_stale(checker: Checker
                                                                     ) -> None:
    """CANopenNode: `000#0102`, then node 2's heartbeat queued before it (7Fh), its TPDO,
    then 05h. Its first report after the command may still be a queued one: no S001, no
    S005. Reporting 7Fh twice, it did not start: its TPDO after that is S001."""
    start = ["702#00", "702#7F", "000#0102", "702#7F", "182#00000000", "702#05"]
    assert _codes(checker, start) == []
    ignored = ["702#00", "702#7F", "000#0102", "702#7F", "702#7F", "182#00000000"]
    assert _codes(checker, ignored, select="S001") == [("S001", 2)]


def test_no_timestamps_a_report_a_heartbeat_cycle_later_is_not_stale(checker: Checker
                                                                      ) -> None:
    """`000#8103`, then node 3's next report only after nodes 1 and 2 have each reported
    twice: no queued report, a sign of life without a boot-up (B001). A review found it
    missed, and the pasted log passed where the recording fails. Right after the command
    (before another node's second report) it may still be a queued one."""
    late = ["701#05", "702#05", "703#05", "000#8103", "701#05", "702#05", "701#05",
            "702#05", "703#05"]
    assert _codes(checker, late, select="B001") == [("B001", 3)]
    soon = ["701#05", "702#05", "703#05", "000#8103", "701#05", "703#05", "703#00",
            "703#7F"]
    assert _codes(checker, soon, select="B001") == []


def test_no_timestamps_b003_needs_its_boot_ups_in_a_row(checker: Checker) -> None:
    """Without a window B003 takes a 00h right after N's previous 00h (N heartbeats 00h);
    a node that reported another state between its two boot-ups rebooted: B002."""
    repeated = ["703#00", "703#00", "703#00", "703#05"]
    assert _codes(checker, repeated, select="B002,B003") == [("B003", 3)]
    rebooted = ["703#00", "703#7F", "702#05", "703#7F", "703#00", "703#7F"]
    assert _codes(checker, rebooted, select="B002,B003") == [("B002", 3)]


def test_no_timestamps_no_n002_from_frame_numbers(checker: Checker) -> None:
    """N002's intervals need time: node 2's heartbeats 3 and 6 frames apart in turn are
    no two producers. Its state pattern (7F, 05, 7F, 05) still is."""
    frames = ["702#00"]
    for k in range(6):  # node 2 every 3rd, then every 6th frame, in turn
        frames += ["702#7F"] + ["703#7F"] * (2 if k % 2 == 0 else 5)
    assert _codes(checker, frames, select="N002") == []
    pattern = ["702#00", "702#7F", "702#05", "702#7F", "702#05"]
    assert _codes(checker, pattern, select="N002") == [("N002", 2)]


def test_no_timestamps_a_tpdo_before_the_boot_up_that_answers_a_reset(checker: Checker
                                                                      ) -> None:
    """Lely's TPDOs right after `000#8100` were queued before the reset (2 us with
    timestamps, within B001's grace): without time, a TPDO before the boot-up that
    answers the reset is no sign of life. A node that goes on reporting does not reset."""
    reset = ["702#05", "182#01", "000#8100", "182#02", "702#00", "702#7F"]
    assert _codes(checker, reset, select="B001") == []
    alive = ["702#05", "000#8102", "702#05", "702#05", "702#05"]
    assert _codes(checker, alive, select="B001") == [("B001", 2)]


def test_no_timestamps_a_start_before_a_self_starting_node_reports(checker: Checker
                                                                  ) -> None:
    """CANopenNode's self-starting slave sends its TPDO right after its boot-up; the master
    starts it before its first heartbeat, so that heartbeat (05h) cannot show whether it
    started itself. With timestamps S001's grace after the reset covers the TPDO (16 us);
    without them, its PDOs before the command are unjudged, as SPEC §2 has it for a reset
    or a boot-up before the first report. Reporting 7Fh first, it did not start itself."""
    started = ["000#8203", "703#00", "183#03000000", "000#0103", "703#05", "183#04000000"]
    assert _codes(checker, started, select="S001,S005") == []
    told = ["000#8203", "703#00", "183#03000000", "703#7F", "000#0103", "703#05"]
    assert _codes(checker, told, select="S001") == [("S001", 3)]


def test_a_slow_reset_self_starting_node_started_before_its_first_report(
        checker: Checker) -> None:
    """The same with timestamps and a device that takes 300 ms to reset (CANopenNode's
    16 us on Linux were within S001's 5 ms grace after the reset; a real device's boot is
    not): its TPDO right after its boot-up comes before the master's start command and
    before any report, so nothing shows whether it started itself. It was S001, an error
    for a correct self-starting slave. A first report of 7Fh before the command still
    shows it did not start itself."""
    started = [(0.0, "000#8103"), (0.3, "703#00"), (0.30002, "183#03000000"),
               (0.35, "000#0103"), (0.4, "703#05"), (0.5, "183#04000000")]
    assert checker.findings(candump(started), select="S001,S005") == []
    told = [(0.0, "000#8103"), (0.3, "703#00"), (0.30002, "183#03000000"), (0.32, "703#7F"),
            (0.35, "000#0103"), (0.4, "703#05")]
    assert [r for r, _n, _t in checker.findings(candump(told), select="S001")] == ["S001"]


def test_a_boot_up_earlier_in_time_than_the_last_is_no_repeat(checker: Checker) -> None:
    """Two captures in one file (`cat a.log b.log`): node 3's boot-up of the second has an
    earlier time than its last of the first. That is no boot-up repeated "over -0.102 s"
    (B003, an error); I005 says the time went back."""
    first = [(10.0, "703#00"), (10.1, "703#7F"), (10.2, "703#7F")]
    second = [(9.9, "703#00"), (10.0, "703#7F")]
    text = candump(first) + candump(second)
    got = checker.findings(text, select="B002,B003,I005")
    assert sorted(r for r, _n, _t in got) == ["B002", "I005"], got


def test_a_boot_up_at_the_time_of_the_last_after_time_went_back_is_no_repeat(
        checker: Checker) -> None:
    """The same capture twice in one file (`cat run.asc run.asc`, each from 0 s): node 3's
    second boot-up has the time of its first, but its heartbeats between them were later
    than both. That was B003 "2 times in a row over 0.000 s" (an error: FAIL on a healthy
    network); the time between the two is unknown. Two 00h at one time with nothing later
    between them are still a repeat."""
    run = [(0.0, "703#00"), (0.1, "703#7F"), (0.2, "703#7F")]
    got = checker.findings(candump(run) + candump(run), select="B002,B003,I005")
    assert sorted(r for r, _n, _t in got) == ["B002", "I005"], got
    stuck = [(0.0, "703#00"), (0.0, "703#00"), (0.1, "703#7F")]
    assert [r for r, _n, _t in checker.findings(candump(stuck), select="B003")] == ["B003"]


def test_two_captures_whose_self_start_spans_go_back_in_time(checker: Checker) -> None:
    """`cat self_start.log late_master.log` (CANopenNode): every node's spans in which its
    PDOs are not judged go back in time. S001 crashed (IndexError, exit 2) instead of
    checking each node's spans in file order."""
    from conftest import SAMPLES

    folder = SAMPLES / "canopennode"
    text = (folder / "self_start.log").read_text() + (folder / "late_master.log").read_text()
    res = checker.run(text)
    assert res.stats.backwards_timestamps == 1 and res.stats.frames > 900
    assert "I005" in {f.rule for f in res.findings}


def test_a_timeout_in_the_second_of_two_captures_points_into_it(checker: Checker) -> None:
    """A log pasted twice into one file (`cat run.log run.log`): each H001 points at a line
    of its own copy. Located by time alone, both pointed into the first copy (the first
    frame in the file at or after the moment); now at the first such frame after the
    heartbeat the timeout was counted from."""
    from conftest import SAMPLES

    text = (SAMPLES / "heartbeat_loss.log").read_text()
    n = len(text.splitlines())
    single = checker.run(text, select="H001")
    double = checker.run(text + text, select="H001")
    lines = [f.line or 0 for f in single.findings]
    assert lines and all(lines)
    assert sorted(f.line or 0 for f in double.findings) == sorted(
        lines + [line + n for line in lines])


# -- a heartbeat producer that a guarding master polls (CANopenNode after a power cycle) --


def _polled(frames: list[tuple[float, str]], until: float = 3.0) -> str:
    """Node 4 boots at 0 s; its master sends `704#R1` every 100 ms from 0.05 s."""
    requests = [(0.05 + 0.1 * i, "704#R1") for i in range(int(until * 10))]
    return candump(sorted([(0.0, "704#00"), *requests, *frames]))


def test_heartbeats_of_a_polled_node_are_no_guarding_answers(checker: Checker) -> None:
    """Back at its power-on 1017h = 1000 ms (guarding slave off), node 4 heartbeats while
    its master polls every 100 ms: each `704#7F` comes within 100 ms of a request it did
    not answer. They were guarding answers with toggle 0, each a G001."""
    beats = [(0.5 + i, "704#7F") for i in range(3)]
    res = checker.run(_polled(beats), select="G001")
    assert res.findings == []
    (m,) = [m for cm in res.model.channels for m in cm.nodes.values() if m.node == 4]
    assert [iv.source for iv in m.intervals][-1] == "heartbeat"


def test_heartbeats_of_a_polled_node_at_any_phase_and_period(checker: Checker) -> None:
    """The polling's phase and the heartbeat period vary: a first heartbeat 50 ms after
    the first request (one request before it), and a 250 ms producer with two requests
    between its heartbeats. A review found G001 on 6 of 20 such logs at 1000 ms and on
    nearly all at 200-250 ms."""
    early = [(0.1 + i, "704#7F") for i in range(3)]
    assert checker.findings(_polled(early), select="G001,G004") == []
    short = [(0.12 + 0.25 * i, "704#7F") for i in range(11)]
    assert checker.findings(_polled(short), select="G001,G004") == []


def test_the_first_answer_after_the_switch_to_guarding_is_judged_alone(checker: Checker
                                                                       ) -> None:
    """One heartbeat while polled, then the master writes 1017h = 0 and the node answers
    `704#7F`, `704#FF`, ...: the heartbeat is no answer whose toggle the first real one
    repeats (G001 at 0.950 before)."""
    frames = [(0.5, "704#7F"), (0.9, "604#2B17100000000000"), (0.9005, "584#6017100000000000")]
    frames += [(0.9502 + 0.1 * i, "704#FF" if i % 2 else "704#7F") for i in range(15)]
    assert checker.findings(_polled(frames), select="G001") == []


def test_a_repeated_toggle_after_a_missed_request_is_still_g001(checker: Checker) -> None:
    """A guarding node that misses a request and then repeats its last toggle: G001 (its
    answers before were prompt, none taken for a heartbeat). With the right toggle after
    the miss: no G001."""
    answers = ["704#7F", "704#FF", "704#7F", "704#FF", None, "704#FF", "704#7F"]
    frames = [(0.0502 + 0.1 * i, a) for i, a in enumerate(answers) if a]
    assert checker.findings(_polled(frames, 0.7), select="G001") == [("G001", 4, 0.55)]
    answers[5:] = ["704#7F", "704#FF"]
    frames = [(0.0502 + 0.1 * i, a) for i, a in enumerate(answers) if a]
    assert checker.findings(_polled(frames, 0.7), select="G001") == []


def test_a_first_heartbeat_followed_by_another_is_no_answer_from_before_the_trace(
        checker: Checker) -> None:
    """Node 2's first frame, 70 ms into the trace, is followed by its next heartbeat, not by
    a request: it is a heartbeat, and the gap after it counts (a request sent before the
    trace is only taken where a request to N comes before N's next report). Node 4's
    first frame, an answer `704#85` followed by a request, is no heartbeat with bit 7 set."""
    frames = [(0.0, "701#05"), (0.07, "702#05"), (0.5, "702#05")]
    frames += [(0.5 + 0.1 * i, "702#05") for i in range(1, 20)]
    frames += [(1.0 + 0.1 * i, "704#R") for i in range(10)]
    frames += [(0.02, "704#85")] + [(1.0005 + 0.1 * i, "704#05" if i % 2 == 0 else "704#85")
                                   for i in range(10)]
    got = checker.findings(candump(sorted(frames)), select="H001,C003,G004,G001")
    assert got == [("H001", 2, 0.22)]  # 0.07 + 1.5 x 100 ms
