"""The third-party log corpus (`../shared/corpus/third_party/`, see its PROVENANCE.md).

Every candump and ASC file is read without a crash and compared frame by frame
with python-can 4.6.1 (`can.LogReader`, or `CanutilsLogReader` on the
decompressed text where python-can cannot open the file); the places where
python-can misreads are listed one by one. The exact counts below are
regression pins: each comment says where the number comes from.
"""

from __future__ import annotations

import dataclasses
import gzip
import io
from pathlib import Path

import can
import numpy as np
import pytest
from conftest import CORPUS, needs_corpus

from nmtcheck.errors import InputError
from nmtcheck.readers import InputStats, open_input
from nmtcheck.readers.frames import FrameBatch

THIRD = CORPUS / "third_party"

pytestmark = needs_corpus


def read(path: Path) -> tuple[InputStats, dict[str, np.ndarray]]:
    opened = open_input(str(path))
    batches = list(opened.batches)
    names = [f.name for f in dataclasses.fields(FrameBatch)]
    return opened.stats, {n: np.concatenate([getattr(b, n) for b in batches]) for n in names}


CANDUMP = [
    "savvycan/candump.log",
    "css-electronics/multiGeneratorCAN.log",
    "scapy/candump.gz",  # gzip, no inner suffix
    "scapy/gmlan_trace.candump.gz",
]
ASC = [
    "python-can/issue_1256.asc",
    "python-can/issue_1299.asc",
    "python-can/logfile.asc",
    "python-can/logfile_errorframes.asc",
    "python-can/single_frame.asc",
    "python-can/single_frame_us_locale.asc",
    "python-can/test_CanErrorFrames.asc",
    "python-can/test_CanFdMessage.asc",
    "python-can/test_CanFdMessage64.asc",
    "python-can/test_CanFdRemoteMessage.asc",
    "python-can/test_CanMessage.asc",
    "python-can/test_CanMessage.asc.gz",
    "python-can/test_CanRemoteMessage.asc",
]

# Read by the BLF, TRC, CSV and CLX000 readers; pinned and compared with python-can in
# test_readers_blf.py, test_readers_trc.py and test_readers_csv.py. CarBusAnalyzer.trc (a
# different tool's format with PEAK's suffix) stays an "unknown log format".
BLF_TRC_CSV = [
    "python-can/issue_1905.blf",
    "python-can/test_CanErrorFrameExt.blf",
    "python-can/test_CanFdMessage.blf",
    "python-can/test_CanFdMessage64.blf",
    "python-can/test_CanMessage.blf",
    "python-can/test_CanMessage2.blf",
    "python-can/test_CanMessage.trc",
    "python-can/test_CanMessage_V1_0_BUS1.trc",
    "python-can/test_CanMessage_V1_1.trc",
    "python-can/test_CanMessage_V1_3.trc",
    "python-can/test_CanMessage_V2_0_BUS1.trc",
    "python-can/test_CanMessage_V2_1.trc",
    "savvycan/GVRET_Log.csv",
    "wireshark/canlogger-cl2000.txt",
]

# Read by the MF4 and pcap readers; pinned and compared with python-can (MF4) or a plain
# struct reading (pcap: python-can has no pcap reader) in test_readers_mf4.py and
# test_readers_pcap.py.
MF4_PCAP = [
    "css-electronics/17BD1DB7_00000006_00000170.MF4",
    "css-electronics/2F6913DB_00000004_00000001.MF4",
    "css-electronics/FCBF0606_00003482_00000001-60B621D9.MF4",
    "scapy/candump_gmlan_scanner.pcap.gz",
    "scapy/candump_uds_scanner.pcap.gz",
    "scapy/canfd.pcap.gz",
    "scapy/gmlan_trace.pcap.gz",
]

# Pinned from this reader's output (nmtcheck, this commit), cross-checked as noted:
# (frames, extended, error_frames, remote_frames, fd_frames, ignored, skipped, channels,
#  start, end). "PROV" = the frame count given in PROVENANCE.md (python-can 4.6.1).
EXPECTED: dict[str, tuple[int, int, int, int, int, int, int, list[str], float, float]] = {
    # PROV 12974; one line per frame (`grep -c .`); timestamps start at 166.0 s
    "savvycan/candump.log": (12974, 0, 0, 0, 0, 0, 0, ["vcan0"], 166.0, 174.0),
    # PROV: 164 frames, 128 FD, 82 extended; can0/can1
    "css-electronics/multiGeneratorCAN.log": (164, 82, 0, 0, 128, 0, 0, ["can0", "can1"],
                                              1581668399.05375, 1581668407.74865),
    # PROV: 9 frames (0x123 ×4, ext 0x1F334455 ×5)
    "scapy/candump.gz": (9, 5, 0, 0, 0, 0, 0, ["vcan0"], 1539191392.761779, 1539191495.56332),
    # PROV: 1087 lines, same frames as gmlan_trace.pcap.gz (relative, start 0.297 s)
    "scapy/gmlan_trace.candump.gz": (1087, 0, 0, 0, 0, 0, 0, ["vcan2"], 0.297, 4951.645),
    # PROV 1457; no trigger block and no "Start of measurement" line: nothing ignored
    "python-can/issue_1256.asc": (1457, 0, 0, 0, 0, 0, 0, ["1"], 0.019968, 7.960498),
    # PROV 4; ignored: Start of measurement
    "python-can/issue_1299.asc": (4, 0, 0, 0, 0, 1, 0, ["1"], 13.258199, 13.258907),
    # PROV 20 (4 RTR, 4 error, 4 FD by python-can). Extended: 8× 18EBFF00x + 50005x = 9
    # (python-can says 13: it marks its error frames extended). FD: 300, 4EE and the CANFD
    # ErrorFrame = 3 (50005x has no EDL flag: a classic remote frame on an FD channel).
    # Ignored: Start of measurement, 3 chip status, 6 Statistic, 2 J1939TP = 12.
    "python-can/logfile.asc": (20, 9, 4, 4, 3, 12, 0, ["1", "2", "3", "4", "5"],
                               2.501, 30.806898),
    # PROV 12 (2 RTR, 3 error); extended 6× 18EBFF00x; ignored: start + 2 chip status
    "python-can/logfile_errorframes.asc": (12, 6, 3, 2, 0, 3, 0, ["1", "2", "3", "4"],
                                           2.501, 20.248887),
    # PROV 1; `d 40`: 64 data bytes on a classic line, so an FD frame
    "python-can/single_frame.asc": (1, 1, 0, 0, 1, 1, 0, ["1"], 0.0, 0.0),
    "python-can/single_frame_us_locale.asc": (1, 1, 0, 0, 0, 1, 0, ["1"], 0.0, 0.0),
    # PROV 4 error frames, one of them a CANFD ErrorFrame
    "python-can/test_CanErrorFrames.asc": (4, 0, 4, 0, 1, 1, 0, ["1", "2", "5"],
                                           2.501, 30.806898),
    "python-can/test_CanFdMessage.asc": (3, 1, 0, 0, 3, 1, 0, ["1", "2", "3"],
                                         30.005021, 30.005071),
    "python-can/test_CanFdMessage64.asc": (2, 1, 0, 0, 2, 1, 0, ["4"], 30.506898, 31.506898),
    # flags 0x200050: remote (bit 4), no EDL: not FD (python-can says FD)
    "python-can/test_CanFdRemoteMessage.asc": (1, 1, 0, 1, 0, 1, 0, ["3"],
                                               30.300981, 30.300981),
    # 4-decimal timestamp; channel 2 comes first in the file
    "python-can/test_CanMessage.asc": (2, 0, 0, 0, 0, 1, 0, ["2", "1"], 2.501, 17.876708),
    "python-can/test_CanMessage.asc.gz": (2, 0, 0, 0, 0, 1, 0, ["2", "1"], 2.501, 17.876708),
    "python-can/test_CanRemoteMessage.asc": (3, 0, 0, 3, 0, 1, 0, ["2", "3", "4"],
                                             2.510001, 2.584921),
}

# Where python-can 4.6.1 misreads these files: (file, 1-based line, field).
PYTHON_CAN_WRONG = {
    # classic DLC 13 carries 8 bytes; python-can applies the FD table and reports 32
    ("python-can/issue_1299.asc", 9, "dlc"),
    # CANFD lines whose flags have no EDL bit (0x200050): classic remote frames
    ("python-can/logfile.asc", 34, "fd"),
    ("python-can/test_CanFdRemoteMessage.asc", 7, "fd"),
    # 64 data bytes cannot be classic CAN; python-can keeps is_fd False
    ("python-can/single_frame.asc", 6, "fd"),
}


def _python_can_messages(rel: str) -> list[can.Message]:
    path = THIRD / rel
    if rel.startswith("scapy/"):
        # python-can picks its reader by suffix and rejects `.gz` without an inner suffix
        with pytest.raises(ValueError):
            can.LogReader(str(path))
        text = gzip.decompress(path.read_bytes()).decode()
        return list(can.CanutilsLogReader(io.StringIO(text)))
    return list(can.LogReader(str(path)))


def test_corpus_file_lists_are_complete() -> None:
    """Every corpus file either is one of the lists above or is rejected as unknown."""
    readable = set()
    for path in sorted(THIRD.rglob("*")):
        if not path.is_file() or path.name == "PROVENANCE.md":
            continue
        rel = path.relative_to(THIRD).as_posix()
        try:
            opened = open_input(str(path))
        except InputError as exc:
            assert "unknown log format" in str(exc), rel
            continue
        for _ in opened.batches:
            pass
        readable.add(rel)
    assert readable == set(CANDUMP) | set(ASC) | set(BLF_TRC_CSV) | set(MF4_PCAP)


@pytest.mark.parametrize("rel", CANDUMP + ASC)
def test_pinned_stats(rel: str) -> None:
    stats, _ = read(THIRD / rel)
    frames, ext, err, rtr, fd, ignored, skipped, channels, start, end = EXPECTED[rel]
    assert stats.format == ("candump" if rel in CANDUMP else "asc")
    assert (stats.frames, stats.extended, stats.error_frames, stats.remote_frames,
            stats.fd_frames, stats.ignored, stats.skipped, stats.channels) == (
        frames, ext, err, rtr, fd, ignored, skipped, channels)
    assert stats.start == pytest.approx(start, abs=1e-9)
    assert stats.end == pytest.approx(end, abs=1e-9)
    assert stats.backwards_timestamps == 0
    assert stats.dropped == 0


@pytest.mark.parametrize("rel", CANDUMP + ASC)
def test_frames_match_python_can(rel: str) -> None:
    stats, cols = read(THIRD / rel)
    msgs = _python_can_messages(rel)
    assert len(msgs) == stats.frames == len(cols["ts"])
    candump = rel in CANDUMP
    differences = set()
    for i, msg in enumerate(msgs):
        line = int(cols["line"][i])
        dlc = int(cols["dlc"][i])
        err = bool(cols["err"][i])
        assert float(cols["ts"][i]) == pytest.approx(msg.timestamp, abs=1e-9)
        assert err == msg.is_error_frame
        if err:
            continue  # python-can leaves an error frame's is_extended_id at its default, True
        chan = msg.channel if candump else str(int(str(msg.channel)) + 1)  # python-can ASC: 0-based
        assert stats.channels[int(cols["chan"][i])] == chan
        ours = {
            "id": int(cols["can_id"][i]),
            "ext": bool(cols["ext"][i]),
            "rtr": bool(cols["rtr"][i]),
            "fd": bool(cols["fd"][i]),
            "dlc": dlc,
            "data": b"" if cols["rtr"][i] else bytes(cols["data"][i, : min(dlc, 8)]),
        }
        theirs = {
            "id": msg.arbitration_id,
            "ext": msg.is_extended_id,
            "rtr": msg.is_remote_frame,
            "fd": msg.is_fd,
            "dlc": msg.dlc,
            "data": bytes(msg.data[:8]),
        }
        differences |= {(rel, line, k) for k in ours if ours[k] != theirs[k]}
    assert differences == {d for d in PYTHON_CAN_WRONG if d[0] == rel}


@pytest.mark.parametrize("rel", ["scapy/candump.gz", "scapy/gmlan_trace.candump.gz"])
def test_gzip_without_inner_suffix_counts_lines(rel: str) -> None:
    text = gzip.decompress((THIRD / rel).read_bytes()).decode()
    stats, _ = read(THIRD / rel)
    assert stats.frames == sum(1 for line in text.splitlines() if line.strip())


def test_gzip_asc_equals_plain_asc() -> None:
    _a, ca = read(THIRD / "python-can/test_CanMessage.asc")
    _b, cb = read(THIRD / "python-can/test_CanMessage.asc.gz")
    for name in ca:
        np.testing.assert_array_equal(ca[name], cb[name], err_msg=name)


def test_logfile_asc_known_values() -> None:
    stats, c = read(THIRD / "python-can/logfile.asc")
    assert stats.error_frames == 4 and stats.remote_frames == 4
    err_lines = [int(x) for x in c["line"][c["err"]]]
    assert err_lines == [13, 14, 15, 36]  # 3 classic ErrorFrame variants + CANFD ErrorFrame
    rtr = {int(line): (int(i), bool(e), int(d)) for line, i, e, d in
           zip(c["line"][c["rtr"]], c["can_id"][c["rtr"]], c["ext"][c["rtr"]],
               c["dlc"][c["rtr"]], strict=True)}
    # `100 Tx r`, `200 Tx r Length = …`, `300 Tx r 8 …`, CANFD 50005x with flags 0x200050
    assert rtr == {16: (0x100, False, 0), 17: (0x200, False, 0), 18: (0x300, False, 8),
                   34: (0x50005, True, 5)}
    # line 33: CANFD 300 with a symbolic name, 8 bytes; line 35: CANFD 4EE, 64 bytes
    fd8 = int(np.flatnonzero(c["line"] == 33)[0])
    assert (int(c["can_id"][fd8]), int(c["dlc"][fd8])) == (0x300, 8)
    assert bool(c["fd"][fd8]) and bytes(c["data"][fd8]) == bytes(range(1, 9))
    fd64 = int(np.flatnonzero(c["line"] == 35)[0])
    assert (int(c["can_id"][fd64]), int(c["dlc"][fd64]), bool(c["fd"][fd64])) == (0x4EE, 64, True)
    # the J1939TP lines (23, 32) and the chip status lines are not frames
    assert not set(c["line"].tolist()) & {8, 9, 10, 11, 12, 23, 24, 27, 32}


def test_issue_1299_dlc_13() -> None:
    _stats, c = read(THIRD / "python-can/issue_1299.asc")
    i = int(np.flatnonzero(c["can_id"] == 0x3FF)[0])
    assert int(c["dlc"][i]) == 13
    assert bytes(c["data"][i]) == bytes.fromhex("55AA010203040506")  # 8 bytes on the bus
    assert not c["fd"][i]


def test_issue_1256_without_trigger_block() -> None:
    path = THIRD / "python-can/issue_1256.asc"
    assert b"Begin Triggerblock" not in path.read_bytes()
    stats, c = read(path)
    assert stats.frames == 1457
    assert int(c["line"][0]) == 5  # the first line after the 4 header lines
    assert int(c["can_id"][0]) == 0x64 and bytes(c["data"][0, :4]) == bytes.fromhex("64000000")


def test_savvycan_ids_0x708_to_0x754_are_ordinary_frames() -> None:
    # PROVENANCE: 0x708–0x754 frames with DLC 8 are automotive, not heartbeats; the reader
    # only reports them as 11-bit data frames with their 8 bytes
    _stats, c = read(THIRD / "savvycan/candump.log")
    sel = (c["can_id"] >= 0x708) & (c["can_id"] <= 0x754)
    assert sel.any()
    assert (c["dlc"][sel] == 8).all()
    assert not (c["ext"][sel] | c["rtr"][sel] | c["err"][sel]).any()
