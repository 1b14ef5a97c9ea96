"""Batches -> sparse NMT events, a compact store of node frames, and per-ID aggregates.

One streaming pass over the frame batches keeps:

* `nmt`: the frames on CAN-ID 000h (NMT commands, valid or not) as compact
  columns: a hostile log may hold nothing else.
* `emcy`: the EMCY frames (081h..0FFh) as compact columns grouped by node:
  context for the reports, and a node may send them as fast as the bus allows.
* `events`: the few other frames the NMT state model needs one by one: the SDOs
  that configure error control and PDOs.
* `ec`: the error-control traffic (701h..77Fh) as compact columns grouped by
  node: heartbeats are the one NMT stream as dense as a node's period.
* `store`: per frame a timestamp and line (to find "the first frame at or
  after a moment"), and for the frames that belong to a node but are not
  events (TPDO, RPDO, SDO response, EMCY) their node key and kind. These are
  checked vectorised against the finished timeline. Chunks go to a temporary
  directory once they pass a memory budget, so memory stays bounded.
* aggregates that need no timeline: restricted CAN-IDs (C001) and each
  node's first and last transmitted frame.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

import numpy as np

from nmtcheck.protocol import sdo
from nmtcheck.readers.frames import (
    EC_BASE,
    EMCY_BASE,
    MAX_NODE_ID,
    NMT_ID,
    RPDO_BASES,
    SDO_RX_BASE,
    SDO_TX_BASE,
    STD_ID_MASK,
    STD_IDS,
    TPDO_BASES,
    FrameBatch,
    is_restricted_id,
    node_key,
)
from nmtcheck.spool import (
    ChunkStore,
    ColumnSpool,
)
from nmtcheck.timeline import ec_compact

KIND_TPDO = 1
KIND_RPDO = 2
KIND_SDO_TX = 3
KIND_EMCY = 4
KIND_EC = 5  # error-control data frame (only in first/last-seen bookkeeping)
KIND_CONFIGURED = 6  # on a configured (non-default) PDO COB-ID: attributed by checks/state.py
KIND_NAMES = {KIND_TPDO: "TPDO", KIND_RPDO: "RPDO", KIND_SDO_TX: "SDO response",
              KIND_EMCY: "EMCY", KIND_EC: "error-control"}

EVENT_DTYPE = np.dtype([
    ("ts", "f8"), ("idx", "i8"), ("line", "i8"), ("chan", "i4"), ("can_id", "u4"),
    ("rtr", "?"), ("dlc", "i2"), ("data", "u1", (8,)),
])

# the frames on 000h: command specifier and node-ID are data bytes 0 and 1 (33 bytes a frame)
NMT_COLUMNS: dict[str, type] = {
    "ts": np.float64, "idx": np.int64, "line": np.int64, "chan": np.int32, "rtr": np.bool_,
    "dlc": np.int16, "cs": np.uint8, "target": np.uint8}

# EMCY frames: the 8 data bytes packed in one integer (26 bytes a frame)
EMCY_COLUMNS: dict[str, type] = {
    "ts": np.float64, "idx": np.int64, "line": np.int64, "key": np.int32, "dlc": np.int16,
    "data": np.uint64}

# SYNC frames (SPEC §9.1.5): the counter is byte 0 when DLC = 1 (19 bytes a frame)
SYNC_COLUMNS: dict[str, type] = {
    "ts": np.float64, "idx": np.int64, "line": np.int64, "chan": np.int32, "rtr": np.bool_,
    "dlc": np.int16, "counter": np.uint8, "can_id": np.uint16}
# remote frames on an EMCY COB-ID (SPEC §9.1.7: malformed, E002): rare, kept apart
EMCY_RTR_COLUMNS: dict[str, type] = {
    "ts": np.float64, "idx": np.int64, "line": np.int64, "key": np.int32, "dlc": np.int16}
DEFAULT_SYNC_ID = 0x080
# LSS frames (SPEC §9.1.8): 7E5h requests, 7E4h responses, the 8 data bytes packed (27 bytes)
LSS_RESPONSE_ID, LSS_REQUEST_ID = 0x7E4, 0x7E5
LSS_COLUMNS: dict[str, type] = {
    "ts": np.float64, "idx": np.int64, "line": np.int64, "chan": np.int32, "dlc": np.int16,
    "can_id": np.uint16, "data": np.uint64}

EC_COLUMNS: dict[str, type] = {
    "ts": np.float64, "idx": np.int64, "line": np.int64, "key": np.int32, "rtr": np.bool_,
    "dlc": np.int16, "value": np.uint8}

class FirstTx(NamedTuple):
    """A node's first transmitted frame."""

    idx: int
    ts: float
    kind: int  # KIND_*


@dataclass
class NodeFrames:
    """Frames of the node-frame store as columns (`first_node_frame_after`'s answers)."""

    ts: np.ndarray
    idx: np.ndarray  # -1: no such frame
    line: np.ndarray
    kind: np.ndarray  # KIND_*

    @classmethod
    def none(cls, n: int) -> NodeFrames:
        return cls(np.full(n, np.nan), np.full(n, -1, np.int64), np.zeros(n, np.int64),
                   np.zeros(n, np.int8))

    def __len__(self) -> int:
        return len(self.idx)

    def take(self, rows: np.ndarray | slice) -> NodeFrames:
        return NodeFrames(self.ts[rows], self.idx[rows], self.line[rows], self.kind[rows])


class FrameAt(NamedTuple):
    """Where a frame is: its index in the input and its line (record number)."""

    idx: int
    line: int


@dataclass
class IdUse:
    """First use and count of one CAN-ID on one channel."""

    first_idx: int
    first_ts: float
    first_line: int
    count: int


@dataclass
class Decoded:
    """Everything later stages need from one input."""

    events: np.ndarray  # EVENT_DTYPE, file order: EMCY and SDO frames
    nmt: dict[str, np.ndarray]  # NMT_COLUMNS, file order: the frames on 000h
    emcy: dict[str, np.ndarray]  # EMCY_COLUMNS, sorted by node key, file order within a key
    ec: dict[str, np.ndarray]  # EC_COLUMNS, sorted by node key, file order within a key
    frame_times: ChunkStore  # per batch: ts, base index, lines (_lines), channels (_chans)
    node_frames: ChunkStore  # per batch: key, kind, can_id, ts, idx, dlc, line
    restricted: dict[tuple[int, int], IdUse] = field(default_factory=dict)
    # node key -> (frame index, ts, kind) of the node's first transmitted frame
    first_tx: dict[int, FirstTx] = field(default_factory=dict)
    last_tx: dict[int, float] = field(default_factory=dict)
    standard_frames: int = 0  # 11-bit data and remote frames: what CANopen decoding sees
    # per node key, the steady heartbeat runs dropped from `ec` (a long log only)
    ec_runs: dict[int, ec_compact.GapRuns] = field(default_factory=dict)
    ec_spool: ColumnSpool | None = None  # every error-control row, when `ec` is compacted
    # per node key, the steady guarding exchanges dropped from `ec` (a long log only)
    ec_guard_runs: dict[int, ec_compact.GuardRuns] = field(default_factory=dict)
    # SYNC_COLUMNS, file order: the frames on the SYNC COB-IDs (SPEC §9.1.5)
    sync: dict[str, np.ndarray] = field(
        default_factory=lambda: {n: np.zeros(0, t) for n, t in SYNC_COLUMNS.items()})
    # EMCY_RTR_COLUMNS, file order: remote frames on 081h..0FFh
    emcy_rtr: dict[str, np.ndarray] = field(
        default_factory=lambda: {n: np.zeros(0, t) for n, t in EMCY_RTR_COLUMNS.items()})
    # per channel code, the smallest intervals before an 8-byte frame (SPEC §9.1.6: d8)
    d8_candidates: dict[int, np.ndarray] = field(default_factory=dict)
    channels: int = 0  # channel codes seen
    pdo_frames: int = 0  # data frames on PDO CAN-IDs (pre-defined or configured)
    # LSS_COLUMNS, file order: the data frames on 7E4h and 7E5h (SPEC §9.1.8)
    lss: dict[str, np.ndarray] = field(
        default_factory=lambda: {n: np.zeros(0, t) for n, t in LSS_COLUMNS.items()})

    def d8(self, chan: int) -> float | None:
        """d8 of §9.1.6: the smallest interval before an 8-byte frame on the channel, when
        at least 3 such intervals lie within 5 % of it (a busy bus repeats its
        back-to-back spacing); None otherwise."""
        vals = self.d8_candidates.get(chan)
        if vals is None or len(vals) < 3:
            return None
        d8 = float(vals[0])
        return d8 if d8 > 0 and int(np.count_nonzero(vals <= d8 * 1.05)) >= 3 else None

    def times_before(self, idx: int, count: int) -> np.ndarray:
        """The times of up to `count` frames before frame `idx`, in file order (all
        channels: the caller knows the input has one)."""
        out: list[np.ndarray] = []
        for chunk in self.frame_times:
            base = int(chunk["base"][0])
            n = len(chunk["ts"])
            if base >= idx:
                break
            hi = min(idx - base, n)
            out.append(chunk["ts"][max(hi - count, 0):hi])
        joined = np.concatenate(out) if out else np.zeros(0)
        return joined[-count:]

    def ec_rows(self, key: int) -> slice:
        """The rows of `ec` that belong to one node key."""
        return key_rows(self.ec["key"], key, key)

    @property
    def last_event_ts(self) -> float | None:
        times = [float(a.max()) for a in (self.events["ts"], self.nmt["ts"], self.emcy["ts"],
                                          self.ec["ts"]) if len(a)]
        return max(times) if times else None

    def close(self) -> None:
        self.frame_times.close()
        self.node_frames.close()
        if self.ec_spool is not None:
            self.ec_spool.close()

    def restore_ec(self, keys: set[int]) -> None:
        """Every error-control row of these node keys back in `ec`, their runs gone."""
        if self.ec_spool is None or not keys:
            return
        self.ec, self.ec_runs, self.ec_guard_runs = ec_compact.restore(
            self.ec_spool, self.ec, self.ec_runs, self.ec_guard_runs, keys,
            ec_compact.SETTINGS.chunk)

    def drop_moments(self, drops: Sequence[tuple[Any, ...]]) -> dict[str, np.ndarray]:
        """Each logger drop record's moment (`InputStats.drops`: line, lost, frame, ts), as
        columns ts, idx, line, count: the frame its reader placed it at (BLF, CL2000), at
        the time the record gives (else that frame's), or else the first frame after its
        line (candump `DROPCOUNT`); one pass over the frame times for all of them. A
        record with no frame after it is left out."""
        lines = np.asarray([d[0] for d in drops], np.int64)
        counts = np.asarray([d[1] for d in drops], np.int64)
        given = np.asarray([d[2] if len(d) > 2 and d[2] is not None else -1 for d in drops],
                           np.int64)
        at = np.asarray([d[3] if len(d) > 3 and d[3] is not None else np.nan for d in drops],
                        np.float64)
        ts = np.full(len(lines), np.nan)
        idx = np.full(len(lines), -1, np.int64)
        placed = given >= 0
        todo = ~placed & (lines > 0)
        find = placed.copy()  # the reader's frames: that they exist, and their times
        if todo.any() or find.any():
            for chunk in self.frame_times:
                t = chunk["ts"]
                if not len(t) or not (todo.any() or find.any()):
                    continue
                base = int(chunk["base"][0])
                if todo.any():
                    fl = frame_time_lines(chunk)
                    pos = np.searchsorted(fl, lines, side="right")
                    hit = todo & (pos < len(t))
                    ts[hit] = t[pos[hit]]
                    idx[hit] = base + pos[hit]
                    todo &= ~hit
                rel = given - base
                hit = find & (rel >= 0) & (rel < len(t))
                ts[hit] = t[rel[hit]]
                idx[hit] = given[hit]
                find &= ~hit
        ts = np.where(placed & ~np.isnan(at), at, ts)
        keep = idx >= 0
        return {"ts": ts[keep], "idx": idx[keep], "line": lines[keep], "count": counts[keep]}

    def first_frame_at_or_after(self, moments: list[float],
                                after: list[int | None] | None = None) -> list[FrameAt | None]:
        """(frame index, line) of the first frame whose time is >= each moment, and that
        comes after frame `after[i]` where one is given (the moment's evidence: where time
        goes back, the first such frame in file order can be in another capture)."""
        result: list[FrameAt | None] = [None] * len(moments)
        if not moments:
            return result
        after = after or [None] * len(moments)
        order = np.argsort(np.asarray(moments, np.float64), kind="stable")
        pending = list(order)
        for chunk in self.frame_times.reaching(min(moments)):
            if not pending:
                break
            ts = chunk["ts"]
            base = int(chunk["base"][0])
            runmax = np.maximum.accumulate(ts)  # tolerate timestamps that go backwards
            qs = np.asarray([moments[i] for i in pending], np.float64)
            pos = np.searchsorted(runmax, qs, side="left")
            still = []
            for q, p in zip(pending, pos.tolist(), strict=True):
                a = after[q]
                if a is not None and base + p <= a:  # time went back: look after frame a
                    start = max(a + 1 - base, 0)
                    hit = np.flatnonzero(ts[start:] >= moments[q])[:1]
                    p = start + int(hit[0]) if hit.size else len(ts)
                if p < len(ts):
                    result[q] = FrameAt(base + p, _line_at(chunk, p))
                else:
                    still.append(q)
            pending = still
        return result

    def last_frame(self, end: float) -> tuple[float, FrameAt] | None:
        """Time and place of the last frame in the file of the chunks that reach `end` (the
        input's last time: earlier chunks are not read back); None if there is none."""
        last: dict[str, np.ndarray] | None = None
        for chunk in self.frame_times.reaching(end):
            if len(chunk["ts"]):
                last = chunk
        if last is None:
            return None
        n = len(last["ts"])
        return float(last["ts"][-1]), FrameAt(int(last["base"][0]) + n - 1,
                                               int(frame_time_lines(last)[-1]))

    def first_frame_after_line(self, line: int) -> tuple[float, int] | None:
        """(time, index) of the first frame after record `line`; the last frame if none
        follows, None without frames."""
        prev: tuple[float, int] | None = None
        for chunk in self.frame_times:
            ts = chunk["ts"]
            if not len(ts):
                continue
            after = np.flatnonzero(frame_time_lines(chunk) > line)
            if after.size:
                k = int(after[0])
                return float(ts[k]), int(chunk["base"][0]) + k
            prev = (float(ts[-1]), int(chunk["base"][0]) + len(ts) - 1)
        return prev

    def first_node_frame_after(self, keys: np.ndarray, moments: np.ndarray,
                               after_idx: np.ndarray, kinds: tuple[int, ...] | None = None
                               ) -> NodeFrames:
        """For each query (node key, moment, frame index): the node's first transmitted
        non-event frame (TPDO, SDO response, EMCY; only `kinds` if given) at or after the
        moment and after that frame in the file, as columns (idx -1: none). A log may
        reset its nodes a million times, so queries and answers are arrays, never
        objects."""
        keys = np.asarray(keys, np.int64)
        moments = np.asarray(moments, np.float64)
        after_idx = np.asarray(after_idx, np.int64)
        found = NodeFrames.none(len(keys))
        if not len(keys) or not len(self.node_frames):
            return found
        wanted = np.unique(keys)
        earliest = float(moments.min())
        for chunk in self.node_frames.reaching(earliest):
            sent = (chunk["kind"] != KIND_RPDO) if kinds is None else np.isin(
                chunk["kind"], kinds)
            tx = np.flatnonzero(sent & (chunk["ts"] >= earliest)
                                & np.isin(chunk["key"], wanted))
            if not tx.size:
                continue
            key = chunk["key"][tx].astype(np.int64)
            ts = chunk["ts"][tx]
            idx = chunk["idx"][tx]
            order = np.lexsort((idx, ts, key))
            skey, sts, sidx = key[order], ts[order], idx[order]
            pos, hi = _first_at(skey, sts, keys, moments)
            hit = np.flatnonzero(pos < hi)
            # a frame earlier in the file than the query's own (timestamps out of order) is
            # no answer: step past it (rare, so one query at a time)
            for q in hit[sidx[pos[hit]] <= after_idx[hit]].tolist():
                p = int(pos[q])
                while p < hi[q] and sidx[p] <= after_idx[q]:
                    p += 1
                pos[q] = p
            hit = hit[pos[hit] < hi[hit]]
            rows = tx[order[pos[hit]]]
            better = (found.idx[hit] < 0) | (chunk["ts"][rows] < found.ts[hit])
            hit, rows = hit[better], rows[better]
            found.ts[hit] = chunk["ts"][rows]
            found.idx[hit] = chunk["idx"][rows]
            found.line[hit] = node_frame_lines(chunk, rows)
            found.kind[hit] = chunk["kind"][rows]
        return found


def _first_at(skey: np.ndarray, sts: np.ndarray, keys: np.ndarray, moments: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """Per query (key, moment): the first position among its key's rows of (skey, sts),
    sorted by key then time, whose time is >= the moment, and the end of its key's rows.
    One searchsorted per distinct key, over all that key's queries."""
    pos = np.zeros(len(keys), np.int64)
    end = np.zeros(len(keys), np.int64)
    by_key = np.argsort(keys, kind="stable")
    sorted_keys = keys[by_key]
    for k in np.unique(sorted_keys).tolist():
        qa, qb = np.searchsorted(sorted_keys, [k, k + 1])
        a, b = np.searchsorted(skey, [k, k + 1])
        q = by_key[qa:qb]
        pos[q] = a + np.searchsorted(sts[a:b], moments[q], side="left")
        end[q] = b
    return pos, end


def _node_of(can_id: np.ndarray, bases: Iterable[int]) -> tuple[np.ndarray, np.ndarray]:
    """Node-ID (1..127) and a match mask for IDs base+N of any of the bases."""
    node = np.zeros(can_id.shape, np.int64)
    mask = np.zeros(can_id.shape, bool)
    cid = can_id.astype(np.int64)
    for base in bases:
        m = (cid > base) & (cid <= base + MAX_NODE_ID)
        node = np.where(m, cid - base, node)
        mask |= m
    return node, mask


def _id_tables() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per 11-bit CAN-ID (index STD_IDS = 2048: any other ID): the frame kind (KIND_*, error
    control included), the node-ID, and whether CiA 301 reserves the ID. One gather per batch
    replaces a dozen range comparisons per frame."""
    ids = np.arange(STD_IDS + 1, dtype=np.uint32)
    kind = np.zeros(STD_IDS + 1, np.int8)
    node = np.zeros(STD_IDS + 1, np.int16)
    for k, bases in ((KIND_TPDO, TPDO_BASES), (KIND_RPDO, RPDO_BASES),
                     (KIND_SDO_TX, (SDO_TX_BASE,)), (KIND_EMCY, (EMCY_BASE,)),
                     (KIND_EC, (EC_BASE,))):
        n, m = _node_of(ids, bases)
        m[STD_IDS] = False
        kind[m] = k
        node[m] = n[m]
    restricted = is_restricted_id(ids)
    restricted[STD_IDS] = False
    return kind, node, restricted


_KIND_OF_ID, _NODE_OF_ID, _RESTRICTED_ID = _id_tables()
_ID_KEYS = 4096  # above any 11-bit CAN-ID: channel * _ID_KEYS + CAN-ID is one integer


_CONFIG_INDICES = np.array(sorted(sdo.CONFIG_OBJECTS))


def key_rows(keys: np.ndarray, lo: int, hi: int) -> slice:
    """The rows of a column sorted by node key whose key is in lo..hi."""
    return slice(int(np.searchsorted(keys, lo, side="left")),
                 int(np.searchsorted(keys, hi, side="right")))


def node_groups(cols: dict[str, np.ndarray]) -> dict[int, list[tuple[int, slice]]]:
    """Per channel code, each node's rows of columns grouped by node key (`ec`, `emcy`),
    found in one pass: a log may have tens of thousands of channels."""
    keys = cols["key"]
    if not len(keys):
        return {}
    uniq, first = np.unique(keys, return_index=True)
    bounds = np.append(first, len(keys)).tolist()
    out: dict[int, list[tuple[int, slice]]] = {}
    for g, key in enumerate(uniq.tolist()):
        out.setdefault(key // 128, []).append((key % 128, slice(bounds[g], bounds[g + 1])))
    return out


def sdo_events(cid: np.ndarray, b: FrameBatch) -> np.ndarray:
    """SDO downloads to the objects that configure error control and PDOs (1400h-1BFFh),
    their
    confirmations, and every SDO abort: sparse frames the timeline decodes one by one."""
    data_frame = ~b.rtr & (b.dlc >= 4)
    found = np.zeros(len(cid), bool)
    # SDO responses (581h..5FFh) and requests (601h..67Fh); 600h is no node's
    sdo = (data_frame & (cid >= SDO_TX_BASE + 1) & (cid <= SDO_RX_BASE + MAX_NODE_ID)
           & (cid != SDO_RX_BASE))
    rows = np.flatnonzero(sdo)
    if not rows.size:
        return found
    # Only the SDO frames' payloads are looked at (a few per thousand frames).
    data = b.data[rows]
    scid = cid[rows]
    index = data[:, 1].astype(np.int64) | (data[:, 2].astype(np.int64) << 8)
    config = np.isin(index, _CONFIG_INDICES) | ((index >= 0x1400) & (index <= 0x1BFF))
    cmd = data[:, 0]
    request = (scid >= SDO_RX_BASE + 1) & ((cmd & 0xE0) == 0x20) & config
    response = (scid <= SDO_TX_BASE + MAX_NODE_ID) & (((cmd == 0x60) & config) | (cmd == 0x80))
    found[rows[request | response]] = True
    return found


def _lines(line: np.ndarray) -> dict[str, np.ndarray]:
    """A batch's line numbers for the frame-time store: usually consecutive (text logs
    without junk lines) or all 0 (binary logs), then two numbers instead of a column."""
    first = line[:1].copy()
    if line.shape[0] and line[0] == 0 and not line.any():
        return {"line_first": first, "line_step": np.zeros(1, np.int64)}
    if line.shape[0] and bool((np.diff(line) == 1).all()):
        return {"line_first": first, "line_step": np.ones(1, np.int64)}
    return {"line": line}


def _chans(chan: np.ndarray) -> dict[str, np.ndarray]:
    """A batch's channel codes for the frame-time store: one number when the batch has
    one channel (a log of one channel always), else a column (q of §9.1.6 looks at one
    channel's frames)."""
    if chan.shape[0] and bool((chan == chan[0]).all()):
        return {"chan_one": chan[:1].copy()}
    return {"chan": chan.copy()}


def _node_lines(line: np.ndarray, idx: np.ndarray) -> dict[str, np.ndarray]:
    """Line numbers for the node-frame store: two numbers instead of a column when lines
    are all 0 (binary logs) or a constant offset from the frame index (text logs
    without junk lines)."""
    if line.shape[0] and not line.any():  # binary logs: no lines
        return {"line_off": np.zeros(1, np.int64), "line_step": np.zeros(1, np.int64)}
    off = line - idx
    if off.shape[0] and bool((off == off[0]).all()):
        return {"line_off": off[:1].copy(), "line_step": np.ones(1, np.int64)}
    return {"line": line}


def node_frame_lines(chunk: dict[str, np.ndarray], rows: np.ndarray) -> np.ndarray:
    """The line numbers of some rows of a node-frame chunk."""
    lines: np.ndarray = (chunk["line"][rows] if "line" in chunk else
                         chunk["idx"][rows] * chunk["line_step"][0] + chunk["line_off"][0])
    return lines


def frame_time_lines(chunk: dict[str, np.ndarray]) -> np.ndarray:
    """The line number of every frame of one `frame_times` chunk (see `_lines`)."""
    if "line" in chunk:
        return np.asarray(chunk["line"], np.int64)
    n = len(chunk["ts"])
    return int(chunk["line_first"][0]) + int(chunk["line_step"][0]) * np.arange(n, dtype=np.int64)


def _line_at(chunk: dict[str, np.ndarray], pos: int) -> int:
    if "line" in chunk:
        return int(chunk["line"][pos])
    return int(chunk["line_first"][0]) + int(chunk["line_step"][0]) * pos


def _first_last(keys: np.ndarray, rows: np.ndarray, kinds: np.ndarray, b: FrameBatch,
                first_tx: dict[int, FirstTx], last_tx: dict[int, float]) -> None:
    """Update each node key's first (index, ts, kind) and last ts from one batch's transmitted
    frames (`rows`, with their `keys`); ufunc.at instead of sorting. The keys index a dense
    table while it is small next to the batch; channel codes spread them (chan * 128 + N:
    200,000 channels reach 25.6 M), then the batch's distinct keys do."""
    size = int(keys.max()) + 1
    if size > 4 * keys.shape[0] + 4096:
        present, slot = np.unique(keys, return_inverse=True)
        size = present.shape[0]
    else:
        present, slot = None, keys
    pos = np.arange(keys.shape[0])
    last = np.full(size, -1)
    np.maximum.at(last, slot, pos)
    at = np.flatnonzero(last >= 0) if present is None else np.arange(size)
    key_of = at if present is None else present
    new = [j for j, k in enumerate(key_of.tolist()) if k not in first_tx]
    if new:
        first = np.full(size, keys.shape[0])
        np.minimum.at(first, slot, pos)
        for j in new:
            row = rows[first[at[j]]]
            first_tx[int(key_of[j])] = FirstTx(int(b.index[row]), float(b.ts[row]),
                                               int(kinds[row]))
    last_tx.update(zip(key_of.tolist(), b.ts[rows[last[at]]].tolist(), strict=True))


def _written_pdo_cob_ids(ev: np.ndarray) -> set[int]:
    """COB-IDs that SDO downloads in these events write to a PDO communication parameter."""
    cid = ev["can_id"].astype(np.int64)
    data = ev["data"]
    index = data[:, 1].astype(np.int64) | (data[:, 2].astype(np.int64) << 8)
    hit = ((cid >= SDO_RX_BASE + 1) & (cid <= SDO_RX_BASE + MAX_NODE_ID)
           & ((data[:, 0] & 0xE2) == 0x22) & (data[:, 3] == 1)
           & (((index >= 0x1400) & (index <= 0x1403)) | ((index >= 0x1800) & (index <= 0x1803))))
    cob = data[hit, 4].astype(np.int64) | (data[hit, 5].astype(np.int64) << 8)
    return {int(c) & STD_ID_MASK for c in cob.tolist()}


def decode(batches: Iterable[FrameBatch], pdo_cob_ids: Iterable[int] = (),
           protect_s: float = 0.0, sync_cob_ids: Iterable[int] = (DEFAULT_SYNC_ID,)
           ) -> Decoded:
    """Stream the batches once; keep only sparse events, the compact store and aggregates.

    `pdo_cob_ids`: configured PDO COB-IDs outside the pre-defined set (network file,
    EDS/DCF); COB-IDs written by SDO in the trace are added as they are seen.
    `protect_s`: a long log keeps every error-control frame at least this long after an
    NMT or SDO frame (a rule looks that far after a command: S004's obey time).
    `sync_cob_ids`: the CAN-IDs whose frames are kept as SYNC frames (SPEC §9.1.5: 080h
    unless the files configure another).
    """
    keep = np.zeros(STD_IDS + 1, bool)  # 11-bit IDs stored for later attribution
    for c in pdo_cob_ids:
        keep[c & STD_ID_MASK] = True
    is_sync = np.zeros(STD_IDS + 1, bool)
    for c in sync_cob_ids:
        is_sync[c & STD_ID_MASK] = True
    sync_spool = ColumnSpool(SYNC_COLUMNS)
    emcy_rtr_spool = ColumnSpool(EMCY_RTR_COLUMNS)
    lss_spool = ColumnSpool(LSS_COLUMNS)
    event_spool = ColumnSpool({"row": EVENT_DTYPE})  # SDO frames: rows of EVENT_DTYPE
    nmt_spool = ColumnSpool(NMT_COLUMNS)
    emcy_spool = ColumnSpool(EMCY_COLUMNS)
    ec_spool = ColumnSpool(EC_COLUMNS)
    bootups = ColumnSpool({"ts": np.float64, "idx": np.int64, "chan": np.int32})
    frame_times = ChunkStore()
    node_frames = ChunkStore()
    restricted: dict[tuple[int, int], IdUse] = {}
    d8 = _D8()
    pdo_frames = 0
    first_tx: dict[int, FirstTx] = {}
    last_tx: dict[int, float] = {}
    standard = 0

    for b in batches:
        # (copies of one-element slices: a view would keep the whole column alive)
        frame_times.append(ts=b.ts, base=b.index[:1].copy(), **_lines(b.line),
                           **_chans(b.chan))
        d8.add(b)
        co = ~b.ext & ~b.err
        standard += int(np.count_nonzero(co))
        cid = b.can_id.astype(np.int64)
        ec = co & (cid >= EC_BASE + 1) & (cid <= EC_BASE + MAX_NODE_ID)
        if ec.any():
            _spool_ec(b, cid, np.flatnonzero(ec), ec_spool, bootups)
        nmt = co & (cid == NMT_ID)
        if nmt.any():
            sel = np.flatnonzero(nmt)
            nmt_spool.append({"ts": b.ts[sel], "idx": b.index[sel], "line": b.line[sel],
                              "chan": b.chan[sel], "rtr": b.rtr[sel], "dlc": b.dlc[sel],
                              "cs": b.data[sel, 0], "target": b.data[sel, 1]})
        _spool_sync_emcy(b, cid, co, is_sync, sync_spool, emcy_spool, emcy_rtr_spool)
        _spool_lss(b, cid, co, lss_spool)
        ev_mask = co & sdo_events(cid, b)
        if ev_mask.any():
            sel = np.flatnonzero(ev_mask)
            ev = np.empty(sel.size, EVENT_DTYPE)
            ev["ts"] = b.ts[sel]
            ev["idx"] = b.index[sel]
            ev["line"] = b.line[sel]
            ev["chan"] = b.chan[sel]
            ev["can_id"] = b.can_id[sel]
            ev["rtr"] = b.rtr[sel]
            ev["dlc"] = b.dlc[sel]
            ev["data"] = b.data[sel]
            event_spool.append({"row": ev})
            for c in _written_pdo_cob_ids(ev):
                keep[c] = True

        # Kind and node of every 11-bit data frame, by table lookup on the CAN-ID.
        id11 = np.minimum(b.can_id, STD_IDS)
        kinds = _KIND_OF_ID[id11]
        kinds[(kinds == 0) & keep[id11]] = KIND_CONFIGURED
        kinds[~(co & ~b.rtr)] = 0
        nodes = _NODE_OF_ID[id11]
        keys = node_key(b.chan.astype(np.int32), nodes)
        pdo_frames += int(np.count_nonzero((kinds == KIND_TPDO) | (kinds == KIND_RPDO)
                                           | (kinds == KIND_CONFIGURED)))
        sel = np.flatnonzero((kinds > 0) & (kinds != KIND_EC))
        if sel.size:  # in file order: the rules take the first offending frame of each run
            key = keys[sel]
            node_frames.append(
                key=key.astype(np.int16 if key.max() < 1 << 15 else np.int32), kind=kinds[sel],
                can_id=b.can_id[sel].astype(np.uint16), ts=b.ts[sel],
                idx=b.index[sel], dlc=b.dlc[sel].astype(np.uint8),
                **_node_lines(b.line[sel], b.index[sel]),
            )

        # Each node's first and last transmitted frame (anything but RPDOs, which others send).
        tx_sel = np.flatnonzero((kinds > 0) & (kinds != KIND_RPDO) & (kinds != KIND_CONFIGURED))
        if tx_sel.size:
            _first_last(keys[tx_sel], tx_sel, kinds, b, first_tx, last_tx)

        res = co & _RESTRICTED_ID[id11]
        if res.any():
            sel = np.flatnonzero(res)
            # one integer per (channel, CAN-ID) to count with np.unique
            chan_ids = b.chan[sel].astype(np.int64) * _ID_KEYS + cid[sel]
            uniq, first_pos, counts = np.unique(chan_ids, return_index=True, return_counts=True)
            for k, p, c in zip(uniq.tolist(), first_pos.tolist(), counts.tolist(), strict=True):
                chan_id = divmod(k, _ID_KEYS)
                use = restricted.get(chan_id)
                if use is None:
                    row = sel[p]
                    restricted[chan_id] = IdUse(int(b.index[row]), float(b.ts[row]),
                                            int(b.line[row]), int(c))
                else:
                    use.count += int(c)

    events = event_spool.column("row")
    event_spool.close()
    nmt_cols = {name: nmt_spool.column(name) for name in NMT_COLUMNS}
    nmt_spool.close()
    emcy_cols = _grouped(emcy_spool, EMCY_COLUMNS)
    emcy_spool.close()
    sync_cols = {name: sync_spool.column(name) for name in SYNC_COLUMNS}
    sync_spool.close()
    emcy_rtr_cols = {name: emcy_rtr_spool.column(name) for name in EMCY_RTR_COLUMNS}
    emcy_rtr_spool.close()
    lss_cols = {name: lss_spool.column(name) for name in LSS_COLUMNS}
    lss_spool.close()
    settings = ec_compact.SETTINGS
    if protect_s > settings.protect_s:
        settings = replace(settings, protect_s=protect_s)
    ec_runs: dict[int, ec_compact.GapRuns] = {}
    guard_runs: dict[int, ec_compact.GuardRuns] = {}
    kept_spool: ColumnSpool | None = None
    if len(ec_spool) > settings.above:  # a long log: steady runs as summaries
        boot_cols = {name: bootups.column(name) for name in ("ts", "idx", "chan")}
        ec_cols, ec_runs, guard_runs = ec_compact.compact(ec_spool, nmt_cols, events, settings,
                                                          boot_cols)
        kept_spool = ec_spool  # read again if a run turns out to matter (`restore`)
    else:
        ec_cols = _grouped(ec_spool, EC_COLUMNS)
        ec_spool.close()
    bootups.close()
    return Decoded(events, nmt_cols, emcy_cols, ec_cols, frame_times, node_frames, restricted,
                   first_tx, last_tx, standard, ec_runs, kept_spool, guard_runs, sync_cols,
                   emcy_rtr_cols, d8.best, d8.channels, pdo_frames, lss_cols)


class _D8:
    """Per channel, the `KEEP` smallest intervals between consecutive frames whose later
    frame has 8 data bytes (SPEC §9.1.6), kept batch by batch and vectorised over the
    channels (a log may have tens of thousands): d8 is the first of them."""

    KEEP = 16

    def __init__(self) -> None:
        self.last = np.full(0, np.nan)  # per channel code: its last frame's time so far
        self.top = np.full(0, np.inf)  # per channel code: the largest candidate kept
        self.chan = np.zeros(0, np.int64)  # the candidates: channel, interval
        self.iv = np.zeros(0)

    @property
    def channels(self) -> int:
        return len(self.last)

    def add(self, b: FrameBatch) -> None:
        keep = ~b.err
        if not keep.any():
            return
        chan, ts, dlc = b.chan[keep].astype(np.int64), b.ts[keep], b.dlc[keep]
        top = int(chan.max()) + 1
        if top > len(self.last):
            self.last = np.concatenate([self.last, np.full(top - len(self.last), np.nan)])
            self.top = np.concatenate([self.top, np.full(top - len(self.top), np.inf)])
        one = chan.min() == chan.max()
        if not one:
            order = np.argsort(chan, kind="stable")
            chan, ts, dlc = chan[order], ts[order], dlc[order]
        first = np.ones(len(chan), bool)
        first[1:] = chan[1:] != chan[:-1]
        prev = np.empty(len(ts))
        prev[1:] = ts[:-1]
        prev[first] = self.last[chan[first]]
        last = np.ones(len(chan), bool)
        last[:-1] = first[1:]
        self.last[chan[last]] = ts[last]
        iv = ts - prev
        # only what can still be among a channel's KEEP smallest (most frames, once a
        # channel has KEEP candidates: a compare, no sort)
        sel = (dlc == 8) & (iv >= 0) & (iv < self.top[chan])
        if not sel.any():
            return
        c, v = chan[sel], iv[sel]
        if one and len(v) > self.KEEP:  # one channel (most logs): a partition, no sort
            v = np.partition(v, self.KEEP - 1)[:self.KEEP]
            c = c[:self.KEEP]
        elif not one:
            c, v = self._smallest(c, v)
        self.chan = np.concatenate([self.chan, c])
        self.iv = np.concatenate([self.iv, v])
        if len(self.iv) > 4 * self.KEEP * max(top, 1):
            self.chan, self.iv = self._smallest(self.chan, self.iv)
            full = np.bincount(self.chan, minlength=len(self.top)) >= self.KEEP
            if full.any():  # the candidates are sorted by channel, then interval
                ends = np.cumsum(np.bincount(self.chan, minlength=len(self.top))) - 1
                self.top[full] = self.iv[ends[full]]

    def _smallest(self, chan: np.ndarray, iv: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The KEEP smallest candidates of each channel, by channel, then interval."""
        order = np.lexsort((iv, chan))
        c = chan[order]
        start = np.flatnonzero(np.concatenate([[True], c[1:] != c[:-1]]))
        rank = np.arange(len(c)) - np.repeat(start, np.diff(np.append(start, len(c))))
        order = order[rank < self.KEEP]
        return chan[order], iv[order]

    @property
    def best(self) -> dict[int, np.ndarray]:
        chan, iv = self._smallest(self.chan, self.iv)
        uniq, start = np.unique(chan, return_index=True)
        bounds = np.append(start, len(chan))
        return {int(c): iv[bounds[k]:bounds[k + 1]] for k, c in enumerate(uniq.tolist())}


def _spool_sync_emcy(b: FrameBatch, cid: np.ndarray, co: np.ndarray, is_sync: np.ndarray,
                     sync_spool: ColumnSpool, emcy_spool: ColumnSpool,
                     emcy_rtr_spool: ColumnSpool) -> None:
    """The batch's SYNC frames (`is_sync`: per 11-bit ID) and EMCY frames (remote ones
    apart) into their spools."""
    sync = co & is_sync[np.minimum(cid, STD_IDS)]
    if sync.any():
        sel = np.flatnonzero(sync)
        sync_spool.append({"ts": b.ts[sel], "idx": b.index[sel], "line": b.line[sel],
                           "chan": b.chan[sel], "rtr": b.rtr[sel], "dlc": b.dlc[sel],
                           "counter": b.data[sel, 0], "can_id": cid[sel]})
    emcy_any = co & (cid >= EMCY_BASE + 1) & (cid <= EMCY_BASE + MAX_NODE_ID)
    emcy_rtr = emcy_any & b.rtr
    if emcy_rtr.any():
        sel = np.flatnonzero(emcy_rtr)
        emcy_rtr_spool.append({
            "ts": b.ts[sel], "idx": b.index[sel], "line": b.line[sel],
            "key": node_key(b.chan[sel].astype(np.int32), cid[sel] - EMCY_BASE),
            "dlc": b.dlc[sel]})
    emcy = emcy_any & ~b.rtr
    if emcy.any():
        sel = np.flatnonzero(emcy)
        emcy_spool.append({
            "ts": b.ts[sel], "idx": b.index[sel], "line": b.line[sel],
            "key": node_key(b.chan[sel].astype(np.int32), cid[sel] - EMCY_BASE),
            "dlc": b.dlc[sel],
            "data": np.ascontiguousarray(b.data[sel]).view(np.uint64).ravel()})


def _spool_lss(b: FrameBatch, cid: np.ndarray, co: np.ndarray, spool: ColumnSpool) -> None:
    """The batch's LSS data frames (7E4h, 7E5h) into their spool."""
    lss = co & ~b.rtr & ((cid == LSS_REQUEST_ID) | (cid == LSS_RESPONSE_ID))
    if lss.any():
        sel = np.flatnonzero(lss)
        spool.append({"ts": b.ts[sel], "idx": b.index[sel], "line": b.line[sel],
                      "chan": b.chan[sel], "dlc": b.dlc[sel], "can_id": cid[sel],
                      "data": np.ascontiguousarray(b.data[sel]).view(np.uint64).ravel()})


def _spool_ec(b: FrameBatch, cid: np.ndarray, sel: np.ndarray, ec_spool: ColumnSpool,
              bootups: ColumnSpool) -> None:
    """The batch's error-control rows `sel` into the spool, and their boot-ups apart
    (sparse: a long log's compaction lets each divide every node's runs on its channel)."""
    rtr, dlc = b.rtr[sel], b.dlc[sel]
    value = np.where((dlc >= 1) & ~rtr, b.data[sel, 0], 0)
    ec_spool.append({
        "ts": b.ts[sel], "idx": b.index[sel], "line": b.line[sel],
        "key": node_key(b.chan[sel].astype(np.int32), cid[sel] - EC_BASE),
        "rtr": rtr, "dlc": dlc, "value": value})
    boot = sel[(value == 0) & (dlc == 1) & ~rtr]
    if boot.size:
        bootups.append({"ts": b.ts[boot], "idx": b.index[boot], "chan": b.chan[boot]})


def _grouped(spool: ColumnSpool, columns: dict[str, type]) -> dict[str, np.ndarray]:
    """Join spooled columns and group them by node key (stable, so file order within a
    node), one column at a time to keep the peak low."""
    cols = {"key": spool.column("key")}
    order = np.argsort(cols["key"], kind="stable")
    cols["key"] = cols["key"][order]
    for name in columns:
        if name != "key":
            cols[name] = spool.column(name)[order]
    return cols
