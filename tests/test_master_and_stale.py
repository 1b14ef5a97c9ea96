"""SPEC §2 as revised for real CiA 302 networks: the NMT master (network file, device
file, inference), stale reports, the heartbeat period in force, when a heartbeat gap
starts (H001), and N002's stall exception. Each behaviour has a case where a rule must
fire and one where it must stay silent."""

from __future__ import annotations

from pathlib import Path

from conftest import Checker, candump
from traces import hb

# A CiA 302 master (node 1) as Lely and python-canopen masters start: its own boot-up,
# reset communication to all, its heartbeat; slaves 2 and 3 boot after the reset, stay
# silent until 1017h is written, then heartbeat; start all.
MASTER_START = [
    (0.000, "701#00"), (0.001, "701#7F"), (0.050, "000#8200"),
    (0.080, "702#00"), (0.090, "703#00"),
]


def cia302(end: float = 3.0) -> list[tuple[float, str]]:
    fr = list(MASTER_START) + hb(1, 0.101, 0.6) + hb(1, 0.601, end, "05")
    for n, t in ((2, 0.3), (3, 0.4)):  # 1017h = 100 ms written and confirmed
        fr += [(t, f"60{n}#2B17100064000000"), (t + 0.002, f"58{n}#6017100000000000")]
        fr += hb(n, t + 0.003, 0.55) + hb(n, 0.6 + n / 1000, end, "05")
    fr += [(0.55, "000#0100")]
    return sorted(fr)


def masters(res) -> list[tuple[str, int | None, str | None]]:  # type: ignore[no-untyped-def]
    return [(cm.name, cm.master.node if cm.master else None,
             cm.master.source if cm.master else None) for cm in res.model.channels]


# --- the master and its three sources ----------------------------------------------------

def test_master_is_inferred_from_a_real_start_up(checker: Checker) -> None:
    res = checker.run(candump(cia302()))
    assert masters(res) == [("can0", 1, "inferred")]
    master = res.model.channels[0].master
    assert master is not None and "did not obey" in master.detail
    assert [(f.rule, f.node) for f in res.findings] == []  # no B001/S004 for the master


def test_without_the_master_its_own_broadcast_would_be_b001(checker: Checker) -> None:
    """The master ignores its own reset: with inference off (window 0) the SPEC's old
    reading applies the broadcast to node 1 and a healthy start-up fails."""
    fr = cia302()
    prof = checker.tmp_path / "noinfer.toml"
    prof.write_text("[timeline]\nmaster_window_ms = 0\n")
    assert checker.findings(candump(fr), profile=str(prof), select="B,S004") == [
        ("B001", 1, 0.201)]  # 0.101 s is stale
    assert checker.findings(candump(fr), select="B,S004") == []


def test_master_from_the_network_file_wins(checker: Checker) -> None:
    res = checker.run(candump(cia302()), network="master = 1\n")
    assert masters(res) == [("can0", 1, "network")]
    res = checker.run(candump(cia302(), "can1"), network="[channels.can1]\nmaster = 1\n")
    assert masters(res) == [("can1", 1, "network")]


def test_master_from_a_device_file_with_1f80_bit_0(checker: Checker, tmp_path: Path) -> None:
    dcf = tmp_path / "master.dcf"
    dcf.write_text("[DeviceComissioning]\nNodeID=1\n[1F80]\nParameterName=NMT startup\n"
                   "ObjectType=0x7\nDataType=0x0007\nAccessType=rw\nDefaultValue=0x00000001\n"
                   "PDOMapping=0\n")
    res = checker.run(candump(cia302()), network=f'[nodes.1]\ndcf = "{dcf}"\n')
    assert masters(res) == [("can0", 1, "device-file")]


def test_no_master_without_a_broadcast(checker: Checker) -> None:
    fr = [(t, f.replace("000#8200", "000#8202").replace("000#0100", "000#0102"))
          for t, f in cia302()]
    res = checker.run(candump(fr))
    assert masters(res) == [("can0", None, None)]
    assert "no broadcast" in res.model.channels[0].master_note


def test_no_master_when_the_candidate_obeyed(checker: Checker) -> None:
    """Node 2 boots last before a broadcast reset and obeys it with a boot-up: a slave."""
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 0.5) + [(0.5, "000#8200"), (0.52, "702#00")]
          + hb(2, 0.6, 2.0))
    fr[0] = (0.45, "702#00")  # its boot-up right before the broadcast
    fr = sorted(fr[1:] + [(0.0, "702#00"), (0.45, "702#00")])
    res = checker.run(candump(fr))
    assert masters(res) == [("can0", None, None)]


def test_no_master_when_the_candidate_answers_a_reset(checker: Checker) -> None:
    """A boot-up that answers a reset (condition 2) is a slave's, even if the node then
    ignores the next broadcast."""
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 0.4) + [(0.4, "000#8102"), (0.45, "702#00")]
          + [(0.5, "000#0100")] + hb(2, 0.55, 2.0))
    res = checker.run(candump(sorted(fr)))
    assert masters(res) == [("can0", None, None)]
    assert ("S004", 2, 0.65) in checker.findings(candump(sorted(fr)))


def test_no_master_when_two_nodes_qualify(checker: Checker) -> None:
    fr = cia302(14.0)
    # node 5 boots (no reset for 12 s) and a second reset-all follows at once, which node 5
    # ignores too
    fr += [(12.0, "705#00"), (12.05, "000#8200")] + hb(5, 12.2, 14.0)
    res = checker.run(candump(sorted(fr)))
    assert masters(res) == [("can0", None, None)]
    assert "several" in res.model.channels[0].master_note


def test_a_direct_command_still_applies_to_the_master(checker: Checker) -> None:
    fr = cia302() + [(2.0, "000#8101")]  # another device resets node 1
    assert ("B001", 1, 2.101) in checker.findings(candump(sorted(fr)), select="B001")


def test_the_report_names_the_master(checker: Checker, tmp_path: Path) -> None:
    import json
    import subprocess
    import sys

    log = tmp_path / "start.log"
    log.write_text(candump(cia302()))
    out = subprocess.run([sys.executable, "-m", "nmtcheck", "check", str(log), "--format",
                          "json"], capture_output=True, text=True, check=True).stdout
    channels = json.loads(out)["channels"]
    assert channels[0]["master"]["node"] == 1 and channels[0]["master"]["source"] == "inferred"
    text = subprocess.run([sys.executable, "-m", "nmtcheck", "check", str(log)],
                          capture_output=True, text=True, check=True).stdout
    assert "can0: NMT master node 1 (inferred from the start-up" in text


# --- stale reports -----------------------------------------------------------------------

def test_guarding_response_queued_before_a_start_is_stale(checker: Checker) -> None:
    """The queued 7Fh response 1 us after the start is not evidence: no S005, and the
    timeline does not flip back to PRE-OPERATIONAL."""
    fr = [(0.0, "705#00")]
    toggle = 0
    for i in range(1, 20):
        t = i * 0.1
        state = 0x05 if t > 1.0 else 0x7F
        fr += [(t, "705#R"), (t + (0.000001 if i == 10 else 0.002),
                              f"705#{toggle << 7 | state:02X}")]
        toggle ^= 1
    fr += [(1.0, "000#0105")]
    fr = sorted(fr)
    res = checker.run(candump(fr))
    assert [(f.rule, f.node) for f in res.findings] == []
    states = [iv.state for iv in res.nodes()[0].intervals]
    assert states == ["PRE-OPERATIONAL", "OPERATIONAL"]


def test_a_report_of_the_old_state_after_obey_ms_is_evidence(checker: Checker) -> None:
    fr = [(0.0, "705#00")] + hb(5, 0.1, 2.0) + [(0.55, "000#0105")]
    assert checker.findings(candump(sorted(fr)), select="S004,S005") == [("S004", 5, 0.7)]


def test_heartbeat_queued_before_a_reset_is_no_sign_of_life(checker: Checker) -> None:
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 1.0, "05") + [(1.0, "000#8102"), (1.0005, "702#05"),
                                                        (1.02, "702#00")] + hb(2, 1.1, 2.0))
    assert checker.findings(candump(sorted(fr)), select="B") == []
    # the same 05h 200 ms after the reset is evidence: the node did not reset
    late = ([(0.0, "702#00")] + hb(2, 0.1, 1.0, "05")
            + [(1.0, "000#8102"), (1.205, "702#05"), (1.3, "702#00")] + hb(2, 1.4, 2.0))
    assert checker.findings(candump(sorted(late)), select="B001") == [("B001", 2, 1.205)]


# --- H001: a boot-up starts no gap -------------------------------------------------------

def test_slave_silent_after_boot_up_until_1017h_is_written(checker: Checker) -> None:
    """Power-on 1017h = 0: the boot-up is followed by 3 s of silence until the master writes
    1017h; with the network file's consumer time that is no H001."""
    fr = [(0.0, "702#00"), (3.0, "602#2B17100064000000"), (3.002, "582#6017100000000000")]
    fr += hb(2, 3.05, 5.0)
    net = "[nodes.2]\nconsumer_timeout_ms = 150\n"
    assert checker.findings(candump(fr), network=net) == []
    assert checker.findings(candump(fr)) == []


def test_the_1017h_write_starts_the_gap(checker: Checker) -> None:
    """After the write the node must heartbeat within the timeout: a first heartbeat
    0.5 s after a 100 ms write is an H001 at write + 150 ms."""
    fr = [(0.0, "702#00"), (3.0, "602#2B17100064000000"), (3.002, "582#6017100000000000")]
    fr += hb(2, 3.5, 5.0)
    assert checker.findings(candump(fr), select="H001") == [("H001", 2, 3.152)]


def test_heartbeat_during_the_1017h_exchange_follows_the_new_period(checker: Checker) -> None:
    """Stacks apply 1017h before they confirm: the heartbeat between request and
    confirmation already runs at 300 ms and its gap is not judged by the old 100 ms."""
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0)
    fr += [(1.0, "602#2B1710002C010000"), (1.0004, "702#7F"), (1.0008, "582#6017100000000000")]
    fr += hb(2, 1.3004, 3.0, period=0.3)
    assert checker.findings(candump(sorted(fr))) == []


# --- H002: the period in force ------------------------------------------------------------

def test_h002_uses_the_confirmed_producer_time_not_the_median(checker: Checker) -> None:
    """1017h = 100 ms confirmed, heartbeats every 100 ms; later 400 ms (the node's own
    change). The whole-trace median is 400 ms, yet 100 ms heartbeats are on time."""
    fr = [(0.0, "702#00"), (0.05, "602#2B17100064000000"), (0.052, "582#6017100000000000")]
    fr += hb(2, 0.1, 1.0) + hb(2, 1.0, 9.0, period=0.4)
    assert checker.findings(candump(fr), select="H002") == []
    early = fr + [(0.52, "702#7F")]  # 20 ms after a heartbeat: early against 100 ms
    assert checker.findings(candump(sorted(early)), select="H002") == [("H002", 2, 0.52)]


def test_first_heartbeat_after_a_1017h_write_is_not_early(checker: Checker) -> None:
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0)
    fr += [(0.93, "602#2B17100032000000"), (0.931, "702#7F"), (0.932, "582#6017100000000000")]
    fr += hb(2, 0.981, 2.0, period=0.05)
    assert checker.findings(candump(sorted(fr)), select="H002") == []


# --- N002: a stalled fixed-rate producer is not two devices ------------------------------

def test_late_heartbeat_and_catch_up_is_not_a_duplicate_node(checker: Checker) -> None:
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.08, "702#7F"), (1.1, "702#7F")]
    fr += hb(2, 1.2, 3.0)
    assert checker.findings(candump(fr), select="N002") == []


def test_two_producers_out_of_phase_are_a_duplicate_node(checker: Checker) -> None:
    fr = [(0.0, "702#00")] + hb(2, 0.1, 2.0) + hb(2, 0.13, 2.0)
    assert checker.findings(candump(sorted(fr)), select="N002") == [("N002", 2, 0.3)]


def test_unreadable_device_file_values_are_in_every_report(tmp_path: Path) -> None:
    import json
    import subprocess
    import sys

    dcf = Path(__file__).parent / "data" / "devices" / "slave_values.dcf"
    net = tmp_path / "net.toml"
    net.write_text(f'[nodes.2]\ndcf = "{dcf}"\n')
    log = tmp_path / "start.log"
    log.write_text(candump(cia302()))
    args = [sys.executable, "-m", "nmtcheck", "check", str(log), "--network", str(net)]
    text = subprocess.run(args, capture_output=True, text=True).stdout
    report = json.loads(subprocess.run(args + ["--format", "json"], capture_output=True,
                                       text=True).stdout)
    notes = report["network"]["notes"]
    assert notes and all(n.startswith("node 2 ") for n in notes)
    assert "values that could not be read" in text and notes[0] in text
    html = tmp_path / "r.html"
    subprocess.run(args + ["-o", str(html)], capture_output=True, text=True)
    assert "network-notes" in html.read_text()


# --- cases the differential test against the reference model found ----------------------

def test_a_node_whose_only_traffic_is_a_1017h_write(checker: Checker) -> None:
    fr = [(0.0, "605#2B17100032000000"), (0.001, "585#6017100000000000")]
    assert checker.findings(candump(fr)) == []


def test_heartbeats_while_1017h_is_0_start_no_gap(checker: Checker) -> None:
    """Heartbeat disabled by SDO: the heartbeat at 0.7 s opens no gap, so the non-zero
    write at 0.721 s does, and the node answers only 0.28 s later."""
    fr = [(0.0, "702#00"), (0.1, "702#7F"), (0.2, "702#7F"), (0.3, "702#7F"),
          (0.4, "602#2B17100000000000"), (0.401, "582#6017100000000000"), (0.7, "702#7F"),
          (0.72, "602#2B17100064000000"), (0.721, "582#6017100000000000"), (1.0, "702#7F")]
    assert checker.findings(candump(fr), select="H001") == [("H001", 2, 0.871)]


def test_two_commands_while_offline_compare_with_the_state_before_offline(checker: Checker) -> None:
    fr = [(0.0, "702#04"), (0.1, "702#04"), (0.2, "702#04"), (0.5, "000#0102"),
          (0.5, "000#0102"), (0.55, "702#04"), (0.65, "702#05")]
    res = checker.run(candump(fr))
    assert [(f.rule, f.node) for f in res.findings if f.rule != "H001"] == []
    assert [iv.state for iv in res.nodes()[0].intervals][-1] == "OPERATIONAL"


def test_the_median_is_the_period_where_1017h_is_0(checker: Checker) -> None:
    fr = [(0.0, "702#7F"), (0.05, "702#7F"), (0.1, "702#7F"), (0.15, "702#7F"),
          (0.2, "702#7F"), (0.21, "602#2B17100000000000"), (0.211, "582#6017100000000000"),
          (0.25, "702#7F"), (0.28, "702#7F")]
    net = "[nodes.2]\nheartbeat_ms = 100\n"
    assert checker.findings(candump(fr), network=net, select="H002") == []
