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
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from nmtcheck.errors import InputError
from nmtcheck.readers import Source

REFERENCE_ENV = "NMTCHECK_REFERENCE"
BLOCK_BYTES = 4 << 20
PAD = 96  # bytes before and after a block's data: gathers at line offsets never fall off

ONES = np.uint64(0x0101010101010101)
HIGH = np.uint64(0x8080808080808080)
ASCII_ZEROS = np.uint64(0x3030303030303030)
_U64 = np.uint64


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
    raw: bytes  # the block's text (for the per-line parser)

    def __len__(self) -> int:
        return int(self.starts.shape[0])

    def line(self, row: int) -> bytes:
        """A line's raw bytes as the line iterator yields them (with its newline, if any)."""
        a = int(self.starts[row]) - PAD
        b = int(self.ends[row]) - PAD + 1
        return self.raw[a:min(b, len(self.raw))]


def _block(raw: bytes, first_line: int) -> Block:
    n = len(raw)
    buf = np.zeros(PAD + n + 1 + PAD, np.uint8)
    buf[PAD:PAD + n] = np.frombuffer(raw, np.uint8)
    ends = np.flatnonzero(buf[PAD:PAD + n] == 10) + PAD
    if n and raw[-1:] != b"\n":  # a last line without newline: give it one in the padding
        buf[PAD + n] = 10
        ends = np.append(ends, PAD + n)
    starts = np.empty_like(ends)
    if ends.size:
        starts[0] = PAD
        starts[1:] = ends[:-1] + 1
    words = np.ndarray(shape=(buf.shape[0] - 7,), dtype="<u8", buffer=buf, strides=(1,))
    return Block(buf, words, starts, ends, first_line, raw)


def blocks(source: Source, size: int | None = None) -> Iterator[Block]:
    """The input as blocks of whole lines; read errors of damaged files become InputError."""
    size = size or BLOCK_BYTES
    carry = b""
    line = 1
    while True:
        try:
            chunk = source.stream.read(size)
        except source.errors as exc:
            raise InputError(source.path,
                             f"read error (truncated or corrupt file?): {exc}") from None
        if not chunk:
            if carry:
                yield _block(carry, line)
            return
        cut = chunk.rfind(b"\n")
        if cut < 0:
            carry += chunk
            continue
        raw = carry + chunk[:cut + 1]
        carry = chunk[cut + 1:]
        block = _block(raw, line)
        line += len(block)
        yield block


def find_byte(buf: np.ndarray, base: np.ndarray, byte: int, guess: int,
              lo: int, hi: int, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per row, the smallest offset k (lo <= k < hi) with buf[base + k] == byte.

    Tries `guess` first (every line of a file usually has the same layout) and
    searches offset by offset only for the rows where the guess misses. A guess
    hit may not be the first occurrence: the caller's validation of the field
    before it (digits only, no whitespace) rejects such lines. Returns (offset
    array, found mask) for `rows` (indices into base).
    """
    guess = guess if lo <= guess < hi else lo
    off = np.full(rows.shape[0], guess, np.int64)
    found = buf[base[rows] + guess] == byte
    miss = np.flatnonzero(~found)
    for k in range(lo, hi):
        if miss.size == 0:
            break
        hit = buf[base[rows[miss]] + k] == byte
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


def hex_nibbles(word: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(per-byte nibble values, all-hex mask) of 8 ASCII characters."""
    def over(x: np.ndarray, limit: int) -> np.ndarray:  # 80h in each byte whose value >= limit
        return (x + ONES * _U64(0x80 - limit)) & HIGH

    lower = word | (ONES * _U64(0x20))
    digit = over(word, 0x30) & ~over(word, 0x3A)
    letter = over(lower, 0x61) & ~over(lower, 0x67)
    valid = ((word & HIGH) == 0) & ((digit | letter) == HIGH)
    nib = (word & (ONES * _U64(0x0F))) + (letter >> _U64(7)) * _U64(9)
    return nib, valid


def pack_nibbles(nib: np.ndarray) -> np.ndarray:
    """8 nibbles (one per byte, first = high nibble of byte 0) -> 4 bytes in the low 32 bits."""
    y = ((nib << _U64(4)) | (nib >> _U64(8))) & _U64(0x00FF00FF00FF00FF)
    y = (y | (y >> _U64(8))) & _U64(0x0000FFFF0000FFFF)
    return (y | (y >> _U64(16))) & _U64(0xFFFFFFFF)


POW10 = 10.0 ** np.arange(20)
MAX_EXACT = 2**53  # integers up to here are exact in a float64
