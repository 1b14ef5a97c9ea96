"""Issue 24, round 3 of the outside stress run: timestamps no recorder writes (item 4),
hostile names in every text-like output (items 5 and 11), the line splitter of
`check --follow -` (item 3), 29-bit and error frames on the vectorised path (item 7),
many channels in the candump reader, the live monitor under overload (item 8), fleet
workers whose driver dies (item 6), overlapping fleet runs (item 9)."""

from __future__ import annotations

import csv
import io
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import REPO, SAMPLES, read_columns, run_cli

from nmtcheck.readers import MAX_LINE_BYTES, OVERLONG_LINE
from nmtcheck.safe_text import dumps_finite, escape_controls

ENV = {**os.environ, "PYTHONPATH": str(REPO)}
INJECTION = "\n::error file=x.c,line=1::pwned\n::add-mask::secret\n::stop-commands::t0k\n"
RAW_CONTROLS = ("\x00", "\x07", "\x1b", "\r", "\x85", "\u2028")


def _strict_json(text: str) -> object:
    def no_constant(name: str) -> object:
        raise ValueError(f"non-finite number {name} in the report")

    return json.loads(text, parse_constant=no_constant)


# -- item 4: timestamps candump never writes ---------------------------------------------------

def _heartbeats_with(stamps: list[str]) -> str:
    lines = [f"({1_700_000_000 + i * 0.1:.6f}) can0 705#05" for i in range(30)]
    for k, stamp in enumerate(stamps):
        lines.insert(5 + 4 * k, f"({stamp}) can0 705#05")
    return "\n".join(lines) + "\n"


BAD_STAMPS = ["1e308", "-1", "-1.000000", "inf", "nan", "1E5", "+5.0", "1_000.0",
              "1000000000000.000000", "99999999999999999999999.5"]


@pytest.mark.parametrize("reference", ["0", "1"])
def test_stamps_candump_never_writes_are_skipped_records(tmp_path: Path, reference: str,
                                                         monkeypatch: pytest.MonkeyPatch
                                                         ) -> None:
    monkeypatch.setenv("NMTCHECK_REFERENCE", reference)
    log = tmp_path / "ts.log"
    log.write_text(_heartbeats_with(BAD_STAMPS))
    stats, cols = read_columns(log)
    assert stats.frames == 30 and stats.skipped == len(BAD_STAMPS), stats
    assert bool(((cols["ts"] >= 1.7e9) & (cols["ts"] < 1.8e9)).all())
    assert stats.backwards_timestamps == 0


def test_no_report_holds_a_non_finite_number(tmp_path: Path) -> None:
    (tmp_path / "ts.log").write_text(_heartbeats_with(["1e308", "-1"]))
    for fmt in ("json", "sarif", "html"):
        res = subprocess.run([sys.executable, "-W", "error::RuntimeWarning", "-m", "nmtcheck",
                              "check", "ts.log", "--format", fmt], cwd=tmp_path,
                             capture_output=True, text=True, env=ENV, timeout=120)
        assert res.returncode in (0, 1), res.stderr
        assert "Warning" not in res.stderr, res.stderr
        if fmt != "html":  # (the page's script has `-Infinity` of its own)
            _strict_json(res.stdout)
    text = run_cli("check", "ts.log", cwd=tmp_path).stdout
    assert "skipped records: 2" in text and " inf " not in text and "nan" not in text


def test_dumps_finite_and_dataset_rows_never_hold_inf() -> None:
    doc = {"a": float("inf"), "b": [1.5, float("-inf"), {"c": float("nan")}], "d": "x"}
    assert _strict_json(dumps_finite(doc)) == {"a": None, "b": [1.5, None, {"c": None}],
                                               "d": "x"}
    from nmtcheck.fleet.dataset import to_table

    row = {"url": "u", "channel": "can0", "node": 5, "first_seen": float("-inf"),
           "hb_p50_ms": float("inf"), "worst_gap_at": float("nan"), "last_seen": 2.0}
    table = to_table("node_stats", [row]).to_pylist()[0]
    assert table["first_seen"] is None and table["hb_p50_ms"] is None
    assert table["worst_gap_at"] is None and table["last_seen"] == 2.0


# -- items 5 and 11: hostile names in every text-like output -----------------------------------

def _assert_inert(text: str, where: str) -> None:
    for line in text.splitlines():
        assert not line.lstrip().startswith("::"), (where, line)
    for ch in RAW_CONTROLS:
        assert ch not in text, (where, repr(ch))


def _mcap_heartbeats(topic: str) -> bytes:
    from mcap.writer import Writer

    out = io.BytesIO()
    writer = Writer(out)
    writer.start()
    channel = writer.register_channel(topic, "json", 0)
    t = 1_700_000_000 * 10**9
    for i in range(20):
        stamp = t + (i * 100 if i < 10 else 2000 + i * 100) * 10**6
        payload = json.dumps({"can_id": 0x705, "data": "05", "dlc": 1}).encode()
        writer.add_message(channel, log_time=stamp, publish_time=stamp, data=payload)
    writer.finish()
    return out.getvalue()


HUMAN = ("text", "concise", "markdown", "csv")


def test_a_hostile_topic_injects_nothing(tmp_path: Path) -> None:
    (tmp_path / "evil.mcap").write_bytes(_mcap_heartbeats("/can" + INJECTION + "\x00\x1b[2J"))
    for fmt in HUMAN:
        res = run_cli("check", "evil.mcap", "--format", fmt, cwd=tmp_path)
        assert res.returncode == 1, (fmt, res.stderr)
        _assert_inert(res.stdout, fmt)
        if fmt != "concise":  # (which names the channel only where an input has several)
            assert "\\x0a::error file=x.c" in res.stdout, (fmt, res.stdout)
        _assert_inert(res.stderr, fmt)


def test_a_hostile_file_name_and_channel_inject_nothing(tmp_path: Path) -> None:
    name = "run" + INJECTION.replace("/", "_") + "\x07.log"
    evil_iface = "ca\x1b]0;owned\x07n\x7f0"
    (tmp_path / name).write_text((SAMPLES / "heartbeat_loss.log").read_text()
                                 .replace(" can0 ", f" {evil_iface} "))
    for fmt in HUMAN:
        res = run_cli("check", "--format", fmt, "--", name, cwd=tmp_path)
        assert res.returncode == 1, (fmt, res.stderr)
        _assert_inert(res.stdout, fmt)
        assert "\\x0a::error file=x.c" in res.stdout, (fmt, res.stdout)
        if fmt != "concise":
            assert "\\x1b]0;owned\\x07" in res.stdout.replace("\\\\", "\\"), (fmt, res.stdout)
        if fmt == "csv":
            rows = list(csv.DictReader(io.StringIO(res.stdout)))
            assert rows and all("\x1b" not in v for r in rows for v in r.values())
    # error messages: a file that is not there, and one that is no log
    for bad in ("missing" + INJECTION + ".log", "nolog" + INJECTION + ".log"):
        if bad.startswith("nolog"):
            (tmp_path / bad).write_bytes(b"\x1b[31m nothing here \x07\n")
        res = run_cli("check", "--", bad, cwd=tmp_path)
        assert res.returncode == 2
        _assert_inert(res.stderr, "stderr")
        _assert_inert(res.stdout, "stdout")


def test_live_lines_and_node_table_are_escaped() -> None:
    from nmtcheck.live.display import Display
    from nmtcheck.live.tracker import LiveFinding, NodeState
    from nmtcheck.timeline.model import NodeConfig

    out = io.StringIO()
    display = Display(out, table=True)
    lf = LiveFinding("H001", "heartbeat-timeout", "error", "can0" + INJECTION + "\x1b[2J", 5,
                     1.0, "no heartbeat on " + "can0" + INJECTION)
    display.finding(lf)
    display.withdrawn(lf)
    display.note("nmtcheck: " + INJECTION)
    display.refresh([NodeState("c\x1b[1An" + INJECTION, 5, NodeConfig())], 1.0)
    text = out.getvalue().replace("\x1b[J", "").replace("\x1b[", "CSI")
    # the table redraw's own cursor moves are the only escapes, and only at a line start
    _assert_inert(text.replace("\x1b", ""), "live")
    assert "CSI2J" not in text and "\\x1b[2J" in text


def test_escape_controls_keeps_ordinary_text() -> None:
    for text in ("can0", "Kanal ä/ü €", "node 5: 0.150 s", "a\\b", "–…"):
        assert escape_controls(text) == text
    assert escape_controls("a\nb\tc\x00\x1b\x9b\u202e") == "a\\x0ab\\x09c\\x00\\x1b\\x9b\\u202e"


# -- item 3: one line splitter, with a cap, on every input path --------------------------------

def test_follow_reads_a_long_line_in_linear_time(tmp_path: Path) -> None:
    from nmtcheck.readers import split_lines

    pieces = [b"x" * 65536] * 320 + [b"\n(1700000000.000000) can0 705#05\n"]  # a 20 MB line
    began = time.perf_counter()
    lines = list(split_lines(iter(pieces)))
    assert time.perf_counter() - began < 2.0
    assert lines == [OVERLONG_LINE, b"(1700000000.000000) can0 705#05\n"]
    assert list(split_lines(iter([b"a\nb", b"c\r\n", b"", b"d"]))) == [b"a\n", b"bc\r\n", b"d"]
    exact = b"y" * (MAX_LINE_BYTES - 1) + b"\n"
    assert list(split_lines(iter([exact[:5], exact[5:]]))) == [exact]


def test_check_follow_of_a_40_mb_line_is_one_skipped_record(tmp_path: Path) -> None:
    head = (SAMPLES / "healthy.log").read_bytes()
    data = head + b"(" + b"7" * (40 << 20) + b"\n" + head
    began = time.perf_counter()
    res = subprocess.run([sys.executable, "-m", "nmtcheck", "check", "--follow", "-",
                          "--format", "json"], input=data, capture_output=True, env=ENV,
                         timeout=120, cwd=tmp_path)
    took = time.perf_counter() - began
    assert res.returncode in (0, 1), res.stderr
    report = _strict_json(res.stdout.decode())
    assert isinstance(report, dict)
    assert report["inputs"][0]["skipped"] >= 1
    assert took < 30, took


# -- item 7 and the channel dimension: the vectorised candump path ----------------------------

def _wide_log(path: Path, n: int) -> None:
    lines = []
    for i in range(n):
        t = f"({1_700_000_000 + i / 1000:.6f})"
        kind = i % 6
        if kind == 0:
            lines.append(f"{t} can0 {0x18FEF100 + i % 256:08X}#{i % 65536:04X}00000000FFFF")
        elif kind == 1:
            lines.append(f"{t} can0 {0x20000004 | (i % 7) << 8:08X}#0000080000000000")
        elif kind == 2:
            lines.append(f"{t} can1 {0x0CF00400 + i % 9:08x}#{i % 256:02x}")
        elif kind == 3:
            lines.append(f"{t} can0 {0xC0000000 | i:08X}#")  # flag bits above 29: dropped
        elif kind == 4:
            lines.append(f"{t} can0 705#05")
        else:
            lines.append(f"{t} can1 {0x1FFFFFFF:08X}#0102030405060708 R")
    path.write_text("\n".join(lines) + "\n")


def test_29_bit_and_error_frames_take_the_vectorised_path(tmp_path: Path,
                                                          monkeypatch: pytest.MonkeyPatch
                                                          ) -> None:
    from nmtcheck.readers import candump

    log = tmp_path / "wide.log"
    _wide_log(log, 6000)
    monkeypatch.setenv("NMTCHECK_REFERENCE", "1")
    ref_stats, ref = read_columns(log)
    monkeypatch.setenv("NMTCHECK_REFERENCE", "0")
    monkeypatch.setenv("NMTCHECK_THREADS", "1")
    calls = []
    real = candump._parse_line

    def counted(*args: object, **kw: object) -> object:
        calls.append(args[0])
        return real(*args, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(candump, "_parse_line", counted)
    stats, fast = read_columns(log)
    assert calls == []  # not one line through the per-line parser
    for name, col in ref.items():
        assert (col == fast[name]).all(), name
    assert (stats.frames, stats.extended, stats.error_frames, stats.channels) == (
        ref_stats.frames, ref_stats.extended, ref_stats.error_frames, ref_stats.channels)
    assert stats.extended == 4000 and stats.error_frames == 1000


def test_many_channels_read_in_linear_time(tmp_path: Path) -> None:
    def write(n: int) -> Path:
        log = tmp_path / f"c{n}.log"
        log.write_text("".join(f"({1_700_000_000 + i / 1000:.6f}) c{i} 705#00\n"
                               for i in range(n))
                       + "".join(f"({1_700_000_100 + i / 1000:.6f}) c{i} 185#01\n"
                                 for i in range(n)))
        return log

    took = {}
    for n in (2_000, 40_000):
        log = write(n)
        began = time.perf_counter()
        stats, cols = read_columns(log)
        took[n] = time.perf_counter() - began
        assert stats.frames == 2 * n and len(stats.channels) == n
        assert stats.channels[:3] == ["c0", "c1", "c2"]
        assert (cols["chan"][:n] == cols["chan"][n:]).all()
    # 20 times the channels: far from 400 times the time (quadratic took 16 s and 2.4 GB)
    assert took[40_000] < 5.0 and took[40_000] < 60 * max(took[2_000], 0.02), took


# -- item 6: fleet workers end when their driver dies, however it dies -------------------------

def _session_members(sid: int) -> list[int]:
    out = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            stat = Path(f"/proc/{entry}/stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()
        if int(fields[3]) == sid and fields[0] != "Z":  # session id; zombies have ended
            out.append(int(entry))
    return out


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_kill_9_of_the_driver_ends_every_worker(tmp_path: Path) -> None:
    pytest.importorskip("pyarrow")
    logs = tmp_path / "logs"
    logs.mkdir()
    body = "".join(f"({1_700_000_000 + i / 100:.6f}) can0 705#05\n" for i in range(150_000))
    for k in range(24):
        (logs / f"log{k:02d}.log").write_text(body)
    temp = tmp_path / "temp"
    temp.mkdir()
    driver = subprocess.Popen([sys.executable, "-m", "nmtcheck", "check", "logs/*.log",
                               "--results", "results", "--isolated", "--executor", "local:2"],
                              cwd=tmp_path, env={**ENV, "TMPDIR": str(temp)},
                              start_new_session=True,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    def pool_dirs() -> list[str]:
        return [p.name for p in temp.iterdir() if p.name.startswith("nmtcheck-workers-")]

    try:
        deadline = time.monotonic() + 60
        while (len(_session_members(driver.pid)) < 4 or not pool_dirs()) and (
                time.monotonic() < deadline):
            time.sleep(0.05)  # the driver, the fork server, its workers and their directory
        assert len(_session_members(driver.pid)) >= 4, "the workers never started"
        time.sleep(0.3)
        driver.kill()
        assert driver.wait() == -9  # killed in the middle of the run, not ended by itself
        deadline = time.monotonic() + 20
        while _session_members(driver.pid) and time.monotonic() < deadline:
            time.sleep(0.1)
        left = _session_members(driver.pid)
        assert not left, [Path(f"/proc/{p}/cmdline").read_bytes()[:120] for p in left]
        assert not pool_dirs()  # the workers removed it: the killed driver could not
        # and the driver's multiprocessing directory (pymp-*, the fork server's socket):
        # nothing of the run is left in the temporary directory (issue 39, item 6)
        assert not sorted(p.name for p in temp.iterdir())
    finally:
        for pid in _session_members(driver.pid):
            os.kill(pid, 9)


# -- item 9: one fleet run at a time per dataset; rows without their commit record go ---------

def test_a_second_run_into_a_locked_dataset_is_refused_and_orphans_go(tmp_path: Path) -> None:
    pytest.importorskip("pyarrow")
    import nmtcheck as api
    from nmtcheck.fleet.dataset import Dataset

    logs = tmp_path / "logs"
    logs.mkdir()
    for name in ("healthy.log", "heartbeat_loss.log"):
        (logs / name).write_bytes((SAMPLES / name).read_bytes())
    ds = Dataset(str(tmp_path / "results"))
    ds.ensure()
    held = ds.lock()  # another run, as far as the command line can tell
    try:
        res = run_cli("check", "logs/*.log", "--results", "results", "--isolated",
                      cwd=tmp_path)
        assert res.returncode == 2 and "one run at a time" in res.stderr, res.stderr
        assert "\n" not in res.stderr.strip()
    finally:
        held.close()
    # a batch that wrote findings but never its inputs file (killed, a full disk)
    ds.write("findings", "part-orphan", [{"date": "2023-11-14", "input_id": "x",
                                          "batch_id": "orphan", "url": "gone.log",
                                          "rule": "H001", "time": 1.0}])
    res = run_cli("check", "logs/*.log", "--results", "results", "--isolated", cwd=tmp_path)
    assert res.returncode == 1, res.stderr
    assert not list((tmp_path / "results").rglob("part-orphan.parquet"))
    import pyarrow.dataset as pads

    raw = pads.dataset(str(tmp_path / "results" / "findings"), format="parquet").to_table()
    data = api.read_results(tmp_path / "results")
    assert raw.num_rows == len(data.findings) > 0  # the raw table: no row the API hides


# -- item 8: the live monitor under overload ---------------------------------------------------

def test_an_overloaded_session_drops_counts_says_so_and_stays_bounded(tmp_path: Path) -> None:
    from nmtcheck.engine import select_rules
    from nmtcheck.live.frames import LiveFrame
    from nmtcheck.live.session import Session
    from nmtcheck.settings.profiles import load_profile

    profile = load_profile("default")
    notes: list[int] = []
    session = Session(profile, select_rules(profile, [], []), None, str(tmp_path / "rec.log"),
                      timer=False, on_overload=notes.append, queue_frames=500)
    slow = session.tracker.feed

    def slow_feed(frame: LiveFrame) -> None:
        time.sleep(0.00002)
        slow(frame)

    session.tracker.feed = slow_feed  # type: ignore[method-assign,assignment]
    sent = 60_000
    deepest = 0
    for i in range(sent):
        session.submit(LiveFrame(1_700_000_000 + i * 0.0001, "can0", 0x705, data=b"\x05",
                                 dlc=1))
        deepest = max(deepest, len(session._queue))
    outcome = session.close()
    assert deepest <= 500
    assert outcome.dropped > 0 and notes and notes[0] <= outcome.dropped
    res = outcome.result
    assert res is not None
    assert res.stats.frames + outcome.dropped == sent  # every frame checked or counted
    assert res.stats.dropped == outcome.dropped
    i004 = [f for f in res.findings if f.rule == "I004"]
    assert len(i004) == 1 and f"{outcome.dropped} frames" in i004[0].message
    recording = (tmp_path / "rec.log").read_text()
    assert "DROPCOUNT: dropped" in recording


def test_a_monitor_that_keeps_up_drops_nothing_and_answers_at_once() -> None:
    import can

    import nmtcheck

    monitor = nmtcheck.Monitor()
    for i in range(2000):
        monitor.on_message_received(can.Message(timestamp=1_700_000_000 + i * 0.01,
                                                arbitration_id=0x705, data=[5],
                                                is_extended_id=False))
    res = monitor.result()  # everything handed over before the call is in it
    assert res is not None and res.stats.frames == 2000 and monitor.dropped == 0
    monitor.stop()
