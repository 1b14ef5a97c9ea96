"""PEAK TRC reader.

The python-can test files (`corpus/third_party/python-can/*.trc`, one per version, one
of them written by PCAN-View itself) are compared with python-can's `TRCReader` frame
by frame; the versions and records it cannot read (1.2, error frames, CAN FD lengths)
are hand-written in the layout of PEAK's format description and of those files.
"""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import can
import numpy as np
import pytest
from conftest import CORPUS, needs_corpus, shared_file
from conftest import read_columns as read

from nmtcheck.errors import InputError
from nmtcheck.readers import FORMATS, InputStats, detect_format, open_input
from nmtcheck.readers.trc import start_time_from_ole_days

THIRD = CORPUS / "third_party"
PCAN = THIRD / "python-can"
HAVE_CORPUS = THIRD.is_dir()
CORPUS_TRC = sorted(p.name for p in PCAN.glob("*.trc")) if HAVE_CORPUS else []
CAR_BUS_ANALYZER = "corpus/third_party/savvycan/CarBusAnalyzer.trc"  # copied to tests/data

START_DAYS = 44548.6028595139  # 2021-12-18 14:28:07.062 (the corpus files' $STARTTIME)
START = start_time_from_ole_days(START_DAYS)


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


def python_can_rows(path: Path) -> list[Row]:
    return [(m.timestamp, str(m.channel), m.arbitration_id, m.is_extended_id, m.is_remote_frame,
             m.is_error_frame, m.is_fd, m.dlc,
             b"" if m.is_remote_frame else bytes(m.data[: min(m.dlc, 8)]))
            for m in can.TRCReader(str(path))]


def write(tmp_path: Path, lines: list[str], name: str = "trace.trc") -> Path:
    path = tmp_path / name
    path.write_bytes("".join(line + "\r\n" for line in lines).encode("cp1252"))
    return path


# the eleven frames every python-can TRC test file holds (ID 0x000 with DLC 8 is a
# malformed NMT command; the remote frame on 704h is a node-guarding request for node 4)
OFFSETS_MS = [17535.4, 17700.3, 17873.8, 19295.4, 19500.6, 19705.2, 20592.7, 20798.6, 20956.0,
              21097.1, 48937.6]
IDS = [0x100, 0x100, 0x100, 0x000, 0x000, 0x000, 0x100, 0x100, 0x100, 0x100, 0x704]


# --- the corpus ---------------------------------------------------------------------------


@needs_corpus
@pytest.mark.parametrize("name", CORPUS_TRC)
def test_corpus_matches_python_can(name: str) -> None:
    path = PCAN / name
    stats, cols = read(path, strict=True)
    assert stats.format == "trc"
    ours, theirs = rows(stats, cols), python_can_rows(path)
    assert len(ours) == len(theirs) == stats.frames
    for a, b in zip(ours, theirs, strict=True):
        assert a[0] == pytest.approx(b[0], abs=1e-6)
        assert a[1:] == b[1:]


@needs_corpus
@pytest.mark.parametrize("name", [n for n in CORPUS_TRC if n != "test_CanMessage.trc"])
def test_corpus_versions_hold_the_same_frames(name: str) -> None:
    stats, cols = read(PCAN / name)
    v1_0 = name == "test_CanMessage_V1_0_BUS1.trc"  # offsets in whole ms, no $STARTTIME
    expected_ts = [(math.floor(o) if v1_0 else o) / 1000 + (0.0 if v1_0 else START)
                   for o in OFFSETS_MS]
    assert list(cols["ts"]) == pytest.approx(expected_ts, abs=1e-6)
    assert list(cols["can_id"]) == IDS
    assert list(cols["ext"]) == [i == 0x100 for i in IDS]  # 8 hex digits: 29-bit
    assert list(cols["rtr"]) == [False] * 10 + [True]
    assert int(cols["dlc"][-1]) == 1 and (cols["dlc"][:10] == 8).all()
    # the bus-status line (FFFFFFFF / Warng / ST) is counted as a non-frame record
    assert (stats.frames, stats.ignored, stats.skipped, stats.channels) == (11, 1, 0, ["1"])


@needs_corpus
def test_converted_asc_file_channels_and_start() -> None:
    stats, cols = read(PCAN / "test_CanMessage.trc")
    assert stats.channels == ["2", "1"]
    assert rows(stats, cols)[0][1:] == ("2", 0xC8, False, False, False, False, 8,
                                        bytes.fromhex("0908070605040302"))
    start = start_time_from_ole_days(43008.920986006946)  # 2017-09-30 22:06:13.191
    assert float(cols["ts"][0]) == pytest.approx(start + 2.501, abs=1e-6)
    assert float(cols["ts"][1]) == pytest.approx(start + 17.876708, abs=1e-6)


def test_car_bus_analyzer_trc_is_rejected_not_misread() -> None:
    path = shared_file(CAR_BUS_ANALYZER)
    assert detect_format(path.read_bytes()[:65536]) is None
    with pytest.raises(InputError) as exc:
        open_input(str(path))
    message = str(exc.value)
    assert message.startswith(f"{path}: unknown log format")
    assert all(name in message for name in FORMATS) and "--input-format" in message
    # forced: its CR-only "lines" are not TRC records, and none becomes a frame
    stats, _ = read(path, input_format="trc")
    assert stats.frames == 0 and stats.skipped >= 1
    with pytest.raises(ValueError):
        list(can.TRCReader(str(path)))  # python-can fails on it too, with a traceback


def test_car_bus_analyzer_trc_exits_2_with_one_line(tmp_path: Path) -> None:
    path = shared_file(CAR_BUS_ANALYZER)
    res = subprocess.run([sys.executable, "-m", "nmtcheck", "check", str(path)], cwd=tmp_path,
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 2 and "Traceback" not in res.stderr
    supported = ", ".join(FORMATS)
    (line,) = res.stderr.strip().splitlines()
    assert line.startswith(
        f"nmtcheck: {path}: unknown log format (supported: {supported}; use --input-format NAME)")
    # the first line that looks like a frame is quoted (issue 38): a CR-only line end
    # cuts it, as an editor shows the file
    assert "; line 1 looks like a CAN frame but no format reads it: `46,016 1 0004 45A 8" in line


# --- versions python-can cannot read ------------------------------------------------------

V1_2 = [
    ";$FILEVERSION=1.2",
    f";$STARTTIME={START_DAYS}",
    ";   Generated by PCAN-Explorer v5.0.0.851",
    ";-------------------------------------------------------------------------------",
    ";   Bus  Name         Connection               Protocol  Bit rate",
    ";   1    Connection1  TestNet@pcan_usb         CAN       500 kbit/s",
    ";   2    Connection2  TestNet2@pcan_usb        CAN       500 kbit/s",
    ";-------------------------------------------------------------------------------",
    ";   Message Number",
    ";   |         Time Offset (ms)",
    ";   |         |       Bus",
    ";   |         |       |    Type",
    ";   |         |       |    |       ID (hex)",
    ";   |         |       |    |       |     Data Length Code",
    ";   |         |       |    |       |     |   Data Bytes (hex) ...",
    ";---+-- ------+------ +- --+-- ----+---  +  -+ -- -- -- -- -- -- --",
    "     1)      1841.180 1  Tx        0701  1  00",
    "     2)      1842.347 1  Warng FFFFFFFF  4  00 00 00 08 BUSHEAVY",
    "     3)      1843.203 2  Rx        0702  1  05",
    "     4)      1844.900 2  Error     0008  4  00 19 08 08",
    "     5)      1845.000 1  Rx        0703  1  RTR",
    "     6)      1846.000 2  Rx    1ABCDEF0  2  11 22",
]


def test_version_1_2(tmp_path: Path) -> None:
    path = write(tmp_path, V1_2)
    stats, cols = read(path, strict=True)
    got = rows(stats, cols)
    assert [r[1:] for r in got] == [
        ("1", 0x701, False, False, False, False, 1, b"\x00"),
        ("2", 0x702, False, False, False, False, 1, b"\x05"),
        ("2", 0, False, False, True, False, 0, b""),
        ("1", 0x703, False, True, False, False, 1, b""),
        ("2", 0x1ABCDEF0, True, False, False, False, 2, b"\x11\x22"),
    ]
    assert [r[0] - START for r in got] == pytest.approx([1.84118, 1.843203, 1.8449, 1.845,
                                                         1.846], abs=1e-6)
    assert (stats.ignored, stats.error_frames, stats.channels) == (1, 1, ["1", "2"])


def test_python_can_crashes_on_version_1_2(tmp_path: Path) -> None:
    path = write(tmp_path, V1_2)
    with pytest.raises(ValueError):  # it parses 1.2 as 1.0 and takes "Tx" for a DLC
        list(can.TRCReader(str(path)))


@needs_corpus
def test_version_1_2_converted_from_the_corpus_1_3_file(tmp_path: Path) -> None:
    # 1.3 is 1.2 plus a reserved column: dropping it must give the same frames
    lines = (PCAN / "test_CanMessage_V1_3.trc").read_text().splitlines()
    converted = []
    for line in lines:
        if line.startswith(";$FILEVERSION"):
            line = ";$FILEVERSION=1.2"
        elif not line.startswith(";"):
            tokens = line.split()
            line = "  ".join(tokens[:5] + tokens[6:])
        converted.append(line)
    a, ca = read(PCAN / "test_CanMessage_V1_3.trc")
    b, cb = read(write(tmp_path, converted), strict=True)
    assert rows(a, ca) == rows(b, cb) and (a.ignored, b.ignored) == (1, 1)


# --- error frames and status records: counted, never dropped ------------------------------


def test_error_and_status_lines_of_every_version(tmp_path: Path) -> None:
    files = {
        "1.0": [";##########", "     1)      1841  0701  1  05",
                "     2)      1842  0008  4  ERROR 00 19 08 08",
                "     3)      1843  FFFFFFFF  4  00 00 00 04 -- -- -- -- BUSLIGHT",
                "     4)      1844  0100  3  RTR"],
        "1.1": [";$FILEVERSION=1.1", f";$STARTTIME={START_DAYS}",
                "     1)      1841.0  Rx         0701  1  05",
                "     2)      1842.3  Error      0008  4  00 19 08 08",
                "     3)      1843.2  Warng  FFFFFFFF  4  00 00 00 04  BUSLIGHT",
                "     4)      1844.0  Rx         0100  3  RTR"],
        "1.3": [";$FILEVERSION=1.3", f";$STARTTIME={START_DAYS}",
                "     1)      1841.000 1  Rx        0701 -  1    05",
                "     2)      1842.300 1  Error     0008 -  4    00 19 08 08",
                "     3)      1843.200 1  Warng FFFFFFFF -  4    00 00 00 04 BUSLIGHT",
                "     4)      1844.000 1  Rx        0100 -  3    RTR"],
        "2.0": [";$FILEVERSION=2.0", f";$STARTTIME={START_DAYS}", ";$COLUMNS=N,O,T,I,d,l,D",
                "      1      1841.000 DT     0701 Rx 1  05",
                "      2      1842.300 ER          Rx    02 00 05 00 00",
                "      3      1843.200 ST          Rx    00 00 00 04",
                "      4      1844.000 RR     0100 Rx 3",
                "      5      1844.500 EC          Rx    00 00 60 00",
                "      6      1844.700 EV                User-defined text"],
        "2.1": [";$FILEVERSION=2.1", f";$STARTTIME={START_DAYS}",
                ";$COLUMNS=N,O,T,B,I,d,R,L,D",
                "      1      1841.000 DT 1      0701 Rx -  1    05",
                "      2      1842.300 ER 1         - Rx -  5    02 00 05 00 00",
                "      3      1843.200 ST 1         - Rx -  4    00 00 00 04",
                "      4      1844.000 RR 1      0100 Rx -  3",
                "      5      1844.500 EC 1         - Rx -  4    00 00 60 00",
                "      6      1844.700 EV 1 User-defined text"],
    }
    for version, lines in files.items():
        stats, cols = read(write(tmp_path, lines, f"v{version}.trc"), strict=True)
        assert stats.format == "trc", version
        start = 0.0 if version == "1.0" else START
        got = rows(stats, cols)
        assert [r[1:] for r in got] == [
            ("1", 0x701, False, False, False, False, 1, b"\x05"),
            ("1", 0, False, False, True, False, 0, b""),
            ("1", 0x100, False, True, False, False, 3, b""),
        ], version
        assert got[1][0] == pytest.approx(start + (1.842 if version == "1.0" else 1.8423))
        assert stats.error_frames == 1 and stats.remote_frames == 1, version
        assert stats.ignored == {"1.0": 1, "1.1": 1, "1.3": 1, "2.0": 3, "2.1": 3}[version]
        theirs = tmp_path / f"v{version}.trc"
        if version == "1.0":  # python-can takes "ERROR" for a data byte and crashes
            with pytest.raises(ValueError):
                list(can.TRCReader(str(theirs)))
        else:  # python-can drops the error frames (and the status lines) without a word
            assert [m.is_error_frame for m in can.TRCReader(str(theirs))] == [False, False]


# --- CAN FD in version 2.x ----------------------------------------------------------------


def test_can_fd_frames_report_their_data_length(tmp_path: Path) -> None:
    data12 = " ".join(f"{i:02X}" for i in range(12))
    v21 = write(tmp_path, [";$FILEVERSION=2.1", f";$STARTTIME={START_DAYS}",
                           ";$COLUMNS=N,O,T,B,I,d,R,L,D",
                           f"      1         1.000 FD 1      0123 Rx -  9    {data12}",
                           f"      2         2.000 FB 2  00012345 Tx -  9    {data12}",
                           "      3         3.000 DT 1      0701 Rx -  1    05"], "fd21.trc")
    v20 = write(tmp_path, [";$FILEVERSION=2.0", f";$STARTTIME={START_DAYS}",
                           ";$COLUMNS=N,O,T,I,d,l,D",
                           f"      1         1.000 FD     0123 Rx 12 {data12}",
                           f"      2         2.000 BI 00012345 Tx 12 {data12}",
                           "      3         3.000 DT     0701 Rx 1  05"], "fd20.trc")
    for path, chans in ((v21, ["1", "2", "1"]), (v20, ["1", "1", "1"])):
        stats, cols = read(path, strict=True)
        assert [r[1:] for r in rows(stats, cols)] == [
            (chans[0], 0x123, False, False, False, True, 12, bytes(range(8))),
            (chans[1], 0x12345, True, False, False, True, 12, bytes(range(8))),
            (chans[2], 0x701, False, False, False, False, 1, b"\x05"),
        ]
        assert stats.fd_frames == 2
    # python-can reports the DLC code 9 (2.1) and re-encodes the length 12 into DLC 9 (2.0)
    assert [m.dlc for m in can.TRCReader(str(v21))][:2] == [9, 9]
    assert [m.dlc for m in can.TRCReader(str(v20))][:2] == [9, 9]


# --- detection, header and bad lines ------------------------------------------------------


def test_detection() -> None:
    assert detect_format(b";$FILEVERSION=2.1\r\n;$STARTTIME=44548.6\r\n") == "trc"
    assert detect_format(b";####\r\n;   C:\\x.trc\r\n     1)     17535  0100  8  00\r\n") == "trc"
    assert detect_format(b"     1)     17535  00000100  8  00 00 00 00 00 00 00 00\r\n") == "trc"
    assert detect_format(b"; just a comment\r\n; and another\r\n") is None
    assert detect_format(b"@ TEXT @ 2 @ 64 @ 0 @ 55 @\r46,016\t1\t0004\t45A\t8\t5A\r") is None


def test_start_time_is_days_since_1899() -> None:
    assert start_time_from_ole_days(25569.0) == 0.0  # 1970-01-01
    assert start_time_from_ole_days(25569.5) == 43200.0


def test_bad_lines_are_skipped_and_fatal_under_strict(tmp_path: Path) -> None:
    path = write(tmp_path, [";$FILEVERSION=1.1", f";$STARTTIME={START_DAYS}",
                            "     1)      1841.0  Rx         0701  1  05",
                            "     2)      1842.x  Rx         0701  1  05",
                            "     3)      1843.0  Rx         0701  2  05",
                            "     4)      1844.0  Rx         0800  1  05",
                            "     5)      1845.0  Qx         0701  1  05",
                            "     6)      1846.0  Rx         0701  1  05"])
    stats, _cols = read(path)
    assert stats.frames == 2 and stats.skipped == 4 and stats.skipped_lines == [4, 5, 6, 7]
    with pytest.raises(InputError) as exc:
        read(path, strict=True)
    assert str(exc.value).startswith(f"{path}:4: ") and "time offset" in str(exc.value)


def test_unknown_version_and_missing_columns_are_input_errors(tmp_path: Path) -> None:
    with pytest.raises(InputError) as exc:
        read(write(tmp_path, [";$FILEVERSION=3.7", "   1  1.0 DT 0701 Rx 1 05"], "v37.trc"))
    assert "version 3.7" in str(exc.value)
    with pytest.raises(InputError) as exc:
        read(write(tmp_path, [";$FILEVERSION=2.1", ";$COLUMNS=N,O,T", "   1  1.0 DT"], "c.trc"))
    assert "$COLUMNS" in str(exc.value)
