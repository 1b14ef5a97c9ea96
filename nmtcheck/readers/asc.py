"""Vector ASC (ASCII) logs as written by CANoe/CANalyzer and python-can's ASCWriter.

Handles `base hex|dec`, `timestamps absolute|relative` (relative: each stamp
is the delta from the previous event), trigger blocks present, absent or
repeated, classic `d`/`r` lines, `ErrorFrame`, `CANFD` lines (the flags field
says whether a frame is FD and whether it is remote), channels above 9,
cp1252 text and CRLF. Timestamps stay as written: seconds since the start of
measurement, as CANoe shows them.

Where python-can's ASCReader differs, this reader follows the file: `TxRq`
lines are transmit requests, not bus frames; relative timestamps are
accumulated; channels keep their 1-based number; a CANFD line with data
length 0 is remote only if its flags say so.

Speed: classic data frames in the file's own column layout (learned from one
line) are parsed vectorised a block at a time (readers/blocks.py) while the
file is `base hex` with absolute timestamps; every other line goes through
`_parse_line`, the per-line reference parser, in file order.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from nmtcheck.readers.blocks import (
    HIGH,
    MAX_EXACT,
    POW10,
    Block,
    LineWords,
    SlowRow,
    all_digits,
    byte_flags,
    byte_mask,
    count_flags,
    digit_flags,
    fill_high,
    fill_low,
    find_byte,
    hex_flags,
    high_flags,
    merged_batches,
    parse_digits,
    parsed_blocks,
    reference_path,
)
from nmtcheck.readers.detect import is_text
from nmtcheck.readers.frames import BatchBuilder, FrameBatch
from nmtcheck.readers.records import plausible_time
from nmtcheck.readers.source import Source
from nmtcheck.readers.stats import InputStats, Row, account, batches_of

FLAG_REMOTE = 0x10  # <MessageFlags> bit 4
FLAG_EDL = 0x1000  # bit 12: an FD frame
FLAG_RTR = 2  # BatchBuilder's flag bit of a remote frame
_NON_FRAME_AFTER_CHANNEL = {b"statistic:", b"j1939tp", b"status:", b"overloadframe"}


class _Bad(Exception):
    """A frame-like line that does not parse."""


def _num(tok: bytes, base: int) -> int:
    try:
        value = int(tok, base)
    except ValueError:
        raise _Bad(f"{tok.decode('latin-1')!r} is not a number") from None
    if value < 0:  # int() takes a sign; no ASC field has one
        raise _Bad(f"{tok.decode('latin-1')!r} is negative")
    return value


def _data(tokens: list[bytes], n: int, base: int) -> bytes:
    if len(tokens) < n:
        raise _Bad(f"expected {n} data bytes, found {len(tokens)}")
    if base == 16 and any(len(t) != 2 for t in tokens[:n]):  # `%02X`: one digit is a cut
        raise _Bad("data byte is not two hex digits")  # or damaged byte (`d 1 0`)
    values = [_num(t, base) for t in tokens[:n]]
    if any(v > 0xFF for v in values):
        raise _Bad("data byte above FFh")
    return bytes(values)


def _can_id(tok: bytes, base: int) -> tuple[int, bool]:
    ext = tok[-1:] in (b"x", b"X")
    value = _num(tok[:-1] if ext else tok, base)
    if value > (0x1FFFFFFF if ext else 0x7FF):
        raise _Bad("CAN-ID out of range")
    return value, ext


_HEADER = re.compile(rb"^\s*(date\s|base\s+(hex|dec)|Begin Triggerblock|// version)", re.I)
_EVENT = re.compile(rb"^\s*\d+\.\d+\s+(\d+|CANFD)\s+")


def sniff(head: bytes) -> bool:
    """An ASC log starts with its `date`/`base`/trigger-block header or with event lines;
    `//` comment lines before them are the format's own (the reader passes over them too)."""
    if not is_text(head):
        return False
    for raw in head.splitlines()[:50]:
        line = raw.strip()
        if line and (not line.startswith(b"//") or _HEADER.match(line)):
            return _HEADER.match(line) is not None or _EVENT.match(line) is not None
    return False


@dataclass
class _State:
    """What earlier lines set for the following ones."""

    base: int = 16
    relative: bool = False
    clock: float = 0.0  # running sum of deltas in relative mode

    @property
    def plain(self) -> bool:
        """Hex numbers and absolute timestamps: the only state the fast path parses."""
        return self.base == 16 and not self.relative


def _parse_line(raw: bytes, lineno: int, stats: InputStats, state: _State) -> Row | None:
    """One line: (ts, channel, id, ext, rtr, err, fd, dlc, data), or None for a line that is
    no frame (header, comment, status…: counted into stats where it is a record)."""
    tokens = raw.split()
    if not tokens:
        return None
    first = tokens[0].lower()
    if first in (b"date", b"//") or first.startswith(b"//"):
        return None
    if first == b"base":
        state.base = 10 if len(tokens) > 1 and tokens[1].lower() == b"dec" else 16
        state.relative = b"relative" in raw.lower()
        return None
    if first in (b"internal", b"no") and b"events" in raw.lower():
        return None
    if first in (b"begin", b"end") and len(tokens) > 1 and tokens[1].lower() == b"triggerblock":
        state.clock = 0.0
        return None
    try:
        stamp = float(tokens[0])
    except ValueError:
        stats.skip(lineno, "line does not start with a timestamp")
        return None
    if not plausible_time(stamp, negative=True):
        stats.skip(lineno, "timestamp is not a finite number within range")
        return None
    if state.relative:
        state.clock += stamp
        ts = state.clock
    else:
        ts = stamp
    if len(tokens) < 3:
        stats.skip(lineno, "event without content")
        return None
    kind = tokens[1]
    try:
        if kind == b"CANFD":
            frame = _fd_frame(tokens, state.base)
        elif kind.isdigit():
            if tokens[2].lower() in _NON_FRAME_AFTER_CHANNEL:
                stats.ignored += 1
                return None
            frame = _classic_frame(tokens, state.base)
        else:  # chip status, start of measurement, other buses, system variables…
            stats.ignored += 1
            return None
    except _Bad as exc:
        stats.skip(lineno, str(exc))
        return None
    if frame is None:  # TxRq: a transmit request, never on the bus
        stats.ignored += 1
        return None
    chan_name, can_id, ext, rtr, err, fd, dlc, data = frame
    return Row(ts, chan_name, can_id, ext, rtr, err, fd, dlc, data)


def read(source: Source, stats: InputStats) -> Iterator[FrameBatch]:
    if reference_path():
        return read_lines(source, stats)
    return read_blocks(source, stats)


def read_lines(source: Source, stats: InputStats) -> Iterator[FrameBatch]:
    """The reference path: every line through `_parse_line`."""
    return batches_of(stats, _rows(source, stats))


def _rows(source: Source, stats: InputStats) -> Iterator[tuple[int, Row]]:
    state = _State()
    for lineno, raw in enumerate(source.lines(), source.first_line):
        row = _parse_line(raw, lineno, stats, state)
        if row is not None:
            yield lineno, row


# The fast path's line: `<spaces><digits>.<digits> <channel> <id, 1-3 hex> Rx|Tx d <dlc 0-8>`
# and then exactly dlc ` XX` bytes, followed by whitespace or the end of the line. The
# spacing is learned from one such line (CANoe and python-can pad to fixed columns after
# the timestamp); lines spaced otherwise go through `_parse_line`.
_COMMON = re.compile(rb" *(\d{1,8})\.(\d{1,9})( +)(\d{1,3})( +)([0-9A-Fa-f]{1,3}) +([RT]x) +"
                     rb"([dD]) ([0-8])(?:(?: [0-9A-Fa-f]{2})*)(?=[ \t\r\n\x0b\x0c]|$)")
MAX_WIDTH = 64  # columns from the timestamp to the data: wider lines go per line (see PAD)
_WS = np.zeros(256, bool)
_WS[list(b" \t\r\n\x0b\x0c")] = True


@dataclass
class _Layout:
    """Column offsets after the timestamp, relative to the space that ends it."""

    frac: int  # digits after the dot
    chan: int  # channel digits start
    chan_w: int
    ident: int  # CAN-ID field start; the field runs to `direction`
    direction: int
    dtype: int  # the `d`; the DLC digit is 2 later, the data 3 later

    @classmethod
    def learn(cls, line: bytes) -> _Layout | None:
        m = _COMMON.match(line)
        if m is None:
            return None
        end = m.end(2)
        layout = cls(len(m[2]), m.start(4) - end, len(m[4]), m.start(6) - end,
                     m.start(7) - end, m.start(8) - end)
        return layout if layout.width <= MAX_WIDTH else None

    @property
    def width(self) -> int:
        return self.dtype + 3


@dataclass
class _Parsed:
    fast: np.ndarray  # rows (within the block) parsed here, in order
    ts: np.ndarray
    chan: np.ndarray  # channel number as written
    can_id: np.ndarray
    dlc: np.ndarray
    data: np.ndarray
    flags: np.ndarray  # BatchBuilder's flag bits: remote frames (node guarding) have bit 1


_U64 = np.uint64
_SPACES = _U64(0x2020202020202020)


def _data_tables() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per word of the data field (` XX` × 8 = 24 bytes): the flags of the bytes that are
    spaces, of those that are hex digits, and per DLC 0..8 of those that must be either."""
    space = np.zeros(3, np.uint64)
    digit = np.zeros(3, np.uint64)
    need = np.zeros((3, 9), np.uint64)
    for k in range(8):
        for pos, table in ((3 * k, space), (3 * k + 1, digit), (3 * k + 2, digit)):
            flag = np.uint64(0x80 << (8 * (pos % 8)))
            table[pos // 8] |= flag
            need[pos // 8, k + 1:] |= flag
    return space, digit, need


_DATA_SPACES, _DATA_DIGITS, _DATA_NEED = _data_tables()


def _fixed_words(layout: _Layout) -> list[tuple[int, np.uint64, np.uint64]]:
    """(offset, mask, value) words that check the template's fixed bytes after the
    timestamp: the spaces between the fields and the `x` of Rx/Tx (the byte after the
    frame type is checked apart: a remote frame's line may end there)."""
    fixed = {c: 0x20 for c in range(layout.chan)}
    fixed.update({c: 0x20 for c in range(layout.chan + layout.chan_w, layout.ident)})
    fixed.update({c: 0x20 for c in range(layout.ident + 3, layout.direction)})  # ID: 1..3 hex
    fixed.update({c: 0x20 for c in range(layout.direction + 2, layout.dtype)})
    fixed[layout.direction + 1] = ord("x")
    out = []
    for start in range(0, layout.width, 8):
        mask = value = 0
        for c, byte in fixed.items():
            if start <= c < start + 8:
                mask |= 0xFF << (8 * (c - start))
                value |= byte << (8 * (c - start))
        if mask:
            out.append((start, np.uint64(mask), np.uint64(value)))
    return out


_LEADING = np.asarray([0 if not b & 1 else 1 if not b & 2 else 2 if not b & 4 else 3
                       for b in range(16)], np.int64)


def _parse_block(block: Block, layout: _Layout, rows: np.ndarray) -> _Parsed:
    """Vectorised parse of the given rows of `block` that have the common shape."""
    buf = block.buf
    s = block.starts[rows]
    j, ok = find_byte(buf, s, 0x2E, _dot_guess(block, s), 1, 9)
    dot = s + j
    line = LineWords(block, dot)  # every field is at a constant offset from the dot
    # Before the dot: spaces, then 1..8 digits (bytes of the previous line count as spaces).
    head = fill_high(line.word(-8), j, _SPACES)
    digits = digit_flags(head)
    n_int = count_flags(digits)
    ok &= (n_int >= 1) & ((digits | byte_flags(head, 0x20)) == HIGH) & (
        digits == high_flags(n_int))
    whole = parse_digits(fill_high(head, n_int))
    frac_word = fill_low(line.word(1), layout.frac)
    ok &= all_digits(frac_word)
    frac = parse_digits(frac_word) // np.uint64(10 ** max(8 - layout.frac, 0))
    if layout.frac > 8:
        ninth = line.byte(9) - _U64(0x30)  # non-digits wrap around: > 9
        ok &= ninth <= _U64(9)
        frac = frac * _U64(10) + ninth
    end = dot + 1 + layout.frac  # the space after the timestamp
    total = whole * np.uint64(10 ** layout.frac) + frac
    ts = total.astype(np.float64) / POW10[layout.frac]
    # After the timestamp: the template (spaces, the `x` of Rx/Tx) checked word by word,
    # then the fields.
    after = 1 + layout.frac  # the space that ends the timestamp, from the dot
    for off, mask, value in _fixed_words(layout):
        ok &= (line.word(after + off) & mask) == value
    chan = np.zeros(rows.size, np.uint64)
    for k in range(layout.chan_w):
        digit = line.byte(after + layout.chan + k) - _U64(0x30)  # non-digits wrap: > 9
        ok &= digit <= _U64(9)
        chan = chan * _U64(10) + digit
    # CAN-ID field: 1..3 hex digits, then spaces up to the direction column.
    first = line.word(after + layout.ident)
    flags, nib = hex_flags(first)
    id_len = _LEADING[((((flags >> _U64(7)) * _U64(0x0102040810204080))
                        >> _U64(56)) & _U64(15)).astype(np.int64)]
    width = layout.direction - layout.ident
    ok &= (id_len >= 1) & (id_len < width)
    need = HIGH & ~byte_mask(id_len) & byte_mask(min(width, 3))  # the rest: in the template
    ok &= (byte_flags(first, 0x20) & need) == need
    # The first three nibbles as one number (spaces count 0), less the ones past the ID.
    mask4 = _U64(15)
    id3 = (nib & mask4) << _U64(8) | ((nib >> _U64(8)) & mask4) << _U64(4) | (
        (nib >> _U64(16)) & mask4)
    can_id = id3 >> ((3 - id_len) * 4).astype(np.uint64)
    ok &= can_id <= 0x7FF
    direction = line.byte(after + layout.direction)
    ok &= (direction == 0x52) | (direction == 0x54)
    dtype = line.byte(after + layout.dtype)
    dlc = line.byte(after + layout.dtype + 2) - _U64(0x30)
    # A remote frame: `r` (or `R`) then the end of the line, or one space and its length
    # 0..8 then whitespace; other spellings (more spaces, a longer token) go per line.
    past_r = dot + after + layout.dtype + 1
    end_now = (buf[past_r] == 0x0A) | (buf[past_r] == 0x0D) & (buf[past_r + 1] == 0x0A)
    with_dlc = (buf[past_r] == 0x20) & (dlc <= _U64(8)) & _WS[buf[past_r + 2]]
    remote = ((dtype == 0x72) | (dtype == 0x52)) & (end_now | with_dlc)
    ok &= ((dtype == 0x64) | (dtype == 0x44)) & (buf[past_r] == 0x20) | remote
    ok &= (dlc <= _U64(8)) | end_now
    dlc = np.where(remote & end_now, _U64(0), np.minimum(dlc, _U64(8))).astype(np.int64)
    data_len = np.where(remote, 0, dlc)  # a remote frame carries no data
    # Data: ` XX` per byte, then whitespace or the end of the line.
    nibs = np.empty((rows.size, 3), np.uint64)
    for k in range(3):
        word = line.word(after + layout.width + 8 * k)
        flags, nibs[:, k] = hex_flags(word)
        have = (byte_flags(word, 0x20) & _DATA_SPACES[k]) | (flags & _DATA_DIGITS[k])
        need = _DATA_NEED[k][data_len]
        ok &= (have & need) == need
    body = end + layout.width
    ok &= _WS[buf[body + 3 * data_len]] | remote
    # Each character's nibble shifted up, or'ed with the next one's: byte 3k+1 is data byte k.
    pairs = nibs.view(np.uint8).reshape(-1) << np.uint8(4)
    pairs[:-1] |= nibs.view(np.uint8).reshape(-1)[1:]
    data = pairs.reshape(-1, 24)[:, 1::3].copy()
    data.view(np.uint64)[:, 0] &= byte_mask(data_len)
    inexact = ok & (total >= np.uint64(MAX_EXACT))
    for i in np.flatnonzero(inexact):  # more digits than a double holds
        ts[i] = float(block.buf[dot[i] - n_int[i]:end[i]].tobytes())
    chan = chan.astype(np.int64)
    flags = np.where(remote, FLAG_RTR, 0).astype(np.uint8)
    if bool(ok.all()):
        return _Parsed(rows, ts, chan, can_id.astype(np.uint32), dlc.astype(np.int16), data,
                       flags)
    good = np.flatnonzero(ok)
    return _Parsed(rows[good], ts[good], chan[good], can_id[good].astype(np.uint32),
                   dlc[good].astype(np.int16), data[good], flags[good])



def _dot_guess(block: Block, s: np.ndarray) -> int:
    """Where the first line's dot is (timestamps of one file mostly have the same width)."""
    if not s.size:
        return 4
    line = block.buf[s[0]:s[0] + 16].tobytes()
    dot = line.find(b".")
    return dot if 1 <= dot < 9 else 4


def read_blocks(source: Source, stats: InputStats) -> Iterator[FrameBatch]:
    """The fast path: common lines vectorised per block, the rest line by line, in order."""
    builder = BatchBuilder()
    state = _State()
    layouts: list[_Layout] = []

    def learn(block: Block) -> None:
        for row in range(len(block)):
            if (layout := _Layout.learn(block.line(row))) is not None:
                layouts.append(layout)
                return

    def parse(block: Block) -> _Parsed | None:
        """Parsed ahead as if the state were plain; `_merge` drops it if it is not."""
        if not layouts:
            return None
        return _parse_block(block, layouts[0], np.arange(len(block)))

    for block, parsed in parsed_blocks(source, parse, learn):
        yield from _merge(block, parsed if state.plain else None, stats, state, builder)
    if (last := account(stats, builder.take())) is not None:
        yield last


def _merge(block: Block, parsed: _Parsed | None, stats: InputStats, state: _State,
           builder: BatchBuilder) -> Iterator[FrameBatch]:
    """Walk the block's lines in order: fast rows as parsed, the others through
    `_parse_line`; a line that leaves the plain state hands every later line to it too."""
    n = len(block)
    if parsed is None:
        parsed = _Parsed(np.empty(0, np.int64), np.empty(0), np.empty(0, np.int64),
                         np.empty(0, np.uint32), np.empty(0, np.int16), np.empty((0, 8), np.uint8),
                         np.empty(0, np.uint8))
    slow_rows: list[int] = []
    slow_vals: list[Row] = []

    def parse_line(row: int) -> None:
        vals = _parse_line(block.line(row), block.first_line + row, stats, state)
        if vals is not None:
            slow_rows.append(row)
            slow_vals.append(vals)

    cut = n  # rows from here on are not taken from the fast parse
    if parsed.fast.shape[0] < n:
        is_fast = np.zeros(n, bool)
        is_fast[parsed.fast] = True
        for row in np.flatnonzero(~is_fast).tolist():
            parse_line(row)
            if not state.plain:
                cut = row + 1
                break
    for row in range(cut, n):
        parse_line(row)
    k = int(np.searchsorted(parsed.fast, cut))  # the fast rows before the cut
    fast_rows, chan = parsed.fast[:k], parsed.chan[:k]
    # Channel names in order of first appearance, as the reference registers them.
    first_of = _first_rows(chan, fast_rows)
    firsts = {str(v): row for v, row in first_of.items()}
    for row, vals in zip(slow_rows, slow_vals, strict=True):
        if row < firsts.get(vals.channel, row + 1):
            firsts[vals.channel] = row
    for name, _row in sorted(firsts.items(), key=lambda kv: kv[1]):
        stats.channel_code(name)
    codes = {v: stats.channel_code(str(v)) for v in first_of}
    if len(codes) == 1:
        chan_code = np.full(k, codes.popitem()[1], np.int32)
    else:
        code_of = np.zeros(max(codes, default=0) + 1, np.int32)
        code_of[list(codes)] = list(codes.values())
        chan_code = code_of[chan]
    fast_cols = (parsed.ts[:k], chan_code, parsed.can_id[:k], parsed.dlc[:k], parsed.data[:k],
                 parsed.flags[:k])
    slow = [SlowRow(v.ts, stats.channel_code(v.channel), v.can_id, v.ext, v.rtr, v.err, v.fd,
                    v.dlc, v.data) for v in slow_vals]
    for batch in merged_batches(builder, block, fast_rows, fast_cols, slow_rows, slow):
        account(stats, batch)
        yield batch


def _first_rows(values: np.ndarray, rows: np.ndarray) -> dict[int, int]:
    """Each distinct value and the row it first appears on (one value: no sorting)."""
    if values.shape[0] == 0:
        return {}
    if bool((values == values[0]).all()):
        return {int(values[0]): int(rows[0])}
    distinct, first = np.unique(values, return_index=True)
    return dict(zip(distinct.tolist(), rows[first].tolist(), strict=True))


_Frame = tuple[str, int, bool, bool, bool, bool, int, bytes]


def _classic_frame(tokens: list[bytes], base: int) -> _Frame | None:
    """`<ts> <ch> <id>[x] Rx|Tx d <dlc> <bytes…>` / `… r [dlc]` / `<ts> <ch> ErrorFrame …`."""
    chan = str(int(tokens[1]))
    if tokens[2].lower() == b"errorframe":
        return chan, 0, False, False, True, False, 0, b""
    if len(tokens) < 5:
        raise _Bad("truncated frame line")
    can_id, ext = _can_id(tokens[2], base)
    direction = tokens[3]
    if direction == b"TxRq":
        return None
    if direction not in (b"Rx", b"Tx"):
        raise _Bad(f"unknown direction {direction.decode('latin-1')!r}")
    dtype = tokens[4].lower()
    if dtype == b"r":
        dlc = 0
        if len(tokens) > 5 and tokens[5].isalnum() and len(tokens[5]) == 1:
            dlc = _num(tokens[5], base)
        return chan, can_id, ext, True, False, False, dlc, b""
    if dtype != b"d" or len(tokens) < 6:
        raise _Bad("expected 'd <dlc>' or 'r'")
    dlc = _num(tokens[5], base)
    if dlc > 64:
        raise _Bad("DLC above 64")
    if dlc > 15:  # an FD frame written as a classic line: the field is its data length
        return chan, can_id, ext, False, False, True, dlc, _data(tokens[6:], dlc, base)[:8]
    data = _data(tokens[6:], min(dlc, 8), base)
    return chan, can_id, ext, False, False, False, dlc, data


def _fd_frame(tokens: list[bytes], base: int) -> _Frame | None:
    """`<ts> CANFD <ch> <dir> <id>[x] [name] <brs> <esi> <dlc> <len> <data…> <dur> <bits> <flags>`…

    None for a `TxRq` line (a transmit request, never on the bus).
    """
    if len(tokens) < 5:
        raise _Bad("truncated CANFD line")
    chan = str(_num(tokens[2], 10))
    if tokens[3] == b"TxRq":
        return None
    if tokens[4].lower() == b"errorframe":
        return chan, 0, False, False, True, True, 0, b""
    can_id, ext = _can_id(tokens[4], base)
    rest = tokens[5:]
    if len(rest) >= 2 and not (rest[0].isdigit() and rest[1].isdigit()):
        rest = rest[1:]  # symbolic message name
    if len(rest) < 4:
        raise _Bad("truncated CANFD line")
    data_length = _num(rest[3], 10)
    if data_length > 64:
        raise _Bad("CAN FD data length above 64")
    data = _data(rest[4:], data_length, base)
    trailer = rest[4 + data_length :]
    fd, rtr = True, False
    if len(trailer) >= 3:
        flags = _num(trailer[2], 16)
        fd = bool(flags & FLAG_EDL) or data_length > 8
        rtr = bool(flags & FLAG_REMOTE) and not fd and data_length == 0
    dlc = _num(rest[2], 16) if rtr else data_length
    return chan, can_id, ext, rtr, False, fd, dlc, data[:8]
