"""CANopenNode v4 recordings where the stack itself raises SYNC and EMCY faults
(samples/canopennode/sync_emcy/, README in samples/canopennode/, "SYNC and EMCY
recordings"): nmtcheck's exact findings on each log, with its network file and without.

The ground truth is not nmtcheck's output: it is the stack's own word. dev.c prints, to
the hub's `.events` file beside each log (CLOCK_REALTIME, the clock of the log), every
NMT state change from CANopenNode's `CO_NMT_initCallbackChanged` callback and every EMCY
the stack sends from `CO_EM_initCallbackRx` (called with ident 0 right after its own
EMCY went out), plus the application's `status` (NMT state, 1001h, active error bits)
near the end, and, from the patched stack of `emcy_short` (emcy_short.patch), every EMCY
it sent with a DLC other than 8. The tests below first check that the log holds what the
stack says it did, then nmtcheck's verdict: each expected finding is derived from the
SPEC's text (SPEC_COMM §9.2, §9.3.4) and the log's frames, and commented where it is
derived.

Where nmtcheck's verdict differed from the SPEC on these real recordings, the case is
in the recordings' README ("SPEC_COMM vs nmtcheck on these recordings"); none is open.
"""

from __future__ import annotations

from itertools import pairwise
from pathlib import Path

import pytest
import stack_recording as recording
from conftest import SAMPLES
from stack_recording import Event, Found, Frame

from nmtcheck.results import InputResult

FOLDER = SAMPLES / "canopennode" / "sync_emcy"
NETWORK = {
    "sync_producer_stopped": "network_sync_stopped.toml",
    "sync_counter": "network_sync_counter.toml",
    "sync_counter_skip": "network_sync_counter.toml",
    "emcy_inhibit": "network_emcy.toml",
    "sync_length": "network_sync_length.toml",
    "emcy_short": "network_emcy_short.toml",
    "sync_period_fast": "network_sync_period_fast.toml",
}


def _log(name: str) -> Path:
    return FOLDER / f"{name}.log"


def _frames(name: str) -> list[Frame]:
    return recording.frames(_log(name))


def _events(name: str) -> list[Event]:
    return recording.events(_log(name))


def _emcys_sent(name: str) -> list[tuple[float, int, str]]:
    return recording.emcys_sent(_log(name))


def _states(name: str, device: str) -> list[tuple[float, str]]:
    return recording.states(_log(name), device)


def _status(name: str) -> dict[str, str]:
    return recording.status(_log(name))


def _check(name: str, network: Path | str | None) -> InputResult:
    net = FOLDER / NETWORK[name] if network == "file" else network
    return recording.check(_log(name), Path(net) if net is not None else None)


def _found(res: InputResult) -> Found:
    return recording.found(res)


def _ground_truth_emcys_are_on_the_bus(name: str) -> list[Frame]:
    return recording.emcys_are_on_the_bus(_log(name))


def test_every_recording_has_its_tests() -> None:
    assert {p.stem for p in FOLDER.glob("*.log")} == set(NETWORK)
    assert {p.stem for p in FOLDER.glob("*.events")} == set(NETWORK)


# -- sync_producer_stopped: the SYNC producer (node 2) stopped by the master ---------------

STOP = "sync_producer_stopped"


def test_sync_producer_stopped_ground_truth() -> None:
    """Node 2 produces SYNC every 20 ms; the master wrote 1006h = 20 ms to nodes 3 and 4
    (0.998 s) and stops node 2 at 3.998 s. Both consumers time out (CO_SYNC.c: 1.5 x
    1006h after the last SYNC), send EMCY 8100h with CANopenNode's error bit 18h, register
    10h (communication), the µs since the last SYNC as info, and drop to PRE-OPERATIONAL
    in the same CO_process() call; when node 2 runs again (6.0 s) they reset the error
    (EMCY 0000h, bit 18h) and stay pre-operational until started at 7.0 s."""
    frames = _frames(STOP)
    stop = next(f for f in frames if (f.can_id, f.data) == (0x000, "0202"))
    assert (stop.line, stop.t) == (434, 3.997872)
    last_sync = [f for f in frames if f.can_id == 0x080 and f.t < stop.t][-1]
    assert (last_sync.line, last_sync.t, last_sync.data) == (433, 3.983065, "")
    assert not [f for f in frames if f.can_id == 0x080 and stop.t < f.t < 5.99]
    # the consumers' 1006h = 20000 us, written by the master and confirmed at 0.998 s
    assert [(f.line, f.can_id, f.data) for f in frames
            if f.can_id in (0x603, 0x583, 0x604, 0x584) and f.data[2:6] == "0610"] == [
        (125, 0x603, "23061000204E0000"), (126, 0x583, "6006100000000000"),
        (127, 0x604, "23061000204E0000"), (128, 0x584, "6006100000000000")]
    emcys = _ground_truth_emcys_are_on_the_bus(STOP)
    assert [(f.line, f.t, f.can_id, f.data) for f in emcys] == [
        (436, 4.014470, 0x084, "00811018EE750000"),  # info 75EEh = 30190 µs
        (437, 4.014546, 0x083, "0081101853760000"),  # info 7653h = 30291 µs
        (535, 6.018591, 0x083, "0000001800000000"),
        (536, 6.018639, 0x084, "0000001800000000")]
    for node, emcy in ((4, emcys[0]), (3, emcys[1])):
        info_us = int.from_bytes(bytes.fromhex(emcy.data)[4:], "little")
        assert info_us > 30000 and abs(emcy.t - info_us / 1e6 - last_sync.t) < 0.002, node
    assert _states(STOP, "s2")[-3:] == [(0.152453, "OPERATIONAL"), (3.997919, "STOPPED"),
                                        (5.997942, "OPERATIONAL")]
    assert _states(STOP, "s3")[-3:] == [(0.152633, "OPERATIONAL"),
                                        (4.014454, "PRE-OPERATIONAL"), (6.997909, "OPERATIONAL")]
    assert _states(STOP, "s4")[-3:] == [(0.153073, "OPERATIONAL"),
                                        (4.014417, "PRE-OPERATIONAL"), (6.997920, "OPERATIONAL")]
    assert all("error register 00, active error bits: none" in s
               for s in _status(STOP).values()) and len(_status(STOP)) == 3
    # what the bus shows of the drops: node 3's heartbeat at once, node 4's guarding
    # answer to the master's next request
    assert next((f.line, f.t, f.data) for f in frames
                if f.can_id == 0x703 and f.t > 4.0) == (438, 4.014565, "7F")
    assert next((f.line, f.t, f.data) for f in frames
                if f.can_id == 0x704 and f.t > 4.0 and not f.data.startswith("R")) == (
        440, 4.073032, "FF")


# SPEC §9.2.1 Y001: t_s + 1.5 x P, P = 1006h 20 ms (the network file's [sync] period_us,
# else, by §9.1.1, the smallest non-zero 1006h of the other nodes: 20 ms written by SDO to
# nodes 3 and 4 at 0.998 s); a stop of the producer does not end the segment (§9.1.5).
# S005 (§3) at each consumer's first report of PRE-OPERATIONAL, explained by its EMCY 8100h
# (§9.3.4 `error_behaviour` (i), code 81xxh; (ii) register 10h too).
STOP_FOUND: Found = [("Y001", 2, 3.983065 + 0.030), ("S005", 3, 4.014565),
                     ("S005", 4, 4.073032)]


def test_sync_producer_stopped_with_the_network_file() -> None:
    res = _check(STOP, "file")
    assert _found(res) == [(r, n, round(t, 6)) for r, n, t in STOP_FOUND]
    y001, s3, s4 = res.findings
    assert y001.basis == "configured" and y001.line == 436
    assert y001.message == ("no SYNC for 2034.368 ms after 3.983065 s (line 433); timeout "
                            "30.000 ms = 1.5 x 1006h 20.000 ms (network)")
    # its cause: the master's stop of the producer, and the producer's report of STOPPED
    assert [(c["kind"], c["line"], c["link"]) for c in y001.causes or []] == [
        ("nmt", 434, "producer_state"), ("node_state", 435, "producer_state")]
    # the consumers' EMCYs answer it
    assert [(r["kind"], r["node"], r["code"], r["role"]) for r in y001.reactions or []] == [
        ("emcy_other", 4, "8100h", "response"), ("emcy_other", 3, "8100h", "response")]
    for s005, line, t in ((s3, 437, "4.014546"), (s4, 436, "4.014470")):
        assert s005.message.endswith(f"explained by EMCY 8100h at {t} s (line {line})")
        chain = [(c["kind"], c.get("code"), c.get("rule"), c["link"], c["depth"])
                 for c in s005.causes or []]
        assert chain == [("emcy", "8100h", None, "error_behaviour", 1),
                         ("finding", None, "Y001", "sync_timeout", 2),
                         ("nmt", None, None, "producer_state", 3)]
    # the SYNC ran at its 1006h (median 20.47 ms, within Y005's 10 %): Y005 judged, silent;
    # the resets of 6.02 s leave no node in error: no E003
    assert "Y005" not in res.not_evaluated and "Y001" not in res.not_evaluated


def test_sync_producer_stopped_without_a_network_file() -> None:
    """The producer is unknown (never inferred from frames): Y001 has no node. The S005
    findings and their explanations are those of the network file."""
    res = _check(STOP, None)
    assert [(r, n) for r, n, _t in _found(res)] == [("Y001", None), ("S005", 3), ("S005", 4)]
    assert _found(res)[1:] == STOP_FOUND[1:]
    y001, s3, s4 = res.findings
    assert y001.line == 436  # the first frame at or after the limit: node 4's EMCY
    for s005, line, t in ((s3, 437, "4.014546"), (s4, 436, "4.014470")):
        assert s005.message.endswith(f"explained by EMCY 8100h at {t} s (line {line})")
        assert [(c["kind"], c.get("rule"), c["link"]) for c in s005.causes or []][:2] == [
            ("emcy", None, "error_behaviour"), ("finding", "Y001", "sync_timeout")]
    assert "Y005" in res.not_evaluated  # the producer's 1006h is unknown


def test_sync_producer_stopped_y001_takes_the_consumers_written_1006h() -> None:
    """SPEC §9.1.1: P is the smallest non-zero 1006h of the other nodes in force: 20 ms,
    written by SDO to nodes 3 and 4 at 0.998 s (confirmed lines 126, 128), which ends the
    first segment (the producer is not known without the network file): the gap is timed
    by it, not by the measured median."""
    res = _check(STOP, None)
    y001 = res.findings[0]
    assert _found(res)[0] == ("Y001", None, round(STOP_FOUND[0][2], 6))
    assert y001.basis == "configured" and "1.5 x 1006h 20.000 ms" in y001.message


# -- sync_counter: a healthy SYNC with a counter (1019h = 4) ---------------------------------

COUNTER, SKIP = "sync_counter", "sync_counter_skip"


def _counter_breaks(name: str) -> list[tuple[int, float, int, int]]:
    """(line, time, previous, counter) of each SYNC whose counter is not the previous + 1
    (4 wraps to 1), leaving out the first SYNC after the reset at 0.1 s (CANopenNode
    restarts its counter at 1 with its SYNC service)."""
    frames = _frames(name)
    reset = next(f.line for f in frames if (f.can_id, f.data) == (0x000, "8200"))
    syncs = [f for f in frames if f.can_id == 0x080]
    assert all(len(f.data) == 2 and 1 <= int(f.data, 16) <= 4 for f in syncs)  # DLC 1
    out = []
    for a, b in pairwise(syncs):
        prev, cur = int(a.data, 16), int(b.data, 16)
        if cur != prev % 4 + 1 and not a.line < reset < b.line:
            out.append((b.line, b.t, prev, cur))
    return out


def test_sync_counter_ground_truth() -> None:
    """The master's SYNC every 20 ms counts 1, 2, 3, 4, 1, … from power-on to the end;
    no consumer raised an EMCY (no SYNC timeout, no SYNC length error: every node has
    1019h = 4), every slave is OPERATIONAL with error register 00h at the end."""
    assert _counter_breaks(COUNTER) == []
    assert _emcys_sent(COUNTER) == [] and not [
        f for f in _frames(COUNTER) if 0x81 <= f.can_id <= 0xFF]
    status = _status(COUNTER)
    assert len(status) == 3 and all(
        s == "status: NMT state OPERATIONAL, error register 00, active error bits: none"
        for s in status.values())


@pytest.mark.parametrize("network", [None, "file"], ids=["bare", "network"])
def test_sync_counter_is_silent(network: str | None) -> None:
    """Y002 (length and counter against 1019h) and Y003 (sequence) stay silent, with
    1019h = 4 from the network file and with it unknown; Y001 and Y005 too."""
    res = _check(COUNTER, network)
    assert _found(res) == []
    if network:
        assert not {"Y001", "Y002", "Y003", "Y005"} & set(res.not_evaluated)


# -- sync_counter_skip: the patched master skips counter 2 once -----------------------------

def test_sync_counter_skip_ground_truth() -> None:
    """sync_skip.patch makes the master's stack skip counter 2 once, from its 300th SYNC
    on: the patched code says so at 6.209957 s, and the log has one break, 3 after 1."""
    injected = [e for e in _events(SKIP) if e.text.startswith("injected (patched stack)")]
    assert [(e.t, e.device) for e in injected] == [(6.209957, "master")]
    assert _counter_breaks(SKIP) == [(657, 6.210083, 1, 3)]
    assert _emcys_sent(SKIP) == []  # CANopenNode's consumers do not check the counter


@pytest.mark.parametrize(("network", "node"), [(None, None), ("file", 1)],
                         ids=["bare", "network"])
def test_sync_counter_skip_is_y003(network: str | None, node: int | None) -> None:
    """Y003 at the breaking SYNC (§9.2.1: with C = 4, (3 − 2) mod 4 = 1 SYNC missing; with
    C unknown, 3 > 2: 3 − 2 missing); its node is the producer when the network file names
    it, else null."""
    res = _check(SKIP, network)
    assert _found(res) == [("Y003", node, 6.210083)]
    [y003] = res.findings
    assert y003.line == 657
    assert y003.message == ("SYNC counter 3 after 1 (expected 2): 1 SYNC(s) missing; "
                            "1 break(s), 1 SYNC(s) missing in this segment")


def test_sync_counter_bare_lists_y002_as_partly_evaluated() -> None:
    """SPEC §9.1.3/§9.1.9: without a network file 1019h is unknown, so Y002 is only partly
    evaluated (DLC > 1, remote frames, DLC changes)."""
    res = _check(COUNTER, None)
    assert "Y002" not in res.not_evaluated
    assert res.partly_evaluated["Y002"].startswith("1019h unknown")


# -- emcy_inhibit: bursts of application errors spaced by 1015h -----------------------------

EMCY = "emcy_inhibit"


def test_emcy_inhibit_ground_truth() -> None:
    """Node 3 (1015h = 50 ms at power-on): three manufacturer errors (bits 40h–42h) at
    2.998 s and their resets 20 ms later; the stack sends the six EMCYs 50.2–51.0 ms
    apart, the error register as it is when each one leaves (80h for the first, 00h once
    the resets are in). Node 2 (1015h = 30 ms by SDO at 2.0 s): FF00h (bit 42h) and the
    generic-critical 6100h (bit 2Ch, register bit 0) at 4.998 s, the reset of 42h 10 ms
    later; it drops to PRE-OPERATIONAL in the same call (NMT control: generic +
    communication), three EMCYs 30.7 and 31.0 ms apart, and 2Ch stays active."""
    emcys = _ground_truth_emcys_are_on_the_bus(EMCY)
    assert [(f.line, f.t, f.can_id, f.data) for f in emcys] == [
        (186, 2.998128, 0x083, "0050804001000000"),
        (187, 3.048707, 0x083, "0061004102000000"),
        (192, 3.099351, 0x083, "00FF004203000000"),
        (195, 3.149975, 0x083, "0000004000000000"),
        (203, 3.200929, 0x083, "0000004100000000"),
        (204, 3.251083, 0x083, "0000004200000000"),
        (298, 4.998060, 0x082, "00FF814204000000"),
        (300, 5.028756, 0x082, "0061012C05000000"),
        (301, 5.059772, 0x082, "0000014200000000")]
    for node, inhibit in ((3, 0.050), (2, 0.030)):
        times = [f.t for f in emcys if f.can_id == 0x80 + node]
        assert min(b - a for a, b in pairwise(times)) >= inhibit
    sdo = [(f.line, f.data) for f in _frames(EMCY) if f.can_id in (0x602, 0x582)]
    assert sdo[-2:] == [(131, "2B1510002C010000"), (132, "6015100000000000")]  # 1015h = 300
    assert _states(EMCY, "s2")[-2:] == [(0.152145, "OPERATIONAL"), (4.998042, "PRE-OPERATIONAL")]
    assert _states(EMCY, "s3")[-1:] == [(0.152436, "OPERATIONAL")]
    assert _status(EMCY) == {
        "s2": "status: NMT state PRE-OPERATIONAL, error register 01, active error bits: 2C",
        "s3": "status: NMT state OPERATIONAL, error register 00, active error bits: none"}


# E003 (§9.2.3): node 2's last EMCY is a reset with register 01h (in error, §9.1.7); node 3's
# last one a reset with register 00h. E001: node 3's EMCYs are >= 1015h apart, node 2's >=
# the 1015h written by SDO. S005 at node 2's first heartbeat 7Fh.
EMCY_FOUND: Found = [("S005", 2, 4.999121), ("E003", 2, 5.059772)]


def test_emcy_inhibit_with_the_network_file() -> None:
    res = _check(EMCY, "file")
    assert _found(res) == EMCY_FOUND
    assert "E001" not in res.not_evaluated  # judged on both nodes, silent
    s005, e003 = res.findings
    # error_register_mask = 11h (the example NMT control): FF00h's register 81h has bit 0,
    # so §9.3.4 `error_behaviour` (ii) links it; it is the first EMCY after OPERATIONAL
    assert s005.message.endswith("explained by EMCY FF00h at 4.998060 s (line 298)")
    assert [(c["kind"], c["code"], c["link"]) for c in s005.causes or []] == [
        ("emcy", "FF00h", "error_behaviour")]
    # the generic-critical EMCY leaves 30 ms later (the inhibit time): a report, not a cause
    assert [(r["kind"], r["code"], r["role"]) for r in s005.reactions or []] == [
        ("emcy", "6100h", "report")]
    assert e003.line == 301 and e003.message.startswith(
        "node 2 still in error at the end of the trace: last EMCY 0000h")
    assert "error register 01h; codes since the last full reset: FF00h, 6100h, 0000h" in (
        e003.message)


def test_emcy_inhibit_without_a_network_file() -> None:
    """The same findings. Node 2's 1015h (300, written by SDO) is in the trace, so E001
    judges node 2 and is silent. S005 is not explained: with no `error_register_mask`
    the link takes register bit 4 only (§9.3.4 (ii), a choice), FF00h's byte 3 (42h) is
    no generic-critical marker (iii), and the 2Ch EMCY comes after the drop."""
    res = _check(EMCY, None)
    assert _found(res) == EMCY_FOUND
    s005 = res.findings[0]
    assert "explained by" not in s005.message
    assert all(c["link"] != "error_behaviour" for c in s005.causes or [])


def test_emcy_inhibit_e001_judges_these_emcys(tmp_path: Path) -> None:
    """The silence is E001's verdict, not a skip: the same log with node 3's 1015h given
    as 60 ms (more than the stack used) fires E001 once, at node 3's second EMCY (50.6 ms
    after the first), for the run of five."""
    text = (FOLDER / NETWORK[EMCY]).read_text()
    assert "emcy_inhibit_100us = 500" in text
    wrong = tmp_path / "network.toml"
    wrong.write_text(text.replace("emcy_inhibit_100us = 500", "emcy_inhibit_100us = 600"))
    res = _check(EMCY, wrong)
    assert [f for f in _found(res) if f[0] == "E001"] == [("E001", 3, 3.048707)]


def test_emcy_inhibit_bare_lists_e001_for_node_3() -> None:
    """SPEC §9.1.3: without a network file node 3's 1015h is unknown and its six EMCYs are
    not judged (node 2's is written by SDO): E001 is partly evaluated, naming node 3."""
    res = _check(EMCY, None)
    assert "E001" not in res.not_evaluated
    assert res.partly_evaluated["E001"].endswith("(can0 node 3)")


# -- emcy_short: a stack that sends EMCYs with DLC 4 (E002) ----------------------------------

SHORT = "emcy_short"


def test_emcy_short_ground_truth() -> None:
    """Node 3 on the patched stack (dev_emcyshort): its application raises manufacturer
    error 5000h (bit 40h, register 80h) at 3.0 s and resets it at 3.5 s, then the same at
    5.0 s and 5.5 s. The stack sends four EMCYs, the callback gives each one's eight bytes;
    the patch says the first two went out with DLC 4, and the bus has exactly that: lines
    184 and 211 carry the first four of the callback's bytes, lines 292 and 319 all eight.
    No other EMCY; node 3 stays OPERATIONAL (register bit 7 is not in its NMT control mask)
    and ends with register 00h."""
    injected = [e for e in _events(SHORT) if e.text.startswith("injected (patched stack)")]
    assert [(e.device, e.text) for e in injected] == [
        ("s3", "injected (patched stack): EMCY 083h sent with DLC 4 instead of 8")] * 2
    emcys = [f for f in _frames(SHORT) if 0x81 <= f.can_id <= 0xFF]
    sent = _emcys_sent(SHORT)
    assert [(f.line, f.t, f.can_id, f.data) for f in emcys] == [
        (184, 2.997921, 0x083, "00508040"),
        (211, 3.497895, 0x083, "00000040"),
        (292, 4.997944, 0x083, "0050804002000000"),
        (319, 5.497881, 0x083, "0000004000000000")]
    assert [(node, data) for _, node, data in sent] == [
        (3, "0050804001000000"), (3, "0000004000000000"),
        (3, "0050804002000000"), (3, "0000004000000000")]
    for k, (frame, (t, node, data)) in enumerate(zip(emcys, sent, strict=True)):
        dlc = 4 if k < len(injected) else 8
        assert (frame.can_id, frame.data) == (0x80 + node, data[:2 * dlc])
        assert abs(frame.t - t) < 0.001
    for frame, e in zip(emcys, injected, strict=False):
        assert 0 <= frame.t - e.t < 0.001  # the patched code logs right after CO_CANsend()
    assert _states(SHORT, "s3")[-1:] == [(0.15284, "OPERATIONAL")]
    assert set(_status(SHORT).values()) == {
        "status: NMT state OPERATIONAL, error register 00, active error bits: none"}


@pytest.mark.parametrize("network", [None, "file"], ids=["bare", "network"])
def test_emcy_short_is_e002(network: str | None) -> None:
    """E002 (§9.2.3) (b): lines 184 and 211 are EMCYs of node 3 (on 83h, DLC >= 2, §9.1.7)
    of DLC 4 with nothing in between on 83h: one run, one finding at the first with its
    count. The EMCYs of DLC 8 fire nothing; E002 needs no configuration, so the network
    file changes nothing. E003 is silent: node 3's last EMCY is a reset with register 00h.
    E001 cannot fire: 1015h is 0 (the file) or unknown (without it: not evaluated)."""
    res = _check(SHORT, network)
    assert _found(res) == [("E002", 3, 2.997921)]
    [e002] = res.findings
    assert e002.line == 184
    assert e002.message == (
        "EMCY of node 3 with DLC 4, 8 expected (CanFestival consumers drop it) (2 frames)")
    assert "E002" not in res.not_evaluated and "E002" not in res.partly_evaluated
    if network is None:
        assert "E001" in res.not_evaluated


# -- heartbeat consumer timeouts in the earlier recordings (EMCY 8130h, byte 3 = 1Bh) --------

def _canopennode(name: str, network: bool) -> InputResult:
    folder = SAMPLES / "canopennode"
    return recording.check(folder / f"{name}.log", folder / "network.toml" if network else None)


@pytest.mark.parametrize("network", [False, True], ids=["bare", "network"])
def test_master_unplugged_drops_are_explained_by_the_consumers_emcys(network: bool) -> None:
    """master_unplugged.log: the slaves' heartbeat consumers (600 ms) miss the master and
    send EMCY 8130h, byte 3 = 1Bh (`082/083#3081101B00000000`), then drop to
    PRE-OPERATIONAL; node 4's life guarding sends the same EMCY (`084#…`, info 0). Each
    S005 is explained by the node's own EMCY (§9.3.4 `error_behaviour`)."""
    res = _canopennode("master_unplugged", network)
    explained = {f.node: f.message.rsplit("; ", 1)[1] for f in res.findings
                 if f.rule == "S005" and f.node != 1}
    assert explained == {
        2: "explained by EMCY 8130h at 4.511724 s (line 252)",
        3: "explained by EMCY 8130h at 4.511630 s (line 251)",
        4: "explained by EMCY 8130h at 4.270265 s (line 244)"}
    for f in res.findings:
        if f.rule == "S005" and f.node != 1:
            [cause] = [c for c in f.causes or [] if c["link"] == "error_behaviour"]
            assert (cause["kind"], cause["node"], cause["code"]) == ("emcy", f.node, "8130h")


def test_unplugged_heartbeat_master_drop_is_explained() -> None:
    """unplugged_heartbeat.log without the network file (no master known): the master's
    drop to PRE-OPERATIONAL (S005 node 1) is explained by its own EMCY 8130h (consumer
    entry 1 = node 3), and that EMCY by node 3's H001 (`heartbeat_consumer`). Node 3's own
    drop is not explained: its EMCY was sent while it was unplugged and never reached the
    bus (its reset `083#0000001B00000000` comes at 7.085 s, after the drop)."""
    res = _canopennode("unplugged_heartbeat", False)
    s1 = next(f for f in res.findings if (f.rule, f.node) == ("S005", 1))
    assert s1.message.endswith("explained by EMCY 8130h at 5.278436 s (line 300)")
    assert [(c["kind"], c.get("code"), c.get("rule"), c.get("node"), c["link"])
            for c in s1.causes or []][:2] == [
        ("emcy", "8130h", None, 1, "error_behaviour"),
        ("finding", None, "H001", 3, "heartbeat_consumer")]
    s3 = next(f for f in res.findings if (f.rule, f.node) == ("S005", 3))
    assert "explained by" not in s3.message


# -- sync_length: consumers that expect a SYNC counter the producer does not send --------------

LENGTH = "sync_length"


def test_sync_length_ground_truth() -> None:
    """The master produces SYNC every 20 ms without a counter (DLC 0). At 1.0 s it writes
    1019h = 4 and 1006h = 20 ms to nodes 2 and 3 (lines 125-132, confirmed). At the next
    SYNC (1.006 s) both consumers report a wrong SYNC length (EMCY 8240h, error bit 19h,
    register 10h) and drop to PRE-OPERATIONAL (NMT control: communication bit); as they
    drop every SYNC from then on, their SYNC timeout follows (8100h, bit 18h, 30 ms after
    the last SYNC they accepted). Node 4 (no 1019h written) runs on."""
    frames = _frames(LENGTH)
    syncs = [f for f in frames if f.can_id == 0x080]
    assert {f.data for f in syncs} == {""}
    assert [(f.line, f.data) for f in frames if 125 <= f.line <= 132] == [
        (125, "2F19100004000000"), (126, "6019100000000000"),
        (127, "23061000204E0000"), (128, "6006100000000000"),
        (129, "2F19100004000000"), (130, "6019100000000000"),
        (131, "23061000204E0000"), (132, "6006100000000000")]
    assert [(node, data) for _t, node, data in _emcys_sent(LENGTH)] == [
        (2, "4082101980000000"), (3, "4082101980000000"),
        (2, "008110187E750000"), (3, "0081101888750000")]
    emcys = _ground_truth_emcys_are_on_the_bus(LENGTH)
    assert [f.line for f in emcys] == [134, 135, 138, 139]
    first_bad = next(f for f in syncs if f.line > 132)
    assert (first_bad.line, first_bad.t) == (133, 1.006008)
    assert emcys[0].t - first_bad.t < 0.002
    assert _states(LENGTH, "s2")[-1] == (1.007151, "PRE-OPERATIONAL")
    assert _states(LENGTH, "s3")[-1] == (1.007172, "PRE-OPERATIONAL")
    status = _status(LENGTH)
    assert status["s2"].endswith("error register 10, active error bits: 18 19")
    assert status["s3"].endswith("error register 10, active error bits: 18 19")
    assert status["s4"].endswith("error register 00, active error bits: none")


# SPEC §9.2.1 Y002 (b): C = 4 in force at the SYNC (the producer's 1019h unknown, the nodes
# with a known one agree: nodes 2 and 3, written by SDO, §9.1.1), so DLC 0 is wrong, one
# run from the first such SYNC. S005 (§3) for both consumers, explained by their EMCY
# 8240h (§9.3.4 `error_behaviour` (ii): register 10h) and that EMCY by the Y002
# (`sync_length`). E003 for both: bits 18h and 19h stay active to the end.
LENGTH_FOUND: Found = [("Y002", None, 1.006008), ("S005", 3, 1.007286),
                       ("S005", 2, 1.00736), ("E003", 2, 1.017753), ("E003", 3, 1.017819)]


@pytest.mark.parametrize("network", [None, "file"], ids=["bare", "network"])
def test_sync_length_is_y002_with_its_chain(network: str | None) -> None:
    res = _check(LENGTH, network)
    assert _found(res) == LENGTH_FOUND
    y002 = res.findings[0]
    assert y002.line == 133
    assert y002.message.startswith(
        "SYNC with 0 data byte(s); 1019h = 4 (written by SDO at line 126) requires 1: "
        "CANopenNode consumers drop it, CANopenNode and Lely consumers raise EMCY 8240h (")
    for s005, line in zip(res.findings[1:3], (135, 134), strict=True):
        chain = [(c["kind"], c.get("code"), c.get("rule"), c["link"], c["depth"])
                 for c in s005.causes or []]
        assert chain == [("emcy", "8240h", None, "error_behaviour", 1),
                         ("finding", None, "Y002", "sync_length", 2)]
        assert (s005.causes or [])[0]["line"] == line
    # before the writes (1.0 s) no node's 1019h is known: those SYNCs had only the checks
    # that need no C (§9.1.9)
    assert "Y002" in res.partly_evaluated


# -- sync_period_fast: a SYNC slower than the producer's 1006h (Y005) --------------------------

FAST = "sync_period_fast"


def _sync_intervals_in_segments(name: str) -> list[float]:
    """The SYNC intervals, none across the master's broadcast reset (a segment end)."""
    frames = _frames(name)
    reset = next(f for f in frames if (f.can_id, f.data) == (0x000, "8200"))
    syncs = [f for f in frames if f.can_id == 0x080]
    return [b.t - a.t for a, b in pairwise(syncs) if not a.t < reset.t < b.t]


def test_sync_period_fast_ground_truth() -> None:
    """The master powers on with 1006h = 5300 us (`dev --sync-us 5300`, its command line in
    the `.events`). Its application calls CO_process() about once a millisecond, and the
    stack sends the SYNC in the first call at or past 1006h, then counts from 0 again
    (CO_SYNC.c): every 6th call, about 6.15 ms, never late enough for a consumer's 1.5 x
    1006h."""
    spawn = [line for line in (FOLDER / f"{FAST}.events").read_text().splitlines()
             if line.startswith("# hub t=") and "spawn master:" in line]
    assert len(spawn) == 1 and spawn[0].endswith("--sync-us 5300")
    frames = _frames(FAST)
    assert {f.data for f in frames if f.can_id == 0x080} == {""}
    iv = sorted(_sync_intervals_in_segments(FAST))
    assert len(iv) > 900
    assert 0.0060 < iv[len(iv) // 2] < 0.0063
    assert iv[-1] < 1.5 * 0.0053
    assert _emcys_sent(FAST) == []


def test_sync_period_fast_is_y005() -> None:
    """SPEC §9.2.1 Y005: the median interval of each segment (before and after the master's
    reset of all nodes) is 16 % over the producer's 1006h; one finding per segment, at its
    last SYNC. Y001 (limit 7.95 ms) stays silent."""
    res = _check(FAST, "file")
    found = _found(res)
    assert [(r, n) for r, n, _t in found] == [("Y005", 1), ("Y005", 1)]
    first, last = res.findings
    for f in (first, last):
        assert "the producer's 1006h = 5.300 ms (network): +16." in f.message
    assert last.line == len(_frames(FAST))  # the last SYNC is the log's last frame
    assert "Y001" not in res.not_evaluated


def test_sync_period_fast_without_a_network_file() -> None:
    """Without the producer's 1006h Y005 is not evaluated; Y001 judges by the measured
    median and stays silent."""
    res = _check(FAST, None)
    assert _found(res) == []
    assert "Y005" in res.not_evaluated
