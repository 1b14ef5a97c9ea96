"""What a rule is: a code, a name, a default severity, typed parameters and a check.

A check is a generator over one input's model that yields `Problem`s. It never
knows its own severity or whether it is enabled: the engine stamps code, name,
severity and location on each problem (as yamllint does).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from nmtcheck.timeline import InputModel

SEVERITIES = ("error", "warning", "info")


@dataclass(frozen=True)
class Param:
    """A rule parameter: its TOML name, Python type and meaning."""

    name: str
    type: type
    doc: str


@dataclass
class Problem:
    """One finding as a check sees it: where and what, not how loud."""

    channel: str | None  # None: the input itself (I-rules)
    node: int | None
    time: float
    message: str
    frame_index: int | None = None  # None: a moment; the engine finds the first frame at/after it
    line: int | None = None


Check = Callable[[InputModel, dict[str, Any]], Iterator[Problem]]


@dataclass(frozen=True)
class Rule:
    code: str
    name: str
    severity: str
    params: tuple[Param, ...]
    check: Check
    exempt_from_unknown: bool = False

    @property
    def doc(self) -> str:
        return inspect.cleandoc(self.check.__doc__ or "")

    @property
    def summary(self) -> str:
        return self.doc.splitlines()[0] if self.doc else ""


def rule(code: str, name: str, severity: str, *params: Param,
         exempt_from_unknown: bool = False) -> Callable[[Check], Rule]:
    """Declare a rule; the decorated function's docstring is its documentation."""

    def wrap(check: Check) -> Rule:
        return Rule(code, name, severity, params, check, exempt_from_unknown)

    return wrap


def runs(items: list[Any], same_run: Callable[[Any, Any], bool]) -> Iterator[list[Any]]:
    """Split a sequence into runs of neighbours that `same_run` joins."""
    run: list[Any] = []
    for item in items:
        if run and not same_run(run[-1], item):
            yield run
            run = []
        run.append(item)
    if run:
        yield run


def run_starts(join: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised `runs`: `join[i]` says item i continues the run of item i-1 (`join[0]` is
    ignored). Returns the index of each run's first item and the run's length."""
    n = len(join)
    if not n:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    first = np.flatnonzero(np.concatenate([[True], ~np.asarray(join, bool)[1:]]))
    return first, np.diff(np.append(first, n))


def count_note(n: int, what: str = "frames") -> str:
    return f" ({n} {what})" if n > 1 else ""
