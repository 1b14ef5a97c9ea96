"""Errors that end a run with exit code 2 and one line on stderr."""

from __future__ import annotations


class NmtcheckError(Exception):
    """A usage or input problem: reported as one line, exit code 2, never a traceback."""


class InputError(NmtcheckError):
    """An input that cannot be read; names the file and, where known, the line."""

    def __init__(self, path: str, message: str, line: int | None = None) -> None:
        self.path = path
        self.line = line
        self.message = message
        where = f"{path}:{line}" if line else path
        super().__init__(f"{where}: {message}")


class UsageError(NmtcheckError):
    """A bad option, profile or network file; names the file and key where there is one."""


# The Python API's arguments (api.check, live.Monitor): a wrong type or value is a
# TypeError or ValueError naming the argument, as pandas raises them, never a string read
# character by character or a file object taken for a name.

def _kind(value: object) -> str:
    return type(value).__name__


def string_list(name: str, value: object) -> list[str]:
    """An argument that takes several strings (`select`, `ignore`, `topics`): a list or
    tuple of them. A lone string is refused: it would be taken character by character."""
    if isinstance(value, str | bytes):
        raise TypeError(f"{name}: expected a list of strings, got the {_kind(value)} "
                        f"{value[:40]!r}: write [{value[:40]!r}]")
    if not isinstance(value, list | tuple | set | frozenset):
        raise TypeError(f"{name}: expected a list of strings, got {_kind(value)}")
    bad = [v for v in value if not isinstance(v, str)]
    if bad:
        raise TypeError(f"{name}: expected a list of strings, it holds a {_kind(bad[0])}")
    return list(value)


def whole_number(name: str, value: object, minimum: int, meaning: str = "") -> int:
    """An integer argument >= `minimum` (`jobs`, `max_findings`); bool is no number."""
    if not isinstance(value, int) or isinstance(value, bool):
        raise TypeError(f"{name}: expected an int, got {_kind(value)} {value!r:.40}")
    if value < minimum:
        raise ValueError(f"{name}: expected an int >= {minimum}{meaning}, got {value}")
    return value


def optional_text(name: str, value: object, paths: bool = False) -> None:
    """An argument that is a string (or, with `paths`, an os.PathLike too) or None."""
    import os

    if value is None or isinstance(value, str) or (paths and isinstance(value, os.PathLike)):
        return
    want = "a path (str or os.PathLike)" if paths else "a str"
    raise TypeError(f"{name}: expected {want} or None, got {_kind(value)}")
