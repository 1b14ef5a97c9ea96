"""One module per output format behind one function: `render(results, options) -> str`."""

from __future__ import annotations

import gc
import importlib
import os
from collections.abc import Callable, Iterable, Iterator
from typing import TypeVar, cast

from nmtcheck.errors import UsageError
from nmtcheck.results import InputResult

_T = TypeVar("_T")
Renderer = Callable[[list[InputResult], dict[str, object]], str]
Streamer = Callable[[list[InputResult], dict[str, object]], Iterable[str]]
# format name -> module in this package (imported only when the format is used)
MODULES = {"text": "text", "concise": "concise", "json": "json", "csv": "csv", "html": "html",
           "junit": "junit", "sarif": "sarif", "github": "github", "markdown": "markdown"}
FORMATS = (*MODULES, "auto")
PLANNED: tuple[str, ...] = ()
# Longest first where one suffix ends another (".sarif.json" before ".json").
SUFFIXES = {".txt": "text", ".sarif.json": "sarif", ".json": "json", ".csv": "csv",
            ".html": "html", ".htm": "html", ".xml": "junit", ".sarif": "sarif",
            ".md": "markdown", ".markdown": "markdown"}


def auto_format(environ: dict[str, str] | None = None) -> str:
    """`--format auto`: GitHub annotations when running under GitHub Actions, else text."""
    env = os.environ if environ is None else environ
    return "github" if env.get("GITHUB_ACTIONS") == "true" else "text"


def renderer(name: str) -> Renderer:
    if name == "auto":
        name = auto_format()
    module = MODULES.get(name)
    if module is None:
        raise UsageError(f"--format {name}: unknown format (available: {', '.join(FORMATS)})")
    return cast(Renderer, importlib.import_module(f"nmtcheck.reporters.{module}").render)


def streamer(name: str) -> Streamer:
    """The report in pieces to write one after the other, for the formats that can hold
    more than fits in memory at once (a module's `stream`); the others in one piece."""
    render = renderer(name)
    module = importlib.import_module(render.__module__)
    stream = getattr(module, "stream", None)
    if stream is not None:
        return lambda results, options: _paused_stream(cast(Streamer, stream)(results, options))
    return lambda results, options: [_paused(lambda: render(results, options))]


def _paused(make: Callable[[], _T]) -> _T:
    """`make()` with the cyclic garbage collector paused: a report of tens of thousands
    of nodes makes rows of short-lived objects, none in a cycle, and the collector's
    passes over the long-lived model in between free nothing (a sixth of the text
    report's time at 40,000 channels)."""
    was = gc.isenabled()
    gc.disable()
    try:
        return make()
    finally:
        if was:
            gc.enable()


def _paused_stream(pieces: Iterable[str]) -> Iterator[str]:
    """Each piece made as in `_paused`; the collector runs while one is written."""
    it = iter(pieces)
    while (piece := _paused(lambda: next(it, None))) is not None:
        yield piece


def statistics_renderer(name: str) -> Renderer:
    """`--statistics`: one line per rule with its count (JSON for `--format json`)."""
    from nmtcheck.reporters import statistics

    return statistics.render_json if name == "json" else statistics.render


def format_for_path(path: str) -> str:
    for suffix, name in SUFFIXES.items():
        if path.lower().endswith(suffix):
            return name
    raise UsageError(f"--output {path}: cannot tell the format from the suffix "
                     f"(use one of {', '.join(SUFFIXES)})")
