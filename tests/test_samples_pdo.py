"""CANopenNode v4 recordings where the stack itself shows PDO timing faults
(samples/canopennode/pdo/, README in samples/canopennode/, "PDO recordings"): nmtcheck's
findings on each log, with its network file and without.

The ground truth is not nmtcheck's output: it is the stack's own word and the bus. dev.c
prints, to the hub's `.events` file beside each log (CLOCK_REALTIME, the clock of the
log), every NMT state change from CANopenNode's `CO_NMT_initCallbackChanged` callback,
every EMCY the stack sends from `CO_EM_initCallbackRx` (called with ident 0 right after
its own EMCY went out), the PDO configuration the stack initialised at each
communication reset ("PDO configuration", read back from its object dictionary), every
application request for a TPDO, the application's `status` near the end, and, from the
patched stack of `tpdo_inhibit_bypass` (tpdo_inhibit.patch), every TPDO it sent with its
inhibit time still running, and from that of `tpdo_late` (tpdo_late.patch), every
synchronous TPDO it sent after its synchronous window. The tests first check that the log
holds what the stack says it did and that each network file describes what the stack ran
with, then nmtcheck's verdict: each expected finding is derived from the SPEC's text
(SPEC_COMM §9.1.6, §9.2.1, §9.2.2, §9.3.4; SPEC §3 for S002/S005) and the log's frames, and
commented where it is derived.

The cases where nmtcheck's verdict once differed (PDO parameters written by SDO in the
trace, an RPDO that reaches two consumers) are ordinary tests now, each with its case in
its docstring or comment.
"""

from __future__ import annotations

import re
import sys
from itertools import pairwise
from pathlib import Path
from typing import Any

import pytest
import stack_recording as recording
from conftest import SAMPLES
from stack_recording import DEVICES, Event, Found, Frame

from nmtcheck.results import Finding, InputResult

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

FOLDER = SAMPLES / "canopennode" / "pdo"
LOGS = ("rpdo_producer_stopped", "rpdo_timeout_stale_heartbeat", "tpdo_event_timer",
        "tpdo_inhibit_bypass", "rpdo_length", "sync_tpdo", "reserved_type", "tpdo_late",
        "tpdo_late_written")


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


def _emcys_sent(name: str) -> list[tuple[float, int, str]]:
    return recording.emcys_sent(_log(name))


def _states(name: str, device: str) -> list[tuple[float, str]]:
    return recording.states(_log(name), device)


def _status(name: str) -> dict[str, str]:
    return recording.status(_log(name))


def _check(name: str, network: Path | str | None) -> InputResult:
    net = _network(name) if network == "file" else network
    return recording.check(_log(name), Path(net) if net is not None else None)


def _found(res: InputResult) -> Found:
    return recording.found(res)


def _one(res: InputResult, rule: str, node: int | None) -> Finding:
    [f] = [f for f in res.findings if (f.rule, f.node) == (rule, node)]
    return f


def _first_at_or_after(name: str, t: float) -> Frame:
    return next(f for f in _frames(name) if f.t >= round(t, 6))


def _ground_truth_emcys_are_on_the_bus(name: str) -> list[Frame]:
    return recording.emcys_are_on_the_bus(_log(name))


def test_every_recording_has_its_tests() -> None:
    assert {p.stem for p in FOLDER.glob("*.log")} == set(LOGS)
    assert {p.stem for p in FOLDER.glob("*.events")} == set(LOGS)
    assert {p.name for p in FOLDER.glob("*.toml")} == {f"network_{n}.toml" for n in LOGS}


# -- the network files describe what the stacks ran with -------------------------------------

PDO_CONFIG = re.compile(r"PDO configuration: ([TR])PDO1 COB-ID (\w{8}) type (\d+)"
                        r"(?: inhibit (\d+))? event (\d+) mapping((?: \w{8})+| none)")


def _stack_pdos(name: str) -> dict[tuple[int, str], dict[str, Any]]:
    """(node, "tpdo"/"rpdo") -> the PDO1 parameters the stack printed at its last
    communication reset, as network-file keys. CANopenNode stores a pre-defined COB-ID
    without the node-ID and adds it (CO_PDO.c, OD_read_PDO_commParam)."""
    out: dict[tuple[int, str], dict[str, Any]] = {}
    for e in _events(name):
        m = PDO_CONFIG.fullmatch(e.text)
        if not m:
            continue
        node = DEVICES[e.device]
        kind = "tpdo" if m[1] == "T" else "rpdo"
        cob = int(m[2], 16)
        assert cob & 0x80000000 == 0  # dev.c prints valid PDOs only
        can_id = cob & 0x7FF
        if can_id == (0x180 if kind == "tpdo" else 0x200):
            can_id += node
        pdo: dict[str, Any] = {"cob_id": can_id, "transmission_type": int(m[3]),
                               "event_timer_ms": int(m[5]),
                               "mapping": [int(v, 16) for v in m[6].split()]}
        if m[4] is not None:
            pdo["inhibit_100us"] = int(m[4])
        out[node, kind] = pdo
    return out


@pytest.mark.parametrize("name", LOGS)
def test_network_file_is_the_stacks_pdo_configuration(name: str) -> None:
    """Every valid PDO the stacks initialised is in the network file with the same COB-ID,
    transmission type, inhibit time, event timer and mapping, and nothing else is."""
    net = tomllib.loads(_network(name).read_text())
    described: dict[tuple[int, str], dict[str, Any]] = {}
    for n, node in net["nodes"].items():
        for kind in ("tpdo", "rpdo"):
            for k, pdo in node.get(kind, {}).items():
                assert k == "1"
                described[int(n), kind] = {key: v for key, v in pdo.items() if key != "sync_start"}
                if kind == "tpdo":
                    assert pdo["sync_start"] == 0  # OD.c: 1800h sub 6 = 0
        assert node["error_register_mask"] == 0x11  # dev.c: generic + communication
    assert described == _stack_pdos(name)


# -- rpdo_producer_stopped: node 3's RPDO deadline, the producer (node 2) stopped -------------

STOP = "rpdo_producer_stopped"


def test_rpdo_producer_stopped_ground_truth() -> None:
    """Node 2's TPDO1 (182h, event timer 100 ms) is node 3's RPDO1 with a 250 ms deadline.
    The master stops node 2 at 3.998 s. 250 ms after the last 182h node 3's stack reports
    EMCY 8250h (error bit 17h, register 10h, info = µs since the timer was armed) and drops
    to PRE-OPERATIONAL in the same call (NMT control: communication bit); it then resets the
    error (0000h, bit 17h: outside OPERATIONAL the deadline timer is cleared, CANopen.c
    CO_process_RPDO). Node 2 runs again from 6.0 s, node 3 from 7.0 s."""
    frames = _frames(STOP)
    stop = next(f for f in frames if (f.can_id, f.data) == (0x000, "0202"))
    assert (stop.line, stop.t) == (268, 3.99824)
    tpdo = _on(STOP, 0x182)
    last = [f for f in tpdo if f.t < stop.t][-1]
    assert (last.line, last.t) == (265, 3.966909)
    assert not [f for f in tpdo if stop.t < f.t < 5.99]
    assert [(f.line, f.t, f.data) for f in frames if f.can_id == 0x702 and 3.99 < f.t < 4.0] == [
        (269, 3.999419, "04")]
    emcys = _ground_truth_emcys_are_on_the_bus(STOP)
    assert [(f.line, f.t, f.can_id, f.data) for f in emcys] == [
        (282, 4.218791, 0x083, "508210177BD30300"),  # info 3D37Bh = 250747 µs
        (283, 4.219807, 0x083, "0000001700000000")]
    info_us = int.from_bytes(bytes.fromhex(emcys[0].data)[4:], "little")
    assert info_us > 250000 and abs(emcys[0].t - info_us / 1e6 - last.t) < 0.002
    assert _states(STOP, "s2")[-3:] == [(0.153069, "OPERATIONAL"), (3.998326, "STOPPED"),
                                        (5.998257, "OPERATIONAL")]
    assert _states(STOP, "s3")[-3:] == [(0.153304, "OPERATIONAL"),
                                        (4.218732, "PRE-OPERATIONAL"), (6.998276, "OPERATIONAL")]
    # what the bus shows of node 3's drop: its heartbeats 05h until 4.166967, 7Fh from 4.219849
    assert [(f.line, f.t, f.data) for f in frames if f.can_id == 0x703 and 4.1 < f.t < 4.3] == [
        (278, 4.166967, "05"), (284, 4.219849, "7F")]
    assert len(_status(STOP)) == 3 and all(
        s == "status: NMT state OPERATIONAL, error register 00, active error bits: none"
        for s in _status(STOP).values())


# D004 (§9.2.2): armed at node 3's last 182h (3.966909), deadline E_c = 250 ms (network
# file); node 3 OPERATIONAL through 4.216909 (its next reports 05h) and its first other
# report (7Fh, 4.219849) follows its EMCY 8250h (4.218791 >= t_l + E_c): judged.
# S005 (SPEC §3) at node 3's first 7Fh. S002 (SPEC §3, a configured RPDO of node 3 on the
# bus while it is PRE-OPERATIONAL): node 2's first TPDO at its start (line 19, node 3 is
# started 0.3 ms later) and node 2's TPDOs from 6.0 s until node 3 is started at 7.0 s.
STOP_FOUND: Found = [("S002", 3, 0.153098), ("D004", 3, 3.966909 + 0.250),
                     ("S005", 3, 4.219849), ("S002", 3, 5.998279)]


def test_rpdo_producer_stopped_with_the_network_file() -> None:
    res = _check(STOP, "file")
    assert _found(res) == [(r, n, round(t, 6)) for r, n, t in STOP_FOUND]
    s002, d004, s005, s002_run = res.findings
    assert (s002.line, s002_run.line) == (19, 371)
    assert s002_run.message.endswith("(10 frames)")  # 5.998279 ... 6.900, every 100 ms
    assert d004.line == 282  # the first frame at or after 4.216909: node 3's EMCY
    assert d004.message.startswith("no RPDO 182h for node 3 for ")
    assert "deadline 1400h:05 = 250 ms (network); producer node 2" in d004.message
    assert d004.message.endswith("confirmed by EMCY 8250h of node 3 at 4.218791 s (line 282)")
    # §9.3.4 producer_state: t_e = t_l + the producer's event timer 100 ms = 4.066909; the
    # stop (3.998240) and node 2's report of STOPPED (3.999419) lie in (t_l, t_e]
    assert [(c["kind"], c["line"], c["link"]) for c in d004.causes or []] == [
        ("nmt", 268, "producer_state"), ("node_state", 269, "producer_state")]
    assert [(r["kind"], r["node"], r["line"], r["role"]) for r in d004.reactions or []][:2] == [
        ("emcy", 3, 282, "report"), ("node_state", 3, 284, "report")]
    # the chain of SPEC_COMM §9.3.6's example: the drop, explained by node 3's EMCY 8250h
    # (error_behaviour (ii): register 10h ∩ mask 11h), whose cause is D004 (rpdo_timeout:
    # the gap contains the EMCY), whose cause is the master's stop of node 2 (producer_state)
    assert s005.message.endswith("explained by EMCY 8250h at 4.218791 s (line 282)")
    assert [(c["kind"], c.get("code"), c.get("rule"), c["line"], c["link"], c["depth"])
            for c in s005.causes or []] == [
        ("emcy", "8250h", None, 282, "error_behaviour", 1),
        ("finding", None, "D004", 282, "rpdo_timeout", 2),
        ("nmt", None, None, 268, "producer_state", 3)]
    # node 2's TPDO stops before its 112 ms limit (D001 silent); node 3's reset EMCY leaves
    # it without an active error (no E003)
    assert not {"D001", "D004", "D005"} & set(res.not_evaluated)


def test_rpdo_producer_stopped_without_a_network_file() -> None:
    """No PDO is configured: 182h is node 2's default TPDO1 and nobody's RPDO (node 3's
    defaults are 203h/303h/403h/503h), so no D004 and no S002. S005 is still explained by
    the EMCY 8250h (error_behaviour (ii) with the default mask 10h); below it nothing:
    D004 is not evaluated and `pdo_gap` looks at node 3's RPDO streams, which carry no
    frame."""
    res = _check(STOP, None)
    assert _found(res) == [("S005", 3, 4.219849)]
    [s005] = res.findings
    assert s005.message.endswith("explained by EMCY 8250h at 4.218791 s (line 282)")
    assert [(c["kind"], c.get("code"), c["link"], c["depth"]) for c in s005.causes or []] == [
        ("emcy", "8250h", "error_behaviour", 1)]


# -- rpdo_timeout_stale_heartbeat: the same with a 300 ms deadline --------------------------

STALE = "rpdo_timeout_stale_heartbeat"


def test_rpdo_timeout_stale_heartbeat_ground_truth() -> None:
    """As rpdo_producer_stopped with node 3's deadline 300 ms: 3 × node 2's event timer and
    3 × node 3's own heartbeat period, which run in phase from the start. The RPDO timeout
    (EMCY 8250h, info 300.367 ms) fell in the CO_process() call in which node 3's heartbeat
    was due: CANopenNode sends the EMCY (CO_EM_process), then the due heartbeat with the
    state it still has (CO_NMT_process, before it applies the error register), then drops
    to PRE-OPERATIONAL; the heartbeat of the new state follows in the next call. So the bus
    shows 8250h, `703#05`, the reset 0000h, `703#7F`; the stack's callback reports
    PRE-OPERATIONAL before the hub stamped that 05h."""
    frames = _frames(STALE)
    last = [f for f in _on(STALE, 0x182) if f.t < 3.998][-1]
    assert (last.line, last.t) == (265, 3.970957)
    assert next(f for f in frames if f.can_id == 0x000 and f.t > 3.9).line == 268
    emcys = _ground_truth_emcys_are_on_the_bus(STALE)
    assert [(f.line, f.t, f.data) for f in emcys] == [
        (282, 4.272494, "508210174F950400"),  # info 4954Fh = 300367 µs
        (284, 4.273544, "0000001700000000")]
    assert [(f.line, f.t, f.data) for f in frames if f.can_id == 0x703 and 4.1 < f.t < 4.3] == [
        (278, 4.172136, "05"), (283, 4.272605, "05"), (285, 4.273585, "7F")]
    [(t_drop, state)] = [s for s in _states(STALE, "s3") if 4.0 < s[0] < 5.0]
    assert (t_drop, state) == (4.272451, "PRE-OPERATIONAL")
    assert emcys[0].t - 0.0001 < t_drop < 4.272605  # after the EMCY's callback, before the 05h


# D004 and S002 as in rpdo_producer_stopped (deadline 300 ms); S005 at the 7Fh.
STALE_FOUND: Found = [("S002", 3, 0.154118), ("D004", 3, 3.970957 + 0.300),
                      ("S005", 3, 4.273585), ("S002", 3, 5.998049)]


def test_rpdo_timeout_stale_heartbeat_with_the_network_file() -> None:
    res = _check(STALE, "file")
    assert _found(res) == [(r, n, round(t, 6)) for r, n, t in STALE_FOUND]
    d004, s005 = res.findings[1:3]
    assert d004.line == 282 and d004.message.endswith(
        "confirmed by EMCY 8250h of node 3 at 4.272494 s (line 282)")
    # by SPEC_COMM §9.3.4's letter the EMCY would be no `error_behaviour` cause: it is not in
    # (t_p, t_f] = (4.272605, 4.273585], t_p being the 05h sent after it; nmtcheck follows the
    # stack (explain/chains.py `same_cycle_start`): the test below
    assert s005.message.endswith("explained by EMCY 8250h at 4.272494 s (line 282)")


def test_rpdo_timeout_stale_heartbeat_drop_is_explained_by_the_rpdo_timeout() -> None:
    """CANopenNode sent the due heartbeat 703#05 (4.272605, line 283) after the EMCY 8250h
    (4.272494, line 282) in the same CO_process() call, before applying the error
    register (its callback says PRE-OPERATIONAL at 4.272451): the 05h is no evidence the
    EMCY came later. An EMCY of N at most 5 ms before N's last report of the old state,
    with only N's own frames between, counts as inside the window: a choice beyond SPEC
    §9.3.4, which follows the real stack."""
    res = _check(STALE, "file")
    s005 = _one(res, "S005", 3)
    assert s005.message.endswith("explained by EMCY 8250h at 4.272494 s (line 282)")
    assert [(c["kind"], c.get("rule"), c["link"]) for c in s005.causes or []] == [
        ("emcy", None, "error_behaviour"), ("finding", "D004", "rpdo_timeout"),
        ("nmt", None, "producer_state")]


# -- tpdo_event_timer: event-driven TPDOs with event timers and inhibit times, healthy --------

EVT = "tpdo_event_timer"


def _requests(name: str, device: str) -> list[float]:
    return [e.t for e in _events(name)
            if e.device == device and e.text.startswith("application: 2000h = ")]


def test_tpdo_event_timer_ground_truth() -> None:
    """Node 2 (type 254, inhibit 10 ms, event timer 100 ms), node 3 (type 255, 20 ms,
    250 ms), node 4 (type 254, neither: on request only) send their TPDO1 as CANopenNode
    lets them: never closer than the inhibit time, even when the application asks every
    2 ms (node 2 at 3.0 s, 20 requests) or 5 ms (node 3 at 5.0 s, 10 requests) — the stack
    holds the frame and sends the newest value when the inhibit time is over — and never
    longer apart than the event timer plus one processing tick while OPERATIONAL."""
    for can_id, inhibit, event in ((0x182, 0.010, 0.100), (0x183, 0.020, 0.250)):
        times = [f.t for f in _on(EVT, can_id)]
        gaps = [b - a for a, b in pairwise(times)]
        assert min(gaps) >= inhibit, hex(can_id)
        assert max(gaps) < event + 0.0015, hex(can_id)
    assert len(_requests(EVT, "s2")) == 25 and len(_requests(EVT, "s3")) == 10
    # the bursts: 20 requests in 39 ms gave 5 frames 10.2-10.6 ms apart, 10 requests in
    # 46 ms gave 4 frames 20.7-20.9 ms apart; the last frame carries the last value
    burst2 = [f for f in _on(EVT, 0x182) if 2.99 < f.t < 3.1]
    assert [f.line for f in burst2] == [209, 210, 211, 212, 213]
    assert burst2[-1].data == "19000000"  # 2000h = 25: the 20th request's value
    burst3 = [f for f in _on(EVT, 0x183) if 4.99 < f.t < 5.1]
    assert [f.line for f in burst3] == [338, 339, 340, 342]
    # node 4: once when it is started (CANopenNode sends an event-driven TPDO on entering
    # OPERATIONAL) and once after each of its four requests, within 1.5 ms
    node4 = _on(EVT, 0x184)
    assert node4[0].line == 35 and len(node4) == 1 + 4
    assert all(0 < f.t - r < 0.0015 for f, r in zip(node4[1:], _requests(EVT, "s4"), strict=True))
    assert len(_status(EVT)) == 3 and all(
        s == "status: NMT state OPERATIONAL, error register 00, active error bits: none"
        for s in _status(EVT).values())
    assert _emcys_sent(EVT) == []


@pytest.mark.parametrize("network", [None, "file"], ids=["bare", "network"])
def test_tpdo_event_timer_is_silent(network: str | None) -> None:
    """D001 (L = 1.1 × E + 2 ms: 112 ms for node 2, 277 ms for node 3, 552 ms for the
    master; node 4 has no event timer) and D002 (node 2 >= 10 ms, node 3 >= 20 ms) stay
    silent; D005 too (every TPDO has DLC 4 = its mapping)."""
    res = _check(EVT, network)
    assert _found(res) == []


def _with(name: str, tmp_path: Path, old: str, new: str) -> Path:
    text = _network(name).read_text()
    assert text.count(old) == 1, old
    wrong = tmp_path / "network.toml"
    wrong.write_text(text.replace(old, new))
    return wrong


NODE2_TPDO = "[nodes.2.tpdo.1]"


def test_tpdo_event_timer_d002_judges_these_frames(tmp_path: Path) -> None:
    """The silence is D002's verdict, not a skip: with node 2's inhibit time given as
    11 ms (more than the stack used) the burst at 3.0 s (5 frames 10.2-10.6 ms apart) is
    one run, at its second frame; nothing else of node 2's is closer than 11 ms."""
    text = _network(EVT).read_text()
    block = text[text.index(NODE2_TPDO):]
    assert block.index("inhibit_100us = 100") < block.index("[nodes.3]")
    res = _check(EVT, _with(EVT, tmp_path, "inhibit_100us = 100", "inhibit_100us = 110"))
    assert _found(res) == [("D002", 2, 3.00968)]
    assert res.findings[0].line == 210


def test_tpdo_event_timer_d001_judges_these_frames(tmp_path: Path) -> None:
    """The same for D001: with node 2's event timer given as 80 ms (L = 90 ms) every
    100 ms gap of node 2 while OPERATIONAL fires, the first after its first TPDO."""
    text = _network(EVT).read_text()
    block = text[text.index(NODE2_TPDO):]
    old = "inhibit_100us = 100\nevent_timer_ms = 100"
    assert old in block
    res = _check(EVT, _with(EVT, tmp_path, old, "inhibit_100us = 100\nevent_timer_ms = 80"))
    first = _on(EVT, 0x182)[0]
    assert first.line == 19
    found = _found(res)
    assert {(r, n) for r, n, _t in found} == {("D001", 2)}
    assert found[0][2] == round(first.t + 0.090, 6) and len(found) > 80


# -- tpdo_inhibit_bypass: the patched stack ignores the inhibit time four times ---------------

BYPASS = "tpdo_inhibit_bypass"


def test_tpdo_inhibit_bypass_ground_truth() -> None:
    """Node 2 (inhibit 10 ms, event timer 100 ms) on the patched stack: its application
    asks for the TPDO five times 1 ms apart at 3.0 s; the stack sends at the first request
    (line 207) and, the patch says, four more times with 8.9 ms of the inhibit time left
    (lines 208-211, 1.04-1.13 ms apart). At 6.0 s the same requests: the patch is spent,
    the stack holds the second frame until the inhibit time is over (10.5 ms)."""
    injected = [e for e in _events(BYPASS) if e.text.startswith("injected (patched stack)")]
    assert [e.device for e in injected] == ["s2"] * 4
    assert all(re.fullmatch(r"injected \(patched stack\): TPDO 182h sent with 8\d{3} us of "
                            r"its inhibit time 10000 us left", e.text) for e in injected)
    tpdo = _on(BYPASS, 0x182)
    burst = [f for f in tpdo if 2.99 < f.t < 3.1]
    assert [(f.line, f.t) for f in burst] == [
        (207, 2.999281), (208, 3.00032), (209, 3.001451), (210, 3.002576), (211, 3.003665)]
    for frame, e in zip(burst[1:], injected, strict=True):
        assert 0 < frame.t - e.t < 0.001  # the patched code logs just before CO_CANsend()
    assert [(f.line, f.t) for f in tpdo if 5.99 < f.t < 6.1] == [(394, 5.999069), (395, 6.009536)]
    gaps = [b.t - a.t for a, b in pairwise(tpdo)]
    assert sorted(gaps)[4] >= 0.010  # only the four injected ones are closer than 10 ms
    assert len(_status(BYPASS)) == 3 and _emcys_sent(BYPASS) == []


def test_tpdo_inhibit_bypass_with_the_network_file() -> None:
    """D002 (§9.2.2): F1 line 207, F2 line 208, 1.039 ms < 10 ms − r (1 µs) − q (F1 is not
    back to back with the frame before it): one finding for the run of four pairs, at the
    first F2, with the count and the smallest spacing (1.039 ms)."""
    res = _check(BYPASS, "file")
    assert _found(res) == [("D002", 2, 3.00032)]
    [d002] = res.findings
    assert d002.line == 208
    assert d002.message.startswith(
        "TPDO 182h of node 2 1.039 ms after the previous one (line 207); inhibit time "
        "1800h:03 = 100 ")
    assert "(network)" in d002.message
    rest = d002.message.split("allowance", 1)[1]
    assert re.search(r"\b4\b", rest) and "1.039" in rest  # the count, the smallest spacing


def test_tpdo_inhibit_bypass_without_a_network_file() -> None:
    """No inhibit time is known: D002 cannot judge, nothing else fires."""
    assert _found(_check(BYPASS, None)) == []


# -- rpdo_length: RPDO mappings longer and shorter than the producer's TPDO -------------------

LENGTH = "rpdo_length"


def test_rpdo_length_ground_truth() -> None:
    """Node 2's TPDO1 has DLC 4 throughout (its mapping: 2000h, 32 bit). Node 3 maps 8
    bytes: its first 182h arrives while it is PRE-OPERATIONAL (line 19), and when the master
    starts it CANopenNode raises EMCY 8210h (error bit 04h, register 00h, info = mapped
    length 8) and discards every frame. Node 4 maps 2 bytes: EMCY 8220h (info 2) when it is
    started; it processes the frames and keeps the error. At 5.0 s the master rewrites node
    3's mapping by SDO (RPDO invalid, 1600h = 2001h 32 bit, valid again, lines 331-340);
    node 3's next 182h is right: it resets the error (0000h, info = the new length 4)."""
    tpdo = _on(LENGTH, 0x182)
    assert {len(f.data) for f in tpdo} == {8} and len(tpdo) == 99
    assert (tpdo[0].line, tpdo[0].t) == (19, 0.152287)
    emcys = _ground_truth_emcys_are_on_the_bus(LENGTH)
    assert [(f.line, f.t, f.can_id, f.data) for f in emcys] == [
        (28, 0.152665, 0x083, "1082000408000000"),
        (38, 0.153228, 0x084, "2082000402000000"),
        (345, 5.076245, 0x083, "0000000404000000")]
    sdo = [(f.line, f.can_id, f.data) for f in _frames(LENGTH) if f.can_id in (0x603, 0x583)]
    assert sdo[-10:] == [
        (331, 0x603, "2300140182010080"), (332, 0x583, "6000140100000000"),
        (333, 0x603, "2F00160000000000"), (334, 0x583, "6000160000000000"),
        (335, 0x603, "2300160120000120"), (336, 0x583, "6000160100000000"),
        (337, 0x603, "2F00160001000000"), (338, 0x583, "6000160000000000"),
        (339, 0x603, "2300140182010000"), (340, 0x583, "6000140100000000")]
    assert _states(LENGTH, "s3")[-1] == (0.152604, "OPERATIONAL")
    assert _states(LENGTH, "s4")[-1] == (0.153037, "OPERATIONAL")
    assert _status(LENGTH) == {
        "s2": "status: NMT state OPERATIONAL, error register 00, active error bits: none",
        "s3": "status: NMT state OPERATIONAL, error register 00, active error bits: none",
        "s4": "status: NMT state OPERATIONAL, error register 00, active error bits: 04"}


def _length_frames_before_the_fix() -> int:
    return sum(1 for f in _on(LENGTH, 0x182) if f.line < 331)


def test_rpdo_length_with_the_network_file() -> None:
    """D005 (b) for both consumers at the first 182h (node 3 and node 4 are
    PRE-OPERATIONAL: CN checks the length at reception, §9.2.2 amended), none (a) for node 2
    (DLC 4 = its mapping); E003 for node 4, whose last EMCY is 8220h. The S002 findings of
    that frame are tested below."""
    res = _check(LENGTH, "file")
    assert sorted(f for f in _found(res) if f[0] != "S002") == [
        ("D005", 3, 0.152287), ("D005", 4, 0.152287), ("E003", 4, 0.153228)]
    d3, d4 = _one(res, "D005", 3), _one(res, "D005", 4)
    assert (d3.line, d4.line) == (19, 19)
    assert d3.message.startswith("RPDO 182h has DLC 4; node 3 maps 8 bytes (1600h, network): "
                                 "node 3 discards it and raises EMCY 8210h")
    assert d4.message == ("RPDO 182h has DLC 4; node 4 maps 2 bytes (1600h, network): node 4 "
                          "raises EMCY 8220h (99 frames)")
    assert _one(res, "E003", 4).line == 38
    assert "D005" not in res.not_evaluated


def test_rpdo_length_s002_for_both_consumers() -> None:
    res = _check(LENGTH, "file")
    assert sorted(f for f in _found(res) if f[0] == "S002") == [
        ("S002", 3, 0.152287), ("S002", 4, 0.152287)]


def test_rpdo_length_d005_counts_the_frames_of_the_file_mapping_only() -> None:
    assert _length_frames_before_the_fix() == 49
    res = _check(LENGTH, "file")
    assert _one(res, "D005", 3).message == (
        "RPDO 182h has DLC 4; node 3 maps 8 bytes (1600h, network): node 3 discards it and "
        "raises EMCY 8210h (49 frames)")


def test_rpdo_length_without_a_network_file() -> None:
    """Only E003 (node 4): EMCY rules need no configuration. No mapping is known until the
    master writes node 3's, and that one fits (4 bytes): no D005."""
    res = _check(LENGTH, None)
    assert _found(res) == [("E003", 4, 0.153228)]


def test_rpdo_length_bare_lists_d005_as_partly_evaluated() -> None:
    res = _check(LENGTH, None)
    assert "D005" not in res.not_evaluated
    assert "D005" in res.partly_evaluated


# -- sync_tpdo: synchronous TPDOs with a SYNC producer, healthy -------------------------------

SYNC = "sync_tpdo"


def _syncs_between(name: str, a: Frame, b: Frame) -> int:
    return sum(1 for f in _on(name, 0x080) if a.t < f.t < b.t)


def test_sync_tpdo_ground_truth() -> None:
    """The master's SYNC (DLC 0) every 20 ms. Node 2 (type 1) sends one TPDO after every
    SYNC, node 3 (type 4) after every 4th, each within 1 ms of its SYNC; node 4 (type 0)
    at most one per SYNC, at the SYNC after its application asked (10 requests 1 ms apart
    at 3.0 s: one TPDO; 10 requests 30 ms apart at 5.0 s: ten). Node 2 stopped at 4.0 s
    (line 642), started at 6.0 s (line 868)."""
    syncs = _on(SYNC, 0x080)
    assert {f.data for f in syncs} == {""}
    reset = next(f for f in _frames(SYNC) if (f.can_id, f.data) == (0x000, "8200"))
    gaps = sorted(b.t - a.t for a, b in pairwise(syncs) if not a.t < reset.t < b.t)
    assert 0.0202 < gaps[len(gaps) // 2] < 0.0207 and gaps[-1] < 0.024  # one 23.96 ms
    for can_id, n in ((0x182, 1), (0x183, 4)):
        frames = _on(SYNC, can_id)
        for a, b in pairwise(frames):
            if not a.t < 3.9977 < b.t:  # node 2's stop and start
                assert _syncs_between(SYNC, a, b) == n, (hex(can_id), a, b)
    node4 = _on(SYNC, 0x184)
    assert all(_syncs_between(SYNC, a, b) >= 1 for a, b in pairwise(node4))
    assert len(node4) == 1 + 1 + 10
    for frame in _on(SYNC, 0x182) + _on(SYNC, 0x183) + node4:
        last_sync = [s for s in syncs if s.t < frame.t][-1]
        assert frame.t - last_sync.t < 0.001
    assert [(f.line, f.data) for f in _frames(SYNC) if f.can_id == 0x000 and f.t > 1] == [
        (642, "0202"), (868, "0102")]
    assert len(_status(SYNC)) == 3 and _emcys_sent(SYNC) == []


@pytest.mark.parametrize("network", [None, "file"], ids=["bare", "network"])
def test_sync_tpdo_is_silent(network: str | None) -> None:
    """D003 (one TPDO per n SYNCs; the first after a start only opens the count), Y001 and
    Y005 stay silent."""
    assert _found(_check(SYNC, network)) == []


def test_sync_tpdo_d003_judges_these_frames(tmp_path: Path) -> None:
    """The silence is D003's verdict: with node 3's type given as 2 (its stack ran 4),
    every pair of its TPDOs has 4 = 2 × 2 SYNCs between (one TPDO missing, (a)): one run,
    timed at the 3rd SYNC after its first TPDO (which only opens the count)."""
    res = _check(SYNC, _with(SYNC, tmp_path, "transmission_type = 4", "transmission_type = 2"))
    first = _on(SYNC, 0x183)[0]
    third = [s for s in _on(SYNC, 0x080) if s.t > first.t][2]
    assert _found(res) == [("D003", 3, third.t)]


# -- tpdo_late: a synchronous TPDO sent after the synchronous window (Y004) ------------------

LATE = "tpdo_late"


def _late_tpdos(name: str, after_sync: str, after_window: str
                ) -> tuple[list[Frame], list[Frame], list[Any]]:
    """Node 2's TPDO 182h, those more than 1 ms after their SYNC, and the patched stack's
    three "injected" events (device s2), whose texts give the delays as patterns."""
    injected = [e for e in _events(name) if e.text.startswith("injected (patched stack)")]
    assert [e.device for e in injected] == ["s2"] * 3
    assert all(re.fullmatch(rf"injected \(patched stack\): TPDO 182h sent {after_sync} us "
                            rf"after the SYNC, {after_window} us after its window 1007h = "
                            r"10000 us", e.text) for e in injected)
    tpdo = _on(name, 0x182)
    return tpdo, [f for f in tpdo if f.t - _last_sync_before(name, f).t > 0.001], injected


def _last_sync_before(name: str, frame: Frame) -> Frame:
    return [s for s in _on(name, 0x080) if s.t < frame.t][-1]


def test_tpdo_late_ground_truth() -> None:
    """The master's SYNC (DLC 0) every 20 ms; node 2's TPDO1 type 1 with 1007h = 10 ms at
    power-on, on the patched stack (dev_late). The patch says it held the TPDO back three
    times and sent it 14.25-14.27 ms after the SYNC by its own timer (4.25-4.27 ms after the
    window); on the bus these are lines 344, 495 and 649, 14.44-14.48 ms after the SYNC
    before them (lines 343, 494, 648). Every other 182h is within 1 ms of its SYNC, one per
    SYNC (nothing is late but what the patch made late); nodes 3 and 4 keep their
    event-driven TPDO1 (type 254, 500 ms). No EMCY (the hub driver sends at once, so
    CANopenNode's "TPDO outside window" error bit is never set), all OPERATIONAL."""
    tpdo, late, injected = _late_tpdos(LATE, r"142\d\d", r"42\d\d")
    assert [(f.line, f.t, _last_sync_before(LATE, f).line) for f in late] == [
        (344, 2.227327, 343), (495, 3.259849, 494), (649, 4.290046, 648)]
    for frame, e in zip(late, injected, strict=True):
        assert 0 < frame.t - e.t < 0.001  # the patched code logs just before CO_CANsend()
        assert 0.014 < frame.t - _last_sync_before(LATE, frame).t < 0.015
    assert all(_syncs_between(LATE, a, b) == 1 for a, b in pairwise(tpdo))
    syncs = _on(LATE, 0x080)
    assert {f.data for f in syncs} == {""}
    reset = next(f for f in _frames(LATE) if (f.can_id, f.data) == (0x000, "8200"))
    gaps = sorted(b.t - a.t for a, b in pairwise(syncs) if not a.t < reset.t < b.t)
    assert 0.0202 < gaps[len(gaps) // 2] < 0.0210 and gaps[-1] < 0.027  # one 25.90 ms
    assert set(_status(LATE).values()) == {
        "status: NMT state OPERATIONAL, error register 00, active error bits: none"}
    assert len(_status(LATE)) == 3 and _emcys_sent(LATE) == []


def test_tpdo_late_with_the_network_file() -> None:
    """Y004 (§9.2.1): W = `[sync] window_us` = 10 ms; each late frame comes more than W + r
    (1 µs) after the latest SYNC, node 2 OPERATIONAL; the late frames are not consecutive
    (on-time frames between them), so each is its own run. D003 stays silent (one TPDO
    per SYNC: the late one is still before the next SYNC), Y001 and Y005 too."""
    res = _check(LATE, "file")
    assert _found(res) == [("Y004", 2, 2.227327), ("Y004", 2, 3.259849), ("Y004", 2, 4.290046)]
    assert [f.line for f in res.findings] == [344, 495, 649]
    assert res.findings[0].message == (
        "TPDO 182h (node 2, type 1) 14.470 ms after SYNC at 2.212857 s (line 343); "
        "synchronous window 1007h = 10.000 ms (network)")
    assert "Y004" not in res.not_evaluated


def test_tpdo_late_y004_needs_the_window(tmp_path: Path) -> None:
    """The three findings are the window's verdict: with 1007h given as 0 (no window) the
    same log is silent, and Y004 is listed as not evaluated."""
    res = _check(LATE, _with(LATE, tmp_path, "window_us = 10000", "window_us = 0"))
    assert _found(res) == []
    assert "Y004" in res.not_evaluated


def test_tpdo_late_without_a_network_file() -> None:
    """Neither node 2's transmission type nor its 1007h is on the bus (power-on values):
    Y004 is not evaluated (SPEC_COMM §9.1.4), nothing fires."""
    res = _check(LATE, None)
    assert _found(res) == []
    assert "Y004" in res.not_evaluated


WRITTEN = "tpdo_late_written"


def test_tpdo_late_written_ground_truth() -> None:
    """As tpdo_late, but node 2's power-on 1007h is 0 and the master writes 1007h = 10000 µs
    to it by SDO (line 164, confirmed line 165 at 0.998143; the master's SDO client: ok).
    The patch acts only with a window set, and says it held the TPDO back three times,
    4.24-4.38 ms after that window; on the bus lines 346, 497 and 652, 14.36-14.57 ms after
    the SYNC before them (lines 345, 496, 651). Every other 182h within 1 ms of its SYNC."""
    frames = _frames(WRITTEN)
    assert [(f.line, f.t, f.can_id, f.data) for f in frames if f.can_id in (0x602, 0x582)
            and f.t > 0.5] == [(164, 0.998041, 0x602, "2307100010270000"),
                               (165, 0.998143, 0x582, "6007100000000000")]
    assert "SDO write node 2 1007:00 = 10000 ok" in [e.text for e in _events(WRITTEN)]
    tpdo, late, injected = _late_tpdos(WRITTEN, r"14\d{3}", r"4\d{3}")
    assert [(f.line, f.t, _last_sync_before(WRITTEN, f).line) for f in late] == [
        (346, 2.220826, 345), (497, 3.255112, 496), (652, 4.289718, 651)]
    for frame, e in zip(late, injected, strict=True):
        assert 0 < frame.t - e.t < 0.001
    assert all(_syncs_between(WRITTEN, a, b) == 1 for a, b in pairwise(tpdo))
    assert len(_status(WRITTEN)) == 3 and _emcys_sent(WRITTEN) == []


def test_tpdo_late_written_with_the_network_file() -> None:
    """Y004 (§9.2.1) with W = node 2's 1007h written by SDO (10 ms, from 0.998143: the
    value in force from its confirmation, SPEC_COMM §9.1.1): the three late frames, each
    its own run, as in tpdo_late."""
    res = _check(WRITTEN, "file")
    assert _found(res) == [("Y004", 2, 2.220826), ("Y004", 2, 3.255112), ("Y004", 2, 4.289718)]


def test_tpdo_late_written_without_a_network_file() -> None:
    """The window is in the trace, node 2's transmission type is not: Y004 is not evaluated
    (SPEC_COMM §9.1.4), nothing fires."""
    res = _check(WRITTEN, None)
    assert _found(res) == []
    assert "Y004" in res.not_evaluated


# -- the basis of a time limit (SPEC §7 findings[j].basis, SPEC_COMM §9.2.0) ----------------

@pytest.mark.parametrize(("name", "rule", "node"), [(BYPASS, "D002", 2), (STOP, "D004", 3)])
def test_d_time_limits_are_configured(name: str, rule: str, node: int) -> None:
    assert _one(_check(name, "file"), rule, node).basis == "configured"


# -- the rules that could not judge (SPEC_COMM §9.1.3, §9.1.9) -------------------------------

# Per log and network file, the D-rules that lack what they need: D002 needs a TPDO of type
# 254/255 with a non-zero inhibit time, D003 a synchronous TPDO, D004 an RPDO with a
# non-zero event timer, D001 an event-driven TPDO with a non-zero event timer, D005 a mapping.
# Without the file nothing of that is known (rpdo_length's SDO-written mapping is tested above).
NOT_EVALUATED: dict[tuple[str, str | None], set[str]] = {
    ("rpdo_producer_stopped", "file"): {"D002", "D003"},
    ("rpdo_timeout_stale_heartbeat", "file"): {"D002", "D003"},
    ("tpdo_event_timer", "file"): {"D003", "D004"},
    ("tpdo_inhibit_bypass", "file"): {"D003", "D004"},
    ("rpdo_length", "file"): {"D002", "D003", "D004"},
    ("sync_tpdo", "file"): {"D002", "D004"},
    ("reserved_type", "file"): {"D002", "D003", "D004"},
    ("tpdo_late", "file"): {"D002", "D004"},
    ("tpdo_late_written", "file"): {"D002", "D004"},
    **{(name, None): {"D001", "D002", "D003", "D004", "D005"} for name in LOGS
       if name != "rpdo_length"},
    ("rpdo_length", None): {"D001", "D002", "D003", "D004"},
}




@pytest.mark.parametrize(("name", "network"), [
    (n, f) for n, f in sorted(NOT_EVALUATED, key=str)],
    ids=[f"{n}-{'network' if f else 'bare'}" for n, f in sorted(NOT_EVALUATED, key=str)])
def test_d_rules_not_evaluated(name: str, network: str | None) -> None:
    res = _check(name, network)
    assert {c for c in res.not_evaluated if c.startswith("D")} == NOT_EVALUATED[name, network]


# -- reserved_type: the master writes reserved transmission types (D006) ---------------------

RESERVED = "reserved_type"


def test_reserved_type_ground_truth() -> None:
    """The master downloads 1800h:02 = 245 to node 2 (2.0 s) and 1400h:02 = 250 to node 3
    (3.0 s); CANopenNode refuses both with abort 06090030h (invalid value), as its
    `.events` say (the master's SDO client result)."""
    frames = _frames(RESERVED)
    assert [(f.line, f.can_id, f.data) for f in frames if f.can_id in (0x602, 0x582, 0x603, 0x583)
            and f.t > 1.5] == [
        (131, 0x602, "2F001802F5000000"), (132, 0x582, "8000180230000906"),
        (186, 0x603, "2F001402FA000000"), (187, 0x583, "8000140230000906")]
    results = [e.text for e in _events(RESERVED)
               if "SDO write node" in e.text and "failed" in e.text]
    assert results == ["SDO write node 2 1800:02 failed, abort 06090030",
                       "SDO write node 3 1400:02 failed, abort 06090030"]
    assert _emcys_sent(RESERVED) == []


@pytest.mark.parametrize("network", [None, "file"], ids=["bare", "network"])
def test_reserved_type_is_d006(network: str | None) -> None:
    """SPEC §9.2.2 D006: at each download request, refused; nothing else on this healthy
    network (D006 needs no configuration)."""
    res = _check(RESERVED, network)
    assert _found(res) == [("D006", 2, 1.997582), ("D006", 3, 2.997574)]
    d2, d3 = res.findings
    assert (d2.line, d3.line) == (131, 186)
    assert d2.message == (
        "download 1800h:02 = 245 to node 2: transmission types 241–251 (TPDO) are reserved; "
        "node 2 refused it (abort 06090030h: invalid value for parameter (download only))")
    assert d3.message == (
        "download 1400h:02 = 250 to node 3: transmission types 241–253 (RPDO) are reserved; "
        "node 3 refused it (abort 06090030h: invalid value for parameter (download only))")
