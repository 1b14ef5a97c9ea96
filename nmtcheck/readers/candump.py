"""SocketCAN candump log format (`candump -l` / `-L`): `(ts) iface ID#DATA [R|T]`.

Covers remote frames (`ID#R`, `ID#R<len>`, `ID#R<len>_<dlc>`), 8-digit extended
IDs, error frames (CAN_ERR_FLAG 0x20000000 in the ID), CAN FD
(`ID##<flags><data>`), the raw-DLC suffix of `candump -8` (`ID#<8 bytes>_<dlc>`),
the optional direction flag, nanosecond timestamps and `DROPCOUNT:` lines. CAN XL
lines (`ID###…` of older can-utils, `<vcid><prio>#<flags>:<sdt>:<af>#<data>` of
newer ones) are well-formed records that are not CAN CC/FD frames: ignored.

Speed: the common line, `(<digits>.<digits>) <iface> <3 hex>#<0..8 hex bytes>`
with an optional ` R`/` T`, is parsed vectorised a block of lines at a time
(readers/blocks.py); every other line goes through `_parse_line`, the per-line
reference parser, in file order.
"""

from __future__ import annotations

import re
from binascii import unhexlify
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from nmtcheck.frames import BatchBuilder, FrameBatch
from nmtcheck.readers import (
    MAX_SKIPPED_LINES_KEPT,
    InputStats,
    Row,
    Source,
    account,
    batches_of,
    is_text,
)
from nmtcheck.readers.blocks import (
    MAX_EXACT,
    POW10,
    Block,
    LineWords,
    SlowRow,
    all_digits,
    fill_high,
    fill_low,
    find_byte,
    hex_nibbles,
    merged_batches,
    pack_nibbles,
    parse_digits,
    parsed_blocks,
    reference_path,
)

CAN_ERR_FLAG = 0x20000000
CAN_EFF_MASK = 0x1FFFFFFF
_HEX_DIGITS = b"0123456789abcdefABCDEF"
_FAST = re.compile(  # a classic 11-bit data frame; everything else takes the general path
    rb"\(([0-9]{1,12}\.[0-9]{1,9})\) (\S+) ([0-9A-Fa-f]{3})#((?:[0-9A-Fa-f]{2}){0,8})"
    rb"(?: [RT])?\r?\n?")
_DROP = re.compile(rb"DROPCOUNT:\s*dropped\s+(\d{1,18})\b")  # more digits: not a count
_CANXL = re.compile(rb"[0-9A-Fa-f]{5}#[0-9A-Fa-f]{2}:[0-9A-Fa-f]{2}:[0-9A-Fa-f]{8}#[0-9A-Fa-f.]*$")


def _is_hex(b: bytes) -> bool:
    return bool(b) and not b.translate(None, _HEX_DIGITS)  # nothing left once hex is deleted


def _bad_raw_dlc(sep: bytes, raw_dlc: bytes) -> bool:
    """A `_<dlc>` suffix (len8_dlc, `candump -8`) must be one hex digit."""
    return bool(sep) and (len(raw_dlc) != 1 or not _is_hex(raw_dlc))


_SNIFF = re.compile(rb"^\s*\(\s*-?\d+(\.\d+)?\)\s+\S+\s+[0-9A-Fa-f]+##?")


def sniff(head: bytes) -> bool:
    """A candump log starts (within its first 50 lines) with a `(ts) iface ID#` line."""
    if not is_text(head):
        return False
    for raw in head.splitlines()[:50]:
        line = raw.strip()
        if line:
            return _SNIFF.match(line) is not None
    return False


# One frame parsed by `_parse_line`: ts, interface name (the line's bytes), CAN-ID, ext, rtr,
# err, fd, dlc, data. A plain tuple, not a NamedTuple: `_parse_line` is the per-line parser
# (the reference path, every line of `check --follow`), where building one costs.
_Row = tuple[float, bytes, int, bool, bool, bool, bool, int, bytes]


class _Skip(Exception):
    """A line that is no well-formed record; the message is the skip's reason."""


def _parse_line(raw: bytes, lineno: int, stats: InputStats) -> _Row | None:
    """One line: (ts, iface, id, ext, rtr, err, fd, dlc, data), or None for a non-frame line
    (counted into stats: skipped, ignored, dropped)."""
    fast = _FAST.fullmatch(raw)
    if fast is not None:  # the common case: a classic 11-bit data frame
        data = unhexlify(fast[4])
        return (float(fast[1]), fast[2], int(fast[3], 16), False, False, False, False,
                len(data), data)
    try:
        return _parse_general(raw, stats)
    except _Skip as bad:
        stats.skip(lineno, str(bad))
        return None


def _parse_general(raw: bytes, stats: InputStats) -> _Row | None:
    """Any line `_FAST` does not take; raises _Skip for an unparseable record."""
    parts = raw.split()
    if not parts:
        return None
    if parts[0].startswith(b"DROPCOUNT"):
        _count_drops(raw, stats)
        return None
    if len(parts) < 3 or len(parts) > 4:
        raise _Skip("expected '(timestamp) interface ID#DATA'")
    tok_ts, iface, frame = parts[0], parts[1], parts[2]
    if len(parts) == 4 and parts[3] not in (b"R", b"T"):
        raise _Skip("unexpected text after the frame")
    ts = _timestamp(tok_ts)
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


def _count_drops(raw: bytes, stats: InputStats) -> None:
    """A `DROPCOUNT: dropped N` line: frames the logger lost."""
    m = _DROP.search(raw)
    if m is None:
        raise _Skip("DROPCOUNT line without a count")
    stats.dropped += int(m.group(1))
    stats.ignored += 1


def _timestamp(tok_ts: bytes) -> float:
    """The `(seconds)` field."""
    if not (tok_ts.startswith(b"(") and tok_ts.endswith(b")")):
        raise _Skip("timestamp is not in parentheses")
    try:
        ts = float(tok_ts[1:-1])
    except ValueError:
        raise _Skip("timestamp is not a number") from None
    if ts != ts or ts in (float("inf"), float("-inf")):
        raise _Skip("timestamp is not a finite number")
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
    if reference_path():
        return read_lines(source, stats)
    return read_blocks(source, stats)


def read_lines(source: Source, stats: InputStats) -> Iterator[FrameBatch]:
    """The reference path: every line through `_parse_line`."""
    return batches_of(stats, _rows(source, stats))


def _rows(source: Source, stats: InputStats) -> Iterator[tuple[int, Row]]:
    for lineno, raw in enumerate(source.lines(), source.first_line):
        row = _parse_line(raw, lineno, stats)
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
class _Parsed:
    """A block's common-shape lines, parsed; the other lines are `slow`."""

    fast: np.ndarray  # row numbers (within the block) of the lines parsed here
    slow: np.ndarray  # row numbers of every other line, for `_parse_line`
    ts: np.ndarray
    can_id: np.ndarray
    dlc: np.ndarray
    data: np.ndarray  # uint8 [n, 8]
    iface: np.ndarray  # uint64 [n, 2]: the interface name's bytes, zero padded
    iface_len: np.ndarray


_U64 = np.uint64
_U8 = _U64(8)
_Columns = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                 np.ndarray]  # ok, ts, can_id, dlc, data (one word), name (two words), name length


def _parse_block(block: Block, layout: _Layout) -> _Parsed:
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
    if isinstance(k, int) and isinstance(j, int) and isinstance(m, int):
        cols = _parse_shape(block, s, e, ok, k, j, m)
    else:  # several layouts in one block: each decoded apart, the results in row order
        shape = np.broadcast_to(np.asarray(k) << 10 | np.asarray(j) << 5 | m, rows.shape)
        cols = (np.zeros(rows.size, bool), np.zeros(rows.size), np.zeros(rows.size, np.uint32),
                np.zeros(rows.size, np.int16), np.zeros(rows.size, np.uint64),
                np.zeros((rows.size, 2), np.uint64), np.zeros(rows.size, np.int64))
        for value in np.unique(shape).tolist():
            sel = np.flatnonzero(shape == value)
            parts = _parse_shape(block, s[sel], e[sel], ok[sel], value >> 10, (value >> 5) & 31,
                                 value & 31)
            for col, part in zip(cols, parts, strict=True):
                col[sel] = part
    ok, ts, can_id, dlc, data, name, name_len = cols
    data8 = data.view(np.uint8).reshape(-1, 8)
    if rows.size == n and bool(ok.all()):  # the usual block: every line has the common shape
        return _Parsed(rows, np.empty(0, np.int64), ts, can_id, dlc, data8, name, name_len)
    good = np.flatnonzero(ok)
    fast = rows[good]
    is_fast = np.zeros(n, bool)
    is_fast[fast] = True
    return _Parsed(fast, np.flatnonzero(~is_fast), ts[good], can_id[good], dlc[good],
                   data8[good], name[good], name_len[good])


def _parse_shape(block: Block, s: np.ndarray, e: np.ndarray, ok: np.ndarray, close: int,
                 dot: int, name_len: int) -> _Columns:
    """The lines starting at `s` and ending (newline) at `e` whose `)`, `.` and the space
    after the interface are at offsets `close`, `dot` and `close + 2 + name_len`; `ok`:
    where those were found."""
    buf = block.buf
    line = LineWords(block, s)
    int_w, frac_w = dot - 1, close - dot - 1
    ok = ok & (line.byte(close + 1) == 0x20)
    if not (1 <= int_w <= 12 and 1 <= frac_w <= 9):
        ok[:] = False
        int_w, frac_w = min(max(int_w, 1), 12), min(max(frac_w, 1), 9)

    # Timestamp: the integer digits right-aligned before the dot, the fraction's last (up to
    # 8) digits right-aligned before the `)`: the decimal's digits as one exact integer.
    low = fill_high(line.word(dot - 8), min(int_w, 8))
    ok &= all_digits(low)
    total = parse_digits(low)
    if int_w > 8:
        high = fill_high(line.word(dot - 16), int_w - 8)
        ok &= all_digits(high)
        total += parse_digits(high) * _U64(10**8)
    frac = fill_high(line.word(close - 8), min(frac_w, 8))
    ok &= all_digits(frac)
    total = total * _U64(10**frac_w) + parse_digits(frac)
    if frac_w == 9:  # nanoseconds: the fraction's first digit
        first = line.byte(dot + 1) - _U64(0x30)  # non-digits wrap around: > 9
        ok &= first <= _U64(9)
        total += first * _U64(10**8)
    # float(total) / 10**frac_w is the correctly rounded value, as float() of the text is.
    ts = total.astype(np.float64) / POW10[frac_w]
    # More than 16 digits may even overflow `total`: those take float() of the text.
    inexact = ok if int_w + frac_w > 16 else ok & (total >= _U64(MAX_EXACT))
    for i in np.flatnonzero(inexact).tolist():  # more digits than a double holds
        ts[i] = float(buf[s[i] + 1:s[i] + close].tobytes())

    name = close + 2
    names = np.zeros((s.size, 2), np.uint64)
    names[:, 0] = fill_low(line.word(name), name_len, _U64(0))
    if name_len > 8:
        names[:, 1] = fill_low(line.word(name + 8), name_len - 8, _U64(0))
    head = line.word(name + name_len + 1)  # 3 ID digits, "#", 4 data digits
    ok &= (head & _U64(0xFF000000)) == _U64(0x23000000)
    ident, ok_id = hex_nibbles(fill_low(head, 3))
    ok &= ok_id
    mask4 = _U64(0xF)
    can_id = ((ident & mask4) << _U8) | (((ident >> _U8) & mask4) << _U64(4)) | (
        (ident >> _U64(16)) & mask4)

    # Data: after the `#` up to the end of the line, less a `\r` and a ` R`/` T` flag.
    last = buf[e - 1]
    if (cr := last == 0x0D).any():
        e = e - cr
        last = buf[e - 1]
    if (flag := (last == 0x52) | (last == 0x54)).any():
        e = e - 2 * (flag & (buf[e - 2] == 0x20))
    data_at = name + name_len + 5
    hex_len = e - (s + data_at)
    ok &= (hex_len >= 0) & (hex_len <= 16) & (hex_len % 2 == 0)
    nib1, ok1 = hex_nibbles(fill_low(line.word(data_at), hex_len))
    ok &= ok1
    data = pack_nibbles(nib1)
    if (hex_len > 8).any():
        nib2, ok2 = hex_nibbles(fill_low(line.word(data_at + 8), hex_len - 8))
        ok &= ok2
        data |= pack_nibbles(nib2) << _U64(32)
    return (ok, ts, can_id.astype(np.uint32), (hex_len // 2).astype(np.int16), data, names,
            np.full(s.size, name_len, np.int64))


_WHITESPACE = frozenset(b" \t\n\r\x0b\x0c")


_NameKey = tuple[int, int, int]  # an interface name as two zero-padded words and its length


class _Channels:
    """Interface names of fast lines (as zero-padded words) -> channel codes."""

    def __init__(self) -> None:
        self.codes: dict[_NameKey, int] = {}

    def resolve(self, p: _Parsed
                ) -> tuple[np.ndarray, list[tuple[int, bytes, _NameKey, np.ndarray]], np.ndarray]:
        """(code per fast row, -1 where the name is new; the new names, each with its first
        row, key and rows; rows whose "name" has whitespace in it: not fast lines after all)."""
        code = np.full(p.fast.shape[0], -1, np.int32)
        pending = np.ones(p.fast.shape[0], bool)

        def rows_of(key: _NameKey) -> np.ndarray:
            lo, hi, length = key
            rows: np.ndarray = ((p.iface[:, 0] == np.uint64(lo))
                                & (p.iface[:, 1] == np.uint64(hi)) & (p.iface_len == length))
            return rows

        for key, c in self.codes.items():
            hit = rows_of(key)
            code[hit] = c
            pending &= ~hit
        new: list[tuple[int, bytes, _NameKey, np.ndarray]] = []
        bad = np.zeros(p.fast.shape[0], bool)
        while pending.any():
            i = int(np.argmax(pending))
            key = (int(p.iface[i, 0]), int(p.iface[i, 1]), int(p.iface_len[i]))
            hit = pending & rows_of(key)
            pending &= ~hit
            name = (key[0].to_bytes(8, "little") + key[1].to_bytes(8, "little"))[:key[2]]
            if _WHITESPACE.intersection(name):
                bad |= hit
            else:
                new.append((int(p.fast[i]), name, key, hit))
        return code, new, bad


def read_blocks(source: Source, stats: InputStats) -> Iterator[FrameBatch]:
    """The fast path: common lines vectorised per block, the rest line by line, in order."""
    layout = _Layout()
    channels = _Channels()
    chan_of: dict[bytes, int] = {}
    builder = BatchBuilder()
    for block, p in parsed_blocks(source, lambda b: _parse_block(b, layout), layout.learn):
        code, new, bad = channels.resolve(p)
        if bad.any():  # an interface name with odd whitespace: let the reference decide
            keep = ~bad
            p = _demote(p, bad)
            code = code[keep]
            new = [(row, name, key, hit[keep]) for row, name, key, hit in new]
        # The other lines, in file order (they count skips and may name channels too).
        slow_rows: list[int] = []
        slow_vals: list[_Row] = []
        for row in _lines_to_parse(block, p.slow, stats).tolist():
            parsed = _parse_line(block.line(row), block.first_line + row, stats)
            if parsed is not None:
                slow_rows.append(row)
                slow_vals.append(parsed)
        # Register new channel names in order of first appearance, as the reference does.
        firsts: dict[bytes, int] = {name: row for row, name, _key, _hit in new}
        for row, vals in zip(slow_rows, slow_vals, strict=True):
            iface = vals[1]
            if iface not in chan_of and row < firsts.get(iface, row + 1):
                firsts[iface] = row
        for name, _row in sorted(firsts.items(), key=lambda kv: kv[1]):
            if name not in chan_of:
                chan_of[name] = stats.channel_code(name.decode("latin-1"))
        for _row, name, key, hit in new:
            code[hit] = channels.codes[key] = chan_of[name]
        slow = [SlowRow(ts, chan_of[iface], can_id, ext, rtr, err, fd, dlc, data)
                for ts, iface, can_id, ext, rtr, err, fd, dlc, data in slow_vals]
        for batch in merged_batches(builder, block, p.fast, (p.ts, code, p.can_id, p.dlc, p.data),
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
    lines that begin with `#` are unparseable records (counted here in bulk, but for the
    first few, whose line numbers are kept). A file of blank or comment lines then costs what
    counting its lines costs, not a Python call per line. Under --strict a comment line
    goes to `_parse_line` (the first skip is fatal, with its reason)."""
    if rows.size < MANY_SLOW_LINES:
        return rows
    nonblank = np.cumsum(~_WHITESPACE_BYTE[block.buf], dtype=np.int64)
    starts, ends = block.starts[rows], block.ends[rows]
    blank = nonblank[ends - 1] - nonblank[starts - 1] == 0
    comment = ~blank & (block.buf[starts] == ord("#"))
    if stats.strict or not comment.any():
        out: np.ndarray = rows[~blank]
        return out
    # Only the first few skipped line numbers are kept: the first comment lines go to
    # `_parse_line` among the others, in file order; the rest can only be counted.
    parse = ~blank & ~comment
    commented = np.flatnonzero(comment)
    room = max(MAX_SKIPPED_LINES_KEPT - len(stats.skipped_lines), 0)
    parse[commented[:room]] = True
    stats.skipped += len(commented) - min(room, len(commented))
    out = rows[parse]
    return out


def _demote(p: _Parsed, bad: np.ndarray) -> _Parsed:
    keep = ~bad
    slow = np.union1d(p.slow, p.fast[bad])
    return _Parsed(p.fast[keep], slow, p.ts[keep], p.can_id[keep], p.dlc[keep], p.data[keep],
                   p.iface[keep], p.iface_len[keep])
