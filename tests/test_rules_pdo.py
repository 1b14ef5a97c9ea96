"""Group D (PDO timing, SPEC §9.2.2): every test vector of §9.5.2 verbatim, each rule
firing and staying silent; the chains CH1, CH2 and CH4 of §9.5.5; the PDO parameters the
device files give; and the values a network file refuses."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import Checker, assert_one_line_error, run_cli

D1 = "[nodes.3.tpdo.1]\ncob_id = 0x183\ntransmission_type = 254\nevent_timer_ms = 100\n"
D2 = "[nodes.3.tpdo.1]\ncob_id = 0x183\ntransmission_type = 255\ninhibit_100us = 100\n"
D3 = "[nodes.3.tpdo.1]\ncob_id = 0x183\ntransmission_type = 2\n"
D3_1 = "[nodes.3.tpdo.1]\ncob_id = 0x183\ntransmission_type = 1\n"
D4 = "[nodes.4.rpdo.1]\ncob_id = 0x204\nevent_timer_ms = 50\n"
D5R = "[nodes.4.rpdo.1]\ncob_id = 0x204\nmapping = [0x60400010, 0x60600008]\n"
D5T = "[nodes.3.tpdo.1]\ncob_id = 0x183\nmapping = [0x60410010]\n"
CH2 = ("[nodes.3.tpdo.1]\ncob_id = 0x204\ntransmission_type = 255\nevent_timer_ms = 20\n"
       "[nodes.4.rpdo.1]\ncob_id = 0x204\nevent_timer_ms = 50\n")
Y = "[sync]\nperiod_us = 10000\n"


def log(*lines: str) -> str:
    return "".join(line + "\n" for line in lines)


def found(checker: Checker, text: str, network: str | None = None, group: str = "D"
          ) -> list[tuple[str, int | None, float, int | None, int | None]]:
    res = checker.run(text, network=network)
    return [(f.rule, f.node, round(f.time, 6), f.frame_index, f.line)
            for f in res.findings if f.rule[0] in group]


D1_LOG = log("(10.000000) can0 703#00", "(10.001000) can0 000#0103", "(10.002000) can0 183#0100",
             "(10.102000) can0 183#0200", "(10.202000) can0 183#0300",
             "(10.500000) can0 183#0400", "(10.600000) can0 183#0500")


def test_d001_fires_after_the_event_timer(checker: Checker) -> None:
    assert found(checker, D1_LOG, D1) == [("D001", 3, 10.314, 5, 6)]
    [f] = checker.run(D1_LOG, network=D1).findings
    assert "event timer 1800h:05 = 100 ms (network), limit 112.000 ms" in f.message


def test_d001_silent_when_the_producer_is_stopped_inside_the_gap(checker: Checker) -> None:
    text = D1_LOG.replace("(10.500000) can0 183#0400\n(10.600000) can0 183#0500\n", log(
        "(10.250000) can0 000#0203", "(10.480000) can0 000#0103", "(10.481000) can0 183#0400",
        "(10.581000) can0 183#0500"))
    assert found(checker, text, D1) == []


def test_d001_silent_when_the_producers_state_is_not_supervised(checker: Checker) -> None:
    text = log("(10.000000) can0 703#00", "(10.001000) can0 000#0103",
               "(10.002000) can0 183#0100", "(10.102000) can0 183#0200",
               "(10.200000) can0 703#05", "(10.202000) can0 183#0300",
               "(10.400000) can0 703#7F", "(10.600000) can0 703#7F")
    assert found(checker, text, D1, "DS") == [("S005", 3, 10.4, 6, 7)]


def test_d001_silent_when_the_producer_fell_silent(checker: Checker) -> None:
    """An unplugged producer: no frame of any kind until its heartbeat timeout (H001)."""
    beats = [f"({10 + 0.05 * k:.6f}) can0 703#05" for k in range(5)]
    tpdos = [f"({10.0101 + 0.1 * k:.6f}) can0 183#0{k}00" for k in range(3)]
    text = log("(9.990000) can0 000#0103", *sorted(beats + tpdos), "(11.000000) can0 703#05")
    assert [f[0] for f in found(checker, text, D1, "DH")] == ["H001"]


def test_d002_fires_below_the_inhibit_time(checker: Checker) -> None:
    text = log("(10.000000) can0 703#00", "(10.001000) can0 000#0103",
               "(10.010000) can0 183#0100", "(10.013000) can0 183#0200",
               "(10.030000) can0 183#0300")
    assert found(checker, text, D2) == [("D002", 3, 10.013, 3, 4)]
    assert found(checker, text.replace("10.013000", "10.019999"), D2) == []


def test_d002_allows_for_a_frame_that_waited_for_the_bus(checker: Checker) -> None:
    """d8 = 130 us; F1 ends a back-to-back run that began at 10.008000: q(F1) = 650 us, the
    limit 9.349 ms < 9.480 ms. Without the run the pair fires."""
    text = log("(10.000000) can0 703#00", "(10.001000) can0 000#0103",
               "(10.008000) can0 201#1122334455667788", "(10.008130) can0 202#1122334455667788",
               "(10.008260) can0 203#1122334455667788", "(10.008390) can0 204#1122334455667788",
               "(10.008520) can0 183#0100", "(10.018000) can0 183#0200")
    assert found(checker, text, D2) == []
    bare = "".join(line for line in text.splitlines(keepends=True) if "#1122" not in line)
    assert found(checker, bare, D2) == [("D002", 3, 10.018, 3, 4)]


def test_d002_allows_for_the_bus_wait_on_one_channel_of_two(checker: Checker) -> None:
    """The vector above on can0, with can1's frames in between: q(F1) is still 650 us,
    from can0's frames alone (back to back means on one bus). Without can0's run the
    pair fires."""
    text = log("(10.000000) can0 703#00", "(10.001000) can0 000#0103",
               "(10.008000) can0 201#1122334455667788", "(10.008050) can1 301#01",
               "(10.008130) can0 202#1122334455667788", "(10.008200) can1 302#0102",
               "(10.008260) can0 203#1122334455667788", "(10.008390) can0 204#1122334455667788",
               "(10.008450) can1 303#01", "(10.008520) can0 183#0100",
               "(10.018000) can0 183#0200")
    assert found(checker, text, D2) == []
    bare = "".join(line for line in text.splitlines(keepends=True)
                   if "can0 20" not in line)
    assert found(checker, bare, D2) == [("D002", 3, 10.018, 6, 7)]


def test_d003_missing_tpdo(checker: Checker) -> None:
    text = log("(10.000000) can0 703#00", "(10.001000) can0 000#0103", "(10.010000) can0 080#",
               "(10.010500) can0 183#01", "(10.020000) can0 080#", "(10.030000) can0 080#",
               "(10.030500) can0 183#02", "(10.040000) can0 080#", "(10.050000) can0 080#",
               "(10.060000) can0 080#", "(10.070000) can0 080#", "(10.070500) can0 183#03")
    assert found(checker, text, D3) == [("D003", 3, 10.06, 9, 10)]


def test_d003_two_tpdos_between_the_same_syncs(checker: Checker) -> None:
    text = log("(10.000000) can0 703#00", "(10.001000) can0 000#0103", "(10.010000) can0 080#",
               "(10.010500) can0 183#01", "(10.020000) can0 080#", "(10.020500) can0 183#02",
               "(10.021000) can0 183#03", "(10.030000) can0 080#", "(10.030500) can0 183#04")
    assert found(checker, text, D3_1) == [("D003", 3, 10.021, 6, 7)]


def test_d003_silent_on_the_phase_and_at_the_trace_end(checker: Checker) -> None:
    text = log("(10.000000) can0 703#00", "(10.001000) can0 000#0103", "(10.010000) can0 080#",
               "(10.020000) can0 080#", "(10.020500) can0 183#01", "(10.030000) can0 080#",
               "(10.040000) can0 080#", "(10.040500) can0 183#02", "(10.050000) can0 080#")
    assert found(checker, text, D3) == []


def test_d003_stopped_stream(checker: Checker) -> None:
    """(e): after the stream's last TPDO, three SYNCs (n + 1 for type 2) pass while node 3
    stays OPERATIONAL."""
    text = log("(10.000000) can0 703#00", "(10.001000) can0 000#0103", "(10.010000) can0 080#",
               "(10.010500) can0 183#01", "(10.020000) can0 080#", "(10.030000) can0 080#",
               "(10.030500) can0 183#02", "(10.040000) can0 080#", "(10.050000) can0 080#",
               "(10.060000) can0 080#", "(10.070000) can0 080#")
    assert found(checker, text, D3) == [("D003", 3, 10.06, 9, 10)]


D4_LOG = log("(10.000000) can0 704#00", "(10.001000) can0 000#0104", "(10.010000) can0 204#0100",
             "(10.030000) can0 204#0200", "(10.050000) can0 204#0300",
             "(10.200000) can0 204#0400", "(10.220000) can0 204#0500")


def test_d004_fires_when_the_deadline_expires(checker: Checker) -> None:
    assert found(checker, D4_LOG, D4) == [("D004", 4, 10.1, 5, 6)]
    assert "producer unknown" in checker.run(D4_LOG, network=D4).findings[0].message


def test_d004_silent_before_the_first_rpdo_and_when_stopped(checker: Checker) -> None:
    late = log("(10.000000) can0 704#00", "(10.001000) can0 000#0104",
               "(10.500000) can0 204#0100", "(10.520000) can0 204#0200")
    assert found(checker, late, D4) == []
    stopped = D4_LOG.replace("(10.200000) can0 204#0400\n(10.220000) can0 204#0500\n", log(
        "(10.060000) can0 000#0204", "(10.300000) can0 000#0104", "(10.310000) can0 204#0400",
        "(10.330000) can0 204#0500"))
    assert found(checker, stopped, D4) == []


def test_d005_rpdo_shorter_than_the_consumers_mapping(checker: Checker) -> None:
    text = log("(10.000000) can0 704#00", "(10.001000) can0 000#0104",
               "(10.010000) can0 204#0F0001", "(10.020000) can0 204#0F00",
               "(10.030000) can0 204#0F00", "(10.040000) can0 204#0F0001")
    assert found(checker, text, D5R) == [("D005", 4, 10.02, 3, 4)]
    assert checker.run(text, network=D5R).findings[0].message.endswith(
        "node 4 discards it and raises EMCY 8210h (2 frames)")


def test_d005_tpdo_longer_than_the_producers_mapping(checker: Checker) -> None:
    text = log("(10.000000) can0 703#00", "(10.001000) can0 000#0103",
               "(10.010000) can0 183#3702000000000000", "(10.020000) can0 183#3702000000000000")
    assert found(checker, text, D5T) == [("D005", 3, 10.01, 2, 3)]


def test_d005_in_pre_operational(checker: Checker) -> None:
    text = log("(10.000000) can0 704#00", "(10.010000) can0 204#0F00",
               "(10.020000) can0 000#0104", "(10.030000) can0 204#0F0001")
    assert found(checker, text, D5R, "DS") == [("D005", 4, 10.01, 1, 2),
                                              ("S002", 4, 10.01, 1, 2)]


def test_d006_reserved_types(checker: Checker) -> None:
    refused = log("(10.000000) can0 603#2F021802F1000000",
                  "(10.001000) can0 583#8002180230000906")
    assert found(checker, refused) == [("D006", 3, 10.0, 0, 1)]
    assert "refused it (abort 06090030h" in checker.run(refused).findings[0].message
    accepted = log("(10.000000) can0 604#2F001402FC000000",
                   "(10.001000) can0 584#6000140200000000")
    assert found(checker, accepted) == [("D006", 4, 10.0, 0, 1)]
    assert "accepted it" in checker.run(accepted).findings[0].message
    valid = log("(10.000000) can0 603#2F001802FC000000", "(10.001000) can0 583#6000180200000000")
    assert found(checker, valid) == []


def test_pdo_parameters_from_a_device_file(checker: Checker, tmp_path: Path) -> None:
    """1800h sub 2/5 and 1A00h of node 3's EDS: D001 and D005 judge with them."""
    eds = tmp_path / "n3.eds"
    eds.write_text(
        "[DeviceInfo]\nProductName=x\n"
        "[1800]\nParameterName=TPDO1\nObjectType=0x9\nSubNumber=6\n"
        "[1800sub0]\nParameterName=n\nObjectType=0x7\nDataType=0x5\nAccessType=ro\n"
        "DefaultValue=6\n"
        "[1800sub1]\nParameterName=cob\nObjectType=0x7\nDataType=0x7\nAccessType=rw\n"
        "DefaultValue=$NODEID+0x180\n"
        "[1800sub2]\nParameterName=type\nObjectType=0x7\nDataType=0x5\nAccessType=rw\n"
        "DefaultValue=254\n"
        "[1800sub5]\nParameterName=event\nObjectType=0x7\nDataType=0x6\nAccessType=rw\n"
        "DefaultValue=100\n"
        "[1A00]\nParameterName=map\nObjectType=0x9\nSubNumber=2\n"
        "[1A00sub0]\nParameterName=n\nObjectType=0x7\nDataType=0x5\nAccessType=rw\n"
        "DefaultValue=1\n"
        "[1A00sub1]\nParameterName=m1\nObjectType=0x7\nDataType=0x7\nAccessType=rw\n"
        "DefaultValue=0x60410010\n")
    net = f'[nodes.3]\neds = "{eds}"\n'
    assert found(checker, D1_LOG, net) == [("D001", 3, 10.314, 5, 6)]
    long = D1_LOG.replace("183#0300", "183#030000")
    assert [f[0] for f in found(checker, long, net)] == ["D005", "D001"]


@pytest.mark.parametrize("bad, needle", [
    ("[nodes.3.tpdo.1]\ntransmission_type = 245\n", "transmission_type: 245 is reserved"),
    ("[nodes.3.rpdo.1]\ntransmission_type = 252\n", "transmission_type: 252 is reserved"),
    ("[nodes.3.tpdo.600]\ncob_id = 0x183\n", "[nodes.3.tpdo.600]: PDO number must be 1..512"),
    ("[nodes.3.tpdo.1]\nmapping = [" + ", ".join(["1"] * 65) + "]\n", "mapping: expected a list"),
    ("[nodes.3.tpdo.1]\nevent_timer = 5\n", "event_timer: unknown key"),
])
def test_bad_pdo_keys_are_one_line_errors(tmp_path: Path, bad: str, needle: str) -> None:
    (tmp_path / "net.toml").write_text(bad)
    (tmp_path / "x.log").write_text(D1_LOG)
    assert_one_line_error(run_cli("check", "x.log", "--network", "net.toml", cwd=tmp_path),
                          "net.toml", needle)


# -- chains (§9.5.5) ------------------------------------------------------------------------

def _entries(entries: list[dict[str, object]] | None, *keys: str) -> list[tuple[object, ...]]:
    return [tuple(c.get(k) for k in keys) for c in entries or []]


def test_ch1_a_consumers_emcy_explained_by_the_producers_heartbeat_gap(checker: Checker) -> None:
    text = log("(10.000000) can0 702#05", "(10.000500) can0 705#05",
               "(10.001000) can0 605#2316100196000200", "(10.002000) can0 585#6016100100000000",
               "(10.100000) can0 702#05", "(10.100500) can0 705#05", "(10.200500) can0 705#05",
               "(10.251000) can0 085#3081101B00000000", "(10.251500) can0 705#7F",
               "(10.351500) can0 705#7F", "(10.451500) can0 705#7F")
    res = checker.run(text)
    h = next(f for f in res.findings if f.rule == "H001")
    assert (h.node, round(h.time, 6), h.frame_index, h.line) == (2, 10.25, 7, 8)
    assert _entries(h.causes, "kind", "node", "link") == [("sdo_write", 5, "window")]
    assert _entries(h.reactions, "kind", "node", "code", "time", "role") == [
        ("emcy_other", 5, "8130h", 10.251, "response")]
    s = next(f for f in res.findings if f.rule == "S005")
    assert (s.node, round(s.time, 6)) == (5, 10.2515)
    assert _entries(s.causes, "kind", "node", "code", "rule", "time", "link", "depth",
                    "parent") == [
        ("emcy", 5, "8130h", None, 10.251, "error_behaviour", 1, None),
        ("finding", 2, None, "H001", 10.25, "heartbeat_consumer", 2, 0)]
    assert ("E003", 5) in {(f.rule, f.node) for f in res.findings}


def test_ch2_the_text_example_of_the_spec(checker: Checker) -> None:
    text = log("(10.000000) can0 703#05", "(10.000500) can0 704#05", "(10.010000) can0 204#0100",
               "(10.030000) can0 204#0200", "(10.050000) can0 204#0300",
               "(10.055000) can0 000#0203", "(10.100000) can0 703#04",
               "(10.101000) can0 084#5082101751C30000", "(10.101500) can0 704#7F",
               "(10.200000) can0 703#04", "(10.201500) can0 704#7F")
    res = checker.run(text, network=CH2)
    d = next(f for f in res.findings if f.rule == "D004")
    assert (d.node, round(d.time, 6), d.frame_index, d.line) == (4, 10.1, 6, 7)
    assert _entries(d.causes, "kind", "node", "time", "frame_index", "line", "link") == [
        ("nmt", 3, 10.055, 5, 6, "producer_state")]
    assert _entries(d.reactions, "kind", "node", "code", "time", "role") == [
        ("node_state", 3, None, 10.1, "during"), ("emcy", 4, "8250h", 10.101, "report"),
        ("node_state", 4, None, 10.1015, "report")]
    s = next(f for f in res.findings if f.rule == "S005")
    assert _entries(s.causes, "kind", "node", "rule", "time", "link", "depth", "parent") == [
        ("emcy", 4, None, 10.101, "error_behaviour", 1, None),
        ("finding", 4, "D004", 10.1, "rpdo_timeout", 2, 0),
        ("nmt", 3, None, 10.055, "producer_state", 3, 1)]
    assert not [f for f in res.findings if f.rule == "D001"]
    assert ("E003", 4) in {(f.rule, f.node) for f in res.findings}


def test_ch4_a_consumers_sync_timeout(checker: Checker) -> None:
    text = log("(10.000000) can0 703#05", "(10.010000) can0 080#", "(10.020000) can0 080#",
               "(10.030000) can0 080#", "(10.046000) can0 083#00811018FC3A0000",
               "(10.046500) can0 703#7F", "(10.100000) can0 080#")
    res = checker.run(text, network=Y)
    y = next(f for f in res.findings if f.rule == "Y001")
    assert (y.node, round(y.time, 6), y.frame_index, y.line) == (None, 10.045, 4, 5)
    assert y.causes == []
    assert _entries(y.reactions, "kind", "node", "code", "role") == [
        ("emcy_other", 3, "8100h", "response")]
    s = next(f for f in res.findings if f.rule == "S005")
    assert _entries(s.causes, "kind", "rule", "link", "depth", "parent") == [
        ("emcy", None, "error_behaviour", 1, None), ("finding", "Y001", "sync_timeout", 2, 0)]


def test_reports_carry_the_streams_and_the_sync(tmp_path: Path) -> None:
    """SPEC §9.4.1 through the JSON report and the Python API: `pdo_streams[]` with its
    producer, consumer, parameters, measured timing and findings; `channels[i].sync`;
    a D finding's `cob_id`."""
    import json

    import nmtcheck

    (tmp_path / "ch2.toml").write_text(CH2)
    (tmp_path / "ch2.log").write_text(log(
        "(10.000000) can0 703#05", "(10.000500) can0 704#05", "(10.010000) can0 204#0100",
        "(10.030000) can0 204#0200", "(10.050000) can0 204#0300", "(10.055000) can0 000#0203",
        "(10.100000) can0 703#04", "(10.101000) can0 084#5082101751C30000",
        "(10.101500) can0 704#7F", "(10.200000) can0 703#04", "(10.201500) can0 704#7F"))
    report = nmtcheck.check(tmp_path / "ch2.log", network=tmp_path / "ch2.toml")
    doc = json.loads(report.to_json())
    assert doc["report_version"] == 2
    [st] = doc["pdo_streams"]
    assert (st["cob_id"], st["kind"], st["producer"]["node"]) == ("204h", "tpdo", 3)
    assert [c["node"] for c in st["consumers"]] == [4]
    assert st["consumers"][0]["event_timer_ms"]["value"] == 50
    assert st["parameters"]["event_timer_ms"] == {"value": 20, "source": "network", "node": 3}
    assert st["measured"]["frames"] == 3 and st["measured"]["period_median_ms"] == 20.0
    assert st["findings"] == {"D004": 1}
    assert [f["cob_id"] for f in doc["findings"] if f["rule"] == "D004"] == ["204h"]
    assert report.pdo_streams[["cob_id", "kind", "producer_node"]].values.tolist() == [
        ["204h", "tpdo", 3]]
    assert report.sync.empty  # no SYNC on this channel


def test_ch3_an_error_frame_explains_the_bus_off_emcy(tmp_path: Path) -> None:
    """§9.5.5 CH3: the error frame inside node 5's heartbeat gap is H001's cause; its EMCY
    8140h afterwards is a reaction, and the EMCY event's own cause is that error frame
    (link `can_errors`: after node 5's last frame at 10.300)."""
    import json

    from nmtcheck.engine import check_input, select_rules
    from nmtcheck.reporters import json as json_report
    from nmtcheck.settings.profiles import load_profile

    path = tmp_path / "ch3.log"
    path.write_text(log("(10.000000) can0 705#05", "(10.100000) can0 705#05",
                        "(10.200000) can0 705#05", "(10.300000) can0 705#05",
                        "(10.350000) can0 20000080#0000000000000000",
                        "(11.000000) can0 085#4081110000000000", "(11.010000) can0 705#05"))
    profile = load_profile("default")
    res = check_input(str(path), 0, profile, select_rules(profile, [], []))
    h = next(f for f in res.findings if f.rule == "H001")
    assert (h.node, round(h.time, 6), h.frame_index, h.line) == (5, 10.45, 5, 6)
    assert _entries(h.causes, "kind", "time", "frame_index", "line", "link", "count") == [
        ("error_frames", 10.35, 4, 5, "window", 1)]
    assert _entries(h.reactions, "kind", "node", "code", "time", "role") == [
        ("emcy", 5, "8140h", 11.0, "report")]
    [event] = [e for e in json.loads(json_report.render([res], {}))["events"]
               if e["kind"] == "emcy"]
    assert _entries(event["causes"], "kind", "time", "link") == [
        ("error_frames", 10.35, "can_errors")]


def test_an_emcy_event_carries_its_chain_and_canopennodes_detail(checker: Checker) -> None:
    """CH2's EMCY 8250h as an event: its cause the D004 gap (`rpdo_timeout`), that gap's
    the NMT stop of the producer; byte 3 = 17h and the info read as CANopenNode's."""
    import json

    from nmtcheck.reporters import json as json_report

    text = log("(10.000000) can0 703#05", "(10.000500) can0 704#05", "(10.010000) can0 204#0100",
               "(10.030000) can0 204#0200", "(10.050000) can0 204#0300",
               "(10.055000) can0 000#0203", "(10.100000) can0 703#04",
               "(10.101000) can0 084#5082101751C30000", "(10.101500) can0 704#7F")
    res = checker.run(text, network=CH2)
    [event] = [e for e in json.loads(json_report.render([res], {}))["events"]
               if e["kind"] == "emcy"]
    assert _entries(event["causes"], "kind", "rule", "link", "depth", "parent") == [
        ("finding", "D004", "rpdo_timeout", 1, None), ("nmt", None, "producer_state", 2, 0)]
    assert event["canopennode"] == {"error_bit": "17h", "info": 50001,
                                    "meaning": "RPDO timeout (us since the timer was armed "
                                               "= 50001)"}


def test_a_timeline_change_no_command_explains_carries_its_causes(checker: Checker) -> None:
    """§9.3.6: node 4's PRE-OPERATIONAL interval (a change no NMT command explains) carries
    S005's chain in the JSON timeline, by the dict path and the streamed path alike, also
    with S005 not selected."""
    import json

    from nmtcheck.reporters import json as json_report

    text = log("(10.000000) can0 703#05", "(10.000500) can0 704#05", "(10.010000) can0 204#0100",
               "(10.030000) can0 204#0200", "(10.050000) can0 204#0300",
               "(10.055000) can0 000#0203", "(10.100000) can0 703#04",
               "(10.101000) can0 084#5082101751C30000", "(10.101500) can0 704#7F")
    res = checker.run(text, network=CH2, ignore="S005")
    rows = [r for r in json.loads(json_report.render([res], {}))["timeline"] if "causes" in r]
    assert [(r["node"], r["state"], r["start"]) for r in rows] == [
        (4, "PRE-OPERATIONAL", 10.1015)]
    assert _entries(rows[0]["causes"], "kind", "rule", "link", "depth", "parent") == [
        ("emcy", None, "error_behaviour", 1, None), ("finding", "D004", "rpdo_timeout", 2, 0),
        ("nmt", None, "producer_state", 3, 1)]
    streamed = [json.loads(line) for line in json_report._timeline_lines([res])]
    assert streamed == list(json_report._timeline([res]))


def test_a_consumers_emcy_for_a_rebooted_producer(checker: Checker) -> None:
    """`heartbeat_remote_reset` (§9.3.4): CANopenNode's 8130h with byte 3 = 1Ch follows
    node 2's boot-up (node 2 had sent heartbeats): node 5's drop is explained by it."""
    text = log("(10.000000) can0 702#05", "(10.000500) can0 705#05", "(10.100000) can0 702#05",
               "(10.100500) can0 705#05", "(10.150000) can0 702#00",
               "(10.151000) can0 085#3081101C00000000", "(10.151500) can0 705#7F",
               "(10.250000) can0 702#05")
    s = next(f for f in checker.run(text).findings if f.rule == "S005")
    assert _entries(s.causes, "kind", "node", "link", "depth", "parent") == [
        ("emcy", 5, "error_behaviour", 1, None), ("bootup", 2, "heartbeat_remote_reset", 2, 0)]


def test_a_consumers_sync_length_emcy(checker: Checker) -> None:
    """`sync_length` (§9.3.4): EMCY 8240h (byte 3 = 19h) right after a SYNC that Y002
    reports (1019h = 0, one data byte)."""
    text = log("(10.000000) can0 703#05", "(10.010000) can0 080#", "(10.020000) can0 080#05",
               "(10.021000) can0 083#4082101940000000", "(10.021500) can0 703#7F")
    res = checker.run(text, network="[sync]\ncounter_overflow = 0\n")
    s = next(f for f in res.findings if f.rule == "S005")
    assert _entries(s.causes, "kind", "rule", "link", "depth") == [
        ("emcy", None, "error_behaviour", 1), ("finding", "Y002", "sync_length", 2)]


def test_the_html_report_shows_the_streams_and_the_emcys(checker: Checker) -> None:
    """SPEC §9.4.2: the HTML report's SYNC, PDO and EMCY section lists the stream with its
    producer, consumer, event timer, deadline and findings, and the node's EMCY codes."""
    from nmtcheck.reporters import html

    text = log("(10.000000) can0 703#05", "(10.000500) can0 704#05", "(10.010000) can0 204#0100",
               "(10.030000) can0 204#0200", "(10.050000) can0 204#0300",
               "(10.055000) can0 000#0203", "(10.100000) can0 703#04",
               "(10.101000) can0 084#5082101751C30000", "(10.101500) can0 704#7F")
    page = html.render([checker.run(text, network=CH2)], {})
    section = page.split('<section id="communication">')[1].split("</section>")[0]
    row = section.split('<tr data-cob="204h">')[1].split("</tr>")[0]
    assert "node 3 → node 4" in row and ">255<" in row and "D004 × 1" in row
    assert ">20<" in row.replace(" ", "") and ">50<" in row.replace(" ", "")
    emcy = section.split('<table class="data emcy-table">')[1]
    assert "8250h" in emcy and "yes, register 10h" in emcy and "canopennode" in emcy


def test_order_only_messages_name_frames_not_seconds(checker: Checker) -> None:
    """Without timestamps D003 still counts SYNCs, and E003 still lists what is active:
    their messages name frames, never seconds made of frame numbers (SPEC §1)."""
    log = "703#05\n080#\n183#01\n080#\n080#\n080#\n183#01\n083#0010010000000000\n"
    res = checker.run(log, network="[nodes.3.tpdo.1]\ncob_id = 0x183\ntransmission_type = 1\n")
    [d003] = [f for f in res.findings if f.rule == "D003"]
    assert d003.message == ("TPDO 183h (type 1) missing after SYNC at frame 4 (line 4): 3 SYNCs "
                            "between TPDOs at frame 3 and frame 7, expected 1")
    [e003] = [f for f in res.findings if f.rule == "E003"]
    assert "last EMCY 1000h generic error at frame 8 (line 8)" in e003.message
    assert " s (line" not in d003.message + e003.message
