"""Opening one input: the file (or standard input), its compression, its format, and the
reader's batches, with a damaged stream's cut last line told apart from a bad record."""

from __future__ import annotations

import codecs
import io
import os
import re
import stat
import sys
from collections.abc import Callable, Generator, Iterator
from dataclasses import dataclass
from typing import IO, Any

from nmtcheck.errors import InputError
from nmtcheck.readers.detect import (
    FORMAT_MODULES,
    FORMATS,
    TEXT_FORMATS,
    detect,
    detect_numbered,
    format_module,
    frame_like_line,
)
from nmtcheck.readers.frames import FrameBatch
from nmtcheck.readers.records import is_note_line
from nmtcheck.readers.source import (
    HEAD_BYTES,
    Prefixed,
    Source,
    Unnumbered,
    UpToDamage,
    decompressed,
    read_up_to,
    stream_errors,
)
from nmtcheck.readers.stats import InputStats


def printable_path(path: str) -> str:
    """The path as reports show it: bytes of a file name that are not UTF-8 (kept by Python
    as surrogates, which no report can write) become `\\xNN` escapes."""
    return path.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")


@dataclass
class OpenedInput:
    stats: InputStats
    batches: Generator[FrameBatch, None, None]  # close() it to close the file early
    # the line number of a last line without a newline in a plain text file (else None;
    # CUT_IF_DAMAGED: a compressed one's last line, if its stream turns out damaged):
    # where a recording killed mid-write, or a file copied while it was written, ends
    cut_line: int | None = None


def open_input(path: str, input_format: str | None = None, strict: bool = False,
               options: dict[str, Any] | None = None) -> OpenedInput:
    """Open, decompress and sniff one log; exit-2 errors name the file."""
    raw, display = _open_raw(path)
    try:
        head, stream, compression, damage = _decompressed_head(raw, display, strict)
    except OSError as exc:  # reading a path that opened: an I/O error of the device
        raw.close()
        raise InputError(display, f"cannot read: {exc.strerror or exc}") from None
    except BaseException:
        raw.close()
        raise
    if head.startswith(codecs.BOM_UTF8):  # a text file saved by a Windows editor
        head = head[len(codecs.BOM_UTF8) :]
    try:
        fmt, start, gutter = _format_of(head, input_format, display, compression, damage)
    except InputError:
        raw.close()
        raise
    reader = format_module(fmt).read
    stats = InputStats(path=display, format=fmt, strict=strict)
    content: io.RawIOBase = Prefixed(head, stream)
    if gutter is not None:  # line numbers pasted with the lines: each line without its own
        content = Unnumbered(content, gutter)
    buffered = io.BufferedReader(content, buffer_size=1 << 20)
    source = Source(display, buffered, stream_errors(compression), compression,
                    None if compression or path == "-" else path, options or {})
    cut = None
    if fmt in TEXT_FORMATS and path != "-":
        cut = (unterminated_line(raw) if not compression
               else CUT_IF_DAMAGED if compression != "utf-16" else None)
    return OpenedInput(stats, _batches(reader, raw, source, stats, start, damage), cut)


# What the unknown-format error says of a text whose line looks like a CAN frame that no
# format reads (a directory's `.txt` with such a line is a log: nmtcheck/cli/inputs.py)
FRAME_LIKE = "looks like a CAN frame"

# `OpenedInput.cut_line` of a compressed text log: where its stream is damaged (cut off
# while it was written or copied), its last line read is where it was cut
CUT_IF_DAMAGED = -1


def unterminated_line(raw: IO[bytes]) -> int | None:
    """The number of a plain file's last line when it has no newline, else None. Reads
    one byte, and counts the lines only then (a log cut while it was written is rare)."""
    try:
        where = raw.tell()
    except (OSError, ValueError):  # not seekable (a pipe, a device): nothing to tell
        return None
    try:
        size = raw.seek(0, os.SEEK_END)
        if not size:
            return None
        raw.seek(size - 1)
        if raw.read(1) == b"\n":
            return None
        raw.seek(0)
        return 1 + sum(piece.count(b"\n") for piece in iter(lambda: raw.read(1 << 20), b""))
    except (OSError, ValueError):
        return None
    finally:
        raw.seek(where)


def _open_raw(path: str) -> tuple[IO[bytes], str]:
    """The file (or standard input, `-`) as raw bytes, and its name for messages."""
    if path == "-":
        if sys.stdin is None:  # started without a standard input (fd 0 closed)
            raise InputError("<stdin>", "no standard input to read")
        return sys.stdin.buffer, "<stdin>"
    display = printable_path(path)
    if os.path.isdir(path):
        raise InputError(display, "is a directory, not a log file")
    kind = special_kind(path)
    if kind:  # opening a FIFO waits for a writer, reading a device may never end: a hang
        raise InputError(display, f"not a regular file ({kind}): give its content on "
                         "standard input (-) if it is a log")
    try:
        return open(path, "rb"), display  # closed when the batches are exhausted
    except FileNotFoundError:
        raise InputError(display, "no such file" if not os.path.islink(path)
                         else "a symbolic link to a file that does not exist") from None
    except OSError as exc:
        raise InputError(display, f"cannot open: {exc.strerror or exc}") from None


def special_kind(path: str) -> str:
    """What `path` is when it exists and is no regular file or directory ("a FIFO", "a
    socket", "a device"), else ""."""
    try:
        mode = os.stat(path).st_mode
    except OSError:  # missing, a broken link: opening it names why
        return ""
    if stat.S_ISREG(mode) or stat.S_ISDIR(mode):
        return ""
    return ("a FIFO" if stat.S_ISFIFO(mode) else "a socket" if stat.S_ISSOCK(mode)
            else "a device")


def _decompressed_head(raw: IO[bytes], display: str, strict: bool
                       ) -> tuple[bytes, IO[bytes], str, UpToDamage | None]:
    """The first HEAD_BYTES of the content, the decompressed stream they were read from, the
    compression's name ("" if none), and what remembers damage of a compressed stream."""
    magic = raw.read(6)
    try:
        stream, compression = decompressed(Prefixed(magic, raw), magic)  # type: ignore[arg-type]
    except ImportError:
        raise InputError(
            display, "zstd-compressed, but the 'zstandard' module is not installed"
        ) from None
    damage: UpToDamage | None = None
    if compression:
        damage = UpToDamage(stream, stream_errors(compression), display, strict)
        stream = io.BufferedReader(damage)
    return read_up_to(stream, HEAD_BYTES), stream, compression, damage


def _format_of(head: bytes, input_format: str | None, display: str, compression: str,
               damage: UpToDamage | None) -> tuple[str, int, re.Pattern[bytes] | None]:
    """The input's format (given, or detected from `head`), where in `head` the lines it
    reads start (past leading lines that are no record), and the line-number gutter to
    take off each line (`12: `, `cat -n`'s, an editor's) when the lines are numbered."""
    if not head:
        if damage is not None and damage.damage is not None:
            raise InputError(display, f"cannot decompress ({compression}): {damage.damage}")
        raise InputError(display, "empty file: no records to check")
    fmt: str | None = input_format
    start = 0  # bytes of leading lines that are no record, before the format's first line
    gutter: re.Pattern[bytes] | None = None
    found = detect(head)
    if fmt is None and found is not None:
        fmt, start = found
    elif found is None and (numbered := detect_numbered(head)) is not None and fmt in (
            None, numbered[0]):  # no format as it is: pasted with line numbers (`12: `)
        fmt, start, gutter = numbered
    if fmt is not None and fmt not in FORMAT_MODULES:
        raise InputError(display, f"unknown input format {fmt!r} (supported: {', '.join(FORMATS)})")
    if fmt is None:
        if damage is not None and damage.damage is not None:
            raise InputError(display, f"cannot decompress ({compression}) beyond its first "
                             f"{len(head)} bytes, too few to tell the format: {damage.damage}")
        raise InputError(display, "unknown log format (supported: " + ", ".join(FORMATS)
                         + "; use --input-format NAME)" + _frame_like_hint(head))
    return fmt, start, gutter


def _frame_like_hint(head: bytes) -> str:
    """What the unknown-format error adds for a text with a line that looks like a CAN
    frame: that line, quoted, and what the formats that write such lines expect."""
    found = frame_like_line(head)
    if found is None:
        return ""
    number, line, candump_like = found
    text = line.decode("utf-8", "replace")
    if len(text) > QUOTED_CHARS:
        text = text[:QUOTED_CHARS] + "…"
    expected = ("candump writes `(1700000000.000000) can0 702#05` (-L), `can0 702#05` or "
                "`702#05`" if candump_like else
                "e.g. candump `(1700000000.000000) can0 702#05`, candump screen output "
                "`can0  702   [1]  05`, Vector ASC `0.010000 1  702  Rx   d 1 05`")
    return f"; line {number} {FRAME_LIKE} but no format reads it: `{text}` ({expected})"


QUOTED_CHARS = 80  # of a line quoted in an error message


def _batches(reader: Callable[[Source, InputStats], Iterator[FrameBatch]], raw: IO[bytes],
             source: Source, stats: InputStats, start: int,
             damage: UpToDamage | None) -> Generator[FrameBatch, None, None]:
    """The reader's batches; `raw` is closed when they end (or the generator is closed)."""
    try:
        if start:  # leading lines that are no record: skipped records, in order
            leading = read_up_to(source.stream, start).split(b"\n")[:-1]
            for lineno, line in enumerate(leading, 1):
                if is_note_line(line):
                    stats.note()  # a comment or a shell prompt pasted above the log
                elif line.strip():
                    stats.skip(lineno, "a line before the first record "
                                       "(a note or a banner?)")
            source.first_line = len(leading) + 1
        yield from reader(source, stats)
        if damage is not None and damage.damage is not None:
            stats.truncated = True  # read up to the damage of the compressed stream
        if stats.truncated and stats.strict:
            raise InputError(source.path, "the input ends early (cut off or damaged); "
                             "without --strict it is read up to there")
    finally:
        raw.close()
