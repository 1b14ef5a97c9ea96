"""Which format a log is, from its content: each format module sniffs the first bytes
(binary magic first, then text), past a few leading lines a person may have added."""

from __future__ import annotations

import importlib
from collections.abc import Iterator
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
