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
