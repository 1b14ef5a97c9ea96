"""PDO parameters written by SDO in the trace (SPEC §9.1.1, §9.1.3): a confirmed download
wins over the files from its confirmation until the node's next boot-up or reset; after
that reset the object has no known value until it is written again (stacks differ on what
a reset restores), while an object never written keeps its file value.

A mapping is known where sub 0 and every entry 1..n in force are known; it changes where
the master rewrites it (sub 0 = 0, the entries, sub 0 = n), so D005 reads it per frame.
The other parameters (type, inhibit time, event timer) are given to the rules as one
value: the value in force over all of the stream's frames where that is one known value,
else unknown (a rule then skips the party rather than judge frames by a value that did
not hold for them).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from nmtcheck.processes.comm_values import UNKNOWN, Value, written_value
from nmtcheck.protocol import sdo
from nmtcheck.timeline.model import NodeModel
from nmtcheck.timeline.node_events import WriteTable

EPS = 1e-9
MPDO = (0xFE, 0xFF)


def _table(m: NodeModel, index: int, sub: int) -> WriteTable:
    """Where the node's confirmed writes of `index`:`sub` are kept: the COB-IDs of PDOs
    1-4 with the error-control objects (the timeline applies them), the rest apart."""
    return m.writes if sdo.is_config_index(index, sub) else m.pdo_writes


def _rows(m: NodeModel | None, index: int, sub: int) -> np.ndarray:
    if m is None:
        return np.zeros(0, np.int64)
    w = _table(m, index, sub)
    if not len(w):
        return np.zeros(0, np.int64)
    return np.flatnonzero((w.index == index) & (w.sub == sub))


def value_at(m: NodeModel | None, index: int, sub: int, file: Value, t: float) -> Value:
    """`index`:`sub` of the node at `t`: its last confirmed write while it holds, unknown
    after a reset ended it, else the file's value (§9.1.3)."""
    if m is None:
        return file
    return written_value(_table(m, index, sub), m.node, index, sub, t, file)


def changes(m: NodeModel | None, index: int, subs: range | tuple[int, ...]) -> np.ndarray:
    """The moments the objects' values in force may change: each write's confirmation
    and the reset that ends it, sorted."""
    if m is None:
        return np.zeros(0)
    out = []
    for sub in subs:
        rows = _rows(m, index, sub)
        if rows.size:
            w = _table(m, index, sub)
            out += [w.ts[rows], w.until[rows][np.isfinite(w.until[rows])]]
    return np.unique(np.concatenate(out)) if out else np.zeros(0)


def pieces(m: NodeModel | None, index: int, sub: int, file: Value
           ) -> tuple[np.ndarray, list[Value]]:
    """`index`:`sub` over time: the moments it may change (the first is -inf) and the
    value in force from each on; `np.searchsorted(starts, t, "right") - 1` finds t's."""
    starts = np.concatenate([[-np.inf], changes(m, index, (sub,))])
    return starts, [value_at(m, index, sub, file, float(t) if np.isfinite(t) else -1e300)
                    for t in starts.tolist()]


def written(m: NodeModel | None, index: int, subs: range | tuple[int, ...]) -> bool:
    return any(_rows(m, index, sub).size for sub in subs)


def constant_over(m: NodeModel | None, index: int, sub: int, file: Value, a: float,
                  b: float) -> Value:
    """The one value in force over [a, b] (a stream's frames), else unknown."""
    if not written(m, index, (sub,)):
        return file
    points = changes(m, index, (sub,))
    found = [value_at(m, index, sub, file, p) for p in
             [a, *points[(points > a + EPS) & (points <= b + EPS)].tolist()]]
    if all(v.known for v in found) and len({v.value for v in found}) == 1:
        return found[-1]
    return UNKNOWN


@dataclass(frozen=True)
class MappingPieces:
    """A party's mapped length over time: from `start[i]` on, `length[i]` bytes (-1:
    unknown, 0: not judged: no entries or an MPDO) with where it came from."""

    start: np.ndarray
    length: np.ndarray
    source: list[Value]

    def at(self, ts: np.ndarray) -> np.ndarray:
        """The piece in force at each time (an index into `length`/`source`)."""
        out: np.ndarray = np.searchsorted(self.start, ts + EPS, side="right") - 1
        return out

    @property
    def known(self) -> bool:
        return bool((self.length > 0).any())


def mapping_pieces(m: NodeModel | None, map_index: int, entries: list[int] | None,
                   file: Value) -> MappingPieces:
    """The mapped length (bytes, ⌈Σ bits / 8⌉) in force from the start and after each
    change the trace makes to `map_index`; `entries` and `file` are the files' mapping
    (None: none given)."""
    subs = range(0x41)
    points = changes(m, map_index, subs)
    start = np.concatenate([[-np.inf], points])
    lengths, sources = [], []
    given = entries if entries is not None else []
    count_file = Value(len(given), file.source, file.node) if entries is not None else UNKNOWN
    for p in start.tolist():
        t = p if np.isfinite(p) else -1e300
        count = value_at(m, map_index, 0, count_file, t)
        if not count.known:
            lengths.append(-1)
            sources.append(UNKNOWN)
            continue
        n = int(count.value or 0)
        if n == 0 or n in MPDO:
            lengths.append(0)
            sources.append(count)
            continue
        parts = [value_at(m, map_index, k, Value(given[k - 1], file.source, file.node)
                          if k <= len(given) else UNKNOWN, t) for k in range(1, min(n, 64) + 1)]
        if not all(v.known for v in parts):
            lengths.append(-1)
            sources.append(UNKNOWN)
            continue
        bits = sum(int(v.value or 0) & 0xFF for v in parts)
        lengths.append(-(-bits // 8))
        sdo_parts = [v for v in [count, *parts] if v.source == "sdo"]
        sources.append(max(sdo_parts, key=lambda v: v.time or 0.0) if sdo_parts else count)
    return MappingPieces(start, np.asarray(lengths, np.int64), sources)


def valid_at(m: NodeModel | None, base_index: int, cob_id: int, ts: np.ndarray
             ) -> np.ndarray:
    """Per frame time: whether the party's COB-ID in force is not known to be another
    one or not valid (bit 31; the master clears it while it remaps, §9.1.3)."""
    if not written(m, base_index, (1,)):
        return np.ones(len(ts), bool)
    starts, values = pieces(m, base_index, 1, UNKNOWN)
    ok = [not v.known or (not int(v.value or 0) & 0x80000000
                          and int(v.value or 0) & 0x7FF == cob_id) for v in values]
    result: np.ndarray = np.asarray(ok, bool)[np.searchsorted(starts, ts + EPS, side="right") - 1]
    return result


def written_cob_ids(m: NodeModel, kind: str) -> dict[int, set[int]]:
    """Per PDO number k: the valid 11-bit COB-IDs the trace writes to the node's
    1400h/1800h + k - 1 sub 1 (bit 31 clear, bit 29 clear)."""
    base = 0x1800 if kind == "tpdo" else 0x1400
    out: dict[int, set[int]] = {}
    for table in (m.writes, m.pdo_writes):
        if not len(table):
            continue
        sel = np.flatnonzero((table.sub == 1) & (table.index >= base)
                             & (table.index <= base + 0x1FF))
        for k in sel.tolist():
            value = int(table.value[k])
            if not value & 0xA0000000:
                out.setdefault(int(table.index[k]) - base + 1, set()).add(value & 0x7FF)
    return out
