"""CSV-like text logs: python-can's CSV, SavvyCAN/GVRET CSV and CSS Electronics CLX000 logs.

python-can CSV files are written by `can.CSVWriter` and compared with `can.CSVReader`.
SavvyCAN's example log (`corpus/third_party/savvycan/`) exists as GVRET CSV and as
candump `-L` with the same frames, so each is the other's reference; the CL2000 file
(`corpus/third_party/wireshark/`) is the example from CSS Electronics' documentation.
"""

from __future__ import annotations

import calendar
import random
from pathlib import Path

import can
import numpy as np
import pytest
from conftest import CORPUS, needs_corpus
from conftest import read_columns as read

from nmtcheck.errors import InputError
from nmtcheck.readers import InputStats, detect_format

THIRD = CORPUS / "third_party"


Row = tuple[float, str, int, bool, bool, bool, bool, int, bytes]


def rows(stats: InputStats, cols: dict[str, np.ndarray]) -> list[Row]:
    out = []
    for i in range(len(cols["ts"])):
        dlc = int(cols["dlc"][i])
        rtr, err = bool(cols["rtr"][i]), bool(cols["err"][i])
        data = b"" if rtr or err else bytes(cols["data"][i, : min(dlc, 8)])
        out.append((float(cols["ts"][i]), stats.channels[int(cols["chan"][i])],
                    int(cols["can_id"][i]), bool(cols["ext"][i]), rtr, err,
                    bool(cols["fd"][i]), dlc, data))
    return out


def write(tmp_path: Path, lines: list[str], name: str) -> Path:
    path = tmp_path / name
    path.write_text("".join(line + "\n" for line in lines))
    return path


# --- python-can CSV -----------------------------------------------------------------------


def test_python_can_csv_matches_python_can(tmp_path: Path) -> None:
    rnd = random.Random(7)
    msgs = []
    for i in range(2000):
        ext, rtr = rnd.random() < 0.2, rnd.random() < 0.05
        dlc = rnd.randint(0, 8)
        msgs.append(can.Message(timestamp=1_700_000_000 + i * 0.0137, is_extended_id=ext,
                                arbitration_id=rnd.randint(0, 0x1FFFFFFF if ext else 0x7FF),
                                is_remote_frame=rtr, dlc=dlc,
                                data=None if rtr else rnd.randbytes(dlc)))
    msgs.append(can.Message(timestamp=1_700_000_100.0, is_error_frame=True))
    path = tmp_path / "w.csv"
    with can.CSVWriter(str(path)) as writer:
        for m in msgs:
            writer.on_message_received(m)
    stats, cols = read(path, strict=True)
    assert stats.format == "csv" and stats.channels == ["1"]
    theirs = list(can.CSVReader(str(path)))
    assert [r[0] for r in rows(stats, cols)] == [m.timestamp for m in theirs]
    assert [r[2:] for r in rows(stats, cols)] == [
        (m.arbitration_id, m.is_extended_id and not m.is_error_frame, m.is_remote_frame,
         m.is_error_frame, False, m.dlc,
         b"" if m.is_remote_frame or m.is_error_frame else bytes(m.data)) for m in theirs]
    assert stats.error_frames == 1 and stats.frames == 2001


def test_python_can_csv_fd_frames_and_bad_rows(tmp_path: Path) -> None:
    path = write(tmp_path, [
        "timestamp,arbitration_id,extended,remote,error,dlc,data",
        "1.5,0x123,0,0,0,12,AAECAwQFBgcICQoL",  # 12 bytes: CAN FD (the writer has no FD column)
        "1.6,0x124,0,0,0,2,AQI=",
        "1.7,0x800,0,0,0,0,",  # an 11-bit ID above 7FFh
        "1.8,0x125,0,2,0,0,",  # a flag that is neither 0 nor 1
        "x,0x126,0,0,0,0,",
        "1.9,0x127,0,0,0,0",  # six columns
        "2.0,0x701,0,1,0,1,",  # a remote frame
    ], "fd.csv")
    stats, cols = read(path)
    assert [r[1:] for r in rows(stats, cols)] == [
        ("1", 0x123, False, False, False, True, 12, bytes(range(8))),
        ("1", 0x124, False, False, False, False, 2, b"\x01\x02"),
        ("1", 0x701, False, True, False, False, 1, b""),
    ]
    assert stats.skipped_lines == [4, 5, 6, 7]
    with pytest.raises(InputError) as exc:
        read(path, strict=True)
    assert str(exc.value).startswith(f"{path}:4: ")
    fd_only = write(tmp_path, path.read_text().splitlines()[:2], "fd-only.csv")
    assert not next(iter(can.CSVReader(str(fd_only)))).is_fd  # python-can: 12 bytes, classic


# --- SavvyCAN / GVRET CSV -----------------------------------------------------------------


@needs_corpus
def test_gvret_csv_has_the_frames_of_the_candump_log() -> None:
    stats, cols = read(THIRD / "savvycan" / "GVRET_Log.csv", strict=True)
    ref_stats, ref = read(THIRD / "savvycan" / "candump.log")
    assert stats.format == "csv" and stats.frames == ref_stats.frames == 12974
    for name in ("can_id", "ext", "rtr", "err", "fd", "dlc", "data"):
        np.testing.assert_array_equal(cols[name], ref[name], err_msg=name)
    assert stats.channels == ["0"]  # GVRET's 0-based bus number, as written
    # microsecond stamps: 166064000 -> 166.064 s (the candump copy was cut to 10 ms ticks)
    assert (stats.start, stats.end) == (166.064, 174.624)
    assert float(cols["ts"][4]) == 166.064 and int(cols["dlc"][4]) == 7
    assert list(cols["line"][:2]) == [2, 3]


@needs_corpus
def test_python_can_cannot_read_gvret_csv() -> None:
    with pytest.raises(ValueError):
        list(can.CSVReader(str(THIRD / "savvycan" / "GVRET_Log.csv")))


def test_gvret_csv_with_direction_column_and_bad_rows(tmp_path: Path) -> None:
    path = write(tmp_path, [
        "Time Stamp,ID,Extended,Dir,Bus,LEN,D1,D2,D3,D4,D5,D6,D7,D8",
        "39747828,000005EB,false,Rx,0,8,E8,45,85,4B,4A,28,36,69,",
        "39747900,18FEF100,true,Tx,1,3,01,02,03,00,00,00,00,00,",
        "39747950,00000701,false,Rx,1,1,05,00,00,00,00,00,00,00,",
        "39748000,00000801,false,Rx,0,1,05,00,00,00,00,00,00,00,",  # 11-bit above 7FFh
        "39748100,00000702,maybe,Rx,0,1,05,00,00,00,00,00,00,00,",
        "39748200,00000703,false,Rx,0,4,05,00,",  # fewer data bytes than LEN
    ], "v2.csv")
    assert detect_format(path.read_bytes()) == "csv"
    stats, cols = read(path)
    assert [r[1:] for r in rows(stats, cols)] == [
        ("0", 0x5EB, False, False, False, False, 8, bytes.fromhex("E845854B4A283669")),
        ("1", 0x18FEF100, True, False, False, False, 3, b"\x01\x02\x03"),
        ("1", 0x701, False, False, False, False, 1, b"\x05"),
    ]
    assert list(cols["ts"]) == [39.747828, 39.7479, 39.74795]
    assert stats.channels == ["0", "1"] and stats.skipped_lines == [5, 6, 7]


def test_csv_detection() -> None:
    assert detect_format(b"timestamp,arbitration_id,extended,remote,error,dlc,data\n") == "csv"
    assert detect_format(b"Time Stamp,ID,Extended,Bus,LEN,D1,D2,D3\n") == "csv"
    assert detect_format(b"Time Stamp,ID,Extended,Dir,Bus,LEN,D1,D2\n1,2\n") == "csv"
    assert detect_format(b"timestamp,id,data\n1,2,3\n") is None
    assert detect_format(b"ID,Data Bytes\n4f5,ff 34\n") is None


# --- CSS Electronics CLX000 ---------------------------------------------------------------

CL_HEADER = [
    "# Logger type: CL1000", "# HW rev: 6.xx", "# FW rev: 5.31", "# Logger ID: LAB",
    "# Session No.: 3", "# Split No.: 1", "# Time: 20240301T120000",
]


@needs_corpus
def test_cl2000_documentation_example() -> None:
    path = THIRD / "wireshark" / "canlogger-cl2000.txt"
    assert detect_format(path.read_bytes()) == "cl2000"
    stats, cols = read(path, strict=True)
    start = calendar.timegm((2017, 1, 1, 2, 22, 31, 0, 0, 0))
    got = rows(stats, cols)
    assert [round(r[0] - start, 3) for r in got] == [0.683, 0.688, 0.693, 0.701, 0.783, 0.788,
                                                     0.793, 0.801]
    assert [r[1:] for r in got[:2]] == [
        ("1", 0x7DF, False, False, False, False, 8, bytes.fromhex("02010d5555555555")),
        ("1", 0x7E8, False, False, False, False, 8, bytes.fromhex("03410d00aaaaaaaa")),
    ]
    assert stats.frames == 8 and stats.channels == ["1"] and stats.skipped == 0


def test_clx000_separators_time_format_lost_and_length(tmp_path: Path) -> None:
    path = write(tmp_path, CL_HEADER + [
        '# Value separator: ","', "# Time format: 6", '# Time separator: ":"',
        '# Time separator ms: "."', '# Date separator: "/"', '# Time and date separator: "T"',
        "# Bit-rate: 250000", "# Silent mode: false", "# Cyclic mode: false",
        "Timestamp,Lost,Type,ID,Length,Data",
        "2024/03/01T12:00:01.250,0,0,701,1,05",
        "2024/03/01T12:00:01.500,4,9,18FEF100,3,010203",
        "2024/03/01T12:00:02.000,0,1,18FEF101,0,",
        "2024/03/01T12:00:02.100,0,5,702,1,05",  # unknown type
        "2024/03/01T12:00:02.200,0,0,703,2,05",  # length does not match the data
        "2024/03/01T12:61:02.300,0,0,704,1,05",  # not a time
    ], "clx.txt")
    stats, cols = read(path)
    start = calendar.timegm((2024, 3, 1, 12, 0, 0, 0, 0, 0))
    got = rows(stats, cols)
    assert [round(r[0] - start, 3) for r in got] == [1.25, 1.5, 2.0]
    assert [r[1:] for r in got] == [
        ("1", 0x701, False, False, False, False, 1, b"\x05"),
        ("1", 0x18FEF100, True, False, False, False, 3, b"\x01\x02\x03"),
        ("1", 0x18FEF101, True, False, False, False, 0, b""),
    ]
    assert stats.dropped == 4 and stats.skipped_lines == [21, 22, 23]


def test_clx000_short_timestamps_take_the_header_date(tmp_path: Path) -> None:
    # time format 4 (DDThhmmsskkk): year and month come from "# Time"
    path = write(tmp_path, CL_HEADER + ['# Value separator: ";"', "# Time format: 4",
                                        '# Time and date separator: "T"',
                                        "Timestamp;Type;ID;Data",
                                        "01T120000683;8;7df;02010d5555555555",
                                        "02T000000001;0;7e8;03410d00aaaaaaaa"], "short.txt")
    _stats, cols = read(path, strict=True)
    assert list(cols["ts"]) == [calendar.timegm((2024, 3, 1, 12, 0, 0, 0, 0, 0)) + 0.683,
                                calendar.timegm((2024, 3, 2, 0, 0, 0, 0, 0, 0)) + 0.001]


def test_clx000_detection() -> None:
    assert detect_format(b"# Logger type: CL2000\n# HW rev: 6.xx\n") == "cl2000"
    assert detect_format(b"# Logger type: CANLogger1000\n") == "cl2000"
    assert detect_format(b"# Logger type: something else\n") is None
