"""Reading a log: bytes in, columnar frame batches out (`frames.FrameBatch`).

`open_input(path)` opens one input (opening.py): its compression and text encoding
(source.py), its format detected by content (detect.py), and the format's reader, one
module per format, which yields batches and keeps `InputStats` (stats.py) up to date.
`captures.py` finds several recordings joined in one file. Every reader is a generator
`read(source, stats)`; adding a format is a module and a line in `detect.FORMAT_MODULES`.
"""

from __future__ import annotations

from nmtcheck.readers.detect import (
    FORMAT_MODULES,
    FORMATS,
    MAX_LEADING_LINES,
    TEXT_FORMATS,
    detect_format,
    format_module,
    is_text,
)
from nmtcheck.readers.opening import CUT_IF_DAMAGED, OpenedInput, open_input, printable_path
from nmtcheck.readers.records import (
    MAX_TIMESTAMP_S,
    is_note_line,
    note_follows,
    plausible_time,
    unsigned,
)
from nmtcheck.readers.source import (
    MAX_LINE_BYTES,
    OVERLONG_LINE,
    READ_PIECE,
    Source,
    peek,
    split_lines,
)
from nmtcheck.readers.stats import Drop, InputStats, Row, account, batches_of

__all__ = [
    "CUT_IF_DAMAGED", "FORMATS", "FORMAT_MODULES", "MAX_LEADING_LINES", "MAX_LINE_BYTES",
    "MAX_TIMESTAMP_S", "OVERLONG_LINE", "READ_PIECE", "TEXT_FORMATS", "Drop", "InputStats",
    "OpenedInput", "Row", "Source", "account", "batches_of", "detect_format", "format_module",
    "is_note_line", "is_text", "note_follows", "open_input", "peek", "plausible_time",
    "printable_path", "split_lines", "unsigned",
]
