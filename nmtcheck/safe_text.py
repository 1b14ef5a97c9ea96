"""Output that cannot act on whoever reads it: control characters shown, never sent.

A channel name (an MCAP topic, a JSON `channel` field, an interface name in a text
log), a file name or a message built from them may hold any character. Written raw
into a text-like report (text, concise, markdown, CSV cells, the live lines, error
messages) a newline followed by `::error file=…::…` becomes a GitHub workflow command
in a CI log (`::add-mask::`, `::stop-commands::` work too), an ESC sequence
rewrites the terminal, NUL and BEL upset whatever reads the file. `escape_controls`
writes every such character as `\\xNN` (`\\uNNNN` above U+00FF), the form `xml_safe`
and `printable_path` use, so the text stays one line and shows what the name holds.

`finite` is the same promise for numbers: no report or dataset holds a non-finite
number (`Infinity` is not JSON; strict parsers reject the whole document).
"""

from __future__ import annotations

import json
import math
import re
from typing import Any

# C0 controls (newline, CR, tab, ESC, BEL, NUL, ...), DEL, C1 controls (NEL U+0085 among
# them), the Unicode line and paragraph separators, and the bidirectional overrides that
# make a terminal or an editor show text in another order than it is
_CONTROL = re.compile("[\x00-\x1f\x7f-\x9f\u2028\u2029\u202a-\u202e\u2066-\u2069]")


def _escape(m: re.Match[str]) -> str:
    code = ord(m.group())
    return f"\\x{code:02x}" if code <= 0xFF else f"\\u{code:04x}"


def escape_matching(pattern: re.Pattern[str], text: str) -> str:
    """`text` with every match of `pattern` (single characters) written as `\\xNN`."""
    return pattern.sub(_escape, text)


def escape_controls(text: object) -> str:
    """`text` with every control character written as `\\xNN` (or `\\uNNNN`): one line
    that no terminal or CI runner acts on."""
    s = "" if text is None else str(text)
    if s.isascii() and s.isprintable():  # the usual text: one C call, nothing to do
        return s
    return escape_matching(_CONTROL, s)


# The longest error line: a value of a file quoted whole (a 10 MB string) is cut to this
ERROR_LINE_CHARS = 1000


def error_line(text: object) -> str:
    """An error message as the one line on stderr: control characters escaped, and at
    most ERROR_LINE_CHARS long, its middle cut out and counted."""
    s = escape_controls(text)
    if len(s) <= ERROR_LINE_CHARS:
        return s
    head, tail = ERROR_LINE_CHARS * 3 // 4, ERROR_LINE_CHARS // 5
    return f"{s[:head]} … ({len(s) - head - tail} characters left out) … {s[-tail:]}"


def escape_lines(lines: list[str]) -> str:
    """Report lines, each escaped, joined by newlines (a line's own newline, from a name,
    is shown as `\\x0a`, never starts a line)."""
    return "\n".join(escape_controls(line) for line in lines)


def finite(value: Any) -> Any:
    """`value` with every non-finite float (inf, -inf, nan) in it, at any depth of dicts,
    lists and tuples, as None."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [finite(v) for v in value]
    return value


def dumps_finite(value: Any, **kwargs: Any) -> str:
    """`json.dumps` that never writes `Infinity` or `NaN` (those become null): the fast
    C encoder, and the walk of `finite` only where a non-finite number is in the way."""
    try:
        return json.dumps(value, allow_nan=False, **kwargs)
    except ValueError:
        return json.dumps(finite(value), allow_nan=False, **kwargs)
