"""Shared machinery of the vectorised text readers (candump, ASC).

A text log is read in large blocks cut at a newline. Each block becomes one
padded numpy byte array; a reader finds the line starts and ends, checks per
line (vectorised) whether the line has the format's common shape, and decodes
those lines' fields with SWAR arithmetic on 8-byte words gathered at computed
offsets. Every other line goes through the reader's per-line parser, which is
also the reference path (`NMTCHECK_REFERENCE=1` forces it for whole files, so
tests can compare both).

Past the first few MB, blocks are also split into lines and parsed in a forked
worker process (readers/forked.py; worker threads where forking is not safe),
while the reading thread reads ahead and merges the parsed blocks in file order;
`NMTCHECK_THREADS=1` keeps everything on the reading thread.
"""

from __future__ import annotations

import os
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, fields
from functools import partial
from typing import TYPE_CHECKING, Any, NamedTuple, TypeVar

import numpy as np

from nmtcheck.errors import InputError
from nmtcheck.readers import forked
from nmtcheck.readers.frames import BatchBuilder, FrameBatch
from nmtcheck.readers.source import MAX_LINE_BYTES, OVERLONG_LINE, Source

if TYPE_CHECKING:
    from concurrent.futures import Future

REFERENCE_ENV = "NMTCHECK_REFERENCE"
THREADS_ENV = "NMTCHECK_THREADS"
BLOCK_BYTES = 2 << 20
PARALLEL_BYTES = 8 << 20  # a shorter input is parsed by the reading thread alone
CARRY_ROOM = 64 << 10  # a block sent to the worker process may start with this much carry
MAX_WORKERS = 2  # parse threads (without fork): the machine this is tuned on has 2 cores
T = TypeVar("T")
PAD = 128  # bytes before and after a block's data: gathers at line offsets never fall off

ONES = np.uint64(0x0101010101010101)
HIGH = np.uint64(0x8080808080808080)
ASCII_ZEROS = np.uint64(0x3030303030303030)
_U64 = np.uint64


def usable_cpus() -> int:
    """CPUs this process may run on (the affinity mask where the OS has one)."""
    affinity = getattr(os, "sched_getaffinity", None)
    return len(affinity(0)) if affinity else os.cpu_count() or 1


def reference_path() -> bool:
    """True when the per-line reference parser must read every line (tests, bug hunts)."""
    return os.environ.get(REFERENCE_ENV, "") not in ("", "0")


def parse_threads() -> int:
    """NMTCHECK_THREADS if set, else one per CPU up to MAX_WORKERS: 1 parses every block on
    the reading thread; more, in parallel (the worker threads, without fork)."""
    value = os.environ.get(THREADS_ENV, "").strip()
    if value.isdigit() and int(value) >= 1:
        return int(value)
    return min(usable_cpus(), MAX_WORKERS)


@dataclass
class Block:
    """One block of whole lines as a padded byte array."""

    buf: np.ndarray  # uint8, 8-byte aligned: PAD bytes, the block, a newline, PAD bytes
    words: np.ndarray  # uint64 view: words[i] = the 8 bytes at buf[i:i+8] (little endian)
    aligned: np.ndarray  # uint64 view: aligned[i] = words[8 * i]
    starts: np.ndarray  # int64 index into buf of each line's first byte
    ends: np.ndarray  # int64 index into buf of each line's newline (added after a last line)
    first_line: int  # 1-based line number of the block's first line
    unterminated: bool = False  # the input's last line had no newline (one was added)

    def __len__(self) -> int:
        return int(self.starts.shape[0])

    def line(self, row: int) -> bytes:
        """A line's raw bytes as `Source.lines()` yields them (with its newline, if any;
        OVERLONG_LINE for a line of MAX_LINE_BYTES or more)."""
        start, end = int(self.starts[row]), int(self.ends[row])
        if end - start >= MAX_LINE_BYTES:
            return OVERLONG_LINE
        if self.unterminated and row == len(self) - 1:
            end -= 1
        return self.buf[start:end + 1].tobytes()


Chunk = forked.Chunk  # a padded buffer (see Block.buf) and how many bytes of lines it holds


def _block(chunk: Chunk) -> Block:
    """The lines of a chunk: `buf` = PAD bytes, `size` bytes of whole lines, at least PAD more
    (numbered later, in file order: `first_line` is 0 here)."""
    buf, size = chunk
    ends = np.flatnonzero(buf[PAD:PAD + size] == 10) + PAD
    unterminated = bool(size) and buf[PAD + size - 1] != 10
    if unterminated:  # a last line without newline: give it one in the padding
        buf[PAD + size] = 10
        ends = np.append(ends, PAD + size)
    starts = np.empty_like(ends)
    if ends.size:
        starts[0] = PAD
        starts[1:] = ends[:-1] + 1
    return _lines(buf, starts, ends, unterminated)


def _lines(buf: np.ndarray, starts: np.ndarray, ends: np.ndarray, unterminated: bool) -> Block:
    words = np.ndarray(shape=(buf.shape[0] - 7,), dtype="<u8", buffer=buf, strides=(1,))
    aligned = np.ndarray(shape=(buf.shape[0] // 8,), dtype="<u8", buffer=buf)
    return Block(buf, words, aligned, starts, ends, 0, unterminated)


def _aligned_empty(n: int) -> np.ndarray:
    """n uninitialised bytes starting at a multiple of 8 (for the uint64 view)."""
    raw = np.empty(n + 8, np.uint8)
    skip = -raw.ctypes.data % 8
    return raw[skip:skip + n]


def _read_into(source: Source, view: memoryview) -> int:
    """Fill `view` from the stream (fewer bytes only at the end of the input)."""
    got = 0
    try:
        while got < len(view):
            n = source.stream.readinto(view[got:])  # type: ignore[attr-defined]
            if not n:
                break
            got += n
    except source.errors as exc:
        raise InputError(source.path, f"read error (truncated or corrupt file?): {exc}") from None
    return got


def _last_newline(data: np.ndarray) -> int:
    """Offset of the last newline in `data`, -1 if none (searched from the end: a block's
    last newline is a line length away from it)."""
    hi, step = data.shape[0], 4096
    while hi > 0:
        lo = max(hi - step, 0)
        hits = np.flatnonzero(data[lo:hi] == 10)
        if hits.size:
            out: int = lo + int(hits[-1])
            return out
        hi, step = lo, step * 4
    return -1


def _chunks(source: Source) -> Iterator[Chunk]:
    """The input in chunks of whole lines, read straight into padded numpy buffers; read
    errors of damaged files become InputError."""
    size = BLOCK_BYTES
    carry = b""
    while True:
        buf = _aligned_empty(PAD + len(carry) + size + 1 + PAD)
        buf[:PAD] = 0
        buf[PAD:PAD + len(carry)] = np.frombuffer(carry, np.uint8)
        got = _read_into(source, buf.data[PAD + len(carry):PAD + len(carry) + size])
        filled = len(carry) + got
        buf[PAD + filled:] = 0
        if got == 0:  # end of input: what is left is the last line
            if filled:
                yield buf, filled
            return
        cut = _last_newline(buf[PAD:PAD + filled]) + 1
        if not cut:
            if filled < MAX_LINE_BYTES:  # a line longer than this read: read on
                carry = buf[PAD:PAD + filled].tobytes()
            else:  # overlong: one skipped record, as Source.lines() has it, never held whole
                carry = OVERLONG_LINE + _rest_after_line(source)
            continue
        carry = buf[PAD + cut:PAD + filled].tobytes()
        buf[PAD + cut:] = 0
        yield buf, cut


def _rest_after_line(source: Source) -> bytes:
    """Read and drop the rest of the current line; what follows its newline in the last read
    (empty at the end of the input)."""
    while True:
        try:
            chunk = source.stream.read(BLOCK_BYTES)
        except source.errors as exc:
            raise InputError(source.path,
                             f"read error (truncated or corrupt file?): {exc}") from None
        if not chunk:
            return b""
        cut = chunk.find(b"\n")
        if cut >= 0:
            return chunk[cut + 1:]


def parsed_blocks(source: Source, parse: Callable[[Block], T],
                  learn: Callable[[Block], None] | None = None) -> Iterator[tuple[Block, T]]:
    """(block, parse(block)) in file order. `learn` sees the first block before any parsing.

    The first PARALLEL_BYTES are parsed here. Past them, with more than one CPU (and unless
    NMTCHECK_THREADS=1), blocks are split into lines and parsed in parallel: by a forked
    worker process next to this one (readers/forked.py), or by worker threads where
    forking is not safe. A small input never starts either."""
    it = _chunks(source)
    first = next(it, None)
    if first is None:
        return
    head = _block(first)
    if learn is not None:
        learn(head)

    def job(chunk: Chunk) -> tuple[Block, T]:
        lines = _block(chunk)
        return lines, parse(lines)

    line = source.first_line
    for block, parsed in _parallel(job, it, (head, parse(head)), first[1]):
        block.first_line = line  # numbered here, in order: a worker cannot know it
        line += len(block)
        yield block, parsed


def _parallel(job: Callable[[Chunk], tuple[Block, T]], it: Iterator[Chunk],
              first: tuple[Block, T], seen: int) -> Iterator[tuple[Block, T]]:
    """`first`, then job(chunk) for each chunk, in order; in parallel once more than
    PARALLEL_BYTES have been read (`seen`: the bytes so far)."""
    yield first
    threads = parse_threads()
    for chunk in it:
        yield job(chunk)
        seen += chunk[1]
        if threads > 1 and seen > PARALLEL_BYTES:
            break
    else:
        return
    if forked.available():
        rebuilt = partial(_rebuilt, kind=type(first[1]))  # every block's parse is of one type
        yield from forked.ForkedParser(job, _arrays, rebuilt,
                                       BLOCK_BYTES + 2 * PAD + CARRY_ROOM).map(it)
        return
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(threads, thread_name_prefix="nmtcheck-parse") as pool:
        pending: deque[Future[tuple[Block, T]]] = deque()
        for chunk in it:
            pending.append(pool.submit(job, chunk))
            if len(pending) > threads:  # at most threads + 1 blocks parsed ahead
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()


def _arrays(result: tuple[Block, Any]) -> list[np.ndarray]:
    """A parsed block as arrays, to come back from the worker process: where its lines
    are, and the reader's parse of it (a dataclass of arrays, or None)."""
    lines, parsed = result
    cols = [] if parsed is None else [getattr(parsed, f.name) for f in fields(parsed)]
    return [lines.starts, lines.ends, np.asarray([lines.unterminated]), *cols]


def _rebuilt(chunk: Chunk, arrays: list[np.ndarray], kind: type) -> tuple[Block, Any]:
    """What `_arrays` took apart, on this process's copy of the chunk."""
    buf, size = chunk
    starts, ends, unterminated, *cols = arrays
    if unterminated[0]:
        buf[PAD + size] = 10  # as `_block` did in the worker
    return _lines(buf, starts, ends, bool(unterminated[0])), kind(*cols) if cols else None


class SlowRow(NamedTuple):
    """A frame from a reader's per-line parser (a line the vectorised parse leaves), its
    channel already coded."""

    ts: float
    chan: int  # code into InputStats.channels
    can_id: int
    ext: bool
    rtr: bool
    err: bool
    fd: bool
    dlc: int
    data: bytes


def merged_batches(builder: BatchBuilder, block: Block, fast_rows: np.ndarray,
                   fast_cols: tuple[np.ndarray, ...], slow_rows: list[int],
                   slow: list[SlowRow]) -> Iterator[FrameBatch]:
    """The block's frames in file order, the vectorised rows (`fast_cols`: ts, channel code,
    id, dlc, data and maybe flags: bit 0 ext, 1 rtr, 2 err, 3 fd) merged with the per-line
    parsed ones, handed to `builder`; yields the
    batches it completes."""
    ts, chan, can_id, dlc, data, *fast_flags = fast_cols  # flags: all 0 when not given
    flags = np.zeros(fast_rows.shape[0] + len(slow), np.uint8)
    if fast_flags:
        flags[:fast_rows.shape[0]] = fast_flags[0]
    if not slow:
        yield from builder.add_columns(ts, chan, can_id, flags, dlc, data,
                                       fast_rows + block.first_line)
        return
    rows = np.concatenate([fast_rows, np.asarray(slow_rows, np.int64)])
    order = np.argsort(rows, kind="stable")
    flags[fast_rows.shape[0]:] = [v.ext | v.rtr << 1 | v.err << 2 | v.fd << 3 for v in slow]
    slow_data = np.frombuffer(b"".join(v.data[:8].ljust(8, b"\0") for v in slow),
                              np.uint8).reshape(len(slow), 8)
    yield from builder.add_columns(
        np.concatenate([ts, np.asarray([v.ts for v in slow], np.float64)])[order],
        np.concatenate([chan, np.asarray([v.chan for v in slow], np.int32)])[order],
        np.concatenate([can_id, np.asarray([v.can_id for v in slow], np.uint32)])[order],
        flags[order],
        np.concatenate([dlc, np.asarray([v.dlc for v in slow], np.int16)])[order],
        np.concatenate([data, slow_data])[order],
        rows[order] + block.first_line)


def find_byte(buf: np.ndarray, base: np.ndarray, byte: int, guess: int,
              lo: int, hi: int) -> tuple[np.ndarray | int, np.ndarray]:
    """Per line, the smallest offset k (lo <= k < hi) with buf[base + k] == byte.

    Tries `guess` first (every line of a file usually has the same layout) and
    searches offset by offset only for the lines where the guess misses. A guess
    hit may not be the first occurrence: the caller's validation of the field
    before it (digits only, no whitespace) rejects such lines. Returns (offsets,
    found mask); the offset is one int when the guess is right for every line.
    """
    guess = guess if lo <= guess < hi else lo
    found = buf[base + guess] == byte
    miss = np.flatnonzero(~found)
    if miss.size == 0:
        return guess, found
    off = np.full(base.shape[0], guess, np.int64)
    for k in range(lo, hi):
        if miss.size == 0:
            break
        hit = buf[base[miss] + k] == byte
        off[miss[hit]] = k
        found[miss[hit]] = True
        miss = miss[~hit]
    return off, found


class LineWords:
    """Per line, the bytes from `base` (an index into the block per line) on, as 8-byte
    words that fields at constant offsets are shifted out of.

    numpy gathers 8 bytes at unaligned offsets slowly; aligned words are gathered instead and
    each line's pair shifted into place (half the cost), and one line's words are shared by
    all its fields."""

    def __init__(self, block: Block, base: np.ndarray) -> None:
        self._aligned = block.aligned
        self._index = base >> 3
        self._shift = ((base & 7) << 3).astype(np.uint64)
        self._back = _U64(64) - self._shift  # a shift by 64 gives 0 in numpy
        self._raw: dict[int, np.ndarray] = {}
        self._words: dict[int, np.ndarray] = {}

    def _aligned_word(self, i: int) -> np.ndarray:
        if i not in self._raw:
            self._raw[i] = self._aligned[self._index + i]
        return self._raw[i]

    def _word(self, i: int) -> np.ndarray:
        """The bytes base + 8i .. base + 8i + 7."""
        if i not in self._words:
            self._words[i] = (self._aligned_word(i) >> self._shift) | (
                self._aligned_word(i + 1) << self._back)
        return self._words[i]

    def word(self, off: int) -> np.ndarray:
        """The 8 bytes at base + off."""
        q, r = divmod(off, 8)
        if not r:
            return self._word(q)
        out: np.ndarray = (self._word(q) >> _U64(8 * r)) | (self._word(q + 1) << _U64(64 - 8 * r))
        return out

    def byte(self, off: int) -> np.ndarray:
        """The byte at base + off (as uint64)."""
        q, r = divmod(off, 8)
        out: np.ndarray = (self._word(q) >> _U64(8 * r)) & _U64(0xFF)
        return out


_KEEP_LOW = np.asarray([(1 << (8 * w)) - 1 for w in range(9)], np.uint64)


def _uniform(width: np.ndarray | int) -> int | None:
    """The one width all rows share (the usual case: masks become scalars), else None."""
    if isinstance(width, int):
        return width
    if width.shape[0] == 0:
        return 0
    lo, hi = int(width.min()), int(width.max())
    return lo if lo == hi else None


def fill_low(word: np.ndarray, width: np.ndarray | int,
             pad: np.uint64 = ASCII_ZEROS) -> np.ndarray:
    """Keep the low `width` bytes (a left-aligned field of 0..8 bytes), the rest = `pad`'s."""
    w = _uniform(width)
    if w is not None:
        keep = _KEEP_LOW[min(max(w, 0), 8)]
        out: np.ndarray = (word & keep) | (pad & ~keep)
        return out
    keep_arr = _KEEP_LOW[np.clip(width, 0, 8)]
    out = (word & keep_arr) | (pad & ~keep_arr)
    return out


def fill_high(word: np.ndarray, width: np.ndarray | int,
              pad: np.uint64 = ASCII_ZEROS) -> np.ndarray:
    """Keep the high `width` bytes (a right-aligned field of 0..8 bytes), the rest = `pad`'s."""
    w = _uniform(width)
    if w is not None:
        drop = _KEEP_LOW[8 - min(max(w, 0), 8)]
        out: np.ndarray = (word & ~drop) | (pad & drop)
        return out
    drop_arr = _KEEP_LOW[8 - np.clip(width, 0, 8)]
    out = (word & ~drop_arr) | (pad & drop_arr)
    return out


def all_digits(word: np.ndarray) -> np.ndarray:
    """True where all 8 bytes are ASCII decimal digits."""
    nib = np.uint64(0xF0F0F0F0F0F0F0F0)
    out: np.ndarray = (((word & nib) == ASCII_ZEROS)
                       & (((word + ONES * _U64(6)) & nib) == ASCII_ZEROS))
    return out


def parse_digits(word: np.ndarray) -> np.ndarray:
    """The value of 8 ASCII decimal digits (first byte most significant)."""
    x = word - ASCII_ZEROS
    x = (x * _U64(10) + (x >> _U64(8))) & _U64(0x00FF00FF00FF00FF)
    x = (x * _U64(100) + (x >> _U64(16))) & _U64(0x0000FFFF0000FFFF)
    x = (x * _U64(10000) + (x >> _U64(32))) & _U64(0xFFFFFFFF)
    out: np.ndarray = x
    return out


def _at_least(low7: np.ndarray, limit: int) -> np.ndarray:
    """80h in each byte of `low7` (bytes below 80h: no carries) whose value is >= limit."""
    out: np.ndarray = (low7 + ONES * _U64(0x80 - limit)) & HIGH
    return out


_LOW7 = ONES * _U64(0x7F)


def byte_flags(word: np.ndarray, byte: int) -> np.ndarray:
    """80h in each byte equal to `byte`, 00h elsewhere."""
    t = word ^ (ONES * _U64(byte))
    out: np.ndarray = ~(((t & _LOW7) + _LOW7) | t | _LOW7)
    return out


def digit_flags(word: np.ndarray) -> np.ndarray:
    """80h in each byte that is an ASCII decimal digit."""
    low7 = word & _LOW7
    out: np.ndarray = _at_least(low7, 0x30) & ~_at_least(low7, 0x3A) & ~word & HIGH
    return out


_ABOVE = {limit: ONES * _U64(0x80 - limit) for limit in (0x30, 0x3A, 0x61, 0x67)}


def hex_flags(word: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(80h in each byte that is a hex digit, per-byte nibble values where it is)."""
    low7 = word & _LOW7
    lower = low7 | (ONES * _U64(0x20))
    ascii_ = ~word & HIGH
    # (x + 80h - a) & ~(x + 80h - b) has 80h where a <= x < b (7-bit x: no carries)
    letter = (lower + _ABOVE[0x61]) & ~(lower + _ABOVE[0x67]) & ascii_
    flags = ((low7 + _ABOVE[0x30]) & ~(low7 + _ABOVE[0x3A]) & ascii_) | letter
    nib = (word & (ONES * _U64(0x0F))) + (letter >> _U64(7)) * _U64(9)
    return flags, nib


def count_flags(flags: np.ndarray) -> np.ndarray:
    """How many bytes carry the 80h flag."""
    out: np.ndarray = (((flags >> _U64(7)) * ONES) >> _U64(56)).astype(np.int64)
    return out


def low_flags(width: np.ndarray | int) -> np.ndarray | np.uint64:
    """80h in the low `width` bytes (0..8): the flag pattern of a left-aligned field."""
    if isinstance(width, int):
        out: np.ndarray | np.uint64 = _KEEP_LOW[min(max(width, 0), 8)] & HIGH
        return out
    out = _KEEP_LOW[np.clip(width, 0, 8)] & HIGH
    return out


def high_flags(width: np.ndarray | int) -> np.ndarray | np.uint64:
    """80h in the high `width` bytes (0..8): the flag pattern of a right-aligned field."""
    if isinstance(width, int):
        out: np.ndarray | np.uint64 = ~_KEEP_LOW[8 - min(max(width, 0), 8)] & HIGH
        return out
    out = ~_KEEP_LOW[8 - np.clip(width, 0, 8)] & HIGH
    return out


def byte_mask(width: np.ndarray | int) -> np.ndarray | np.uint64:
    """FFh in the low `width` bytes (0..8)."""
    if isinstance(width, int):
        out: np.ndarray | np.uint64 = _KEEP_LOW[min(max(width, 0), 8)]
        return out
    out = _KEEP_LOW[np.clip(width, 0, 8)]
    return out


def hex_nibbles(word: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(per-byte nibble values, all-hex mask) of 8 ASCII characters."""
    flags, nib = hex_flags(word)
    return nib, flags == HIGH


def pack_nibbles(nib: np.ndarray) -> np.ndarray:
    """8 nibbles (one per byte, first = high nibble of byte 0) -> 4 bytes in the low 32 bits."""
    y = ((nib << _U64(4)) | (nib >> _U64(8))) & _U64(0x00FF00FF00FF00FF)
    y = (y | (y >> _U64(8))) & _U64(0x0000FFFF0000FFFF)
    out: np.ndarray = (y | (y >> _U64(16))) & _U64(0xFFFFFFFF)
    return out


POW10 = 10.0 ** np.arange(20)
MAX_EXACT = 2**53  # integers up to here are exact in a float64


def decimal_stamps(line: LineWords, buf: np.ndarray, s: np.ndarray, ok: np.ndarray, dot: int,
                   close: int, int_w: int, frac_w: int) -> tuple[np.ndarray, np.ndarray]:
    """(seconds, ok) of a decimal number per line: `int_w` (1..12) digits right-aligned
    before offset `dot` (the `.`), `frac_w` (1..9) after it, up to offset `close` (the
    byte after the number: candump's `)`). `ok` narrowed to the lines whose number is all
    digits there; each value is float() of its text, correctly rounded."""
    # the decimal's digits as one exact integer: the integer digits' last 8 and the
    # fraction's last 8 as words, right-aligned before the dot and the close
    low = fill_high(line.word(dot - 8), min(int_w, 8))
    ok = ok & all_digits(low)
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
        ts[i] = float(buf[s[i] + dot - int_w:s[i] + close].tobytes())
    return ts, ok
