"""Vector BLF reader.

Files written by python-can's `BLFWriter` are compared with python-can's `BLFReader`
frame by frame (python-can numbers channels from 0, the file from 1). What the
writer never produces (header version 2 and 3 objects, CAN_FD_MESSAGE(_64) and error
objects, lost-data records, damaged files) is built here byte by byte with the
layouts of Vector's binlog objects.
"""

from __future__ import annotations

import itertools
import random
import struct
import subprocess
import sys
import zlib
from pathlib import Path
from typing import cast

import can
import numpy as np
import pytest
from conftest import CORPUS, needs_corpus
from conftest import read_columns as read

from nmtcheck.errors import InputError
from nmtcheck.readers import InputStats, detect_format, open_input
from nmtcheck.readers.blf import systemtime_to_epoch

THIRD = CORPUS / "third_party"
CORPUS_BLF = sorted(p.name for p in (THIRD / "python-can").glob("*.blf")) if THIRD.is_dir() else []

START = (2024, 1, 1, 1, 12, 0, 0, 0)  # SYSTEMTIME: Mon 2024-01-01 12:00:00.000
START_EPOCH = 1704110400.0


# --- building BLF files -------------------------------------------------------------------


def file_header(start: tuple[int, ...] = START) -> bytes:
    head = struct.pack("<4sLBBBBBBBBQQLL8H8H", b"LOGG", 144, 5, 0, 0, 0, 2, 6, 8, 1,
                       0, 0, 0, 0, *start, *start)
    return head.ljust(144, b"\0")


def obj(otype: int, body: bytes, ts_ns: int = 0, version: int = 1, flags: int = 2,
        size: int | None = None) -> bytes:
    """One object: base header + object header (version 1, 2 or other) + body + padding."""
    if version == 2:
        header = struct.pack("<LBxHQQ", flags, 0, 0, ts_ns, 0)
    else:
        header = struct.pack("<LHHQ", flags, 0, 0, ts_ns)
    hsize = 16 + len(header)
    total = hsize + len(body)
    base = struct.pack("<4sHHLL", b"LOBJ", hsize, version, total if size is None else size, otype)
    return base + header + body + b"\0" * (total % 4)


def container(payload: bytes, method: int = 2) -> bytes:
    data = zlib.compress(payload) if method == 2 else payload
    total = 32 + len(data)
    return (struct.pack("<4sHHLL", b"LOBJ", 16, 1, total, 10) + struct.pack("<H6xL4x", method,
            len(payload)) + data + b"\0" * (total % 4))


def blf(*payloads: bytes, method: int = 2) -> bytes:
    """A file with one container per payload (objects may straddle them)."""
    return file_header() + b"".join(container(p, method) for p in payloads)


def can_message(chan: int, can_id: int, data: bytes, *, dlc: int | None = None,
                flags: int = 0, ext: bool = False) -> bytes:
    return struct.pack("<HBBL8s", chan, flags, len(data) if dlc is None else dlc,
                       can_id | (0x80000000 if ext else 0), data)


def can_fd_message(chan: int, can_id: int, data: bytes, *, dlc: int, fd_flags: int = 1,
                   flags: int = 0) -> bytes:
    return struct.pack("<HBBLLBBB5x64s4x", chan, flags, dlc, can_id, 0, 0, fd_flags, len(data),
                       data)


def can_fd_message_64(chan: int, can_id: int, data: bytes, *, dlc: int, flags: int = 0x1000,
                      valid: int | None = None) -> bytes:
    valid = len(data) if valid is None else valid
    return struct.pack("<BBBBLLLLLLLHBBL", chan, dlc, valid, 0, can_id, 0, flags, 0, 0, 0, 0,
                       0, 0, 0, 0) + data


def write(tmp_path: Path, content: bytes, name: str = "trace.blf") -> Path:
    path = tmp_path / name
    path.write_bytes(content)
    return path


Row = tuple[float, str, int, bool, bool, bool, bool, int, bytes]


def rows(stats: InputStats, cols: dict[str, np.ndarray]) -> list[Row]:
    """(ts, channel, id, ext, rtr, err, fd, dlc, data shown) per frame."""
    out = []
    for i in range(len(cols["ts"])):
        dlc = int(cols["dlc"][i])
        rtr, err = bool(cols["rtr"][i]), bool(cols["err"][i])
        data = b"" if rtr or err else bytes(cols["data"][i, : min(dlc, 8)])
        out.append((float(cols["ts"][i]), stats.channels[int(cols["chan"][i])],
                    int(cols["can_id"][i]), bool(cols["ext"][i]), rtr, err,
                    bool(cols["fd"][i]), dlc, data))
    return out


def python_can_rows(path: Path) -> list[Row]:
    out = []
    for m in can.BLFReader(str(path)):
        data = b"" if m.is_remote_frame or m.is_error_frame else bytes(m.data[: min(m.dlc, 8)])
        out.append((m.timestamp, str(cast(int, m.channel) + 1), m.arbitration_id,
                    m.is_extended_id and not m.is_error_frame, m.is_remote_frame,
                    m.is_error_frame, m.is_fd, m.dlc, data))
    return out


def random_messages(n: int, seed: int) -> list[can.Message]:
    rnd = random.Random(seed)
    out = []
    t = 1_700_000_000.0
    for _ in range(n):
        t += rnd.choice([0.0, 0.000137, 0.001, 0.1])
        ext = rnd.random() < 0.2
        rtr = rnd.random() < 0.05
        dlc = rnd.randint(0, 8)
        out.append(can.Message(
            timestamp=t, arbitration_id=rnd.randint(0, 0x1FFFFFFF if ext else 0x7FF),
            is_extended_id=ext, is_remote_frame=rtr, dlc=dlc,
            data=None if rtr else rnd.randbytes(dlc), channel=rnd.randint(0, 3),
            is_rx=rnd.random() < 0.5))
    return out


def write_with_python_can(path: Path, msgs: list[can.Message], **kw: object) -> Path:
    with can.BLFWriter(str(path), **kw) as writer:  # type: ignore[arg-type]
        for m in msgs:
            writer.on_message_received(m)
    return path


# --- written by python-can, compared with python-can --------------------------------------


@pytest.mark.parametrize("kw", [
    {},
    {"compression_level": 0},  # plain (uncompressed) containers
    {"max_container_size": 1000},  # many small containers: objects straddle them
    {"max_container_size": 77},  # smaller than one object: one object spans 2-3 containers
], ids=["zlib", "plain", "straddling", "tiny-containers"])
def test_python_can_files_match_python_can(tmp_path: Path, kw: dict[str, object]) -> None:
    path = write_with_python_can(tmp_path / "w.blf", random_messages(3000, seed=len(kw)), **kw)
    stats, cols = read(path, strict=True)
    assert stats.format == "blf" and stats.skipped == 0 and stats.ignored == 0
    ours, theirs = rows(stats, cols), python_can_rows(path)
    assert len(ours) == len(theirs) == 3000
    assert ours == theirs  # timestamps identical to the last bit
    assert stats.extended == sum(r[3] for r in ours) and stats.remote_frames == sum(
        r[4] for r in ours)
    assert list(cols["index"]) == list(range(3000)) and not cols["line"].any()


def test_large_file_comes_in_several_batches(tmp_path: Path) -> None:
    msgs = [can.Message(timestamp=1000.0 + i * 1e-4, arbitration_id=0x181 + i % 4,
                        is_extended_id=False, data=i.to_bytes(4, "little"), channel=0)
            for i in range(120_000)]
    path = write_with_python_can(tmp_path / "big.blf", msgs)
    opened = open_input(str(path))
    batches = list(opened.batches)
    assert len(batches) > 1
    index = np.concatenate([b.index for b in batches])
    assert list(index[:3]) == [0, 1, 2] and int(index[-1]) == 119_999
    data = np.concatenate([b.data for b in batches])
    assert [int.from_bytes(bytes(d[:4]), "little") for d in data[::10_000]] == list(
        range(0, 120_000, 10_000))
    assert opened.stats.frames == 120_000 and opened.stats.channels == ["1"]


def test_error_frames_and_remote_frames_written_by_python_can(tmp_path: Path) -> None:
    msgs = [
        can.Message(timestamp=5.0, arbitration_id=0x704, is_extended_id=False,
                    is_remote_frame=True, dlc=1, channel=1),
        can.Message(timestamp=5.1, is_error_frame=True, channel=1),
        can.Message(timestamp=5.2, arbitration_id=0x704, is_extended_id=False, data=b"\x05",
                    channel=1, is_rx=False),
    ]
    path = write_with_python_can(tmp_path / "e.blf", msgs)
    stats, cols = read(path)
    assert [r[1:] for r in rows(stats, cols)] == [
        ("2", 0x704, False, True, False, False, 1, b""),
        ("2", 0, False, False, True, False, 0, b""),
        ("2", 0x704, False, False, False, False, 1, b"\x05"),
    ]
    assert (stats.error_frames, stats.remote_frames) == (1, 1)


# --- object types, header versions and flags (hand-built) ---------------------------------


def test_object_types_flags_and_channels(tmp_path: Path) -> None:
    objects = [
        obj(1, can_message(1, 0x181, b"\x01\x02"), ts_ns=1_000_000),
        obj(1, can_message(2, 0x1ABCDE, b"\xaa", ext=True, flags=0x01), ts_ns=2_000_000),  # Tx
        obj(1, can_message(1, 0x704, b"\x55" * 8, dlc=1, flags=0x80), ts_ns=3_000_000),  # RTR
        obj(86, can_message(12, 0x701, b"\x05\xee\xee") + b"\0" * 8, ts_ns=4_000_000),
        obj(100, can_fd_message(3, 0x123, bytes(range(12)), dlc=9, fd_flags=0x3), ts_ns=5_000_000),
        obj(101, can_fd_message_64(4, 0x80000456, bytes(range(64)), dlc=15), ts_ns=6_000_000),
        obj(2, struct.pack("<HH4x", 1, 0), ts_ns=7_000_000),  # CAN_ERROR
        obj(73, struct.pack("<HHLBBBxLLH2x8s", 2, 0, 0, 0, 0, 8, 0, 0x80000777, 0, b"\xff" * 8),
            ts_ns=8_000_000),  # CAN_ERROR_EXT
        obj(104, struct.pack("<BBBBHHHBxLLLLLLLHH", 3, 0, 0, 0, 0, 0, 0, 0, 0x321, 0, 0, 0, 0, 0,
                             0, 0, 0) + bytes(8), ts_ns=9_000_000),  # CAN_FD_ERROR_64
    ]
    path = write(tmp_path, blf(b"".join(objects)))
    stats, cols = read(path, strict=True)
    t = START_EPOCH
    assert rows(stats, cols) == [
        (t + 0.001, "1", 0x181, False, False, False, False, 2, b"\x01\x02"),
        (t + 0.002, "2", 0x1ABCDE, True, False, False, False, 1, b"\xaa"),
        (t + 0.003, "1", 0x704, False, True, False, False, 1, b""),
        (t + 0.004, "12", 0x701, False, False, False, False, 3, b"\x05\xee\xee"),
        (t + 0.005, "3", 0x123, False, False, False, True, 12, bytes(range(8))),
        (t + 0.006, "4", 0x456, True, False, False, True, 64, bytes(range(8))),
        (t + 0.007, "1", 0, False, False, True, False, 0, b""),
        (t + 0.008, "2", 0x777, False, False, True, False, 0, b""),
        (t + 0.009, "3", 0x321, False, False, True, True, 0, b""),
    ]
    assert (stats.error_frames, stats.fd_frames, stats.extended) == (3, 3, 2)
    assert bytes(cols["data"][2]) == bytes(8)  # a remote frame carries no data


def test_header_version_2_and_ten_microsecond_stamps(tmp_path: Path) -> None:
    objects = [
        obj(1, can_message(1, 0x701, b"\x00"), ts_ns=12_345_678_901, version=2),
        obj(1, can_message(1, 0x701, b"\x05"), ts_ns=150_000, flags=1),  # 150000 × 10 µs
    ]
    stats, cols = read(write(tmp_path, blf(b"".join(objects))), strict=True)
    assert list(cols["ts"] - START_EPOCH) == pytest.approx([12.345678901, 1.5], abs=1e-6)
    assert stats.backwards_timestamps == 1 and stats.skipped == 0


def test_header_version_3_is_reported_not_silently_skipped(tmp_path: Path) -> None:
    objects = [obj(1, can_message(1, 0x701, b"\x05")),
               obj(1, can_message(1, 0x702, b"\x05"), version=3),
               obj(65, b"some app text\0\0\0", version=3),  # not a frame: a non-frame record
               obj(1, can_message(1, 0x703, b"\x05"))]
    path = write(tmp_path, blf(b"".join(objects)))
    stats, cols = read(path)
    assert list(cols["can_id"]) == [0x701, 0x703]
    assert stats.skipped == 1 and stats.skipped_lines == [2] and stats.ignored == 1
    with pytest.raises(InputError) as exc:
        read(path, strict=True)
    assert "header version 3" in str(exc.value)


def test_classic_frame_in_fd_object_keeps_its_dlc(tmp_path: Path) -> None:
    # no EDL flag: a classic frame; DLC 13 carries 8 bytes (python-can applies the FD table)
    body = can_fd_message(1, 0x3FF, b"\x55\xaa\x01\x02\x03\x04\x05\x06", dlc=13, fd_flags=0)
    path = write(tmp_path, blf(obj(100, body)))
    stats, cols = read(path)
    assert rows(stats, cols)[0][2:] == (0x3FF, False, False, False, False, 13,
                                        b"\x55\xaa\x01\x02\x03\x04\x05\x06")
    theirs = next(iter(can.BLFReader(str(path))))
    assert theirs.dlc == 32  # python-can's misreading


def test_fd64_with_more_valid_bytes_than_stored(tmp_path: Path) -> None:
    # TSMaster (python-can issue 1905): valid_bytes 64, 4 bytes stored; the rest are zeros
    body = can_fd_message_64(7, 0x6A9, b"\xff" * 4, dlc=15, valid=64)
    stats, cols = read(write(tmp_path, blf(obj(101, body))))
    assert rows(stats, cols)[0][1:] == ("7", 0x6A9, False, False, False, True, 64,
                                        b"\xff" * 4 + bytes(4))


def test_data_lost_and_other_objects(tmp_path: Path) -> None:
    objects = [obj(1, can_message(1, 0x701, b"\x05")),
               obj(125, struct.pack("<L", 1)),  # DATA_LOST_BEGIN
               obj(126, struct.pack("<LQL", 1, 0, 17)),  # DATA_LOST_END: 17 events lost
               obj(96, bytes(40)),  # GLOBAL_MARKER
               obj(1, can_message(1, 0x701, b"\x05"), ts_ns=10)]
    stats, _cols = read(write(tmp_path, blf(b"".join(objects))), strict=True)
    assert (stats.frames, stats.ignored, stats.dropped, stats.skipped) == (2, 3, 17, 0)


def test_object_outside_any_container(tmp_path: Path) -> None:
    content = (file_header() + container(obj(1, can_message(1, 0x180, b"\x00")))
               + obj(1, can_message(1, 0x181, b"\x01"), ts_ns=500)
               + container(obj(1, can_message(1, 0x182, b"\x02"), ts_ns=1000)))
    _stats, cols = read(write(tmp_path, content), strict=True)
    assert list(cols["can_id"]) == [0x180, 0x181, 0x182]  # in file order
    assert list(cols["index"]) == [0, 1, 2]


def test_signature_inside_frame_data_is_not_an_object(tmp_path: Path) -> None:
    objects = [obj(1, can_message(1, 0x181, b"LOBJLOBJ")),
               obj(1, can_message(1, 0x182, b"xLOBJ"), ts_ns=1),
               obj(1, can_message(1, 0x183, b"\x03"), ts_ns=2)]
    _stats, cols = read(write(tmp_path, blf(b"".join(objects))), strict=True)
    assert [bytes(d).rstrip(b"\0") for d in cols["data"]] == [b"LOBJLOBJ", b"xLOBJ", b"\x03"]


def test_object_straddling_three_containers(tmp_path: Path) -> None:
    payload = b"".join(obj(101, can_fd_message_64(1, 0x100 + i, bytes(64), dlc=15), ts_ns=i)
                       for i in range(3))
    cuts = [0, 50, 70, 200, len(payload)]  # the first object ends in the third container
    parts = [payload[a:b] for a, b in itertools.pairwise(cuts)]
    _stats, cols = read(write(tmp_path, blf(*parts)), strict=True)
    assert list(cols["can_id"]) == [0x100, 0x101, 0x102]


# --- damage: reported, never a hang ------------------------------------------------------


def test_object_size_zero_does_not_hang(tmp_path: Path) -> None:
    good = obj(1, can_message(1, 0x701, b"\x05"))
    broken = obj(1, can_message(1, 0x702, b"\x05"), size=0)
    path = write(tmp_path, blf(good + broken + obj(1, can_message(1, 0x703, b"\x05"))))
    stats, cols = read(path)
    assert list(cols["can_id"]) == [0x701, 0x703]  # resynchronised at the next object
    assert stats.skipped == 1
    with pytest.raises(InputError) as exc:
        read(path, strict=True)
    assert "size 0" in str(exc.value)


def test_python_can_loops_forever_on_object_size_zero(tmp_path: Path) -> None:
    # python-can's BLFReader yields the size-0 object again and again (its position never
    # advances); the child process stops itself after 1000 messages from a 2-object file
    path = write(tmp_path, blf(obj(1, can_message(1, 0x701, b"\x05"))
                               + obj(1, can_message(1, 0x702, b"\x05"), size=0)))
    script = ("import can, itertools, sys\n"
              "msgs = list(itertools.islice(can.BLFReader(sys.argv[1]), 1000))\n"
              "print(len(msgs), hex(msgs[-1].arbitration_id))\n")
    res = subprocess.run([sys.executable, "-c", script, str(path)], capture_output=True,
                         text=True, timeout=120)
    assert res.stdout.split() == ["1000", "0x702"]
    assert read(path)[0].frames == 1


def test_container_size_zero_and_garbage_between_objects(tmp_path: Path) -> None:
    zero_container = struct.pack("<4sHHLL", b"LOBJ", 16, 1, 0, 10)
    content = (file_header() + container(obj(1, can_message(1, 0x701, b"\x05")))
               + zero_container + b"garbage!" * 3
               + container(obj(1, can_message(1, 0x702, b"\x05"))))
    stats, cols = read(write(tmp_path, content))
    assert list(cols["can_id"]) == [0x701, 0x702]
    assert stats.skipped == 1


def test_unknown_compression_and_corrupt_zlib(tmp_path: Path) -> None:
    bad_method = container(obj(1, can_message(1, 0x702, b"\x05")), method=0)
    bad_method = bad_method[:16] + struct.pack("<H", 7) + bad_method[18:]
    corrupt = container(obj(1, can_message(1, 0x703, b"\x05")))
    corrupt = corrupt[:32] + b"\xff\xff\xff\xff" + corrupt[36:]
    content = (file_header() + container(obj(1, can_message(1, 0x701, b"\x05"))) + bad_method
               + corrupt + container(obj(1, can_message(1, 0x704, b"\x05"))))
    stats, cols = read(write(tmp_path, content))
    assert list(cols["can_id"]) == [0x701, 0x704]
    assert stats.skipped == 2


@pytest.mark.parametrize("level", [0, 6], ids=["plain", "zlib"])
def test_truncated_file_keeps_complete_frames(tmp_path: Path, level: int) -> None:
    rnd = random.Random(level)
    msgs = [can.Message(timestamp=1_700_000_000.0 + i, arbitration_id=0x181,
                        is_extended_id=False, data=rnd.randbytes(8), channel=0)
            for i in range(500)]
    full = write_with_python_can(tmp_path / "full.blf", msgs, max_container_size=4096,
                                 compression_level=level)
    content = full.read_bytes()
    path = write(tmp_path, content[: len(content) - 1000], "cut.blf")
    stats, cols = read(path)
    assert 400 < stats.frames < 500 and stats.skipped == 1
    assert list(cols["ts"]) == [1_700_000_000.0 + i for i in range(stats.frames)]
    assert [bytes(d) for d in cols["data"]] == [bytes(m.data) for m in msgs[: stats.frames]]


def test_truncated_header_and_sniffing(tmp_path: Path) -> None:
    assert detect_format(file_header()) == "blf"
    assert detect_format(b"LOGX" + bytes(100)) != "blf"
    with pytest.raises(InputError) as exc:
        read(write(tmp_path, b"LOGG" + bytes(20)))
    assert "header is truncated" in str(exc.value)
    log = tmp_path / "x.log"
    log.write_text("(1.0) can0 701#05\n")
    with pytest.raises(InputError) as exc:
        read(log, input_format="blf")
    assert str(exc.value) == f"{log}: not a BLF file (no LOGG signature)"


def test_systemtime_conversion() -> None:
    assert systemtime_to_epoch(START) == START_EPOCH
    assert systemtime_to_epoch((0,) * 8) == 0.0  # no start time in the header


# --- the third-party corpus ---------------------------------------------------------------

# Where python-can 4.6.1 reads these files differently: (file, 0-based frame, field).
PYTHON_CAN_WRONG = {
    # EDL and RTR both set (synthetic values): an FD frame cannot be remote
    ("test_CanFdMessage64.blf", 0, "rtr"),
    ("test_CanFdMessage64.blf", 1, "rtr"),
}


@needs_corpus
@pytest.mark.parametrize("name", CORPUS_BLF)
def test_corpus_matches_python_can(name: str) -> None:
    path = THIRD / "python-can" / name
    stats, cols = read(path)
    ours, theirs = rows(stats, cols), python_can_rows(path)
    assert len(ours) == len(theirs) == stats.frames > 0
    fields = ["ts", "chan", "id", "ext", "rtr", "err", "fd", "dlc", "data"]
    differences = set()
    for i, (a, b) in enumerate(zip(ours, theirs, strict=True)):
        for k, x, y in zip(fields, a, b, strict=True):
            if k == "data" and (a[4] or b[4]):
                continue  # one side calls it remote: no data to compare
            if k in ("id", "dlc") and a[5]:
                continue  # error frames: python-can fills ID and DLC from other fields
            if x != y:
                differences.add((name, i, k))
    assert differences == {d for d in PYTHON_CAN_WRONG if d[0] == name}


CORPUS_EXPECTED = {
    # frames, fd, error, channels, ignored (each python-can test file ends with a
    # container holding two reserved type-115 objects)
    "issue_1905.blf": (22, 22, 0, ["7"], 2),
    "test_CanErrorFrameExt.blf": (2, 0, 2, ["4369"], 2),
    "test_CanFdMessage.blf": (2, 2, 0, ["4369"], 2),
    "test_CanFdMessage64.blf": (2, 2, 0, ["17"], 2),
    "test_CanMessage.blf": (2, 0, 0, ["4369"], 2),
    "test_CanMessage2.blf": (2, 0, 0, ["4369"], 2),
}


@needs_corpus
@pytest.mark.parametrize("name", CORPUS_BLF)
def test_corpus_pinned_stats(name: str) -> None:
    stats, _cols = read(THIRD / "python-can" / name, strict=True)
    assert (stats.frames, stats.fd_frames, stats.error_frames, stats.channels,
            stats.ignored) == CORPUS_EXPECTED[name]
    assert stats.skipped == 0 and stats.remote_frames == 0


@needs_corpus
def test_issue_1905_values() -> None:
    stats, cols = read(THIRD / "python-can" / "issue_1905.blf")
    assert set(cols["can_id"].tolist()) == {0x6A9} and (cols["dlc"] == 64).all()
    assert bytes(cols["data"][0]) == b"\xff" * 8
    assert stats.start == pytest.approx(1735654183.491113, abs=1e-6)
    assert stats.end == pytest.approx(1735654288.492673, abs=1e-6)
