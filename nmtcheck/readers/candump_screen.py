"""candump's screen output (what `candump can0 | tee file` saves), not its `-l`/`-L` log format.

    (1700000000.123456)  can0  123   [8]  11 22 33 44 55 66 77 88
      can0  12345678   [2]  remote request
      can0  RX B -  123  [12]  00 11 22 33 44 55 66 77 88 99 AA BB
      can0  20000004   [8]  00 04 00 00 00 00 00 00   ERRORFRAME

Covers no timestamp, `-ta` (epoch), `-tA` (local date and time, read as UTC),
`-td` (delta to the previous frame) and `-tz` (since the first frame); `-x`
(`RX`/`TX` and the BRS/ESI flags), `-a` (ASCII column), `-i` (binary bytes),
`-S` (swapped bytes, joined by a backtick), CAN FD (`[12]` two-digit lengths),
`{x}` raw DLCs, error frames (`ERRORFRAME`, CAN_ERR_FLAG in the ID, `-e`
explanations on tab-indented continuation lines), remote requests and the ANSI
colour escapes of `-c`. `DROPCOUNT:` lines add to the dropped frames.

`-td` and `-tz` print the same `(000.123456)` form: a file whose relative stamps
ever decrease within its first DETECT_LINES frames is read as deltas (summed),
otherwise as offsets from the first frame. In a delta log a line whose delta can
be read keeps it even when the rest of the line cannot be parsed (a skipped
record), so the frames after it do not shift. Output without timestamps has no
time (`InputStats.timestamped` False, when the first DETECT_LINES lines hold no
frame with one): every frame is at 0 s, in file order, so only rules that need
no time can be trusted (record with `-ta` or `candump -L`); a frame line of the
other kind than the log's (with a timestamp or without) is a skipped record.

Logs as people paste them (SPEC §1): leading white space (tabs included) is no
part of a record — a tab-indented line is `-e`'s explanation only right after an
error frame, and only when it is no frame itself; text after a complete record
is a note, ignored (readers.note_follows); a line that is only a note or a
comment (`# …`, a shell prompt such as `$ candump can0`, `...`) is a non-frame
record. python-can has no reader for this format.

Speed: the file's common line (a classic 11-bit data frame, with or without `-ta`/`-tz`
stamps) is parsed vectorised a block of lines at a time (readers/blocks.py), at the
offsets its first such line has (`_Layout`); every other line goes through
`_LineParser`, the per-line reference parser, in file order. `-td` logs are read line by
line (each time adds to the one before).
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import datetime, timezone
from itertools import chain, islice
from typing import Any

import numpy as np

from nmtcheck.readers.blocks import (
    Block,
    LineWords,
    decimal_stamps,
    fill_low,
    reference_path,
)
from nmtcheck.readers.candump import ParsedLines, read_parsed_blocks
from nmtcheck.readers.detect import is_text
from nmtcheck.readers.frames import FrameBatch
from nmtcheck.readers.records import (
    MAX_TIMESTAMP_S,
    is_note_line,
    note_follows,
    plausible_time,
    unsigned,
)
from nmtcheck.readers.source import Source, peek
from nmtcheck.readers.stats import InputStats, Row, batches_of

_U64 = np.uint64

CAN_ERR_FLAG = 0x20000000
CAN_EFF_MASK = 0x1FFFFFFF
DETECT_LINES = 2000  # frames looked at to tell -td from -tz

_ANSI = re.compile(rb"\x1b\[[0-9;]*[A-Za-z]")
_STAMP = re.compile(rb"^\s*\(([^)]*)\)\s*")
# A delta that can still be read where the line's `)` is lost: `(000.100000  can0 …`
_OPEN_STAMP = re.compile(rb"^\s*\((\d+\.\d+)(?:\s|$)")
_ABS_DATE = re.compile(rb"^(\d{4}-\d{2}-\d{2} \d{2}:\d{2}:\d{2})\.(\d{1,9})$")
_NUMBER = re.compile(rb"^(\d+)\.(\d+)$")
_LENGTH = re.compile(rb"^(\[(\d{1,2})\]|\{([0-9A-Fa-f])\})$")
_DROP = re.compile(rb"DROPCOUNT:\s*dropped\s+(\d+)")
_SNIFF = re.compile(
    rb"^\s*(\([^)]*\)\s+)?\S+\s+((RX|TX)(\s+[-BEX])+\s+)?[0-9A-Fa-f]{3,8}\s+(\[\d{1,2}\]|\{[0-9A-Fa-f]\})"
)
_FLAG_TOKENS = {b"-", b"B", b"E", b"X"}


class _Bad(Exception):
    """A frame line that does not parse."""


def sniff(head: bytes) -> bool:
    """The first non-empty lines look like `[(time)] iface ID  [len]  data`."""
    if not is_text(head):
        return False
    for raw in head.splitlines()[:50]:
        line = _ANSI.sub(b"", raw).strip()
        if line and not line.startswith(b"DROPCOUNT"):
            return _SNIFF.match(line) is not None
    return False


def _data(tokens: list[bytes], n: int) -> bytes:
    """n data bytes from hex (`11`) or binary (`-i`: `00010001`) tokens."""
    if len(tokens) < n:
        raise _Bad(f"expected {n} data bytes, found {len(tokens)}")
    head = tokens[:n]
    if all(len(tok) == 2 for tok in head):  # hex pairs, the usual: one call, not n
        try:
            return bytes.fromhex(b"".join(head).decode("latin-1"))
        except ValueError:
            pass  # a token that is not hex: the loop below names it
    out = bytearray()
    for tok in tokens[:n]:
        if len(tok) == 2 and (value := unsigned(tok, 16)) is not None:
            out.append(value)
        elif len(tok) == 8 and not tok.strip(b"01"):
            out.append(int(tok, 2))
        else:
            raise _Bad(f"data byte {tok.decode('latin-1')!r} is not hex or binary")
    return bytes(out)


Frame = tuple[str, int, bool, bool, bool, bool, int, bytes]  # iface id ext rtr err fd dlc data


def _frame(tokens: list[bytes], text: bytes = b"") -> Frame:
    """`iface [RX|TX flags] ID [len] data… [ERRORFRAME | remote request]`; `text`: the line
    the tokens were split from (after the timestamp), for telling a note after the data."""
    if len(tokens) < 3:
        raise _Bad("expected 'interface ID [length]'")
    iface = tokens[0].decode("latin-1")
    rest = tokens[1:]
    if rest[0] in (b"RX", b"TX"):  # -x: direction, then BRS/ESI (and XL) flags
        rest = rest[1:]
        while rest and rest[0] in _FLAG_TOKENS:
            rest = rest[1:]
    if len(rest) < 2:
        raise _Bad("expected 'ID [length]'")
    id_text, length = rest[0], _LENGTH.match(rest[1])
    if len(id_text) not in (3, 8) or length is None:
        raise _Bad("expected a 3 or 8 digit hex ID and a [length]")
    can_id = unsigned(id_text, 16)
    if can_id is None:
        raise _Bad("CAN-ID is not hex")
    ext = len(id_text) == 8
    err = ext and bool(can_id & CAN_ERR_FLAG)
    if err:
        ext = False
    can_id &= CAN_EFF_MASK & ~(CAN_ERR_FLAG if err else 0)
    body = rest[2:]
    if length[2] is not None:  # [len]: one digit for classic CAN, two (`%02d`) for CAN FD
        dlc = n = int(length[2])
        fd = len(length[2]) == 2
        if not fd and dlc > 8:
            raise _Bad("classic frame longer than 8 bytes")
    else:  # {x}: a classic frame's raw DLC above 8 (`-8`), with 8 data bytes
        dlc = int(length[3], 16)
        fd = False
        n = min(dlc, 8)
    if dlc > 64:
        raise _Bad("length above 64")
    if body[:2] == [b"remote", b"request"]:
        return iface, can_id, ext, True, False, False, dlc, b""
    if b"ERRORFRAME" in body:
        body = body[:body.index(b"ERRORFRAME")]
        err = True
    if body and b"`" in body[0] and not body[0].startswith(b"`"):  # -S: swapped byte order
        body = body[0].split(b"`")[::-1] + body[1:]
    data = _data(body, n)
    extra = body[n:]
    if extra and not extra[0].startswith((b"'", b"`")) and not (  # -a: the ASCII column
            tokens[len(tokens) - len(extra):] == extra
            and note_follows(text, len(tokens) - len(extra))):  # a note: `05   # boot-up`
        raise _Bad("unexpected text after the data")
    return iface, can_id, ext, False, err, fd, dlc, data[:8]


class _Clock:
    """Turns the stamp in parentheses into seconds: absolute, date, delta or zero-based."""

    def __init__(self, deltas: bool) -> None:
        self.deltas = deltas
        self.total = 0.0

    def __call__(self, stamp: bytes | None) -> float:
        if stamp is None:
            return 0.0
        dated = _ABS_DATE.match(stamp)
        if dated is not None:
            try:
                when = datetime.strptime(dated[1].decode(), "%Y-%m-%d %H:%M:%S")
            except ValueError:  # digits in the right places, but month 13 or hour 25
                raise _Bad("timestamp is not a date") from None
            fraction = int(dated[2]) / 10 ** len(dated[2])
            out: float = when.replace(tzinfo=timezone.utc).timestamp() + fraction
            return out
        number = _NUMBER.match(stamp)
        if number is None:
            raise _Bad("timestamp is not a number")
        value = float(stamp)
        if not plausible_time(value):
            raise _Bad(f"timestamp out of range (0 to {MAX_TIMESTAMP_S:.0e} s)")
        if self.deltas and _is_relative(number[1]):
            self.total += value
            return self.total
        return value


def _is_relative(seconds: bytes) -> bool:
    """-td/-tz print `%03ld` seconds, -ta `%010ld`: ten digits mean an epoch time."""
    return len(seconds) < 10


def _split(raw: bytes) -> tuple[bytes | None, bytes]:
    """(the stamp in parentheses or None, the rest of the line), colour escapes removed."""
    line = _ANSI.sub(b"", raw)
    m = _STAMP.match(line)
    if m is None:
        return None, line
    return m[1].strip(), line[m.end():]


def _looks_like_deltas(lines: list[bytes]) -> bool:
    """True when relative stamps go down somewhere: deltas (-td), not offsets (-tz). Or,
    never going down, when read as offsets every frame after the first two would come
    within a twentieth of the first gap of each other, while read as deltas they are
    about equal: `candump -td can0,703:7FF` of one node's 100 ms heartbeat whose jitter
    happens to grow (0, 0.099981, 0.100002, 0.100033, ...), not five heartbeats in 0.1 ms."""
    values: list[float] = []
    for raw in lines:
        stamp, _rest = _split(raw)
        if stamp is None:
            continue
        number = _NUMBER.match(stamp)
        if number is None or not _is_relative(number[1]):
            continue
        value = float(stamp)
        if values and value < values[-1]:
            return True
        values.append(value)
    if len(values) < 5 or values[1] <= 0:
        return False
    spread = values[-1] - values[1]  # what all frames after the second span as offsets
    return spread < values[1] / 20


def read(source: Source, stats: InputStats) -> Iterator[FrameBatch]:
    """A block of lines at a time, decided by the same first lines as the reference
    decides; line by line (the reference) for `-td` logs, whose times each depend on the
    last, and where the first DETECT_LINES lines do not fit HEAD_PEEK_BYTES."""
    head = None if reference_path() else _head_lines(peek(source, HEAD_PEEK_BYTES))
    stamped = head is not None and _timestamped(head)
    if head is None or (stamped and _looks_like_deltas(head)):
        return batches_of(stats, _rows(source, stats))
    return _read_blocks(source, stats, stamped)


def _head_lines(head: bytes) -> list[bytes] | None:
    """The first DETECT_LINES lines of `head` as `Source.lines()` gives them; None where
    `head` (HEAD_PEEK_BYTES of the input) ends before them (very long lines)."""
    lines = head.split(b"\n")
    if len(lines) <= DETECT_LINES and len(head) == HEAD_PEEK_BYTES:
        return None
    out = [line + b"\n" for line in lines[:DETECT_LINES]]
    if len(lines) <= DETECT_LINES and not head.endswith(b"\n"):  # the whole input, its last
        out[-1] = out[-1][:-1]  # line without a newline
    return out


# --- the fast path ----------------------------------------------------------------------

HEAD_PEEK_BYTES = 1 << 20  # enough for DETECT_LINES lines of candump's screen output
_FAST = re.compile(  # a classic 11-bit data frame as candump prints it; the layout's model
    rb"( *)(?:\(([0-9]{1,12})\.([0-9]{1,9})\)( +))?([A-Za-z0-9_.-]{1,16})( +)"
    rb"([0-9A-Fa-f]{3})( +)\[([0-8])\]( +([0-9A-Fa-f]{2})(?: [0-9A-Fa-f]{2})*)? {0,2}\r?\n?")
_NAME_BYTE = np.zeros(256, bool)  # what an interface name of the fast path is made of
_NAME_BYTE[list(b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789_.-")] = True
_HEX_VALUE = np.full(256, 16, np.uint8)  # a hex digit's value, 16 for any other byte
for _i, _c in enumerate(b"0123456789abcdef"):
    _HEX_VALUE[_c] = _HEX_VALUE[bytes([_c]).upper()[0]] = _i
_DROPCOUNT = int.from_bytes(b"DROPCOUN", "little")
MAX_OFFSET = 96  # the layout's last field starts before this: gathers stay in a block's pad


@dataclass
class _Layout:
    """Where the fields of the file's common line are, from the first line of that shape:
    a classic 11-bit data frame with or without `(seconds)`, as candump prints it. Every
    line of a screen log is printed with one format string, so the offsets hold for almost
    every line; a line that differs in any byte is left to the reference parser."""

    stamped: bool  # the log's timestamps (decided by its first lines, as the reference)
    usable: bool = False
    lead: int = 0  # spaces before `(` (or the interface)
    dot: int = 0
    close: int = 0
    name_at: int = 0
    name_len: int = 0
    id_at: int = 0
    bracket: int = 0  # the `[` of `[len]`
    data_at: int = 0  # the first data byte (learned from a line with data)

    def learn(self, block: Block) -> None:
        first: tuple[int, ...] | None = None
        for row in range(min(len(block), 50)):
            m = _FAST.fullmatch(block.line(row))
            if m is None or (m[2] is not None) != self.stamped:
                continue
            offsets = (len(m[1]), m.end(2) if self.stamped else 0,
                       m.end(3) if self.stamped else 0, m.start(5), len(m[5]), m.start(7),
                       m.start(9) - 1)
            if first is None:
                first = offsets
                (self.lead, self.dot, self.close, self.name_at, self.name_len, self.id_at,
                 self.bracket) = offsets
                self.data_at = self.bracket + 5  # `[1]  05`: candump's two spaces
                self.usable = True
            if m[11] is not None and offsets == first:  # the data's place, where it has data
                self.data_at = m.start(11)
                break
        self.usable &= self.data_at + 3 * 8 < MAX_OFFSET

    def spaces(self) -> list[int]:
        """The offsets that hold a space in every line of the layout (with data)."""
        gaps = [range(0, self.lead), range(self.name_at + self.name_len, self.id_at),
                range(self.id_at + 3, self.bracket)]
        if self.stamped:
            gaps.append(range(self.close + 1, self.name_at))
        return [k for gap in gaps for k in gap]


def _parse_block(block: Block, lay: _Layout) -> ParsedLines:
    """Vectorised parse of the lines of `block` that have the layout's shape byte for byte;
    every other line is left `slow`."""
    n = len(block)
    buf, s = block.buf, block.starts
    if not lay.usable or n == 0:
        return _no_fast_lines(n)
    e = block.ends - (buf[block.ends - 1] == 0x0D)  # the end without `\r` and up to two
    for _ in range(2):  # trailing spaces
        e -= buf[e - 1] == 0x20
    ok = np.ones(n, bool)
    for k in lay.spaces():
        ok &= buf[s + k] == 0x20
    line = LineWords(block, s)
    if lay.stamped:
        ok &= (buf[s + lay.lead] == 0x28) & (buf[s + lay.dot] == 0x2E) & (
            buf[s + lay.close] == 0x29)
        ts, ok = decimal_stamps(line, buf, s, ok, lay.dot, lay.close,
                                lay.dot - lay.lead - 1, lay.close - lay.dot - 1)
    else:
        ts = np.zeros(n)
    for k in range(lay.name_len):
        ok &= _NAME_BYTE[buf[s + lay.name_at + k]]
    if lay.name_len >= 9:  # `DROPCOUNT…` as a name: a DROPCOUNT line to the reference
        ok &= ~((line.word(lay.name_at) == _U64(_DROPCOUNT))
                & (buf[s + lay.name_at + 8] == ord("T")))
    names = np.zeros((n, 2), np.uint64)
    names[:, 0] = fill_low(line.word(lay.name_at), lay.name_len, _U64(0))
    if lay.name_len > 8:
        names[:, 1] = fill_low(line.word(lay.name_at + 8), lay.name_len - 8, _U64(0))
    hi, mid, lo = (_HEX_VALUE[buf[s + lay.id_at + k]] for k in range(3))
    ok &= (hi | mid | lo) < 16
    can_id = (hi.astype(np.uint32) << 8) | (mid.astype(np.uint32) << 4) | lo
    b = lay.bracket
    dlc = buf[s + b + 1].astype(np.int16) - ord("0")
    ok &= (buf[s + b] == ord("[")) & (buf[s + b + 2] == ord("]")) & (dlc >= 0) & (dlc <= 8)
    dlc = np.where(ok, dlc, 0).astype(np.int16)
    with_data = dlc > 0
    ok &= e == np.where(with_data, s + lay.data_at + 3 * dlc - 1, s + b + 3)
    for k in range(b + 3, lay.data_at):  # between `]` and the first data byte
        ok &= ~with_data | (buf[s + k] == 0x20)
    data = np.zeros((n, 8), np.uint8)
    for i in range(8):
        has = dlc > i
        if not has.any():
            break
        at = s + lay.data_at + 3 * i
        high, low = _HEX_VALUE[buf[at]], _HEX_VALUE[buf[at + 1]]
        ok &= ~has | ((high | low) < 16)
        if i:
            ok &= ~has | (buf[at - 1] == 0x20)
        data[:, i] = np.where(has, (high << 4) | low, 0)
    fast = np.flatnonzero(ok)
    return ParsedLines(fast, np.flatnonzero(~ok), ts[fast], can_id[fast], dlc[fast],
                       data[fast], names[fast], np.full(fast.size, lay.name_len, np.int64),
                       np.zeros(fast.size, np.uint8))


def _no_fast_lines(n: int) -> ParsedLines:
    empty = np.empty(0, np.int64)
    return ParsedLines(empty, np.arange(n), np.empty(0), np.empty(0, np.uint32),
                       np.empty(0, np.int16), np.empty((0, 8), np.uint8),
                       np.empty((0, 2), np.uint64), empty, np.empty(0, np.uint8))


def _read_blocks(source: Source, stats: InputStats, stamped: bool) -> Iterator[FrameBatch]:
    """The fast path: the common lines vectorised a block at a time (readers/blocks.py),
    every other line through the reference parser, in file order. Not for `-td` logs."""
    stats.timestamped = stamped
    layout = _Layout(stamped)
    parser = _LineParser(stamped, deltas=False)
    last_fast = False  # whether the previous block's last line was a fast one

    def slow_lines(block: Block, p: ParsedLines, stats: InputStats
                   ) -> Iterator[tuple[int, tuple[Any, ...]]]:
        nonlocal last_fast
        is_fast = np.zeros(len(block) + 1, bool)  # row -1 (at the end): the previous block's
        is_fast[p.fast] = True
        is_fast[-1] = last_fast
        for row in p.slow.tolist():
            if is_fast[row - 1]:  # a fast line is a frame and no error frame
                parser.explaining = False
            frame = parser.parse(block.first_line + row, block.line(row), stats)
            if frame is not None:
                yield row, (frame.ts, frame.channel.encode("latin-1"), *frame[2:])
        if len(block):
            last_fast = bool(is_fast[len(block) - 1])

    return read_parsed_blocks(source, stats, lambda b: _parse_block(b, layout), layout.learn,
                              slow_lines)


def _timestamped(lines: list[bytes]) -> bool:
    """Whether the log has timestamps, by its first lines: no more of their frames lack a
    timestamp than have one that can be read. One damaged line either way does not decide
    it: it is a skipped record."""
    stamped = bare = 0
    for raw in lines:
        stamp, rest = _split(raw)
        try:
            if stamp is not None:
                _Clock(deltas=False)(stamp)
            _frame(rest.split(), rest)
        except _Bad:
            continue
        stamped += stamp is not None
        bare += stamp is None
    return stamped >= bare


class _LineParser:
    """The reference parser of one line at a time, with what it carries from line to line:
    the clock (deltas add up) and whether the last record was an error frame (`-e`
    explains it on the tab-indented lines after it)."""

    def __init__(self, stamped: bool, deltas: bool) -> None:
        self.stamped = stamped
        self.clock = _Clock(deltas=deltas)
        self.explaining = False

    def parse(self, lineno: int, raw: bytes, stats: InputStats) -> Row | None:
        """The frame of line `lineno`, or None (counted into `stats` where it is a record)."""
        if not raw.strip():
            return None
        stamp, rest = _split(raw)
        tokens = rest.split()
        if tokens and tokens[0].startswith(b"DROPCOUNT"):
            self.explaining = False
            m = _DROP.search(raw)
            count = None if m is None else unsigned(m[1])
            if count is None:
                stats.skip(lineno, "DROPCOUNT line without a count")
            else:
                stats.drop(lineno, count)
                stats.ignored += 1
            return None
        if is_note_line(raw):
            self.explaining = False
            stats.note(raw=raw, line=lineno)  # a comment, a prompt, `...`: no record
            return None
        clock = self.clock
        try:
            if (stamp is not None) != self.stamped:
                _damaged_delta(raw, clock)
                raise _Bad("a frame without a timestamp in a log with timestamps"
                           if self.stamped else
                           "a frame with a timestamp in a log without timestamps")
            try:
                ts = clock(stamp)  # a delta counts even when the rest of the line is damaged
            except _Bad:
                _damaged_delta(raw, clock)
                raise
            iface, can_id, ext, rtr, err, fd, dlc, data = _frame(tokens, rest)
        except _Bad as exc:
            if self.explaining and raw[:1] == b"\t":
                return None  # part of the error frame's record: its `-e` explanation
            self.explaining = b"ERRORFRAME" in raw  # a damaged error frame keeps it
            stats.skip(lineno, str(exc))
            return None
        self.explaining = err
        return Row(ts, iface, can_id, ext, rtr, err, fd, dlc, data)


def _rows(source: Source, stats: InputStats) -> Iterator[tuple[int, Row]]:
    lines = source.lines()
    head = list(islice(lines, DETECT_LINES))
    stamped = _timestamped(head)
    stats.timestamped = stamped
    parser = _LineParser(stamped, deltas=stamped and _looks_like_deltas(head))
    for lineno, raw in enumerate(chain(head, lines), source.first_line):
        row = parser.parse(lineno, raw, stats)
        if row is not None:
            yield lineno, row


def _damaged_delta(raw: bytes, clock: _Clock) -> None:
    """A line of a delta log whose stamp in parentheses is damaged (its `)` lost): its delta
    still counts if the line starts with one (`(000.100000  can0  701 …`)."""
    if clock.deltas and (m := _OPEN_STAMP.match(_ANSI.sub(b"", raw))):
        clock(m[1])
