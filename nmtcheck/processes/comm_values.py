"""The value in force of a communication object of SPEC §9.1.1 (1005h, 1006h, 1007h, 1019h,
1014h, 1015h, 1029h:01) for one node at one moment, with where it came from.

The order is §6's: a confirmed SDO download in the trace, from its confirmation until
the node's next boot-up or reset (§9.1.3); else the network file's key; else the node's
device file. After a reset, an object that was written by SDO before has no known value
until the next confirmed write: the stacks differ (CiA 301 and Lely restore the power-on
value, CANopenNode keeps the value in RAM), so neither the written nor the file's value
can be assumed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nmtcheck.timeline.model import NodeModel
from nmtcheck.timeline.node_events import WriteTable

EPS = 1e-9


@dataclass(frozen=True)
class Value:
    """A value in force and its source: `network`, `device-file`, `sdo` (with the
    confirmation's time and line), `default` (§9.1.4), `measured`, or None: unknown."""

    value: int | float | None
    source: str | None = None
    node: int | None = None
    time: float | None = None
    line: int | None = None

    @property
    def known(self) -> bool:
        return self.value is not None

    def as_dict(self) -> dict[str, object]:
        out: dict[str, object] = {"value": self.value, "source": self.source}
        if self.node is not None:
            out["node"] = self.node
        if self.source == "sdo":
            out["time"] = None if self.time is None else round(self.time, 6)
            out["line"] = self.line or None
        return out


UNKNOWN = Value(None)


def in_force(m: NodeModel | None, node: int, index: int, sub: int, t: float,
             network: int | None, device: int | None) -> Value:
    """Object `index`:`sub` of `node` at `t` (`m`: its model, None when the log shows no
    such node; `network`, `device`: the files' values)."""
    fallback = (Value(network, "network", node) if network is not None
                else Value(device, "device-file", node) if device is not None else UNKNOWN)
    if m is None:
        return fallback
    return written_value(m.writes, node, index, sub, t, fallback)


def written_value(w: WriteTable, node: int, index: int, sub: int, t: float,
                  fallback: Value) -> Value:
    """`index`:`sub` at `t` by the confirmed writes `w`: the last one while it holds,
    unknown after the reset that ended it (§9.1.3), else `fallback` (the files')."""
    if not len(w):
        return fallback
    mine = np.flatnonzero((w.index == index) & (w.sub == sub) & (w.ts <= t + EPS))
    if not len(mine):
        return fallback
    k = int(mine[-1])
    if float(w.until[k]) > t + EPS:
        return Value(int(w.value[k]), "sdo", node, float(w.ts[k]), int(w.line[k]))
    return UNKNOWN


def written_at(m: NodeModel | None, indices: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """(times, frame indices) of the node's confirmed SDO writes of these objects."""
    if m is None or not len(m.writes):
        return np.zeros(0), np.zeros(0, np.int64)
    sel = np.isin(m.writes.index, indices)
    return m.writes.ts[sel], m.writes.idx[sel]
