"""SocketCAN candump log format (`candump -l` / `-L`): `(ts) iface ID#DATA [R|T]`.

Covers remote frames (`ID#R`, `ID#R<len>`, `ID#R<len>_<dlc>`), 8-digit extended
IDs, error frames (CAN_ERR_FLAG 0x20000000 in the ID), CAN FD
(`ID##<flags><data>`), the raw-DLC suffix of `candump -8` (`ID#<8 bytes>_<dlc>`),
the optional direction flag, nanosecond timestamps and `DROPCOUNT:` lines. CAN XL
lines (`ID###…` of older can-utils, `<vcid><prio>#<flags>:<sdt>:<af>#<data>` of
newer ones) are well-formed records that are not CAN CC/FD frames: ignored.

Logs as people paste them (SPEC §1) are read too: leading white space (tabs
included) is no part of a record; text after a complete record (`701#05  # boot-up`)
is a note, ignored (`note_follows` says what counts as one); a line that is
only a note or a comment (`# …`, a shell prompt, `...`) is a non-frame record
(`InputStats.notes`). Lines without `(timestamp)` — `can0 701#05`, or cansend's
bare `701#05` (channel `1`) — make a log without timestamps when the first lines
hold no frame with one (`InputStats.timestamped` False, every frame at 0 s, in
file order); in a log with timestamps such a line is a skipped record, and the
other way round.

Speed: the common line, `(<digits>.<digits>) <iface> <3 hex>#<0..8 hex bytes>`
with an optional ` R`/` T`, is parsed vectorised a block of lines at a time
(readers/blocks.py); every other line goes through `_parse_line`, the per-line
reference parser, in file order.
"""

from __future__ import annotations

import re
from binascii import unhexlify
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass

import numpy as np

from nmtcheck.readers.blocks import (
    Block,
    LineWords,
    SlowRow,
    decimal_stamps,
    fill_low,
    find_byte,
    hex_nibbles,
    merged_batches,
    pack_nibbles,
    parsed_blocks,
    reference_path,
)
from nmtcheck.readers.detect import is_text
from nmtcheck.readers.frames import BatchBuilder, FrameBatch
from nmtcheck.readers.records import MAX_TIMESTAMP_S, is_note_line, note_follows, plausible_time
from nmtcheck.readers.source import Source, peek
from nmtcheck.readers.stats import InputStats, Row, account, batches_of

CAN_ERR_FLAG = 0x20000000
CAN_EFF_MASK = 0x1FFFFFFF
_HEX_DIGITS = b"0123456789abcdefABCDEF"
_FAST = re.compile(  # a classic 11-bit data frame; everything else takes the general path
    rb"\(([0-9]{1,12}\.[0-9]{1,9})\) (\S+) ([0-9A-Fa-f]{3})#((?:[0-9A-Fa-f]{2}){0,8})"
    rb"(?: [RT])?\r?\n?")
_STAMP = re.compile(rb"[0-9]{1,40}(?:\.[0-9]{1,40})?")  # what `(…)` of a candump line holds
_DROP = re.compile(rb"DROPCOUNT:\s*dropped\s+(\d{1,18})\b")  # more digits: not a count
_CANXL = re.compile(rb"[0-9A-Fa-f]{5}#[0-9A-Fa-f]{2}:[0-9A-Fa-f]{2}:[0-9A-Fa-f]{8}#[0-9A-Fa-f.]*$")


def _is_hex(b: bytes) -> bool:
    return bool(b) and not b.translate(None, _HEX_DIGITS)  # nothing left once hex is deleted


def _bad_raw_dlc(sep: bytes, raw_dlc: bytes) -> bool:
    """A `_<dlc>` suffix (len8_dlc, `candump -8`) must be one hex digit."""
    return bool(sep) and (len(raw_dlc) != 1 or not _is_hex(raw_dlc))


_SNIFF = re.compile(rb"^\s*\(\s*-?\d+(\.\d+)?\)\s+\S+\s+[0-9A-Fa-f]+##?")
# `ID#DATA` as pasted without `(timestamp)`: after an interface name, or bare (cansend's syntax)
_SNIFF_LOOSE = re.compile(rb"^(?:[A-Za-z][^\s()#]{0,15}\s+)?(?:[0-9A-Fa-f]{3}|[0-9A-Fa-f]{8})#"
                          rb"(?:#[0-9A-Fa-f]|[Rr]|[0-9A-Fa-f]{2}|\s|$)")
_IFACE = re.compile(rb"[A-Za-z][^\s()#]{0,15}")  # an interface name where no timestamp precedes it
BARE_CHANNEL = b"1"  # the channel of `ID#DATA` lines that name no interface
DETECT_LINES = 2000  # lines looked at (within HEAD_BYTES) to tell whether the log has timestamps
QUICK_BYTES = 8192  # where most lines start with `(`, the log has timestamps: no line parsed


def _first_line(head: bytes) -> bytes | None:
    """The first non-blank line of the first 50 (without its white space), if any."""
    for raw in head.splitlines()[:50]:
        line = raw.strip()
        if line:
            return line
    return None


def sniff(head: bytes) -> bool:
    """A candump log starts (within its first 50 lines) with a `(ts) iface ID#` line."""
    if not is_text(head):
        return False
    line = _first_line(head)
    return line is not None and _SNIFF.match(line) is not None


def sniff_loose(head: bytes) -> bool:
    """Lines as people paste them: `can0 701#05` or `701#05`, without `(timestamp)`."""
    if not is_text(head):
        return False
    line = _first_line(head)
    return line is not None and _SNIFF_LOOSE.match(line) is not None


# One frame parsed by `_parse_line`: ts, interface name (the line's bytes), CAN-ID, ext, rtr,
# err, fd, dlc, data. A plain tuple, not a NamedTuple: `_parse_line` is the per-line parser
# (the reference path, every line of `check --follow`), where building one costs.
_Row = tuple[float, bytes, int, bool, bool, bool, bool, int, bytes]


class _Skip(Exception):
    """A line that is no well-formed record; the message is the skip's reason."""


def _parse_line(raw: bytes, lineno: int, stats: InputStats, stamped: bool = True
                ) -> _Row | None:
    """One line: (ts, iface, id, ext, rtr, err, fd, dlc, data), or None for a non-frame line
    (counted into stats: skipped, ignored, dropped). `stamped`: the log has timestamps (a
    frame line without one is a skipped record), else it has none (and one with is)."""
    if stamped:
        fast = _FAST.fullmatch(raw)
        if fast is not None:  # the common case: a classic 11-bit data frame
            data = unhexlify(fast[4])
            return (float(fast[1]), fast[2], int(fast[3], 16), False, False, False, False,
                    len(data), data)
    try:
        return _parse_general(raw, stats, stamped, lineno)
    except _Skip as bad:
        stats.skip(lineno, str(bad))
        return None


def _parse_general(raw: bytes, stats: InputStats, stamped: bool = True, lineno: int = 0
                   ) -> _Row | None:
    """Any line `_FAST` does not take; raises _Skip for an unparseable record."""
    parts = raw.split()
    if not parts:
        return None
    if parts[0].startswith(b"DROPCOUNT"):
        _count_drops(raw, stats, lineno)
        return None
    if is_note_line(raw):
        stats.note(raw=raw, line=lineno)  # a comment, a shell prompt, `...`: no record
        return None
    ts, iface, frame = _fields(raw, parts, stamped)
    hash_pos = frame.find(b"#")
    if hash_pos == 5 and _CANXL.match(frame):
        stats.ignored += 1  # CAN XL frame: not CAN CC/FD traffic
        return None
    id_text = frame[:hash_pos]
    if hash_pos < 0 or len(id_text) not in (3, 8) or not _is_hex(id_text):
        raise _Skip("CAN-ID must be 3 or 8 hex digits followed by '#'")
    can_id = int(id_text, 16)
    ext = len(id_text) == 8
    rest = frame[hash_pos + 1 :]
    if rest.startswith(b"##"):
        stats.ignored += 1  # CAN XL frame: not CAN CC/FD traffic
        return None
    fd, rtr, dlc, data = _payload(rest)
    err = False
    if ext and can_id & CAN_ERR_FLAG:
        err = True
        ext = False
    can_id &= CAN_EFF_MASK
    if err:
        can_id &= ~CAN_ERR_FLAG & CAN_EFF_MASK
    return ts, iface, can_id, ext, rtr, err, fd, dlc, data


def _fields(raw: bytes, parts: list[bytes], stamped: bool) -> tuple[float, bytes, bytes]:
    """(timestamp, interface, `ID#…` field) of a line's tokens: `(ts) iface ID#DATA`, or
    (a log without timestamps) `iface ID#DATA` or `ID#DATA`, each maybe followed by the
    direction flag (`R`/`T`) and a note."""
    if parts[0][:1] == b"(":
        if len(parts) < 3:
            raise _Skip("expected '(timestamp) interface ID#DATA'")
        ts = _timestamp(parts[0])
        if not stamped:
            raise _Skip("a frame with a timestamp in a log without timestamps")
        iface, frame, tail = parts[1], parts[2], parts[3:]
    else:
        if b"#" in parts[0]:
            iface, frame, tail = BARE_CHANNEL, parts[0], parts[1:]
        elif len(parts) > 1 and b"#" in parts[1] and _IFACE.fullmatch(parts[0]):
            iface, frame, tail = parts[0], parts[1], parts[2:]
        else:
            raise _Skip("expected '(timestamp) interface ID#DATA'" if stamped
                        else "expected 'interface ID#DATA' or 'ID#DATA'")
        if stamped:
            raise _Skip("a frame without a timestamp in a log with timestamps")
        ts = 0.0
    if tail[:1] in ([b"R"], [b"T"]):  # the direction flag of `candump -x`
        tail = tail[1:]
    if tail and not note_follows(raw, len(parts) - len(tail)):
        raise _Skip("unexpected text after the frame")
    return ts, iface, frame


def _timestamped(head: bytes) -> bool:
    """Whether a log has timestamps, by its first lines (DETECT_LINES within `head`): no
    more of their frames lack a timestamp than have one. One damaged line either way does
    not decide it: it is a skipped record."""
    first = head[:QUICK_BYTES]
    if 2 * (first.count(b"\n(") + first.startswith(b"(")) > first.count(b"\n") + 1:
        return True  # the usual log: most lines start like `(timestamp)`, no bare frame can
    lines = head.split(b"\n")[:DETECT_LINES]
    scratch = InputStats("")
    stamped = bare = 0
    for raw in lines:
        if _FAST.fullmatch(raw):
            stamped += 1
        else:
            for with_ts in (True, False):
                try:
                    if _parse_general(raw, scratch, with_ts) is not None:
                        stamped += with_ts
                        bare += not with_ts
                        break
                except _Skip:
                    pass
        if 2 * stamped > len(lines):
            break
    return stamped >= bare


def _count_drops(raw: bytes, stats: InputStats, lineno: int = 0) -> None:
    """A `DROPCOUNT: dropped N` line: frames the logger lost."""
    m = _DROP.search(raw)
    if m is None:
        raise _Skip("DROPCOUNT line without a count")
    stats.drop(lineno, int(m.group(1)))
    stats.ignored += 1


def _timestamp(tok_ts: bytes) -> float:
    """The `(seconds)` field."""
    if not (tok_ts.startswith(b"(") and tok_ts.endswith(b")")):
        raise _Skip("timestamp is not in parentheses")
    text = tok_ts[1:-1]
    if _STAMP.fullmatch(text) is None:  # candump writes `seconds.micro/nanoseconds` only
        try:
            float(text)
        except ValueError:
            raise _Skip("timestamp is not a number") from None
        raise _Skip("timestamp is not seconds as candump writes them (digits, a dot, "
                    "digits: no sign, no exponent)")
    ts = float(text)
    if not plausible_time(ts):
        raise _Skip(f"timestamp out of range (0 to {MAX_TIMESTAMP_S:.0e} s)")
    return ts


def _payload(rest: bytes) -> tuple[bool, bool, int, bytes]:
    """(fd, rtr, dlc, data) of what follows `ID#`: `#<flags><data>` (CAN FD), `R[len]`
    (remote) or hex data, either with an optional `_<dlc>` suffix."""
    if rest.startswith(b"#"):  # CAN FD: ##<flags nibble><data>
        body = rest[2:]
        if len(rest) < 2 or not _is_hex(rest[1:2]) or len(body) % 2 or len(body) > 128 or (
            body and not _is_hex(body)
        ):
            raise _Skip("malformed CAN FD data")
        data = bytes.fromhex(body.decode())
        return True, False, len(data), data
    if rest[:1] in (b"R", b"r"):
        tail, sep, raw_dlc = rest[1:].partition(b"_")
        if (tail and not (len(tail) == 1 and b"0" <= tail <= b"8")) or _bad_raw_dlc(
            sep, raw_dlc
        ):
            raise _Skip("malformed remote frame length")
        return False, True, int(tail) if tail else 0, b""
    body, sep, raw_dlc = rest.partition(b"_")  # a len8_dlc suffix (`_9`): DLC > 8
    if len(body) % 2 or (body and not _is_hex(body)) or len(body) > 16 or _bad_raw_dlc(
        sep, raw_dlc
    ):
        raise _Skip("data must be 0..8 bytes of hex")
    data = bytes.fromhex(body.decode())
    return False, False, len(data), data


def read(source: Source, stats: InputStats) -> Iterator[FrameBatch]:
    if not _timestamped(peek(source)):  # pasted lines without `(timestamp)`: few, line by line
        stats.timestamped = False
        return read_lines(source, stats, stamped=False)
    if reference_path():
        return read_lines(source, stats)
    return read_blocks(source, stats)


def read_lines(source: Source, stats: InputStats, stamped: bool = True
               ) -> Iterator[FrameBatch]:
    """The reference path: every line through `_parse_line`."""
    return batches_of(stats, _rows(source, stats, stamped))


def _rows(source: Source, stats: InputStats, stamped: bool) -> Iterator[tuple[int, Row]]:
    for lineno, raw in enumerate(source.lines(), source.first_line):
        row = _parse_line(raw, lineno, stats, stamped)
        if row is not None:
            ts, iface, can_id, ext, rtr, err, fd, dlc, data = row
            yield lineno, Row(ts, iface.decode("latin-1"), can_id, ext, rtr, err, fd, dlc, data)


@dataclass
class _Layout:
    """Offsets of `)`, `.` and the interface's end in the file's lines, guessed from one line."""

    close: int = 18  # `(1700000000.000000)`: `)` at offset 18 from `(`
    dot: int = 11
    iface_len: int = 4  # can0

    def learn(self, block: Block) -> None:
        for row in range(min(len(block), 50)):
            m = _FAST.fullmatch(block.line(row))
            if m is not None:
                self.close = m.end(1)
                self.dot = m.start(1) + m[1].index(b".")
                self.iface_len = len(m[2])
                return


@dataclass
class ParsedLines:
    """A block's common-shape lines, parsed; the other lines are `slow`."""

    fast: np.ndarray  # row numbers (within the block) of the lines parsed here
    slow: np.ndarray  # row numbers of every other line, for `_parse_line`
    ts: np.ndarray
    can_id: np.ndarray
    dlc: np.ndarray
    data: np.ndarray  # uint8 [n, 8]
    iface: np.ndarray  # uint64 [n, 2]: the interface name's bytes, zero padded
    iface_len: np.ndarray
    flags: np.ndarray  # uint8: bit 0 extended (29-bit), bit 2 error frame (BatchBuilder's)


_U64 = np.uint64
_U8 = _U64(8)
_Columns = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                 np.ndarray, np.ndarray]  # ok, ts, can_id, dlc, data (one word), name (two
# words), name length, flags
FLAG_EXT, FLAG_RTR, FLAG_ERR = 1, 2, 4  # BatchBuilder's flag bits
_ID_WIDE = 1 << 15  # in a block's shape key: the lines' CAN-IDs have 8 hex digits


def _parse_block(block: Block, layout: _Layout) -> ParsedLines:
    """Vectorised parse of the lines of `block` that match `_FAST`; nothing else is touched.

    Lines are grouped by where their `)`, `.` and the space after the interface are (one
    group in almost every block), and each group is decoded at constant offsets: scalar
    widths and masks, no per-line ones."""
    buf = block.buf
    n = len(block)
    rows = np.flatnonzero(buf[block.starts] == 0x28)  # "("
    s = block.starts[rows]
    k, ok = find_byte(buf, s, 0x29, layout.close, 4, 24)
    j, ok_dot = find_byte(buf, s, 0x2E, layout.dot, 2, 14)
    ok &= ok_dot
    m, ok_sp = find_byte(buf, s + k + 2, 0x20, layout.iface_len, 1, 17)
    ok &= ok_sp
    e = block.ends[rows]
    # `ID#`: 3 hex digits (11-bit), else 8 (29-bit, error frames): the `#` after 3 or not
    wide = buf[s + k + m + 6] != 0x23
    if isinstance(k, int) and isinstance(j, int) and isinstance(m, int) and not wide.any():
        cols = _parse_shape(block, s, e, ok, k, j, m, 3)
    else:  # several layouts in one block: each decoded apart, the results in row order
        shape = np.broadcast_to(np.asarray(k) << 10 | np.asarray(j) << 5 | m, rows.shape)
        shape = shape | np.where(wide, _ID_WIDE, 0)
        cols = (np.zeros(rows.size, bool), np.zeros(rows.size), np.zeros(rows.size, np.uint32),
                np.zeros(rows.size, np.int16), np.zeros(rows.size, np.uint64),
                np.zeros((rows.size, 2), np.uint64), np.zeros(rows.size, np.int64),
                np.zeros(rows.size, np.uint8))
        for value in np.unique(shape).tolist():
            sel = np.flatnonzero(shape == value)
            parts = _parse_shape(block, s[sel], e[sel], ok[sel], (value >> 10) & 31,
                                 (value >> 5) & 31, value & 31, 8 if value & _ID_WIDE else 3)
            for col, part in zip(cols, parts, strict=True):
                col[sel] = part
    ok, ts, can_id, dlc, data, name, name_len, flags = cols
    data8 = data.view(np.uint8).reshape(-1, 8)
    if rows.size == n and bool(ok.all()):  # the usual block: every line has the common shape
        return ParsedLines(rows, np.empty(0, np.int64), ts, can_id, dlc, data8, name, name_len,
                       flags)
    good = np.flatnonzero(ok)
    fast = rows[good]
    is_fast = np.zeros(n, bool)
    is_fast[fast] = True
    return ParsedLines(fast, np.flatnonzero(~is_fast), ts[good], can_id[good], dlc[good],
                   data8[good], name[good], name_len[good], flags[good])


def _parse_shape(block: Block, s: np.ndarray, e: np.ndarray, ok: np.ndarray, close: int,
                 dot: int, name_len: int, id_len: int) -> _Columns:
    """The lines starting at `s` and ending (newline) at `e` whose `)`, `.` and the space
    after the interface are at offsets `close`, `dot` and `close + 2 + name_len`, with a
    CAN-ID of `id_len` hex digits (3, or 8: 29-bit and error frames); `ok`: where those
    were found."""
    buf = block.buf
    line = LineWords(block, s)
    int_w, frac_w = dot - 1, close - dot - 1
    ok = ok & (line.byte(close + 1) == 0x20)
    if not (1 <= int_w <= 12 and 1 <= frac_w <= 9):
        ok[:] = False
        int_w, frac_w = min(max(int_w, 1), 12), min(max(frac_w, 1), 9)

    ts, ok = decimal_stamps(line, buf, s, ok, dot, close, int_w, frac_w)

    name = close + 2
    names = np.zeros((s.size, 2), np.uint64)
    names[:, 0] = fill_low(line.word(name), name_len, _U64(0))
    if name_len > 8:
        names[:, 1] = fill_low(line.word(name + 8), name_len - 8, _U64(0))
    id_at = name + name_len + 1
    if id_len == 3:
        head = line.word(id_at)  # 3 ID digits, "#", 4 data digits
        ok &= (head & _U64(0xFF000000)) == _U64(0x23000000)
        ident, ok_id = hex_nibbles(fill_low(head, 3))
        ok &= ok_id
        mask4 = _U64(0xF)
        can_id = ((ident & mask4) << _U8) | (((ident >> _U8) & mask4) << _U64(4)) | (
            (ident >> _U64(16)) & mask4)
        flags = np.zeros(s.size, np.uint8)
    else:  # 8 ID digits, "#": as `_parse_general`, the error flag makes an error frame
        ident, ok_id = hex_nibbles(line.word(id_at))
        ok &= ok_id & (line.byte(id_at + 8) == _U64(0x23))
        raw = pack_nibbles(ident).astype(np.uint32).byteswap()  # first digit most significant
        err = (raw & np.uint32(CAN_ERR_FLAG)) != 0
        can_id = raw & np.uint32(CAN_EFF_MASK)
        flags = np.where(err, FLAG_ERR, FLAG_EXT).astype(np.uint8)

    # Data: after the `#` up to the end of the line, less a `\r` and a ` R`/` T` flag.
    last = buf[e - 1]
    if (cr := last == 0x0D).any():
        e = e - cr
        last = buf[e - 1]
    if (flag := (last == 0x52) | (last == 0x54)).any():
        e = e - 2 * (flag & (buf[e - 2] == 0x20))
    data_at = id_at + id_len + 1
    hex_len = e - (s + data_at)
    # A remote frame: `R` (or `r`), maybe its length digit 0..8 (node guarding, remote
    # PDOs); a len8_dlc suffix (`R_9`) is left to `_parse_general`.
    first = line.byte(data_at)
    digit = line.byte(data_at + 1) - _U64(0x30)  # non-digits wrap around: > 8
    remote = ((first == _U64(0x52)) | (first == _U64(0x72))) & (
        (hex_len == 1) | ((hex_len == 2) & (digit <= _U64(8))))
    dlc = hex_len // 2
    if remote.any():
        dlc = np.where(remote, np.where(hex_len == 2, digit.astype(np.int64), 0), dlc)
        hex_len = np.where(remote, 0, hex_len)
        flags = flags | np.where(remote, FLAG_RTR, 0).astype(np.uint8)
    ok &= (hex_len >= 0) & (hex_len <= 16) & (hex_len % 2 == 0)
    nib1, ok1 = hex_nibbles(fill_low(line.word(data_at), hex_len))
    ok &= ok1
    data = pack_nibbles(nib1)
    if (hex_len > 8).any():
        nib2, ok2 = hex_nibbles(fill_low(line.word(data_at + 8), hex_len - 8))
        ok &= ok2
        data |= pack_nibbles(nib2) << _U64(32)
    return (ok, ts, can_id.astype(np.uint32), dlc.astype(np.int16), data, names,
            np.full(s.size, name_len, np.int64), flags)


_WHITESPACE = frozenset(b" \t\n\r\x0b\x0c")


_NameKey = tuple[int, int, int]  # an interface name as two zero-padded words and its length


class ChannelNames:
    """Interface names of fast lines (as zero-padded words) -> channel codes.

    Per block the distinct names are found once (np.unique) and looked up in a dict: linear
    in the lines and the names, however many channels a log has (40,000 interfaces of two
    frames each cost what 80,000 frames on one do)."""

    def __init__(self) -> None:
        self.codes: dict[_NameKey, int] = {}

    def resolve(self, p: ParsedLines) -> tuple[np.ndarray, np.ndarray, list[tuple[int, bytes, int]],
                                           np.ndarray]:
        """(code per distinct name, -1 where the name is new; which distinct name each fast
        row has; the new names, each with its first row (in the block) and its place among
        the distinct ones; per distinct name, whether it has whitespace in it: its rows
        are no fast lines after all)."""
        keys = np.empty((p.fast.shape[0], 3), np.uint64)
        keys[:, :2] = p.iface
        keys[:, 2] = p.iface_len
        if keys.shape[0] and bool((keys == keys[0]).all()):  # the usual block: one interface
            uniq, first = keys[:1], np.zeros(1, np.int64)
            inverse = np.zeros(keys.shape[0], np.int64)
        else:
            uniq, first, inverse = np.unique(keys, axis=0, return_index=True,
                                             return_inverse=True)
            inverse = inverse.reshape(-1)
        ucode = np.full(uniq.shape[0], -1, np.int32)
        bad = np.zeros(uniq.shape[0], bool)
        new: list[tuple[int, bytes, int]] = []
        for u, (lo, hi, length) in enumerate(uniq.tolist()):
            key = (lo, hi, length)
            code = self.codes.get(key)
            if code is not None:
                ucode[u] = code
                continue
            name = (lo.to_bytes(8, "little") + hi.to_bytes(8, "little"))[:length]
            if _WHITESPACE.intersection(name):
                bad[u] = True
            else:
                new.append((int(p.fast[first[u]]), name, u))
        return ucode, inverse, new, bad



def read_blocks(source: Source, stats: InputStats) -> Iterator[FrameBatch]:
    """The fast path: common lines vectorised per block, the rest line by line, in order."""
    layout = _Layout()
    return read_parsed_blocks(source, stats, lambda b: _parse_block(b, layout), layout.learn,
                              _slow_lines)


def _slow_lines(block: Block, p: ParsedLines, stats: InputStats) -> Iterator[tuple[int, _Row]]:
    """The lines `_parse_block` left, through `_parse_line`: (row, frame) for each frame."""
    for row in _lines_to_parse(block, p.slow, stats).tolist():
        parsed = _parse_line(block.line(row), block.first_line + row, stats)
        if parsed is not None:
            yield row, parsed


SlowLines = Callable[[Block, ParsedLines, InputStats], Iterable[tuple[int, _Row]]]


def read_parsed_blocks(source: Source, stats: InputStats, parse: Callable[[Block], ParsedLines],
                       learn: Callable[[Block], None], slow_lines: SlowLines
                       ) -> Iterator[FrameBatch]:
    """A text reader's fast path (this one's and candump screen output's): each block's
    common lines vectorised by `parse`, the others (`ParsedLines.slow`) parsed by
    `slow_lines` (a frame as `_parse_line` gives it: its interface name as bytes),
    merged in file order; channels coded in order of first appearance, as the reference
    path codes them."""
    channels = ChannelNames()
    chan_of: dict[bytes, int] = {}
    builder = BatchBuilder()
    for block, p in parsed_blocks(source, parse, learn):
        ucode, inverse, new, bad_names = channels.resolve(p)
        if bad_names.any():  # an interface name with odd whitespace: let the reference decide
            bad = bad_names[inverse]
            p = _demote(p, bad)
            inverse = inverse[~bad]
        # The other lines, in file order (they count skips and may name channels too).
        slow_rows: list[int] = []
        slow_vals: list[_Row] = []
        for row, parsed in slow_lines(block, p, stats):
            slow_rows.append(row)
            slow_vals.append(parsed)
        # Register new channel names in order of first appearance, as the reference does.
        firsts: dict[bytes, int] = {name: row for row, name, _u in new}
        for row, vals in zip(slow_rows, slow_vals, strict=True):
            iface = vals[1]
            if iface not in chan_of and row < firsts.get(iface, row + 1):
                firsts[iface] = row
        for name, _row in sorted(firsts.items(), key=lambda kv: kv[1]):
            if name not in chan_of:
                chan_of[name] = stats.channel_code(name.decode("latin-1"))
        for _row, name, u in new:
            ucode[u] = chan_of[name]
        if new:  # each new name's key, from its first row (one pass over the rows)
            at = np.full(ucode.shape[0], -1, np.int64)
            at[inverse[::-1]] = np.arange(inverse.shape[0] - 1, -1, -1)
            for _row, _name, u in new:
                r = int(at[u])
                channels.codes[(int(p.iface[r, 0]), int(p.iface[r, 1]),
                                int(p.iface_len[r]))] = int(ucode[u])
        code = ucode[inverse]
        slow = [SlowRow(ts, chan_of[iface], can_id, ext, rtr, err, fd, dlc, data)
                for ts, iface, can_id, ext, rtr, err, fd, dlc, data in slow_vals]
        for batch in merged_batches(builder, block, p.fast,
                                    (p.ts, code, p.can_id, p.dlc, p.data, p.flags),
                                    slow_rows, slow):
            account(stats, batch)
            yield batch
    if (last := account(stats, builder.take())) is not None:
        yield last


_WHITESPACE_BYTE = np.zeros(256, bool)  # what bytes.split() splits on
_WHITESPACE_BYTE[list(b" \t\n\r\x0b\x0c")] = True
MANY_SLOW_LINES = 64  # below this, the slow path is cheaper than the vectorised filter


def _lines_to_parse(block: Block, rows: np.ndarray, stats: InputStats) -> np.ndarray:
    """The slow rows that need `_parse_line`: blank lines are nothing (dropped here), and
    lines that begin with `#` are comments, non-frame records (counted here in bulk, as
    `_parse_line` counts them: `InputStats.note`). A file of blank or comment lines then
    costs what counting its lines costs, not a Python call per line."""
    if rows.size < MANY_SLOW_LINES:
        return rows
    nonblank = np.cumsum(~_WHITESPACE_BYTE[block.buf], dtype=np.int64)
    starts, ends = block.starts[rows], block.ends[rows]
    blank = nonblank[ends - 1] - nonblank[starts - 1] == 0
    comment = ~blank & (block.buf[starts] == ord("#"))
    stats.note(int(np.count_nonzero(comment)))
    out: np.ndarray = rows[~blank & ~comment]
    return out


def _demote(p: ParsedLines, bad: np.ndarray) -> ParsedLines:
    keep = ~bad
    slow = np.union1d(p.slow, p.fast[bad])
    return ParsedLines(p.fast[keep], slow, p.ts[keep], p.can_id[keep], p.dlc[keep], p.data[keep],
                   p.iface[keep], p.iface_len[keep], p.flags[keep])
