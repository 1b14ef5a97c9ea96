"""Live checking (nmtcheck/live/): the tracker against the offline check on the real-stack
samples, the candump recording, and `nmtcheck.Monitor` on python-can's virtual bus with a
python-canopen stack and a Lely recording replayed at its real timing.

Offline = online: every live finding must be among the offline check's findings of the
session's recording (same rule, channel, node; time within CONFIRM_TOLERANCE_S).
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can
import canopen
import pytest
from conftest import SAMPLES

import nmtcheck
from nmtcheck.engine import check_input, select_rules
from nmtcheck.live.frames import LiveFrame, candump_line
from nmtcheck.live.session import CONFIRM_TOLERANCE_S, BusClock, Session
from nmtcheck.live.tracker import LiveFinding
from nmtcheck.readers import InputStats
from nmtcheck.readers.candump import _parse_line
from nmtcheck.settings.network import load_network
from nmtcheck.settings.profiles import load_profile

PROFILE = load_profile("default")
RULES = select_rules(PROFILE, [], [])
# rules whose every offline finding the tracker must also have seen live, on these samples
LIVE_RULES = {"H001", "G001", "G002", "B001", "B002", "B003", "C001", "C002", "C003",
              "Y001", "Y002", "Y003", "Y004", "D001", "D002", "D004", "D005", "D006",
              "E001", "E002"}


def frames_of(path: Path) -> list[LiveFrame]:
    stats = InputStats(str(path))
    out = []
    with open(path, "rb") as f:
        for lineno, raw in enumerate(f, 1):
            row = _parse_line(raw, lineno, stats)
            if row is not None:
                ts, iface, cid, ext, rtr, err, fd, dlc, data = row
                out.append(LiveFrame(ts, iface.decode(), cid, ext, rtr, err, fd, dlc, data))
    return out


def replay_at_real_timing(window: list[LiveFrame], channel: str, **monitor_options: Any
                          ) -> tuple[nmtcheck.Monitor, list[tuple[float, LiveFinding]]]:
    """Send the frames on a python-can virtual bus at their recorded spacing to a
    `nmtcheck.Monitor` on the other end; the monitor and each finding with the wall time
    it was reported at."""
    tx = can.Bus(interface="virtual", channel=channel)
    rx = can.Bus(interface="virtual", channel=channel)
    reported: list[tuple[float, LiveFinding]] = []
    monitor = nmtcheck.Monitor(on_finding=lambda lf: reported.append((time.time(), lf)),
                               **monitor_options)
    notifier = can.Notifier(rx, [monitor])
    try:
        began = time.perf_counter()
        for f in window:
            delay = (f.ts - window[0].ts) - (time.perf_counter() - began)
            if delay > 0:
                time.sleep(delay)
            tx.send(can.Message(arbitration_id=f.can_id, data=f.data, is_remote_frame=f.rtr,
                                dlc=f.dlc, is_extended_id=False))
        time.sleep(0.02)
    finally:
        notifier.stop()
        monitor.stop()
        tx.shutdown()
        rx.shutdown()
    return monitor, reported


SAMPLE_LOGS = sorted([*SAMPLES.glob("canopen_master/*.log"), *SAMPLES.glob("lely/*.log"),
                      *SAMPLES.glob("lely/*/*.log"), *SAMPLES.glob("canopennode/*.log"),
                      *SAMPLES.glob("*.log")])


@pytest.mark.parametrize("with_network", [False, True], ids=["bare", "network"])
@pytest.mark.parametrize("path", SAMPLE_LOGS, ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_accelerated_replay_equals_offline(path: Path, with_network: bool, tmp_path: Path) -> None:
    """Every sample fed frame by frame (no timer: the next frame is the clock): the final
    result is `check` on the original log, each live finding is confirmed, and every
    offline finding of a live rule was reported live."""
    net = None
    if with_network:
        # the folder's network.toml, else the recording's own (lely/comm: network_NAME.toml)
        found = [f for f in (path.parent / "network.toml",
                             path.parent / f"network_{path.stem}.toml") if f.is_file()]
        if not found:
            pytest.skip(f"{path.parent.name}/{path.name} has no network file (LSS recordings)")
        net = load_network(str(found[0]))
    record = tmp_path / "session.log"
    session = Session(PROFILE, RULES, net, str(record), timer=False)
    for frame in frames_of(path):
        session.feed(frame)
    outcome = session.close()
    assert outcome.result is not None
    original = check_input(str(path), 0, PROFILE, RULES, net)
    key = [(f.rule, f.node, round(f.time, 6), f.message) for f in original.findings]
    assert [(f.rule, f.node, round(f.time, 6), f.message)
            for f in outcome.result.findings] == key
    # a provisional live finding (it rests on what only the whole trace settles: a period
    # measured so far, a file's producer time that a later SDO write voids) may be
    # withdrawn by the offline check; a certain one must be confirmed
    assert [lf for lf in outcome.live if lf.confirmed != "confirmed" and lf.certain] == []
    live = {(lf.rule, lf.node, round(lf.time, 3)) for lf in outcome.live}
    for f in original.findings:
        if f.rule in LIVE_RULES:
            assert any((f.rule, f.node) == (r, n) and abs(t - f.time) <= CONFIRM_TOLERANCE_S
                       for r, n, t in live), (f.rule, f.node, f.time, sorted(live))


def test_samples_give_live_findings() -> None:
    """The parametrised test above is not vacuous: the samples hold live findings of
    several rules."""
    rules = set()
    for path in SAMPLE_LOGS:
        s = Session(PROFILE, RULES, None, timer=False)
        for f in frames_of(path):
            s.feed(f)
        rules |= {lf.rule for lf in s.close().live}
    assert {"H001", "G002", "B001", "B002"} <= rules


def test_candump_line_round_trip(tmp_path: Path) -> None:
    """What the session records reads back as the same frames (RTR, extended, error, FD)."""
    frames = [LiveFrame(1.5, "can0", 0x705, dlc=1, data=b"\x05"),
              LiveFrame(1.6, "can0", 0x705, rtr=True),
              LiveFrame(1.7, "can0", 0x123, rtr=True, dlc=5),
              LiveFrame(1.8, "can1", 0x1ABCDEF, ext=True, dlc=2, data=b"\x01\x02"),
              LiveFrame(1.9, "can0", 0x80, err=True, dlc=8, data=bytes(8)),
              LiveFrame(2.0, "can0", 0x181, fd=True, dlc=12, data=bytes(range(12)))]
    path = tmp_path / "r.log"
    path.write_text("".join(candump_line(f) for f in frames))
    assert frames_of(path) == frames


def test_timer_fires_heartbeat_timeout_without_a_next_frame() -> None:
    """H001 at its expiry from the clock alone: no frame follows the last heartbeat."""
    wall = [100.0]
    clock = BusClock(lambda: wall[0])
    got: list[LiveFinding] = []
    s = Session(PROFILE, RULES, None, timer=False, clock=clock, on_finding=got.append)
    for i in range(5):
        wall[0] = 100.0 + i * 0.1
        s.feed(LiveFrame(10.0 + i * 0.1, "can0", 0x705, dlc=1, data=b"\x05"))
    wall[0] = 100.4 + 0.14  # 1.5 x 0.1 s not yet over (plus the grace)
    s.tick()
    assert got == []
    wall[0] = 100.4 + 0.15 + 0.02
    s.tick()
    assert [(lf.rule, lf.node, round(lf.time, 6)) for lf in got] == [("H001", 5, 10.55)]
    assert s.nodes()[0].state == "OFFLINE"
    outcome = s.close()
    assert outcome.live[0].confirmed == "clock-only"  # the recording ends at 10.4 s


# -- python-can virtual bus: python-canopen stack and Monitor ------------------------------


def _local_node(network: canopen.Network, node_id: int) -> canopen.LocalNode:
    od = canopen.ObjectDictionary()
    var = canopen.objectdictionary.ODVariable("Producer heartbeat time", 0x1017)
    var.data_type = canopen.objectdictionary.UNSIGNED16
    var.default = 0
    var.access_type = "rw"
    od.add_object(var)
    node = canopen.LocalNode(node_id, od)
    network.add_node(node)
    return node


def test_monitor_on_canopen_stack(tmp_path: Path) -> None:
    """A python-canopen master and three LocalNodes on a virtual bus; node 3 stops its
    heartbeat, node 2 reboots on its own, node 4 answers a reset by heartbeating 00h.
    Monitor's live findings are confirmed by `nmtcheck check` of its recording, and
    H001 is reported within 100 ms of expiry."""
    channel = f"live-{id(tmp_path)}"
    master = canopen.Network()
    master.connect(interface="virtual", channel=channel)
    slaves = canopen.Network()
    slaves.connect(interface="virtual", channel=channel)
    bus = can.Bus(interface="virtual", channel=channel)
    reported: list[tuple[float, LiveFinding]] = []
    record = tmp_path / "session.log"
    monitor = nmtcheck.Monitor(record=record, channel="vcan0",
                               on_finding=lambda lf: reported.append((time.time(), lf)))
    notifier = can.Notifier(bus, [monitor])
    try:
        nodes = {n: _local_node(slaves, n) for n in (2, 3, 4)}
        for node in nodes.values():
            node.nmt.state = "INITIALISING"  # boot-up 70N#00
            node.nmt.state = "PRE-OPERATIONAL"
            node.nmt.start_heartbeat(100)
        time.sleep(0.5)
        master.nmt.send_command(0x01)  # start all
        for node in nodes.values():
            node.nmt.state = "OPERATIONAL"
        time.sleep(0.5)
        nodes[3].nmt.stop_heartbeat()  # the fault: node 3 falls silent
        time.sleep(0.6)
        nodes[2].nmt.stop_heartbeat()  # node 2 reboots without a reset command
        nodes[2].nmt.state = "INITIALISING"
        nodes[2].nmt.state = "PRE-OPERATIONAL"
        nodes[2].nmt.start_heartbeat(100)
        time.sleep(0.3)
        master.send_message(0x000, bytes([0x81, 4]))  # reset node 4: python-canopen's
        time.sleep(0.4)  # LocalNode then heartbeats 00h (a boot-up) every period
    finally:
        notifier.stop()
        monitor.stop()  # before the heartbeats stop: that is no fault of the network
        for node in nodes.values():
            node.nmt.stop_heartbeat()
        master.disconnect()
        slaves.disconnect()
        bus.shutdown()
    live = monitor.live_findings()
    assert {(lf.rule, lf.node) for lf in live} == {("H001", 3), ("B002", 2), ("B003", 4)}, live
    assert all(lf.confirmed == "confirmed" for lf in live), live
    offline = check_input(str(record), 0, PROFILE, RULES)
    assert [(f.rule, f.node, f.time) for f in monitor.findings()] == [
        (f.rule, f.node, f.time) for f in offline.findings]
    assert monitor.findings(severity="error", rule="H001")[0].node == 3
    # latency: wall time of the report minus the expiry (virtual-bus timestamps are wall time)
    (at, h001), = [(t, lf) for t, lf in reported if lf.rule == "H001"]
    latency = at - h001.time
    assert 0 <= latency < 0.1, latency
    tl = monitor.timeline()
    assert [iv.state for iv in tl[(channel, 3)]][-1] == "OFFLINE"


def test_monitor_thread_safe_reads_while_feeding(tmp_path: Path) -> None:
    """findings(), timeline() and report() while the Notifier's thread feeds: no error,
    and what is read is a consistent check of a prefix of the traffic."""
    channel = f"ts-{id(tmp_path)}"
    tx = can.Bus(interface="virtual", channel=channel)
    rx = can.Bus(interface="virtual", channel=channel)
    monitor = nmtcheck.Monitor(channel="vcan0")
    notifier = can.Notifier(rx, [monitor])
    stop = threading.Event()

    def send() -> None:  # a 2 ms heartbeat: the check runs beside it
        tx.send(can.Message(arbitration_id=0x706, data=[0], is_extended_id=False))
        while not stop.is_set():
            tx.send(can.Message(arbitration_id=0x706, data=[5], is_extended_id=False))
            time.sleep(0.002)

    t = threading.Thread(target=send)
    t.start()
    try:
        counts = []
        for _ in range(10):
            res = monitor.result()
            counts.append(res.stats.frames if res else 0)
            # the text report names only nodes with findings: the JSON one lists them all
            assert res is None or '"node": 6' in monitor.report("json")
            assert all(f.node == 6 for f in monitor.findings())  # H001/H002 from jitter
            time.sleep(0.02)
    finally:
        stop.set()
        t.join()
        notifier.stop()
        monitor.stop()
        tx.shutdown()
        rx.shutdown()
    assert counts == sorted(counts) and counts[-1] > 20
    final = monitor.result()
    assert final is not None and final.stats.skipped == 0 and final.stats.frames > counts[-1]


def test_lely_recording_replayed_at_real_timing(tmp_path: Path) -> None:
    """samples/lely/unplugged_heartbeat.log from 4.5 s to 7.05 s, sent on a virtual bus at
    its real timing: node 3's heartbeat timeout (1.5 x 100 ms without the network file) and
    its missing boot-up after the master's reset are reported live, confirmed by the
    offline check of the recording, H001 within 100 ms of its expiry.

    (With the network file the master's own 300 ms timeout and its reset of node 3 fall
    on the same 0.1 ms: re-timed by the replay, the reset may come first, and then
    neither the live nor the offline check has an H001. Both agree either way.)"""
    frames = frames_of(SAMPLES / "lely" / "unplugged_heartbeat.log")
    t0 = frames[0].ts
    window = [f for f in frames if 4.5 <= f.ts - t0 <= 7.05]
    monitor, reported = replay_at_real_timing(window, f"lely-{id(tmp_path)}")
    live = [(lf.rule, lf.node, lf.confirmed) for lf in monitor.live_findings()]
    # notifier.stop() takes up to 0.5 s: heartbeats stopped meanwhile are timeouts after
    # the last recorded frame, stated as such (no offline check can see them)
    assert [x for x in live if x[2] != "clock-only"] == [
        ("H001", 3, "confirmed"), ("B001", 3, "confirmed")], live
    res = monitor.result()
    assert res is not None
    start = res.stats.start or 0.0
    h001 = next(f for f in res.findings if f.rule == "H001")
    # the original has it at 5.05 s: 0.55 s into the window
    assert abs((h001.time - start) - (5.051 - (window[0].ts - t0))) < 0.03
    at, lf = next((t, lf) for t, lf in reported if lf.rule == "H001")
    assert 0 <= at - lf.time < 0.1, at - lf.time


def test_late_frame_withdraws_a_clock_timeout() -> None:
    """The clock fired H001, then a heartbeat stamped before the timeout's moment arrives
    (it waited in a driver queue longer than the grace): the finding is withdrawn, the
    node is back, and the offline check agrees there was no timeout."""
    wall = [100.0]
    withdrawn: list[LiveFinding] = []
    s = Session(PROFILE, RULES, None, timer=False, clock=BusClock(lambda: wall[0]),
                on_withdraw=withdrawn.append)
    for i in range(5):
        wall[0] = 100.0 + i * 0.1
        s.feed(LiveFrame(10.0 + i * 0.1, "can0", 0x705, dlc=1, data=b"\x05"))
    wall[0] = 100.4 + 0.2
    s.tick()
    assert [lf.rule for lf in s.live] == ["H001"] and s.nodes()[0].state == "OFFLINE"
    s.feed(LiveFrame(10.54, "can0", 0x705, dlc=1, data=b"\x05"))  # stamped before 10.55
    assert withdrawn == s.live and s.nodes()[0].state == "OPERATIONAL"
    assert s.nodes()[0].findings == 0
    outcome = s.close()
    assert outcome.result is not None and outcome.result.findings == []
    assert [lf.confirmed for lf in outcome.live] == ["withdrawn"]


def test_clock_offset_forgets_an_old_maximum() -> None:
    """An adapter clock that runs slow against the host: the offset follows it instead of
    keeping the oldest, largest one (timeouts would fire early)."""
    wall = [0.0]
    clock = BusClock(lambda: wall[0])
    clock.observe(1000.0)
    for k in range(1, 40):
        wall[0] = float(k)
        clock.observe(1000.0 + k - 0.001 * k)  # 1000 ppm slow
    assert clock.offset is not None and abs(clock.offset - (1000.0 - 0.039)) < 0.012


def test_display_plain_lines_and_terminal_table() -> None:
    """Not a terminal: one line per finding, no escape codes. A terminal: the node table
    under the lines, redrawn in place."""
    import io

    from nmtcheck.live.display import Display

    lf = LiveFinding("H001", "heartbeat-timeout", "error", "can0", 5, 12.402,
                     "no heartbeat from node 5")
    plain = io.StringIO()
    d = Display(plain)
    d.start = 0.0
    d.refresh([], 13.0)
    d.finding(lf)
    assert plain.getvalue() == ("   12.402 s  can0 node 5  H001 heartbeat-timeout  "
                                "no heartbeat from node 5\n")
    s = Session(PROFILE, RULES, None, timer=False)
    s.feed(LiveFrame(12.0, "can0", 0x705, dlc=1, data=b"\x05"))
    tty = io.StringIO()
    d = Display(tty, table=True)
    d.start = 12.0
    d.refresh(s.nodes(), 12.25)
    d.finding(lf)
    d.refresh(s.nodes(), 12.5)
    s.close()
    out = tty.getvalue()
    assert out.count("\x1b[2F\x1b[J") == 2  # the two-line table cleared before each redraw
    assert out.rstrip().endswith("can0          5  OPERATIONAL            0.500 s  0")
    assert "no heartbeat from node 5" in out


# -- the pytest fixture recipe of docs/guides/benches.md, as written there ------------------


@pytest.fixture
def device() -> Iterator[canopen.LocalNode]:
    """The device under test: a python-canopen node on the bench's bus."""
    network = canopen.Network()
    network.connect(interface="virtual", channel="bench")
    node = _local_node(network, 7)
    yield node
    node.nmt.stop_heartbeat()
    network.disconnect()


@pytest.fixture
def nmt_monitor(tmp_path: Path) -> Iterator[nmtcheck.Monitor]:
    """Every test that uses it fails on an error-level NMT finding during the test.
    Request it after the device fixtures: it then ends before they stop the devices."""
    bus = can.Bus(interface="virtual", channel="bench")  # the bench's bus, e.g. pcan
    monitor = nmtcheck.Monitor(record=tmp_path / "nmt.log")
    notifier = can.Notifier(bus, [monitor])
    yield monitor
    monitor.stop()  # first: what the bus does after the test is not the test's
    notifier.stop()
    bus.shutdown()
    assert monitor.errors == []
    errors = monitor.findings(severity="error")
    assert errors == [], monitor.report("concise")


def test_fixture_recipe_healthy_device(device: canopen.LocalNode,
                                       nmt_monitor: nmtcheck.Monitor) -> None:
    """A python-canopen device that boots, is started and heartbeats: the fixture finds
    nothing; the report and the timeline are there for the test to look at."""
    device.nmt.state = "INITIALISING"
    device.nmt.state = "PRE-OPERATIONAL"
    device.nmt.start_heartbeat(50)
    device.network.nmt.send_command(0x01)
    device.nmt.state = "OPERATIONAL"
    time.sleep(0.4)
    report = json.loads(nmt_monitor.report("json"))
    assert [n["node"] for n in report["nodes"]] == [7]
    assert report["findings"] == []
    assert [iv.state for iv in nmt_monitor.timeline()[("bench", 7)]][-1] == "OPERATIONAL"


def test_monitor_keeps_a_bus_error_and_what_came_before(tmp_path: Path) -> None:
    """The Notifier's bus fails mid-test (shut down under it): the Monitor keeps the error
    in `errors` (the Notifier raises it to no one, and goes on failing: the first ten are
    kept, all counted) and everything received before it is still checked."""
    channel = f"gone-{id(tmp_path)}"
    tx = can.Bus(interface="virtual", channel=channel)
    rx = can.Bus(interface="virtual", channel=channel)
    monitor = nmtcheck.Monitor()
    notifier = can.Notifier(rx, [monitor], timeout=0.05)
    try:
        tx.send(can.Message(arbitration_id=0x703, data=[0], is_extended_id=False))
        for _ in range(4):
            tx.send(can.Message(arbitration_id=0x703, data=[5], is_extended_id=False))
            time.sleep(0.05)
        time.sleep(0.05)
        rx.shutdown()  # the adapter goes away
        time.sleep(0.2)
    finally:
        notifier.stop()
        monitor.stop()
        tx.shutdown()
    assert monitor.errors[0] == "CanOperationError: Cannot operate on a closed bus"
    assert len(monitor.errors) <= 10 and monitor.error_count >= len(monitor.errors)
    res = monitor.result()
    assert res is not None and res.stats.frames == 5


@pytest.mark.parametrize(("suffix", "writer"), [
    (".blf", can.BLFReader), (".asc", can.ASCReader), (".trc", can.TRCReader),
    (".log", can.CanutilsLogReader), (".asc.gz", None)])
def test_record_writer_follows_the_suffix(suffix: str, writer: type | None,
                                          tmp_path: Path) -> None:
    """`monitor --record rec.blf` writes a BLF file (python-can's writer for the suffix, as
    `can.Logger` chooses), which `nmtcheck check` reads to the same findings; the report
    names the recording kept."""
    record = tmp_path / f"rec{suffix}"
    s = Session(PROFILE, RULES, None, str(record), timer=False)
    source = SAMPLES / "healthy.log"
    for frame in frames_of(source):
        s.feed(frame)
    outcome = s.close()
    assert outcome.result is not None and outcome.result.stats.path == str(record)
    assert not Path(s.path).exists() or s.path == str(record)  # no candump left beside it
    if writer is None:
        import gzip

        with gzip.open(record) as f:
            assert f.read(4) == b"date"
        return
    got = list(writer(str(record)))
    assert len(got) == outcome.result.stats.frames
    if suffix in (".blf", ".asc", ".log"):  # formats nmtcheck reads
        again = check_input(str(record), 0, PROFILE, RULES)
        assert [(f.rule, f.node, round(f.time, 3)) for f in again.findings] == [
            (f.rule, f.node, round(f.time, 3)) for f in outcome.result.findings]


def test_a_timeout_inside_a_recording_gap_is_named_as_such(tmp_path: Path) -> None:
    """Nodes 2 and 5 beat every 100 ms; the whole channel is silent from 10.3 s to 11.5 s.
    Live, both heartbeat timeouts ran out in that silence; offline it is one
    I007 and no H001 (SPEC §3): the summary names it as inside a recording gap, not as
    unconfirmed."""
    from nmtcheck.live.display import live_summary

    lines = [f"({10 + k / 10:.6f}) can0 70{n}#05" for k in range(4) for n in (2, 5)]
    lines += [f"({11.5 + k / 10:.6f}) can0 70{n}#05" for k in range(4) for n in (2, 5)]
    log = tmp_path / "gap.log"
    log.write_text("\n".join(lines) + "\n")
    profile = load_profile("default")
    session = Session(profile, select_rules(profile, [], []), None, timer=False)
    for frame in frames_of(log):
        session.feed(frame)
    outcome = session.close()
    assert outcome.result is not None
    assert [f.rule for f in outcome.result.findings] == ["I007"]
    gap = [lf for lf in outcome.live if lf.rule == "H001"]
    assert {lf.node for lf in gap} == {2, 5}
    assert all(lf.confirmed == "recording-gap" for lf in gap)
    text = live_summary(outcome, "end of file")
    assert f"{len(gap)} inside a recording gap (I007)" in text
    assert "inside a silence the offline check reads as a recording gap (I007)" in text


def test_a_session_never_closed_leaves_no_recording_behind(tmp_path: Path,
                                                           monkeypatch: pytest.MonkeyPatch
                                                           ) -> None:
    """The temporary recording of a session without `record` goes with the session
    even when nobody closes it (a program that forgot to, a Monitor refused after its
    session began): such files piled up in the temporary directory."""
    import gc
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    s = Session(PROFILE, RULES, None, timer=False)
    s.feed(LiveFrame(1.0, "can0", 0x705, dlc=1, data=b"\x00"))
    assert [p.name for p in tmp_path.iterdir()] == [Path(s.path).name]
    del s
    gc.collect()
    assert list(tmp_path.iterdir()) == []
    closed = Session(PROFILE, RULES, None, timer=False)  # closed: removed at once, once
    closed.close()
    assert list(tmp_path.iterdir()) == []
