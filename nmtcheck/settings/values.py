"""What every settings file (network, profile, configuration) shares: its TOML read with
any nesting refused in one line, numbers that are finite times and factors, and values
quoted short in an error (a 10 MB value is named, not echoed)."""

from __future__ import annotations

import sys
from typing import Any

from nmtcheck.errors import UsageError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

# The largest number a setting takes: its times are milliseconds (CiA 301's are 16-bit),
# its factors and counts small; 1e9 ms is 11.6 days. Above it a value is a typo or an
# attack (1e308 x 1.5 is inf), never a network's timing.
MAX_NUMBER = 1e9

# How much of a value an error quotes
QUOTED_CHARS = 40


def quoted(value: Any, limit: int = QUOTED_CHARS) -> str:
    """`repr(value)`, cut after `limit` characters with the length it has in all."""
    if isinstance(value, int) and not isinstance(value, bool) and value.bit_length() > 128:
        return f"an integer of {len(format(value, 'x'))} hex digits"  # repr may refuse
    text = repr(value)
    if len(text) <= limit:
        return text
    return f"{text[:limit]}… ({len(text)} characters)"


def shortened(text: str, limit: int = QUOTED_CHARS) -> str:
    """A name from a settings file (a key, a profile name), cut after `limit` characters
    with the length it has in all."""
    return text if len(text) <= limit else f"{text[:limit]}… ({len(text)} characters)"


def loads(text: str) -> dict[str, Any]:
    """tomllib.loads; a document nested deeper than Python's recursion (arrays or inline
    tables thousands of levels deep) is a TOMLDecodeError as any other invalid TOML, and
    so is an integer too long to convert (Python's 4300-digit limit)."""
    try:
        doc: dict[str, Any] = tomllib.loads(text)
    except RecursionError:
        raise tomllib.TOMLDecodeError("arrays or inline tables nested too deeply") from None
    except ValueError as exc:
        if isinstance(exc, tomllib.TOMLDecodeError):
            raise
        raise tomllib.TOMLDecodeError(f"a value too large to read ({exc})") from None
    return doc


def number(where: str, value: int | float, integer: bool = False) -> int | float:
    """A setting's number: finite, 0 .. MAX_NUMBER (times, factors, counts); errors name
    `where` and quote the value short."""
    kind = "a whole number" if integer else "a number"
    if value < 0:  # (nan is not, and is refused below)
        raise UsageError(f"{where}: expected {kind} >= 0, got {quoted(value)}")
    if not value <= MAX_NUMBER:  # inf, nan, 1e308
        raise UsageError(f"{where}: expected {kind} >= 0 that is finite and at most "
                         f"{MAX_NUMBER:.0e}, got {quoted(value)}")
    return value
