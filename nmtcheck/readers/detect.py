"""Which format a log is, from its content: each format module sniffs the first bytes
(binary magic first, then text), past a few leading lines a person may have added."""

from __future__ import annotations

import importlib
import re
from collections.abc import Iterator
from itertools import pairwise
from types import ModuleType

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


# Line-number gutters as people paste logs (SPEC §1): `grep -n` (`12:` a matching line,
# `12-` a context line), `cat -n` and `nl` (`    12<TAB>`), an editor's or a code view's
# (`12 | `, `12│`), `less -N` and vim's `:set number` (`  12 `). Tried in this order, only
# on a text no format takes as it is.
GUTTERS = (
    re.compile(rb"[ \t]*(\d{1,9})[:-][ \t]?"),
    re.compile(rb"[ \t]*(\d{1,9})\t"),
    re.compile(rb"[ \t]*(\d{1,9})[ \t]*(?:\||\xe2\x94\x82|\xc2\xa6)[ \t]?"),
    re.compile(rb"[ \t]*(\d{1,9}) +"),
)
GUTTER_LINES = 200  # lines of the head looked at for a gutter


def _gutters(head: bytes) -> Iterator[re.Pattern[bytes]]:
    """The gutter styles that number the head's lines: at least four in five of its first
    non-blank lines (two at least, unless it has one) start with one, numbers increasing."""
    lines = [line for line in head.split(b"\n")[:GUTTER_LINES] if line.strip()]
    for gutter in GUTTERS:
        numbers = [int(m[1]) for m in map(gutter.match, lines) if m is not None]
        if (len(numbers) >= min(2, len(lines)) and 5 * len(numbers) >= 4 * len(lines)
                and all(a < b for a, b in pairwise(numbers))):
            yield gutter


def line_gutter(gutter: re.Pattern[bytes]) -> re.Pattern[bytes]:
    """`gutter` at the start of every line of a text (for `re.sub`)."""
    return re.compile(rb"(?m)^" + gutter.pattern)


def detect_numbered(head: bytes) -> tuple[str, int, re.Pattern[bytes]] | None:
    """For a text no format takes as it is: the format of its lines without their line
    numbers (`detect`), where they start, and the gutter to take off each line; None when
    no gutter numbers its lines or the lines without it are no format either."""
    if not is_text(head):
        return None
    for gutter in _gutters(head):
        found = detect(line_gutter(gutter).sub(b"", head))
        if found is not None:
            return (*found, gutter)
    return None


# A token that looks like a CAN frame's ID and what follows it in some log: `702#05`,
# `702 [1] 05`, `0702 1 05`, `18FF0102 8 ...` — a hint for the unknown-format error
_FRAME_LIKE = re.compile(
    rb"(?<![0-9A-Za-z_.])([0-9A-Fa-f]{3,4}|[0-9A-Fa-f]{8})"
    rb"(?:(#)|[ \t]+\[\d{1,2}\]|h?[ \t]+[0-8](?:[ \t]+[0-9A-Fa-f]{2}(?![0-9A-Za-z]))+)")
FRAME_LIKE_LINES = 200  # lines of the head looked at for one that looks like a frame


def frame_like_line(head: bytes) -> tuple[int, bytes, bool] | None:
    """The first of the head's lines (1-based number, text with its white space runs as
    single spaces) that looks like a CAN frame, and whether it is written `ID#DATA` as
    candump writes frames; None if none does or the head is no text."""
    if not is_text(head):
        return None
    for number, line in enumerate(head.split(b"\n")[:FRAME_LIKE_LINES], 1):
        m = _FRAME_LIKE.search(line)
        if m is not None:  # the piece of a line of CR-only line ends that holds it
            begin = line.rfind(b"\r", 0, m.start()) + 1
            end = line.find(b"\r", m.end())
            piece = line[begin:end if end >= 0 else len(line)]
            return number, b" ".join(piece.split()), m[2] is not None
    return None
