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

from nmtcheck.frames import BatchBuilder, FrameBatch
from nmtcheck.readers import InputStats, Source, account, is_text
from nmtcheck.readers.blocks import (
    MAX_EXACT,
    POW10,
    Block,
    all_digits,
    blocks,
    fill_high,
    fill_low,
    find_byte,
    parse_digits,
    reference_path,
)

FLAG_REMOTE = 0x10  # <MessageFlags> bit 4
FLAG_EDL = 0x1000  # bit 12: an FD frame
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
    """An ASC log starts with its `date`/`base`/trigger-block header or with event lines."""
    if not is_text(head):
        return False
    for raw in head.splitlines()[:50]:
        line = raw.strip()
        if line:
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


_Row = tuple[float, str, int, bool, bool, bool, bool, int, bytes]


def _parse_line(raw: bytes, lineno: int, stats: InputStats, state: _State) -> _Row | None:
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
    if stamp != stamp or stamp in (float("inf"), float("-inf")):
        stats.skip(lineno, "timestamp is not a finite number")
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
    return ts, chan_name, can_id, ext, rtr, err, fd, dlc, data


def read(source: Source, stats: InputStats) -> Iterator[FrameBatch]:
    if reference_path():
        return read_lines(source, stats)
    return read_blocks(source, stats)


def read_lines(source: Source, stats: InputStats) -> Iterator[FrameBatch]:
    """The reference path: every line through `_parse_line`."""
    builder = BatchBuilder()
    state = _State()
    for lineno, raw in enumerate(source.lines(), 1):
        row = _parse_line(raw, lineno, stats, state)
        if row is None:
            continue
        ts, chan_name, can_id, ext, rtr, err, fd, dlc, data = row
        builder.add(ts, stats.channel_code(chan_name), can_id, ext=ext, rtr=rtr, err=err, fd=fd,
                    dlc=dlc, data=data, line=lineno)
        if builder.full and (batch := account(stats, builder.take())) is not None:
            yield batch
    if (batch := account(stats, builder.take())) is not None:
        yield batch


# The fast path's line: `<spaces><digits>.<digits> <channel> <id, 1-3 hex> Rx|Tx d <dlc 0-8>`
# and then exactly dlc ` XX` bytes, followed by whitespace or the end of the line. The
# spacing is learned from one such line (CANoe and python-can pad to fixed columns after
# the timestamp); lines spaced otherwise go through `_parse_line`.
_COMMON = re.compile(rb" *(\d{1,8})\.(\d{1,9})( +)(\d{1,3})( +)([0-9A-Fa-f]{1,3}) +([RT]x) +([dD]) ([0-8])"
                     rb"(?:(?: [0-9A-Fa-f]{2})*)(?=[ \t\r\n\x0b\x0c]|$)")
_WS = np.zeros(256, bool)
_WS[list(b" \t\r\n\x0b\x0c")] = True
_HEX = np.full(256, 255, np.uint8)
for _i, _c in enumerate(b"0123456789abcdef"):
    _HEX[_c] = _HEX[bytes([_c]).upper()[0]] = _i


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
        return cls(len(m[2]), m.start(4) - end, len(m[4]), m.start(6) - end, m.start(7) - end,
                   m.start(8) - end)

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


def _columns(block: Block, pos: np.ndarray, width: int) -> np.ndarray:
    """uint8 [n, width]: the bytes at pos .. pos+width of each row."""
    words = -(-width // 8)
    gathered = np.empty((pos.shape[0], words), np.uint64)
    for k in range(words):
        gathered[:, k] = block.words[pos + 8 * k]
    return gathered.view(np.uint8)[:, :width]


def _parse_block(block: Block, layout: _Layout, rows: np.ndarray) -> _Parsed:
    """Vectorised parse of the given rows of `block` that have the common shape."""
    buf = block.buf
    s = block.starts[rows]
    j, ok = find_byte(buf, s, 0x2E, layout_dot_guess(block, s), 1, 9, np.arange(rows.size))
    dot = s + j
    # Before the dot: spaces, then 1..8 digits (bytes of the previous line count as spaces).
    head = _columns(block, dot - 8, 8).copy()
    head[np.arange(8)[None, :] < (8 - j)[:, None]] = 0x20
    digit = (head >= 0x30) & (head <= 0x39)
    ok &= digit[:, 7] & ((head == 0x20) | digit).all(1) & (~digit[:, :7] | digit[:, 1:]).all(1)
    n_int = digit.sum(1)
    whole = parse_digits(fill_high(head.view(np.uint64).ravel(), n_int))
    frac_word = fill_low(block.words[dot + 1], layout.frac)
    ok &= all_digits(frac_word)
    frac = parse_digits(frac_word) // np.uint64(10 ** max(8 - layout.frac, 0))
    if layout.frac > 8:
        ninth = buf[dot + 9].astype(np.int64) - 0x30
        ok &= (ninth >= 0) & (ninth <= 9)
        frac = frac * np.uint64(10) + np.clip(ninth, 0, 9).astype(np.uint64)
    end = dot + 1 + layout.frac  # the space after the timestamp
    total = whole * np.uint64(10 ** layout.frac) + frac
    ts = total.astype(np.float64) / POW10[layout.frac]
    cols = _columns(block, end, layout.width)
    spaces = [c for c in range(layout.chan)] + list(
        range(layout.chan + layout.chan_w, layout.ident)) + list(
        range(layout.direction + 2, layout.dtype)) + [layout.dtype + 1]
    ok &= (cols[:, spaces] == 0x20).all(1)
    chan_digits = cols[:, layout.chan:layout.chan + layout.chan_w].astype(np.int64) - 0x30
    ok &= ((chan_digits >= 0) & (chan_digits <= 9)).all(1)
    chan = np.zeros(rows.size, np.int64)
    for k in range(layout.chan_w):
        chan = chan * 10 + chan_digits[:, k]
    field = cols[:, layout.ident:layout.direction]
    hexv = _HEX[field[:, :3]].astype(np.int64)
    is_hex = hexv < 16
    id_len = is_hex[:, 0] * (1 + is_hex[:, 1] * (1 + is_hex[:, 2]))
    pad = field == 0x20
    ok &= (id_len > 0) & (pad | (np.arange(field.shape[1])[None, :] < id_len[:, None])).all(1)
    hexv = np.where(is_hex, hexv, 0)
    can_id = np.select([id_len == 3, id_len == 2],
                       [hexv[:, 0] << 8 | hexv[:, 1] << 4 | hexv[:, 2], hexv[:, 0] << 4 | hexv[:, 1]],
                       hexv[:, 0])
    ok &= can_id <= 0x7FF
    direction = cols[:, layout.direction]
    ok &= ((direction == 0x52) | (direction == 0x54)) & (cols[:, layout.direction + 1] == 0x78)
    dtype = cols[:, layout.dtype]
    ok &= (dtype == 0x64) | (dtype == 0x44)
    dlc = cols[:, layout.dtype + 2].astype(np.int64) - 0x30
    ok &= (dlc >= 0) & (dlc <= 8)
    dlc = np.clip(dlc, 0, 8)
    body = _columns(block, end + layout.width, 25)  # up to 8 ` XX` and what follows
    used = np.arange(8)[None, :] < dlc[:, None]
    ok &= ((body[:, 0:24:3] == 0x20) | ~used).all(1)
    nib = _HEX[body[:, [1 + 3 * k + h for k in range(8) for h in (0, 1)]]].reshape(-1, 8, 2)
    ok &= ((nib < 16).all(2) | ~used).all(1)
    ok &= _WS[body[np.arange(rows.size), 3 * dlc]]
    data = np.where(used, (nib[:, :, 0] << 4) | (nib[:, :, 1] & 15), 0).astype(np.uint8)
    inexact = ok & (total >= np.uint64(MAX_EXACT))
    for i in np.flatnonzero(inexact):  # more digits than a double holds
        ts[i] = float(block.buf[dot[i] - n_int[i]:end[i]].tobytes())
    good = np.flatnonzero(ok)
    return _Parsed(rows[good], ts[good], chan[good], can_id[good].astype(np.uint32),
                   dlc[good].astype(np.int16), data[good])


def layout_dot_guess(block: Block, s: np.ndarray) -> int:
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
    layout: _Layout | None = None
    for block in blocks(source):
        n = len(block)
        if layout is None:
            for row in range(n):
                layout = _Layout.learn(block.line(row))
                if layout is not None:
                    break
        parsed = None
        if layout is not None and state.plain:
            candidates = np.flatnonzero(block.buf[block.starts] != 0x62)  # not `base`
            parsed = _parse_block(block, layout, candidates)
        yield from _merge(block, parsed, stats, state, builder)
    if (last := account(stats, builder.take())) is not None:
        yield last


def _merge(block: Block, parsed: _Parsed | None, stats: InputStats, state: _State,
           builder: BatchBuilder) -> Iterator[FrameBatch]:
    """Walk the block's lines in order: fast rows as parsed, the others through
    `_parse_line`; a line that leaves the plain state hands every later line to it too."""
    n = len(block)
    is_fast = np.zeros(n, bool)
    if parsed is not None:
        is_fast[parsed.fast] = True
    slow = np.flatnonzero(~is_fast).tolist()
    slow_rows: list[int] = []
    slow_vals: list[_Row] = []
    cut = n  # rows from here on are not taken from the fast parse
    i = 0
    while i < len(slow):
        row = slow[i]
        i += 1
        if row >= cut:
            break
        was_plain = state.plain
        vals = _parse_line(block.line(row), block.first_line + row, stats, state)
        if vals is not None:
            slow_rows.append(row)
            slow_vals.append(vals)
        if was_plain and not state.plain:
            cut = row + 1
    if cut < n:  # every later line through the per-line parser, fast ones included
        for row in range(cut, n):
            vals = _parse_line(block.line(row), block.first_line + row, stats, state)
            if vals is not None:
                slow_rows.append(row)
                slow_vals.append(vals)
    if parsed is not None and cut < n:
        keep = parsed.fast < cut
        parsed = _Parsed(parsed.fast[keep], parsed.ts[keep], parsed.chan[keep],
                         parsed.can_id[keep], parsed.dlc[keep], parsed.data[keep])
    # Channel names in order of first appearance, as the reference registers them.
    firsts: dict[str, int] = {}
    fast_names: dict[int, str] = {}
    if parsed is not None and parsed.fast.size:
        values = np.unique(parsed.chan)
        for v in values.tolist():
            fast_names[v] = name = str(v)
            firsts[name] = int(parsed.fast[int(np.argmax(parsed.chan == v))])
    for row, vals in zip(slow_rows, slow_vals, strict=True):
        if row < firsts.get(vals[1], row + 1):
            firsts[vals[1]] = row
    for name, _row in sorted(firsts.items(), key=lambda kv: kv[1]):
        stats.channel_code(name)
    nf = 0 if parsed is None else parsed.fast.shape[0]
    ns = len(slow_rows)
    if nf + ns == 0:
        return
    flags = np.zeros(nf + ns, np.uint8)
    if parsed is not None:
        code_of = np.zeros(max(fast_names) + 1 if fast_names else 1, np.int32)
        for v, name in fast_names.items():
            code_of[v] = stats.channel_code(name)
        fast_cols = (parsed.ts, code_of[parsed.chan], parsed.can_id, parsed.dlc, parsed.data,
                     parsed.fast)
    else:
        fast_cols = (np.empty(0), np.empty(0, np.int32), np.empty(0, np.uint32),
                     np.empty(0, np.int16), np.empty((0, 8), np.uint8), np.empty(0, np.int64))
    rows = np.concatenate([fast_cols[5], np.asarray(slow_rows, np.int64)])
    ts = np.concatenate([fast_cols[0], np.asarray([v[0] for v in slow_vals], np.float64)])
    chan = np.concatenate([fast_cols[1], np.asarray([stats.channel_code(v[1])
                                                     for v in slow_vals], np.int32)])
    can_id = np.concatenate([fast_cols[2], np.asarray([v[2] for v in slow_vals], np.uint32)])
    flags[nf:] = [v[3] | v[4] << 1 | v[5] << 2 | v[6] << 3 for v in slow_vals]
    dlc = np.concatenate([fast_cols[3], np.asarray([v[7] for v in slow_vals], np.int16)])
    data = np.concatenate([fast_cols[4], np.frombuffer(
        b"".join(v[8][:8].ljust(8, b"\0") for v in slow_vals), np.uint8).reshape(ns, 8)])
    order = np.argsort(rows, kind="stable") if ns else slice(None)
    for batch in builder.add_columns(ts[order], chan[order], can_id[order], flags[order],
                                     dlc[order], data[order], rows[order] + block.first_line):
        account(stats, batch)
        yield batch


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
