"""What a rule is: a code, a name, a default severity, typed parameters and a check.

Two kinds of check, as yamllint has token and line rules. Most rules judge one node
(`@rule`): `check(node, ctx, params)` yields `(time, message)` or `(time, message,
frame)` and the engine stamps channel and node. A few judge the whole input
(`@input_rule`): `check(model, params)` yields `Problem`s. Either may yield a columnar
`Problems` batch when it can find a million. A check never knows its own severity or
whether it is enabled: the engine stamps code, name and severity (as yamllint does).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from nmtcheck.timeline.model import (
    ChannelModel,
    InputModel,
    Master,
    NodeModel,
    TimelineParams,
    Timeout,
)

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
    maximum: float | None = None  # the largest value a profile may give (a share: 1)


@dataclass
class Problem:
    """One finding as a check sees it: where and what, not how loud."""

    channel: str | None  # None: the input itself (I-rules)
    node: int | None
    time: float
    message: str
    frame_index: int | None = None  # None: a moment; the engine finds the first frame at/after it
    line: int | None = None
    after: int | None = None  # a moment's evidence frame: the frame found comes after it


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
    frame_index: np.ndarray | None = None  # None: moments (or one row's -1: that row is)
    line: np.ndarray | None = None
    nodes: np.ndarray | None = None  # per problem, for a per-input rule (-1: the network)

    def __len__(self) -> int:
        return len(self.time)

    def node_of(self, i: int) -> int | None:
        if self.nodes is None:
            return self.node
        n = int(self.nodes[i])
        return None if n < 0 else n

    def problem(self, i: int) -> Problem:
        idx = -1 if self.frame_index is None else int(self.frame_index[i])
        return Problem(self.channel, self.node_of(i), float(self.time[i]), self.message(i),
                       None if idx < 0 else idx,
                       None if self.line is None or idx < 0 else int(self.line[i]))

    def subset(self, rows: np.ndarray) -> Problems:
        """These rows only, in order (messages still made on demand)."""

        def message(i: int) -> str:
            return self.message(int(rows[i]))

        return Problems(self.channel, self.node, self.time[rows], message,
                        None if self.frame_index is None else self.frame_index[rows],
                        None if self.line is None else self.line[rows],
                        None if self.nodes is None else self.nodes[rows])


def batch(time: np.ndarray, message: Callable[[int], str], frame_index: np.ndarray | None = None,
          line: np.ndarray | None = None) -> Problems:
    """A `Problems` batch from a per-node check: the engine fills in channel and node."""
    return Problems(None, None, time, message, frame_index, line)


class Located(Protocol):
    """A frame a finding points at: an `EcFrame`, `NmtFrame`, ... (anything with these)."""

    @property
    def idx(self) -> int: ...
    @property
    def line(self) -> int: ...


Params = dict[str, Any]
# What a per-node check yields: a moment (the engine finds its frame; for a `Timeout`'s,
# one after the frame the wait started from: where time goes back, as in two captures in
# one file, the first frame at the moment can lie in the other capture), a moment at a
# frame (a `Located` or an (index, line) pair), or a batch.
Found = tuple[float, str] | tuple[float, str, Located | tuple[int, int] | Timeout] | Problems
Check = Callable[[InputModel, Params], Iterator["Problem | Problems"]]
NodeCheck = Callable[[NodeModel, "NodeContext", Params], Iterator[Found]]


@dataclass(frozen=True)
class NodeContext:
    """What a per-node check may know beyond its node: the input and the node's channel."""

    model: InputModel
    channel: ChannelModel

    @property
    def start(self) -> float:
        """The start of the channel's trace: the input's, or its capture's."""
        return self.channel.start

    @property
    def end(self) -> float:
        return self.channel.end

    @property
    def timeline(self) -> TimelineParams:
        return self.model.timeline

    @property
    def master(self) -> Master | None:
        return self.channel.master


@dataclass(frozen=True)
class Rule:
    code: str
    name: str
    severity: str
    params: tuple[Param, ...]
    check: Check | NodeCheck  # per input, or per node if `per_node`
    exempt_from_unknown: bool = False
    # whose findings: "node" (a node's), "network" (the channel's: node null),
    # "network+node" (either), "input" (the input itself: no channel, no node)
    scope: str = "node"
    per_node: bool = False  # check(node, ctx, params) for each node, else check(model, params)

    @property
    def doc(self) -> str:
        return inspect.cleandoc(self.check.__doc__ or "")

    @property
    def summary(self) -> str:
        return self.doc.splitlines()[0] if self.doc else ""


SCOPES = ("node", "network", "network+node", "input")


def rule(code: str, name: str, severity: str, *params: Param,
         exempt_from_unknown: bool = False) -> Callable[[NodeCheck], Rule]:
    """Declare a per-node rule: `check(node, ctx, params)`, called for each node of each
    channel (channels in model order, nodes in number order). Its docstring is its
    documentation."""
    assert severity in SEVERITIES, (code, severity)

    def wrap(check: NodeCheck) -> Rule:
        return Rule(code, name, severity, params, check, exempt_from_unknown, "node", True)

    return wrap


def input_rule(code: str, name: str, severity: str, *params: Param,
               exempt_from_unknown: bool = False, scope: str = "input"
               ) -> Callable[[Check], Rule]:
    """Declare a rule over the whole input: `check(model, params)` yields `Problem`s (for
    findings across nodes or channels, or of the input itself)."""
    assert severity in SEVERITIES and scope in SCOPES, (code, severity, scope)

    def wrap(check: Check) -> Rule:
        return Rule(code, name, severity, params, check, exempt_from_unknown, scope)

    return wrap


def run_starts(join: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vectorised `runs`: `join[i]` says item i continues the run of item i-1 (`join[0]` is
    ignored). Returns the index of each run's first item and the run's length."""
    n = len(join)
    if not n:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    first = np.flatnonzero(np.concatenate([[True], ~np.asarray(join, bool)[1:]]))
    return first, np.diff(np.append(first, n))


WINDOW = 1 << 18  # frames (SYNCs, one stream's PDOs) a rule works on at once


def windows(n: int) -> Iterator[tuple[int, int]]:
    """The ranges [a, b) of `n` frames, `WINDOW` at a time: a rule's working arrays over
    one range, not over all (a 5 M-frame stream's D001 took 240 MB, 5 M SYNCs' Y001
    265 MB)."""
    for a in range(0, n, WINDOW):
        yield a, min(a + WINDOW, n)


def flagged_runs(join: np.ndarray, flagged: np.ndarray) -> list[tuple[int, int]]:
    """`run_starts`, keeping only the runs whose first item is flagged, as (first, length)
    pairs: a rule walks its findings, never every run of a long stream. Where a join never
    links a flagged item to an unflagged one (every rule's: it joins items of one defect)
    only the flagged items are looked at: `run_starts` of a clean stream of 5 M frames
    made two arrays of 5 M run starts and lengths (80 MB) to keep none of them."""
    join, flagged = np.asarray(join, bool), np.asarray(flagged, bool)
    if len(join) > 1 and np.any(join[1:] & (flagged[1:] != flagged[:-1])):
        first, length = run_starts(join)
        keep = flagged[first] if len(first) else np.zeros(0, bool)
        return list(zip(first[keep].tolist(), length[keep].tolist(), strict=True))
    cand = np.flatnonzero(flagged)
    if not len(cand):
        return []
    # a flagged item continues the run before it where it is joined to the item before,
    # which is then flagged too: the candidate before it
    cont = join[cand] & (cand > 0)
    starts = np.flatnonzero(~cont)
    lengths = np.diff(np.append(starts, len(cand)))
    return list(zip(cand[starts].tolist(), lengths.tolist(), strict=True))


def count_note(n: int, what: str = "frames") -> str:
    return f" ({n} {what})" if n > 1 else ""
