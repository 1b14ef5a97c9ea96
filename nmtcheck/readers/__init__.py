"""Opening a log: decompression, format detection by content, and dispatch to a reader.

Every reader is a generator `read(lines, stats, strict)` over the input's raw
lines that yields `FrameBatch` objects and keeps `InputStats` up to date.
"""

from __future__ import annotations

import bz2
import codecs
import gzip
import importlib
import io
import lzma
import os
import sys
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from types import ModuleType
from typing import IO, Any, cast

import numpy as np

from nmtcheck.errors import InputError
from nmtcheck.frames import FrameBatch

MAX_SKIPPED_LINES_KEPT = 10
HEAD_BYTES = 65536


@dataclass
class InputStats:
    """What a reader saw in one input; every record is accounted for here."""

    path: str
    format: str = ""
    frames: int = 0
    skipped: int = 0  # records that could not be parsed
    skipped_lines: list[int] = field(default_factory=list)
    ignored: int = 0  # well-formed records that are not bus frames (status, statistics, TxRq…)
    extended: int = 0
    error_frames: int = 0
    remote_frames: int = 0
    fd_frames: int = 0
    dropped: int = 0  # frames the logger says it lost (candump DROPCOUNT)
    backwards_timestamps: int = 0
    start: float | None = None
    end: float | None = None
    channels: list[str] = field(default_factory=list)
    strict: bool = False
    _chan_codes: dict[str, int] = field(default_factory=dict, repr=False)

    def channel_code(self, name: str) -> int:
        code = self._chan_codes.get(name)
        if code is None:
            code = len(self.channels)
            self._chan_codes[name] = code
            self.channels.append(name)
        return code

    def skip(self, line: int, why: str) -> None:
        """Count an unparseable record; fatal under --strict."""
        if self.strict:
            raise InputError(self.path, f"cannot parse {self.format} record: {why}", line)
        self.skipped += 1
        if len(self.skipped_lines) < MAX_SKIPPED_LINES_KEPT:
            self.skipped_lines.append(line)


def account(stats: InputStats, batch: FrameBatch | None) -> FrameBatch | None:
    """Count a finished batch into the input's stats (vectorised, once per batch)."""
    if batch is None or len(batch) == 0:
        return None
    ts = batch.ts
    back = int(np.count_nonzero(ts[1:] < ts[:-1]))
    if stats.end is not None and ts[0] < stats.end:
        back += 1
    if stats.start is None:
        stats.start = float(ts[0])
    stats.end = float(ts[-1])
    stats.backwards_timestamps += back
    stats.frames += len(batch)
    stats.extended += int(np.count_nonzero(batch.ext))
    stats.error_frames += int(np.count_nonzero(batch.err))
    stats.remote_frames += int(np.count_nonzero(batch.rtr))
    stats.fd_frames += int(np.count_nonzero(batch.fd))
    return batch


# Format name -> module, in the order sniffing tries them (binary magic bytes first, then
# text). A format module has `sniff(head: bytes) -> bool` (light, no heavy imports) and
# `read(source: Source, stats: InputStats) -> Iterator[FrameBatch]`. Adding a format = a
# module + a line here.
FORMAT_MODULES: dict[str, str] = {
    "mcap": "nmtcheck.readers.mcaplog",
    "mf4": "nmtcheck.readers.mf4",
    "pcap": "nmtcheck.readers.pcap",
    "blf": "nmtcheck.readers.blf",
    "candump": "nmtcheck.readers.candump",
    "asc": "nmtcheck.readers.asc",
    "trc": "nmtcheck.readers.trc",
    "candump-screen": "nmtcheck.readers.candump_screen",
    "csv": "nmtcheck.readers.csvlog",
    "cl2000": "nmtcheck.readers.cl2000",
}
FORMATS = tuple(FORMAT_MODULES)


def format_module(name: str) -> ModuleType:
    return importlib.import_module(FORMAT_MODULES[name])


def is_text(head: bytes) -> bool:
    """Text formats never contain NUL bytes."""
    return b"\x00" not in head[:4096]


def detect_format(head: bytes) -> str | None:
    """Name the format of a log from its first bytes (after decompression)."""
    for name in FORMAT_MODULES:
        if format_module(name).sniff(head):
            return name
    return None


def _decompressed(raw: IO[bytes], magic: bytes) -> tuple[IO[bytes], str]:
    """The decompressing stream for `magic`, and the compression's name ("" if none).

    Raises ImportError for zstd when the optional `zstandard` module is missing.
    """
    if magic.startswith(b"\x1f\x8b"):
        return cast(IO[bytes], gzip.GzipFile(fileobj=raw)), "gzip"
    if magic.startswith(b"BZh"):
        return bz2.BZ2File(raw), "bzip2"
    if magic.startswith(b"\xfd7zXZ\x00"):
        return lzma.LZMAFile(raw), "xz"
    if magic.startswith(b"\x28\xb5\x2f\xfd"):
        import zstandard

        return zstandard.ZstdDecompressor().stream_reader(raw), "zstd"
    return raw, ""


class _Prefixed(io.RawIOBase):
    """A stream that replays bytes already read (for sniffing) before the rest."""

    def __init__(self, head: bytes, rest: IO[bytes]) -> None:
        self._head = head
        self._rest = rest

    def readable(self) -> bool:
        return True

    def readinto(self, b: bytearray | memoryview) -> int:  # type: ignore[override]
        if self._head:
            n = min(len(b), len(self._head))
            b[:n] = self._head[:n]
            self._head = self._head[n:]
            return n
        data = self._rest.read(len(b))
        n = len(data)
        b[:n] = data
        return n


def _read_up_to(stream: IO[bytes], n: int) -> bytes:
    """Read n bytes or up to EOF (a raw stream may return less per call)."""
    parts: list[bytes] = []
    got = 0
    while got < n:
        chunk = stream.read(n - got)
        if not chunk:
            break
        parts.append(chunk)
        got += len(chunk)
    return b"".join(parts)


def _stream_errors(compression: str) -> tuple[type[Exception], ...]:
    """What a damaged (truncated or corrupt) compressed stream raises while being read."""
    errors: tuple[type[Exception], ...] = (OSError, EOFError, lzma.LZMAError, zlib.error)
    if compression == "zstd":
        import zstandard

        errors += (zstandard.ZstdError,)
    return errors


def _lines(stream: IO[bytes], path: str, errors: tuple[type[Exception], ...]) -> Iterator[bytes]:
    """Raw lines (LF or CRLF endings); read errors of damaged files become InputError."""
    try:
        yield from stream
    except errors as exc:
        raise InputError(path, f"read error (truncated or corrupt file?): {exc}") from None


@dataclass
class Source:
    """One decompressed input as a reader sees it."""

    path: str  # the name to show in messages
    stream: IO[bytes]  # buffered, from the first byte of the (decompressed) content
    errors: tuple[type[Exception], ...]  # what a damaged stream raises while being read
    compression: str = ""  # "", "gzip", "bzip2", "xz" or "zstd"
    file_path: str | None = None  # the path on disk when uncompressed (for seeking libraries)
    options: dict[str, Any] = field(default_factory=dict)  # e.g. {"topics": [...]} from --topic

    def lines(self) -> Iterator[bytes]:
        """Raw lines (LF or CRLF endings); read errors become InputError."""
        return _lines(self.stream, self.path, self.errors)


@dataclass
class OpenedInput:
    stats: InputStats
    batches: Iterator[FrameBatch]


def open_input(path: str, input_format: str | None = None, strict: bool = False,
               options: dict[str, Any] | None = None) -> OpenedInput:
    """Open, decompress and sniff one log; exit-2 errors name the file."""
    if path == "-":
        raw: IO[bytes] = sys.stdin.buffer
        display = "<stdin>"
    else:
        display = path
        if os.path.isdir(path):
            raise InputError(path, "is a directory, not a log file")
        try:
            raw = open(path, "rb")  # noqa: SIM115 - closed when the batches are exhausted
        except FileNotFoundError:
            raise InputError(path, "no such file") from None
        except OSError as exc:
            raise InputError(path, f"cannot open: {exc.strerror or exc}") from None
    try:
        magic = raw.read(6)
        try:
            stream, compression = _decompressed(_Prefixed(magic, raw), magic)  # type: ignore[arg-type]
        except ImportError:
            raise InputError(
                display, "zstd-compressed, but the 'zstandard' module is not installed"
            ) from None
        errors = _stream_errors(compression)
        try:
            head = _read_up_to(stream, HEAD_BYTES)
        except errors as exc:
            raise InputError(display, f"cannot decompress: {exc}") from None
    except BaseException:
        raw.close()
        raise
    if head.startswith(codecs.BOM_UTF8):  # a text file saved by a Windows editor
        head = head[len(codecs.BOM_UTF8) :]
    if not head:
        raw.close()
        raise InputError(display, "empty file: no records to check")
    fmt = input_format or detect_format(head)
    if fmt is not None and fmt not in FORMAT_MODULES:
        raw.close()
        raise InputError(display, f"unknown input format {fmt!r} (supported: {', '.join(FORMATS)})")
    if fmt is None:
        raw.close()
        raise InputError(
            display,
            "unknown log format (supported: " + ", ".join(FORMATS) + "; use --input-format NAME)",
        )
    reader = format_module(fmt).read
    stats = InputStats(path=display, format=fmt, strict=strict)
    buffered = io.BufferedReader(_Prefixed(head, stream), buffer_size=1 << 20)

    def batches() -> Iterator[FrameBatch]:
        try:
            source = Source(display, buffered, errors, compression,
                            None if compression or path == "-" else path, options or {})
            yield from reader(source, stats)
        finally:
            raw.close()

    return OpenedInput(stats, batches())
