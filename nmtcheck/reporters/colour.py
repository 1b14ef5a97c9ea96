"""Colour on a terminal for the text and concise reports (`check --color`).

`auto` (the default) colours when standard output is a terminal, `NO_COLOR` is not set
to a non-empty value (https://no-color.org) and `TERM` is not `dumb`; `always` and
`never` decide alone. Colour is added to the finished report, after every name from a
log had its control characters escaped, and only where the report's own structure is:
a finding's severity and the verdict word, never inside a message.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable, Iterator
from typing import IO

RESET = "\x1b[0m"
STYLES = {"error": "\x1b[31m", "warning": "\x1b[33m", "info": "\x1b[36m",
          "FAIL": "\x1b[1;31m", "PASS": "\x1b[1;32m", "NOT GATED": "\x1b[1;33m",
          "ORDER ONLY": "\x1b[1;33m"}  # a pass whose timing was not checked: not green

_SEVERITY = "error|warning|info"
# (a pass over a log without timestamps: `PASS (order only: timing not checked)`)
_VERDICT = r"PASS \(order only[^)]*\)|PASS|FAIL|NOT GATED"
_TIME = r"(?:-?[\d.]+ s|frame \d+)"  # `frame N` in a log without timestamps
PATTERNS = {
    # `    1.560400 s  line 77      error   H001 heartbeat-timeout: ...`
    "text": [re.compile(rf"^( +{_TIME}  (?:line|frame) \S+ +)({_SEVERITY})(?= )", re.M),
             re.compile(rf"^()({_VERDICT})(?=: )", re.M)],
    # `samples/x.log:77: 1.560400s H001 [error] ...`
    "concise": [re.compile(rf"^(.*?:\d*: (?:-?[\d.]+s|frame \d+) [A-Z]\d{{3}} \[)"
                           rf"({_SEVERITY})(?=\] )", re.M),
                re.compile(rf"^(nmtcheck )({_VERDICT})(?=: )", re.M)],
}


def wanted(choice: str, stream: IO[str] | None) -> bool:
    """Whether to colour: `--color always|never`, else (auto) a terminal without NO_COLOR."""
    if choice != "auto":
        return choice == "always"
    if os.environ.get("NO_COLOR") or os.environ.get("TERM") == "dumb":
        return False
    isatty = getattr(stream, "isatty", None)
    return bool(isatty and isatty())


def paint(text: str, fmt: str) -> str:
    """`text`, a report in `fmt`, with its severities and verdict coloured."""
    for pattern in PATTERNS.get(fmt, []):
        text = pattern.sub(lambda m: f"{m[1]}{_style(m[2])}{m[2]}{RESET}", text)
    return text


def _style(word: str) -> str:
    return STYLES["ORDER ONLY"] if word.startswith("PASS (") else STYLES[word]


def painted(chunks: Iterable[str], fmt: str) -> Iterator[str]:
    """The report's pieces coloured, line by line (a line is never split in two)."""
    if fmt not in PATTERNS:
        yield from chunks
        return
    held = ""
    for chunk in chunks:
        held += chunk
        cut = held.rfind("\n") + 1
        if cut:
            yield paint(held[:cut], fmt)
            held = held[cut:]
    if held:
        yield paint(held, fmt)
