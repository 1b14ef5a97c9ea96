"""Helpers for the text readers: numbers and times as logs write them, and the lines
that are only a note or a comment as people paste logs (SPEC §1): non-frame records,
never skipped records."""

from __future__ import annotations

import re

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
