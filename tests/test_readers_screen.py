"""candump screen output (`candump can0 > file`, not `-l`/`-L`).

Lines are written here in the exact printf layouts of can-utils' candump.c and
lib.c (`sprint_long_canframe`): ` (%010ld.%06ld)  %*s  %03X   [%d]  %02X …`.
python-can has no reader for this format, so the reference is the candump `-L`
log of the same frames.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import SAMPLES
from conftest import read_columns as read

from nmtcheck.errors import InputError
from nmtcheck.readers import InputStats, detect_format

ESC = "\x1b"
BLUE, RED, RESET = f"{ESC}[1m{ESC}[34m", f"{ESC}[1m{ESC}[31m", f"{ESC}[0m"


Row = tuple[float, str, int, bool, bool, bool, bool, int, bytes]


def rows(stats: InputStats, cols: dict[str, np.ndarray]) -> list[Row]:
    out = []
    for i in range(len(cols["ts"])):
        dlc = int(cols["dlc"][i])
        rtr, err = bool(cols["rtr"][i]), bool(cols["err"][i])
        data = b"" if rtr else bytes(cols["data"][i, : min(dlc, 8)])
        out.append((round(float(cols["ts"][i]), 6), stats.channels[int(cols["chan"][i])],
                    int(cols["can_id"][i]), bool(cols["ext"][i]), rtr, err,
                    bool(cols["fd"][i]), dlc, data))
    return out


def write(tmp_path: Path, lines: list[str], name: str = "screen.txt") -> Path:
    path = tmp_path / name
    path.write_text("".join(line + "\n" for line in lines))
    return path


def screen_line(stamp: str, iface: str, can_id: int, data: bytes, *, ext: bool = False,
                fd: bool = False, rtr: bool = False, err: bool = False, dlc: int | None = None,
                extra: str = "", indent: bool = False) -> str:
    """One line the way candump prints it (timestamp mode already formatted)."""
    if err or ext:
        ident = f"{can_id | (0x20000000 if err else 0):08X}  "
    else:
        ident = f"     {can_id:03X}  " if indent else f"{can_id:03X}  "
    length = len(data) if dlc is None else dlc
    body = f"[{length:02d}] " if fd else f" [{length}] "
    if rtr:
        body = f" [{length}]  remote request"
    else:
        body += "".join(f" {b:02X}" for b in data)
        if err:
            body += f"{'ERRORFRAME':>{3 * (8 - len(data)) + 13}}"
    prefix = f" {stamp} " if stamp else " "
    return f"{prefix} {iface}{extra}  {ident}{body}"


# --- one file per timestamp mode ----------------------------------------------------------

FRAMES: list[tuple[float, int, bytes, dict[str, Any]]] = [  # (seconds, id, data, kwargs)
    (1700000000.000100, 0x701, b"\x00", {}),
    (1700000000.100200, 0x000, b"\x01\x00", {}),
    (1700000000.250300, 0x704, b"", {"rtr": True, "dlc": 1}),
    (1700000000.250900, 0x1ABCDE, b"\x11\x22", {"ext": True}),
    (1700000000.600000, 0x123, bytes(range(12)), {"fd": True}),
    (1700000000.700001, 0x004, bytes([0, 4, 0, 0, 0, 0, 0, 0]), {"err": True}),
    (1700000000.700002, 0x185, b"\x01\x02\x03", {}),
]
EXPECTED = [
    (0x701, False, False, False, False, 1, b"\x00"),
    (0x000, False, False, False, False, 2, b"\x01\x00"),
    (0x704, False, True, False, False, 1, b""),
    (0x1ABCDE, True, False, False, False, 2, b"\x11\x22"),
    (0x123, False, False, False, True, 12, bytes(range(8))),
    (0x004, False, False, True, False, 8, bytes([0, 4, 0, 0, 0, 0, 0, 0])),
    (0x185, False, False, False, False, 3, b"\x01\x02\x03"),
]


def stamp_for(mode: str, t: float, first: float, previous: float) -> str:
    sec, usec = divmod(round(t * 1e6), 1_000_000)
    if mode == "a":
        return f"({sec:010d}.{usec:06d})"
    if mode == "A":
        return f"(2023-11-14 22:13:{20 + sec - 1700000000:02d}.{usec:06d})"
    base = previous if mode == "d" else first
    dsec, dusec = divmod(round((t - base) * 1e6), 1_000_000)
    return f"({dsec:03d}.{dusec:06d})"


@pytest.mark.parametrize("mode", ["a", "A", "d", "z", "none"])
def test_timestamp_modes(tmp_path: Path, mode: str) -> None:
    lines = []
    previous = FRAMES[0][0]
    for t, can_id, data, kw in FRAMES:
        stamp = "" if mode == "none" else stamp_for(mode, t, FRAMES[0][0], previous)
        previous = t
        lines.append(screen_line(stamp, "can0", can_id, data, indent=True, **kw))
    path = write(tmp_path, lines)
    assert detect_format(path.read_bytes()) == "candump-screen"
    stats, cols = read(path, strict=True)
    got = rows(stats, cols)
    assert [r[2:] for r in got] == EXPECTED
    assert stats.channels == ["can0"]
    offsets = [r[0] - got[0][0] for r in got]
    if mode == "none":
        assert offsets == [0.0] * len(FRAMES)  # no time in the file
    else:
        assert offsets == pytest.approx([t - FRAMES[0][0] for t, *_ in FRAMES], abs=2e-6)
    if mode == "a":
        assert got[0][0] == 1700000000.0001
    if mode == "A":  # local date and time, read as UTC
        assert got[0][0] == pytest.approx(1700000000.0001, abs=1e-6)
    assert (stats.error_frames, stats.remote_frames, stats.fd_frames, stats.extended) == (
        1, 1, 1, 1)


def test_delta_and_zero_stamps_are_told_apart(tmp_path: Path) -> None:
    # the same four frames: -td prints the gaps (they shrink), -tz the growing offsets
    delta = write(tmp_path, [screen_line(s, "can0", 0x701, b"\x05") for s in
                             ("(000.000000)", "(000.500000)", "(000.100000)", "(001.000000)")],
                  "d.txt")
    zero = write(tmp_path, [screen_line(s, "can0", 0x701, b"\x05") for s in
                            ("(000.000000)", "(000.500000)", "(000.600000)", "(001.600000)")],
                 "z.txt")
    assert list(read(delta)[1]["ts"]) == pytest.approx([0.0, 0.5, 0.6, 1.6])
    assert list(read(zero)[1]["ts"]) == pytest.approx([0.0, 0.5, 0.6, 1.6])


# --- -x, colours, -e, -a, -i, -S, -8, DROPCOUNT --------------------------------------------


def test_extra_info_and_colour_escapes(tmp_path: Path) -> None:
    lines = [
        # -x: direction and the BRS/ESI flags after the interface
        screen_line("(1700000000.000001)", "can0", 0x701, b"\x05", extra="  RX - -"),
        screen_line("(1700000000.000002)", "can1", 0x123, bytes(12), fd=True, extra="  TX B E"),
        # -c: colour per interface before the name (level 1) or before the timestamp (3)
        f" (1700000000.000003)  {BLUE}can0{RESET}  702   [1]  7F",
        f" {RED}(1700000000.000004)  can1  703   [1]  05{RESET}",
        f" (1700000000.000005)  {BLUE}can0  RX - -  704   [1]  04{RESET}",
    ]
    stats, cols = read(write(tmp_path, lines), strict=True)
    assert [r[1:4] for r in rows(stats, cols)] == [
        ("can0", 0x701, False), ("can1", 0x123, False), ("can0", 0x702, False),
        ("can1", 0x703, False), ("can0", 0x704, False)]
    assert list(cols["fd"]) == [False, True, False, False, False]
    assert detect_format(lines[2].encode() + b"\n") == "candump-screen"


def test_error_frame_explanations_and_views(tmp_path: Path) -> None:
    lines = [
        "  can0  20000004   [8]  00 04 00 00 00 00 00 00   ERRORFRAME",
        "\tcontroller-problem{rx-error-warning}",  # -e
        "\terror-counter-tx-rx{{0}{97}}",
        "  can0  181   [4]  41 42 20 43                '.B C'",  # -a, a space in the ASCII
        "  can0  182   [2]  00000001 10000000",  # -i: binary bytes
        "  can0  183   [3]  03`02`01",  # -S: swapped byte order
        "  can0  184   {9}  01 02 03 04 05 06 07 08",  # -8: raw DLC 9 of a classic frame
        "  can0  185   [0] ",
        "DROPCOUNT: dropped 3 CAN frames on 'can0' socket (total drops 3)",
    ]
    stats, cols = read(write(tmp_path, lines), strict=True)
    assert [r[2:] for r in rows(stats, cols)] == [
        (0x004, False, False, True, False, 8, bytes([0, 4, 0, 0, 0, 0, 0, 0])),
        (0x181, False, False, False, False, 4, b"AB C"),
        (0x182, False, False, False, False, 2, b"\x01\x80"),
        (0x183, False, False, False, False, 3, b"\x01\x02\x03"),
        (0x184, False, False, False, False, 9, bytes(range(1, 9))),
        (0x185, False, False, False, False, 0, b""),
    ]
    assert (stats.dropped, stats.ignored, stats.skipped) == (3, 1, 0)
    assert list(cols["line"]) == [1, 4, 5, 6, 7, 8]


def test_bad_lines(tmp_path: Path) -> None:
    lines = ["  can0  701   [1]  05", "  can0  701   [2]  05", "  can0  70G   [1]  05",
             "  can0  701   [9]  00 00 00 00 00 00 00 00 00", "(12x.5)  can0  701   [1]  05",
             "  can0  701   [1]  05 and more", "  can0  702   [1]  05"]
    path = write(tmp_path, lines)
    stats, cols = read(path)
    assert list(cols["can_id"]) == [0x701, 0x702]
    assert stats.skipped_lines == [2, 3, 4, 5, 6]
    with pytest.raises(InputError) as exc:
        read(path, strict=True)
    assert str(exc.value).startswith(f"{path}:2: ")


def test_detection_does_not_take_other_formats() -> None:
    assert detect_format(b"  can0  123   [8]  11 22 33 44 55 66 77 88\n") == "candump-screen"
    assert detect_format(b" (1.000000)  vcan0  12345678   [2]  remote request\n") == (
        "candump-screen")
    assert detect_format(b"(1700000000.000001) can0 123#1122\n") == "candump"
    assert detect_format(b"   0.019968 1  64   Rx   d 4 64 00 00 00\n") == "asc"
    assert detect_format(b"     1)     17535  00000100  8  00 00 00 00 00 00 00 00\n") == "trc"


# --- a recorded sample as screen output ---------------------------------------------------


def test_sample_as_screen_output_has_the_log_frames(tmp_path: Path) -> None:
    log = SAMPLES / "guard_toggle.log"
    lines = []
    for raw in log.read_text().splitlines():
        stamp, iface, frame = raw.split()[:3]
        ident, _, payload = frame.partition("#")
        rtr = payload.startswith("R")
        data = b"" if rtr else bytes.fromhex(payload)
        dlc = int(payload[1:] or 0) if rtr else None
        lines.append(screen_line(stamp, iface, int(ident, 16), data, rtr=rtr, dlc=dlc,
                                 extra="  RX - -"))
    a, ca = read(log)
    b, cb = read(write(tmp_path, lines))
    assert b.format == "candump-screen" and b.skipped == 0
    for name in ("ts", "can_id", "ext", "rtr", "err", "fd", "dlc", "data"):
        np.testing.assert_array_equal(ca[name], cb[name], err_msg=name)
    assert a.remote_frames == b.remote_frames > 0
