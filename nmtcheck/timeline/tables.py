"""The columnar tables of the NMT and error-control streams: a channel's frames on 000h
(`NmtTable`), the commands that apply to a node (`CommandTable`), a node's frames on
700h+N (`EcTable`) and its state intervals (`IntervalTable`), with the frame objects
(`NmtFrame`, `Command`, `EcFrame`, `Interval`) made only for what a rule or a report
looks at.

Their own module because they are storage, not knowledge of a node: the timeline fills
them, the rules read them, and `model.py` holds what is known of nodes and channels.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeVar, cast

import numpy as np
from numpy.typing import DTypeLike

from nmtcheck.protocol.nmt import (
    COMMAND_NAMES,
    COMMAND_STATE,
    EC_KIND_NAMES,
    GUARD,
    HEARTBEAT,
    MALFORMED,
    REQUEST,
    RESETS,
    SOURCES,
    STATES,
    nmt_problem,
)

if TYPE_CHECKING:
    from nmtcheck.timeline.ec_compact import GapRuns, GuardRuns

_NO_ROWS: dict[np.dtype[Any], np.ndarray] = {}  # per dtype: see column()
_T = TypeVar("_T")


def column(values: Any, dtype: DTypeLike) -> np.ndarray:
    """`np.asarray(values, dtype)`, but one shared zero-length array per dtype for no
    rows: every node starts with a dozen empty tables, and a log may have tens of
    thousands of nodes (a zero-length array cannot be written into)."""
    if not isinstance(values, np.ndarray) or values.size or values.ndim != 1:
        return np.asarray(values, dtype)
    key = np.dtype(dtype)
    empty = _NO_ROWS.get(key)
    if empty is None:
        empty = _NO_ROWS[key] = np.zeros(0, key)
    return empty


_BLANKS: dict[type, dict[str, Any]] = {}


def blank(cls: type[_T], make: Callable[[], _T]) -> _T:
    """An empty table of `cls` without building it: its attributes are those of one
    `make()` made once per class (zero-length columns, shared: they cannot be written
    into). Every node starts with a dozen empty tables, and a log may have tens of
    thousands of nodes."""
    attrs = _BLANKS.get(cls)
    if attrs is None:
        attrs = _BLANKS[cls] = dict(vars(make()))
    obj: _T = object.__new__(cls)
    obj.__dict__.update(attrs)
    return obj


_SHARED: dict[type, Any] = {}


def shared_empty(cls: type[_T]) -> _T:
    """The one empty table of `cls` (its `empty()`) that every node without one of its own
    holds: a log may have tens of thousands of nodes, and an empty table per node and
    kind took 2.7 KB a node. Never changed: the timeline gives a node a table of its
    own, it never writes into or assigns to the shared one."""
    table = _SHARED.get(cls)
    if table is None:
        table = _SHARED[cls] = cls.empty()  # type: ignore[attr-defined]
    return cast(_T, table)


@dataclass(frozen=True)
class NmtFrame:
    """A frame on CAN-ID 000h, valid or not."""

    ts: float
    idx: int
    line: int
    rtr: bool
    dlc: int
    cs: int
    target: int
    problem: str | None  # why it is malformed (C002), None if valid


@dataclass(frozen=True)
class Command:
    """A valid NMT command as it applies to one node."""

    ts: float
    idx: int
    line: int
    cs: int
    broadcast: bool

    @property
    def is_reset(self) -> bool:
        return self.cs in RESETS

    @property
    def name(self) -> str:
        return COMMAND_NAMES[self.cs] + (" (broadcast)" if self.broadcast else "")


_KNOWN_CS = np.zeros(256, bool)
_KNOWN_CS[list(COMMAND_STATE) + list(RESETS)] = True


def known_cs(cs: np.ndarray) -> np.ndarray:
    """Whether each byte is a command specifier CiA 301 defines."""
    known: np.ndarray = _KNOWN_CS[cs]
    return known
_RESET_CS = np.zeros(256, bool)
_RESET_CS[list(RESETS)] = True


def reset_cs(cs: np.ndarray) -> np.ndarray:
    """Whether each byte is a reset command specifier (reset node, reset communication)."""
    reset: np.ndarray = _RESET_CS[cs]
    return reset


class NmtTable:
    """A channel's frames on CAN-ID 000h as columns, valid or not (a hostile log may
    hold millions of them): a `NmtFrame` is made only for what a rule reports."""

    def __init__(self, ts: np.ndarray, idx: np.ndarray, line: np.ndarray, rtr: np.ndarray,
                 dlc: np.ndarray, cs: np.ndarray, target: np.ndarray) -> None:
        self.ts = column(ts, np.float64)
        self.idx = column(idx, np.int64)
        self.line = column(line, np.int64)
        self.rtr = column(rtr, bool)
        self.dlc = column(dlc, np.int16)
        self.cs = column(cs, np.uint8)
        self.target = column(target, np.uint8)
        self.valid = ~self.rtr & (self.dlc == 2) & _KNOWN_CS[self.cs] & (self.target <= 127)

    @classmethod
    def empty(cls) -> NmtTable:
        z = np.zeros(0)
        return blank(cls, lambda: cls(z, z, z, z, z, z, z))

    def __len__(self) -> int:
        return len(self.ts)

    def __getitem__(self, pos: int) -> NmtFrame:
        rtr, dlc, cs, target = (bool(self.rtr[pos]), int(self.dlc[pos]), int(self.cs[pos]),
                                int(self.target[pos]))
        return NmtFrame(float(self.ts[pos]), int(self.idx[pos]), int(self.line[pos]), rtr, dlc,
                        cs, target, nmt_problem(rtr, dlc, cs, target))

    def __iter__(self) -> Iterator[NmtFrame]:
        return (self[i] for i in range(len(self)))


def plain_rows(*columns: np.ndarray, block: int = 4096) -> Iterator[tuple[Any, ...]]:
    """The rows of some columns as tuples of plain Python numbers, converted a block at a
    time (`tolist` per block: fast, and memory stays flat however long the columns)."""
    for lo in range(0, len(columns[0]) if columns else 0, block):
        yield from zip(*(c[lo:lo + block].tolist() for c in columns), strict=True)


class _Gathered:
    """A `CommandTable` column: the NMT table's column of that name at the commands'
    positions, gathered on each access."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    def __get__(self, table: CommandTable, owner: type | None = None) -> np.ndarray:
        column: np.ndarray = getattr(table.nmt, self.name)[table.pos]
        return column


class CommandTable:
    """The valid NMT commands that apply to one node, as positions into its channel's
    `NmtTable`: a log of nothing but NMT commands gives each of 127 nodes every
    broadcast, so a node holds a position per command, not a copy of the columns. The
    columns (`ts`, `idx`, ...) are gathered on each access: take them once per check."""

    def __init__(self, nmt: NmtTable, pos: np.ndarray) -> None:
        self.nmt = nmt
        self.pos = np.asarray(pos, np.int32 if len(nmt) < 1 << 31 else np.int64)
        self.is_reset = _RESET_CS[nmt.cs[self.pos]]

    @classmethod
    def empty(cls) -> CommandTable:
        return blank(cls, lambda: cls(NmtTable.empty(), np.zeros(0, np.int64)))

    def __len__(self) -> int:
        return len(self.pos)

    def __getitem__(self, pos: int) -> Command:
        nmt, at = self.nmt, int(self.pos[pos])
        return Command(float(nmt.ts[at]), int(nmt.idx[at]), int(nmt.line[at]), int(nmt.cs[at]),
                       bool(nmt.target[at] == 0))

    def __iter__(self) -> Iterator[Command]:
        return (self[i] for i in range(len(self)))

    def name(self, pos: int) -> str:
        at = int(self.pos[pos])
        return COMMAND_NAMES[int(self.nmt.cs[at])] + (
            " (broadcast)" if self.nmt.target[at] == 0 else "")

    ts = _Gathered()
    idx = _Gathered()
    line = _Gathered()
    cs = _Gathered()

    @property
    def broadcast(self) -> np.ndarray:
        broadcast: np.ndarray = self.nmt.target[self.pos] == 0
        return broadcast

    @property
    def reset_idx(self) -> np.ndarray:
        """File positions of the reset commands (sorted: commands are in file order)."""
        idx: np.ndarray = self.nmt.idx[self.pos[self.is_reset]]
        return idx

    @property
    def reset_ts(self) -> np.ndarray:
        ts: np.ndarray = self.nmt.ts[self.pos[self.is_reset]]
        return ts


@dataclass(frozen=True)
class EcFrame:
    """One frame on 700h+N, materialised from the node's columns for a finding or a test."""

    pos: int  # position in the node's EcTable
    ts: float
    idx: int
    line: int
    rtr: bool
    dlc: int
    value: int  # data byte 0
    kind: str  # request | bootup | heartbeat | guard | malformed

    @property
    def code(self) -> int:
        return self.value & 0x7F

    @property
    def toggle(self) -> int:
        return self.value >> 7

    @property
    def reports_state(self) -> bool:
        return self.kind in ("bootup", "heartbeat", "guard")


class EcTable:
    """A node's frames on 700h+N as columns, in file order.

    Heartbeats are the one dense NMT stream (a frame per node per period), so
    they stay numpy columns; rules compute on them vectorised and materialise an
    `EcFrame` only for what they report.
    """

    def __init__(self, ts: np.ndarray, idx: np.ndarray, line: np.ndarray, rtr: np.ndarray,
                 dlc: np.ndarray, value: np.ndarray) -> None:
        self.ts = column(ts, np.float64)
        self.idx = column(idx, np.int64)
        self.line = column(line, np.int64)
        self.rtr = column(rtr, bool)
        self.dlc = column(dlc, np.int16)
        self.value = column(value, np.uint8)
        self.kind = np.where(self.rtr, REQUEST, MALFORMED).astype(np.int8)
        # a report of the pre-command state just after a command (SPEC §2 stale reports)
        self.stale = np.zeros(len(self.ts), bool)
        # steady heartbeats dropped between rows (a long log only, `ec_compact`)
        self.runs: GapRuns | None = None
        self.guard_runs: GuardRuns | None = None  # dropped guarding exchanges (ec_compact)

    @classmethod
    def empty(cls) -> EcTable:
        z = np.zeros(0)
        return blank(cls, lambda: cls(z, z, z, z, z, z))

    @classmethod
    def view(cls, cols: dict[str, np.ndarray], rows: slice, kind: np.ndarray,
             stale: np.ndarray) -> EcTable:
        """Rows `rows` of columns of the constructor's dtypes, with their kinds and stale
        marks, all views: the timeline makes `kind` and `stale` once for every node (a
        log may have tens of thousands of nodes of a frame or two each). A node of a few
        rows gets a `_FewEcRows`: 8 views held per node were 865 bytes a node."""
        if rows.stop - rows.start <= FEW_ROWS and cols["kind"] is kind and (
                cols["stale"] is stale):
            return _FewEcRows(cols, rows)
        t = blank(cls, cls.empty)
        t.ts, t.idx, t.line = cols["ts"][rows], cols["idx"][rows], cols["line"][rows]
        t.rtr, t.dlc, t.value = cols["rtr"][rows], cols["dlc"][rows], cols["value"][rows]
        t.kind, t.stale = kind[rows], stale[rows]
        return t


    def __len__(self) -> int:
        return len(self.ts)

    def __getitem__(self, pos: int) -> EcFrame:
        return EcFrame(int(pos), float(self.ts[pos]), int(self.idx[pos]), int(self.line[pos]),
                       bool(self.rtr[pos]), int(self.dlc[pos]), int(self.value[pos]),
                       EC_KIND_NAMES[self.kind[pos]])

    def __iter__(self) -> Iterator[EcFrame]:
        return (self[i] for i in range(len(self)))

    def frames(self, positions: Iterable[int]) -> list[EcFrame]:
        return [self[int(p)] for p in positions]

    def where(self, *kinds: int) -> np.ndarray:
        """Positions of the frames of these kinds (compared one kind at a time: np.isin
        costs far more on the few frames most nodes have). Not kept between calls: for
        a node of millions of heartbeats that would hold 8 bytes a frame more."""
        hit = self.kind == kinds[0]
        for k in kinds[1:]:
            hit |= self.kind == k
        return np.flatnonzero(hit)

    def count(self, kind: int) -> int:
        """How many frames of this kind, the heartbeats of dropped runs included."""
        n = int(np.count_nonzero(self.kind == kind))
        if kind == HEARTBEAT and self.runs is not None:
            n += self.runs.dropped
        if kind in (REQUEST, GUARD) and self.guard_runs is not None:
            n += self.guard_runs.dropped // 2
        return n

    @property
    def code(self) -> np.ndarray:
        return self.value & 0x7F

    def after(self, idx: int) -> int:
        """Position of the first frame later in the file than frame index `idx`."""
        return int(np.searchsorted(self.idx, idx, side="right"))


FEW_ROWS = 2  # a node of at most this many error-control rows: a `_FewEcRows` (see there)


class _Rows:
    """A `_FewEcRows` column: a view of the node's rows of the channel-wide column, made
    on each read. A non-data descriptor: a column assigned to the table (`classify`
    sets `kind`) is read from the table's own attributes instead."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    def __get__(self, table: _FewEcRows, owner: type | None = None) -> np.ndarray:
        column: np.ndarray = table._cols[self.name][table._rows]
        return column


class _FewEcRows(EcTable):
    """A node's few rows of the channel-wide error-control columns (`EcTable.view`),
    each column a view made when it is read and not kept: a log of 200,000 channels has
    200,000 nodes of a frame or two, and 8 kept views cost 865 bytes a node. A column
    assigned (`classify` sets `kind`) is kept as assigned; writes into a column's view
    reach the channel-wide column as they do through a kept view. Only for a node of
    `FEW_ROWS` rows: a view made per read costs about 1,500 instructions, and a node of
    a boot-up and three heartbeats (40,000 channels) is read some 28 times (4.5 % more
    instructions for the whole check with up to 8 rows, 2026-12-08)."""

    runs = None  # a small node has no dropped run (`ec_compact` drops long runs only)
    guard_runs = None
    ts = _Rows()
    idx = _Rows()
    line = _Rows()
    rtr = _Rows()
    dlc = _Rows()
    value = _Rows()
    kind = _Rows()
    stale = _Rows()

    def __init__(self, cols: dict[str, np.ndarray], rows: slice) -> None:
        self._cols, self._rows = cols, rows

    def __len__(self) -> int:
        rows = self._rows
        return int(rows.stop - rows.start)

    def __getitem__(self, pos: int) -> EcFrame:
        """The frame at `pos`, read from the channel-wide columns (no view made)."""
        n, p = len(self), int(pos)
        if not -n <= p < n:
            raise IndexError(pos)
        at = self._rows.start + (p if p >= 0 else p + n)
        cols, own_kind = self._cols, self.__dict__.get("kind")
        kind = cols["kind"][at] if own_kind is None else own_kind[at - self._rows.start]
        return EcFrame(p, float(cols["ts"][at]), int(cols["idx"][at]), int(cols["line"][at]),
                       bool(cols["rtr"][at]), int(cols["dlc"][at]), int(cols["value"][at]),
                       EC_KIND_NAMES[kind])


def kind_stamp(ec: EcTable) -> object:
    """What changes when a table's kinds are replaced (`classify` assigns `kind`): the
    caches of `NodeModel.kind_counts` and `heartbeat_pairs` hold it. The kinds' array
    where the table keeps one, else (a `_FewEcRows` not yet classified) the table: a
    view made on each read is never the same object twice. A dict lookup, not a
    property: it is asked some 20 times a node."""
    return ec.__dict__.get("kind", ec)


@dataclass
class Interval:
    start: float
    end: float
    state: str
    source: str


class IntervalTable:
    """A node's state intervals as columns (state and source as indices into `STATES`
    and `SOURCES`): a node that changes state on every heartbeat has millions of them.
    An `Interval` is made only when one is looked at."""

    def __init__(self, start: np.ndarray, end: np.ndarray, state: np.ndarray,
                 source: np.ndarray) -> None:
        self.start = column(start, np.float64)
        self.end = column(end, np.float64)
        self.state = column(state, np.int8)
        self.source = column(source, np.int8)

    @classmethod
    def empty(cls) -> IntervalTable:
        z = np.zeros(0)
        return blank(cls, lambda: cls(z, z, z, z))

    def __len__(self) -> int:
        return len(self.start)

    def __getitem__(self, pos: int) -> Interval:
        return Interval(float(self.start[pos]), float(self.end[pos]), STATES[self.state[pos]],
                        SOURCES[self.source[pos]])

    def __iter__(self) -> Iterator[Interval]:
        for a, b, st, so in zip(self.start.tolist(), self.end.tolist(), self.state.tolist(),
                                self.source.tolist(), strict=True):
            yield Interval(a, b, STATES[st], SOURCES[so])


class FewIntervals(IntervalTable):
    """The one or two intervals of a node whose frames are boot-ups only (`bootups_only`):
    their bounds as Python floats, the columns made when read and not kept (the state
    and source columns are shared read-only ones). A log of 200,000 channels has 200,000
    such nodes, and 4 arrays kept per node were 425 bytes a node."""

    def __init__(self, bounds: tuple[float, ...], state: np.ndarray,
                 source: np.ndarray) -> None:
        self._bounds, self.state, self.source = bounds, state, source

    def __getattr__(self, name: str) -> Any:
        # only for what the instance lacks: the start and end columns
        if name == "start":
            return np.array(self.__dict__["_bounds"][:-1], np.float64)
        if name == "end":
            return np.array(self.__dict__["_bounds"][1:], np.float64)
        raise AttributeError(name)

    def __len__(self) -> int:
        return len(self._bounds) - 1

    @property
    def bounds(self) -> tuple[float, ...]:
        """The first interval's start, each next one's, and the last one's end."""
        return self._bounds


def interval_columns(tables: list[IntervalTable], with_end: bool = True
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Several nodes' intervals as one set of columns, node after node: each table's
    length, and the start, end (empty unless `with_end`) and state columns. The
    intervals of `FewIntervals` go in as Python numbers, not as an array per node made
    and held until the join (a log of 200,000 channels: 200,000 tables)."""
    lengths = np.fromiter((len(t) for t in tables), np.int64, len(tables))
    pieces: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    starts: list[float] = []
    ends: list[float] = []
    states: list[int] = []

    def few_to_pieces() -> None:
        if starts:
            pieces.append((np.asarray(starts, np.float64), np.asarray(ends, np.float64),
                           np.asarray(states, np.int8)))
            starts.clear()
            ends.clear()
            states.clear()

    for t in tables:
        if isinstance(t, FewIntervals):
            bounds = t.bounds
            starts.extend(bounds[:-1])
            if with_end:
                ends.extend(bounds[1:])
            states.extend(t.state.tolist())
        elif len(t):
            few_to_pieces()
            pieces.append((t.start, t.end if with_end else _NO_ENDS, t.state))
    few_to_pieces()
    if not pieces:
        return lengths, np.zeros(0), np.zeros(0), np.zeros(0, np.int8)
    # (a join is a new array: each is the caller's to write into)
    return (lengths, np.concatenate([p[0] for p in pieces]).astype(np.float64, copy=False),
            np.concatenate([p[1] for p in pieces]).astype(np.float64, copy=False),
            np.concatenate([p[2] for p in pieces]).astype(np.int8, copy=False))


_NO_ENDS = np.zeros(0)  # interval_columns without the ends


def shared_column(values: list[int], dtype: DTypeLike) -> np.ndarray:
    """One read-only array per distinct short list of values and dtype."""
    key = (tuple(values), np.dtype(dtype))
    found = _SHARED_COLUMNS.get(key)
    if found is None:
        found = _SHARED_COLUMNS[key] = np.asarray(values, dtype)
        found.flags.writeable = False
    return found


_SHARED_COLUMNS: dict[tuple[tuple[int, ...], np.dtype[Any]], np.ndarray] = {}


def next_of(marks: np.ndarray, after: np.ndarray, values: np.ndarray | None = None,
             none: float = np.iinfo(np.int64).max) -> np.ndarray:
    """Per entry of `after`, the first of the sorted `marks` greater than it (or that
    mark's entry of `values`), `none` where there is none."""
    k = np.searchsorted(marks, after, side="right")
    if not len(marks):
        return np.full(len(after), none)
    got = (marks if values is None else values)[np.minimum(k, len(marks) - 1)]
    return np.where(k < len(marks), got, none)
