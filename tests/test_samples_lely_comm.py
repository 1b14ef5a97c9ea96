"""Lely recordings where Lely's SYNC/PDO/EMCY behaviour differs from CANopenNode's
(samples/lely/comm/, README there): nmtcheck's findings and chains on each log, with its
network file and without.

The ground truth is not nmtcheck's output: it is the stack's own word and the bus.
record_comm.cpp prints, to the `.events` file beside each log (the log's clock), every NMT
state change of each Lely slave (Lely calls OnCommand after the transition, also for the
ENTER_PREOP its 1029h handling gives itself), every EMCY the slave sends (from the callback
in which Lely raised it: OnRpdoError, OnHeartbeat, OnLifeGuarding, with the code and error
register on top of Lely's error stack), its RPDO errors, the first SYNC and RPDO after a
pause, the master's commands and views, and a status line near the end (state, 1001h, the
top of the error stack, SYNC and RPDO counts). The tests first check that the log holds
what the stack says it did, then nmtcheck's verdict: each expected finding is derived from
SPEC_COMM (§9.1.5, §9.2, §9.3.4) and the log's frames, and commented where it is derived.

Lely differs from CANopenNode here (SPEC_COMM §9.1.5, §9.3.4 `error_behaviour`, §9.8): it
applies 1029h:01 to EMCY codes 81xxh only, so an RPDO timeout (8250h) leaves the consumer
OPERATIONAL; it has no SYNC consumer timeout, so a stopped SYNC producer gives no EMCY and
no state change; a heartbeat or life-guarding timeout (8130h) does move the node; a SYNC of
the wrong length raises 8240h but Lely still hands it to the application.

Three cases where nmtcheck once fell short of SPEC_COMM on these recordings (a guarding
answer as `producer_state`, the `life_guarding` link, a TPDO COB-ID written by SDO) are
ordinary tests now, each with its case in its docstring.
"""

from __future__ import annotations

import configparser
import re
from itertools import pairwise
from pathlib import Path
from typing import Any

import pytest
import stack_recording as recording
from conftest import SAMPLES
from stack_recording import DEVICES, Event, Found, Frame

from nmtcheck.results import Finding, InputResult

FOLDER = SAMPLES / "lely" / "comm"
LOGS = ("rpdo_producer_stopped", "sync_producer_stopped", "master_unplugged", "sync_pdo",
        "sync_length")
EMCY_SENT = re.compile(r"EMCY sent: code (\w{4}) register (\w\w) \((.+)\)")
POWER_ON = re.compile(r"power on \((.+)\)")
NO_MSEF = "00" * 5  # Lely's Error(eec, er) passes no manufacturer-specific field: zeros


def _network(name: str) -> Path:
    return FOLDER / f"network_{name}.toml"


def _log(name: str) -> Path:
    return FOLDER / f"{name}.log"


def _frames(name: str) -> list[Frame]:
    return recording.frames(_log(name))


def _on(name: str, can_id: int) -> list[Frame]:
    return [f for f in _frames(name) if f.can_id == can_id and not f.data.startswith("R")]


def _events(name: str) -> list[Event]:
    return recording.events(_log(name))


def _states(name: str, device: str) -> list[tuple[float, str]]:
    """The device's NMT states as Lely reported them, without the reset sub-states."""
    return [s for s in recording.states(_log(name), device) if not s[1].startswith("RESET")]


def _status(name: str) -> dict[str, str]:
    return recording.status(_log(name))


def _emcys_sent(name: str) -> list[tuple[float, int, str, str]]:
    """(time, node, the 8 data bytes Lely sends, why) of every EMCY the stack says it sent."""
    out = []
    for e in _events(name):
        m = EMCY_SENT.fullmatch(e.text)
        if m:
            code = int(m[1], 16).to_bytes(2, "little").hex().upper()
            out.append((e.t, DEVICES[e.device], code + m[2] + NO_MSEF, m[3]))
    return out


def _ground_truth_emcys_are_on_the_bus(name: str) -> list[Frame]:
    """Every EMCY the stack says it sent is a frame of the log on 80h + N with the same
    bytes, at most 1 ms after the callback's stamp, in the same order; the log holds no
    other EMCY."""
    emcys = [f for f in _frames(name) if 0x81 <= f.can_id <= 0xFF]
    sent = _emcys_sent(name)
    assert len(emcys) == len(sent), (emcys, sent)
    for frame, (t, node, data, _why) in zip(emcys, sent, strict=True):
        assert (frame.can_id, frame.data) == (0x80 + node, data)
        assert 0 <= frame.t - t < 0.001, (frame, t)
    return emcys


def _check(name: str, network: Path | str | None) -> InputResult:
    net = _network(name) if network == "file" else network
    return recording.check(_log(name), Path(net) if net is not None else None)


def _found(res: InputResult) -> Found:
    return recording.found(res)


def _one(res: InputResult, rule: str, node: int | None) -> Finding:
    [f] = [f for f in res.findings if (f.rule, f.node) == (rule, node)]
    return f


def _links(entries: list[dict[str, Any]] | None) -> list[tuple[Any, ...]]:
    return [(c["kind"], c.get("rule"), c["line"], c["link"], c["depth"]) for c in entries or []]


def _emcy_chain(res: InputResult, node: int, line: int) -> list[tuple[Any, ...]]:
    """The chain of the EMCY event of `node` on log line `line` (SPEC_COMM §9.3.5)."""
    [causes] = [v for k, v in res.event_causes.items() if k[1] == node
                and k[2] == line - 1]  # frame index = line - 1 in a candump log
    return _links(causes)


def _with(name: str, tmp_path: Path, old: str, new: str) -> Path:
    """The network file with `old` replaced by `new` (once), in tmp_path, with its device
    file paths made absolute."""
    text = _network(name).read_text()
    assert text.count(old) == 1, old
    text = text.replace(old, new)
    text = re.sub(r'(dcf|eds) = "([^"]+)"',
                  lambda m: f'{m[1]} = "{(FOLDER / m[2]).resolve().as_posix()}"', text)
    out = tmp_path / "network.toml"
    out.write_text(text)
    return out


def test_every_recording_has_its_tests() -> None:
    assert {p.stem for p in FOLDER.glob("*.log")} == set(LOGS)
    assert {p.stem for p in FOLDER.glob("*.events")} == set(LOGS)
    assert {p.name for p in FOLDER.glob("*.toml")} == {f"network_{n}.toml" for n in LOGS}


@pytest.mark.parametrize("name", LOGS)
def test_recorder_logged_every_frame_once(name: str) -> None:
    """The recorder's own check (frames the devices put on the bus = frames logged, every
    device received all the others') passed, and the log is what it counted."""
    last = _log(name).with_suffix(".events").read_text().splitlines()[-1]
    m = re.fullmatch(r"# logged (\d+) frames, sent (\d+) -> OK", last)
    assert m and m[1] == m[2] and int(m[1]) == len(_frames(name))


@pytest.mark.parametrize("name", LOGS)
def test_network_file_names_the_eds_each_slave_ran_with(name: str) -> None:
    """Each slave's `eds` in the network file is the file the recorder powered it on with
    (its `power on (...)` event); the master is ../master.dcf."""
    powered = {DEVICES[e.device]: m[1] for e in _events(name)
               if (m := POWER_ON.fullmatch(e.text))}
    text = _network(name).read_text()
    named = {int(n): path for n, path in
             re.findall(r'\[nodes\.(\d)\]\n(?:#[^\n]*\n)*(?:eds|dcf) = "([^"]+)"', text)}
    # the recorder runs in samples/lely/, the network file's paths are relative to comm/
    assert {n: (FOLDER / p).resolve() for n, p in named.items() if n != 1} == {
        n: (FOLDER.parent / p).resolve() for n, p in powered.items() if n != 1}
    assert named[1] == "../master.dcf"
    assert powered[1] == "master.dcf, master.bin"


def _eds_value(path: Path, section: str) -> str:
    ini = configparser.ConfigParser()
    ini.read(path)
    return ini[section]["DefaultValue"]


# -- rpdo_producer_stopped: Lely's RPDO deadline raises 8250h, the consumer stays up ---------

STOP = "rpdo_producer_stopped"


def test_rpdo_producer_stopped_ground_truth() -> None:
    """Node 2's TPDO1 (182h, sent by the application every 500 ms) is node 3's RPDO1 with a
    750 ms deadline (1400h:05, rpdo_deadline.eds); node 3's 1029h:01 = 0. The master stops
    node 2 at 3.99 s. 750 ms after the last 182h Lely calls node 3's OnRpdoError (8250h,
    register 10h) and sends EMCY 8250h with register 11h (Lely sets bit 0 with every error,
    emcy.c); node 3 stays OPERATIONAL (its heartbeats stay 05h, its TPDO 183h goes on): Lely
    applies 1029h only to 81xxh (nmt.c co_nmt_on_err). The error stays on its stack."""
    assert _eds_value(FOLDER / "rpdo_deadline.eds", "1400sub5") == "750"
    assert _eds_value(FOLDER.parent / "slave.eds", "1029sub1") == "0x00"
    frames = _frames(STOP)
    stop = next(f for f in frames if (f.can_id, f.data) == (0x000, "0202"))
    start = next(f for f in frames if (f.can_id, f.data) == (0x000, "0102") and f.t > stop.t)
    assert (stop.line, stop.t, start.line, start.t) == (267, 3.986644, 367, 5.986659)
    tpdo = _on(STOP, 0x182)
    last = [f for f in tpdo if f.t < stop.t][-1]
    after = [f for f in tpdo if f.t > stop.t]
    assert (last.line, last.t) == (260, 3.856644) and (after[0].line, after[0].t) == (386, 6.356648)
    assert after[0].t > start.t
    [rpdo_error] = [e for e in _events(STOP) if e.text.startswith("RPDO 1 error")]
    assert (rpdo_error.t, rpdo_error.device, rpdo_error.text) == (
        4.60673, "s3", "RPDO 1 error: code 8250 register 10 (Lely OnRpdoError)")
    assert 0.750 < rpdo_error.t - last.t < 0.751
    emcys = _ground_truth_emcys_are_on_the_bus(STOP)
    assert [(f.line, f.t, f.can_id, f.data) for f in emcys] == [
        (302, 4.606794, 0x083, "5082110000000000")]
    # node 3: OPERATIONAL from its start to the end, by its own word and on the bus
    assert _states(STOP, "s3")[-1] == (0.100643, "OPERATIONAL")
    assert {f.data for f in _on(STOP, 0x703) if f.t > 0.3} == {"05"}
    assert len([f for f in _on(STOP, 0x183) if f.t > emcys[0].t]) == 9
    assert _states(STOP, "s2")[-3:] == [(0.100588, "OPERATIONAL"), (3.986702, "STOPPED"),
                                        (5.98676, "OPERATIONAL")]
    assert _status(STOP)["s3"] == ("status: NMT state OPERATIONAL, error register 11, "
                                   "EMCY error stack top 8250, SYNC 0, RPDO 13")


# D004 (§9.2.2): armed at node 3's last 182h (3.856644), E_c = 750 ms (node 3's EDS); node 3
# OPERATIONAL throughout (its heartbeats); the next 182h comes at 6.356648: one finding at
# t_l + E_c. producer_state (§9.3.4): t_e = t_l + the stream's median interval (500 ms; the
# producer's event timer is 0) = 4.356644 holds the stop (3.986644, line 267) and node 2's
# report of STOPPED (702#04, 4.000392, line 269). No S005: node 3 never leaves OPERATIONAL.
# E003 (§9.2.3): Lely never sends the 0000h reset of the 8250h (its error stays on the stack).
STOP_FOUND: Found = [("D004", 3, 4.606644), ("E003", 3, 4.606794)]


def test_rpdo_producer_stopped_with_the_network_file() -> None:
    res = _check(STOP, "file")
    assert _found(res) == STOP_FOUND
    d004, e003 = res.findings
    assert d004.line == 302  # the first frame at or after 4.606644: node 3's EMCY
    assert d004.message == (
        "no RPDO 182h for node 3 for 2500.004 ms; deadline 1400h:05 = 750 ms (device file); "
        "producer node 2; confirmed by EMCY 8250h of node 3 at 4.606794 s (line 302)")
    assert _links(d004.causes) == [("nmt", None, 267, "producer_state", 1),
                                   ("node_state", None, 269, "producer_state", 1)]
    assert [(r["kind"], r["node"], r["line"], r["role"]) for r in d004.reactions or []] == [
        ("emcy", 3, 302, "report")]
    # the EMCY's chain: rpdo_timeout -> D004, whose first cause is the stop of node 2
    assert _emcy_chain(res, 3, 302) == [("finding", "D004", 302, "rpdo_timeout", 1),
                                        ("nmt", None, 267, "producer_state", 2)]
    assert e003.line == 302 and "codes since the last full reset: 8250h" in e003.message
    # no timeline change of node 3 (the stack's word): nothing for a chain to explain
    assert not [k for k in res.interval_causes if k[1] == 3]
    assert "D004" not in res.not_evaluated and "D005" not in res.not_evaluated


def test_rpdo_producer_stopped_without_a_network_file() -> None:
    """No PDO is configured: 182h is node 2's default TPDO1 and nobody's RPDO, so no D004;
    the EMCY 8250h stays unexplained (`pdo_gap` looks at node 3's default RPDO streams,
    which carry no frame). E003 as with the file."""
    res = _check(STOP, None)
    assert _found(res) == [("E003", 3, 4.606794)]
    assert _emcy_chain(res, 3, 302) == []
    assert "D004" in res.not_evaluated


def _without_tpdo_tables(tmp_path: Path) -> Path:
    """The network file of rpdo_producer_stopped without its [nodes.N.tpdo.1] tables: the
    slaves' EDS (TPDO1 invalid at power-on) and the trace's SDO writes only."""
    text = _network(STOP).read_text()
    parts = re.split(r"(?m)^(?=\[)", text)
    kept = "".join(p for p in parts if not re.match(r"\[nodes\.\d\.tpdo\.1\]", p))
    assert kept != text and not re.search(r"(?m)^\[nodes\.\d\.tpdo", kept)
    out = tmp_path / "network.toml"
    out.write_text(re.sub(r'(dcf|eds) = "([^"]+)"',
                          lambda m: f'{m[1]} = "{(FOLDER / m[2]).resolve().as_posix()}"', kept))
    return out


def test_rpdo_producer_stopped_producer_from_the_sdo_written_cob_id(tmp_path: Path) -> None:
    """SPEC_COMM 9.1.1: without the TPDO tables the master's confirmed write of node 2's
    1800h:01 = 182h (line 60) makes node 2 the producer of 182h: D004 names it and has
    the producer_state chain."""
    res = _check(STOP, _without_tpdo_tables(tmp_path))
    d004 = _one(res, "D004", 3)
    assert "producer node 2" in d004.message
    assert _links(d004.causes)[:1] == [("nmt", None, 267, "producer_state", 1)]


# -- sync_producer_stopped: no SYNC consumer timeout in Lely ----------------------------------

SYNC_STOP = "sync_producer_stopped"


def test_sync_producer_stopped_ground_truth() -> None:
    """Node 4 produces SYNC every 50 ms (1005h = 40000080h, 1006h = 50000 µs, no counter);
    nodes 2 and 3 consume it with 1006h = 50000 µs. The master stops node 4 at 3.99 s: the
    SYNC stops (Lely produces it only in PRE-OPERATIONAL and OPERATIONAL) for 2.05 s until
    node 4 is started again. Lely has no SYNC consumer timeout: no EMCY from anyone, nodes 2
    and 3 stay OPERATIONAL; their OnSync sees the next SYNC only after the pause."""
    for eds in ("sync_consumer.eds", "sync_producer.eds"):
        assert _eds_value(FOLDER / eds, "1006") == "50000"
    assert _eds_value(FOLDER / "sync_producer.eds", "1005") == "0x40000080"
    frames = _frames(SYNC_STOP)
    stop = next(f for f in frames if (f.can_id, f.data) == (0x000, "0204"))
    assert (stop.line, stop.t) == (347, 3.986224)
    sync = _on(SYNC_STOP, 0x080)
    assert {f.data for f in sync} == {""}  # DLC 0: 1019h absent
    gaps = [(a, b) for a, b in pairwise(sync) if b.t - a.t > 0.075]
    assert [(a.line, a.t, b.line, b.t) for a, b in gaps] == [(346, 3.97558, 452, 6.02561)]
    assert max(b.t - a.t for a, b in pairwise(sync) if b.t < 3.98) < 0.0501
    assert _emcys_sent(SYNC_STOP) == [] and _ground_truth_emcys_are_on_the_bus(SYNC_STOP) == []
    for dev in ("s2", "s3"):
        assert _states(SYNC_STOP, dev)[-1][1] == "OPERATIONAL"
        assert _states(SYNC_STOP, dev)[-1][0] < 0.2
        [pause] = [e for e in _events(SYNC_STOP)
                   if e.device == dev and e.text == "SYNC received counter 0 after a pause"]
        assert 0 < pause.t - 6.02561 < 0.001
    assert _states(SYNC_STOP, "s4")[-2:] == [(3.986284, "STOPPED"), (5.986339, "OPERATIONAL")]
    assert set(_status(SYNC_STOP).values()) == {
        "status: NMT state OPERATIONAL, error register 00, EMCY error stack top 0000, "
        "SYNC 137, RPDO 0"}
    # what the bus shows: node 4's guarding answer reports STOPPED at 4.002538
    assert [(f.line, f.data) for f in _on(SYNC_STOP, 0x704) if 3.98 < f.t < 4.05] == [
        (352, "04")]


# Y001 (§9.2.1): P = the producer's 1006h, 50 ms (node 4, named by [sync] producer); the
# gap after the SYNC of 3.975580 exceeds T = 75 ms; nodes 2, 3 are OPERATIONAL at t_s + T
# (a stop of the producer does not end the segment, §9.1.5): one finding at 4.050580, node
# 4, basis configured. Nothing else: Lely's consumers did nothing (no EMCY, no S005).
SYNC_STOP_FOUND: Found = [("Y001", 4, 4.05058)]


def test_sync_producer_stopped_with_the_network_file() -> None:
    res = _check(SYNC_STOP, "file")
    assert _found(res) == SYNC_STOP_FOUND
    [y001] = res.findings
    assert (y001.line, y001.basis) == (353, "configured")
    assert y001.message == ("no SYNC for 2050.030 ms after 3.975580 s (line 346); timeout "
                            "75.000 ms = 1.5 x 1006h 50.000 ms (node 4's device file)")
    assert _links(y001.causes)[:1] == [("nmt", None, 347, "producer_state", 1)]
    assert not {"Y001", "Y002", "Y003", "Y005"} & set(res.not_evaluated)


def test_sync_producer_stopped_y001_names_the_producers_guarding_report() -> None:
    """SPEC_COMM 9.3.4 producer_state: node 4 is guarded, and its answer `704#04`
    (line 352) reports STOPPED inside Y001's window: a cause beside the stop itself."""
    y001 = _one(_check(SYNC_STOP, "file"), "Y001", 4)
    assert _links(y001.causes) == [("nmt", None, 347, "producer_state", 1),
                                   ("node_state", None, 352, "producer_state", 1)]


def test_sync_producer_stopped_without_a_network_file() -> None:
    """P measured: the median of the segment's intervals, 50 ms (§9.2.1); the producer is
    unknown (never inferred from frames, §9.1.1): node null, no producer_state link."""
    res = _check(SYNC_STOP, None)
    assert _found(res) == [("Y001", None, 4.05058)]
    [y001] = res.findings
    assert y001.basis == "measured"
    assert ("timeout 75.000 ms = 1.5 x median SYNC interval 50.000 ms [limit measured from "
            "the trace]") in y001.message
    assert not [c for c in y001.causes or [] if c["link"] == "producer_state"]


def test_sync_producer_stopped_two_claimed_producers(tmp_path: Path) -> None:
    """Without `[sync] producer`: dcfgen's master.dcf also has 1005h bit 30 (40000080h) with
    1006h = 0 (Lely then sends no SYNC, sync.c co_sync_update()), so two device files claim
    the SYNC and nmtcheck knows no producer (§9.1.1: "if several do, none"): Y001 takes
    P from a consumer's 1006h (the smallest non-zero one) and names no node; Y005 is not
    evaluated. Why the network files name node 4."""
    res = _check(SYNC_STOP, _with(SYNC_STOP, tmp_path, "producer = 4\n", ""))
    assert _found(res) == [("Y001", None, 4.05058)]
    assert res.findings[0].message.endswith("1.5 x 1006h 50.000 ms (node 2's device file)")
    assert "Y005" in res.not_evaluated


# -- master_unplugged: heartbeat and life-guarding timeouts (8130h) do move Lely's slaves ----

LOST = "master_unplugged"


def test_master_unplugged_ground_truth() -> None:
    """The master is unplugged at 3.99 s for good. Nodes 2 and 3 consume its heartbeat
    (1016h:01 = node 1, 600 ms, written by the master during boot-up); node 4 is guarded
    (100Ch = 100 ms × 100Dh = 3). 600 ms after the master's last heartbeat Lely's heartbeat
    consumers of nodes 2 and 3 time out, 300 ms after the last RTR node 4's life guarding:
    each sends EMCY 8130h (register 11h) and, 1029h:01 = 0, enters PRE-OPERATIONAL (Lely's
    co_nmt_on_err: 81xxh -> co_nmt_comm_err_ind) — the contrast to rpdo_producer_stopped.
    Their TPDOs stop, nodes 2 and 3 send 7Fh; node 4 (no heartbeat, no RTR) says nothing."""
    hb1 = _on(LOST, 0x701)[-1]
    rtr = [f for f in _frames(LOST) if f.can_id == 0x704 and f.data == "R"][-1]
    assert (hb1.line, hb1.t, rtr.line, rtr.t) == (255, 3.798554, 265, 3.901898)
    emcys = _ground_truth_emcys_are_on_the_bus(LOST)
    assert [(f.line, f.t, f.can_id, f.data) for f in emcys] == [
        (273, 4.202018, 0x084, "3081110000000000"),
        (278, 4.398746, 0x082, "3081110000000000"),
        (279, 4.398748, 0x083, "3081110000000000")]
    assert [(node, why) for _t, node, _d, why in _emcys_sent(LOST)] == [
        (4, "life guarding timeout"), (2, "heartbeat consumer timeout"),
        (3, "heartbeat consumer timeout")]
    assert 0.300 < emcys[0].t - rtr.t < 0.301
    assert all(0.600 < f.t - hb1.t < 0.601 for f in emcys[1:])
    assert [_states(LOST, dev)[-1] for dev in ("s2", "s3", "s4")] == [
        (4.398658, "PRE-OPERATIONAL"), (4.398727, "PRE-OPERATIONAL"),
        (4.202001, "PRE-OPERATIONAL")]
    assert [(f.line, f.t, f.data) for f in _frames(LOST)
            if f.can_id in (0x702, 0x703) and 4.3 < f.t < 4.5] == [
        (274, 4.300469, "05"), (275, 4.300471, "05"), (280, 4.4005, "7F"), (281, 4.400501, "7F")]
    assert not [f for f in _frames(LOST) if 0x181 <= f.can_id <= 0x184 and f.t > 4.4]
    assert not [f for f in _frames(LOST) if f.can_id == 0x704 and f.t > 4.0]
    assert {dev: s.split(", ", 1)[0] for dev, s in _status(LOST).items()} == {
        dev: "status: NMT state PRE-OPERATIONAL" for dev in ("s2", "s3", "s4")}
    assert all("error register 11, EMCY error stack top 8130" in s
               for s in _status(LOST).values())


# H001 (§4): node 1's last heartbeat 3.798554 + the consumer time 600 ms (node 2's 1016h,
# written by SDO): 4.398554, "for the rest of the trace". S005 for nodes 2 and 3 at their
# first 7Fh, explained by their EMCY 8130h (error_behaviour (i): 81xxh), whose cause is the
# H001 (heartbeat_consumer: the gap contains t_c). E003 for nodes 2, 3, 4: Lely never resets
# the 8130h. Node 4's drop is not on the bus (no RTR, no heartbeat): no S005.
LOST_FOUND: Found = [("E003", 4, 4.202018), ("H001", 1, 4.398554), ("E003", 2, 4.398746),
                     ("E003", 3, 4.398748), ("S005", 2, 4.4005), ("S005", 3, 4.400501)]


@pytest.mark.parametrize("network", [None, "file"], ids=["bare", "network"])
def test_master_unplugged_findings(network: str | None) -> None:
    """The same with and without the file: the consumer time comes from the trace."""
    res = _check(LOST, network)
    assert _found(res) == LOST_FOUND
    h001 = _one(res, "H001", 1)
    assert h001.message == ("no heartbeat from node 1 for the rest of the trace (consumer "
                            "time 0.600 s of node 2)")
    for node, line, t_c in ((2, 278, "4.398746"), (3, 279, "4.398748")):
        s005 = _one(res, "S005", node)
        assert s005.message.endswith(f"explained by EMCY 8130h at {t_c} s (line {line})")
        assert _links(s005.causes) == [("emcy", None, line, "error_behaviour", 1),
                                       ("finding", "H001", 278, "heartbeat_consumer", 2)]
        assert _emcy_chain(res, node, line) == [
            ("finding", "H001", 278, "heartbeat_consumer", 1)]


def test_master_unplugged_life_guarding_emcy_is_explained() -> None:
    """SPEC_COMM 9.3.4 life_guarding: node 4's EMCY 8130h (4.202018 s, line 273) comes
    300.12 ms after the last RTR to node 4 (3.901898 s, line 265), with 100Ch x 100Dh =
    300 ms known from the SDO writes: its cause is the guarding pause (guarding_gap)."""
    res = _check(LOST, "file")
    assert _emcy_chain(res, 4, 273) == [("guarding_gap", None, 265, "life_guarding", 1)]


# -- sync_pdo: SYNC and a synchronous TPDO/RPDO, healthy --------------------------------------

HEALTHY = "sync_pdo"


def test_sync_pdo_ground_truth() -> None:
    """Node 4 produces SYNC every 50 ms; node 2's TPDO1 is synchronous, every SYNC (type 1,
    sync_tpdo.eds) and node 3's RPDO1 (type 1, sync_rpdo.eds). From the first SYNC after
    node 2 is OPERATIONAL, every SYNC is followed within 0.2 ms by one 182h; node 3's Lely
    processes each at the next SYNC (113 by its status, the 182h frames with a SYNC after
    them before that). No EMCY, nobody leaves OPERATIONAL."""
    assert _eds_value(FOLDER / "sync_tpdo.eds", "1800sub2") == "0x01"
    assert _eds_value(FOLDER / "sync_rpdo.eds", "1400sub2") == "0x01"
    sync = _on(HEALTHY, 0x080)
    tpdo = _on(HEALTHY, 0x182)
    assert (len(sync), len(tpdo)) == (119, 117)
    assert {f.data for f in sync} == {""}
    op2 = _states(HEALTHY, "s2")[-1]
    assert op2 == (0.100595, "OPERATIONAL")
    due = [s for s in sync if s.t > op2[0]]
    assert len(due) == len(tpdo)
    assert all(0 < p.t - s.t < 0.0002 for s, p in zip(due, tpdo, strict=True))
    assert max(b.t - a.t for a, b in pairwise(sync)) < 0.0502
    status = _status(HEALTHY)
    t_status = next(e.t for e in _events(HEALTHY) if e.device == "s3"
                    and e.text.startswith("status: "))
    processed = [p for p in tpdo if any(p.t < s.t < t_status for s in sync)]
    assert status["s3"] == ("status: NMT state OPERATIONAL, error register 00, EMCY error "
                            f"stack top 0000, SYNC 116, RPDO {len(processed)}")
    assert len(processed) == 113
    assert all(s.startswith("status: NMT state OPERATIONAL, error register 00,")
               for s in status.values())
    assert _emcys_sent(HEALTHY) == [] and _ground_truth_emcys_are_on_the_bus(HEALTHY) == []


@pytest.mark.parametrize("network", [None, "file"], ids=["bare", "network"])
def test_sync_pdo_is_silent(network: str | None) -> None:
    """Y001-Y003, Y005, D003, D005 judge the run and stay silent (with the file; Y004 has no
    window to judge, 1007h absent); without the file Y001 (measured) and Y003 still run."""
    res = _check(HEALTHY, network)
    assert _found(res) == []
    judged = {"Y001", "Y002", "Y003", "Y005", "D003", "D005"} if network else {"Y001", "Y003"}
    assert not judged & set(res.not_evaluated)


def test_sync_pdo_y005_judges_these_frames(tmp_path: Path) -> None:
    """The silence is Y005's verdict: with the producer's period given as 40 ms the median
    interval (50.002 ms over 118 intervals) is 25 % off, one finding at the trace end."""
    res = _check(HEALTHY, _with(HEALTHY, tmp_path, "producer = 4\n",
                                "producer = 4\nperiod_us = 40000\n"))
    assert _found(res) == [("Y005", 4, 5.939482)]
    assert res.findings[0].message.startswith(
        "median SYNC interval 50.002 ms over 118 intervals; the producer's 1006h = 40.000 ms")


def test_sync_pdo_d003_judges_these_frames(tmp_path: Path) -> None:
    """And D003's: with node 2's TPDO1 given as type 2 (every 2nd SYNC) the 182h after
    every SYNC is one run of 116."""
    res = _check(HEALTHY, _with(HEALTHY, tmp_path, "cob_id = 0x182\ntransmission_type = 1\n",
                                "cob_id = 0x182\ntransmission_type = 2\n"))
    assert _found(res) == [("D003", 2, 0.189553)]
    assert res.findings[0].message == "1 SYNCs between TPDOs 182h, expected 2 (116 times)"


# -- sync_length: a SYNC of the wrong length, Lely raises 8240h and still processes it -------

LENGTH = "sync_length"


def test_sync_length_ground_truth() -> None:
    """Node 4 produces SYNC without a counter (DLC 0; no device has 1019h, which Lely reads
    as 0) every 50 ms; nodes 2 and 3 consume it. At 3.986 another device's application
    sends one SYNC with DLC 1, `080#05` (the recorder's tool channel: the only frame of
    these logs not sent by Lely). Lely's consumers call OnSyncError (8240h, register 10h)
    and send EMCY 8240h (register 11h), and still hand the SYNC to the application
    (sync.c co_sync_recv(): their OnSync counted 118 SYNCs, the producer sent 117). Nobody
    leaves OPERATIONAL (8240h is no 81xxh)."""
    frames = _frames(LENGTH)
    sync = _on(LENGTH, 0x080)
    [bad] = [f for f in sync if f.data]
    assert (bad.line, bad.t, bad.data) == (347, 3.986056, "05")
    [tool] = [e for e in _events(LENGTH) if e.device == "tool"]
    assert 0 < bad.t - tool.t < 0.001
    assert "# tool: sent 1" in _log(LENGTH).with_suffix(".events").read_text().splitlines()
    errors = [(e.device, e.text) for e in _events(LENGTH) if e.text.startswith("SYNC error")]
    assert errors == [(dev, "SYNC error: code 8240 register 10 (Lely OnSyncError)")
                      for dev in ("s2", "s3")]
    emcys = _ground_truth_emcys_are_on_the_bus(LENGTH)
    assert [(f.line, f.t, f.can_id, f.data) for f in emcys] == [
        (348, 3.986143, 0x082, "4082110000000000"), (349, 3.986144, 0x083, "4082110000000000")]
    status = _status(LENGTH)
    t_status = next(e.t for e in _events(LENGTH) if e.text.startswith("status: "))
    produced = [f for f in sync if f.t < t_status and not f.data]
    assert len(produced) == 117
    assert status["s4"].endswith(f"EMCY error stack top 0000, SYNC {len(produced)}, RPDO 0")
    for dev in ("s2", "s3"):
        assert status[dev] == ("status: NMT state OPERATIONAL, error register 11, EMCY error "
                               f"stack top 8240, SYNC {len(produced) + 1}, RPDO 0")
        assert _states(LENGTH, dev)[-1][0] < 0.2
    assert max(b.t - a.t for a, b in pairwise(sync)) < 0.0503
    assert not [f for f in frames if f.can_id == 0x000 and f.t > 1]


# Y002 (§9.2.1 (b)): C = 0 ([sync] counter_overflow; without the file C is unknown and the
# DLC change within the segment fires, (d)): one finding at the bad SYNC, node null (a SYNC
# carries no sender). The consumers' EMCYs are explained by it (sync_length: the latest
# offending SYNC in [t_c - emcy_delay_ms, t_c]). E003 for nodes 2 and 3 (never reset). No
# Y001, Y003, Y005: the producer's SYNCs keep their 50 ms.
LENGTH_FOUND: Found = [("Y002", None, 3.986056), ("E003", 2, 3.986143), ("E003", 3, 3.986144)]


@pytest.mark.parametrize("network", [None, "file"], ids=["bare", "network"])
def test_sync_length_findings(network: str | None) -> None:
    res = _check(LENGTH, network)
    assert _found(res) == LENGTH_FOUND
    y002 = _one(res, "Y002", None)
    assert y002.line == 347
    assert y002.message == (
        "SYNC with 1 data byte(s); 1019h = 0 (network) requires 0: CANopenNode consumers drop "
        "it, CANopenNode and Lely consumers raise EMCY 8240h" if network else
        "SYNC DLC 1 after DLC 0 at 0.007072 s (line 66) in the same segment")
    for node, line in ((2, 348), (3, 349)):
        assert _emcy_chain(res, node, line) == [("finding", "Y002", 347, "sync_length", 1)]
    judged = {"Y001", "Y002", "Y003", "Y005"} if network else {"Y001", "Y002", "Y003"}
    assert not judged & set(res.not_evaluated)
