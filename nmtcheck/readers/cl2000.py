"""CSS Electronics CL1000/CL2000/CL3000 text logs (the CLX000 loggers' `*.TXT` files).

A `# Logger type: CL2000` header of `# key: value` lines gives the value
separator, the time separators and the start time (`# Time: 20170101T022232`);
a column line (`Timestamp;Type;ID;Data`, optionally `Lost` and `Length`) names
the fields. Types: 0 received standard, 1 received extended, 8 transmitted
standard, 9 transmitted extended. A timestamp carries only its trailing digits
of `YYYYMMDDhhmmsskkk` (how many depends on `Time format`); the leading digits
come from the header's start time, as in the CSS and Wireshark readers. Times
are read as UTC (the logger's clock has no time zone). `Lost` (messages the
logger lost before the record) adds to the dropped frames and is placed at the
record's frame (the `frames_lost` cause). The logger has one
CAN port: every frame is on channel `1`.

python-can has no reader for this format.
"""

from __future__ import annotations

import calendar
from collections.abc import Iterator

from nmtcheck.errors import InputError
from nmtcheck.readers.detect import is_text
from nmtcheck.readers.frames import FrameBatch
from nmtcheck.readers.records import unsigned
from nmtcheck.readers.source import Source
from nmtcheck.readers.stats import InputStats, Row, batches_of

CHANNEL = "1"
FULL_TIME_DIGITS = 17  # YYYYMMDDhhmmsskkk
MESSAGE_TYPES = {b"0": (False, False), b"1": (True, False), b"8": (False, True),
                 b"9": (True, True)}  # type -> (extended, transmitted)
LOGGER_TYPES = (b"CL1000", b"CL2000", b"CL3000", b"CANLogger1000", b"CANLogger2000",
                b"CANLogger3000")
HEADER_PREFIX = b"# Logger type:"


class _Bad(Exception):
    """A record line that does not parse."""


def sniff(head: bytes) -> bool:
    """The log starts with the `# Logger type: CL…` header line."""
    if not is_text(head):
        return False
    for raw in head.splitlines()[:5]:
        line = raw.strip()
        if line:
            if not line.startswith(HEADER_PREFIX):
                return False
            return line[len(HEADER_PREFIX):].strip() in LOGGER_TYPES
    return False


def _separator(value: bytes) -> bytes:
    """`";"` -> `;`, `""` -> nothing."""
    value = value.strip()
    if len(value) >= 2 and value[:1] == b'"' and value[-1:] == b'"':
        return value[1:-1]
    return value


class _Layout:
    """What the header says about separators, the start time and the columns."""

    def __init__(self) -> None:
        self.separator = b";"
        self.strip_chars = b""
        self.start_digits = b"19700101000000000"
        self.columns: dict[bytes, int] = {}

    def header(self, line: bytes) -> None:
        key, _, value = line[1:].partition(b":")
        key = key.strip()
        if key == b"Value separator":
            self.separator = _separator(value) or b";"
        elif key in (b"Time separator", b"Time separator ms", b"Date separator",
                     b"Time and date separator"):
            self.strip_chars += _separator(value)
        elif key == b"Time":
            digits = bytes(c for c in value.strip() if 0x30 <= c <= 0x39)
            self.start_digits = digits.ljust(FULL_TIME_DIGITS, b"0")[:FULL_TIME_DIGITS]

    def timestamp(self, text: bytes) -> float:
        """Seconds since the epoch: the record's trailing digits over the header's start time."""
        digits = text.strip().translate(None, self.strip_chars) if self.strip_chars else text
        digits = digits.strip()
        if not digits.isdigit() or len(digits) > FULL_TIME_DIGITS:
            raise _Bad(f"timestamp {text.decode('latin-1')!r} is not in the header's format")
        full = self.start_digits[: FULL_TIME_DIGITS - len(digits)] + digits
        try:
            year, month, day = int(full[0:4]), int(full[4:6]), int(full[6:8])
            hour, minute, second, ms = (int(full[8:10]), int(full[10:12]), int(full[12:14]),
                                        int(full[14:17]))
            if not (1 <= month <= 12 and 1 <= day <= 31 and hour < 24 and minute < 60
                    and second < 61):
                raise ValueError
            return calendar.timegm((year, month, day, hour, minute, second, 0, 0, 0)) + ms / 1000
        except ValueError:
            raise _Bad(f"timestamp {text.decode('latin-1')!r} is not a date") from None


def read(source: Source, stats: InputStats) -> Iterator[FrameBatch]:
    return batches_of(stats, _rows(source, stats))


def _rows(source: Source, stats: InputStats) -> Iterator[tuple[int, Row]]:
    layout = _Layout()
    frame = 0  # the index of the next frame (every row yielded becomes one, in order)
    for lineno, raw in enumerate(source.lines(), source.first_line):
        line = raw.strip()
        if not line:
            continue
        if line.startswith(b"#"):
            layout.header(line)
            continue
        fields = line.split(layout.separator)
        if not layout.columns:
            layout.columns = {name.strip(): i for i, name in enumerate(fields)}
            if not all(c in layout.columns for c in (b"Timestamp", b"ID", b"Data")):
                raise InputError(source.path, "CLX000 column line lacks Timestamp, ID or Data",
                                 lineno)
            continue
        try:
            ts, can_id, ext, dlc, data, lost = _record(fields, layout)
        except _Bad as exc:
            stats.skip(lineno, str(exc))
            continue
        if lost:  # lost before this record: placed at its frame (the `frames_lost` cause)
            stats.drop(lineno, lost, frame, ts)
        yield lineno, Row(ts, CHANNEL, can_id, ext, False, False, False, dlc, data)
        frame += 1


def _record(fields: list[bytes], layout: _Layout) -> tuple[float, int, bool, int, bytes, int]:
    cols = layout.columns
    if len(fields) != len(cols):
        raise _Bad(f"expected {len(cols)} fields, found {len(fields)}")
    ts = layout.timestamp(fields[cols[b"Timestamp"]])
    ext = False
    if b"Type" in cols:
        kind = MESSAGE_TYPES.get(fields[cols[b"Type"]].strip())
        if kind is None:
            raise _Bad("unknown message type")
        ext = kind[0]
    can_id = unsigned(fields[cols[b"ID"]].strip(), 16)
    if can_id is None:
        raise _Bad("ID is not hex")
    ext = ext or can_id > 0x7FF  # without a Type column only the value tells
    if can_id > 0x1FFFFFFF:
        raise _Bad("ID out of range")
    text = fields[cols[b"Data"]].strip()
    try:
        data = bytes.fromhex(text.decode("latin-1"))
    except ValueError:
        raise _Bad("data is not hex") from None
    if len(data) > 8:
        raise _Bad("more than 8 data bytes")
    dlc = len(data)
    if b"Length" in cols:
        length = unsigned(fields[cols[b"Length"]].strip())
        if length is None:
            raise _Bad("length is not a number")
        dlc = length
        if dlc != len(data):
            raise _Bad(f"length {dlc} does not match the {len(data)} data bytes")
    lost = 0
    if b"Lost" in cols:
        count = unsigned(fields[cols[b"Lost"]].strip())
        if count is None:
            raise _Bad("lost count is not a number")
        lost = count
    return ts, can_id, ext, dlc, data, lost
