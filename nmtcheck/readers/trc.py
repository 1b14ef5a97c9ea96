"""PEAK-System TRC traces (PCAN-View, PCAN-Explorer, PEAK-Converter), versions 1.0 to 2.1.

Layouts, after the `;` comment header (`;$FILEVERSION`, `;$STARTTIME`, `;$COLUMNS`):

* 1.0 (no `$FILEVERSION`): `N) offset ID DLC data…`; `ID DLC ERROR …` is an error
  frame, `DLC RTR` a remote frame, ID `FFFFFFFF` a bus-status warning.
* 1.1: `N) offset type ID DLC data…` with type `Rx`/`Tx`, `Warng` (status) or `Error`.
* 1.2: `N) offset bus type ID DLC data…`; 1.3 adds a reserved column before the DLC.
* 2.0/2.1: whitespace columns named by `$COLUMNS` (N number, O offset, T type,
  B bus, I ID, d direction, R reserved, L DLC, l data length, D data). Types `DT`
  (data), `FD`/`FB`/`FE`/`BI` (CAN FD), `RR` (remote request), `ER` (error frame),
  and the non-frame records `ST` (hardware status), `EC` (error counter change)
  and `EV` (user event).

Offsets are milliseconds; from version 1.1 on they count from `$STARTTIME`
(days since 1899-12-30, read as UTC like python-can does), so timestamps are
epoch seconds; a 1.0 file has offsets only. IDs with more than 4 hex digits
are 29-bit. The channel is the bus number as written, `1` where the version has
no bus column. Error frames (`ER`, `Error`, `ERROR`) are counted as error
frames; status and event lines are counted as non-frame records, never dropped.

Where python-can 4.6.1 differs: it crashes on version 1.2 (it parses it as
1.0) and on a 1.0 error frame (`ERROR` taken for a data byte); it drops `ER`
and `Error` lines, so a bus's error frames vanish;
for CAN FD frames of version 2.x it reports the DLC code (`L`) or re-encodes the
data length into a DLC (`l`) where nmtcheck reports the data length.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from datetime import datetime, timedelta, timezone

from nmtcheck.errors import InputError
from nmtcheck.readers.detect import is_text
from nmtcheck.readers.frames import FrameBatch
from nmtcheck.readers.records import plausible_time, unsigned
from nmtcheck.readers.source import Source
from nmtcheck.readers.stats import InputStats, Row, batches_of

DEFAULT_CHANNEL = "1"  # versions without a bus column log one bus
STATUS_ID = b"FFFFFFFF"  # version 1.x bus-status lines use this ID
FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)
V2_FRAME_TYPES = {b"DT": False, b"FD": True, b"FB": True, b"FE": True, b"BI": True, b"RR": False}
V2_NON_FRAMES = {b"ST", b"EC", b"EV"}
V2_DEFAULT_COLUMNS = {"2.0": "N,O,T,I,d,l,D", "2.1": "N,O,T,B,I,d,R,L,D"}
KNOWN_VERSIONS = ("1.0", "1.1", "1.2", "1.3", "2.0", "2.1")
OLE_EPOCH = datetime(1899, 12, 30, tzinfo=timezone.utc)

_HEX_DIGITS = b"0123456789abcdefABCDEF"
_V1_ROW = re.compile(rb"^\s*\d+\)\s+\d+(\.\d+)?\s+\S+\s+")


class _Bad(Exception):
    """A record line that does not parse."""


def sniff(head: bytes) -> bool:
    """A TRC file starts with `;` comment lines and has `;$FILEVERSION` or 1.0 rows."""
    if not is_text(head):
        return False
    lines = [line.strip() for line in head.splitlines()[:200]]
    lines = [line for line in lines if line]
    if not lines:
        return False
    if not lines[0].startswith(b";"):
        return _V1_ROW.match(lines[0]) is not None
    return any(line.startswith(b";$FILEVERSION=") for line in lines[:5]) or any(
        _V1_ROW.match(line) for line in lines if not line.startswith(b";"))


def start_time_from_ole_days(days: float) -> float:
    """`$STARTTIME` (days since 1899-12-30) as epoch seconds, computed like python-can."""
    return (OLE_EPOCH + timedelta(days=days)).timestamp()


def _hex_bytes(tokens: list[bytes], n: int) -> bytes:
    """n data bytes written as two hex digits each."""
    if len(tokens) < n:
        raise _Bad(f"expected {n} data bytes, found {len(tokens)}")
    digits = b"".join(tokens[:n])
    if len(digits) != 2 * n or digits.translate(None, _HEX_DIGITS):
        raise _Bad("data bytes must be two hex digits each")
    return bytes.fromhex(digits.decode("ascii"))


def _number(tok: bytes, what: str, base: int = 10) -> int:
    value = unsigned(tok, base)
    if value is None:
        raise _Bad(f"{what} {tok.decode('latin-1')!r} is not a number")
    return value


def _offset(tok: bytes) -> float:
    try:
        value = float(tok.replace(b",", b"."))
    except ValueError:
        raise _Bad(f"time offset {tok.decode('latin-1')!r} is not a number") from None
    if not plausible_time(value / 1000.0, negative=True):
        raise _Bad("time offset is not a finite number within range")
    return value / 1000.0


def _can_id(tok: bytes) -> tuple[int, bool]:
    value = _number(tok, "CAN-ID", 16)
    ext = len(tok) > 4
    if value > (0x1FFFFFFF if ext else 0x7FF):
        raise _Bad("CAN-ID out of range")
    return value, ext


class _Header:
    """What the `;$` header lines say."""

    def __init__(self) -> None:
        self.version = "1.0"
        self.start = 0.0
        self.columns: list[str] = []

    def take(self, line: bytes, path: str, lineno: int) -> None:
        key, _, value = line[2:].partition(b"=")
        text = value.strip().decode("latin-1")
        if key == b"FILEVERSION":
            self.version = text
        elif key == b"STARTTIME":
            try:
                self.start = start_time_from_ole_days(float(text.replace(",", ".")))
            except (ValueError, OverflowError):
                raise InputError(path, f"$STARTTIME {text!r} is not a date", lineno) from None
        elif key == b"COLUMNS":
            self.columns = [c.strip() for c in text.split(",")]




def _v1_row(tokens: list[bytes], version: str, start: float) -> Row | None:
    """One row of versions 1.0–1.3; None for a status (warning) line."""
    if len(tokens) < 3 or not tokens[0].endswith(b")"):
        raise _Bad("expected 'N) offset …'")
    ts = _offset(tokens[1]) + (start if version != "1.0" else 0.0)
    chan = DEFAULT_CHANNEL
    rest = tokens[2:]
    if version in ("1.2", "1.3"):
        chan = str(_number(rest[0], "bus"))
        rest = rest[1:]
    if version != "1.0":
        if not rest:
            raise _Bad("missing message type")
        kind, rest = rest[0], rest[1:]
        if kind == b"Warng":
            return None
        if kind == b"Error":
            return Row(ts, chan, 0, False, False, True, False, 0, b"")
        if kind not in (b"Rx", b"Tx"):
            raise _Bad(f"unknown message type {kind.decode('latin-1')!r}")
    if not rest:
        raise _Bad("missing CAN-ID")
    if rest[0] == STATUS_ID:
        return None
    if version == "1.3":
        rest = rest[:1] + rest[2:]  # the reserved column
    if len(rest) < 2:
        raise _Bad("missing DLC")
    dlc = _number(rest[1], "DLC")
    if dlc > 15:
        raise _Bad("DLC above 15")
    if len(rest) > 2 and rest[2] == b"ERROR":
        return Row(ts, chan, 0, False, False, True, False, 0, b"")
    can_id, ext = _can_id(rest[0])
    if len(rest) > 2 and rest[2] == b"RTR":
        return Row(ts, chan, can_id, ext, True, False, False, dlc, b"")
    return Row(ts, chan, can_id, ext, False, False, False, dlc,
               _hex_bytes(rest[2:], min(dlc, 8)))


class _V2Layout:
    """Column positions of a version 2.x file."""

    def __init__(self, columns: list[str]) -> None:
        pos = {name: i for i, name in enumerate(columns)}
        missing = [c for c in ("O", "T", "I", "D") if c not in pos]
        if missing or ("L" not in pos and "l" not in pos):
            raise ValueError(f"$COLUMNS lacks {', '.join(missing or ['L or l'])}")
        self.offset, self.type, self.id, self.data = pos["O"], pos["T"], pos["I"], pos["D"]
        self.bus = pos.get("B")
        self.dlc_code = pos.get("L")
        self.length = pos.get("l")
        self.min_tokens = pos["D"]  # every column before the data

    def row(self, tokens: list[bytes], start: float) -> Row | None:
        """One row; None for a non-frame record (status, error counters, event)."""
        if len(tokens) <= max(self.offset, self.type):
            raise _Bad("truncated line")
        kind = tokens[self.type]
        ts = _offset(tokens[self.offset]) + start
        if kind in V2_NON_FRAMES:
            return None
        chan = DEFAULT_CHANNEL
        if self.bus is not None and self.bus < len(tokens):
            chan = str(_number(tokens[self.bus], "bus"))
        if kind == b"ER":  # columns after the bus may be empty: only time and bus count
            return Row(ts, chan, 0, False, False, True, False, 0, b"")
        if kind not in V2_FRAME_TYPES:
            raise _Bad(f"unknown message type {kind.decode('latin-1')!r}")
        if len(tokens) < self.min_tokens:
            raise _Bad("truncated line")
        fd = V2_FRAME_TYPES[kind]
        rtr = kind == b"RR"
        can_id, ext = _can_id(tokens[self.id])
        if self.dlc_code is not None:
            code = _number(tokens[self.dlc_code], "DLC")
            if code > 15:
                raise _Bad("DLC above 15")
            dlc = FD_LENGTHS[code] if fd else code
        else:
            assert self.length is not None
            dlc = _number(tokens[self.length], "data length")
            if dlc > (64 if fd else 8):
                raise _Bad("data length out of range")
        if rtr:
            return Row(ts, chan, can_id, ext, True, False, False, dlc, b"")
        data = _hex_bytes(tokens[self.data:], dlc if fd else min(dlc, 8))
        return Row(ts, chan, can_id, ext, False, False, fd, dlc, data[:8])


def read(source: Source, stats: InputStats) -> Iterator[FrameBatch]:
    return batches_of(stats, _rows(source, stats))


def _rows(source: Source, stats: InputStats) -> Iterator[tuple[int, Row]]:
    header = _Header()
    layout: _V2Layout | None = None
    started = False  # the first record line fixes the version's layout
    for lineno, raw in enumerate(source.lines(), source.first_line):
        line = raw.strip()
        if not line:
            continue
        if line.startswith(b";"):
            if line.startswith(b";$") and not started:
                header.take(line, source.path, lineno)
            continue
        if not started:
            started = True
            version = header.version
            if version.startswith("2."):
                columns = header.columns or V2_DEFAULT_COLUMNS.get(version, "").split(",")
                try:
                    layout = _V2Layout(columns)
                except ValueError as exc:
                    raise InputError(source.path, f"TRC {version}: {exc}", lineno) from None
            elif version not in KNOWN_VERSIONS:
                raise InputError(source.path, f"TRC file version {version} is not supported "
                                 f"(known: {', '.join(KNOWN_VERSIONS)})", lineno)
        tokens = line.split()
        try:
            row = (layout.row(tokens, header.start) if layout is not None
                   else _v1_row(tokens, header.version, header.start))
        except _Bad as exc:
            stats.skip(lineno, str(exc))
            continue
        if row is None:
            stats.ignored += 1
            continue
        yield lineno, row
