"""The text readers parse blocks in parallel: the result must not show it.

Parallel reading (blocks split into lines and parsed in a forked worker process, or on
worker threads where forking is not safe) must give exactly what serial reading
(NMTCHECK_THREADS=1) gives: the same batches (every column: frame indices, line numbers,
channel codes…) and the same InputStats (skips and their line numbers, ignored records,
drops, channels, time range). Blocks are made small here so that every file is many
blocks, and the parallel start threshold is zero so that the workers really run; each
test checks that they did.
"""

from __future__ import annotations

import dataclasses
import gzip
import os
import random
import threading
from collections.abc import Iterator
from pathlib import Path

import can
import numpy as np
import pytest
from conftest import CORPUS, SAMPLES

from nmtcheck.readers import InputStats, blocks, forked, open_input
from nmtcheck.readers.blocks import REFERENCE_ENV, THREADS_ENV
from nmtcheck.readers.frames import FrameBatch

THIRD = CORPUS / "third_party"
TEXT_LOGS = sorted(SAMPLES.glob("*.log")) + sorted(SAMPLES.glob("*.asc")) + (
    sorted(p for p in THIRD.rglob("*") if p.name.endswith((".log", ".asc", ".asc.gz"))
           or p.name in ("candump.gz", "gmlan_trace.candump.gz")) if THIRD.is_dir() else [])
FIELDS = [f.name for f in dataclasses.fields(FrameBatch)]
MODES = ["process", "threads"] if forked.available() else ["threads"]


@pytest.fixture(params=MODES)
def mode(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    """Each test runs with the worker process and with the thread fallback."""
    if request.param == "threads":
        monkeypatch.setattr(forked, "available", lambda: False)
    return str(request.param)


class ParseSites:
    """Records where blocks are split into lines (the first step of every parse job): the
    process and thread, in a file, so that a forked worker's blocks are seen too."""

    def __init__(self, mp: pytest.MonkeyPatch, log: Path) -> None:
        self.log = log
        log.write_text("")
        self.fd = os.open(log, os.O_WRONLY | os.O_APPEND)  # one write per block: atomic
        original = blocks._block

        def recording(chunk: blocks.Chunk) -> blocks.Block:
            os.write(self.fd, f"{os.getpid()} {threading.current_thread().name}\n".encode())
            return original(chunk)

        mp.setattr(blocks, "_block", recording)

    def clear(self) -> None:
        os.ftruncate(self.fd, 0)

    def sites(self) -> list[tuple[int, str]]:
        return [(int(pid), name) for pid, name in
                (line.split(" ", 1) for line in self.log.read_text().splitlines())]

    def workers(self) -> set[str]:
        """Where blocks were parsed other than on the reading thread: "process", "threads"."""
        return {"process" if pid != os.getpid() else "threads" for pid, name in self.sites()
                if pid != os.getpid() or name.startswith("nmtcheck-parse")}

    @property
    def worker_pids(self) -> set[int]:
        return {pid for pid, _ in self.sites() if pid != os.getpid()}


@pytest.fixture
def sites(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[ParseSites]:
    recorder = ParseSites(monkeypatch, tmp_path / "sites.txt")
    yield recorder
    os.close(recorder.fd)


Reading = tuple[InputStats, list[FrameBatch], set[str]]  # and where workers parsed


def read(path: Path, mp: pytest.MonkeyPatch, sites: ParseSites, threads: int,
         fmt: str | None = None, reference: bool = False) -> Reading:
    with mp.context() as m:
        m.setenv(THREADS_ENV, str(threads))
        m.setenv(REFERENCE_ENV, "1" if reference else "")
        m.setattr(blocks, "PARALLEL_BYTES", 0)
        sites.clear()
        opened = open_input(str(path), fmt)
        batches = list(opened.batches)
        return opened.stats, batches, sites.workers()


def assert_same(a: Reading, b: Reading) -> None:
    assert dataclasses.asdict(a[0]) == dataclasses.asdict(b[0])
    assert [len(batch) for batch in a[1]] == [len(batch) for batch in b[1]]
    for name in FIELDS:
        for x, y in zip(a[1], b[1], strict=True):
            np.testing.assert_array_equal(getattr(x, name), getattr(y, name), err_msg=name)
            assert getattr(x, name).dtype == getattr(y, name).dtype, name


def assert_parallel_reads_as_serial(path: Path, mp: pytest.MonkeyPatch, sites: ParseSites,
                                    mode: str, block_bytes: int, fmt: str | None = None,
                                    reference: bool = False) -> InputStats:
    """Parallel (in `mode`) == serial (and == the per-line reference path, if asked)."""
    mp.setattr(blocks, "BLOCK_BYTES", block_bytes)
    serial = read(path, mp, sites, 1, fmt)
    parallel = read(path, mp, sites, 2, fmt)
    assert serial[2] == set()
    if path.stat().st_size > 4 * block_bytes:
        assert parallel[2] == {mode}, "the workers never ran"
    assert_same(parallel, serial)
    if reference:
        assert_same(parallel, read(path, mp, sites, 2, fmt, reference=True))
    return serial[0]


@pytest.mark.parametrize("path", TEXT_LOGS, ids=lambda p: p.name)
def test_samples_and_corpus(path: Path, mode: str, sites: ParseSites,
                            monkeypatch: pytest.MonkeyPatch) -> None:
    assert_parallel_reads_as_serial(path, monkeypatch, sites, mode, 512)


def _messages(n: int, seed: int) -> list[can.Message]:
    """CANopen-like traffic on two channels: SYNC, PDOs, heartbeats, SDO, and now and then
    an extended, remote, error or FD frame (which the fast paths hand to the line parser)."""
    rnd = random.Random(seed)
    out = []
    t = 1700000000.0
    for i in range(n):
        t += rnd.choice((0.0001, 0.001, 0.0105))
        kind = rnd.random()
        chan = rnd.choice((0, 0, 0, 1))
        if kind < 0.02:
            msg = can.Message(timestamp=t, arbitration_id=0x1ABCDE0 + i % 7, is_extended_id=True,
                              data=bytes([i & 0xFF, 1, 2]), channel=chan)
        elif kind < 0.03:
            msg = can.Message(timestamp=t, arbitration_id=0x701 + i % 3, is_remote_frame=True,
                              dlc=1, channel=chan)
        elif kind < 0.035:
            msg = can.Message(timestamp=t, arbitration_id=0x4, is_error_frame=True, dlc=8,
                              data=bytes(8), channel=chan)
        elif kind < 0.04:
            msg = can.Message(timestamp=t, arbitration_id=0x181, is_fd=True,
                              data=bytes(range(12)), channel=chan)
        else:
            cob = rnd.choice((0x080, 0x181, 0x182, 0x201, 0x281, 0x581, 0x601, 0x701, 0x000))
            size = {0x080: 0, 0x701: 1, 0x000: 2}.get(cob, rnd.choice((8, 8, 4, 0)))
            msg = can.Message(timestamp=t, arbitration_id=cob,
                              data=bytes(rnd.randrange(256) for _ in range(size)), channel=chan)
        out.append(msg)
    return out


def _write(writer: can.io.generic.MessageWriter, msgs: list[can.Message]) -> None:
    with writer:
        for msg in msgs:
            writer.on_message_received(msg)


@pytest.fixture(scope="module")
def written_logs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A candump and an ASC log of 30 000 frames each, by python-can's own writers."""
    root = tmp_path_factory.mktemp("written")
    msgs = _messages(30_000, seed=7)
    paths = {"candump": root / "written.log", "asc": root / "written.asc"}
    _write(can.CanutilsLogWriter(str(paths["candump"]), channel="can0"), msgs)
    _write(can.ASCWriter(str(paths["asc"])), msgs)
    return paths


def _with_bad_lines(good: bytes, block_bytes: int, bad: list[bytes]) -> bytes:
    """`good` with a damaged line around every block boundary: lines end just before,
    on and just after it, so that bad lines are first, last or cut across blocks."""
    out = bytearray()
    lines = good.splitlines(keepends=True)
    rnd = random.Random(block_bytes)
    for line in lines:
        pos = len(out) % block_bytes
        if pos > block_bytes - 120 or pos < 40:
            out += rnd.choice(bad)
        out += line
    return bytes(out)


CANDUMP_BAD = [b"(1700000001.000000) can0 12#00\n", b"garbage\n", b"\n",
               b"(1700000001.000000) can0 123#0\n", b"DROPCOUNT: dropped 3\n",
               b"(1700000001.000000) vcan10 7FF#00112233\n",  # a new channel
               b"(x) can0 123#00\n", b"(1700000001.0) can0 1234#00\r\n"]
ASC_BAD = [b"   1.000000 1  12Z             Rx   d 1 00\n", b"garbage line\n", b"\n",
           b"   1.000000 3  123             Rx   d 8 00 11\n",
           b"   1.000000 7  701             Rx   d 1 05\n",  # a new channel
           b"// a comment\n", b"   1.000000 1  123             TxRq d 0\n",
           b"   1.000000 CANFD   1 Rx  123  1 0 8 8 11 22 33 44 55 66 77 88 0 0 1000 0 0 0 0 0\n"]


@pytest.mark.parametrize("fmt", ["candump", "asc"])
@pytest.mark.parametrize("block_bytes", [1000, 4096])
def test_multi_block_logs_written_by_python_can(written_logs: dict[str, Path], fmt: str,
                                                block_bytes: int, mode: str, sites: ParseSites,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    stats = assert_parallel_reads_as_serial(written_logs[fmt], monkeypatch, sites, mode,
                                            block_bytes, reference=block_bytes == 4096)
    assert stats.frames > 29_000  # python-can's writers keep (almost) every frame
    assert stats.extended > 0 and stats.remote_frames > 0 and stats.error_frames > 0


@pytest.mark.parametrize("block_bytes", [1000, 5000])
def test_bad_lines_at_block_boundaries(written_logs: dict[str, Path], tmp_path: Path,
                                       block_bytes: int, mode: str, sites: ParseSites,
                                       monkeypatch: pytest.MonkeyPatch) -> None:
    for fmt, bad in (("candump", CANDUMP_BAD), ("asc", ASC_BAD)):
        path = tmp_path / written_logs[fmt].name
        path.write_bytes(_with_bad_lines(written_logs[fmt].read_bytes(), block_bytes, bad))
        stats = assert_parallel_reads_as_serial(path, monkeypatch, sites, mode, block_bytes, fmt,
                                                reference=True)
        assert stats.skipped > 10 and len(stats.channels) >= 2


def test_asc_number_base_changes_midway(written_logs: dict[str, Path], tmp_path: Path,
                                        mode: str, sites: ParseSites,
                                        monkeypatch: pytest.MonkeyPatch) -> None:
    """Blocks parsed ahead in hex are read per line once `base dec` is in force, and the
    fast path comes back with `base hex`."""
    lines = written_logs["asc"].read_bytes().splitlines(keepends=True)
    third = len(lines) // 3
    lines.insert(2 * third, b"base hex  timestamps absolute\n")
    lines.insert(third, b"base dec  timestamps absolute\n")
    path = tmp_path / "switch.asc"
    path.write_bytes(b"".join(lines))
    stats = assert_parallel_reads_as_serial(path, monkeypatch, sites, mode, 4096, reference=True)
    assert stats.skipped > 0  # hex IDs and data read as decimal


def test_gzip_input(written_logs: dict[str, Path], tmp_path: Path, mode: str,
                    sites: ParseSites, monkeypatch: pytest.MonkeyPatch) -> None:
    for fmt in ("candump", "asc"):
        path = tmp_path / (written_logs[fmt].name + ".gz")
        path.write_bytes(gzip.compress(written_logs[fmt].read_bytes()))
        assert_parallel_reads_as_serial(path, monkeypatch, sites, mode, 4096)


def test_cut_off_gzip_input(written_logs: dict[str, Path], tmp_path: Path, mode: str,
                            sites: ParseSites, monkeypatch: pytest.MonkeyPatch) -> None:
    packed = gzip.compress(written_logs["candump"].read_bytes())
    path = tmp_path / "cut.log.gz"
    path.write_bytes(packed[: len(packed) * 2 // 3])
    stats = assert_parallel_reads_as_serial(path, monkeypatch, sites, mode, 4096)
    assert stats.truncated and stats.frames > 1000


def test_last_line_without_newline_and_long_lines(written_logs: dict[str, Path],
                                                  tmp_path: Path, mode: str, sites: ParseSites,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """The last line unterminated; lines longer than a block (carried over, too large for
    the worker's slot: parsed by the reading process)."""
    for fmt in ("candump", "asc"):
        lines = written_logs[fmt].read_bytes().splitlines(keepends=True)
        for at in (len(lines) // 4, len(lines) // 2):
            lines.insert(at, b"x" * 20_000 + b"\n")
        path = tmp_path / written_logs[fmt].name
        path.write_bytes(b"".join(lines).rstrip(b"\n"))
        monkeypatch.setattr(blocks, "CARRY_ROOM", 1024)
        assert_parallel_reads_as_serial(path, monkeypatch, sites, mode, 4096)


def test_small_inputs_and_threads_1_stay_serial(written_logs: dict[str, Path], mode: str,
                                                sites: ParseSites,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    path = written_logs["candump"]
    monkeypatch.setattr(blocks, "BLOCK_BYTES", 4096)
    for env, parallel_bytes in (("", path.stat().st_size), ("1", 0)):
        sites.clear()
        with monkeypatch.context() as m:
            m.setenv(THREADS_ENV, env)
            m.setattr(blocks, "PARALLEL_BYTES", parallel_bytes)
            list(open_input(str(path)).batches)
        assert len(sites.sites()) > 50 and sites.workers() == set()


def _long_log(written_logs: dict[str, Path], tmp_path: Path, copies: int = 10) -> Path:
    path = tmp_path / "long.log"
    path.write_bytes(written_logs["candump"].read_bytes() * copies)  # 10: 300 000 frames
    return path


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def test_stopping_early_ends_the_workers(written_logs: dict[str, Path], tmp_path: Path,
                                         mode: str, sites: ParseSites,
                                         monkeypatch: pytest.MonkeyPatch) -> None:
    """A consumer that stops after the first batch (the workers are busy then) leaves no
    worker thread or process behind."""
    monkeypatch.setattr(blocks, "BLOCK_BYTES", 65536)
    monkeypatch.setattr(blocks, "PARALLEL_BYTES", 0)
    monkeypatch.setenv(THREADS_ENV, "2")
    batches = open_input(str(_long_log(written_logs, tmp_path))).batches
    assert len(next(batches)) > 0
    assert sites.workers() == {mode}
    batches.close()
    assert not [t for t in threading.enumerate() if t.name.startswith("nmtcheck-parse")]
    assert not any(_alive(pid) for pid in sites.worker_pids)


def _failing_in_worker(mp: pytest.MonkeyPatch, fail: object) -> None:
    """Make the worker process fail (`fail(count)`) from its 3rd block on."""
    parent = os.getpid()
    original = blocks._block
    count = [0]

    def block(chunk: blocks.Chunk) -> blocks.Block:
        if os.getpid() != parent:
            count[0] += 1
            if count[0] >= 3:
                fail(count[0])  # type: ignore[operator]
        return original(chunk)

    mp.setattr(blocks, "_block", block)


def _raise(count: int) -> None:
    raise RuntimeError(f"block {count}")


@pytest.mark.skipif("process" not in MODES, reason="no worker process here")
@pytest.mark.parametrize("fail", [_raise, lambda count: os._exit(3)], ids=["raises", "dies"])
def test_a_failing_worker_process_changes_nothing(written_logs: dict[str, Path],
                                                  tmp_path: Path, fail: object,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """Blocks the worker could not parse (an exception, or the worker gone) are parsed by
    the reading process: the same result."""
    path = _long_log(written_logs, tmp_path, 3)
    monkeypatch.setattr(blocks, "BLOCK_BYTES", 65536)
    monkeypatch.setattr(blocks, "PARALLEL_BYTES", 0)
    monkeypatch.setenv(THREADS_ENV, "1")
    serial = open_input(str(path))
    serial_batches = list(serial.batches)
    monkeypatch.setenv(THREADS_ENV, "2")
    _failing_in_worker(monkeypatch, fail)
    parallel = open_input(str(path))
    assert_same((parallel.stats, list(parallel.batches), set()),
                (serial.stats, serial_batches, set()))
