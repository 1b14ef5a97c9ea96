"""Groups Y (SYNC) and E (EMCY) of SPEC §9.2: every test vector of §9.5.1 (but Y004, which
needs the PDO streams) and §9.5.3 verbatim, each rule firing and staying silent; the
values they need from the network file, device files and SDO writes in the trace; and
the `not_evaluated` reasons of §9.1.9."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import Checker, assert_one_line_error, run_cli

from nmtcheck.reporters import json as json_report
from nmtcheck.reporters import text as text_report

Y = "[sync]\nperiod_us = 10000\n"
Y1 = Y + "producer = 1\n"
Y0 = "[sync]\ncounter_overflow = 0\n"
Y4 = "[sync]\ncounter_overflow = 4\n"
E = "[nodes.5]\nemcy_inhibit_100us = 100\n"


def log(*lines: str) -> str:
    return "".join(line + "\n" for line in lines)


def found(checker: Checker, text: str, group: str, network: str | None = None,
          profile: str = "default") -> list[tuple[str, int | None, float, int | None,
                                                  int | None]]:
    """(rule, node, time, frame index, line) of the group's findings (SPEC §9.5's form)."""
    res = checker.run(text, network=network, profile=profile)
    return [(f.rule, f.node, round(f.time, 6), f.frame_index, f.line)
            for f in res.findings if f.rule[0] in group]


SYNC_5 = log("(10.000000) can0 080#", "(10.010000) can0 080#", "(10.020000) can0 080#",
             "(10.050000) can0 080#", "(10.060000) can0 080#")


def test_y001_fires_on_the_configured_period(checker: Checker) -> None:
    assert found(checker, SYNC_5, "Y", Y) == [("Y001", None, 10.035, 3, 4)]
    res = checker.run(SYNC_5, network=Y)
    [f] = res.findings
    assert f.basis == "configured" and "timeout 15.000 ms = 1.5 x 1006h 10.000 ms" in f.message
    assert "no SYNC for 30.000 ms" in f.message


def test_y001_fires_on_the_measured_period(checker: Checker) -> None:
    text = log(*(f"(10.0{k}0000) can0 080#" for k in range(7)), "(10.100000) can0 080#")
    assert found(checker, text, "Y") == [("Y001", None, 10.075, 7, 8)]
    [f] = checker.run(text).findings
    assert f.basis == "measured" and "[limit measured from the trace]" in f.message


def test_y001_silent_across_the_producers_reset(checker: Checker) -> None:
    text = log("(10.000000) can0 080#", "(10.010000) can0 080#", "(10.020000) can0 080#",
               "(10.025000) can0 000#8101", "(10.030000) can0 701#00",
               "(10.300000) can0 080#", "(10.310000) can0 080#")
    assert found(checker, text, "Y", Y1) == []


def test_y001_silent_when_every_consumer_is_stopped(checker: Checker) -> None:
    """With the channel's other nodes STOPPED nobody can miss the SYNC (§9.2.1); the same
    gap with node 2 OPERATIONAL fires."""
    stopped = log("(9.900000) can0 702#04", SYNC_5.replace("\n", "\n", 1).rstrip("\n"))
    assert found(checker, stopped, "Y", Y) == []
    running = log("(9.900000) can0 702#05", SYNC_5.rstrip("\n"))
    assert [f[0] for f in found(checker, running, "Y", Y)] == ["Y001"]


def test_y001_silent_without_timestamps(checker: Checker) -> None:
    res = checker.run("".join(line.split(" ", 1)[1] + "\n" for line in SYNC_5.splitlines()),
                      network=Y)
    assert not [f for f in res.findings if f.rule == "Y001"]
    assert res.not_evaluated["Y001"].startswith("no timestamps")


def test_y002_dlc_forbidden_by_1019h(checker: Checker) -> None:
    text = log("(10.000000) can0 080#", "(10.010000) can0 080#", "(10.020000) can0 080#05",
               "(10.030000) can0 080#")
    assert found(checker, text, "Y", Y0) == [("Y002", None, 10.02, 2, 3)]


def test_y002_counter_above_1019h_and_no_y003(checker: Checker) -> None:
    text = log(*(f"(10.0{k}0000) can0 080#0{k + 1}" for k in range(5)),
               "(10.050000) can0 080#01")
    assert found(checker, text, "Y", Y4) == [("Y002", None, 10.04, 4, 5)]


def test_y002_dlc_change_without_1019h(checker: Checker) -> None:
    text = log("(10.000000) can0 080#01", "(10.010000) can0 080#02", "(10.020000) can0 080#",
               "(10.030000) can0 080#")
    assert found(checker, text, "Y") == [("Y002", None, 10.02, 2, 3)]
    [f] = checker.run(text).findings
    assert f.message.endswith("(2 frames)")


def test_y002_and_y003_silent_on_a_restart(checker: Checker) -> None:
    text = log("(10.000000) can0 080#01", "(10.010000) can0 080#02", "(10.020000) can0 080#03",
               "(10.030000) can0 080#01", "(10.040000) can0 080#02")
    assert found(checker, text, "Y") == []


def test_y002_remote_frame(checker: Checker) -> None:
    text = log("(10.000000) can0 080#", "(10.010000) can0 080#R", "(10.020000) can0 080#")
    assert found(checker, text, "Y") == [("Y002", None, 10.01, 1, 2)]


def test_y003_missing_sync(checker: Checker) -> None:
    text = log("(10.000000) can0 080#01", "(10.010000) can0 080#02", "(10.020000) can0 080#03",
               "(10.030000) can0 080#05", "(10.040000) can0 080#06")
    assert found(checker, text, "Y") == [("Y003", None, 10.03, 3, 4)]
    [f] = checker.run(text).findings
    assert "1 SYNC(s) missing" in f.message


def test_y003_repeated_counter(checker: Checker) -> None:
    text = log("(10.000000) can0 080#07", "(10.010000) can0 080#08", "(10.020000) can0 080#08",
               "(10.030000) can0 080#09")
    assert found(checker, text, "Y") == [("Y003", None, 10.02, 2, 3)]
    assert "repeated" in checker.run(text).findings[0].message


def test_y003_silent_on_a_restart_at_1(checker: Checker) -> None:
    text = log("(10.000000) can0 080#07", "(10.010000) can0 080#08", "(10.020000) can0 080#01",
               "(10.030000) can0 080#02", "(10.040000) can0 080#03")
    assert found(checker, text, "Y") == []


SIX_12MS = log(*(f"(10.{12 * k:03d}000) can0 080#" for k in range(6)))


def test_y005_fires_and_stays_silent(checker: Checker) -> None:
    assert found(checker, SIX_12MS, "Y", Y) == [("Y005", None, 10.06, 5, 6)]
    assert "+20.0 %" in checker.run(SIX_12MS, network=Y).findings[0].message
    four = "".join(SIX_12MS.splitlines(keepends=True)[:5])
    assert found(checker, four, "Y", Y) == []
    close = log(*(f"({10 + 0.0105 * k:.6f}) can0 080#" for k in range(6)))
    assert found(checker, close, "Y", Y) == []


def test_y005_needs_the_producers_period(checker: Checker) -> None:
    res = checker.run(SIX_12MS)
    assert res.not_evaluated["Y005"] == "the SYNC producer's 1006h is unknown"


def test_y_values_from_device_files(checker: Checker, tmp_path: Path) -> None:
    """1005h bit 30 names the producer; its 1006h is P; Y001 names the producer node."""
    eds = tmp_path / "sync.eds"
    eds.write_text("[DeviceInfo]\nProductName=sync producer\n"
                   "[1005]\nParameterName=COB-ID SYNC\nObjectType=0x7\nDataType=0x0007\n"
                   "AccessType=rw\nDefaultValue=0x40000080\n"
                   "[1006]\nParameterName=Communication cycle period\nObjectType=0x7\n"
                   "DataType=0x0007\nAccessType=rw\nDefaultValue=10000\n")
    network = f'[nodes.1]\neds = "{eds}"\n'
    assert found(checker, SYNC_5, "Y", network) == [("Y001", 1, 10.035, 3, 4)]
    res = checker.run(SYNC_5, network=network)
    [y001] = [f for f in res.findings if f.rule == "Y001"]
    assert "1006h 10.000 ms (node 1's device file)" in y001.message
    sync = json.loads(json_report.render([res], {}))["channels"][0]["sync"]
    assert sync["producer"] == {"node": 1, "source": "device-file"}
    assert sync["period_us"]["value"] == 10000 and sync["period_us"]["source"] == "device-file"


def test_y_period_written_by_sdo(checker: Checker) -> None:
    """A confirmed download of the producer's 1006h ends the segment and sets P."""
    text = log("(9.000000) can0 601#2306100010270000", "(9.001000) can0 581#6006100000000000",
               SYNC_5.rstrip("\n"))
    assert found(checker, text, "Y", "[sync]\nproducer = 1\n") == [
        ("Y001", 1, 10.035, 5, 6)]


@pytest.mark.parametrize("bad, needle", [
    ("[sync]\ncounter_overflow = 1\n", "counter_overflow: 1 is not a counter overflow value"),
    ("[sync]\nperiod = 5\n", "period: unknown key"),
    ("[sync]\nproducer = 0\n", "producer: expected an integer 1..127"),
    ("[nodes.3.tpdo.1]\ntransmission_type = 245\n", "[nodes.3.tpdo.1] transmission_type: 245 is "
     "reserved"),
    ("[nodes.3.rpdo.1]\nmapping = 5\n", "[nodes.3.rpdo.1] mapping: expected a list"),
    ("[nodes.3]\nemcy_inhibit_100us = -1\n", "[nodes.3] emcy_inhibit_100us: expected an integer"),
    ("[channels.can0.sync]\nwindow_us = 'x'\n", "[channels.can0] sync window_us"),
])
def test_bad_network_keys_are_one_line_errors(tmp_path: Path, bad: str, needle: str) -> None:
    (tmp_path / "net.toml").write_text(bad)
    (tmp_path / "x.log").write_text(SYNC_5)
    res = run_cli("check", "x.log", "--network", "net.toml", cwd=tmp_path)
    assert_one_line_error(res, "net.toml", needle)


# -- group E ------------------------------------------------------------------------------

def test_e001_fires_and_stays_silent(checker: Checker) -> None:
    text = log("(10.000000) can0 705#00", "(10.010000) can0 085#1023030000000000",
               "(10.012000) can0 085#0000000000000000")
    assert found(checker, text, "E", E) == [("E001", 5, 10.012, 2, 3)]
    assert "inhibit time 1015h = 100 x 100 us = 10 ms (network)" in checker.run(
        text, network=E).findings[0].message
    assert found(checker, text.replace("10.012000", "10.020000"), "E", E) == []
    rebooted = log("(10.000000) can0 705#00", "(10.010000) can0 085#1023030000000000",
                   "(11.500000) can0 705#00", "(11.600000) can0 085#1023030000000000")
    res = checker.run(rebooted, network=E)
    assert [(f.rule, f.node, round(f.time, 6)) for f in res.findings
            if f.rule in ("E001", "E003", "B002")] == [("B002", 5, 11.5), ("E003", 5, 11.6)]


def test_e001_allows_for_an_emcy_that_waited_for_the_bus(checker: Checker) -> None:
    """SPEC §9.2.3 (q of §9.1.6): d8 = 130 us; F1 ends a back-to-back run that began at
    10.008000: q(F1) = 650 us, the limit 9.349 ms < 9.480 ms. Without the run the pair
    fires."""
    text = log("(10.000000) can0 705#00",
               "(10.008000) can0 201#1122334455667788", "(10.008130) can0 202#1122334455667788",
               "(10.008260) can0 203#1122334455667788", "(10.008390) can0 204#1122334455667788",
               "(10.008520) can0 085#1023030000000000", "(10.018000) can0 085#0000000000000000")
    assert found(checker, text, "E", E) == []
    bare = "".join(line for line in text.splitlines(keepends=True) if "#1122" not in line)
    assert found(checker, bare, "E", E) == [("E001", 5, 10.018, 2, 3)]


def test_e001_inhibit_written_by_sdo(checker: Checker) -> None:
    """1015h = 100 downloaded to node 5 and confirmed: E001 names the write."""
    text = log("(10.000000) can0 705#00", "(10.001000) can0 605#2B15100064000000",
               "(10.002000) can0 585#6015100000000000",
               "(10.010000) can0 085#1023030000000000", "(10.012000) can0 085#0000000000000000")
    [f] = [f for f in checker.run(text).findings if f.rule == "E001"]
    assert "written by SDO at line 3" in f.message


def test_e001_not_evaluated_without_an_inhibit_time(checker: Checker) -> None:
    text = log("(10.000000) can0 705#00", "(10.010000) can0 085#1023030000000000",
               "(10.012000) can0 085#0000000000000000")
    assert checker.run(text).not_evaluated["E001"] == "no EMCY inhibit time (1015h) known"


def test_e002_dlc_2_and_7(checker: Checker) -> None:
    text = log("(10.000000) can0 705#05", "(10.010000) can0 085#1023")
    assert found(checker, text, "E") == [("E002", 5, 10.01, 1, 2), ("E003", 5, 10.01, 1, 2)]
    text = log("(10.000000) can0 705#05", "(10.010000) can0 085#10230300000000",
               "(10.020000) can0 085#10230300000000")
    assert found(checker, text, "E") == [("E002", 5, 10.01, 1, 2), ("E003", 5, 10.02, 2, 3)]
    assert checker.run(text).findings[0].message.endswith("(2 frames)")


def test_e002_generic_bit_only_when_asked(checker: Checker, tmp_path: Path) -> None:
    text = log("(10.000000) can0 705#05", "(10.010000) can0 085#5082101751C30000",
               "(10.020000) can0 085#0000001700000000")
    assert found(checker, text, "E") == []
    strict = tmp_path / "strict.toml"
    strict.write_text("[rules.E002]\nrequire_generic_bit = true\n")
    assert found(checker, text, "E", profile=str(strict)) == [("E002", 5, 10.01, 1, 2)]


def test_e002_remote_frame(checker: Checker) -> None:
    text = log("(10.000000) can0 705#05", "(10.010000) can0 085#R")
    assert found(checker, text, "E") == [("E002", 5, 10.01, 1, 2)]


def test_e003_fires_and_s005_is_explained(checker: Checker) -> None:
    text = log("(10.000000) can0 705#05", "(10.100000) can0 085#3081101B00000000",
               "(10.200000) can0 705#7F")
    res = checker.run(text)
    assert [(f.rule, f.node, round(f.time, 6)) for f in res.findings] == [
        ("E003", 5, 10.1), ("S005", 5, 10.2)]
    e003, s005 = res.findings
    assert "CANopenNode: heartbeat consumer timeout" in e003.message
    [cause] = s005.causes or []
    assert (cause["kind"], cause["code"], cause["link"]) == ("emcy", "8130h", "error_behaviour")
    assert s005.message.endswith("explained by EMCY 8130h at 0.100000 s (line 2)")
    emcy = json.loads(json_report.render([res], {}))["nodes"][0]["emcy"]
    assert emcy["in_error_at_end"] is True and emcy["stack"] == "canopennode"
    assert emcy["codes"][0]["code"] == "8130h" and emcy["last_register"] == "10h"


def test_e003_silent_after_a_reset_frame_or_a_reboot(checker: Checker) -> None:
    reset = log("(10.000000) can0 705#05", "(10.100000) can0 085#3081101B00000000",
                "(10.200000) can0 085#0000001B00000000")
    assert found(checker, reset, "E") == []
    rebooted = log("(10.000000) can0 705#05", "(10.100000) can0 085#1023030000000000",
                   "(12.000000) can0 705#00", "(12.100000) can0 705#7F")
    res = checker.run(rebooted)
    assert [(f.rule, f.node, round(f.time, 6)) for f in res.findings
            if f.rule in ("E003", "B002")] == [("B002", 5, 12.0)]


def test_error_behaviour_follows_1029h(checker: Checker) -> None:
    """1029h:01 = 2 (to STOPPED): a change to PRE-OPERATIONAL is not its doing; 1 (no
    change): no link at all."""
    text = log("(10.000000) can0 705#05", "(10.100000) can0 085#0081100000000000",
               "(10.200000) can0 705#7F")
    linked = checker.run(text, network="[nodes.5]\nerror_behaviour = 0\n").findings[-1]
    assert [c["link"] for c in linked.causes or []] == ["error_behaviour"]
    for value in (1, 2):
        s005 = checker.run(text, network=f"[nodes.5]\nerror_behaviour = {value}\n").findings[-1]
        assert s005.rule == "S005" and [c["link"] for c in s005.causes or []] == ["window"]


def test_clean_traffic_is_silent(checker: Checker) -> None:
    """A SYNC every 10 ms with counters 1..4 and an error with its reset: nothing."""
    lines = [f"({10 + 0.01 * k:.6f}) can0 080#{k % 4 + 1:02X}" for k in range(40)]
    lines += ["(10.405000) can0 085#1023030000000000", "(10.505000) can0 085#0000000000000000"]
    text = log(*sorted(lines))
    assert found(checker, text, "YE", "[sync]\nperiod_us = 10000\ncounter_overflow = 4\n"
                 "[nodes.5]\nemcy_inhibit_100us = 100\n") == []


# -- chains (SPEC §9.3.4, §9.3.5) -----------------------------------------------------------

STOPPED_PRODUCER = log(
    "(10.000000) can0 701#05", "(10.000100) can0 702#05", "(10.010000) can0 080#",
    "(10.020000) can0 080#", "(10.030000) can0 080#", "(10.040000) can0 080#",
    "(10.045000) can0 000#0201", "(10.056000) can0 082#0081101880BB0000",
    "(10.057000) can0 702#7F", "(10.100000) can0 701#04")
STOPPED_NET = "[sync]\nperiod_us = 10000\nproducer = 1\n"


def test_the_producers_stop_explains_y001(checker: Checker) -> None:
    """Y001's cause is the NMT stop of the SYNC producer inside the gap (`producer_state`);
    the consumer's EMCY and the producer's report of STOPPED come after: reactions."""
    res = checker.run(STOPPED_PRODUCER, network=STOPPED_NET)
    [y] = [f for f in res.findings if f.rule == "Y001"]
    assert (y.node, round(y.time, 6)) == (1, 10.055)
    assert [(c["kind"], c["time"], c["link"]) for c in y.causes or []] == [
        ("nmt", 10.045, "producer_state")]
    assert [(r["kind"], r["node"], r["role"]) for r in y.reactions or []] == [
        ("emcy_other", 2, "response"), ("node_state", 1, "report")]


def test_a_consumer_drop_is_explained_down_to_the_producers_stop(checker: Checker) -> None:
    """S005 of node 2 <- its EMCY 8100h (CANopenNode SYNC timeout, 48000 us after the last
    SYNC) [error_behaviour] <- Y001 [sync_timeout] <- the NMT stop [producer_state]."""
    res = checker.run(STOPPED_PRODUCER, network=STOPPED_NET)
    [s] = [f for f in res.findings if f.rule == "S005"]
    got = [(c["kind"], c.get("rule"), c["link"], c["depth"], c["parent"])
           for c in s.causes or []]
    assert got == [("emcy", None, "error_behaviour", 1, None),
                   ("finding", "Y001", "sync_timeout", 2, 0),
                   ("nmt", None, "producer_state", 3, 1)]
    assert all(c["time"] <= s.time for c in s.causes or [])
    text = "\n".join(line for line in text_report.render([res], {}).splitlines()
                     if "cause:" in line)
    assert "\n          cause: " in text and "\n            cause: " in text


def test_a_sync_timeout_emcy_of_another_gap_is_not_linked(checker: Checker) -> None:
    """CANopenNode's info says the SYNC was missed 900 ms before the EMCY: no Y001 gap
    ends there, so the chain stops at the EMCY."""
    text = STOPPED_PRODUCER.replace("082#0081101880BB0000", "082#0081101840BB0D00")
    [s] = [f for f in checker.run(text, network=STOPPED_NET).findings if f.rule == "S005"]
    assert [c["link"] for c in s.causes or []] == ["error_behaviour"]


W = ("[sync]\nperiod_us = 10000\nwindow_us = 2000\n"
     "[nodes.3.tpdo.1]\ncob_id = 0x183\ntransmission_type = 1\n")
Y004_LOG = log("(10.000000) can0 703#00", "(10.001000) can0 000#0103", "(10.010000) can0 080#",
               "(10.010500) can0 183#0100", "(10.020000) can0 080#", "(10.023000) can0 183#0200",
               "(10.030000) can0 080#", "(10.030400) can0 183#0300")


def test_y004_fires_after_the_window_and_stays_silent_inside(checker: Checker) -> None:
    assert found(checker, Y004_LOG, "Y", W) == [("Y004", 3, 10.023, 5, 6)]
    assert found(checker, Y004_LOG.replace("10.023000", "10.021500"), "Y", W) == []


def test_y004_not_evaluated_without_type_or_window(checker: Checker) -> None:
    res = checker.run(Y004_LOG, network=Y)
    assert res.not_evaluated["Y004"] == "no synchronous PDO with a known transmission type"
    res = checker.run(Y004_LOG, network="[sync]\nperiod_us = 10000\n[nodes.3.tpdo.1]\n"
                                         "cob_id = 0x183\ntransmission_type = 1\n")
    assert res.not_evaluated["Y004"] == "1007h unknown or 0"


def test_y004_silent_while_the_producer_is_not_operational(checker: Checker) -> None:
    """Node 3 never started: its late TPDO is S001's business, not Y004's."""
    text = Y004_LOG.replace("(10.001000) can0 000#0103\n", "")
    assert found(checker, text, "Y", W) == []
