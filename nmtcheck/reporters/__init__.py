"""One module per output format behind one function: `render(results) -> str`."""

from __future__ import annotations

from collections.abc import Callable

from nmtcheck.engine import InputResult
from nmtcheck.errors import UsageError

Renderer = Callable[[list[InputResult], dict[str, object]], str]
FORMATS = ("text", "json", "csv")
PLANNED = ("html", "junit", "sarif", "github", "markdown")
SUFFIXES = {".txt": "text", ".json": "json", ".csv": "csv", ".html": "html", ".htm": "html",
            ".xml": "junit", ".sarif": "sarif", ".md": "markdown"}


def renderer(name: str) -> Renderer:
    if name in PLANNED:
        raise UsageError(f"--format {name}: not available in this version yet "
                         f"(available: {', '.join(FORMATS)})")
    if name == "text":
        from nmtcheck.reporters import text

        return text.render
    if name == "json":
        from nmtcheck.reporters import json as json_reporter

        return json_reporter.render
    if name == "csv":
        from nmtcheck.reporters import csv as csv_reporter

        return csv_reporter.render
    raise UsageError(f"--format {name}: unknown format (available: {', '.join(FORMATS)})")


def format_for_path(path: str) -> str:
    for suffix, name in SUFFIXES.items():
        if path.lower().endswith(suffix):
            return name
    raise UsageError(f"--output {path}: cannot tell the format from the suffix "
                     f"(use one of {', '.join(SUFFIXES)})")
