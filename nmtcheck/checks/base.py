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

from nmtcheck.model import InputModel

SEVERITIES = ("error", "warning", "info")  # the one order: most severe first


def is_failing_severity(severity: str, threshold: str) -> bool:
    """True when a finding of `severity` makes the run fail under `--fail-on threshold`."""
    if threshold == "never":
        return False
    return SEVERITIES.index(severity) <= SEVERITIES.index(threshold)


def fails(counts: dict[str, int], threshold: str) -> bool:
    """The verdict of the exit code: a finding at or above `--fail-on` (counts by severity,
    those left out under `--max-findings` included)."""
    return any(counts.get(s) for s in SEVERITIES if is_failing_severity(s, threshold))


@dataclass(frozen=True)
class Param:
    """A rule parameter: its TOML name, Python type, meaning and default (the one place
    defaults live: `rules/default.toml` changes none of them)."""

    name: str
    type: type
    doc: str
    default: Any


@dataclass
class Problem:
    """One finding as a check sees it: where and what, not how loud."""

    channel: str | None  # None: the input itself (I-rules)
    node: int | None
    time: float
    message: str
    frame_index: int | None = None  # None: a moment; the engine finds the first frame at/after it
    line: int | None = None


@dataclass
class Problems:
    """Many problems of one node as columns, in the order a check found them.

    A vectorised check yields these so that a million offending frames never become a
    million objects: the engine makes a `Problem` (and calls `message`) only for those
    it keeps under the per-rule cap, and counts the rest.
    """

    channel: str | None
    node: int | None
    time: np.ndarray
    message: Callable[[int], str]  # the i-th problem's message
    frame_index: np.ndarray | None = None  # None: moments
    line: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.time)

    def problem(self, i: int) -> Problem:
        return Problem(self.channel, self.node, float(self.time[i]), self.message(i),
                       None if self.frame_index is None else int(self.frame_index[i]),
                       None if self.line is None else int(self.line[i]))


Check = Callable[[InputModel, dict[str, Any]], Iterator["Problem | Problems"]]


@dataclass(frozen=True)
class Rule:
    code: str
    name: str
    severity: str
    params: tuple[Param, ...]
    check: Check
    exempt_from_unknown: bool = False
    # whose findings: "node" (a node's), "network" (the channel's: node null),
    # "network+node" (either), "input" (the input itself: no channel, no node)
    scope: str = "node"

    @property
    def doc(self) -> str:
        return inspect.cleandoc(self.check.__doc__ or "")

    @property
    def summary(self) -> str:
        return self.doc.splitlines()[0] if self.doc else ""


SCOPES = ("node", "network", "network+node", "input")


def rule(code: str, name: str, severity: str, *params: Param,
         exempt_from_unknown: bool = False, scope: str = "node") -> Callable[[Check], Rule]:
    """Declare a rule; the decorated function's docstring is its documentation."""
    assert severity in SEVERITIES and scope in SCOPES, (code, severity, scope)

    def wrap(check: Check) -> Rule:
        return Rule(code, name, severity, params, check, exempt_from_unknown, scope)

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
