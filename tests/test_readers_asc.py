"""Vector ASC reader.

Files are written by python-can's `ASCWriter` and read back with `can.LogReader`
as the reference (python-can numbers channels from 0, the file from 1); the
variants the writer never produces (`base dec`, `timestamps relative`, missing
or repeated trigger blocks, `TxRq`, CANFD flag combinations, status/statistic
lines, cp1252, CRLF) are hand-written in the layout CANoe uses (see the
python-can test files under `corpus/third_party/python-can/`).
"""

from __future__ import annotations

import random
from pathlib import Path

import can
import numpy as np
import pytest
from conftest import read_columns as read

from nmtcheck.errors import InputError
from nmtcheck.readers import InputStats, open_input

Row = tuple[float, str, int, bool, bool, bool, bool, int, bytes]

HEADER = [
    "date Mon Jan 8 10:00:00.000 2024",
    "base hex  timestamps absolute",
    "internal events logged",
    "// version 9.0.0",
    "Begin Triggerblock Mon Jan 8 10:00:00.000 2024",
    "   0.000000 Start of measurement",
]
FOOTER = ["End TriggerBlock"]


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


def write_asc(tmp_path: Path, body: list[str], name: str = "trace.asc",
              header: list[str] | None = None, newline: str = "\r\n",
              encoding: str = "cp1252") -> Path:
    lines = (HEADER if header is None else header) + body + FOOTER
    path = tmp_path / name
    path.write_bytes("".join(line + newline for line in lines).encode(encoding))
    return path


# --- written by python-can, compared with python-can -------------------------------------


def _fixed_messages() -> list[can.Message]:
    m = can.Message
    return [
        m(timestamp=10.0, arbitration_id=0x701, is_extended_id=False, data=[0x00], channel=0),
        m(timestamp=10.1, arbitration_id=0x000, is_extended_id=False, data=[0x01, 0x00],
          channel=0, is_rx=False),
        m(timestamp=10.2, arbitration_id=0x1ABCDEF0, is_extended_id=True, data=[1, 2, 3],
          channel=1),
        m(timestamp=10.3, arbitration_id=0x704, is_extended_id=False, is_remote_frame=True,
          dlc=1, channel=0),
        m(timestamp=10.4, arbitration_id=0x704, is_extended_id=False, is_remote_frame=True,
          dlc=0, channel=0),
        m(timestamp=10.5, arbitration_id=0x18FF00FE, is_extended_id=True, is_remote_frame=True,
          dlc=8, channel=1),
        m(timestamp=10.6, arbitration_id=0x7E0, is_extended_id=False, is_fd=True,
          bitrate_switch=True, data=bytes(range(12)), channel=2),
        m(timestamp=10.7, arbitration_id=0x1FFFFFFF, is_extended_id=True, is_fd=True,
          error_state_indicator=True, data=bytes(range(64)), channel=2),
        m(timestamp=10.8, arbitration_id=0x7FF, is_extended_id=False, data=b"", channel=0),
        m(timestamp=10.9, arbitration_id=0x181, is_extended_id=False, data=bytes([0xFF] * 8),
          channel=11),  # written as channel 12
        m(timestamp=11.0, arbitration_id=0x185, is_extended_id=False, data=[5], channel=9),
    ]


def _random_messages(n: int, seed: int) -> list[can.Message]:
    rnd = random.Random(seed)
    t = 100.0
    msgs = []
    for _ in range(n):
        t += rnd.choice((0.0, 0.000001, 0.0005, 0.01, 1.25))
        ext = rnd.random() < 0.3
        can_id = rnd.randrange(1 << 29) if ext else rnd.randrange(1 << 11)
        kind = rnd.random()
        chan = rnd.randrange(16)
        if kind < 0.15:
            msgs.append(can.Message(timestamp=t, arbitration_id=can_id, is_extended_id=ext,
                                    is_remote_frame=True, dlc=rnd.randrange(9), channel=chan))
        elif kind < 0.35:
            # no empty FD frames here: python-can reads those back as remote frames
            size = rnd.choice((1, 5, 8, 12, 16, 20, 24, 32, 48, 64))
            msgs.append(can.Message(timestamp=t, arbitration_id=can_id, is_extended_id=ext,
                                    is_fd=True, bitrate_switch=rnd.random() < 0.5,
                                    error_state_indicator=rnd.random() < 0.2,
                                    data=rnd.randbytes(size), channel=chan))
        else:
            msgs.append(can.Message(timestamp=t, arbitration_id=can_id, is_extended_id=ext,
                                    data=rnd.randbytes(rnd.randrange(9)), channel=chan,
                                    is_rx=rnd.random() < 0.5))
    return msgs


def _write_python_can(path: Path, msgs: list[can.Message]) -> None:
    writer = can.ASCWriter(str(path))
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
        assert ts == pytest.approx(msg.timestamp, abs=1e-9)
        assert chan == str(int(str(msg.channel)) + 1)  # python-can: 0-based; the file: 1-based
        assert err == msg.is_error_frame
        if err:
            continue  # python-can leaves is_extended_id at its default (True) for errors
        assert (can_id, ext, rtr, fd, dlc) == (
            msg.arbitration_id, msg.is_extended_id, msg.is_remote_frame, msg.is_fd, msg.dlc)
        assert data == bytes(msg.data[:8])
    return stats, ours


def test_python_can_written_fixed_messages(tmp_path: Path) -> None:
    path = tmp_path / "fixed.asc"
    _write_python_can(path, _fixed_messages())
    stats, ours = _compare_with_python_can(path)
    assert stats.format == "asc"
    assert stats.frames == 11
    assert stats.channels == ["1", "2", "3", "12", "10"]
    assert stats.remote_frames == 3
    assert stats.extended == 3
    assert stats.fd_frames == 2
    assert stats.ignored == 1  # "Start of measurement"
    assert stats.skipped == 0
    # the writer makes times relative to the first message: 10.0 s is written as 0.0
    assert ours[0] == (0.0, "1", 0x701, False, False, False, False, 1, b"\x00")
    assert ours[3][4:8] == (True, False, False, 1)
    assert ours[5][2:8] == (0x18FF00FE, True, True, False, False, 8)
    assert ours[6][6:] == (True, 12, bytes(range(8)))
    assert ours[7][2:8] == (0x1FFFFFFF, True, False, False, True, 64)
    assert ours[8][7:] == (0, b"")


def test_python_can_written_random_messages(tmp_path: Path) -> None:
    path = tmp_path / "random.asc"
    msgs = _random_messages(600, seed=7)
    _write_python_can(path, msgs)
    stats, _ = _compare_with_python_can(path)
    assert stats.frames == 600
    assert stats.extended == sum(m.is_extended_id for m in msgs)
    assert stats.remote_frames == sum(m.is_remote_frame for m in msgs)
    assert stats.fd_frames == sum(m.is_fd for m in msgs)
    assert set(stats.channels) == {str(int(str(m.channel)) + 1) for m in msgs}


def test_python_can_written_error_frames(tmp_path: Path) -> None:
    path = tmp_path / "err.asc"
    _write_python_can(path, [
        can.Message(timestamp=1.0, arbitration_id=0x701, is_extended_id=False, data=[0],
                    channel=0),
        can.Message(timestamp=1.25, is_error_frame=True, channel=0),
        can.Message(timestamp=1.5, is_error_frame=True, channel=3),
    ])
    stats, ours = _compare_with_python_can(path)
    assert stats.error_frames == 2 and stats.extended == 0
    assert ours[1] == (0.25, "1", 0, False, False, True, False, 0, b"")
    assert ours[2][:2] == (0.5, "4")


def test_python_can_written_empty_fd_frame_is_not_remote(tmp_path: Path) -> None:
    # ASCWriter writes DataLength 0 with flags 0x1000 (EDL) and no remote bit; python-can's
    # reader calls every CANFD line with DataLength 0 remote. CAN FD has no remote frames.
    path = tmp_path / "fd0.asc"
    _write_python_can(path, [can.Message(timestamp=1.0, arbitration_id=0x123,
                                         is_extended_id=False, is_fd=True, data=b"")])
    stats, ours = read(path)
    assert rows(stats, ours) == [(0.0, "1", 0x123, False, False, False, True, 0, b"")]
    assert stats.remote_frames == 0


# --- hand-written variants ---------------------------------------------------------------


def test_base_dec(tmp_path: Path) -> None:
    header = ["date Mon Jan 8 10:00:00.000 2024", "base dec  timestamps absolute",
              "internal events logged", "Begin Triggerblock Mon Jan 8 10:00:00.000 2024"]
    path = write_asc(tmp_path, [
        "   1.000000 1  1793            Rx   d 1 5",  # 0x701
        "   1.100000 1  0               Tx   d 2 1 5",  # NMT start node 5
        "   1.200000 1  419430400x      Rx   d 3 255 0 16",  # 0x19000000
        "   1.300000 2  1796            Rx   r 1",  # 0x704
    ], header=header)
    stats, cols = read(path)
    got = rows(stats, cols)
    assert got == [
        (1.0, "1", 0x701, False, False, False, False, 1, b"\x05"),
        (1.1, "1", 0x000, False, False, False, False, 2, b"\x01\x05"),
        (1.2, "1", 0x19000000, True, False, False, False, 3, b"\xff\x00\x10"),
        (1.3, "2", 0x704, False, True, False, False, 1, b""),
    ]
    _compare_with_python_can(path)  # python-can reads `base dec` correctly


def test_a_one_digit_data_byte_is_a_damaged_record(tmp_path: Path) -> None:
    """`base hex` data bytes are written `%02X`: `d 1 0` is a line cut inside its data
    byte (a recording killed mid-line), a skipped record, not a boot-up `702#00` (it gave
    B003, FAIL). Two digits, and `base dec`'s numbers, stay data."""
    path = write_asc(tmp_path, [
        "   0.400000 1  702             Rx   d 1 05",
        "   0.500000 1  702             Rx   d 1 0",
        "   0.600000 1  702             Rx   d 2 7F 0",
    ])
    stats, cols = read(path)
    assert stats.frames == 1 and stats.skipped == 2
    assert bytes(cols["data"][0, :1]) == b"\x05"


def test_timestamps_relative_accumulate(tmp_path: Path) -> None:
    header = ["date Mon Jan 8 10:00:00.000 2024", "base hex  timestamps relative",
              "internal events logged", "Begin Triggerblock Mon Jan 8 10:00:00.000 2024",
              "   0.000000 Start of measurement"]
    path = write_asc(tmp_path, [
        "   0.100000 1  701             Rx   d 1 05",
        "   0.200000 1  701             Rx   d 1 05",
        "   0.500000 1  Statistic: D 2 R 0 XD 0 XR 0 E 0 O 0 B 0.01%",  # an event, not a frame
        "   0.050000 1  705             Rx   d 1 7F",
        "   0.000000 1  706             Rx   d 1 7F",
        "   1.000000 CANFD   1 Rx        123                                   1 0 9 12 "
        "01 02 03 04 05 06 07 08 09 0A 0B 0C   102203  133   303000 e0006659 46500250 "
        "4b140250 20011736 2001040d",
    ], header=header)
    stats, cols = read(path)
    assert cols["ts"] == pytest.approx([0.1, 0.3, 0.85, 0.85, 1.85])
    assert stats.backwards_timestamps == 0
    assert stats.ignored == 2
    assert stats.start == pytest.approx(0.1) and stats.end == pytest.approx(1.85)
    # python-can 4.6.1 ignores "timestamps relative": it would give 0.1, 0.2, 0.05, 0.0, 1.0


def test_no_trigger_block(tmp_path: Path) -> None:
    header = ["date Mon Jan 8 10:00:00.000 2024", "base hex  timestamps absolute",
              "internal events logged", "// version 10.0.1"]
    path = tmp_path / "notrigger.asc"
    lines = header + [
        "   0.019968 1  64              Rx   d 4 64 00 00 00  Length = 0 BitCount = 0 ID = 100",
        "   0.029964 1  701             Rx   d 1 05  Length = 0 BitCount = 0 ID = 1793",
    ]
    path.write_text("\n".join(lines) + "\n")
    stats, cols = read(path)
    assert stats.frames == 2 and stats.skipped == 0
    assert list(cols["can_id"]) == [0x64, 0x701]
    assert list(cols["line"]) == [5, 6]
    _compare_with_python_can(path)


def test_repeated_trigger_blocks(tmp_path: Path) -> None:
    path = write_asc(tmp_path, [
        "   1.000000 1  701             Rx   d 1 05",
        "End TriggerBlock",
        "Begin Triggerblock Mon Jan 8 10:05:00.000 2024",
        "   0.000000 Start of measurement",
        "   0.500000 1  702             Rx   d 1 05",
        "End TriggerBlock",
        "// a comment between blocks",
        "Begin TriggerBlock Mon Jan 8 10:06:00.000 2024",
        "   2.000000 1  703             Rx   d 1 05",
    ])
    stats, cols = read(path)
    assert stats.frames == 3 and stats.skipped == 0
    assert list(cols["can_id"]) == [0x701, 0x702, 0x703]
    assert list(cols["ts"]) == [1.0, 0.5, 2.0]  # kept as written, in file order
    assert stats.backwards_timestamps == 1
    assert stats.ignored == 2


def test_txrq_lines_are_not_frames(tmp_path: Path) -> None:
    path = write_asc(tmp_path, [
        "   1.000000 1  000             TxRq d 2 01 05",
        "   1.000100 1  000             Tx   d 2 01 05",
        "   1.100000 2  18FF0001x       TxRq d 1 00",
        "   1.200000 CANFD   1 TxRq       123                                   1 0 8  8 "
        "01 02 03 04 05 06 07 08   102203  133   303000 e0006659 46500250 4b140250 20011736 "
        "2001040d",
    ])
    stats, cols = read(path)
    assert stats.frames == 1
    assert stats.ignored == 1 + 3  # Start of measurement + 3 TxRq
    assert list(cols["ts"]) == [1.0001]
    assert stats.channels == ["1"]
    assert stats.extended == 0 and stats.fd_frames == 0
    # python-can 4.6.1 yields all four lines as frames (its regex matches the `Tx` in `TxRq`)
    assert len(list(can.LogReader(str(path)))) == 4


def test_remote_frames(tmp_path: Path) -> None:
    path = write_asc(tmp_path, [
        "   2.510001 2 100 Rx r",
        "   2.520002 3 200 Tx r Length = 1704000 BitCount = 145 ID = 512",
        "   2.584921 4 300 Rx r 8 Length = 1704000 BitCount = 145 ID = 768",
        "   2.600000 1  704             Rx   r 1",
        "   2.700000 1  18FF0001x       Rx   r 0",
    ])
    stats, cols = read(path)
    assert stats.remote_frames == 5 and stats.frames == 5
    assert list(cols["dlc"]) == [0, 0, 8, 1, 0]
    assert list(cols["ext"]) == [False, False, False, False, True]
    assert stats.channels == ["2", "3", "4", "1"]
    _compare_with_python_can(path)


def test_error_frames(tmp_path: Path) -> None:
    path = write_asc(tmp_path, [
        "   2.501000 1 ErrorFrame",
        "   2.501010 1 ErrorFrame ECC: 10100010",
        "   2.501020 2 ErrorFrame Flags = 0xe CodeExt = 0x20a2 Code = 0x82 ID = 0 DLC = 0 "
        "Position = 5 Length = 11300",
        "   2.600000 3 OverloadFrame",
        "  30.806898 CANFD   5 Tx ErrorFrame Not Acknowledge error, dominant error flag fffe c7 "
        "31ca Arb. 556 44 0 0 f 64 " + "00 " * 64 + "1331984 11 0 46500250 460a0250 20011736 "
        "20010205",
    ])
    stats, cols = read(path)
    assert stats.frames == 4
    assert stats.error_frames == 4
    assert stats.extended == 0
    assert stats.skipped == 0
    assert stats.ignored == 2  # Start of measurement, OverloadFrame
    assert stats.channels == ["1", "2", "5"]
    assert not cols["dlc"].any() and not cols["can_id"].any()


def test_canfd_lines(tmp_path: Path) -> None:
    tail = "   102203  133   {flags} e0006659 46500250 4b140250 20011736 2001040d"
    path = write_asc(tmp_path, [
        # FD data, BRS: flags EDL|BRS
        "  30.005021 CANFD   1 Rx        300                                   1 0 9 12 "
        "11 c2 03 04 05 06 07 08 09 0a 0b 0c" + tail.format(flags="303000"),
        # with a symbolic name and an extended ID
        "  30.005071 CANFD   3 Rx        1C4D80A7x  Generic_Name_12            1 1 8  8 "
        "01 02 03 04 05 06 07 08" + tail.format(flags="303000"),
        # a classic frame on an FD channel: no EDL flag
        "  30.006000 CANFD   1 Rx        701                                   0 0 1  1 "
        "05" + tail.format(flags="0"),
        # a classic remote frame on an FD channel: flags bit 4, DLC 5, data length 0
        "  30.300981 CANFD   3 Tx     50005x                                0 1 5 0 140000 73 "
        "200050 7a60 46500250 460a0250 20011736 20010205",
        # an FD frame without data: EDL, no remote bit
        "  30.400000 CANFD   2 Rx        123                                   0 0 0  0 "
        "   0    0     1000        0        0        0        0        0",
        # 64 bytes, lower-case hex, DLC f
        "  30.506898 CANFD  12 Rx        4EE                                   0 1 f 64 "
        + "a1 " * 64 + "64 1331984 11 0 46500250 460a0250 20011736 20010205",
    ])
    stats, cols = read(path)
    got = rows(stats, cols)
    assert got == [
        (30.005021, "1", 0x300, False, False, False, True, 12, bytes.fromhex("11c2030405060708")),
        (30.005071, "3", 0x1C4D80A7, True, False, False, True, 8, bytes(range(1, 9))),
        (30.006, "1", 0x701, False, False, False, False, 1, b"\x05"),
        (30.300981, "3", 0x50005, True, True, False, False, 5, b""),
        (30.4, "2", 0x123, False, False, False, True, 0, b""),
        (30.506898, "12", 0x4EE, False, False, False, True, 64, b"\xa1" * 8),
    ]
    assert stats.fd_frames == 4 and stats.remote_frames == 1 and stats.skipped == 0


def test_status_statistic_and_other_events_are_ignored(tmp_path: Path) -> None:
    path = write_asc(tmp_path, [
        "   0.015991 CAN 1 Status:chip status error passive - TxErr: 132 RxErr: 0",
        "   0.015991 CAN 2 Status:chip status error active",
        "   1.015991 1  Statistic: D 0 R 0 XD 0 XR 0 E 0 O 0 B 0.00%",
        "   3.297743 1  J1939TP FEE3p        6    0  0   -   Rx   d 23 A0 0F A6 60 3B D1 40 1F "
        "DE 80 25 DF C0 2B E1 00 4B FF FF 3C 0F 00 4B FF FF FF FF FF FF FF FF FF FF FF FF",
        "   4.000000 SV: 1 0 1 ::Namespace::Var = 1",
        "   5.000000 log trigger event",
        "   6.000000 1  701             Rx   d 1 7F  Length = 240015 BitCount = 124 ID = 1793",
    ])
    stats, cols = read(path)
    assert stats.frames == 1
    assert stats.ignored == 7  # 6 above + Start of measurement
    assert stats.skipped == 0
    assert stats.channels == ["1"]
    assert list(cols["line"]) == [13]


def test_channels_above_nine(tmp_path: Path) -> None:
    path = write_asc(tmp_path, [
        "   1.000000 12  701             Rx   d 1 05",
        "   1.100000 1  701             Rx   d 1 05",
        "   1.200000 16  701             Rx   d 1 05",
        "   1.300000 12  702             Rx   d 1 05",
    ])
    stats, cols = read(path)
    assert stats.channels == ["12", "1", "16"]
    assert list(cols["chan"]) == [0, 1, 2, 0]
    _compare_with_python_can(path)


def test_cp1252_and_crlf(tmp_path: Path) -> None:
    body = [
        "// Kommentar: Größe, Qualität – ä",
        "   1.000000 1  701             Rx   d 1 05",
        "   1.100000 CANFD   1 Rx        181  Nachricht_ä                     1 0 8  8 "
        "01 02 03 04 05 06 07 08   102203  133   303000 e0006659 46500250 4b140250 20011736 "
        "2001040d",
    ]
    header = ["date Mo Mär 4 10:00:00.000 2024"] + HEADER[1:]
    crlf = write_asc(tmp_path, body, "crlf.asc", header=header)
    assert b"\xe4" in crlf.read_bytes() and b"\r\n" in crlf.read_bytes()
    lf = write_asc(tmp_path, body, "lf.asc", header=header, newline="\n")
    s_crlf, c_crlf = read(crlf)
    s_lf, c_lf = read(lf)
    assert rows(s_crlf, c_crlf) == rows(s_lf, c_lf)
    assert s_crlf.frames == 2 and s_crlf.skipped == 0
    assert rows(s_crlf, c_crlf)[1][2] == 0x181
    # python-can 4.6.1 opens ASC as UTF-8 text: it raises UnicodeDecodeError on this file
    with pytest.raises(UnicodeDecodeError), can.LogReader(str(crlf)) as reader:
        list(reader)


def test_classic_dlc_above_8(tmp_path: Path) -> None:
    path = write_asc(tmp_path, [
        # classic CAN with DLC 13: 8 bytes on the bus (issue_1299.asc)
        "  13.258671 1  3FF             Tx   d D 55 AA 01 02 03 04 05 06  Length = 232016",
        # a 64-byte frame written as a classic line (single_frame.asc): an FD frame
        " 14.000000 1  123x            Rx   d 40 " + " ".join(f"{i:02X}" for i in range(64)),
    ])
    _stats, cols = read(path)
    assert list(cols["dlc"]) == [13, 64]
    assert bytes(cols["data"][0]) == bytes.fromhex("55AA010203040506")
    assert list(cols["fd"]) == [False, True]
    assert bytes(cols["data"][1]) == bytes(range(8))


BAD_LINES = [
    "   1.500000 1  7G1             Rx   d 1 05",  # not hex
    "   1.500000 1  701             Rx   d 2 05",  # fewer bytes than the DLC
    "   1.500000 1  701             Rx   d 1 100",  # byte above FFh
    "   1.500000 1  801             Rx   d 1 05",  # 11-bit ID above 7FFh
    "   1.500000 1  701             Xx   d 1 05",  # unknown direction
    "   1.500000 1  701             Rx   q 1 05",
    "   1.500000 1  701",
    "   1.500000 1",
    "garbage line",
    "   nan 1  701             Rx   d 1 05",
    "   1.500000 CANFD   1 Rx        300   1 0 9 65 00",
    "   1.500000 CANFD   1 Rx",
]


def test_garbage_lines_are_skipped_with_line_numbers(tmp_path: Path) -> None:
    path = write_asc(tmp_path, ["   1.000000 1  701             Rx   d 1 05"] + BAD_LINES
                     + ["   2.000000 1  701             Rx   d 1 05"])
    stats, cols = read(path)
    first_bad = len(HEADER) + 2
    assert stats.frames == 2
    assert stats.skipped == len(BAD_LINES)
    assert stats.skipped_lines == list(range(first_bad, first_bad + 10))
    assert list(cols["line"]) == [first_bad - 1, first_bad + len(BAD_LINES)]


@pytest.mark.parametrize("bad", BAD_LINES)
def test_each_bad_line_is_skipped(tmp_path: Path, bad: str) -> None:
    stats, _ = read(write_asc(tmp_path, [bad, "   2.000000 1  701             Rx   d 1 05"]))
    assert (stats.frames, stats.skipped, stats.skipped_lines) == (1, 1, [len(HEADER) + 1])


def test_strict_makes_first_bad_line_fatal(tmp_path: Path) -> None:
    path = write_asc(tmp_path, [
        "   1.000000 1  701             Rx   d 1 05",
        "   1.100000 1  Statistic: D 0 R 0 XD 0 XR 0 E 0 O 0 B 0.00%",
        "   1.200000 1  000             TxRq d 2 01 05",
        "   1.300000 1  7G1             Rx   d 1 05",
        "garbage",
    ])
    opened = open_input(str(path), strict=True)
    with pytest.raises(InputError) as exc:
        list(opened.batches)
    line = len(HEADER) + 4
    assert exc.value.line == line
    assert str(exc.value).startswith(f"{path}:{line}: ")
    assert "asc" in str(exc.value)
