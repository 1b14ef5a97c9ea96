"""ASAM MF4 bus-logging reader, compared frame by frame with python-can's MF4Reader.

The CSS Electronics CANedge files of the shared corpus hold data frames only;
remote and error frames come from files written here with python-can's
MF4Writer (CAN_DataFrame, CAN_RemoteFrame and CAN_ErrorFrame groups).
"""

from __future__ import annotations

import dataclasses
import gzip
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import can
import numpy as np
import pytest
from conftest import CORPUS, REPO, needs_corpus

from nmtcheck.errors import InputError
from nmtcheck.readers import InputStats, detect_format, mf4, open_input
from nmtcheck.readers.frames import FrameBatch

pytest.importorskip("asammdf")

THIRD = CORPUS / "third_party"
CSS = "css-electronics"
# (frames, extended, channels, start, end): PROVENANCE frame counts (python-can 4.6.1)
CORPUS_MF4 = {
    f"{CSS}/17BD1DB7_00000006_00000170.MF4": (2010, 0, ["1"], 1608041699.3265, 1608041998.3428),
    f"{CSS}/2F6913DB_00000004_00000001.MF4": (5588, 0, ["1", "2"], 1641469561.9497,
                                              1641469625.4197),
    f"{CSS}/FCBF0606_00003482_00000001-60B621D9.MF4": (1815, 1815, ["1", "2"], 1622547830.084,
                                                       1622548016.2046),
}


def read(path: Path, **kw: Any) -> tuple[InputStats, dict[str, np.ndarray]]:
    opened = open_input(str(path), **kw)
    batches = list(opened.batches)
    names = [f.name for f in dataclasses.fields(FrameBatch)]
    return opened.stats, {n: np.concatenate([getattr(b, n) for b in batches]) for n in names}


def ours(stats: InputStats, cols: dict[str, np.ndarray]) -> list[tuple[Any, ...]]:
    return [(float(cols["ts"][i]), stats.channels[int(cols["chan"][i])],
             int(cols["can_id"][i]), bool(cols["ext"][i]), bool(cols["rtr"][i]),
             bool(cols["err"][i]), bool(cols["fd"][i]), int(cols["dlc"][i]),
             bytes(cols["data"][i, : min(int(cols["dlc"][i]), 8)]) if not cols["rtr"][i]
             else b"") for i in range(len(cols["ts"]))]


def python_can(path: Path) -> list[tuple[Any, ...]]:
    """python-can's reading in the same shape (error frames: never extended, as ours)."""
    return [(m.timestamp, str(m.channel), m.arbitration_id,
             m.is_extended_id and not m.is_error_frame, m.is_remote_frame, m.is_error_frame,
             m.is_fd, m.dlc, b"" if m.is_remote_frame else bytes(m.data[:8]))
            for m in can.LogReader(str(path))]


def assert_same(a: list[tuple[Any, ...]], b: list[tuple[Any, ...]]) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        assert x[0] == pytest.approx(y[0], abs=1e-9), (x, y)
        assert x[1:] == y[1:], (x, y)


@needs_corpus
@pytest.mark.parametrize("rel", sorted(CORPUS_MF4))
def test_canedge_files_match_python_can(rel: str) -> None:
    stats, cols = read(THIRD / rel)
    frames, ext, channels, start, end = CORPUS_MF4[rel]
    assert (stats.format, stats.frames, stats.extended, stats.channels, stats.skipped,
            stats.remote_frames, stats.error_frames) == ("mf4", frames, ext, channels, 0, 0, 0)
    assert stats.start == pytest.approx(start, abs=1e-6)
    assert stats.end == pytest.approx(end, abs=1e-6)
    assert (cols["line"] == 0).all() and cols["index"].tolist() == list(range(frames))
    assert_same(ours(stats, cols), python_can(THIRD / rel))


@needs_corpus
def test_unfinalised_canedge_file() -> None:
    """17BD1DB7…170.MF4 is "UnFinMF": still read, by content, whatever its suffix says."""
    path = THIRD / f"{CSS}/17BD1DB7_00000006_00000170.MF4"
    head = path.read_bytes()[:64]
    assert head.startswith(b"UnFinMF ")
    assert detect_format(head) == "mf4"
    _stats, cols = read(path)
    assert set(cols["can_id"].tolist()) == {0x7EC, 0x7BB}


T0 = 1_700_000_000.0


def _messages() -> list[can.Message]:
    msgs = []
    for i in range(300):
        t = T0 + i * 0.01
        chan = 1 + i % 2
        kind = i % 6
        if kind == 0:
            msgs.append(can.Message(timestamp=t, arbitration_id=0x700 + chan, data=b"\x05",
                                    is_extended_id=False, channel=chan))
        elif kind == 1:
            msgs.append(can.Message(timestamp=t, arbitration_id=0x704, is_remote_frame=True,
                                    dlc=1, is_extended_id=False, channel=chan))
        elif kind == 2:
            msgs.append(can.Message(timestamp=t, arbitration_id=0x18DAF110 + i,
                                    data=bytes([i % 256, 2]), is_extended_id=True, channel=chan))
        elif kind == 3:
            msgs.append(can.Message(timestamp=t, is_error_frame=True, arbitration_id=0x4,
                                    is_extended_id=False, channel=chan))
        elif kind == 4:
            msgs.append(can.Message(timestamp=t, arbitration_id=0x123, data=bytes(range(12)),
                                    is_fd=True, is_extended_id=False, channel=chan))
        else:
            msgs.append(can.Message(timestamp=t, arbitration_id=0x185,
                                    data=bytes(range(i % 9)), is_extended_id=False,
                                    channel=chan))
    return msgs


def write_mf4(path: Path, msgs: list[can.Message]) -> None:
    writer = can.MF4Writer(str(path))
    for msg in msgs:
        writer.on_message_received(msg)
    writer.stop()


@pytest.fixture(scope="module")
def written(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("mf4") / "written.mf4"
    write_mf4(path, _messages())
    return path


def test_data_remote_and_error_groups(written: Path) -> None:
    stats, cols = read(written)
    assert (stats.frames, stats.remote_frames, stats.error_frames, stats.fd_frames,
            stats.extended) == (300, 50, 50, 50, 50)
    assert stats.channels == ["1", "2"]
    assert_same(ours(stats, cols), python_can(written))
    # merged by time from three groups, as written
    expected = [(m.timestamp, str(m.channel), m.arbitration_id) for m in _messages()]
    got = [(t, c, i) for t, c, i, *_rest in ours(stats, cols)]
    assert [g[1:] for g in got] == [e[1:] for e in expected]
    remote = cols["rtr"]
    assert cols["dlc"][remote].tolist() == [1] * 50
    assert not cols["data"][remote].any()


def test_compressed_mf4_is_spooled(written: Path, tmp_path: Path,
                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """asammdf needs a seekable file: a gzip MF4 is decompressed to a temporary file, which
    is removed afterwards."""
    packed = tmp_path / "written.mf4.gz"
    packed.write_bytes(gzip.compress(written.read_bytes()))
    spool = tmp_path / "spool"
    spool.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(spool))
    made: list[str] = []
    mkstemp = tempfile.mkstemp

    def recording_mkstemp(*args: Any, **kw: Any) -> tuple[int, str]:
        fd, name = mkstemp(*args, **kw)
        made.append(name)
        return fd, name

    monkeypatch.setattr(tempfile, "mkstemp", recording_mkstemp)
    _a, ca = read(written)
    assert made == []  # a plain file on disk is read in place
    b, cb = read(packed)
    assert b.format == "mf4"
    for name in ca:
        np.testing.assert_array_equal(ca[name], cb[name], err_msg=name)
    assert len(made) == 1 and Path(made[0]).parent.parent == spool
    assert list(spool.iterdir()) == []


def test_a_damaged_unfinalised_file_leaves_no_copy(written: Path, tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """asammdf copies an unfinalised MF4 (CANedge writes them) whole to a temporary file
    before it reads it, and left that copy behind when the file was damaged: 10 cut-off
    CANedge files left 10 copies in /tmp. Its temporary files now go to a directory of
    the read's, removed however the read ends."""
    data = bytearray(written.read_bytes())
    data[0:8] = b"UnFinMF "
    data[60:62] = (1).to_bytes(2, "little")  # id_unfin_flags: asammdf copies the file first
    cut = tmp_path / "cut.mf4"
    cut.write_bytes(bytes(data[: len(data) // 2]))
    spool = tmp_path / "spool"
    spool.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(spool))
    with pytest.raises(InputError) as exc:
        read(cut)
    assert str(exc.value).startswith(f"{cut}: cannot read MF4 file (cut off or damaged?)")
    assert list(spool.iterdir()) == []


def test_mdf_without_can_groups(tmp_path: Path) -> None:
    from asammdf import MDF, Signal

    path = tmp_path / "signals.mf4"
    mdf = MDF(version="4.10")
    mdf.append([Signal(np.arange(5.0), np.arange(5.0), name="speed")])
    mdf.save(str(path), overwrite=True)
    mdf.close()
    with pytest.raises(InputError) as exc:
        list(open_input(str(path)).batches)
    assert "no CAN bus-logging groups" in str(exc.value)


def test_without_asammdf_the_install_command_is_named(written: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "asammdf", None)  # import asammdf -> ImportError
    with pytest.raises(InputError) as exc:
        list(open_input(str(written)).batches)
    assert str(exc.value) == (f"{written}: reading MF4 needs the optional asammdf package: "
                              "pip install '.[mf4]' in the nmtcheck checkout")


def test_without_asammdf_the_command_exits_2(written: Path, tmp_path: Path) -> None:
    code = ("import sys; sys.modules['asammdf'] = None; from nmtcheck.cli.main import main; "
            f"sys.argv = ['nmtcheck', 'check', {str(written)!r}]; main()")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=tmp_path, env=env, timeout=120)
    assert res.returncode == 2, res.stdout + res.stderr
    assert res.stderr.strip().splitlines() == [
        f"nmtcheck: {written}: reading MF4 needs the optional asammdf package: "
        "pip install '.[mf4]' in the nmtcheck checkout"]


def test_sniff() -> None:
    assert mf4.sniff(b"MDF     4.10    ") and mf4.sniff(b"UnFinMF 4.11    ")
    assert not mf4.sniff(b"MDF4")
