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
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from datetime import datetime, timezone
from itertools import chain, islice

from nmtcheck.frames import FrameBatch
from nmtcheck.readers import (
    MAX_TIMESTAMP_S,
    InputStats,
    Row,
    Source,
    batches_of,
    is_note_line,
    is_text,
    note_follows,
    plausible_time,
    unsigned,
)

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
    return batches_of(stats, _rows(source, stats))


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


def _rows(source: Source, stats: InputStats) -> Iterator[tuple[int, Row]]:
    lines = source.lines()
    head = list(islice(lines, DETECT_LINES))
    stamped = _timestamped(head)
    stats.timestamped = stamped
    clock = _Clock(deltas=stamped and _looks_like_deltas(head))
    explaining = False  # after an error frame: `-e` prints its explanation on `\t` lines
    for lineno, raw in enumerate(chain(head, lines), source.first_line):
        if not raw.strip():
            continue
        stamp, rest = _split(raw)
        tokens = rest.split()
        if tokens and tokens[0].startswith(b"DROPCOUNT"):
            explaining = False
            m = _DROP.search(raw)
            count = None if m is None else unsigned(m[1])
            if count is None:
                stats.skip(lineno, "DROPCOUNT line without a count")
            else:
                stats.drop(lineno, count)
                stats.ignored += 1
            continue
        if is_note_line(raw):
            explaining = False
            stats.note()  # a comment, a shell prompt, `...`: no record
            continue
        try:
            if (stamp is not None) != stamped:
                _damaged_delta(raw, clock)
                raise _Bad("a frame without a timestamp in a log with timestamps" if stamped
                           else "a frame with a timestamp in a log without timestamps")
            try:
                ts = clock(stamp)  # a delta counts even when the rest of the line is damaged
            except _Bad:
                _damaged_delta(raw, clock)
                raise
            iface, can_id, ext, rtr, err, fd, dlc, data = _frame(tokens, rest)
        except _Bad as exc:
            if explaining and raw[:1] == b"\t":
                continue  # part of the error frame's record: its `-e` explanation
            explaining = b"ERRORFRAME" in raw  # a damaged error frame keeps its explanation
            stats.skip(lineno, str(exc))
            continue
        explaining = err
        yield lineno, Row(ts, iface, can_id, ext, rtr, err, fd, dlc, data)


def _damaged_delta(raw: bytes, clock: _Clock) -> None:
    """A line of a delta log whose stamp in parentheses is damaged (its `)` lost): its delta
    still counts if the line starts with one (`(000.100000  can0  701 …`)."""
    if clock.deltas and (m := _OPEN_STAMP.match(_ANSI.sub(b"", raw))):
        clock(m[1])
