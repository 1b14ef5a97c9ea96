"""Shared machinery of the vectorised text readers (candump, ASC).

A text log is read in large blocks cut at a newline. Each block becomes one
padded numpy byte array; a reader finds the line starts and ends, checks per
line (vectorised) whether the line has the format's common shape, and decodes
those lines' fields with SWAR arithmetic on 8-byte words gathered at computed
offsets. Every other line goes through the reader's per-line parser, which is
also the reference path (`NMTCHECK_REFERENCE=1` forces it for whole files, so
tests can compare both).
"""

from __future__ import annotations

import os
from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import TypeVar

import numpy as np

from nmtcheck.errors import InputError
from nmtcheck.frames import BatchBuilder, FrameBatch
from nmtcheck.readers import MAX_LINE_BYTES, OVERLONG_LINE, Source

REFERENCE_ENV = "NMTCHECK_REFERENCE"
BLOCK_BYTES = 2 << 20
MAX_WORKERS = 2  # parse threads: the machine this is tuned on has 2 cores
T = TypeVar("T")
PAD = 96  # bytes before and after a block's data: gathers at line offsets never fall off

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


@dataclass
class Block:
    """One block of whole lines as a padded byte array."""

    buf: np.ndarray  # uint8: PAD bytes, the block, a newline, PAD bytes
    words: np.ndarray  # uint64 view: words[i] = the 8 bytes at buf[i:i+8] (little endian)
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


def _block(buf: np.ndarray, size: int, first_line: int,
           newlines: np.ndarray | None = None) -> Block:
    """A block from `buf` = PAD bytes, `size` bytes of whole lines, at least PAD more
    (`newlines`: the newline offsets in those bytes, if already known)."""
    if newlines is None:
        newlines = np.flatnonzero(buf[PAD:PAD + size] == 10)
    ends = newlines + PAD
    unterminated = bool(size) and buf[PAD + size - 1] != 10
    if unterminated:  # a last line without newline: give it one in the padding
        buf[PAD + size] = 10
        ends = np.append(ends, PAD + size)
    starts = np.empty_like(ends)
    if ends.size:
        starts[0] = PAD
        starts[1:] = ends[:-1] + 1
    words = np.ndarray(shape=(buf.shape[0] - 7,), dtype="<u8", buffer=buf, strides=(1,))
    return Block(buf, words, starts, ends, first_line, unterminated)


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


def blocks(source: Source, size: int | None = None) -> Iterator[Block]:
    """The input as blocks of whole lines, read straight into padded numpy buffers; read
    errors of damaged files become InputError."""
    size = size or BLOCK_BYTES
    carry = b""
    line = 1
    while True:
        buf = np.empty(PAD + len(carry) + size + 1 + PAD, np.uint8)
        buf[:PAD] = 0
        buf[PAD:PAD + len(carry)] = np.frombuffer(carry, np.uint8)
        got = _read_into(source, buf.data[PAD + len(carry):PAD + len(carry) + size])
        filled = len(carry) + got
        buf[PAD + filled:] = 0
        if got == 0:  # end of input: what is left is the last line
            if filled:
                yield _block(buf, filled, line)
            return
        newlines = np.flatnonzero(buf[PAD:PAD + filled] == 10)
        if not newlines.size:
            if filled < MAX_LINE_BYTES:  # a line longer than this read: read on
                carry = buf[PAD:PAD + filled].tobytes()
            else:  # overlong: one skipped record, as Source.lines() has it, never held whole
                carry = OVERLONG_LINE + _rest_after_line(source)
            continue
        cut = int(newlines[-1]) + 1
        carry = buf[PAD + cut:PAD + filled].tobytes()
        buf[PAD + cut:] = 0
        block = _block(buf, cut, line, newlines)
        line += len(block)
        yield block


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
    """(block, parse(block)) in file order, parsing ahead in worker threads: numpy releases
    the GIL in its loops, so the blocks after the current one are parsed on the other cores
    while the caller works. At most `workers + 1` blocks are in memory. `learn` sees the
    first block before any parsing starts."""
    workers = min(usable_cpus(), MAX_WORKERS)
    it = blocks(source)
    first = next(it, None)
    if first is None:
        return
    if learn is not None:
        learn(first)
    if workers < 2:
        yield first, parse(first)
        for block in it:
            yield block, parse(block)
        return
    with ThreadPoolExecutor(workers, thread_name_prefix="nmtcheck-parse") as pool:
        pending: deque[tuple[Block, Future[T]]] = deque([(first, pool.submit(parse, first))])
        for block in it:
            pending.append((block, pool.submit(parse, block)))
            if len(pending) > workers:
                done, future = pending.popleft()
                yield done, future.result()
        while pending:
            done, future = pending.popleft()
            yield done, future.result()


SlowRow = tuple[float, int, int, bool, bool, bool, bool, int, bytes]  # ts, channel code, id,
# ext, rtr, err, fd, dlc, data: a frame from a reader's per-line parser


def merged_batches(builder: BatchBuilder, block: Block, fast_rows: np.ndarray,
                   fast_cols: tuple[np.ndarray, ...], slow_rows: list[int],
                   slow: list[SlowRow]) -> Iterator[FrameBatch]:
    """The block's frames in file order, the vectorised rows (`fast_cols`: ts, channel code,
    id, dlc, data) merged with the per-line parsed ones, handed to `builder`; yields the
    batches it completes."""
    ts, chan, can_id, dlc, data = fast_cols
    flags = np.zeros(fast_rows.shape[0] + len(slow), np.uint8)
    if not slow:
        yield from builder.add_columns(ts, chan, can_id, flags, dlc, data,
                                       fast_rows + block.first_line)
        return
    rows = np.concatenate([fast_rows, np.asarray(slow_rows, np.int64)])
    order = np.argsort(rows, kind="stable")
    flags[fast_rows.shape[0]:] = [v[3] | v[4] << 1 | v[5] << 2 | v[6] << 3 for v in slow]
    slow_data = np.frombuffer(b"".join(v[8][:8].ljust(8, b"\0") for v in slow),
                              np.uint8).reshape(len(slow), 8)
    yield from builder.add_columns(
        np.concatenate([ts, np.asarray([v[0] for v in slow], np.float64)])[order],
        np.concatenate([chan, np.asarray([v[1] for v in slow], np.int32)])[order],
        np.concatenate([can_id, np.asarray([v[2] for v in slow], np.uint32)])[order],
        flags[order],
        np.concatenate([dlc, np.asarray([v[7] for v in slow], np.int16)])[order],
        np.concatenate([data, slow_data])[order],
        rows[order] + block.first_line)


def find_byte(buf: np.ndarray, base: np.ndarray, byte: int, guess: int,
              lo: int, hi: int) -> tuple[np.ndarray, np.ndarray]:
    """Per line, the smallest offset k (lo <= k < hi) with buf[base + k] == byte.

    Tries `guess` first (every line of a file usually has the same layout) and
    searches offset by offset only for the lines where the guess misses. A guess
    hit may not be the first occurrence: the caller's validation of the field
    before it (digits only, no whitespace) rejects such lines. Returns (offsets,
    found mask).
    """
    guess = guess if lo <= guess < hi else lo
    off = np.full(base.shape[0], guess, np.int64)
    found = buf[base + guess] == byte
    miss = np.flatnonzero(~found)
    for k in range(lo, hi):
        if miss.size == 0:
            break
        hit = buf[base[miss] + k] == byte
        off[miss[hit]] = k
        found[miss[hit]] = True
        miss = miss[~hit]
    return off, found


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
        return (word & keep) | (pad & ~keep)
    keep_arr = _KEEP_LOW[np.clip(width, 0, 8)]
    return (word & keep_arr) | (pad & ~keep_arr)


def fill_high(word: np.ndarray, width: np.ndarray | int,
              pad: np.uint64 = ASCII_ZEROS) -> np.ndarray:
    """Keep the high `width` bytes (a right-aligned field of 0..8 bytes), the rest = `pad`'s."""
    w = _uniform(width)
    if w is not None:
        drop = _KEEP_LOW[8 - min(max(w, 0), 8)]
        return (word & ~drop) | (pad & drop)
    drop_arr = _KEEP_LOW[8 - np.clip(width, 0, 8)]
    return (word & ~drop_arr) | (pad & drop_arr)


def all_digits(word: np.ndarray) -> np.ndarray:
    """True where all 8 bytes are ASCII decimal digits."""
    nib = np.uint64(0xF0F0F0F0F0F0F0F0)
    return ((word & nib) == ASCII_ZEROS) & (((word + ONES * _U64(6)) & nib) == ASCII_ZEROS)


def parse_digits(word: np.ndarray) -> np.ndarray:
    """The value of 8 ASCII decimal digits (first byte most significant)."""
    x = word - ASCII_ZEROS
    x = (x * _U64(10) + (x >> _U64(8))) & _U64(0x00FF00FF00FF00FF)
    x = (x * _U64(100) + (x >> _U64(16))) & _U64(0x0000FFFF0000FFFF)
    x = (x * _U64(10000) + (x >> _U64(32))) & _U64(0xFFFFFFFF)
    return x


def _at_least(low7: np.ndarray, limit: int) -> np.ndarray:
    """80h in each byte of `low7` (bytes below 80h: no carries) whose value is >= limit."""
    return (low7 + ONES * _U64(0x80 - limit)) & HIGH


_LOW7 = ONES * _U64(0x7F)


def byte_flags(word: np.ndarray, byte: int) -> np.ndarray:
    """80h in each byte equal to `byte`, 00h elsewhere."""
    t = word ^ (ONES * _U64(byte))
    return ~(((t & _LOW7) + _LOW7) | t | _LOW7)


def digit_flags(word: np.ndarray) -> np.ndarray:
    """80h in each byte that is an ASCII decimal digit."""
    low7 = word & _LOW7
    return _at_least(low7, 0x30) & ~_at_least(low7, 0x3A) & ~word & HIGH


def hex_flags(word: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(80h in each byte that is a hex digit, per-byte nibble values where it is)."""
    low7 = word & _LOW7
    lower = low7 | (ONES * _U64(0x20))
    digit = _at_least(low7, 0x30) & ~_at_least(low7, 0x3A)
    letter = _at_least(lower, 0x61) & ~_at_least(lower, 0x67) & ~word
    flags = (digit | letter) & ~word & HIGH
    nib = (word & (ONES * _U64(0x0F))) + ((letter & HIGH) >> _U64(7)) * _U64(9)
    return flags, nib


def count_flags(flags: np.ndarray) -> np.ndarray:
    """How many bytes carry the 80h flag."""
    return (((flags >> _U64(7)) * ONES) >> _U64(56)).astype(np.int64)


def low_flags(width: np.ndarray | int) -> np.ndarray | np.uint64:
    """80h in the low `width` bytes (0..8): the flag pattern of a left-aligned field."""
    if isinstance(width, int):
        return _KEEP_LOW[min(max(width, 0), 8)] & HIGH
    return _KEEP_LOW[np.clip(width, 0, 8)] & HIGH


def high_flags(width: np.ndarray | int) -> np.ndarray | np.uint64:
    """80h in the high `width` bytes (0..8): the flag pattern of a right-aligned field."""
    if isinstance(width, int):
        return ~_KEEP_LOW[8 - min(max(width, 0), 8)] & HIGH
    return ~_KEEP_LOW[8 - np.clip(width, 0, 8)] & HIGH


def byte_mask(width: np.ndarray | int) -> np.ndarray | np.uint64:
    """FFh in the low `width` bytes (0..8)."""
    if isinstance(width, int):
        return _KEEP_LOW[min(max(width, 0), 8)]
    return _KEEP_LOW[np.clip(width, 0, 8)]


def hex_nibbles(word: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(per-byte nibble values, all-hex mask) of 8 ASCII characters."""
    flags, nib = hex_flags(word)
    return nib, flags == HIGH


def pack_nibbles(nib: np.ndarray) -> np.ndarray:
    """8 nibbles (one per byte, first = high nibble of byte 0) -> 4 bytes in the low 32 bits."""
    y = ((nib << _U64(4)) | (nib >> _U64(8))) & _U64(0x00FF00FF00FF00FF)
    y = (y | (y >> _U64(8))) & _U64(0x0000FFFF0000FFFF)
    return (y | (y >> _U64(16))) & _U64(0xFFFFFFFF)


POW10 = 10.0 ** np.arange(20)
MAX_EXACT = 2**53  # integers up to here are exact in a float64
