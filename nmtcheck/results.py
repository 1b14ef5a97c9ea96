"""What checking an input yields: its findings, the ones past the per-rule cap, the rules
that could not be evaluated, and the verdict's counts. These types sit below the engine
that makes them and every stage that reads them (explain, reporters, live, fleet, the API),
so that none of those imports the engine for a type."""

from __future__ import annotations

import io
import pickle
import sys
from dataclasses import dataclass, field
from typing import Any, NoReturn, cast

import numpy as np

from nmtcheck.checks.base import SEVERITIES
from nmtcheck.processes.boot_records import BootAnalysis
from nmtcheck.readers import InputStats
from nmtcheck.timeline import model as timeline_model
from nmtcheck.timeline import tables
from nmtcheck.timeline.decode import Decoded
from nmtcheck.timeline.model import InputModel, NodeModel


@dataclass
class Finding:
    input: int
    rule: str
    name: str
    severity: str
    channel: str | None  # None: the input itself (I-rules)
    node: int | None
    time: float
    frame_index: int | None
    line: int | None
    message: str
    # configured | measured: where the limit of a time rule came from (SPEC §7), else None
    basis: str | None = None
    # SPEC §8: P findings' Lely-compatible letter and proving frame; the events that may
    # explain H001, G002, B001 (a), B002 and S004 findings (None: the field does not apply)
    boot_letter: str | None = None
    evidence: dict[str, Any] | None = None
    causes: list[dict[str, Any]] | None = None
    causes_omitted: int | None = None
    # SPEC §9.3: what came after the effect began (the master's reset after a timeout, the
    # node's EMCY that reports it), each with its role; None where `causes` is None
    reactions: list[dict[str, Any]] | None = None
    reactions_omitted: int | None = None


MAX_FINDINGS_PER_RULE = 10000  # per input; the rest is counted, never silently dropped


@dataclass
class Omitted:
    """Findings of one rule past the per-rule cap: counted and stated in every report."""

    rule: str
    name: str
    severity: str
    count: int


@dataclass
class InputResult:
    index: int
    stats: InputStats
    model: InputModel
    findings: list[Finding] = field(default_factory=list)
    omitted: list[Omitted] = field(default_factory=list)
    # selected rules that could not be evaluated on this input: code -> reason (SPEC §7)
    not_evaluated: dict[str, str] = field(default_factory=dict)
    # rules that judged part of it and skipped the rest: code -> reason and scope (§9.1.3)
    partly_evaluated: dict[str, str] = field(default_factory=dict)
    # SPEC §9.3.6: each EMCY event's chain, by (channel, node, frame index); the causes of
    # each timeline interval that begins with a change no NMT command explains, by
    # (channel, node, the interval's start rounded to 1 ns)
    event_causes: dict[tuple[str, int, int], list[dict[str, Any]]] = field(
        default_factory=dict)
    interval_causes: dict[tuple[str, int, float], list[dict[str, Any]]] = field(
        default_factory=dict)
    error: str | None = None  # why the input could not be read (then it has nothing else)
    boot: BootAnalysis | None = None  # the CiA 302-2 boot processes (SPEC §8.5)

    def nodes(self) -> list[NodeModel]:
        return list(self.model.nodes())


def summary(results: list[InputResult]) -> dict[str, int]:
    counts = dict.fromkeys(SEVERITIES, 0)
    for res in results:
        for f in res.findings:
            counts[f.severity] += 1
        for o in res.omitted:  # left out of the reports, not out of the verdict
            counts[o.severity] += o.count
    return counts


class _Released:
    """What `model.decoded` is once the input's result is kept for the reports
    (`for_reports`): the reports read the model, its nodes and the analyses kept with it,
    never the decoded frames; a use of them fails here, loudly, instead of finding empty
    tables (the frame stores are closed after the check in any case)."""

    def __getattr__(self, name: str) -> NoReturn:
        if name.startswith("__"):  # pickle, copy and repr look for these: not here
            raise AttributeError(name)
        raise AttributeError(f"decoded.{name}: the decoded frames of a checked input are "
                             "released once its result is kept for the reports "
                             "(nmtcheck.results.for_reports)")

    def __repr__(self) -> str:
        return "<decoded frames: released after the check>"

    def __reduce__(self) -> str:
        return "RELEASED"  # one stand-in, also after a worker process sends it back


RELEASED = _Released()


def for_reports(result: InputResult) -> InputResult:
    """`result` with only what the reports read: the decoded frame tables (the spools'
    columns, the per-frame views the rules used) and the model's query caches are
    released. `nmtcheck check` holds every input's result until the reports are written:
    a two-line log's held 21 KB, 11 KB without these (2026-12-08, tracemalloc); the
    reports are the same byte for byte. Not for the Python API, whose `Report.results`
    gives the whole model."""
    model = result.model
    model.decoded = cast(Decoded, RELEASED)
    model._sent_while.clear()  # sent_while(): a rule's query over the frames
    model.__dict__.pop("_first_tx_after_resets", None)  # likewise (a cached_property)
    return result


# Values that many results share in the process that checked them, and that a pickle would
# copy into every result sent back from a worker: zero-length arrays (a node's empty
# columns, a boot analysis' empty spans), the timeline's shared empty tables and the short
# strings every input repeats (field names, rule reasons, channel names).
SHARED_STRING_MAX = 128  # longer strings are rarely repeated (finding messages, paths)
_EMPTY: dict[tuple[np.dtype[Any], tuple[int, ...]], np.ndarray] = {}


def _shared_empty_array(dtype: np.dtype[Any], shape: tuple[int, ...]) -> np.ndarray:
    """The one read-only zero-length array of this dtype and shape."""
    found = _EMPTY.get((dtype, shape))
    if found is None:
        found = _EMPTY[(dtype, shape)] = np.empty(shape, dtype)
        found.flags.writeable = False
    return found


# the tags of `_SharingPickler`'s persistent IDs: numbers, as a string in a persistent ID
# would be asked for its own ID again
_STRING, _EMPTY_ARRAY, _CONSTANT, _TABLE = range(4)
_CONSTANTS = ("_NO_MEDIAN",)  # the timeline's shared node defaults that are not empty


class _SharingPickler(pickle.Pickler):
    """Writes what `_SharingUnpickler` gives back as one shared object per process."""

    def __init__(self, file: io.BytesIO) -> None:
        super().__init__(file, protocol=pickle.HIGHEST_PROTOCOL)
        self._tables = {id(t): cls for cls, t in tables._SHARED.items()}
        self._constants = {id(getattr(timeline_model, name)): i
                           for i, name in enumerate(_CONSTANTS)}

    def persistent_id(self, obj: Any) -> Any:
        kind = type(obj)
        if kind is str:
            return (_STRING, obj.encode("utf-8", "surrogatepass")) if (
                len(obj) <= SHARED_STRING_MAX) else None
        if kind is np.ndarray:
            if not obj.size and not obj.dtype.hasobject:
                return (_EMPTY_ARRAY, obj.dtype, obj.shape)
            constant = self._constants.get(id(obj))
            return (_CONSTANT, constant) if constant is not None else None
        table = self._tables.get(id(obj))
        return (_TABLE, table) if table is not None else None


class _SharingUnpickler(pickle.Unpickler):
    def persistent_load(self, pid: Any) -> Any:
        tag, value, *rest = pid
        if tag == _STRING:
            return sys.intern(value.decode("utf-8", "surrogatepass"))
        if tag == _EMPTY_ARRAY:
            return _shared_empty_array(value, rest[0])
        if tag == _CONSTANT:
            return getattr(timeline_model, _CONSTANTS[value])
        if tag == _TABLE:
            return tables.shared_empty(value)
        raise pickle.UnpicklingError(f"unknown shared value {tag!r}")


@dataclass
class PackedResult:
    """A result for the reports (`for_reports`) as a worker process sends it back: a
    pickle whose shared values (`_SharingPickler`) stay shared in the process that writes
    the reports, where a plain pickle made a copy of each per result (a two-line log's
    result took 32 KB there, 18 KB so, 11 KB in the process that checked it)."""

    data: bytes

    @classmethod
    def of(cls, result: InputResult) -> PackedResult:
        out = io.BytesIO()
        _SharingPickler(out).dump(for_reports(result))
        return cls(out.getvalue())

    def unpack(self) -> InputResult:
        return cast(InputResult, _SharingUnpickler(io.BytesIO(self.data)).load())
