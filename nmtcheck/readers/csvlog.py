"""CSV frame logs: python-can's CSVWriter and SavvyCAN's native (GVRET) CSV, told apart by header.

python-can: `timestamp,arbitration_id,extended,remote,error,dlc,data` with epoch
seconds, a hex ID (`0x…`), `1`/`0` flags and base64 data. The file has no
channel column: every frame is on channel `1`. A DLC above 8 or more than 8
data bytes marks a CAN FD frame (the writer has no FD column).

SavvyCAN/GVRET: `Time Stamp,ID,Extended,[Dir,]Bus,LEN,D1,…` (the `Dir` column is
in files written since 2020) with microsecond timestamps, an 8-digit hex ID,
`true`/`false`, the 0-based GVRET bus number as the channel name, and one hex
column per data byte (usually eight, zero-filled, and a trailing comma). Columns
are found by their header name, not by position.

Where python-can 4.6.1 differs: its CSVReader cannot read SavvyCAN files at all
(it expects its own seven columns and fails on the first line), and it reports a
frame with more than 8 data bytes from its own files as a classic frame.
"""

from __future__ import annotations

import binascii
from collections.abc import Iterator

from nmtcheck.errors import InputError
from nmtcheck.readers.detect import is_text
from nmtcheck.readers.frames import FrameBatch
from nmtcheck.readers.records import plausible_time, unsigned
from nmtcheck.readers.source import Source
from nmtcheck.readers.stats import InputStats, Row, batches_of

PYTHON_CAN_HEADER = b"timestamp,arbitration_id,extended,remote,error,dlc,data"
DEFAULT_CHANNEL = "1"  # python-can's CSV has no channel column
SAVVYCAN_REQUIRED = ("TIME STAMP", "ID", "EXTENDED", "BUS", "LEN", "D1")
US_PER_S = 1_000_000


class _Bad(Exception):
    """A record line that does not parse."""


def _header_line(head: bytes) -> bytes:
    for raw in head.splitlines()[:5]:
        line = raw.strip()
        if line:
            return line
    return b""


def _savvycan_columns(header: bytes) -> dict[str, int] | None:
    names = [c.strip().upper() for c in header.decode("latin-1").split(",")]
    if not all(n in names for n in SAVVYCAN_REQUIRED):
        return None
    return {n: i for i, n in enumerate(names) if n}


def sniff(head: bytes) -> bool:
    """python-can's exact header, or a header naming SavvyCAN's columns."""
    if not is_text(head):
        return False
    line = _header_line(head)
    return line == PYTHON_CAN_HEADER or _savvycan_columns(line) is not None


def _flag(tok: bytes, true: bytes, false: bytes) -> bool:
    value = tok.strip().lower()
    if value == true:
        return True
    if value == false:
        return False
    raise _Bad(f"flag {tok.decode('latin-1')!r} is neither {true.decode()} nor {false.decode()}")


def _int(tok: bytes, what: str, base: int = 10) -> int:
    text = tok.strip()
    if base == 16 and text[:2] in (b"0x", b"0X"):
        text = text[2:]
    value = unsigned(text, base)
    if value is None:
        raise _Bad(f"{what} {tok.decode('latin-1')!r} is not a number")
    return value


def _python_can_row(fields: list[bytes]) -> tuple[float, int, bool, bool, bool, bool, int, bytes]:
    if len(fields) != 7:
        raise _Bad(f"expected 7 columns, found {len(fields)}")
    stamp, ident, extended, remote, error, dlc_text, payload = fields
    try:
        ts = float(stamp)
    except ValueError:
        raise _Bad("timestamp is not a number") from None
    if not plausible_time(ts, negative=True):
        raise _Bad("timestamp is not a finite number within range")
    ext = _flag(extended, b"1", b"0")
    rtr = _flag(remote, b"1", b"0")
    err = _flag(error, b"1", b"0")
    can_id = _int(ident, "CAN-ID", 16)
    dlc = _int(dlc_text, "DLC")
    try:
        data = binascii.a2b_base64(payload.strip()) if payload.strip() else b""
    except binascii.Error:
        raise _Bad("data is not base64") from None
    if can_id > (0x1FFFFFFF if ext else 0x7FF) or dlc > 64 or len(data) > 64:
        raise _Bad("CAN-ID, DLC or data length out of range")
    fd = dlc > 8 or len(data) > 8
    if err:
        ext = False
    return ts, can_id, ext, rtr, err, fd, dlc, b"" if rtr else data[:8]


class _SavvyCan:
    """One SavvyCAN/GVRET CSV row."""

    def __init__(self, columns: dict[str, int]) -> None:
        self.time, self.id, self.ext = columns["TIME STAMP"], columns["ID"], columns["EXTENDED"]
        self.bus, self.len, self.d1 = columns["BUS"], columns["LEN"], columns["D1"]
        self.min_fields = max(self.time, self.id, self.ext, self.bus, self.len) + 1

    def row(self, fields: list[bytes]) -> tuple[float, str, int, bool, bool, int, bytes]:
        if len(fields) < self.min_fields:
            raise _Bad(f"expected at least {self.min_fields} columns, found {len(fields)}")
        ts = _int(fields[self.time], "timestamp") / US_PER_S
        can_id = _int(fields[self.id], "CAN-ID", 16)
        ext = _flag(fields[self.ext], b"true", b"false")
        bus = str(_int(fields[self.bus], "bus"))
        length = _int(fields[self.len], "LEN")
        if can_id > (0x1FFFFFFF if ext else 0x7FF) or length > 64:
            raise _Bad("CAN-ID or LEN out of range")
        cells = [unsigned(c.strip(), 16) if len(c.strip()) in (1, 2) else None
                 for c in fields[self.d1:self.d1 + length]]
        if len(cells) < length or None in cells:
            raise _Bad(f"expected {length} data bytes of 1 or 2 hex digits")
        data = bytes(cells)  # type: ignore[arg-type]  # no None: checked above
        return ts, bus, can_id, ext, length > 8, length, data[:8]


def read(source: Source, stats: InputStats) -> Iterator[FrameBatch]:
    return batches_of(stats, _rows(source, stats))


def _rows(source: Source, stats: InputStats) -> Iterator[tuple[int, Row]]:
    savvycan: _SavvyCan | None = None
    header_seen = False
    for lineno, raw in enumerate(source.lines(), source.first_line):
        line = raw.strip()
        if not line:
            continue
        if not header_seen:
            header_seen = True
            if line == PYTHON_CAN_HEADER:
                continue
            columns = _savvycan_columns(line)
            if columns is None:
                raise InputError(source.path, "not a python-can or SavvyCAN CSV header", lineno)
            savvycan = _SavvyCan(columns)
            continue
        fields = line.split(b",")
        try:
            if savvycan is not None:
                ts, chan, can_id, ext, fd, dlc, data = savvycan.row(fields)
                rtr = err = False
            else:
                ts, can_id, ext, rtr, err, fd, dlc, data = _python_can_row(fields)
                chan = DEFAULT_CHANNEL
        except _Bad as exc:
            stats.skip(lineno, str(exc))
            continue
        yield lineno, Row(ts, chan, can_id, ext, rtr, err, fd, dlc, data)
