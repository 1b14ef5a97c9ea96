"""A node's events as columns: EMCYs (`EmcyTable`), confirmed SDO writes to its
configuration objects (`WriteTable`), SDO aborts and segmented downloads
(`SdoEventTable`), merged in file order by `NodeEvents`; a `NodeEvent` or a
`ConfigWrite` is made only when one is looked at.

Their own module because they are what a node said that is not NMT (a log may hold
millions of EMCYs or SDO writes): the timeline fills them, the configuration in force
and the reports read them, and `model.py` holds what is known of nodes and channels.
"""

from __future__ import annotations

import heapq
import sys
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from nmtcheck.protocol import emcy, sdo
from nmtcheck.timeline.tables import blank, column, plain_rows, shared_empty


@dataclass
class ConfigWrite:
    """A confirmed SDO expedited download to a configuration object of `node`."""

    ts: float  # the server's confirmation (60h)
    idx: int
    line: int
    node: int  # the SDO server whose object was written
    index: int
    sub: int
    value: int
    until: float = float("inf")  # the node's next boot-up or reset: power-on values again
    request_ts: float = float("nan")  # the client's request: the server may act on it at once
    request_idx: int = -1


class WriteTable:
    """Confirmed SDO writes to configuration objects as columns, in file order (a log may
    write 1017h a million times): a `ConfigWrite` is made when one is looked at."""

    def __init__(self, ts: np.ndarray, idx: np.ndarray, line: np.ndarray, node: np.ndarray,
                 index: np.ndarray, sub: np.ndarray, value: np.ndarray, until: np.ndarray,
                 request_ts: np.ndarray, request_idx: np.ndarray) -> None:
        self.ts = column(ts, np.float64)  # the server's confirmation (60h)
        self.idx = column(idx, np.int64)
        self.line = column(line, np.int64)
        self.node = column(node, np.int16)  # the SDO server whose object was written
        self.index = column(index, np.int32)
        self.sub = column(sub, np.uint8)
        self.value = column(value, np.int64)
        self.until = column(until, np.float64)  # next boot-up or reset: power-on values
        self.request_ts = column(request_ts, np.float64)  # the server may act on it at once
        self.request_idx = column(request_idx, np.int64)

    _COLUMNS = ("ts", "idx", "line", "node", "index", "sub", "value", "until", "request_ts",
                "request_idx")

    @classmethod
    def empty(cls) -> WriteTable:
        z = np.zeros(0)  # every node starts with two
        return blank(cls, lambda: cls(z, z, z, z, z, z, z, z, z, z))

    @classmethod
    def of(cls, writes: Iterable[ConfigWrite]) -> WriteTable:
        rows = list(writes)
        return cls(*(np.asarray([getattr(w, name) for w in rows]) for name in cls._COLUMNS))

    @classmethod
    def concat(cls, tables: list[WriteTable]) -> WriteTable:
        if not tables:
            return cls.empty()
        return cls(*(np.concatenate([getattr(t, name) for t in tables]) for name in cls._COLUMNS))

    def take(self, rows: np.ndarray) -> WriteTable:
        return WriteTable(*(getattr(self, name)[rows] for name in self._COLUMNS))

    def __len__(self) -> int:
        return len(self.ts)

    def __getitem__(self, pos: int) -> ConfigWrite:
        return ConfigWrite(float(self.ts[pos]), int(self.idx[pos]), int(self.line[pos]),
                           int(self.node[pos]), int(self.index[pos]), int(self.sub[pos]),
                           int(self.value[pos]), float(self.until[pos]),
                           float(self.request_ts[pos]), int(self.request_idx[pos]))

    def __iter__(self) -> Iterator[ConfigWrite]:
        return (self[i] for i in range(len(self)))

    def events(self) -> Iterator[NodeEvent]:
        """Each write as the node event the reports list."""
        for ts, idx, line, index, sub, value in plain_rows(
                self.ts, self.idx, self.line, self.index, self.sub, self.value):
            yield NodeEvent(ts, idx, line, "sdo-write", f"{sdo.object_name(index, sub)} = "
                            f"{value} ({value:X}h{_meaning(index, value)}) written by SDO")


def _meaning(index: int, value: int) -> str:
    """What a written value says, where it packs several fields: a 1016h consumer entry
    is the producer's node-ID and the consumer time."""
    if index == 0x1016:
        producer, time_ms = (value >> 16) & 0xFF, value & 0xFFFF
        return f": node {producer}, {time_ms} ms" if time_ms else ": disabled"
    return ""


@dataclass
class NodeEvent:
    """Something a node said that is not a finding: EMCY, SDO abort, configuration write."""

    ts: float
    idx: int
    line: int
    kind: str  # emcy | sdo-abort | sdo-write | sdo-segmented
    text: str
    code: int | None = None


class EmcyTable:
    """A node's EMCY frames as columns, in file order (a node may send them as fast as
    the bus allows): a `NodeEvent`, with its decoded text, is made when one is looked at."""

    def __init__(self, ts: np.ndarray, idx: np.ndarray, line: np.ndarray, dlc: np.ndarray,
                 data: np.ndarray) -> None:
        self.ts = column(ts, np.float64)
        self.idx = column(idx, np.int64)
        self.line = column(line, np.int64)
        self.dlc = column(dlc, np.int16)
        self.data = column(data, np.uint64)  # the 8 data bytes, packed

    @classmethod
    def empty(cls) -> EmcyTable:
        z = np.zeros(0)
        return blank(cls, lambda: cls(z, z, z, z, z))

    def __len__(self) -> int:
        return len(self.ts)

    def __getitem__(self, pos: int) -> NodeEvent:
        code, text = _describe_emcy(int(self.data[pos]), int(self.dlc[pos]))
        return NodeEvent(float(self.ts[pos]), int(self.idx[pos]), int(self.line[pos]), "emcy",
                         text, code)

    def __iter__(self) -> Iterator[NodeEvent]:
        for ts, idx, line, dlc, data in plain_rows(self.ts, self.idx, self.line, self.dlc,
                                                   self.data):
            code, text = _describe_emcy(data, dlc)
            yield NodeEvent(ts, idx, line, "emcy", text, code)


@lru_cache(maxsize=4096)
def _describe_emcy(packed: int, dlc: int) -> tuple[int | None, str]:
    """`emcy.describe` of packed data bytes: a node that floods the bus with EMCYs mostly
    repeats a few of them."""
    return emcy.describe(list(packed.to_bytes(8, sys.byteorder)), dlc)


class SdoEventTable:
    """A server's SDO aborts and confirmed segmented downloads as columns, in file order
    (a log may abort a million of them): their texts are made as the reports read them."""

    def __init__(self, ts: np.ndarray, idx: np.ndarray, line: np.ndarray, abort: np.ndarray,
                 index: np.ndarray, sub: np.ndarray, code: np.ndarray,
                 answered: np.ndarray) -> None:
        self.ts = column(ts, np.float64)
        self.idx = column(idx, np.int64)
        self.line = column(line, np.int64)
        self.abort = column(abort, bool)  # else a confirmed segmented download
        self.index = column(index, np.int32)
        self.sub = column(sub, np.uint8)
        self.code = column(code, np.int64)  # the abort code
        self.answered = column(answered, bool)  # it answers the pending request

    @classmethod
    def empty(cls) -> SdoEventTable:
        z = np.zeros(0)
        return blank(cls, lambda: cls(z, z, z, z, z, z, z, z))

    def __len__(self) -> int:
        return len(self.ts)

    def __iter__(self) -> Iterator[NodeEvent]:
        for ts, idx, line, abort, index, sub, code, answered in plain_rows(
                self.ts, self.idx, self.line, self.abort, self.index, self.sub, self.code,
                self.answered):
            if abort:
                what = (f" to {sdo.object_name(index, sub)}" if answered
                        else f" ({index:04X}h sub {sub})")
                yield NodeEvent(ts, idx, line, "sdo-abort", f"SDO abort{what}: "
                                f"{code:08X}h {sdo.abort_text(code)}", code)
            else:
                yield NodeEvent(ts, idx, line, "sdo-segmented", "segmented download to "
                                f"{sdo.object_name(index, sub)} confirmed; its value is "
                                "not applied")


class NodeEvents:
    """Everything a node said that is not a finding, in file order when iterated, each
    kind as columns: EMCYs (`emcy`), configuration writes (`writes`), SDO aborts and
    segmented downloads (`sdo`)."""

    def __init__(self) -> None:
        self.emcy = shared_empty(EmcyTable)  # until the timeline gives the node its own
        self.writes = shared_empty(WriteTable)
        self.sdo = shared_empty(SdoEventTable)

    def __len__(self) -> int:
        return len(self.emcy) + len(self.writes) + len(self.sdo)

    def __bool__(self) -> bool:
        return len(self) > 0

    def __iter__(self) -> Iterator[NodeEvent]:
        return heapq.merge(self.emcy, self.writes.events(), self.sdo, key=_by_idx)


class NoEvents(NodeEvents):
    """The events of a node that has none: one object shared by every such node (a log
    of 200,000 channels has 200,000 of them), never written: `NodeModel.own_events()`
    gives a node events of its own before the timeline fills them in."""

    def __setattr__(self, name: str, value: Any) -> None:
        if name in self.__dict__:
            raise AttributeError(f"the shared empty events: {name} is set on a node's own")
        super().__setattr__(name, value)


NO_EVENTS = NoEvents()


def _by_idx(e: NodeEvent) -> int:
    return e.idx
