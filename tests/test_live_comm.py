"""Live SYNC, PDO and EMCY rules (nmtcheck/live/comm.py) against the offline check, on the
CANopenNode recordings whose faults the stack itself reported (samples/canopennode/
sync_emcy/, samples/canopennode/pdo/; the expected offline findings and their ground truth
are in tests/test_samples_sync_emcy.py and tests/test_samples_pdo.py).

Offline = online: replayed frame by frame (and once on python-can's virtual bus at the
recording's timing), every offline finding of a rule decided live was reported live with
the same rule, node and time (within CONFIRM_TOLERANCE_S), every live finding of these
groups is confirmed by the check of the recording, and the healthy recordings stay silent.
"""

from __future__ import annotations

import time
from pathlib import Path

import can
import pytest
from conftest import SAMPLES, Checker
from test_live import PROFILE, RULES, frames_of, replay_at_real_timing

import nmtcheck
from nmtcheck.engine import check_input, select_rules
from nmtcheck.live.frames import LiveFrame, candump_line
from nmtcheck.live.session import CONFIRM_TOLERANCE_S, GRACE_S, BusClock, Outcome, Session
from nmtcheck.live.tracker import LiveFinding
from nmtcheck.results import InputResult
from nmtcheck.settings.network import Network, load_network
from nmtcheck.settings.profiles import load_profile

CN = SAMPLES / "canopennode"
LIVE_COMM = {"Y001", "Y002", "Y003", "Y004", "D001", "D002", "D004", "D005", "D006", "E001", "E002"}
GROUPS = ("Y", "D", "E")
# recording -> its network file, and the live rules the stack's faults give with it
RECORDINGS: dict[str, tuple[Path, set[str]]] = {
    "sync_emcy/sync_producer_stopped": (CN / "sync_emcy/network_sync_stopped.toml", {"Y001"}),
    "sync_emcy/sync_counter": (CN / "sync_emcy/network_sync_counter.toml", set()),
    "sync_emcy/sync_counter_skip": (CN / "sync_emcy/network_sync_counter.toml", {"Y003"}),
    "sync_emcy/emcy_inhibit": (CN / "sync_emcy/network_emcy.toml", set()),
    "sync_emcy/emcy_short": (CN / "sync_emcy/network_emcy_short.toml", {"E002"}),
    "pdo/rpdo_length": (CN / "pdo/network_rpdo_length.toml", {"D005"}),
    "pdo/rpdo_producer_stopped": (CN / "pdo/network_rpdo_producer_stopped.toml", {"D004"}),
    "pdo/rpdo_timeout_stale_heartbeat": (
        CN / "pdo/network_rpdo_timeout_stale_heartbeat.toml", {"D004"}),
    "pdo/sync_tpdo": (CN / "pdo/network_sync_tpdo.toml", set()),
    "pdo/tpdo_event_timer": (CN / "pdo/network_tpdo_event_timer.toml", set()),
    "pdo/tpdo_inhibit_bypass": (CN / "pdo/network_tpdo_inhibit_bypass.toml", {"D002"}),
    "pdo/tpdo_late": (CN / "pdo/network_tpdo_late.toml", {"Y004"}),
    "healthy": (CN / "network.toml", set()),
    "sync_pdo": (CN / "network.toml", set()),
}


def _replay(log: Path, network: Network | None, frames: list[LiveFrame] | None = None
            ) -> Outcome:
    session = Session(PROFILE, RULES, network, timer=False)
    for f in frames if frames is not None else frames_of(log):
        session.feed(f)
    return session.close()


def _assert_offline_equals_live(outcome: Outcome, offline_log: Path,
                                network: Network | None) -> set[str]:
    """The session's final result is the offline check of the log; every offline Y/D/E
    finding of a live rule was seen live; every live one is confirmed. The rules seen."""
    res = outcome.result
    assert res is not None
    original = check_input(str(offline_log), 0, PROFILE, RULES, network)
    assert [(f.rule, f.node, round(f.time, 6)) for f in res.findings] == [
        (f.rule, f.node, round(f.time, 6)) for f in original.findings]
    live = [lf for lf in outcome.live if lf.rule[0] in GROUPS]
    assert [(lf.rule, lf.node, lf.confirmed) for lf in live if lf.confirmed != "confirmed"] == []
    for f in res.findings:
        if f.rule in LIVE_COMM:
            assert any((lf.rule, lf.node) == (f.rule, f.node)
                       and abs(lf.time - f.time) <= CONFIRM_TOLERANCE_S for lf in live), (
                f.rule, f.node, f.time, [(lf.rule, lf.node, lf.time) for lf in live])
    return {f.rule for f in res.findings if f.rule in LIVE_COMM}


@pytest.mark.parametrize("with_network", [False, True], ids=["bare", "network"])
@pytest.mark.parametrize("name", sorted(RECORDINGS))
def test_replay_gives_the_offline_findings_live(name: str, with_network: bool) -> None:
    net_path, expected = RECORDINGS[name]
    log = CN / f"{name}.log"
    network = load_network(str(net_path)) if with_network else None
    seen = _assert_offline_equals_live(_replay(log, network), log, network)
    if with_network:  # what the stack reported, found live (tests/test_samples_*.py)
        assert seen == expected
    elif name.endswith(("sync_producer_stopped", "sync_counter_skip", "emcy_short")):
        assert seen == expected  # no configuration needed (Y001 from the written 1006h)
    else:
        assert seen == set()


def test_y001_is_decided_when_the_deadline_passes() -> None:
    """sync_producer_stopped.log up to the master's stop of the SYNC producer (3.998 s):
    no later frame comes, and the SYNC timeout (last SYNC 3.983065 + 1.5 x 20 ms) is
    reported by the clock once it is GRACE_S old; before that, nothing."""
    frames = frames_of(CN / "sync_emcy/sync_producer_stopped.log")
    t0 = frames[0].ts
    head = [f for f in frames if f.ts - t0 <= 3.998]
    wall = [0.0]
    got: list[LiveFinding] = []
    network = load_network(str(CN / "sync_emcy/network_sync_stopped.toml"))
    s = Session(PROFILE, RULES, network, timer=False, clock=BusClock(lambda: wall[0]),
                on_finding=got.append)
    for f in head:
        wall[0] = f.ts - t0
        s.feed(f)
    due = 3.983065 + 0.030
    wall[0] = due + GRACE_S - 0.002
    s.tick()
    assert [lf.rule for lf in got] == []
    wall[0] = due + GRACE_S + 0.002
    s.tick()
    assert [(lf.rule, lf.node, round(lf.time - t0, 6), lf.certain) for lf in got] == [
        ("Y001", 2, round(due, 6), True)]
    outcome = s.close()
    assert [lf.confirmed for lf in outcome.live] == ["clock-only"]  # after the last frame


RPDO_NETWORK = """master = 1
[nodes.3]
heartbeat_ms = 1000
[nodes.3.rpdo.1]
cob_id = 0x182
transmission_type = 254
event_timer_ms = 250
mapping = [0x20000020]
"""


@pytest.mark.parametrize("with_8250", [False, True], ids=["unexplained", "8250h"])
def test_d004_and_a_later_report_of_another_state(tmp_path: Path, with_8250: bool) -> None:
    """Node 3 (heartbeat 1 s) is OPERATIONAL and receives RPDO 182h every 100 ms until
    1.0 s; its deadline (250 ms) passes at 1.25 s and live fires D004 then. Its next report
    (1.5 s) says PRE-OPERATIONAL with no command to it: its state in the gap was not
    supervised (SPEC_COMM §9.1.6) unless its EMCY 8250h at 1.26 s says it left OPERATIONAL
    because of this timeout. Without the EMCY the offline check has no D004 and the live
    one is withdrawn; with it both have it."""
    net = tmp_path / "network.toml"
    net.write_text(RPDO_NETWORK)
    network = load_network(str(net))
    frames = [_frame(0.0, 0x703, b"\x00"), _frame(0.001, 0x000, b"\x01\x03"),
              _frame(0.5, 0x703, b"\x05")]
    frames += [_frame(0.1 * k, 0x182, bytes(4)) for k in range(1, 11)]
    if with_8250:
        frames.append(_frame(1.26, 0x083, bytes([0x50, 0x82, 0x10, 0x17, 0, 0, 0, 0])))
    frames.append(_frame(1.5, 0x703, b"\x7f"))
    frames.sort(key=lambda f: f.ts)
    log = tmp_path / "rpdo.log"
    log.write_text("".join(candump_line(f) for f in frames))
    outcome = _replay(log, network, frames)
    assert outcome.result is not None
    offline = [(f.rule, f.node, round(f.time, 6)) for f in outcome.result.findings
               if f.rule == "D004"]
    live = [(lf.rule, lf.node, round(lf.time, 6), lf.confirmed) for lf in outcome.live
            if lf.rule == "D004"]
    if with_8250:
        assert offline == [("D004", 3, 1.25)]
        assert live == [("D004", 3, 1.25, "confirmed")]
    else:
        assert offline == []
        assert live == [("D004", 3, 1.25, "withdrawn")]


def _with(tmp_path: Path, path: Path, old: str, new: str) -> Network:
    text = path.read_text()
    assert old in text
    out = tmp_path / path.name
    out.write_text(text.replace(old, new, 1))
    return load_network(str(out))


def test_e001_live_on_a_tighter_inhibit_time(tmp_path: Path) -> None:
    """emcy_inhibit.log with node 3's 1015h given as 60 ms (the stack used 50): E001 at
    node 3's second EMCY, 50.6 ms after the first (tests/test_samples_sync_emcy.py), live
    and offline; with the stack's own 50 ms, silent (the test above)."""
    log = CN / "sync_emcy/emcy_inhibit.log"
    network = _with(tmp_path, CN / "sync_emcy/network_emcy.toml",
                    "emcy_inhibit_100us = 500", "emcy_inhibit_100us = 600")
    outcome = _replay(log, network)
    assert _assert_offline_equals_live(outcome, log, network) == {"E001"}
    t0 = outcome.result.stats.start if outcome.result else None
    assert t0 is not None
    assert [(lf.rule, lf.node, round(lf.time - t0, 6), lf.certain) for lf in outcome.live
            if lf.rule == "E001"] == [("E001", 3, 3.048707, True)]


def test_d002_live_on_a_tighter_inhibit_time(tmp_path: Path) -> None:
    """tpdo_event_timer.log with node 2's inhibit time given as 11 ms (the stack used 10):
    the burst at 3.0 s is one D002 run at its second frame, live and offline."""
    log = CN / "pdo/tpdo_event_timer.log"
    path = CN / "pdo/network_tpdo_event_timer.toml"
    text = path.read_text()
    block = text.index("[nodes.2.tpdo.1]")
    out = tmp_path / path.name
    out.write_text(text[:block] + text[block:].replace("inhibit_100us = 100",
                                                       "inhibit_100us = 110", 1))
    network = load_network(str(out))
    outcome = _replay(log, network)
    assert _assert_offline_equals_live(outcome, log, network) == {"D002"}
    t0 = outcome.result.stats.start if outcome.result else 0.0
    assert [(lf.rule, lf.node, round(lf.time - (t0 or 0.0), 6)) for lf in outcome.live
            if lf.rule == "D002"] == [("D002", 2, 3.00968)]


def test_a_pdo_parameter_written_by_sdo_makes_the_live_finding_provisional(
        tmp_path: Path) -> None:
    """The network file gives node 3's TPDO an inhibit time of 10 ms; the master writes
    1800h:03 = 10 (1 ms) and node 3 confirms: the session's check applies the write (no
    D002 for TPDOs 3 ms apart). Live takes PDO parameters from the files, so its D002 is
    provisional, and not confirmed at the end: never a certain finding the check refutes.
    With an upload of 1800h:03 in the write's place (the same frames' times and lengths)
    the same D002 is certain and confirmed."""
    lines = ["(10.000000) can0 703#00", "(10.000500) can0 603#2B0018030A000000",
             "(10.000700) can0 583#6000180300000000", "(10.001000) can0 000#0103",
             "(10.010000) can0 183#0100", "(10.013000) can0 183#0200",
             "(10.030000) can0 183#0300"]
    net = tmp_path / "net.toml"
    net.write_text("[nodes.3.tpdo.1]\ncob_id = 0x183\ntransmission_type = 255\n"
                   "inhibit_100us = 100\n")
    network = load_network(str(net))
    for written, want in ((True, [("D002", False, "not-confirmed")]),
                          (False, [("D002", True, "confirmed")])):
        log = tmp_path / f"written_{written}.log"
        read = ["(10.000500) can0 603#4000180300000000", "(10.000700) can0 583#4B00180364000000"]
        log.write_text("\n".join(lines if written else lines[:1] + read + lines[3:]) + "\n")
        outcome = _replay(log, network)
        assert [(lf.rule, lf.certain, lf.confirmed) for lf in outcome.live
                if lf.rule == "D002"] == want
        assert outcome.result is not None
        assert [f.rule for f in outcome.result.findings if f.rule == "D002"] == (
            [] if written else ["D002"])


def _frame(ts: float, can_id: int, data: bytes, rtr: bool = False, dlc: int | None = None
           ) -> LiveFrame:
    return LiveFrame(ts, "can0", can_id, rtr=rtr, dlc=len(data) if dlc is None else dlc,
                     data=data)


def test_y002_and_e002_fire_live_and_offline(tmp_path: Path) -> None:
    """The rules that need no configuration, on frames no stack of the samples sends: a
    SYNC every 10 ms (counter 1..4) with one of DLC 2 and one remote frame among them, and
    between the SYNCs an EMCY of node 5 of DLC 4 (a run of two) and a remote EMCY. Each
    defect fires once, live and offline; the well-formed frames around them do not."""
    frames = [_frame(0.0, 0x705, b"\x00"), _frame(0.001, 0x705, b"\x05")]
    emcys = {12: bytes([0x10, 0x81, 0x11, 0]), 13: bytes([0x00, 0x00, 0x00, 0]),
             15: b"", 16: bytes(8)}
    for k in range(20):
        t = 0.01 * (k + 1)
        if k == 10:
            frames.append(_frame(t, 0x080, b"\x03\x00"))
        elif k == 11:
            frames.append(_frame(t, 0x080, b"", rtr=True, dlc=0))
        else:
            frames.append(_frame(t, 0x080, bytes([k % 4 + 1])))
        if k in emcys:
            frames.append(_frame(t + 0.005, 0x085, emcys[k], rtr=k == 15))
    log = tmp_path / "bad.log"
    log.write_text("".join(candump_line(f) for f in frames))
    outcome = _replay(log, None, frames)
    _assert_offline_equals_live(outcome, log, None)
    assert [(lf.rule, lf.node, round(lf.time, 3)) for lf in outcome.live] == [
        ("Y002", None, 0.11), ("Y002", None, 0.12), ("E002", 5, 0.135), ("E002", 5, 0.165)]


def test_sync_recording_replayed_on_a_virtual_bus(tmp_path: Path) -> None:
    """sync_producer_stopped.log from 3.5 s to 4.3 s sent on a python-can virtual bus at
    its real timing, through `nmtcheck.Monitor` with the network file: the SYNC timeout is
    reported live within 100 ms of its expiry and confirmed by the check of the recording."""
    frames = frames_of(CN / "sync_emcy/sync_producer_stopped.log")
    t0 = frames[0].ts
    window = [f for f in frames if 3.5 <= f.ts - t0 <= 4.3]
    monitor, reported = replay_at_real_timing(
        window, f"sync-{id(tmp_path)}", network=CN / "sync_emcy/network_sync_stopped.toml")
    y001 = [lf for lf in monitor.live_findings() if lf.rule == "Y001"]
    # the stop's timeout, and any stall of a busy test machine during the replay (a real
    # SYNC gap of the replayed bus): each confirmed by the check of what was replayed
    assert y001 and all((lf.node, lf.confirmed) == (2, "confirmed") for lf in y001)
    for at, lf in ((t, lf) for t, lf in reported if lf.rule == "Y001"):
        assert 0 <= at - lf.time < 0.1, at - lf.time
    res = monitor.result()
    assert res is not None
    # (the window ends before the consumers' EMCY resets: E003, decided at the end)
    assert [f.rule for f in res.findings if f.rule in LIVE_COMM] == ["Y001"] * len(y001)


# -- the SPEC_COMM §9.5 vectors and the rule tests, replayed live -----------------------------

class LiveChecker(Checker):
    """`Checker` (tests/conftest.py) that also feeds each trace frame by frame to a live
    session with the same profile and network file, and notes where live and offline
    disagree: a certain live Y/D/E finding not confirmed, or an offline finding of a rule
    decided live that live did not report."""

    def __init__(self, tmp_path: Path) -> None:
        super().__init__(tmp_path)
        self.disagree: list[tuple[str, str, int | None, float, str]] = []
        self.compared = 0
        self.live_found = 0
        self.rules: set[str] = set()
        self.test = ""

    def run(self, text: str, select: str = "", ignore: str = "", profile: str = "default",
            network: str | None = None, suffix: str = ".log") -> InputResult:
        res = super().run(text, select, ignore, profile, network, suffix)
        if suffix != ".log" or select or ignore or res.stats.start is None:
            return res
        net = load_network(str(self.tmp_path / f"net{self.n}.toml")) if network else None
        prof = load_profile(profile)
        log = self.tmp_path / f"trace{self.n}{suffix}"
        session = Session(prof, select_rules(prof, [], []), net, timer=False)
        for frame in frames_of(log):
            session.feed(frame)
        outcome = session.close()
        self.compared += 1
        start = res.stats.start
        live = [lf for lf in outcome.live if lf.rule[0] in GROUPS]
        self.live_found += len(live)
        self.rules.update(lf.rule for lf in live)
        for lf in live:
            if lf.certain and lf.confirmed not in ("confirmed", "clock-only"):
                self.disagree.append((self.test, lf.rule, lf.node, round(lf.time - start, 6),
                                      f"live {lf.confirmed}"))
        for f in res.findings:
            if f.rule in LIVE_COMM and not any(
                    (lf.rule, lf.node) == (f.rule, f.node)
                    and abs(lf.time - f.time) <= CONFIRM_TOLERANCE_S for lf in live):
                self.disagree.append((self.test, f.rule, f.node, round(f.time - start, 6),
                                      "offline only"))
        return res


# (test, rule, node, seconds from the first frame, what) where live and offline disagree on
# the rule tests' traces; each with why
KNOWN_VECTORS: set[tuple[str, str, int | None, float, str]] = set()


def test_rule_vectors_replayed_live(tmp_path: Path) -> None:
    """Every test of tests/test_rules_sync_emcy.py and tests/test_rules_pdo.py that takes
    the `checker` fixture (and `tmp_path`): the §9.5 vectors verbatim, and the values from
    network file, device files and SDO writes; run again with each trace replayed live."""
    import inspect

    import test_rules_pdo
    import test_rules_sync_emcy

    checker = LiveChecker(tmp_path)
    ran = 0
    for module in (test_rules_sync_emcy, test_rules_pdo):
        for name, fn in sorted(vars(module).items()):
            if not name.startswith("test_") or not callable(fn):
                continue
            params = list(inspect.signature(fn).parameters)
            if params not in (["checker"], ["checker", "tmp_path"]):
                continue
            checker.test = name
            if params == ["checker"]:
                fn(checker)
            else:
                own = tmp_path / name
                own.mkdir()
                fn(checker, own)
            ran += 1
    assert ran > 40 and checker.compared > 80 and checker.live_found > 30
    assert checker.rules == LIVE_COMM  # every rule decided live fires on some trace
    assert set(checker.disagree) == KNOWN_VECTORS


@pytest.mark.parametrize(("name", "rule", "node"), [
    ("sync_emcy/sync_counter_skip", "Y003", 1), ("pdo/rpdo_producer_stopped", "D004", 3)])
def test_check_follow_reports_them_live(name: str, rule: str, node: int) -> None:
    """`nmtcheck check --follow -` (a process) fed the recording through a pipe, with its
    network file: the live line of the rule is on stderr, the end summary counts it as
    confirmed, and stdout is the offline check of the same bytes."""
    import json
    import subprocess
    import sys

    log = CN / f"{name}.log"
    net_path, _expected = RECORDINGS[name]
    proc = subprocess.run(
        [sys.executable, "-m", "nmtcheck", "check", "--follow", "-", "--network",
         str(net_path), "--format", "json", "--fail-on", "never"],
        input=log.read_bytes(), capture_output=True, timeout=120)
    err = proc.stderr.decode()
    assert proc.returncode == 0, err
    assert any(f" {rule} " in line and f"node {node}" in line for line in err.splitlines()
               if not line.startswith("nmtcheck:")), err
    assert "0 not confirmed" in err and "withdrawn" not in err, err
    offline = check_input(str(log), 0, PROFILE, RULES, load_network(str(net_path)))
    report = json.loads(proc.stdout)
    assert [(f["rule"], f["node"], f["time"]) for f in report["findings"]] == [
        (f.rule, f.node, round(f.time, 6)) for f in offline.findings]


def test_monitor_on_a_canopen_sync_producer_and_emcy(tmp_path: Path) -> None:
    """A python-canopen master producing SYNC every 50 ms (its SyncProducer) and two
    LocalNodes on a virtual bus, all OPERATIONAL; node 5 sends two EMCYs 2 ms apart
    (python-canopen's EmcyProducer has no inhibit time; the network file gives 1015h =
    500 ms, far above what a loaded machine can stretch a 2 ms sleep to, and the test
    reads the EMCYs' spacing from the recording), then the master stops its SYNC. Live:
    E001 at the second EMCY and Y001 at the last SYNC + 75 ms, reported within 100 ms of
    its expiry; both confirmed by the check of the recording, which has the same Y/E
    findings."""
    import canopen
    from test_live import _local_node

    net_file = tmp_path / "network.toml"
    net_file.write_text("[sync]\nperiod_us = 50000\n[nodes.5]\nemcy_inhibit_100us = 5000\n")
    channel = f"cosync-{id(tmp_path)}"
    master = canopen.Network()
    master.connect(interface="virtual", channel=channel)
    slaves = canopen.Network()
    slaves.connect(interface="virtual", channel=channel)
    bus = can.Bus(interface="virtual", channel=channel)
    record = tmp_path / "session.log"
    reported: list[tuple[float, LiveFinding]] = []
    monitor = nmtcheck.Monitor(network=net_file, record=record, channel="vcan0",
                               on_finding=lambda lf: reported.append((time.time(), lf)))
    notifier = can.Notifier(bus, [monitor])
    nodes = {n: _local_node(slaves, n) for n in (5, 6)}
    try:
        for node in nodes.values():
            node.nmt.state = "INITIALISING"  # boot-up 70N#00
            node.nmt.state = "PRE-OPERATIONAL"
            node.nmt.start_heartbeat(100)
        time.sleep(0.2)
        master.nmt.send_command(0x01)  # start all
        for node in nodes.values():
            node.nmt.state = "OPERATIONAL"
        master.sync.start(0.05)
        time.sleep(0.6)
        nodes[5].emcy.send(0x8130, 0x11)
        time.sleep(0.002)
        nodes[5].emcy.send(0x0000, 0x00)
        time.sleep(0.4)
        master.sync.stop()  # the fault: no SYNC while the consumers are OPERATIONAL
        time.sleep(0.3)
    finally:
        notifier.stop()
        monitor.stop()
        for node in nodes.values():
            node.nmt.stop_heartbeat()
        master.disconnect()
        slaves.disconnect()
        bus.shutdown()
    res = monitor.result()
    assert res is not None
    t0 = res.stats.start or 0.0
    syncs = [f for f in frames_of(record) if f.can_id == 0x080]
    assert len(syncs) > 15 and all(f.dlc == 0 for f in syncs)
    # ground truth: what the stack sent; the last SYNC before the stop + 1.5 x 50 ms
    last = syncs[-1].ts
    offline = [(f.rule, f.node, round(f.time - t0, 6)) for f in res.findings
               if f.rule[0] in GROUPS]
    assert ("Y001", None, round(last + 0.075 - t0, 6)) in offline
    emcys = [f.ts for f in frames_of(record) if f.can_id == 0x085]
    assert len(emcys) == 2 and emcys[1] - emcys[0] < 0.4, emcys  # inside the 500 ms
    assert [(r, n) for r, n, _t in offline if r == "E001"] == [("E001", 5)]
    live = [lf for lf in monitor.live_findings() if lf.rule[0] in GROUPS]
    # the same findings; live times carry the bus's full timestamps, the recording µs
    got = sorted((lf.rule, lf.node, lf.time - t0) for lf in live)
    assert [(r, n) for r, n, _t in got] == [(r, n) for r, n, _t in sorted(offline)]
    assert all(abs(a[2] - b[2]) < 2e-6 for a, b in zip(got, sorted(offline), strict=True))
    assert all(lf.confirmed == "confirmed" for lf in live), live
    at, y001 = next((t, lf) for t, lf in reported
                    if lf.rule == "Y001" and abs(lf.time - (last + 0.075)) < 2e-6)
    assert 0 <= at - y001.time < 0.1, at - y001.time


RANDOM_NETWORK = """master = 1
[sync]
period_us = 10000
window_us = 3000
producer = 1
counter_overflow = 4
[nodes.2]
heartbeat_ms = 100
emcy_inhibit_100us = 50
[nodes.2.tpdo.1]
cob_id = 0x182
transmission_type = 254
inhibit_100us = 20
event_timer_ms = 30
mapping = [0x20000020]
[nodes.2.tpdo.2]
cob_id = 0x282
transmission_type = 1
mapping = [0x20000020]
[nodes.3]
heartbeat_ms = 100
[nodes.3.rpdo.1]
cob_id = 0x182
transmission_type = 254
event_timer_ms = 40
mapping = [0x20000010]
"""


def _random_trace(seed: int) -> list[LiveFrame]:
    """Adversarial traffic for every live Y/D/E rule: SYNCs of any length and counter,
    PDOs of any length on configured streams, reports, NMT commands and resets, EMCYs of
    any length, confirmed writes of 1006h/1015h/1019h and reserved PDO types, remote
    frames, frames on the same instant."""
    import random

    rnd = random.Random(seed)
    t, out = 100.0, []
    for _ in range(rnd.randint(50, 400)):
        t += rnd.choice([0.0, 0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05])
        kind = rnd.random()
        if kind < 0.15:
            cid, data = 0x080, bytes([rnd.randint(0, 6)])[:rnd.choice([0, 1, 1, 1, 2])]
        elif kind < 0.35:
            cid, data = rnd.choice([0x182, 0x282]), bytes(rnd.choice([2, 4, 4, 4, 8]))
        elif kind < 0.5:
            cid, data = rnd.choice([0x701, 0x702, 0x703]), bytes([rnd.choice([0, 5, 5, 0x7F, 4])])
        elif kind < 0.6:
            cid, data = 0x000, bytes([rnd.choice([1, 2, 0x80, 0x81, 0x82]),
                                      rnd.choice([0, 1, 2, 3])])
        elif kind < 0.75:
            cid = rnd.choice([0x082, 0x083])
            data = bytes([rnd.choice([0, 0x50, 0x30]), rnd.choice([0, 0x82, 0x81]),
                          rnd.randint(0, 3), 0, 0, 0, 0, 0])[:rnd.choice([8, 8, 8, 4, 0])]
        elif kind < 0.85:
            n = rnd.choice([1, 2, 3])
            index = rnd.choice([0x1006, 0x1019, 0x1015, 0x1800, 0x1400])
            sub = 2 if index in (0x1800, 0x1400) else 0
            value = rnd.choice([5000, 10000, 20000, 4, 0, 100, 245, 1]).to_bytes(4, "little")
            out.append(_frame(t, 0x600 + n, bytes([0x23, index & 0xFF, index >> 8, sub])
                              + value))
            t += 0.0005
            cid, data = 0x580 + n, bytes([0x60, index & 0xFF, index >> 8, sub, 0, 0, 0, 0])
        else:
            cid, data = 0x080, b""
        if rnd.random() < 0.03:
            out.append(_frame(t, cid, b"", rtr=True, dlc=0))
        else:
            out.append(_frame(t, cid, data))
    return out


def test_random_traces_certain_live_findings_are_confirmed(tmp_path: Path) -> None:
    """On adversarial random traces, with the network file and without: the session's
    result is the offline check's, and every certain live Y/D/E finding is confirmed by it
    (a provisional one may be withdrawn or not confirmed: it says it may)."""
    net = tmp_path / "network.toml"
    net.write_text(RANDOM_NETWORK)
    network = load_network(str(net))
    counts: dict[tuple[bool, str], int] = {}
    for seed in range(30):
        frames = _random_trace(seed)
        log = tmp_path / f"t{seed}.log"
        log.write_text("".join(candump_line(f) for f in frames))
        for used in (network, None):
            outcome = _replay(log, used, frames)
            assert outcome.result is not None
            offline = check_input(str(log), 0, PROFILE, RULES, used)
            assert [(f.rule, f.node, f.time) for f in outcome.result.findings] == [
                (f.rule, f.node, f.time) for f in offline.findings]
            for lf in outcome.live:
                if lf.rule[0] in GROUPS:
                    key = (lf.certain, lf.confirmed)
                    counts[key] = counts.get(key, 0) + 1
    certain = {c: k for (sure, c), k in counts.items() if sure}
    assert set(certain) <= {"confirmed", "clock-only"}, counts
    assert certain["confirmed"] > 500 and counts.get((False, "confirmed"), 0) > 300, counts


def test_a_late_sync_withdraws_the_timeout_the_clock_fired(tmp_path: Path) -> None:
    """SYNC every 10 ms ([sync] period_us = 10000, limit 15 ms); the clock passes the
    deadline after the SYNC at 0.05 s and fires Y001; then a SYNC stamped 0.06 s (before
    the deadline, 0.065 s) arrives: it waited in a driver queue. The Y001 is withdrawn and
    the offline check of the recording, which has that SYNC in its place, has none."""
    net = tmp_path / "network.toml"
    net.write_text("[sync]\nperiod_us = 10000\n")
    wall = [0.0]
    withdrawn: list[LiveFinding] = []
    s = Session(PROFILE, RULES, load_network(str(net)), timer=False,
                clock=BusClock(lambda: wall[0]), on_withdraw=withdrawn.append)
    for k in range(6):
        wall[0] = 0.01 * k
        s.feed(_frame(0.01 * k, 0x080, b""))
    wall[0] = 0.065 + GRACE_S + 0.005
    s.tick()
    assert [(lf.rule, round(lf.time, 6)) for lf in s.live] == [("Y001", 0.065)]
    s.feed(_frame(0.06, 0x080, b""))
    s.feed(_frame(0.07, 0x080, b""))
    outcome = s.close()
    assert outcome.result is not None
    assert [f.rule for f in outcome.result.findings] == []
    assert [(lf.rule, lf.confirmed) for lf in outcome.live] == [("Y001", "withdrawn")]
    assert withdrawn == outcome.live
