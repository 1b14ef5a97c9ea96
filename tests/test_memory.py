"""Memory stays bounded as the log grows: the reader streams, the decoder's stores spill.

Peak RSS is measured on a child process (`os.wait4`: that child's own peak) that
checks generated candump logs of 1 M and 4 M frames of PDO traffic (a few
heartbeats, so the per-event timeline stays small and the streaming parts are
what is measured): four times the frames may not cost more than 20 % more memory.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO, candump

from nmtcheck.readers import open_input
from nmtcheck.spool import SCRATCH, ChunkStore, ColumnSpool, removed_on_exit
from nmtcheck.timeline.decode import decode


def write_pdo_log(path: Path, frames: int) -> None:
    """`(ts) can0 1XX#<8 bytes>` lines at 5 kHz, and a heartbeat of node 1 every second."""
    template = np.frombuffer(b"(1700000000.000000) can0 181#0011223344556677\n", np.uint8)
    with open(path, "wb") as out:
        for start in range(0, frames, 500_000):
            n = min(500_000, frames - start)
            i = np.arange(start, start + n, dtype=np.int64)
            us = 1_700_000_000 * 10**6 + i * 200
            rows = np.tile(template, (n, 1))
            digits = (us[:, None] // 10 ** np.arange(15, -1, -1)) % 10 + 48
            rows[:, 1:11] = digits[:, :10]
            rows[:, 12:18] = digits[:, 10:]
            cob = 0x180 + i % 16 + 1  # TPDO1 of nodes 1..16
            hexdigits = np.frombuffer(b"0123456789ABCDEF", np.uint8)
            for col, shift in ((25, 8), (26, 4), (27, 0)):
                rows[:, col] = hexdigits[cob >> shift & 15]
            hb = i % 5000 == 0  # node 1's heartbeat: shortened to `701#05` below
            rows[hb, 25:28] = np.frombuffer(b"701", np.uint8)
            text = rows.reshape(-1).tobytes()
            if hb.any():
                text = text.replace(b"701#0011223344556677", b"701#05")
            out.write(text)


# A child's peak RSS starts at its parent's RSS at fork (Linux keeps the high-water mark
# across exec), so the check runs under a small launcher process, never under pytest.
LAUNCHER = ("import os, subprocess, sys; p = subprocess.Popen(sys.argv[1:], "
            "stdout=subprocess.DEVNULL); _, st, ru = os.wait4(p.pid, 0); "
            "print(os.waitstatus_to_exitcode(st), ru.ru_maxrss)")


def peak_rss_mb(log: Path, *options: str) -> float:
    """Peak RSS of `nmtcheck check LOG OPTIONS` (default: the JSON report on stdout)."""
    out = subprocess.run(
        [sys.executable, "-c", LAUNCHER, sys.executable, "-m", "nmtcheck", "check", str(log),
         *(options or ("--format", "json")), "--fail-on", "never"],
        env=dict(os.environ, PYTHONPATH=str(REPO)), capture_output=True, text=True, check=True)
    code, kb = out.stdout.split()
    assert code == "0"
    return int(kb) / 1024


@pytest.mark.skipif(not hasattr(os, "wait4"), reason="needs os.wait4 (POSIX)")
def test_peak_memory_flat_as_the_log_grows(tmp_path: Path) -> None:
    small, large = tmp_path / "small.log", tmp_path / "large.log"
    write_pdo_log(small, 1_000_000)  # the decoder's in-memory budgets are full from here on
    write_pdo_log(large, 4_000_000)
    small_mb, large_mb = peak_rss_mb(small), peak_rss_mb(large)
    assert large_mb <= 1.2 * small_mb, (small_mb, large_mb)
    assert large_mb < 300


def test_chunk_store_spills_past_its_budget_and_reads_back() -> None:
    store = ChunkStore(budget=2500)  # each chunk is 2000 bytes: only the first stays in memory
    chunks: list[dict[str, np.ndarray]] = [
        {"ts": np.arange(k, k + 100, dtype=np.float64), "key": np.full(100, k, np.int32),
         "data": np.full((100, 8), k, np.uint8)} for k in range(5)]
    for c in chunks:
        store.append(**c)
    assert store.spilled == 4
    for got, want in zip(store, chunks, strict=True):
        for name in want:
            np.testing.assert_array_equal(got[name], want[name])
            assert got[name].dtype == want[name].dtype
    store.close()


def test_spills_go_below_the_scratch_directory_a_fleet_task_sets(tmp_path: Path) -> None:
    """A fleet task in a Dask worker sets SCRATCH to the worker's own directory, so that
    what a worker killed mid-log spilled is removed with that directory."""
    token = SCRATCH.set(str(tmp_path))
    try:
        spool = ColumnSpool({"ts": np.float64}, budget=100)
        for k in range(4):
            spool.append({"ts": np.arange(k, k + 50, dtype=np.float64)})
        spilled = [p for p in tmp_path.rglob("*") if p.is_file()]
        assert spilled and all(p.parent.parent == tmp_path for p in spilled)
        assert len(spool.column("ts")) == 200
        spool.close()
    finally:
        SCRATCH.reset(token)
    assert list(tmp_path.iterdir()) == []  # closed: its directory is gone


@pytest.mark.skipif(not hasattr(signal, "pthread_sigmask"), reason="POSIX signal masks")
def test_a_signal_does_not_cut_a_directory_removal_short(tmp_path: Path) -> None:
    """A second Ctrl-C while a directory of fetched logs was being removed left most of
    them behind: the signal now waits until the directory is gone."""
    tmp = tempfile.TemporaryDirectory(dir=tmp_path)
    for i in range(50):
        (Path(tmp.name) / f"copy{i}.log").write_bytes(b"x" * 1000)
    cleanup = tmp.cleanup

    def interrupted_cleanup() -> None:
        os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C as the removal begins
        cleanup()

    tmp.cleanup = interrupted_cleanup  # type: ignore[method-assign]
    # Python's own Ctrl-C handler (a test before may have run the CLI, which sets its own)
    handler = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt), removed_on_exit(tmp) as name:
            assert Path(name).is_dir()
    finally:
        signal.signal(signal.SIGINT, handler)
    assert list(tmp_path.iterdir()) == []


def test_chunk_store_skips_chunks_that_end_before_a_moment() -> None:
    store = ChunkStore(budget=1000)  # the later chunks spill: skipping must not read them
    for k in range(4):
        store.append(ts=np.arange(10.0 * k, 10.0 * k + 10), idx=np.arange(10) + 10 * k)
    assert [int(c["idx"][0]) for c in store.reaching(25.0)] == [20, 30]
    assert [int(c["idx"][0]) for c in store.reaching(-np.inf)] == [0, 10, 20, 30]
    store.close()


def test_column_spool_reads_back_what_was_appended_in_order() -> None:
    spool = ColumnSpool({"ts": np.float64, "key": np.int32}, budget=1000)
    parts = [{"ts": np.arange(k, k + 50, dtype=np.float64), "key": np.full(50, k)}
             for k in range(7)]  # 600 bytes each: several flushes to disk, a rest in memory
    for p in parts:
        spool.append(p)
    ts, key = spool.column("ts"), spool.column("key")
    np.testing.assert_array_equal(ts, np.concatenate([p["ts"] for p in parts]))
    np.testing.assert_array_equal(key, np.concatenate([p["key"] for p in parts]))
    assert key.dtype == np.int32
    spool.close()


def test_error_control_columns_group_by_node_in_file_order(tmp_path: Path) -> None:
    """Enough heartbeats to spill the error-control spool: the grouped columns still hold
    every frame, per node in file order."""
    # 150 000 frames = 4.8 MB of columns, past the spool's 4 MB budget
    frames = [(k * 0.01, f"7{k % 3 + 1:02X}#{k % 2 * 0x7A + 5:02X}") for k in range(150_000)]
    log = tmp_path / "hb.log"
    log.write_text(candump(frames))
    decoded = decode(open_input(str(log), None, False, None).batches)
    try:
        ec = decoded.ec
        assert len(ec["ts"]) == 150_000
        for node in (1, 2, 3):
            rows = decoded.ec_rows(node)
            idx = ec["idx"][rows]
            assert list(idx) == list(range(node - 1, 150_000, 3))
            np.testing.assert_allclose(ec["ts"][rows], 1000.0 + idx * 0.01, atol=1e-6)
            np.testing.assert_array_equal(ec["value"][rows], np.where(idx % 2, 0x7F, 0x05))
    finally:
        decoded.close()
