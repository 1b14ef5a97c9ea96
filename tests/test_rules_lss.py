"""Group L (LSS, CiA 305) of SPEC §9.2.4: every test vector of §9.5.4 verbatim, each rule
firing and staying silent, the reconstruction of §9.1.8 the vectors describe (slave
records, pending node-IDs, fastscan results), the `not_evaluated` of L006 without
timestamps and the LSS report fields of §9.4.1."""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest
from conftest import Checker

from nmtcheck.processes import lss
from nmtcheck.reporters import json as json_report
from nmtcheck.reporters import text as text_report


def log(*lines: str) -> str:
    return "".join(line + "\n" for line in lines)


def found(checker: Checker, text: str, group: str = "L", network: str | None = None
          ) -> list[tuple[str, int | None, float, int | None, int | None]]:
    """(rule, node, time, frame index, line) of the group's findings (SPEC §9.5's form)."""
    res = checker.run(text, network=network)
    return [(f.rule, f.node, round(f.time, 6), f.frame_index, f.line)
            for f in res.findings if f.rule[0] in group]


def messages(checker: Checker, text: str, rule: str) -> list[str]:
    return [f.message for f in checker.run(text).findings if f.rule == rule]


L001 = log("(10.000000) can0 7E5#0401000000000000",
           "(10.010000) can0 7E5#1105000000000000",
           "(12.000000) can0 7E5#0400000000000000")


def test_l001_fires(checker: Checker) -> None:
    assert found(checker, L001) == [("L001", 5, 11.01, 2, 3)]
    [m] = messages(checker, L001, "L001")
    assert m == ("no answer to configure node-ID (11h) sent at 0.010000 s (line 2) "
                 "within 1000 ms")


def test_l001_silent_when_answered(checker: Checker) -> None:
    lines = L001.splitlines()
    text = log(*lines[:2], "(10.011000) can0 7E4#1100000000000000", *lines[2:])
    assert found(checker, text) == []


def test_l001_silent_on_an_unanswered_fastscan_reset_and_l007_fires(checker: Checker) -> None:
    text = log("(10.000000) can0 7E5#5100000000800000",
               "(12.000000) can0 7E5#0400000000000000")
    assert found(checker, text) == [("L007", None, 10.0, 0, 1)]
    assert messages(checker, text, "L007") == [
        "fastscan: no non-configured slave answered the reset"]


SELECTIVE = ["(10.000000) can0 7E5#4000030000000000",
             "(10.001000) can0 7E5#4144460000000000",
             "(10.002000) can0 7E5#4200000000000000",
             "(10.003000) can0 7E5#4301000000000000"]


def test_l002_fires(checker: Checker) -> None:
    text = log(*SELECTIVE, "(12.000000) can0 7E5#0400000000000000")
    assert found(checker, text) == [("L002", None, 11.003, 4, 5)]
    assert messages(checker, text, "L002") == [
        "no slave answered selective switch 00000300h:00004644h:00000000h:00000001h"]


def test_l002_silent_when_44h_answers(checker: Checker) -> None:
    text = log(*SELECTIVE, "(10.004000) can0 7E4#4400000000000000")
    assert found(checker, text) == []


def test_l002_out_of_order(checker: Checker) -> None:
    text = log("(10.000000) can0 7E5#4000030000000000",
               "(10.001000) can0 7E5#4200000000000000",
               "(10.002000) can0 7E5#4144460000000000",
               "(10.003000) can0 7E5#4301000000000000",
               "(12.000000) can0 080#")
    assert found(checker, text) == [("L002", None, 11.003, 4, 5)]
    [m] = messages(checker, text, "L002")
    assert m.endswith("requests out of order (40h, 42h, 41h, 43h)")


def test_l003_node_id_out_of_range(checker: Checker) -> None:
    text = log("(10.000000) can0 7E5#0401000000000000",
               "(10.010000) can0 7E5#1180000000000000",
               "(10.011000) can0 7E4#1101000000000000")
    assert found(checker, text) == [("L003", None, 10.011, 2, 3)]
    assert messages(checker, text, "L003") == [
        "configure node-ID 128: slave answered 1 (out of range)"]


def test_l003_store_not_supported(checker: Checker) -> None:
    text = log("(10.000000) can0 7E5#0401000000000000",
               "(10.010000) can0 7E5#1700000000000000",
               "(10.011000) can0 7E4#1701000000000000")
    assert found(checker, text) == [("L003", None, 10.011, 2, 3)]
    assert messages(checker, text, "L003") == [
        "store configuration: slave answered 1 (not supported)"]


def test_l003_silent_on_bit_timing_and_store_answered_0(checker: Checker) -> None:
    text = log("(10.000000) can0 7E5#0401000000000000",
               "(10.010000) can0 7E5#1300020000000000",
               "(10.011000) can0 7E4#1300000000000000",
               "(10.020000) can0 7E5#1700000000000000",
               "(10.021000) can0 7E4#1700000000000000")
    assert found(checker, text) == []
    res = checker.run(text)
    [lc] = lss.of(res.model).channels.values()  # type: ignore[union-attr]
    assert [ex.result for ex in lc.exchanges] == ["unconfirmed", "ok", "ok"]


def test_l004_fires_and_l001_is_silent(checker: Checker) -> None:
    text = log("(10.000000) can0 7E5#0400000000000000",
               "(10.010000) can0 7E5#1105000000000000",
               "(12.000000) can0 080#")
    assert found(checker, text) == [("L004", 5, 10.01, 1, 2)]
    assert messages(checker, text, "L004") == [
        'configure node-ID sent after switch state global "waiting" at 0.000000 s (line 1) '
        "with no switch to configuration since: no slave can act on it"]


def test_l004_silent_at_the_trace_start(checker: Checker) -> None:
    text = log("(10.000000) can0 7E5#5E00000000000000",
               "(10.001000) can0 7E4#5E05000000000000")
    assert found(checker, text) == []


def test_l004_silent_after_a_switch_to_configuration(checker: Checker) -> None:
    text = log("(10.000000) can0 7E5#0400000000000000",
               "(10.010000) can0 7E5#0401000000000000",
               "(10.020000) can0 7E5#1105000000000000",
               "(10.021000) can0 7E4#1100000000000000")
    assert found(checker, text) == []


def test_l005_two_vendor_ids(checker: Checker) -> None:
    text = log("(10.000000) can0 7E5#0401000000000000",
               "(10.010000) can0 7E5#5A00000000000000",
               "(10.010200) can0 7E4#5A00030000000000",
               "(10.010400) can0 7E4#5A19000000000000")
    assert found(checker, text) == [("L005", None, 10.0104, 3, 4)]
    [m] = messages(checker, text, "L005")
    assert "(vendor-IDs 00000300h and 00000019h)" in m


def test_l005_two_answers_to_configure_node_id_and_l003(checker: Checker) -> None:
    text = log("(10.000000) can0 7E5#0401000000000000",
               "(10.010000) can0 7E5#1105000000000000",
               "(10.010200) can0 7E4#1100000000000000",
               "(10.010400) can0 7E4#1101000000000000")
    assert found(checker, text) == [("L003", 5, 10.0104, 3, 4), ("L005", 5, 10.0104, 3, 4)]
    [m] = messages(checker, text, "L005")
    assert m.endswith("; each that answered 0 took node-ID 5")


def test_l005_silent_on_one_answer_per_request(checker: Checker) -> None:
    text = log("(10.000000) can0 7E5#0401000000000000",
               "(10.010000) can0 7E5#5A00000000000000",
               "(10.010200) can0 7E4#5A00030000000000",
               "(10.020000) can0 7E5#5A00000000000000",
               "(10.020200) can0 7E4#5A00030000000000")
    assert found(checker, text) == []


L006_A = ["(10.000000) can0 7E5#0401000000000000",
          "(10.001000) can0 7E5#5E00000000000000",
          "(10.002000) can0 7E4#5EFF000000000000",
          "(10.003000) can0 7E5#1107000000000000",
          "(10.004000) can0 7E4#1100000000000000",
          "(10.005000) can0 7E5#0400000000000000"]


def test_l006_non_configured_slave_switched_to_waiting(checker: Checker) -> None:
    text = log(*L006_A, "(16.000000) can0 080#")
    assert found(checker, text) == [("L006", 7, 15.005, 6, 7)]
    [m] = messages(checker, text, "L006")
    assert m.startswith("no boot-up of node 7 within 5000 ms after switch to waiting "
                        "(line 6); LSS configured node-ID 7 at 0.003000 s; a non-configured")


def test_l006_silent_with_the_bootup(checker: Checker) -> None:
    text = log(*L006_A, "(10.050000) can0 707#00", "(16.000000) can0 080#")
    res = checker.run(text)
    assert [f for f in res.findings if f.rule[0] == "L"] == []
    [row] = json.loads(json_report.render([res], {}))["lss"]
    [slave] = row["slaves"]
    assert slave["pending_node_id"] == 7 and slave["unconfigured"] is True
    assert slave["bootup"] == {"node": 7, "time": 10.05, "line": 7}
    assert slave["active_node_id"] == 255 and slave["identity"] is None


L006_B = ["(10.000000) can0 7E5#0401000000000000",
          "(10.001000) can0 7E5#5E00000000000000",
          "(10.002000) can0 7E4#5E03000000000000",
          "(10.003000) can0 7E5#1108000000000000",
          "(10.004000) can0 7E4#1100000000000000",
          "(10.005000) can0 7E5#0400000000000000",
          "(10.100000) can0 000#8200",
          "(16.000000) can0 080#"]


def test_l006_configured_slave_after_a_broadcast_reset(checker: Checker) -> None:
    assert found(checker, log(*L006_B)) == [("L006", 8, 15.1, 7, 8)]
    [m] = messages(checker, log(*L006_B), "L006")
    assert "after NMT reset communication (broadcast) (line 7)" in m


def test_l006_silent_without_a_trigger_and_the_node_id_pending(checker: Checker) -> None:
    text = log(*L006_B[:6], *L006_B[7:])
    res = checker.run(text)
    assert [f for f in res.findings if f.rule[0] == "L"] == []
    report = text_report.render([res], {})
    assert "pending node-ID 8" in report


def test_l006_not_evaluated_without_timestamps(checker: Checker) -> None:
    res = checker.run("".join(line.split(" ", 1)[1] + "\n" for line in L006_A)
                      + "can0 080#\n")
    assert not [f for f in res.findings if f.rule == "L006"]
    assert res.not_evaluated["L006"].startswith("no timestamps")


FASTSCAN = ["(10.000000) can0 7E5#5100000000800000",
            "(10.001000) can0 7E4#4F00000000000000",
            "(10.002000) can0 7E5#5100030000000001",
            "(10.003000) can0 7E4#4F00000000000000",
            "(10.004000) can0 7E5#5144460000000102",
            "(10.005000) can0 7E4#4F00000000000000",
            "(10.006000) can0 7E5#5100000000000203",
            "(10.007000) can0 7E4#4F00000000000000",
            "(10.008000) can0 7E5#5101000000000300",
            "(10.009000) can0 7E4#4F00000000000000"]


def test_l007_complete(checker: Checker) -> None:
    text = log(*FASTSCAN)
    assert found(checker, text) == [("L007", None, 10.009, 9, 10)]
    assert messages(checker, text, "L007") == [
        "fastscan found 00000300h:00004644h:00000000h:00000001h (5 requests)"]


def test_l007_abandoned(checker: Checker) -> None:
    text = log(*FASTSCAN[:4], "(12.000000) can0 080#")
    assert found(checker, text) == [("L007", None, 10.003, 3, 4)]
    assert messages(checker, text, "L007") == [
        "fastscan abandoned after vendor-ID = 00000300h (2 requests)"]


def test_l007_silent_on_l002s_vectors(checker: Checker) -> None:
    text = log(*SELECTIVE, "(12.000000) can0 7E5#0400000000000000")
    assert [f for f in found(checker, text) if f[0] == "L007"] == []


def test_the_lss_report_of_a_fastscan(checker: Checker) -> None:
    """§9.4.1: the fastscan's identity becomes a slave record and opens a session."""
    res = checker.run(log(*FASTSCAN))
    [row] = json.loads(json_report.render([res], {}))["lss"]
    assert row["requests"] == 5 and row["unsolicited"] == 0
    [fs] = row["fastscans"]
    assert fs["result"] == "complete" and fs["requests"] == 5
    assert fs["identity"] == {"vendor_id": "0x00000300", "product_code": "0x00004644",
                              "revision_number": "0x00000000", "serial_number": "0x00000001"}
    [slave] = row["slaves"]
    assert slave["identity_source"] == "fastscan" and slave["unconfigured"] is None
    [session] = row["sessions"]
    assert session["identity"] == fs["identity"] and session["exchanges"] == [4]
    assert row["exchanges"][0]["service"] == "fastscan"
    assert row["exchanges"][0]["result"] == "ok"


def test_the_python_api_has_one_row_per_lss_request(tmp_path: Path) -> None:
    import nmtcheck

    path = tmp_path / "lss.log"
    path.write_text(log(*L006_A, "(10.050000) can0 707#00", "(16.000000) can0 080#"))
    report = nmtcheck.check([path])
    assert list(report.lss["service"]) == [
        "switch-state-global", "inquire-node-id", "configure-node-id", "switch-state-global"]
    assert list(report.lss["result"]) == ["unconfirmed", "ok", "ok", "unconfirmed"]
    assert report.lss["lss_session"].tolist() == [0, 0, 0, pd.NA]
    assert report.lss["responses"][1][0]["text"] == "non-configured"


def test_lss_bit_timing_explains_l001(checker: Checker) -> None:
    """§9.3.4 `lss_bit_timing`: the slave switched to 125 kbit/s and no longer answers."""
    text = log("(10.000000) can0 7E5#0401000000000000",
               "(10.010000) can0 7E5#1300040000000000",
               "(10.011000) can0 7E4#1300000000000000",
               "(10.020000) can0 7E5#1564000000000000",
               "(10.200000) can0 7E5#5E00000000000000",
               "(12.000000) can0 7E5#0400000000000000")
    res = checker.run(text)
    [f] = [f for f in res.findings if f.rule == "L001"]
    assert (round(f.time, 6), f.line) == (11.2, 6)
    [c] = f.causes or []
    assert (c["kind"], c["link"], c["time"], c["line"]) == (
        "lss_bit_timing", "lss_bit_timing", 10.02, 4)
    assert "switch delay 100 ms" in c["text"]
    assert "[lss bit timing]" in text_report.render([res], {})


def test_lss_bit_timing_explains_a_heartbeat_timeout(checker: Checker) -> None:
    """Node 3's heartbeat stops right after the activate-bit-timing request; the same
    silence without it has no such cause."""
    beats = [f"({10 + k * 0.1:.6f}) can0 703#05" for k in range(10)]
    lss_lines = ["(10.950000) can0 7E5#0401000000000000",
                 "(10.960000) can0 7E5#1564000000000000",
                 "(10.970000) can0 7E5#0400000000000000"]
    text = log(*beats, *lss_lines, "(13.000000) can0 703#05")
    [h] = [f for f in checker.run(text).findings if f.rule == "H001"]
    linked = [c["kind"] for c in h.causes or () if c["link"] == "lss_bit_timing"]
    assert linked == ["lss_bit_timing"]
    quiet = log(*beats, "(13.000000) can0 703#05")
    [h] = [f for f in checker.run(quiet).findings if f.rule == "H001"]
    assert not [c for c in h.causes or () if c["kind"] == "lss_bit_timing"]


def test_the_html_report_has_an_lss_table(checker: Checker) -> None:
    """§9.4.2: slaves with identity and node-IDs, where an adopted node-ID came from, the
    exchanges folded per session; no LSS section on a log without LSS frames."""
    from nmtcheck.reporters import html as html_report

    res = checker.run(log(*L006_A, "(10.050000) can0 707#00", "(16.000000) can0 080#"))
    page = html_report.render([res], {})
    section = page[page.index('<section id="lss">'):]
    section = section[:section.index("</section>")]
    assert "boot-up of node 7 at 0.050000 s (line 7)" in section
    assert "non-configured" in section and "configure-node-id 7" in section
    quiet = checker.run(log("(10.000000) can0 701#05", "(10.100000) can0 701#05"))
    assert '<section id="lss">' not in html_report.render([quiet], {})


def test_without_timestamps_only_the_next_request_ends_the_wait(checker: Checker) -> None:
    """§9.1.9: L001 and L002 run in part on a log without timestamps (the next 7E5h frame
    ends the wait; the timeout is not judged), and say so."""
    def timeless(*lines: str) -> str:
        return "".join(line.split(" ", 1)[1] + "\n" for line in lines)

    res = checker.run(timeless(*L001.splitlines()))
    assert [(f.rule, f.node, f.frame_index) for f in res.findings if f.rule[0] == "L"] == [
        ("L001", 5, 2)]
    assert res.partly_evaluated["L001"].startswith("no timestamps")
    [m] = [f.message for f in res.findings if f.rule == "L001"]
    assert m == ("no answer to configure node-ID (11h) sent at frame 2 (line 2); the next "
                 "request followed at frame 3 (line 3)")
    res = checker.run(timeless(*SELECTIVE))  # the trace ends: no next request, no finding
    assert [f for f in res.findings if f.rule[0] == "L"] == []
    assert "L002" in res.partly_evaluated


def test_a_flood_of_lss_requests_is_cut_and_said(checker: Checker,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """Memory stays bounded: past MAX_REQUESTS requests a channel's LSS frames are not
    reconstructed; the report counts them and the L rules say they are partly judged."""
    monkeypatch.setattr(lss, "MAX_REQUESTS", 3)
    text = log(*(f"(10.{k:03d}000) can0 7E5#5E00000000000000" for k in range(0, 10, 2)))
    res = checker.run(text)
    [row] = json.loads(json_report.render([res], {}))["lss"]
    assert (row["requests"], row["frames_not_reconstructed"],
            row["not_reconstructed_from_line"]) == (3, 2, 4)
    assert "L003" in res.partly_evaluated and "line 4" in res.partly_evaluated["L003"]


def test_never_fires_where_the_spec_says_so(checker: Checker) -> None:
    """L002 without 40h-42h before the 43h; L001 while the state is unknown; L005 on
    several fastscan answers; a short request's DLC named in L001's message."""
    lone_43 = log("(10.000000) can0 7E5#4301000000000000", "(12.000000) can0 080#")
    assert found(checker, lone_43) == []
    unknown = log("(10.000000) can0 7E5#5E00000000000000", "(12.000000) can0 080#")
    assert found(checker, unknown) == []
    two_4f = log("(10.000000) can0 7E5#5100000000800000",
                 "(10.001000) can0 7E4#4F00000000000000",
                 "(10.001500) can0 7E4#4F00000000000000",
                 "(10.002000) can0 7E5#0400000000000000")
    assert [f[0] for f in found(checker, two_4f)] == ["L007"]
    short = log("(10.000000) can0 7E5#0401000000000000", "(10.010000) can0 7E5#1105",
                "(12.000000) can0 080#")
    [m] = messages(checker, short, "L001")
    assert m.endswith("; the request has DLC 2: CANopenNode slaves ignore it")


def test_unsolicited_answers_are_counted(checker: Checker) -> None:
    text = log("(10.000000) can0 7E4#5E05000000000000",
               "(10.001000) can0 7E5#0401000000000000",
               "(10.002000) can0 7E4#1100000000000000")
    [row] = json.loads(json_report.render([checker.run(text)], {}))["lss"]
    assert row["unsolicited"] == 2 and row["requests"] == 1


def test_the_timeline_shows_the_lss_exchanges(tmp_path: Path) -> None:
    """§9.4.2: `nmtcheck timeline` lists the LSS exchanges and fastscans as channel
    events."""
    from nmtcheck.cli.timeline import render_timeline
    from nmtcheck.engine import check_input, select_rules
    from nmtcheck.settings.profiles import load_profile

    path = tmp_path / "lss.log"
    path.write_text(log(*FASTSCAN, "(10.010000) can0 7E5#1107000000000000",
                        "(10.011000) can0 7E4#1100000000000000",
                        "(10.012000) can0 7E5#0400000000000000"))
    profile = load_profile("default")
    res = check_input(str(path), 0, profile, select_rules(profile, [], []))
    text = render_timeline(res, "text")
    assert "can0 LSS (CiA 305):" in text
    assert "LSS configure node-ID 7 -> ok (line 11)" in text
    assert "LSS switch state global waiting -> unconfirmed (line 13)" in text
    assert ("0.000000 ..     0.009000  fastscan: found "
            "00000300h:00004644h:00000000h:00000001h (5 requests)") in text


def test_lss_bit_timing_explains_a_sync_timeout(checker: Checker) -> None:
    """§9.3.4: a SYNC gap that began right after an activate-bit-timing request."""
    syncs = [f"(10.{k:02d}0000) can0 080#" for k in range(0, 6)]
    text = log(*syncs, "(10.052000) can0 7E5#0401000000000000",
               "(10.053000) can0 7E5#1500000000000000", "(10.200000) can0 080#")
    [y] = [f for f in checker.run(text, network="[sync]\nperiod_us = 10000\n").findings
           if f.rule == "Y001"]
    assert [(c["kind"], c["link"], c["line"]) for c in y.causes or ()
            if c["kind"] == "lss_bit_timing"] == [("lss_bit_timing", "lss_bit_timing", 8)]


def test_lss_bit_timing_ends_the_chain_of_a_sync_timeout_emcy(checker: Checker) -> None:
    """§9.3.5 depth d + 1: node 5's (OPERATIONAL) EMCY 8100h in the SYNC gap links to Y001
    (`sync_timeout`), and Y001's only cause, the activate-bit-timing request, explains it
    in turn (the last link of §9.3.4's table)."""
    syncs = [f"(10.{k:02d}0000) can0 080#" for k in range(0, 6)]
    text = log(*sorted([*syncs, "(10.001000) can0 705#05", "(10.052000) can0 7E5#0401000000000000",
                        "(10.053000) can0 7E5#1500000000000000",
                        "(10.150000) can0 085#0081100000000000", "(10.200000) can0 080#"]))
    res = checker.run(text, network="[sync]\nperiod_us = 10000\n")
    [chain] = [v for k, v in res.event_causes.items() if k[1] == 5]
    assert [(c["kind"], c["link"], c["depth"], c["line"]) for c in chain] == [
        ("finding", "sync_timeout", 1, 10), ("lss_bit_timing", "lss_bit_timing", 2, 9)]


# SPEC §9.5.2's D001 and D003 (a) vectors (d1.toml, d3.toml) with a switch to
# configuration and an activate-bit-timing request (frames as CANopenNode's LSS master
# sends them, samples/canopennode/lss/) concatenated inside the TPDO gap
D1_NET = "[nodes.3.tpdo.1]\ncob_id = 0x183\ntransmission_type = 254\nevent_timer_ms = 100\n"
D3_NET = "[nodes.3.tpdo.1]\ncob_id = 0x183\ntransmission_type = 2\n"
D1_LOG = ["(10.000000) can0 703#00", "(10.001000) can0 000#0103", "(10.002000) can0 183#0100",
          "(10.102000) can0 183#0200", "(10.202000) can0 183#0300", "(10.500000) can0 183#0400",
          "(10.600000) can0 183#0500"]
D3_LOG = ["(10.000000) can0 703#00", "(10.001000) can0 000#0103", "(10.010000) can0 080#",
          "(10.010500) can0 183#01", "(10.020000) can0 080#", "(10.030000) can0 080#",
          "(10.030500) can0 183#02", "(10.040000) can0 080#", "(10.050000) can0 080#",
          "(10.060000) can0 080#", "(10.070000) can0 080#", "(10.070500) can0 183#03"]
SWITCH_LINES = ["(10.031000) can0 7E5#0401000000000000", "(10.031500) can0 7E5#1564000000000000"]


def _bit_timing_causes(checker: Checker, lines: list[str], network: str, rule: str
                       ) -> list[tuple[str | None, float, int | None]]:
    [f] = [f for f in checker.run(log(*sorted(lines)), network=network).findings
           if f.rule == rule]
    assert f.causes is not None  # D001 and D003 carry causes (§9.3.5 roots)
    return [(c["link"], c["time"], c["line"]) for c in f.causes
            if c["kind"] == "lss_bit_timing"]


def test_lss_bit_timing_explains_a_late_event_driven_tpdo(checker: Checker) -> None:
    """§9.3.4 `lss_bit_timing` "as bus_silence": D001's t_e is t_l + E = 10.302; the
    request at 10.210 lies in [t_e - causes_before_ms, t_e]. Without it: no such cause."""
    lss_lines = ["(10.205000) can0 7E5#0401000000000000", "(10.210000) can0 7E5#1564000000000000"]
    assert _bit_timing_causes(checker, D1_LOG + lss_lines, D1_NET, "D001") == [
        ("lss_bit_timing", 10.21, 7)]
    assert _bit_timing_causes(checker, D1_LOG, D1_NET, "D001") == []
    late = ["(10.400000) can0 7E5#0401000000000000", "(10.401000) can0 7E5#1564000000000000"]
    [d] = [f for f in checker.run(log(*sorted(D1_LOG + late)), network=D1_NET).findings
           if f.rule == "D001"]
    assert not [c for c in d.causes or () if c["kind"] == "lss_bit_timing"]
    assert [r["role"] for r in d.reactions or () if r["kind"] == "lss_bit_timing"] == []


def test_bus_silence_explains_a_late_event_driven_tpdo(checker: Checker) -> None:
    """D001's other links (§9.3.4 `bus_silence`): node 4's heartbeats (50 ms) and node 3's
    TPDOs stop together at 10.202 and come back at 10.500: a silence of the whole bus that
    began at t_l. With node 4's heartbeats going on through the gap: no silence."""
    beats = [f"({10 + 0.05 * k:.6f}) can0 704#05" for k in range(5)] + [
        "(10.500000) can0 704#05", "(10.550000) can0 704#05"]
    [d] = [f for f in checker.run(log(*sorted(D1_LOG + beats)), network=D1_NET).findings
           if f.rule == "D001"]
    assert [(c["kind"], c["link"], c["time"], c["end"]) for c in d.causes or ()] == [
        ("silence", "bus_silence", 10.202, 10.5)]
    steady = [f"({10 + 0.05 * k:.6f}) can0 704#05" for k in range(12)]
    [d] = [f for f in checker.run(log(*sorted(D1_LOG + steady)), network=D1_NET).findings
           if f.rule == "D001"]
    assert d.causes == []


def test_lss_bit_timing_explains_a_missing_synchronous_tpdo(checker: Checker) -> None:
    """D003 (a): t_e is the due SYNC (10.050), the request at 10.0315 comes before it."""
    assert _bit_timing_causes(checker, D3_LOG + SWITCH_LINES, D3_NET, "D003") == [
        ("lss_bit_timing", 10.0315, 9)]
    assert _bit_timing_causes(checker, D3_LOG, D3_NET, "D003") == []


def test_lss_bit_timing_does_not_explain_an_extra_synchronous_tpdo(checker: Checker) -> None:
    """D003 (c), two TPDOs between the same SYNCs: a frame that came is no silence, only
    `frames_lost` links to it (§9.3.4)."""
    extra = ["(10.000000) can0 703#00", "(10.001000) can0 000#0103", "(10.010000) can0 080#",
             "(10.010500) can0 183#01", "(10.020000) can0 080#", "(10.020500) can0 183#02",
             "(10.021000) can0 183#03", "(10.030000) can0 080#", "(10.030500) can0 183#04",
             "(10.015000) can0 7E5#0401000000000000", "(10.016000) can0 7E5#1564000000000000"]
    net = D3_NET.replace("= 2", "= 1")
    assert _bit_timing_causes(checker, extra, net, "D003") == []


def test_a_switch_without_its_mode_byte_changes_no_state(checker: Checker) -> None:
    """`7E5#04` (DLC 1) asks for no known state: the configure request after it is judged
    as at the trace start (state unknown), not as after "switch to waiting"."""
    text = log("(10.000000) can0 7E5#04", "(10.010000) can0 7E5#1105000000000000",
               "(12.000000) can0 080#")
    assert found(checker, text) == []


def test_a_lely_like_timeout_and_bootup_wait_from_the_profile(checker: Checker,
                                                              tmp_path: Path) -> None:
    """`[timeline] lss_response_timeout_ms` (Lely's masters wait 100 ms) and `[rules.L006]
    bootup_timeout_ms` move L001's and L006's moments."""
    short = tmp_path / "short.toml"
    short.write_text("[timeline]\nlss_response_timeout_ms = 100\n"
                     "[rules.L006]\nbootup_timeout_ms = 1000\n")
    res = checker.run(L001, profile=str(short))
    assert [(f.rule, round(f.time, 6)) for f in res.findings if f.rule[0] == "L"] == [
        ("L001", 10.11)]
    res = checker.run(log(*L006_A, "(16.000000) can0 080#"), profile=str(short))
    assert [(f.rule, round(f.time, 6)) for f in res.findings if f.rule[0] == "L"] == [
        ("L006", 11.005)]
