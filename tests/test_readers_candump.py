"""candump (`candump -l` / `-L`) reader.

Files are written by python-can's own `CanutilsLogWriter` and read back with
`can.LogReader` as the reference; what python-can cannot write (DROPCOUNT,
nanosecond stamps, `R<len>`, error-frame payloads, CAN XL, …) is hand-written
in the shape can-utils' `lib.c`/`candump.c` print it.
"""

from __future__ import annotations

import functools
import random
from pathlib import Path

import can
import numpy as np
import pytest
from conftest import read_columns as read

from nmtcheck.errors import InputError
from nmtcheck.readers import InputStats, candump, open_input
from nmtcheck.readers.frames import BatchBuilder

T0 = 1_700_000_000.0

Row = tuple[float, str, int, bool, bool, bool, bool, int, bytes]


def rows(stats: InputStats, cols: dict[str, np.ndarray]) -> list[Row]:
    """(ts, channel name, id, ext, rtr, err, fd, dlc, data shown) per frame."""
    out = []
    for i in range(len(cols["ts"])):
        dlc = int(cols["dlc"][i])
        rtr = bool(cols["rtr"][i])
        data = b"" if rtr else bytes(cols["data"][i, : min(dlc, 8)])
        out.append((float(cols["ts"][i]), stats.channels[int(cols["chan"][i])],
                    int(cols["can_id"][i]), bool(cols["ext"][i]), rtr, bool(cols["err"][i]),
                    bool(cols["fd"][i]), dlc, data))
    return out


def write_lines(tmp_path: Path, lines: list[str], name: str = "trace.log",
                newline: str = "\n") -> Path:
    path = tmp_path / name
    path.write_bytes("".join(line + newline for line in lines).encode())
    return path


# --- written by python-can, compared with python-can -------------------------------------


def _fixed_messages() -> list[can.Message]:
    t = T0
    m = can.Message
    return [
        m(timestamp=t + 0.000100, arbitration_id=0x123, is_extended_id=False,
          data=bytes(range(8)), channel="can0"),
        m(timestamp=t + 0.001, arbitration_id=0x000, is_extended_id=False, data=[0x01, 0x05],
          channel="can0"),
        m(timestamp=t + 0.002, arbitration_id=0x705, is_extended_id=False, data=[0x05],
          channel="can1", is_rx=False),
        m(timestamp=t + 0.003, arbitration_id=0x1ABCDEF0, is_extended_id=True, data=[1, 2, 3],
          channel="can1"),
        # an extended frame with a small ID is still written with 8 digits
        m(timestamp=t + 0.004, arbitration_id=0x5, is_extended_id=True, data=b"",
          channel="can0"),
        m(timestamp=t + 0.005, arbitration_id=0x704, is_extended_id=False,
          is_remote_frame=True, dlc=0, channel="can0"),
        # python-can writes a remote frame as `704#R` and drops its DLC: both readers say 0
        m(timestamp=t + 0.006, arbitration_id=0x704, is_extended_id=False,
          is_remote_frame=True, dlc=1, channel="can0"),
        m(timestamp=t + 0.007, arbitration_id=0x18FF0001, is_extended_id=True,
          is_remote_frame=True, channel="can1"),
        m(timestamp=t + 0.008, arbitration_id=0x7E0, is_extended_id=False, is_fd=True,
          bitrate_switch=True, data=bytes(range(12)), channel="can0"),
        m(timestamp=t + 0.009, arbitration_id=0x1FFFFFFF, is_extended_id=True, is_fd=True,
          error_state_indicator=True, data=bytes(range(100, 164)), channel="can1"),
        m(timestamp=t + 0.010, arbitration_id=0x7FF, is_extended_id=False, data=b"",
          channel="can0"),
        m(timestamp=t + 0.011, arbitration_id=0x181, is_extended_id=False,
          data=bytes([0xFF] * 8), channel=0),  # an int channel is written as "can0"
        m(timestamp=t + 0.012, arbitration_id=0x80, is_extended_id=False, data=bytes(5),
          channel="can1"),
    ]


def _random_messages(n: int, seed: int) -> list[can.Message]:
    rnd = random.Random(seed)
    t = T0 + 1.0
    msgs = []
    for _ in range(n):
        t += rnd.choice((0.0, 0.000001, 0.0005, 0.01, 1.25))
        ext = rnd.random() < 0.3
        can_id = rnd.randrange(1 << 29) if ext else rnd.randrange(1 << 11)
        kind = rnd.random()
        chan = rnd.choice(("can0", "can1", "vcan2"))
        if kind < 0.15:
            msgs.append(can.Message(timestamp=t, arbitration_id=can_id, is_extended_id=ext,
                                    is_remote_frame=True, channel=chan))
        elif kind < 0.35:
            size = rnd.choice((0, 1, 5, 8, 12, 16, 20, 24, 32, 48, 64))
            msgs.append(can.Message(timestamp=t, arbitration_id=can_id, is_extended_id=ext,
                                    is_fd=True, bitrate_switch=rnd.random() < 0.5,
                                    data=rnd.randbytes(size), channel=chan))
        else:
            msgs.append(can.Message(timestamp=t, arbitration_id=can_id, is_extended_id=ext,
                                    data=rnd.randbytes(rnd.randrange(9)), channel=chan,
                                    is_rx=rnd.random() < 0.5))
    return msgs


def _write_python_can(path: Path, msgs: list[can.Message]) -> None:
    writer = can.CanutilsLogWriter(str(path))
    for msg in msgs:
        writer.on_message_received(msg)
    writer.stop()


def _compare_with_python_can(path: Path) -> tuple[InputStats, list[Row]]:
    stats, cols = read(path)
    ours = rows(stats, cols)
    theirs = list(can.LogReader(str(path)))
    assert len(ours) == len(theirs)
    for got, msg in zip(ours, theirs, strict=True):
        ts, chan, can_id, ext, rtr, err, fd, dlc, data = got
        assert ts == msg.timestamp
        assert err == msg.is_error_frame
        if err:
            continue  # python-can drops an error frame's channel, ID class and payload
        assert (chan, can_id, ext, rtr, fd, dlc) == (
            msg.channel, msg.arbitration_id, msg.is_extended_id, msg.is_remote_frame,
            msg.is_fd, msg.dlc)
        assert data == bytes(msg.data[:8])
    return stats, ours


def test_python_can_written_fixed_messages(tmp_path: Path) -> None:
    path = tmp_path / "fixed.log"
    _write_python_can(path, _fixed_messages())
    stats, ours = _compare_with_python_can(path)
    assert stats.format == "candump"
    assert stats.frames == 13
    assert stats.channels == ["can0", "can1"]
    assert stats.extended == 4  # 0x1ABCDEF0, 0x5, 0x18FF0001 (RTR), 0x1FFFFFFF (FD)
    assert stats.remote_frames == 3
    assert stats.fd_frames == 2
    assert stats.error_frames == 0
    assert stats.skipped == 0 and stats.ignored == 0 and stats.dropped == 0
    assert stats.start == T0 + 0.0001 and stats.end == T0 + 0.012
    # spot checks against the written values, independent of python-can
    assert ours[4][2:4] == (0x5, True)
    assert ours[6][4] and ours[6][7] == 0
    assert ours[8][6:] == (True, 12, bytes(range(8)))
    assert ours[9][2:] == (0x1FFFFFFF, True, False, False, True, 64, bytes(range(100, 108)))
    assert ours[10][7:] == (0, b"")


def test_python_can_written_random_messages(tmp_path: Path) -> None:
    path = tmp_path / "random.log"
    msgs = _random_messages(600, seed=20240501)
    _write_python_can(path, msgs)
    stats, _ours = _compare_with_python_can(path)
    assert stats.frames == 600
    assert stats.extended == sum(m.is_extended_id for m in msgs)
    assert stats.remote_frames == sum(m.is_remote_frame for m in msgs)
    assert stats.fd_frames == sum(m.is_fd for m in msgs)
    assert set(stats.channels) == {m.channel for m in msgs}
    assert stats.backwards_timestamps == 0


def test_python_can_written_error_frame(tmp_path: Path) -> None:
    # CanutilsLogWriter writes `20000080#` (CAN_ERR_FLAG | CAN_ERR_BUSERROR, no payload)
    path = tmp_path / "err.log"
    _write_python_can(path, [
        can.Message(timestamp=T0, arbitration_id=0x701, is_extended_id=False, data=[0],
                    channel="can0"),
        can.Message(timestamp=T0 + 0.5, is_error_frame=True, channel="can1"),
    ])
    assert path.read_text().splitlines()[1] == f"({T0 + 0.5:f}) can1 20000080#"
    stats, ours = _compare_with_python_can(path)
    assert stats.error_frames == 1 and stats.extended == 0 and stats.frames == 2
    # python-can reads this frame back with channel None; we keep the interface
    assert ours[1] == (T0 + 0.5, "can1", 0x80, False, False, True, False, 0, b"")


# --- what can-utils writes and python-can's writer cannot ----------------------------------


def test_dropcount_is_counted_not_a_frame(tmp_path: Path) -> None:
    # candump.c writes these lines into the log file too; python-can 4.6.1 raises ValueError
    path = write_lines(tmp_path, [
        "(1700000000.000100) can0 701#05",
        "DROPCOUNT: dropped 3 CAN frames on 'can0' socket (total drops 3)",
        "(1700000000.000200) can0 701#05",
        "DROPCOUNT: dropped 1 CAN frame on 'can0' socket (total drops 4)",
    ])
    stats, cols = read(path)
    assert stats.frames == 2
    assert stats.dropped == 4
    assert stats.skipped == 0 and stats.skipped_lines == []
    assert list(cols["line"]) == [1, 3]
    assert list(cols["index"]) == [0, 1]


def test_dropcount_without_count_is_skipped(tmp_path: Path) -> None:
    path = write_lines(tmp_path, ["(1.0) can0 701#05", "DROPCOUNT: lots"])
    stats, _ = read(path)
    assert (stats.frames, stats.skipped, stats.skipped_lines, stats.dropped) == (1, 1, [2], 0)


def test_nanosecond_timestamps(tmp_path: Path) -> None:
    path = write_lines(tmp_path, [
        "(1700000000.123456789) can0 123#11",
        "(1700000001.000000001) can0 123#22",
        "(0.000000001) vcan0 123#33",
    ])
    stats, cols = read(path)
    assert stats.frames == 3
    assert cols["ts"][0] == pytest.approx(1700000000.123456789, abs=1e-6)
    assert cols["ts"][1] == pytest.approx(1700000001.0, abs=1e-6)
    assert cols["ts"][2] == pytest.approx(1e-9)
    assert stats.backwards_timestamps == 1
    assert stats.channels == ["can0", "vcan0"]


def test_direction_flags(tmp_path: Path) -> None:
    path = write_lines(tmp_path, [
        "(1.000000) can0 181#0102 R",
        "(1.100000) can0 000#0105 T",
        "(1.200000) can0 704#R R",
        "(1.300000) can0 181#0102 X",  # not a direction: skipped
    ])
    stats, cols = read(path)
    assert stats.frames == 3
    assert stats.skipped_lines == [4]
    assert list(cols["can_id"]) == [0x181, 0x000, 0x704]
    assert list(cols["rtr"]) == [False, False, True]


def test_remote_frames(tmp_path: Path) -> None:
    path = write_lines(tmp_path, [
        "(1.0) can0 704#R",
        "(1.1) can0 704#R1",
        "(1.2) can0 123#R5",
        "(1.3) can0 7A1#r",
        "(1.4) can0 12345678#R8",
        "(1.5) can0 123#R8_9",  # candump -8: length 8, raw DLC 9 (python-can: int("8_9") = 89)
        "(1.6) can0 123#R0",
    ])
    stats, cols = read(path)
    assert stats.skipped == 0
    assert stats.remote_frames == 7
    assert list(cols["dlc"]) == [0, 1, 5, 0, 8, 8, 0]
    assert list(cols["ext"]) == [False, False, False, False, True, False, False]
    assert not cols["data"].any()


@pytest.mark.parametrize("frame", ["123#R9", "123#R12", "123#RX", "123#R8_", "123#R8_99",
                                   "123#R8_G"])
def test_malformed_remote_frames_are_skipped(tmp_path: Path, frame: str) -> None:
    stats, _ = read(write_lines(tmp_path, ["(1.0) can0 701#05", f"(1.1) can0 {frame}"]))
    assert (stats.frames, stats.skipped_lines) == (1, [2])


def test_len8_dlc_suffix_on_data_frame(tmp_path: Path) -> None:
    path = write_lines(tmp_path, ["(1.0) can0 123#1122334455667788_E"])
    stats, cols = read(path)
    assert stats.frames == 1 and stats.skipped == 0
    assert cols["dlc"][0] == 8
    assert bytes(cols["data"][0]) == bytes.fromhex("1122334455667788")


def test_error_frames_from_can_utils(tmp_path: Path) -> None:
    # python-can 4.6.1 only calls a line an error frame when the bus-error class bit (0x80)
    # is set: it reads `20000004#…` as an extended data frame with ID 0x4
    path = write_lines(tmp_path, [
        "(1.0) can0 20000080#0000000000000000",  # bus error
        "(1.1) can0 20000004#0004000000000000",  # controller problem: rx error passive
        "(1.2) can1 20000040#0000000000000000",  # bus-off
        "(1.3) can0 1ABCDEF0#00",  # an ordinary extended frame
    ])
    stats, cols = read(path)
    assert stats.frames == 4
    assert stats.error_frames == 3
    assert stats.extended == 1
    assert list(cols["err"]) == [True, True, True, False]
    assert list(cols["ext"]) == [False, False, False, True]
    assert list(cols["can_id"]) == [0x80, 0x04, 0x40, 0x1ABCDEF0]
    assert list(cols["dlc"]) == [8, 8, 8, 1]
    assert bytes(cols["data"][1]) == bytes.fromhex("0004000000000000")


def test_can_fd_frames(tmp_path: Path) -> None:
    path = write_lines(tmp_path, [
        "(1.0) can0 123##0",  # FD, no data
        "(1.1) can0 123##1" + "AB" * 12,  # BRS, 12 bytes
        "(1.2) can0 12345678##3" + "01" * 64,  # BRS|ESI, 64 bytes
        "(1.3) can0 123##5" + "11223344",  # FDF|BRS flag nibble of newer kernels
        "(1.4) can0 123##0" + "00" * 65,  # 65 bytes: too long
        "(1.5) can0 123##",  # no flags nibble
        "(1.6) can0 123##G00",
        "(1.7) can0 123##0123",  # odd number of digits
    ])
    stats, cols = read(path)
    assert stats.frames == 4
    assert stats.fd_frames == 4
    assert stats.skipped_lines == [5, 6, 7, 8]
    assert list(cols["dlc"]) == [0, 12, 64, 4]
    assert list(cols["ext"]) == [False, False, True, False]
    assert bytes(cols["data"][1]) == b"\xab" * 8


def test_can_xl_lines_are_ignored(tmp_path: Path) -> None:
    # python-can 4.6.1 raises ValueError on both CAN XL layouts
    path = write_lines(tmp_path, [
        "(1.0) can0 701#05",
        # can-utils 2023.03 style
        "(1.1) xl0 123###80.00.00000000.11223344",
        # current can-utils lib.c: <vcid><prio>#<flags>:<sdt>:<af>#<data>
        "(1.2) xl0 45123#81:00:12345678#11223344.556677",
        "(1.3) xl0 00242#80:01:00000000#00",
        "(1.4) can0 701#05",
    ])
    stats, cols = read(path)
    assert stats.frames == 2
    assert stats.ignored == 3
    assert stats.skipped == 0
    assert stats.channels == ["can0"]
    assert list(cols["line"]) == [1, 5]


GARBAGE = [
    "hello world",
    "(abc) can0 123#00",
    "(1.0) can0 12#00",  # 2-digit ID
    "(1.0) can0 1234#00",  # 4-digit ID
    "(1.0) can0 123#0",  # odd number of digits
    "(1.0) can0 123#112233445566778899",  # 9 bytes in a classic frame
    "(1.0) can0 123#GG",
    "1.0 can0 123#00",  # no parentheses
    "(1.0) can0",
    "(nan) can0 123#00",
    "(inf) can0 123#00",
    "(1.0) can0 123",  # no '#'
    "(1.0) can0 123#00 R extra",
    "(1.0) can0 123#1122_Z",
]


def test_garbage_lines_are_skipped_with_line_numbers(tmp_path: Path) -> None:
    lines = ["(1.000000) can0 701#00"] + GARBAGE + ["(2.000000) can0 701#05"]
    stats, cols = read(write_lines(tmp_path, lines))
    assert stats.frames == 2
    assert stats.skipped == len(GARBAGE)
    assert stats.skipped_lines == list(range(2, 12))  # only the first 10 are kept
    assert list(cols["line"]) == [1, len(lines)]
    assert list(cols["index"]) == [0, 1]


@pytest.mark.parametrize("bad", GARBAGE)
def test_each_garbage_line_is_skipped(tmp_path: Path, bad: str) -> None:
    stats, _ = read(write_lines(tmp_path, ["(1.0) can0 701#00", bad, ""]))
    assert (stats.frames, stats.skipped, stats.skipped_lines) == (1, 1, [2])


def test_strict_makes_first_bad_line_fatal(tmp_path: Path) -> None:
    path = write_lines(tmp_path, [
        "(1.0) can0 701#00",
        "DROPCOUNT: dropped 3 CAN frames on 'can0' socket (total drops 3)",
        "(1.1) xl0 45123#81:00:12345678#11223344",
        "",
        "(1.2) can0 701#05 R",
        "(1.3) can0 70#05",
        "garbage",
    ])
    opened = open_input(str(path), strict=True)
    with pytest.raises(InputError) as exc:
        list(opened.batches)
    assert exc.value.line == 6
    assert str(exc.value).startswith(f"{path}:6: ")
    assert "candump" in str(exc.value)


def test_strict_accepts_a_clean_file(tmp_path: Path) -> None:
    path = tmp_path / "clean.log"
    _write_python_can(path, _fixed_messages())
    stats, _ = read(path, strict=True)
    assert stats.frames == 13 and stats.skipped == 0


def test_crlf_reads_like_lf(tmp_path: Path) -> None:
    lines = ["(1.0) can0 701#00", "(1.1) can1 123#R2 R", "(1.2) can0 20000080#0000000000000000",
             "(1.3) can0 123##1AABB",
             "DROPCOUNT: dropped 2 CAN frames on 'can0' socket (total drops 2)", "bad line"]
    s_lf, c_lf = read(write_lines(tmp_path, lines, "lf.log"))
    s_crlf, c_crlf = read(write_lines(tmp_path, lines, "crlf.log", newline="\r\n"))
    assert rows(s_lf, c_lf) == rows(s_crlf, c_crlf)
    assert (s_crlf.frames, s_crlf.dropped, s_crlf.skipped_lines) == (4, 2, [6])
    assert s_crlf.channels == ["can0", "can1"]


def test_blank_lines_and_indentation(tmp_path: Path) -> None:
    path = write_lines(tmp_path, ["", "  (1.0) can0 701#00  ", "\t", "(1.1)\tcan0\t701#05", ""])
    stats, cols = read(path)
    assert (stats.frames, stats.skipped) == (2, 0)
    assert list(cols["line"]) == [2, 4]


def test_backwards_timestamps_are_kept_in_file_order(tmp_path: Path) -> None:
    path = write_lines(tmp_path, [
        "(10.0) can0 701#05", "(9.0) can0 702#05", "(9.5) can1 703#05", "(8.0) can0 704#05",
        "(8.0) can0 705#05",
    ])
    stats, cols = read(path)
    assert stats.backwards_timestamps == 2
    assert list(cols["ts"]) == [10.0, 9.0, 9.5, 8.0, 8.0]
    assert (stats.start, stats.end) == (10.0, 8.0)


def test_many_batches_keep_index_and_lines(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(candump, "BatchBuilder", functools.partial(BatchBuilder, capacity=4))
    lines = [f"({i}.0) can0 {0x700 + i % 100:03X}#05" for i in range(1, 11)]
    lines.insert(5, "garbage")
    opened = open_input(str(write_lines(tmp_path, lines)))
    batches = list(opened.batches)
    assert [len(b) for b in batches] == [4, 4, 2]
    index = np.concatenate([b.index for b in batches])
    assert list(index) == list(range(10))
    assert list(np.concatenate([b.line for b in batches])) == [1, 2, 3, 4, 5, 7, 8, 9, 10, 11]
    assert opened.stats.frames == 10 and opened.stats.skipped_lines == [6]
