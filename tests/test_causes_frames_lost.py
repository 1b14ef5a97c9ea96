"""The `frames_lost` cause (SPEC §8.6.3, kind 5): a logger drop or a controller overflow
inside a finding's window. Recorded traffic (samples/heartbeat_loss.log: node 3 stops its
heartbeats at 1795299775.666 s, H001 at 775.816 s; the window is [774.666, 776.316] and
[776.767, 777.267] after node 3's next heartbeat) with the records a logger writes
inserted: candump's `DROPCOUNT` line, a SocketCAN controller error frame, a BLF
DATA_LOST_END object (the sample converted by python-can's BLFWriter) and a CSS CLX000
`Lost` count."""

from __future__ import annotations

import struct
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import can
from conftest import SAMPLES, Checker
from conftest import read_columns as read

from nmtcheck.engine import check_input, select_rules
from nmtcheck.readers import Drop
from nmtcheck.reporters import text
from nmtcheck.results import InputResult
from nmtcheck.settings.profiles import load_profile

LOG = (SAMPLES / "heartbeat_loss.log").read_text().splitlines(keepends=True)
DROP = "DROPCOUNT: dropped 17 CAN frames on 'can0' socket (total drops 17)\n"
# SocketCAN: CAN_ERR_FLAG | CAN_ERR_CRTL, byte 1 = CAN_ERR_CRTL_RX_OVERFLOW (01h) or
# CAN_ERR_CRTL_RX_WARNING (04h, no frame lost)
OVERFLOW = "(1795299775.700000) can0 20000004#0001000000000000\n"
WARNING = "(1795299775.700000) can0 20000004#0004000000000000\n"


def with_lines(at: int, *extra: str) -> str:
    """The sample with `extra` inserted after its line `at` (1-based)."""
    return "".join(LOG[:at] + list(extra) + LOG[at:])


def h001(checker: Checker, log: str) -> Any:
    res = checker.run(log)
    found = [f for f in res.findings if f.rule == "H001" and f.node == 3]
    assert len(found) == 1, [(f.rule, f.node) for f in res.findings]
    return res, found[0]


def lost(f: Any) -> list[dict[str, Any]]:
    return [c for c in f.causes or [] if c["kind"] == "frames_lost"]


def test_dropcount_inside_the_gap_is_a_cause(checker: Checker) -> None:
    # after line 75 (775.756512 s): the DROPCOUNT is line 76; its moment is the frame after
    # it (index 75, line 77, 775.790898 s): the lost frames were due before that one
    res, f = h001(checker, with_lines(75, DROP))
    [c] = lost(f)
    assert (c["time"], c["frame_index"], c["line"], c["count"], c["end"], c["node"]) == (
        1795299775.790898, 75, 76, 17, None, None)
    assert c["text"].startswith("the logger reported 17 frame(s) lost (1 DROPCOUNT record(s))")
    assert res.stats.dropped == 17 and res.stats.drops == [Drop(76, 17, None, None)]
    # the input finding sits at the same moment (SPEC: "the first such moment")
    [i004] = [r for r in res.findings if r.rule == "I004"]
    assert (i004.time, i004.frame_index, i004.line) == (1795299775.790898, 75, 76)
    assert i004.message.startswith("the logger reported 17 frames lost in 1 DROPCOUNT "
                                   "record, the first before frame 75 (the record at line 76)")
    # text: an indented cause line under the finding
    out = text.render([res], {})
    start = res.stats.start or 0.0
    assert f"        cause: {1795299775.790898 - start:.6f} s the logger reported 17 frame(s) " \
        "lost" in out


def test_dropcount_outside_the_window_is_no_cause(checker: Checker) -> None:
    # after the last line: 778.19 s, past the window's end (775.816 + 0.5 s)
    res, f = h001(checker, with_lines(len(LOG), DROP))
    assert res.stats.dropped == 17
    assert lost(f) == []
    _res, clean = h001(checker, "".join(LOG))
    assert lost(clean) == []


def test_controller_overflow_error_frame_is_a_cause(checker: Checker) -> None:
    _res, f = h001(checker, with_lines(75, OVERFLOW))
    [c] = lost(f)
    assert (c["time"], c["count"], c["line"]) == (1795299775.7, 1, 76)
    assert "controller overflow" in c["text"]
    # an error frame is also an error frame
    assert [c["count"] for c in f.causes if c["kind"] == "error_frames"] == [1]


def test_error_frame_without_overflow_is_no_lost_frame(checker: Checker) -> None:
    _res, f = h001(checker, with_lines(75, WARNING))
    assert lost(f) == []
    assert [c["count"] for c in f.causes if c["kind"] == "error_frames"] == [1]


# --- BLF: DATA_LOST_END objects (type 126), placed at their own time and the next frame ----

DATA_LOST_END = 126


def blf_with_losses(path: Path, losses: dict[int, tuple[float, int]]) -> Path:
    """The sample through python-can's BLFWriter, with a DATA_LOST_END object (queue,
    first lost object's time, count) at time t written before the sample's frame k, for
    each k: (t, count) of `losses`."""
    msgs = list(can.CanutilsLogReader(str(SAMPLES / "heartbeat_loss.log")))
    with can.BLFWriter(str(path)) as writer:
        for k, m in enumerate(msgs):
            if k in losses:
                t, count = losses[k]
                writer._add_object(DATA_LOST_END, struct.pack("<LQL", 1, 0, count), t)
            writer.on_message_received(m)
    return path


def check(path: Path) -> InputResult:
    profile = load_profile("default")
    return check_input(str(path), 0, profile, select_rules(profile, [], []))


def h001_of(res: InputResult) -> Any:
    found = [f for f in res.findings if f.rule == "H001" and f.node == 3]
    assert len(found) == 1, [(f.rule, f.node) for f in res.findings]
    return found[0]


def test_blf_data_lost_inside_the_gap_is_a_cause(tmp_path: Path) -> None:
    # written between frame 74 (775.756512 s) and frame 75 (775.790898 s), at 775.78 s
    path = blf_with_losses(tmp_path / "lost.blf", {75: (1795299775.78, 17)})
    stats, _cols = read(path, strict=True)
    assert stats.dropped == 17 and stats.frames == 192
    [d] = stats.drops
    assert (d.line, d.lost, d.frame) == (0, 17, 75) and round(d.ts or 0, 6) == 1795299775.78
    res = check(path)
    [c] = lost(h001_of(res))
    # at the object's time; the frame to open is the one after it; a BLF has no lines
    assert (c["time"], c["frame_index"], c["line"], c["count"], c["end"], c["node"]) == (
        1795299775.78, 75, None, 17, None, None)
    [i004] = [r for r in res.findings if r.rule == "I004"]
    assert (i004.time, i004.frame_index, i004.line) == (1795299775.78, 75, None)
    assert "in 1 BLF data-lost record, the first before frame 75;" in i004.message


def test_blf_data_lost_outside_the_window_is_no_cause(tmp_path: Path) -> None:
    # between frames 159 (777.667 s) and 160: past both parts of the window
    path = blf_with_losses(tmp_path / "late.blf", {160: (1795299777.69, 17)})
    res = check(path)
    assert res.stats.dropped == 17 and [(d.frame, d.lost) for d in res.stats.drops] == [
        (160, 17)]
    assert lost(h001_of(res)) == []


def test_blf_data_lost_counts_by_its_own_time_not_the_next_frame(tmp_path: Path) -> None:
    # both before frame 91 (776.340984 s, outside the window that ends at 776.316 s): the
    # object at 776.300 s is inside, the one at 776.330 s is not. Both come after the H001
    # (775.816 s): a drop then cannot have hidden the heartbeat whose absence fired it, so
    # the one inside the window is a reaction on the bus (SPEC §9.3.3), not a cause
    inside = check(blf_with_losses(tmp_path / "in.blf", {91: (1795299776.300, 5)}))
    assert lost(h001_of(inside)) == []
    [c] = [r for r in h001_of(inside).reactions or [] if r["kind"] == "frames_lost"]
    assert (c["time"], c["frame_index"], c["count"], c["role"]) == (
        1795299776.3, 91, 5, "bus")
    outside = check(blf_with_losses(tmp_path / "out.blf", {91: (1795299776.330, 5)}))
    assert [d.frame for d in outside.stats.drops] == [91]
    assert lost(h001_of(outside)) == []
    assert [r for r in h001_of(outside).reactions or [] if r["kind"] == "frames_lost"] == []


def _obj(otype: int, body: bytes, ts_10us: int) -> bytes:
    """A version 1 object with a timestamp in 10 µs units (flag 1), padded as Vector does."""
    size = 32 + len(body)
    return (struct.pack("<4sHHLLLHHQ", b"LOBJ", 32, 1, size, otype, 1, 0, 0, ts_10us)
            + body + b"\0" * (size % 4))


def test_blf_data_lost_outside_a_container_and_after_a_bad_object(tmp_path: Path) -> None:
    # frame 0 in a container; an object of an unknown header version (skipped, no frame);
    # then outside any container a DATA_LOST_END at 25 ms and frame 1: the drop is at frame 1
    def msg(can_id: int, ts: int, version: int = 1) -> bytes:
        o = bytearray(_obj(1, struct.pack("<HBBL8s", 1, 0, 1, can_id, b"\x05"), ts))
        o[6] = version
        return bytes(o)
    payload = msg(0x701, 0) + msg(0x702, 1000, version=7)
    container = (struct.pack("<4sHHLL", b"LOBJ", 16, 1, 32 + len(payload), 10)
                 + struct.pack("<H6xL4x", 0, len(payload)) + payload)
    header = struct.pack("<4sL", b"LOGG", 144).ljust(40, b"\0") + struct.pack(
        "<8H", 2024, 1, 1, 1, 12, 0, 0, 0)
    path = tmp_path / "lone.blf"
    path.write_bytes(header.ljust(144, b"\0") + container
                     + _obj(DATA_LOST_END, struct.pack("<LQL", 0, 0, 3), 2500)
                     + msg(0x703, 3000))
    stats, cols = read(path)
    assert list(cols["can_id"]) == [0x701, 0x703] and stats.skipped == 1
    [d] = stats.drops
    assert (d.line, d.lost, d.frame, round(d.ts or 0, 6)) == (0, 3, 1, 1704110400.025)


# --- CSS CLX000: the `Lost` column, placed at its record's frame --------------------------

CL_HEADER = ("# Logger type: CL2000\n# HW rev: 6.xx\n# FW rev: 5.31\n# Logger ID: LAB\n"
             "# Session No.: 3\n# Split No.: 1\n# Time: 20261121T222254\n"
             '# Value separator: ";"\n# Time format: 6\n# Time separator: ":"\n'
             '# Time separator ms: "."\n# Date separator: "/"\n'
             '# Time and date separator: "T"\n# Bit-rate: 500000\n# Silent mode: false\n'
             "# Cyclic mode: false\nTimestamp;Lost;Type;ID;Length;Data\n")
CL_FIRST_LINE = CL_HEADER.count("\n") + 1  # the line of the sample's first frame


def clx000(path: Path, lost_at: dict[int, int]) -> Path:
    """The sample as a CL2000 logger writes it (ms timestamps), `Lost` = lost_at[k] on the
    record of frame k."""
    rows = []
    for k, m in enumerate(can.CanutilsLogReader(str(SAMPLES / "heartbeat_loss.log"))):
        ms = round(m.timestamp * 1000)
        when = datetime.fromtimestamp(ms // 1000, timezone.utc)
        stamp = when.strftime("%Y/%m/%dT%H:%M:%S") + f".{ms % 1000:03d}"
        rows.append(f"{stamp};{lost_at.get(k, 0)};0;{m.arbitration_id:x};{m.dlc};"
                    f"{m.data.hex()}\n")
    path.write_text(CL_HEADER + "".join(rows))
    return path


def test_clx000_lost_inside_the_gap_is_a_cause(tmp_path: Path) -> None:
    # `Lost` on the record of frame 75 (775.791 s): the frames lost came before it
    res = check(clx000(tmp_path / "lost.txt", {75: 9}))
    assert res.stats.format == "cl2000" and res.stats.dropped == 9
    [c] = lost(h001_of(res))
    assert (c["time"], c["frame_index"], c["line"], c["count"]) == (
        1795299775.791, 75, CL_FIRST_LINE + 75, 9)
    [i004] = [r for r in res.findings if r.rule == "I004"]  # at the same moment
    assert (i004.time, i004.frame_index, i004.line) == (1795299775.791, 75, CL_FIRST_LINE + 75)
    assert "9 frames lost in 1 CL2000 Lost record" in i004.message


def test_i004_is_at_the_first_of_several_losses(tmp_path: Path) -> None:
    res = check(clx000(tmp_path / "two.txt", {160: 2, 40: 3}))
    [i004] = [r for r in res.findings if r.rule == "I004"]
    assert (i004.frame_index, i004.line) == (40, CL_FIRST_LINE + 40)
    assert i004.message.startswith("the logger reported 5 frames lost in 2 CL2000 Lost "
                                   "records, the first before frame 40")


def test_clx000_lost_outside_the_window_is_no_cause(tmp_path: Path) -> None:
    res = check(clx000(tmp_path / "late.txt", {160: 9}))
    assert res.stats.dropped == 9 and [(d.line, d.frame) for d in res.stats.drops] == [
        (CL_FIRST_LINE + 160, 160)]
    assert lost(h001_of(res)) == []
