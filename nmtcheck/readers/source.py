"""A log's bytes as a reader reads them: decompression (gzip, bzip2, xz, zstd, UTF-16
text), lines split with a bound on their length, and the `Source` a reader gets."""

from __future__ import annotations

import bz2
import codecs
import gzip
import io
import lzma
import re
import zlib
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import IO, Any, cast

from nmtcheck.errors import InputError

HEAD_BYTES = 65536
# No format has records anywhere near this long; a longer "line" (a binary file read as
# text, a log whose newlines were lost) is one unparseable record, never held in memory whole.
MAX_LINE_BYTES = 1 << 20
# What `Source.lines()` yields in place of an overlong line: one token that no reader parses
# (and no format takes for a comment or a header), so it counts as one skipped record.
OVERLONG_LINE = b"<line-longer-than-1-MiB>\n"


def decompressed(raw: IO[bytes], magic: bytes) -> tuple[IO[bytes], str]:
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
        return io.BufferedReader(_ZstdFrames(raw)), "zstd"
    if magic.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
        return io.BufferedReader(_Utf16Text(raw)), "utf-16"
    return raw, ""


class _Utf16Text(io.RawIOBase):
    """A UTF-16 text log (with its BOM) read as UTF-8: what Windows PowerShell 5.1 writes
    for `ssh pi candump -L can0 > run.log`. Unread, such a log was "unknown log format",
    and in a directory a skipped file that let the gate pass. A byte sequence that is no
    UTF-16 becomes U+FFFD, so its line is a skipped record, counted."""

    READ_BYTES = 1 << 16

    def __init__(self, raw: IO[bytes]) -> None:
        self.raw = raw
        self.decoder = codecs.getincrementaldecoder("utf-16")("replace")
        self.pending = b""
        self.done = False

    def readable(self) -> bool:
        return True

    def readinto(self, b: Any) -> int:
        while not self.pending and not self.done:
            chunk = self.raw.read(self.READ_BYTES)
            self.done = not chunk
            self.pending = self.decoder.decode(chunk, final=self.done).encode("utf-8")
        n = min(len(b), len(self.pending))
        b[:n] = self.pending[:n]
        self.pending = self.pending[n:]
        return n


class _ZstdFrames(io.RawIOBase):
    """The frames of a zstd stream one after another (a concatenated `.zst` too).

    zstandard's own stream reader ends silently where a cut-off file ends, so a truncated
    log would look whole; here a stream that ends inside a frame raises EOFError, like the
    gzip, bzip2 and xz readers do. Compressed bytes are fed in small pieces, so one call
    never inflates to more than a few MB (a highly compressible block cannot explode).
    """

    FEED_BYTES = 256
    READ_BYTES = 1 << 16

    def __init__(self, raw: IO[bytes]) -> None:
        import zstandard  # ImportError: the caller names the missing module

        self._raw = raw
        self._dctx = zstandard.ZstdDecompressor()
        self._frame = self._dctx.decompressobj()
        self._in_frame = False  # compressed bytes of the current frame have been fed
        self._pending = b""  # compressed bytes read, fed up to _fed
        self._fed = 0
        self._out = b""  # decompressed bytes, returned up to _taken
        self._taken = 0

    def readable(self) -> bool:
        return True

    def readinto(self, b: bytearray | memoryview) -> int:  # type: ignore[override]
        while self._taken == len(self._out):
            if self._fed == len(self._pending):
                self._pending, self._fed = self._raw.read(self.READ_BYTES), 0
                if not self._pending:
                    if self._in_frame:
                        raise EOFError("zstd data ends inside a frame")
                    return 0
            piece = self._pending[self._fed : self._fed + self.FEED_BYTES]
            self._fed += len(piece)
            self._in_frame = True
            self._out, self._taken = self._frame.decompress(piece), 0
            if self._frame.eof:  # the next frame, if any, starts in what was left over
                self._pending = self._frame.unused_data + self._pending[self._fed :]
                self._fed = 0
                self._frame = self._dctx.decompressobj()
                self._in_frame = False
        n = min(len(b), len(self._out) - self._taken)
        b[:n] = self._out[self._taken : self._taken + n]
        self._taken += n
        return n


class Prefixed(io.RawIOBase):
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
        readinto = getattr(self._rest, "readinto", None)
        if readinto is not None:  # straight into the caller's buffer: no copy of a block
            return readinto(b) or 0
        data = self._rest.read(len(b))
        n = len(data)
        b[:n] = data
        return n


class Unnumbered(io.RawIOBase):
    """A text whose lines were pasted with their line numbers (`12: `, `cat -n`'s
    `    12<TAB>`, an editor's `12 | `): the same lines without them, so that line N of the
    file stays line N. `gutter` matches one line's number and what separates it from the
    line (readers/detect.py GUTTERS); a line without one is passed on as it is."""

    def __init__(self, stream: IO[bytes] | io.RawIOBase, gutter: re.Pattern[bytes]) -> None:
        self._read = getattr(stream, "read1", stream.read)
        self._gutter = re.compile(rb"(?m)^" + gutter.pattern)
        self._held = b""  # the start of a line not yet ended (fewer than MAX_LINE_BYTES)
        self._mid = False  # what was passed on ended inside a line: no line starts next
        self._out = b""  # lines without their numbers, not yet read
        self._done = False

    def readable(self) -> bool:
        return True

    def readinto(self, b: bytearray | memoryview) -> int:  # type: ignore[override]
        while not self._out and not self._done:
            chunk = self._read(READ_PIECE)
            data = self._held + chunk
            if not chunk:  # the last line, without a newline
                self._done, self._held = True, b""
                self._out = self._unnumbered(data)
                break
            cut = data.rfind(b"\n") + 1
            if not cut and len(data) < MAX_LINE_BYTES:
                self._held = data
                continue
            cut = cut or len(data)  # an overlong line: passed on as it comes
            self._held = data[cut:]
            self._out = self._unnumbered(data[:cut])
        n = min(len(b), len(self._out))
        b[:n] = self._out[:n]
        self._out = self._out[n:]
        return n

    def _unnumbered(self, data: bytes) -> bytes:
        if not data:
            return data
        rest = 0
        if self._mid:  # the end of a line whose start was passed on
            rest = data.find(b"\n") + 1 or len(data)
        out = data[:rest] + self._gutter.sub(b"", data[rest:])
        self._mid = not out.endswith(b"\n")
        return out


def read_up_to(stream: IO[bytes], n: int) -> bytes:
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


def stream_errors(compression: str) -> tuple[type[Exception], ...]:
    """What a damaged (truncated or corrupt) compressed stream raises while being read."""
    errors: tuple[type[Exception], ...] = (OSError, EOFError, lzma.LZMAError, zlib.error)
    if compression == "zstd":
        import zstandard

        errors += (zstandard.ZstdError,)
    return errors


READ_PIECE = 1 << 16  # what the line splitter reads at a time


def split_lines(chunks: Iterable[bytes], cap: int = MAX_LINE_BYTES) -> Iterator[bytes]:
    """The lines (LF or CRLF endings kept) of a byte stream given in pieces of any size:
    the one line splitter of every text input path (`Source.lines()`, `check --follow -`).

    Linear in the input whatever its lines: a line's pieces are joined once, and a line of
    `cap` bytes or more (without its newline) is never held: it becomes OVERLONG_LINE, one
    skipped record, and the rest of it is only scanned for its end. A last line without a
    newline is yielded as it is."""
    held: list[bytes] = []  # the current line's pieces so far (fewer than `cap` bytes)
    size = 0
    overlong = False  # the current line passed `cap`: dropped up to its newline
    for chunk in chunks:
        if not chunk:
            continue
        parts = chunk.split(b"\n")
        tail = parts.pop()
        for k, part in enumerate(parts):
            if k == 0:  # the end of the line the earlier pieces began
                if overlong:
                    overlong = False
                    yield OVERLONG_LINE
                    continue
                if held:
                    held.append(part)
                    part = b"".join(held)
                    held, size = [], 0
            yield OVERLONG_LINE if len(part) >= cap else part + b"\n"
        if overlong or not tail:
            continue
        held.append(tail)
        size += len(tail)
        if size >= cap:
            held, size, overlong = [], 0, True
    if overlong:
        yield OVERLONG_LINE
    elif held:
        yield b"".join(held)


def _lines(stream: IO[bytes], path: str, errors: tuple[type[Exception], ...]) -> Iterator[bytes]:
    """Raw lines (LF or CRLF endings), each at most MAX_LINE_BYTES (a longer one becomes
    OVERLONG_LINE); read errors of damaged files become InputError."""
    read = getattr(stream, "read1", stream.read)
    try:
        yield from split_lines(iter(lambda: read(READ_PIECE), b""))
    except errors as exc:
        raise InputError(path, f"read error (truncated or corrupt file?): {exc}") from None


class UpToDamage(io.RawIOBase):
    """A decompressed stream that ends where its compressed data is cut off or corrupt.

    A log whose `.gz` was cut when the power went is read up to the damage, and the damage
    is remembered (`damage`) so the report can say the input was truncated; under --strict
    the damage is an input error.
    """

    def __init__(self, stream: IO[bytes], errors: tuple[type[Exception], ...], path: str,
                 strict: bool) -> None:
        self._stream = stream
        self._errors = errors
        self._path = path
        self._strict = strict
        self._read = getattr(stream, "read1", stream.read)
        self.damage: str | None = None

    def readable(self) -> bool:
        return True

    def readinto(self, b: bytearray | memoryview) -> int:  # type: ignore[override]
        if self.damage is not None:
            return 0
        try:
            # read1: one step of the decompressor, so the data decompressed before the
            # damage is returned before the step that meets the damage raises
            data = self._read(len(b))
        except self._errors as exc:
            self.damage = str(exc) or type(exc).__name__
            if self._strict:
                raise InputError(self._path, f"compressed data is cut off or corrupt: "
                                 f"{self.damage}") from None
            return 0
        n = len(data)
        b[:n] = data
        return n


@dataclass
class Source:
    """One decompressed input as a reader sees it."""

    path: str  # the name to show in messages
    stream: IO[bytes]  # buffered, from the first byte of the (decompressed) content
    errors: tuple[type[Exception], ...]  # what a damaged stream raises while being read
    compression: str = ""  # "", "gzip", "bzip2", "xz", "zstd" or "utf-16" (text, re-encoded)
    file_path: str | None = None  # the path on disk when uncompressed (for seeking libraries)
    options: dict[str, Any] = field(default_factory=dict)  # e.g. {"topics": [...]} from --topic
    first_line: int = 1  # the line number of the stream's first line (after leading lines)

    def lines(self) -> Iterator[bytes]:
        """Raw lines (LF or CRLF endings); read errors become InputError."""
        return _lines(self.stream, self.path, self.errors)


def peek(source: Source, size: int = HEAD_BYTES) -> bytes:
    """The first `size` bytes (fewer at the end of the input) of what `source` has left to
    read; `source` still starts with them afterwards. For a reader that must look ahead
    before it decides how to read (candump: whether the log has timestamps)."""
    try:
        head = read_up_to(source.stream, size)
    except source.errors as exc:
        raise InputError(source.path, f"read error (truncated or corrupt file?): {exc}") from None
    source.stream = io.BufferedReader(Prefixed(head, source.stream), buffer_size=HEAD_BYTES)
    return head
