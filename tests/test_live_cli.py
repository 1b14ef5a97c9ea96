"""`nmtcheck check --follow -` and `nmtcheck monitor` as processes: live lines while the
stream runs, complete reports after Ctrl-C, a bus that fails mid-session, a missing driver.

The monitor process listens on python-can's udp_multicast interface (a real bus
across processes on this machine); the bus-error test runs the command in this process
on a virtual bus that is shut down under it (what a USB adapter unplugged looks like to
python-can: the next recv raises).
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import can
import pytest

from nmtcheck.engine import check_input, select_rules
from nmtcheck.settings.profiles import load_profile

PROFILE = load_profile("default")
RULES = select_rules(PROFILE, [], [])


def _nmtcheck(*args: str, **kw: object) -> subprocess.Popen[bytes]:
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    kw.setdefault("stdin", subprocess.PIPE)
    proc: subprocess.Popen[bytes] = subprocess.Popen(  # type: ignore[call-overload]
        [sys.executable, "-m", "nmtcheck", *args], stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, env=env, **kw)
    return proc


class Lines(threading.Thread):
    """Collects a pipe's lines with their arrival (wall) time."""

    def __init__(self, pipe: object) -> None:
        super().__init__(daemon=True)
        self.pipe = pipe
        self.lines: list[tuple[float, str]] = []
        self.start()

    def run(self) -> None:
        for raw in iter(self.pipe.readline, b""):  # type: ignore[attr-defined]
            self.lines.append((time.time(), raw.decode()))

    def text(self) -> str:
        return "".join(t for _w, t in self.lines)


def _feed_heartbeats(proc: subprocess.Popen[bytes], sent: list[bytes], seconds: float,
                     node: int = 5, period: float = 0.05) -> float:
    """Heartbeats of `node` as candump -L lines in real time; the last one's timestamp."""
    ts = time.time()
    end = ts + seconds
    while ts < end:
        ts = time.time()
        line = f"({ts:.6f}) can0 {0x700 + node:03X}#05\n".encode()
        sent.append(line)
        assert proc.stdin is not None
        proc.stdin.write(line)
        proc.stdin.flush()
        time.sleep(period)
    return ts


def test_follow_pipe_live_then_the_full_check(tmp_path: Path) -> None:
    """A pipe fed in real time: the heartbeat timeout is on stderr while the stream still
    runs, within 100 ms of its expiry; at the end stdout is `check` of the same bytes."""
    proc = _nmtcheck("check", "--follow", "-", "--format", "json", "--fail-on", "never")
    err = Lines(proc.stderr)
    sent: list[bytes] = [b"(%.6f) can0 705#00\n" % time.time()]
    assert proc.stdin is not None
    proc.stdin.write(sent[0])
    last = _feed_heartbeats(proc, sent, 1.5)  # long enough for the process to start
    time.sleep(0.4)  # node 5 silent: 1.5 x 50 ms expires 75 ms after `last`
    live = [(w, t) for w, t in err.lines if "H001" in t]
    assert len(live) == 1, err.text()
    assert 0 < live[0][0] - (last + 0.075) < 0.1, live[0][0] - (last + 0.075)
    _feed_heartbeats(proc, sent, 0.2)
    proc.stdin.close()
    assert proc.stdout is not None
    out = proc.stdout.read()
    proc.wait(timeout=30)
    err.join(5)
    assert proc.returncode == 0, err.text()
    log = tmp_path / "fed.log"
    log.write_bytes(b"".join(sent))
    offline = check_input(str(log), 0, PROFILE, RULES)
    report = json.loads(out)
    assert [(f["rule"], f["node"], f["time"]) for f in report["findings"]] == [
        (f.rule, f.node, round(f.time, 6)) for f in offline.findings]
    assert ("H001", 5) in {(f.rule, f.node) for f in offline.findings}
    assert report["inputs"][0]["path"] == "<stdin>"
    assert "1 confirmed by the offline check" in err.text()


def test_follow_sigint_writes_complete_reports(tmp_path: Path) -> None:
    """Ctrl-C while the stream still runs: every -o report is complete, the exit code is
    check's (1: an error-level finding), no traceback."""
    report = tmp_path / "r.json"
    junit = tmp_path / "r.xml"
    proc = _nmtcheck("check", "--follow", "-", "-o", str(report), "-o", str(junit))
    err = Lines(proc.stderr)
    sent: list[bytes] = []
    _feed_heartbeats(proc, sent, 0.4)
    time.sleep(0.3)  # a timeout
    _feed_heartbeats(proc, sent, 0.1)
    deadline = time.time() + 20
    while not any("H001" in t for _w, t in err.lines) and time.time() < deadline:
        time.sleep(0.05)  # the process has read up to the timeout (it starts slowly)
    time.sleep(0.3)
    proc.send_signal(signal.SIGINT)
    proc.wait(timeout=30)
    err.join(5)
    assert proc.returncode == 1, err.text()
    assert "Traceback" not in err.text() and "interrupted (SIGINT)" in err.text()
    data = json.loads(report.read_text())
    assert [f["rule"] for f in data["findings"]] == ["H001"]
    assert junit.read_text().rstrip().endswith("</testsuites>")
    log = tmp_path / "fed.log"
    log.write_bytes(b"".join(sent))
    offline = check_input(str(log), 0, PROFILE, RULES)
    assert data["inputs"][0]["frames"] == offline.stats.frames == len(sent)
    assert [f["time"] for f in data["findings"]] == [round(f.time, 6) for f in offline.findings]


def test_follow_takes_one_log() -> None:
    proc = _nmtcheck("check", "--follow", "samples/healthy.log", "-",
                     cwd=Path(__file__).resolve().parent.parent)
    _out, err = proc.communicate(timeout=30)
    assert proc.returncode == 2
    assert err.decode().strip().splitlines() == [
        "nmtcheck: --follow reads one log as it grows: a file (as tail -F follows it) "
        "or - (standard input)"]


def test_follow_a_growing_file_as_tail_f(tmp_path: Path) -> None:
    """`check --follow FILE`: the file is read from its start and followed as it grows
    (the live timeout on stderr while it is still written), through a rotation (the name
    now another file); Ctrl-C ends it with check's report over every byte read."""
    log = tmp_path / "bus.log"
    report = tmp_path / "r.json"
    sent: list[bytes] = [b"(%.6f) can0 705#00\n" % time.time()]
    log.write_bytes(sent[0])
    proc = _nmtcheck("check", "--follow", str(log), "-o", str(report), "--fail-on", "never",
                     stdin=subprocess.DEVNULL)
    err = Lines(proc.stderr)

    def append(seconds: float, path: Path = log) -> None:
        ts = time.time()
        end = ts + seconds
        with path.open("ab") as f:
            while ts < end:
                ts = time.time()
                line = f"({ts:.6f}) can0 705#05\n".encode()
                sent.append(line)
                f.write(line)
                f.flush()
                time.sleep(0.05)

    append(1.5)
    time.sleep(0.4)  # node 5 silent: a heartbeat timeout while the file is still open
    deadline = time.time() + 20
    while not any("H001" in t for _w, t in err.lines) and time.time() < deadline:
        time.sleep(0.05)
    assert any("H001" in t for _w, t in err.lines), err.text()
    log.rename(tmp_path / "bus.log.1")  # rotated: a new file under the name
    append(0.3)
    time.sleep(0.5)
    assert proc.poll() is None  # a file does not end: it is followed until Ctrl-C
    proc.send_signal(signal.SIGINT)
    proc.wait(timeout=30)
    err.join(5)
    assert proc.returncode == 0, err.text()
    assert "Traceback" not in err.text() and "interrupted (SIGINT)" in err.text()
    data = json.loads(report.read_text())
    assert data["inputs"][0]["path"] == str(log)
    whole = tmp_path / "whole.log"
    whole.write_bytes(b"".join(sent))
    offline = check_input(str(whole), 0, PROFILE, RULES)
    assert data["inputs"][0]["frames"] == offline.stats.frames == len(sent)
    assert [(f["rule"], f["time"]) for f in data["findings"]] == [
        (f.rule, round(f.time, 6)) for f in offline.findings]
    assert [f["rule"] for f in data["findings"]] == ["H001"]


def test_follow_a_missing_file_is_an_input_error(tmp_path: Path) -> None:
    proc = _nmtcheck("check", "--follow", str(tmp_path / "none.log"), stdin=subprocess.DEVNULL)
    _out, err = proc.communicate(timeout=30)
    assert proc.returncode == 2
    assert "none.log: cannot read: No such file or directory" in err.decode()


def test_monitor_process_sigint(tmp_path: Path) -> None:
    """`nmtcheck monitor` on a udp_multicast bus: the finding is printed (plain lines: stdout
    is no terminal) while the session runs; Ctrl-C ends it with the reports and check's
    exit code; the reports equal `nmtcheck check --record`'s file."""
    port = random.randint(20000, 60000)
    record, report = tmp_path / "session.log", tmp_path / "session.json"
    proc = _nmtcheck("monitor", "-i", "udp_multicast", "-c", "239.74.163.2", "--bus-option",
                     f"port={port}", "--record", str(record), "-o", str(report),
                     "--format", "concise", stdin=subprocess.DEVNULL)
    out, err = Lines(proc.stdout), Lines(proc.stderr)
    deadline = time.time() + 30
    while not any("nmtcheck: monitoring" in t for _w, t in err.lines):
        assert time.time() < deadline and proc.poll() is None, err.text()
        time.sleep(0.05)
    bus = can.Bus(interface="udp_multicast", channel="239.74.163.2", port=port)
    try:
        bus.send(can.Message(arbitration_id=0x705, data=[0], is_extended_id=False))
        for _ in range(8):
            bus.send(can.Message(arbitration_id=0x705, data=[5], is_extended_id=False))
            time.sleep(0.1)
        silent_from = time.time()
        time.sleep(0.6)
        bus.send(can.Message(arbitration_id=0x705, data=[5], is_extended_id=False))
        time.sleep(0.3)
    finally:
        bus.shutdown()
    live_before_sigint = [(w, t) for w, t in out.lines if "H001" in t]
    proc.send_signal(signal.SIGINT)
    proc.wait(timeout=30)
    out.join(5)
    err.join(5)
    assert proc.returncode == 1, err.text()
    # the silence's timeout (150 ms after the last heartbeat) was printed while it lasted
    assert any("node 5  H001 heartbeat-timeout" in t and silent_from < w < silent_from + 0.6
               for w, t in live_before_sigint), (silent_from, live_before_sigint)
    assert "session ended: interrupted (SIGINT); 10 frames" in err.text()
    assert "Traceback" not in err.text()
    data = json.loads(report.read_text())
    offline = check_input(str(record), 0, PROFILE, RULES)
    assert [(f["rule"], f["node"], f["time"]) for f in data["findings"]] == [
        (f.rule, f.node, round(f.time, 6)) for f in offline.findings]
    assert "H001" in [f.rule for f in offline.findings]


def test_monitor_bus_error_mid_session(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    """The bus fails under the session (a virtual bus shut down, as an unplugged adapter):
    one line naming the channel, the reports of what was seen, exit 2."""
    from nmtcheck.cli import main as cli
    from nmtcheck.live import bus as live_bus

    channel = f"err-{id(tmp_path)}"
    real_open = live_bus.open_buses
    opened: list[tuple[str, can.BusABC]] = []

    def open_and_keep(*args: object, **kw: object) -> list[tuple[str, can.BusABC]]:
        opened.extend(real_open(*args, **kw))  # type: ignore[arg-type]
        return opened

    monkeypatch.setattr(live_bus, "open_buses", open_and_keep)
    tx = can.Bus(interface="virtual", channel=channel)

    def drive() -> None:
        while not opened:
            time.sleep(0.01)
        tx.send(can.Message(arbitration_id=0x703, data=[0], is_extended_id=False))
        for _ in range(6):
            tx.send(can.Message(arbitration_id=0x703, data=[5], is_extended_id=False))
            time.sleep(0.05)
        time.sleep(0.3)  # H001 of node 3
        tx.send(can.Message(arbitration_id=0x703, data=[5], is_extended_id=False))
        time.sleep(0.1)
        opened[0][1].shutdown()  # the adapter goes away

    report = tmp_path / "r.json"
    t = threading.Thread(target=drive)
    t.start()
    monkeypatch.setattr(sys, "argv", ["nmtcheck", "monitor", "-i", "virtual", "-c", channel,
                                      "--duration", "20", "-o", str(report),
                                      "--format", "json"])
    with pytest.raises(SystemExit) as exit_info:
        cli.main()
    t.join()
    tx.shutdown()
    assert exit_info.value.code == 2
    captured = capsys.readouterr()
    err = captured.err
    # next to a machine format the live lines go to stderr: stdout stays JSON
    assert json.loads(captured.out)["findings"][0]["rule"] == "H001"
    assert f"{channel} node 3  H001 heartbeat-timeout" in err
    assert err.splitlines()[-1] == (f"nmtcheck: {channel}: bus error: Cannot operate on a "
                                    f"closed bus")
    assert "session ended: bus error; 8 frames" in err
    data = json.loads(report.read_text())
    assert [(f["rule"], f["node"]) for f in data["findings"]] == [("H001", 3)]


@pytest.mark.parametrize("interface", ["no_such_interface", "pcan"])
def test_monitor_driver_missing(interface: str, tmp_path: Path) -> None:
    proc = _nmtcheck("monitor", "-i", interface, "-c", "PCAN_USBBUS1", "-o",
                     str(tmp_path / "r.json"), stdin=subprocess.DEVNULL)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 2
    lines = err.decode().strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(
        f"nmtcheck: --interface {interface} --channel PCAN_USBBUS1: "), lines
    assert not (tmp_path / "r.json").exists() and out == b""


def test_monitor_two_channels_duration(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    """Two channels (each its own CANopen network), --duration ends the session; node 5
    falls silent on one channel only; the recording holds both and `check` of it gives
    the report's findings."""
    from nmtcheck.cli import main as cli

    a, b = f"a-{id(tmp_path)}", f"b-{id(tmp_path)}"
    txa, txb = can.Bus(interface="virtual", channel=a), can.Bus(interface="virtual", channel=b)
    stop = threading.Event()

    def drive() -> None:
        time.sleep(0.3)  # the monitor opens its buses
        for bus in (txa, txb):
            bus.send(can.Message(arbitration_id=0x705, data=[0], is_extended_id=False))
        k = 0
        while not stop.is_set():
            txa.send(can.Message(arbitration_id=0x705, data=[5], is_extended_id=False))
            if k < 5:
                txb.send(can.Message(arbitration_id=0x705, data=[5], is_extended_id=False))
            k += 1
            time.sleep(0.05)

    record, report = tmp_path / "s.log", tmp_path / "s.json"
    t = threading.Thread(target=drive)
    t.start()
    monkeypatch.setattr(sys, "argv", [
        "nmtcheck", "monitor", "-i", "virtual", "-c", a, "-c", b, "--duration", "1.2",
        "--record", str(record), "-o", str(report), "--select", "H,B"])
    try:
        with pytest.raises(SystemExit) as exit_info:
            cli.main()
    finally:
        stop.set()
        t.join()
        txa.shutdown()
        txb.shutdown()
    assert exit_info.value.code == 1
    captured = capsys.readouterr()
    assert f"{b} node 5  H001 heartbeat-timeout" in captured.out
    assert "session ended: duration;" in captured.err
    data = json.loads(report.read_text())
    assert [(f["rule"], f["channel"], f["node"]) for f in data["findings"]] == [
        ("H001", b, 5)]
    offline = check_input(str(record), 0, PROFILE, select_rules(PROFILE, ["H", "B"], []))
    assert sorted(offline.stats.channels) == sorted([a, b])
    assert [(f.rule, f.channel, round(f.time, 6)) for f in offline.findings] == [
        (f["rule"], f["channel"], f["time"]) for f in data["findings"]]


@pytest.mark.parametrize(("args", "message"), [
    ([], "no --interface given, and no python-can configuration names one "
         "(~/.canrc, can.ini or $CAN_INTERFACE)"),
    (["-i", "virtual", "--bus-option", "foo"],
     "--bus-option foo: expected KEY=VALUE, e.g. --bus-option receive_own_messages=true"),
    (["-i", "virtual", "-o", "/nonexistent-dir/r.json"],
     "--output /nonexistent-dir/r.json: the directory does not exist"),
    (["-i", "virtual", "--record", "/nonexistent-dir/s.log"],
     "--record /nonexistent-dir/s.log: the directory does not exist"),
    (["-i", "virtual", "--record", "s.rec"],
     "--record s.rec: no log writer for this suffix (known: .asc, .blf, .csv, .db, .log, "
     ".mf4, .trc, .txt, each also .gz)"),
    (["-i", "virtual", "-c", "quiet", "--duration", "0.3"],
     "no frame received on quiet (duration)"),
])
def test_monitor_usage_errors(args: list[str], message: str, tmp_path: Path,
                              monkeypatch: pytest.MonkeyPatch,
                              capsys: pytest.CaptureFixture[str]) -> None:
    """Bad options fail before the session; a session that hears nothing is exit 2 too
    (as `check` of an empty log): one line, never a traceback."""
    from nmtcheck.cli import main as cli

    monkeypatch.chdir(tmp_path)
    monkeypatch.delenv("CAN_INTERFACE", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path))  # no ~/.canrc
    monkeypatch.setattr(sys, "argv", ["nmtcheck", "monitor", "--isolated", *args])
    with pytest.raises(SystemExit) as exit_info:
        cli.main()
    assert exit_info.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1] == f"nmtcheck: {message}"
