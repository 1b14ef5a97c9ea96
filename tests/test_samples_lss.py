"""CANopenNode v4 recordings of LSS (CiA 305) (samples/canopennode/lss/, README there):
CANopenNode's LSS master configuring, scanning and failing to reach CANopenNode LSS
slaves, and nmtcheck's exact findings on each log (no network file).

The ground truth is the stack's own word: lss_dev.c prints to the `.events` file beside
each log every LSS master call with CANopenNode's return code (and the node-ID, vendor-ID
or identity it returned), each slave's communication reset with the node-ID it starts
with, and what its store callback stored. Each test first checks that the log holds what
the stack says it did, then nmtcheck's verdict, each finding derived from SPEC_COMM
§9.2.4 and the log's frames.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import stack_recording as recording
from conftest import SAMPLES
from stack_recording import Frame

from nmtcheck.processes import lss
from nmtcheck.reporters import json as json_report
from nmtcheck.results import InputResult

FOLDER = SAMPLES / "canopennode" / "lss"
TIMEOUT_S = 1.0  # [timeline] lss_response_timeout_ms by default


def _log(name: str) -> Path:
    return FOLDER / f"{name}.log"


def _frames(name: str) -> list[Frame]:
    return recording.frames(_log(name))


def _said(name: str, device: str) -> list[str]:
    """What one device printed, in order (its LSS calls and their return codes)."""
    return [e.text for e in recording.events(_log(name)) if e.device == device]


def _master_calls(name: str) -> list[str]:
    return [t.removeprefix("master: ") for t in _said(name, "master")
            if t.startswith("master: ") and "changeTimeout" not in t]


def _resets(name: str, device: str) -> list[str]:
    return [t for t in _said(name, device) if t.startswith("communication reset")]


def _check(name: str) -> InputResult:
    return recording.check(_log(name), None)


def _found(name: str) -> recording.Found:
    return recording.found(_check(name))


def _lss(name: str) -> dict[str, Any]:
    [row] = json.loads(json_report.render([_check(name)], {}))["lss"]
    return dict(row)


def _first(frames: list[Frame], can_id: int, data: str) -> Frame:
    return next(f for f in frames if f.can_id == can_id and f.data.startswith(data))


def test_configure_node_id_by_selective_switch_and_store_is_silent() -> None:
    """The master selects slave 300h:4644h:0:1, inquires its node-ID (FFh: non-configured),
    configures node-ID 5, stores it and switches to waiting; the slave resets its
    communication by itself and boots as node 5. No finding of any group."""
    name = "lss_configure_store"
    assert _master_calls(name) == [
        "select 300:4644:0:1 -> OK", "inquire_node -> OK, value 000000FF", "node 5 -> OK",
        "store -> OK", "deselect -> OK"]
    assert "LSS store callback: node-ID 5, bit rate 0 stored" in _said(name, "sA")
    assert _resets(name, "sA") == ["communication reset: node-ID 255 (non-configured)",
                                   "communication reset: node-ID 5"]
    frames = _frames(name)
    assert [f.data for f in frames if f.can_id == 0x705][:1] == ["00"]
    assert _found(name) == []
    [slave] = _lss(name)["slaves"]
    assert slave["identity_source"] == "selective" and slave["unconfigured"] is True
    assert slave["pending_node_id"] == 5 and slave["stored"] is True
    boot = _first(frames, 0x705, "00")
    assert slave["bootup"] == {"node": 5, "time": round(boot.t + recording.t0(_log(name)), 6),
                               "line": boot.line}


def test_fastscan_of_one_non_configured_slave() -> None:
    """A fastscan finds 300h:4644h:0:1 (the identity the master returned); node-ID 6 is
    configured, stored and adopted: only L007 (info) at the fastscan's last frame."""
    name = "lss_fastscan_one"
    calls = _master_calls(name)
    assert calls[0] == "fastscan -> SCAN_FINISHED, found 00000300:00004644:00000000:00000001"
    assert calls[1:] == ["node 6 -> OK", "store -> OK", "deselect -> OK"]
    assert _resets(name, "sA")[-1] == "communication reset: node-ID 6"
    frames = _frames(name)
    configure = _first(frames, 0x7E5, "1106")
    last = [f for f in frames if f.line < configure.line][-1]  # the fastscan's last answer
    assert (last.can_id, last.data) == (0x7E4, "4F00000000000000")
    assert _found(name) == [("L007", None, last.t)]
    [fs] = _lss(name)["fastscans"]
    assert fs["result"] == "complete"
    assert fs["identity"]["serial_number"] == "0x00000001"
    assert "found 00000300h:00004644h:00000000h:00000001h" in _check(name).findings[0].message


def test_fastscan_of_two_non_configured_slaves() -> None:
    """Two fastscans find 300h:4644h:0:1 and then 300h:4644h:0:2, each configured (6, 7),
    stored and adopted; a third finds nobody. Three L007 (info), nothing else."""
    name = "lss_fastscan_two"
    calls = _master_calls(name)
    assert calls == [
        "fastscan -> SCAN_FINISHED, found 00000300:00004644:00000000:00000001", "node 6 -> OK",
        "store -> OK", "deselect -> OK",
        "fastscan -> SCAN_FINISHED, found 00000300:00004644:00000000:00000002", "node 7 -> OK",
        "store -> OK", "deselect -> OK", "fastscan -> SCAN_NOACK"]
    assert _resets(name, "sA")[-1] == "communication reset: node-ID 6"
    assert _resets(name, "sB")[-1] == "communication reset: node-ID 7"
    frames = _frames(name)
    ends = [[f for f in frames if f.line < _first(frames, 0x7E5, cs).line][-1]
            for cs in ("1106", "1107")]
    resets = [f for f in frames if f.can_id == 0x7E5 and f.data == "5100000000800000"]
    assert len(resets) == 3
    assert _found(name) == [("L007", None, ends[0].t), ("L007", None, ends[1].t),
                            ("L007", None, resets[2].t)]
    messages = [f.message for f in _check(name).findings]
    assert messages[1].startswith("fastscan found 00000300h:00004644h:00000000h:00000002h")
    assert messages[2] == "fastscan: no non-configured slave answered the reset"
    slaves = _lss(name)["slaves"]
    assert [(s["pending_node_id"], s["bootup"]["node"]) for s in slaves] == [
        (6, 6), (7, 7)]


def test_fastscan_that_finds_nobody() -> None:
    """The only slave is configured (node 3): CANopenNode answers fastscan only while
    non-configured, so the reset goes unanswered (SCAN_NOACK). L007 at the reset."""
    name = "lss_fastscan_nobody"
    assert _master_calls(name) == ["fastscan -> SCAN_NOACK"]
    [reset] = [f for f in _frames(name) if f.can_id == 0x7E5]
    assert not [f for f in _frames(name) if f.can_id == 0x7E4]
    assert _found(name) == [("L007", None, reset.t)]


def test_selective_switch_to_an_identity_nobody_has() -> None:
    """300h:4644h:0:9 is on no slave: the master times out (TIMEOUT); L002 at the 43h +
    1000 ms (the next request comes 1.5 s later)."""
    name = "lss_selective_nobody"
    assert _master_calls(name) == ["select 300:4644:0:9 -> TIMEOUT", "deselect -> OK"]
    serial = _first(_frames(name), 0x7E5, "43")
    assert _found(name) == [("L002", None, round(serial.t + TIMEOUT_S, 6))]
    [f] = _check(name).findings
    assert f.message == ("no slave answered selective switch "
                         "00000300h:00004644h:00000000h:00000009h")


def test_store_answered_with_an_error() -> None:
    """A slave without a store callback answers "store configuration" with 1 (not
    supported): the master gets OK_ILLEGAL_ARGUMENT. L003 at the answer; the node-ID
    itself is adopted (the slave boots as node 5), so nothing else."""
    name = "lss_store_error"
    assert _master_calls(name) == ["select 300:4644:0:1 -> OK", "node 5 -> OK",
                                   "store -> OK_ILLEGAL_ARGUMENT", "deselect -> OK"]
    assert _resets(name, "sA")[-1] == "communication reset: node-ID 5"
    answer = _first(_frames(name), 0x7E4, "1701")
    assert _found(name) == [("L003", None, answer.t)]
    slave = _lss(name)["slaves"][0]
    assert slave["stored"] is False and slave["bootup"]["node"] == 5


def test_two_slaves_in_configuration_answer_one_inquiry() -> None:
    """Switch state global configuration puts both non-configured slaves in configuration
    state; both answer the vendor-ID inquiry (300h and 19h). CANopenNode's master takes
    the first answer (OK, 300h) and sees no fault; L005 at the second answer."""
    name = "lss_two_in_configuration"
    assert _master_calls(name) == ["select_all -> OK", "inquire_vendor -> OK, value 00000300",
                                   "deselect -> OK"]
    answers = [f for f in _frames(name) if f.can_id == 0x7E4]
    assert sorted(f.data for f in answers) == ["5A00030000000000", "5A19000000000000"]
    assert _found(name) == [("L005", None, answers[1].t)]
    assert "vendor-IDs" in _check(name).findings[0].message


def test_configure_bit_timing_on_a_slave_without_bit_rate_support() -> None:
    """A CANopenNode slave without a bit-rate callback drops "configure bit timing": the
    master times out; L001 at the request + 1000 ms, naming CANopenNode's silence."""
    name = "lss_bitrate_silent"
    assert _master_calls(name) == ["select 300:4644:0:1 -> OK", "bitrate 125 -> TIMEOUT",
                                   "deselect -> OK"]
    request = _first(_frames(name), 0x7E5, "1300")
    assert _found(name) == [("L001", None, round(request.t + TIMEOUT_S, 6))]
    assert _check(name).findings[0].message.endswith(
        "; CANopenNode slaves without bit-rate support stay silent")


def test_node_id_lost_in_a_power_cycle_is_not_adopted() -> None:
    """Configured slave 3 (5Eh answered 3) gets node-ID 8, not stored; it is powered off
    and on before any reset (it boots as 3 again: `communication reset: node-ID 3`), and
    the master's broadcast reset communication brings it up as node 3, not 8: L006 at
    the reset + 5000 ms. Node 3's second power-on boot-up, 1.1 s after its first with its
    heartbeat 7Fh between, is a reboot no reset explains: B002 (a warning), not B003
    (boot-ups in a row, an error: it did not keep sending 00h)."""
    name = "lss_not_adopted"
    assert _master_calls(name) == [
        "select 300:4644:0:4 -> OK", "inquire_node -> OK, value 00000003", "node 8 -> OK",
        "deselect -> OK", "CO_NMT_sendCommand(82h, node 0)"]
    assert _resets(name, "sC") == ["communication reset: node-ID 3"] * 3
    # the stack: C reached PRE-OPERATIONAL (127), was powered off, and booted again
    assert [s for _t, s in recording.states(_log(name), "sC")] == ["0", "127"] * 3
    hub = [line.split(maxsplit=3)[3] for line in
           _log(name).with_suffix(".events").read_text().splitlines()
           if line.startswith("# hub t=")]
    assert hub[2:4] == ["power off sC", hub[0]], hub  # the same device, spawned again
    frames = _frames(name)
    reset = _first(frames, 0x000, "8200")
    assert not [f for f in frames if f.can_id == 0x708]
    assert [f.data for f in frames if f.can_id == 0x703 and f.t < reset.t] == ["00", "7F", "00"]
    found = _found(name)
    power_on = [f for f in frames if f.can_id == 0x703 and f.data == "00"][1]
    assert found == [("B002", 3, power_on.t), ("L006", 8, round(reset.t + 5.0, 6))]
    res = _check(name)
    analysis = lss.of(res.model)
    assert analysis is not None
    [lc] = analysis.channels.values()
    [c] = lc.slaves[0].configured
    assert c.trigger is not None and c.trigger[3] == "NMT reset communication (broadcast)"


def test_every_recording_is_checked_here() -> None:
    names = {p.stem for p in FOLDER.glob("*.log")}
    assert names == {
        "lss_configure_store", "lss_fastscan_one", "lss_fastscan_two", "lss_fastscan_nobody",
        "lss_selective_nobody", "lss_store_error", "lss_two_in_configuration",
        "lss_bitrate_silent", "lss_not_adopted"}


LELY = SAMPLES / "lely" / "lss"


def _lely_calls(name: str) -> list[str]:
    return [e.text.removeprefix("master: ") for e in recording.events(LELY / f"{name}.log")
            if e.device == "master" and e.text.startswith("master: ")]


def test_lely_selective_switch_to_an_identity_nobody_has() -> None:
    """Lely's LSS master (src/co/lss.c) gives up after its 100 ms and sends "switch to
    waiting" at once: L002 at that next request, not at the 43h + 1000 ms."""
    name = "lely_selective_nobody"
    calls = _lely_calls(name)
    assert calls[1:3] == ["select 300:4644:0:9 -> cs 00h (timeout)",
                          "waiting -> 0 (unconfirmed)"]
    frames = recording.frames(LELY / f"{name}.log")
    serial = _first(frames, 0x7E5, "43")
    waiting = _first(frames, 0x7E5, "0400")
    assert 0.09 < waiting.t - serial.t < 0.2  # Lely's 100 ms LSS timeout
    res = recording.check(LELY / f"{name}.log", None)
    assert recording.found(res) == [("L002", None, waiting.t)]
    assert res.findings[0].frame_index == waiting.line - 1


def test_lely_fastscan_finds_a_canopennode_slave() -> None:
    """Lely's fastscan (100 ms per request) finds CANopenNode slave A; node-ID 5, store,
    switch to waiting; A boots as node 5 (after Lely's `000#8200` too): only L007."""
    name = "lely_fastscan"
    calls = _lely_calls(name)
    assert calls[1:5] == ["fastscan -> cs 4Fh found 00000300:00004644:00000000:00000001",
                          "node 5 -> cs 11h error 0 spec 0", "store -> cs 17h error 0 spec 0",
                          "waiting -> 0 (unconfirmed)"]
    frames = recording.frames(LELY / f"{name}.log")
    configure = _first(frames, 0x7E5, "1105")
    last = [f for f in frames if f.line < configure.line][-1]
    res = recording.check(LELY / f"{name}.log", None)
    assert recording.found(res) == [("L007", None, last.t)]
    assert [f.data for f in frames if f.can_id == 0x705][:1] == ["00"]


def test_lely_fastscan_finds_a_configured_lely_slave() -> None:
    """A Lely LSS slave answers fastscan whatever its node-ID (src/co/lss.c 1555-1559):
    the configured node 3 (identity 300h:4644h:0:4) is found, which CANopenNode slaves
    never allow (lss_fastscan_nobody). L007 with its identity; its node-ID answer is 3."""
    name = "lely_fastscan_configured"
    calls = _lely_calls(name)
    assert calls[1:3] == ["fastscan -> cs 4Fh found 00000300:00004644:00000000:00000004",
                          "inquire_node -> cs 5Eh node-ID 3"]
    res = recording.check(LELY / f"{name}.log", None)
    [f] = res.findings
    assert (f.rule, f.node) == ("L007", None)
    assert f.message.startswith("fastscan found 00000300h:00004644h:00000000h:00000004h")
    analysis = lss.of(res.model)
    assert analysis is not None
    [lc] = analysis.channels.values()
    assert [(s.identity_source, s.active_node_id, s.unconfigured) for s in lc.slaves] == [
        ("fastscan", 3, False)]


def test_lely_configures_after_switching_to_waiting() -> None:
    """Lely's master leaves it to its caller that a slave is in configuration state
    (`co_lss_set_id_req`): asked to, it sends "configure node-ID 5" right after "switch to
    waiting"; the CANopenNode slave, now waiting, ignores it and Lely times out. L004 at
    the request; L001 stays silent (no slave is in configuration state)."""
    name = "lely_configure_after_waiting"
    calls = _lely_calls(name)
    assert calls[1:4] == ["select 300:4644:0:1 -> cs 44h", "waiting -> 0 (unconfirmed)",
                          "node 5 -> cs 00h error 0 spec 0 (timeout)"]
    frames = recording.frames(LELY / f"{name}.log")
    request = _first(frames, 0x7E5, "1105")
    assert not [f for f in frames if f.can_id == 0x7E4 and f.data.startswith("11")]
    assert recording.found(recording.check(LELY / f"{name}.log", None)) == [
        ("L004", 5, request.t)]
