"""Opening inputs: decompression, format detection by content, and input errors."""

from __future__ import annotations

import bz2
import dataclasses
import gzip
import importlib.util
import io
import lzma
import random
import shutil
import sys
from collections.abc import Callable
from pathlib import Path

import can
import numpy as np
import pytest
from conftest import read_columns as read
from conftest import shared_file

from nmtcheck.errors import InputError
from nmtcheck.readers import InputStats, detect_format, open_input

HAVE_ZSTD = importlib.util.find_spec("zstandard") is not None


def summary(stats: InputStats) -> dict[str, object]:
    d = dataclasses.asdict(stats)
    del d["path"], d["_chan_codes"]
    return d


def same(a: tuple[InputStats, dict[str, np.ndarray]],
         b: tuple[InputStats, dict[str, np.ndarray]]) -> None:
    assert summary(a[0]) == summary(b[0])
    assert a[1].keys() == b[1].keys()
    for name in a[1]:
        np.testing.assert_array_equal(a[1][name], b[1][name], err_msg=name)


def _candump_file(tmp_path: Path) -> Path:
    path = tmp_path / "plain.log"
    writer = can.CanutilsLogWriter(str(path))
    for i in range(200):
        writer.on_message_received(can.Message(
            timestamp=1000.0 + i * 0.01, arbitration_id=0x700 + i % 8, is_extended_id=False,
            data=[i % 128], channel=f"can{i % 2}"))
    writer.on_message_received(can.Message(timestamp=1003.0, is_error_frame=True))
    writer.stop()
    with path.open("a") as f:
        f.write("garbage\n(1004.0) can0 123#R3\n")
    return path


def _asc_file(tmp_path: Path) -> Path:
    path = tmp_path / "plain.asc"
    writer = can.ASCWriter(str(path))
    for i in range(200):
        writer.on_message_received(can.Message(
            timestamp=1000.0 + i * 0.01, arbitration_id=0x180 + i % 8, is_extended_id=False,
            data=bytes(range(i % 9)), channel=i % 3))
    writer.on_message_received(can.Message(timestamp=1003.0, arbitration_id=0x1234,
                                           is_fd=True, data=bytes(20)))
    writer.stop()
    return path


COMPRESSORS: dict[str, Callable[[bytes], bytes]] = {
    "gz": gzip.compress,
    "bz2": bz2.compress,
    "xz": lzma.compress,
}


@pytest.mark.parametrize("make", [_candump_file, _asc_file], ids=["candump", "asc"])
@pytest.mark.parametrize("suffix", ["gz", "bz2", "xz", "zst"])
def test_compressed_copies_read_identically(tmp_path: Path, make: Callable[[Path], Path],
                                            suffix: str) -> None:
    plain = make(tmp_path)
    raw = plain.read_bytes()
    if suffix == "zst":
        if not HAVE_ZSTD:
            pytest.skip("zstandard is not installed")
        import zstandard

        packed = zstandard.ZstdCompressor().compress(raw)
    else:
        packed = COMPRESSORS[suffix](raw)
    # the inner suffix is kept for one copy and dropped for the other: only content counts
    for name in (f"{plain.name}.{suffix}", f"trace.{suffix}", "noext"):
        comp = tmp_path / name
        comp.write_bytes(packed)
        same(read(plain), read(comp))
    stats, _ = read(plain)
    assert stats.frames > 200


def test_large_gzip_spans_many_reads(tmp_path: Path) -> None:
    # bigger than the 64 KiB sniffing head and the decompressor's own buffers
    lines = b"".join(b"(%d.%06d) can0 %03X#%02X\n" % (1000 + i // 1000, i % 1000, 0x700 + i % 100,
                                                          i % 256) for i in range(20000))
    plain = tmp_path / "big.log"
    plain.write_bytes(lines)
    comp = tmp_path / "big.log.gz"
    comp.write_bytes(gzip.compress(lines))
    a, b = read(plain), read(comp)
    same(a, b)
    assert a[0].frames == 20000


def test_format_detected_from_content_not_suffix(tmp_path: Path) -> None:
    cd = _candump_file(tmp_path)
    asc = _asc_file(tmp_path)
    for src, fmt, names in ((cd, "candump", ("x.txt", "x.asc", "x.trc", "x")),
                            (asc, "asc", ("y.log", "y.txt", "y.blf", "y"))):
        ref = read(src)
        for name in names:
            dst = tmp_path / name
            shutil.copyfile(src, dst)
            got = read(dst)
            assert got[0].format == fmt
            same(ref, got)


def test_input_format_overrides_detection(tmp_path: Path) -> None:
    cd = _candump_file(tmp_path)
    stats, _ = read(cd, input_format="candump")
    assert stats.format == "candump" and stats.frames == 202
    # forced to the wrong format: nothing parses, every line is a skipped record
    stats, _ = read(cd, input_format="asc")
    assert stats.format == "asc"
    assert stats.frames == 0
    assert stats.skipped == 203
    with pytest.raises(InputError) as exc:
        read(cd, input_format="asc", strict=True)
    assert str(exc.value).startswith(f"{cd}:1: ")


def test_unknown_input_format_name(tmp_path: Path) -> None:
    cd = _candump_file(tmp_path)
    with pytest.raises(InputError) as exc:
        open_input(str(cd), input_format="vector-xlog")
    assert str(exc.value).startswith(f"{cd}: ") and "vector-xlog" in str(exc.value)


def test_missing_file(tmp_path: Path) -> None:
    path = tmp_path / "nope.log"
    with pytest.raises(InputError) as exc:
        open_input(str(path))
    assert str(exc.value) == f"{path}: no such file"
    assert exc.value.path == str(path) and exc.value.line is None


def test_directory(tmp_path: Path) -> None:
    with pytest.raises(InputError) as exc:
        open_input(str(tmp_path))
    assert str(exc.value).startswith(f"{tmp_path}: ") and "directory" in str(exc.value)


@pytest.mark.parametrize("content", [b"", gzip.compress(b""), bz2.compress(b""),
                                     lzma.compress(b"")], ids=["plain", "gz", "bz2", "xz"])
def test_empty_file(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "empty.log"
    path.write_bytes(content)
    with pytest.raises(InputError) as exc:
        open_input(str(path))
    assert str(exc.value).startswith(f"{path}: ") and "empty" in str(exc.value)


PNG = b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00\x00\x00\x10\x00\x00\x00\x10\x08\x06\x00\x00\x00"


@pytest.mark.parametrize("content", [
    PNG,
    b"just some text\nthat is not a CAN log\n",
    b"ID,Data Bytes\n4f5,ff 34 23 45\n",  # SavvyCAN's generic CSV
    gzip.compress(PNG),
], ids=["png", "text", "csv", "gzipped-png"])
def test_unknown_format(tmp_path: Path, content: bytes) -> None:
    path = tmp_path / "thing.log"
    path.write_bytes(content)
    with pytest.raises(InputError) as exc:
        open_input(str(path))
    assert str(exc.value).startswith(f"{path}: ") and "unknown log format" in str(exc.value)


@pytest.mark.parametrize("rel", [
    "savvycan/CarBusAnalyzer.trc",  # CR-only text trace with a PEAK suffix
])
def test_unsupported_corpus_files_are_rejected(rel: str) -> None:
    path = shared_file(f"corpus/third_party/{rel}")
    with pytest.raises(InputError) as exc:
        open_input(str(path))
    assert str(exc.value).startswith(f"{path}: ")
    assert "unknown log format" in str(exc.value)


def test_corrupt_gzip(tmp_path: Path) -> None:
    packed = gzip.compress(b"".join(b"(%d.0) can0 701#05\n" % i for i in range(5000)))
    path = tmp_path / "corrupt.log.gz"
    path.write_bytes(packed[:40] + b"\xff" * 40 + packed[80:])
    with pytest.raises(InputError) as exc:
        list(open_input(str(path)).batches)
    assert str(exc.value).startswith(f"{path}: ")


@pytest.mark.parametrize("suffix", ["gz", "bz2", "xz"])
def test_truncated_compressed_file(tmp_path: Path, suffix: str) -> None:
    # big enough that gzip and xz find the damage while reading lines, after sniffing: read
    # up to the damage and reported truncated (--strict: an input error); bzip2 decompresses
    # whole 900 kB blocks, so nothing of the cut block can be read: an input error
    rnd = random.Random(suffix)
    text = b"".join(b"(%d.000000) can0 701#%s\n" % (i, rnd.randbytes(8).hex().encode())
                    for i in range(20000))
    packed = COMPRESSORS[suffix](text)
    path = tmp_path / f"trunc.log.{suffix}"
    path.write_bytes(packed[: len(packed) * 3 // 4])
    with pytest.raises(InputError) as exc:
        list(open_input(str(path), strict=True).batches)
    assert str(exc.value).startswith(f"{path}: ")
    if suffix == "bz2":
        with pytest.raises(InputError):
            list(open_input(str(path)).batches)
        return
    stats, cols = read(path)
    assert stats.truncated and 1000 < stats.frames < 20000 and stats.skipped <= 1  # the cut line
    np.testing.assert_array_equal(cols["ts"], np.arange(stats.frames, dtype=float))


def test_zstd_magic(tmp_path: Path) -> None:
    # a damaged zstd file, or any zstd file without the zstandard module: an input error
    path = tmp_path / "x.log.zst"
    path.write_bytes(b"\x28\xb5\x2f\xfd" + b"\x00" * 32)
    with pytest.raises(InputError) as exc:
        list(open_input(str(path)).batches)
    assert str(exc.value).startswith(f"{path}: ")
    if not HAVE_ZSTD:
        assert "zstandard" in str(exc.value)


def test_garbage_third_line(tmp_path: Path) -> None:
    path = tmp_path / "g.log"
    path.write_text("(1.0) can0 701#05\n(1.1) can0 702#05\nthis is not a frame\n"
                    "(1.2) can0 703#05\n")
    stats, cols = read(path)
    assert stats.skipped == 1
    assert stats.skipped_lines == [3]
    assert stats.frames == 3
    assert list(cols["line"]) == [1, 2, 4]


def test_backwards_timestamps_counted(tmp_path: Path) -> None:
    path = tmp_path / "b.log"
    path.write_text("(5.0) can0 701#05\n(4.0) can0 701#05\n(6.0) can1 701#05\n"
                    "(5.5) can0 701#05\n(5.5) can0 701#05\n")
    stats, cols = read(path)
    assert stats.backwards_timestamps == 2
    assert list(cols["ts"]) == [5.0, 4.0, 6.0, 5.5, 5.5]


def test_utf8_bom(tmp_path: Path) -> None:
    for name, text in (("bom.log", "(1.0) can0 701#05\n(1.1) can0 702#05\n"),
                       ("bom.asc", "date Mon Jan 8 10:00:00.000 2024\nbase hex  timestamps "
                                   "absolute\n   1.000000 1  701   Rx   d 1 05\n")):
        path = tmp_path / name
        path.write_bytes(b"\xef\xbb\xbf" + text.encode())
        stats, _ = read(path, strict=True)
        assert stats.skipped == 0 and stats.frames >= 1


def test_stdin(monkeypatch: pytest.MonkeyPatch) -> None:
    data = gzip.compress(b"(1.0) can0 701#05\n(1.1) can0 702#05\n")
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(data)))
    stats, cols = read("-")
    assert stats.path == "<stdin>" and stats.frames == 2
    assert list(cols["can_id"]) == [0x701, 0x702]


def test_detect_format_heads() -> None:
    assert detect_format(b"(1700000000.000000) can0 123#11\n") == "candump"
    assert detect_format(b"\n\n   (0.5) vcan0 12345678##1AA\n") == "candump"
    assert detect_format(b"date Mon Jan 8 10:00:00.000 2024\n") == "asc"
    assert detect_format(b"base hex  timestamps absolute\n") == "asc"
    assert detect_format(b"   0.019968 1  64   Rx   d 4 64 00 00 00\n") == "asc"
    assert detect_format(b"   0.019968 CANFD   1 Rx  64\n") == "asc"
    assert detect_format(PNG) is None
    assert detect_format(b"hello\n" * 100 + b"(1.0) can0 123#11\n") is None  # only 50 lines
