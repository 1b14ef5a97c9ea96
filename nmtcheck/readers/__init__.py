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
import re
import sys
import zlib
from collections.abc import Callable, Generator, Iterable, Iterator
from dataclasses import dataclass, field
from types import ModuleType
from typing import IO, Any, NamedTuple, cast

import numpy as np

from nmtcheck.errors import InputError
from nmtcheck.readers.frames import BatchBuilder, FrameBatch

MAX_SKIPPED_LINES_KEPT = 10
HEAD_BYTES = 65536
# No format has records anywhere near this long; a longer "line" (a binary file read as
# text, a log whose newlines were lost) is one unparseable record, never held in memory whole.
MAX_LINE_BYTES = 1 << 20
# What `Source.lines()` yields in place of an overlong line: one token that no reader parses
# (and no format takes for a comment or a header), so it counts as one skipped record.
OVERLONG_LINE = b"<line-longer-than-1-MiB>\n"


MAX_DROPS = 10000  # drop records placed (InputStats.drops); all of them are counted


class Drop(NamedTuple):
    """One drop record of the logger (`InputStats.drop`); `line` 0: a binary format's."""

    line: int
    lost: int  # frames lost (`count` is a tuple's method)
    frame: int | None = None  # the first frame after the loss; None: after `line`
    ts: float | None = None  # when the logger reported it; None: that frame's time


@dataclass
class InputStats:
    """What a reader saw in one input; every record is accounted for here."""

    path: str
    format: str = ""
    frames: int = 0
    skipped: int = 0  # records that could not be parsed
    skipped_lines: list[int] = field(default_factory=list)
    skip_reason: str = ""  # why the first skipped record could not be parsed
    ignored: int = 0  # well-formed records that are not bus frames (status, statistics, TxRq…)
    notes: int = 0  # of `ignored`: lines that are only a note or a comment (`# …`, a prompt)
    extended: int = 0
    error_frames: int = 0
    remote_frames: int = 0
    fd_frames: int = 0
    dropped: int = 0  # frames the logger says it lost (DROPCOUNT, BLF data lost, CLX000 Lost)
    # the first MAX_DROPS drop records: where a loss sits (SPEC §8.6)
    drops: list[Drop] = field(default_factory=list)
    backwards_timestamps: int = 0
    first_backwards: tuple[int, int, float] | None = None  # frame index, line, time
    truncated: bool = False  # the input ends early (cut off, or a damaged compressed stream)
    start: float | None = None
    end: float | None = None
    channels: list[str] = field(default_factory=list)
    # False when the input has no timestamps written (candump screen output without `-t`,
    # bare `ID#DATA` lines): every frame is at 0 s and only their order counts (SPEC §1)
    timestamped: bool = True
    # the frame index stands for the time: no usable timestamps (set by the engine, SPEC §1)
    order_only: bool = False
    strict: bool = False
    # where a later capture begins in the input (nmtcheck/readers/captures.py): frame index, line,
    # time; and each of its channels' name in the log
    restarts: list[tuple[int, int, float]] = field(default_factory=list)
    capture_channels: dict[str, str] = field(default_factory=dict)
    # where the logger's clock stepped back within a recording: frame index, line, and
    # the seconds the frames after it are timed later than their stamps (captures.py)
    clock_steps: list[tuple[int, int, float]] = field(default_factory=list)
    # the lines of notes that frames were left out (`[snip]`, `...`), in file order; and
    # those of them after which a capture begins, with its first frame's line (captures.py)
    left_out: list[int] = field(default_factory=list)
    left_out_restarts: list[tuple[int, int]] = field(default_factory=list)
    _chan_codes: dict[str, int] = field(default_factory=dict, repr=False)

    def channel_code(self, name: str) -> int:
        code = self._chan_codes.get(name)
        if code is None:
            code = len(self.channels)
            self._chan_codes[name] = code
            self.channels.append(name)
        return code

    def capture_channel(self, name: str, number: int) -> int:
        """The code of channel `name` (as logged) in the input's capture `number` (> 1):
        `can0 (capture 2)`, a channel of its own (nmtcheck/readers/captures.py)."""
        own = f"{name} (capture {number})"
        self.capture_channels[own] = name
        return self.channel_code(own)

    def log_channel(self, name: str) -> str:
        """A channel's name in the log (that of a later capture's channel without it)."""
        return self.capture_channels.get(name, name)

    def drop(self, line: int, count: int, frame: int | None = None,
             ts: float | None = None) -> None:
        """A logger's drop record: counted, and placed for the `frames_lost` cause of the
        findings around it. A text record (`DROPCOUNT`) gives only its `line`: the cause
        places it at the first frame after that line. A reader that knows more gives the
        index of the first frame after the loss (`frame`) and the moment the logger
        reported it (`ts`; None: that frame's time)."""
        self.dropped += count
        if len(self.drops) < MAX_DROPS:
            self.drops.append(Drop(line, count, frame, ts))

    @property
    def drop_record(self) -> str:
        """What this format calls its records of lost frames (reports name them)."""
        return {"blf": "BLF data-lost", "cl2000": "CL2000 Lost"}.get(self.format, "DROPCOUNT")

    def skip(self, line: int, why: str) -> None:
        """Count an unparseable record; fatal under --strict."""
        if self.strict:
            raise InputError(self.path, f"cannot parse {self.format} record: {why}", line)
        if not self.skipped:
            self.skip_reason = why
        self.skipped += 1
        if len(self.skipped_lines) < MAX_SKIPPED_LINES_KEPT:
            self.skipped_lines.append(line)

    def note(self, count: int = 1, raw: bytes | None = None, line: int = 0) -> None:
        """Count lines that are only a note or a comment: non-frame records, not skips. A
        note `raw` at `line` that frames were left out there is kept (`left_out`)."""
        self.ignored += count
        self.notes += count
        if (raw is not None and line and len(self.left_out) < MAX_LEFT_OUT
                and is_left_out_line(raw)):
            self.left_out.append(line)


_DECIMAL_DIGITS = b"0123456789"
_HEX_DIGITS = b"0123456789abcdefABCDEF"


# Notes that say frames were left out here (`...`, `[...]`, `[snip]`, `--- cut ---`): what
# follows is no continuation of what came before (nmtcheck/readers/captures.py)
_LEFT_OUT_NOTES = (
    rb"[\[(<{]?\s*(?:(?:\.\s*){2,}|(?:\xe2\x80\xa6\s*)+)[\])>}]?$"  # `...`, `[...]`, `…`
    rb"|[\[(<{-]*\s*(?:\.{2,}|\xe2\x80\xa6)?\s*(?:snip(?:ped)?|cut|omitted|truncated)\b"
    rb"[^\w]*(?:\.{2,}|\xe2\x80\xa6)?[\])>}-]*$")  # [snip], --- cut ---, ... snipped ...
_LEFT_OUT = re.compile(rb"(?:" + _LEFT_OUT_NOTES + rb")", re.IGNORECASE)
MAX_LEFT_OUT = 10000  # notes of frames left out kept per input (the rest only counted)


# Lines that are only a note or a comment, as people paste logs (SPEC §1, "Logs as people
# paste them"): non-frame records, never skipped records. Matched against the line without
# its leading and trailing white space. No log format's record starts like one of these.
_NOTE_LINE = re.compile(
    rb"(?:"
    rb"\#|//"  # a comment (also a root shell's prompt: `# candump can0`)
    rb"|\$(?:\s|$)"  # a shell prompt: `$ candump can0`
    rb"|(?:\([^()\s]*\)\s*)?[\w.-]+@[\w.-]+(?::\S*)?\s*[$#%>](?:\s|$)"  # user@host:~$ cmd
    rb"|\[[^\]]*@[^\]]*\]\s*[$#%](?:\s|$)"  # [user@host dir]$ cmd
    rb"|PS [A-Za-z]:\\[^>]*>"  # PowerShell: PS C:\> cmd
    rb"|[A-Za-z]:\\[^>]*>"  # cmd.exe: C:\Users\me> type run.log
    rb"|```|~~~"  # a markdown code fence
    rb"|\^C$"  # the terminal's echo of the Ctrl-C that ended `candump`
    rb"|" + _LEFT_OUT_NOTES +
    rb")", re.IGNORECASE)


def is_left_out_line(line: bytes) -> bool:
    """A note that frames were left out here: `...`, `[...]`, `…`, `[snip]`, `--- cut ---`."""
    return _LEFT_OUT.match(line.strip()) is not None


def is_note_line(line: bytes) -> bool:
    """A line that is only a note or a comment: `# …`, `// …`, a shell prompt (`$ candump
    can0`, `user@host:~$ candump -L can0`), `...`, `[snip]`, a markdown code fence, `^C`.
    Leading white space (tabs included) is no part of it."""
    return _NOTE_LINE.match(line.strip()) is not None


_TOKEN = re.compile(rb"\S+")  # what bytes.split() returns, with its place in the line
NOTE_MARKS = b"#/<>-([;=*"  # how a note may start right after a record (`701#05 # boot-up`)


def note_follows(text: bytes, k: int) -> bool:
    """Whether the text after the first k white-space separated tokens of `text` (text
    there is) is a note (SPEC §1): `701#05   # boot-up`, `... [1]  00  <-- here`.

    A note is set apart from the record by two or more spaces or a tab, or starts with one
    of NOTE_MARKS. Text that starts like more data does not count: a token of hex digits
    with a decimal digit in it (`05`, `3344`) or of two hex digits (`FF`) means a damaged
    record (data cut by a space, a wrong length). Neither does one word one space after
    the record (`181#0102 X`): a damaged field, not a note."""
    tokens = _TOKEN.finditer(text)
    end = 0
    for _ in range(k):
        end = next(tokens).end()
    first = next(tokens)
    gap = text[end:first.start()]
    word = first[0]
    if not (len(gap) >= 2 or b"\t" in gap or word[:1] in NOTE_MARKS):
        return False
    if word.translate(None, _HEX_DIGITS):
        return True  # not hex digits only
    return len(word) != 2 and word.translate(None, _DECIMAL_DIGITS) == word


MAX_NUMBER_DIGITS = 40  # no field of any log format is longer; int() of 5000 digits is an error
# A frame's time in seconds is below this (the year 33658 as an epoch time; 31,700 years
# of uptime): no recorder writes more, and a larger stamp (`1e308`) would make periods and
# gaps overflow to infinity. candump's vectorised path reads at most 12 integer digits.
MAX_TIMESTAMP_S = 1e12


def plausible_time(ts: float, negative: bool = False) -> bool:
    """A frame time a report can hold: finite, below MAX_TIMESTAMP_S in magnitude, and
    (unless `negative`: a format whose times are offsets that may precede its start)
    not below zero. A stamp that is not is a skipped record (SPEC §1)."""
    if negative:
        return -MAX_TIMESTAMP_S < ts < MAX_TIMESTAMP_S  # False for nan
    return 0.0 <= ts < MAX_TIMESTAMP_S


def unsigned(tok: bytes, base: int = 10) -> int | None:
    """The value of a field of plain digits, else None. Python's int() also takes `-5`, `+5`,
    `1_0` and surrounding spaces, which in a log field mean damage, not a number (a negative
    CAN-ID would not even fit the frame columns)."""
    if not tok or len(tok) > MAX_NUMBER_DIGITS or tok.translate(
            None, _HEX_DIGITS if base == 16 else _DECIMAL_DIGITS):
        return None
    return int(tok, base)


def account(stats: InputStats, batch: FrameBatch | None) -> FrameBatch | None:
    """Count a finished batch into the input's stats (vectorised, once per batch)."""
    if batch is None or len(batch) == 0:
        return None
    ts = batch.ts
    # each frame against the one before it (the previous batch's last for the first)
    prev = np.concatenate([[stats.end if stats.end is not None else ts[0]], ts[:-1]])
    backwards = np.flatnonzero(ts < prev)
    back = len(backwards)
    if back and stats.first_backwards is None:
        k = int(backwards[0])
        stats.first_backwards = (int(batch.index[k]), int(batch.line[k]), float(ts[k]))
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


class Row(NamedTuple):
    """One frame parsed by a line reader's per-line parser (the slow path: one per line)."""

    ts: float
    channel: str  # the channel's name as the log writes it
    can_id: int
    ext: bool
    rtr: bool
    err: bool
    fd: bool
    dlc: int
    data: bytes


def batches_of(stats: InputStats, rows: Iterable[tuple[int, Row]]) -> Iterator[FrameBatch]:
    """What every line-oriented reader does with its (line number, row) pairs: code the
    channel names, collect the frames, and hand out accounted batches as they fill."""
    builder = BatchBuilder()
    for line, (ts, channel, can_id, ext, rtr, err, fd, dlc, data) in rows:
        builder.add(ts, stats.channel_code(channel), can_id, ext=ext, rtr=rtr, err=err, fd=fd,
                    dlc=dlc, data=data, line=line)
        if builder.full and (batch := account(stats, builder.take())) is not None:
            yield batch
    if (batch := account(stats, builder.take())) is not None:
        yield batch


# Format name -> module, in the order sniffing tries them (binary magic bytes first, then
# text). A format module has `sniff(head: bytes) -> bool` (light, no heavy imports) and
# `read(source: Source, stats: InputStats) -> Iterator[FrameBatch]`, a text format maybe
# `sniff_loose(head: bytes) -> bool` too (tried after every `sniff`). Adding a format = a
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
# The formats that are lines of text: detection looks past leading lines for these only.
TEXT_FORMATS = ("candump", "asc", "trc", "candump-screen", "csv", "cl2000")
# Text detection looks past at most this many leading lines (within the first HEAD_BYTES)
# that no format takes for its start: a note or comment added by hand, a banner. They are
# skipped records (with their line numbers), not an unknown format (SPEC section 1).
MAX_LEADING_LINES = 64


def format_module(name: str) -> ModuleType:
    return importlib.import_module(FORMAT_MODULES[name])


def is_text(head: bytes) -> bool:
    """Text formats never contain NUL bytes."""
    return b"\x00" not in head[:4096]


def detect_format(head: bytes) -> str | None:
    """Name the format of a log from its first bytes (after decompression).

    Every format's `sniff` first; then, for the text formats that have one, `sniff_loose`:
    lines as people paste them that no recorder writes in a file, such as candump's
    `ID#DATA` without `(timestamp) interface` (SPEC §1). They never win over a format that
    recognises the lines as its own."""
    for name in FORMAT_MODULES:
        if format_module(name).sniff(head):
            return name
    return _sniff_loose(head)


def _sniff_loose(head: bytes) -> str | None:
    for name in TEXT_FORMATS:
        loose = getattr(format_module(name), "sniff_loose", None)
        if loose is not None and loose(head):
            return name
    return None


def _past_leading_lines(head: bytes) -> Iterator[int]:
    """Offsets in `head` just past each of its first MAX_LEADING_LINES lines (LF-ended, as
    the readers split them) that is not blank: where a text log may start after them."""
    pos = 0
    for _ in range(MAX_LEADING_LINES):
        end = head.find(b"\n", pos)
        if end < 0:
            return
        blank = not head[pos:end].strip()  # sniffers pass over blank lines themselves
        pos = end + 1
        if not blank:
            yield pos


def detect(head: bytes) -> tuple[str, int] | None:
    """The format of a log from its first bytes, and the offset in `head` where the lines
    that format reads start: 0, or, for a text format, past up to MAX_LEADING_LINES leading
    lines that no format takes for its start (a hand-written note, a banner)."""
    fmt = detect_format(head)
    if fmt is not None:
        return fmt, 0
    if not is_text(head):
        return None
    for start in _past_leading_lines(head):
        rest = head[start:]
        if not rest.strip():
            return None
        for name in TEXT_FORMATS:
            if format_module(name).sniff(rest):
                return name, start
        if (loose := _sniff_loose(rest)) is not None:
            return loose, start
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
        readinto = getattr(self._rest, "readinto", None)
        if readinto is not None:  # straight into the caller's buffer: no copy of a block
            return readinto(b) or 0
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


class _UpToDamage(io.RawIOBase):
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
        head = _read_up_to(source.stream, size)
    except source.errors as exc:
        raise InputError(source.path, f"read error (truncated or corrupt file?): {exc}") from None
    source.stream = io.BufferedReader(_Prefixed(head, source.stream), buffer_size=HEAD_BYTES)
    return head


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
        fmt, start = _format_of(head, input_format, display, compression, damage)
    except InputError:
        raw.close()
        raise
    reader = format_module(fmt).read
    stats = InputStats(path=display, format=fmt, strict=strict)
    buffered = io.BufferedReader(_Prefixed(head, stream), buffer_size=1 << 20)
    source = Source(display, buffered, _stream_errors(compression), compression,
                    None if compression or path == "-" else path, options or {})
    cut = None
    if fmt in TEXT_FORMATS and path != "-":
        cut = (unterminated_line(raw) if not compression
               else CUT_IF_DAMAGED if compression != "utf-16" else None)
    return OpenedInput(stats, _batches(reader, raw, source, stats, start, damage), cut)


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
    try:
        return open(path, "rb"), display  # closed when the batches are exhausted
    except FileNotFoundError:
        raise InputError(display, "no such file" if not os.path.islink(path)
                         else "a symbolic link to a file that does not exist") from None
    except OSError as exc:
        raise InputError(display, f"cannot open: {exc.strerror or exc}") from None


def _decompressed_head(raw: IO[bytes], display: str, strict: bool
                       ) -> tuple[bytes, IO[bytes], str, _UpToDamage | None]:
    """The first HEAD_BYTES of the content, the decompressed stream they were read from, the
    compression's name ("" if none), and what remembers damage of a compressed stream."""
    magic = raw.read(6)
    try:
        stream, compression = _decompressed(_Prefixed(magic, raw), magic)  # type: ignore[arg-type]
    except ImportError:
        raise InputError(
            display, "zstd-compressed, but the 'zstandard' module is not installed"
        ) from None
    damage: _UpToDamage | None = None
    if compression:
        damage = _UpToDamage(stream, _stream_errors(compression), display, strict)
        stream = io.BufferedReader(damage)
    return _read_up_to(stream, HEAD_BYTES), stream, compression, damage


def _format_of(head: bytes, input_format: str | None, display: str, compression: str,
               damage: _UpToDamage | None) -> tuple[str, int]:
    """The input's format (given, or detected from `head`) and where in `head` the lines it
    reads start (past leading lines that are no record)."""
    if not head:
        if damage is not None and damage.damage is not None:
            raise InputError(display, f"cannot decompress ({compression}): {damage.damage}")
        raise InputError(display, "empty file: no records to check")
    fmt: str | None = input_format
    start = 0  # bytes of leading lines that are no record, before the format's first line
    if fmt is None and (found := detect(head)) is not None:
        fmt, start = found
    if fmt is not None and fmt not in FORMAT_MODULES:
        raise InputError(display, f"unknown input format {fmt!r} (supported: {', '.join(FORMATS)})")
    if fmt is None:
        if damage is not None and damage.damage is not None:
            raise InputError(display, f"cannot decompress ({compression}) beyond its first "
                             f"{len(head)} bytes, too few to tell the format: {damage.damage}")
        raise InputError(
            display,
            "unknown log format (supported: " + ", ".join(FORMATS) + "; use --input-format NAME)",
        )
    return fmt, start


def _batches(reader: Callable[[Source, InputStats], Iterator[FrameBatch]], raw: IO[bytes],
             source: Source, stats: InputStats, start: int,
             damage: _UpToDamage | None) -> Generator[FrameBatch, None, None]:
    """The reader's batches; `raw` is closed when they end (or the generator is closed)."""
    try:
        if start:  # leading lines that are no record: skipped records, in order
            leading = _read_up_to(source.stream, start).split(b"\n")[:-1]
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
