"""TEST ORACLE: the pre-columnar, object-per-frame implementation (afef50f), revised once
for the SPEC revision of 2026-11 (stale reports, the NMT master, heartbeat period in force;
H001, H002, N002, B001).

This is nmtcheck's timeline and rule catalogue as of commit afef50f, before fd98c85
turned each node's error-control frames (701h-77Fh) into numpy columns and vectorised
the timeline steps and the rules H002, H003, N002, G001, G003, G004, C003, C004, S004,
S005 and B001-B003. `tests/test_columnar_equivalence.py` checks that the current
package gives exactly what this object-per-frame code gives.

The code below is `git show afef50f:nmtcheck/decode.py`, `.../timeline.py` and the rule
modules `nmtcheck/checks/{bootup,canid,guarding,heartbeat,network,state}.py` of that
commit, copied verbatim but for their import blocks (merged into one, above); then
`runs`/`count_note` of checks/base.py, the rule table of checks/__init__.py and
engine.check_input (as `reference_check`, without the options the tests do not use).
decode.py is frozen too although fd98c85 left it alone: the frames' way into the
timeline is being reworked, and the oracle must not move with it. Reused from the
current package: the readers (`open_input`: both sides read the same frames), the frame
constants of `nmtcheck.frames`, EMCY/SDO texts (`nmtcheck.emcy`, `nmtcheck.sdo`),
`Param`/`Problem`/`Rule`/`rule`, `Finding`, profiles and network files.

SPEC revision (2026-11), written here independently of the package, simply, one object
per frame; every place is marked `# SPEC 2026-11`. The interpretations both sides follow:

A. TimelineParams gains obey_s (S004 obey_ms), master_window_s (profile `[timeline]
   master_window_ms`), reset_window_s (B002) and bootup_timeout_s (B001); `build` takes
   `masters` = channel name -> (node, source, detail) known from the files; ChannelModel
   gains `master` (node, source, detail) and `master_note`.
B. The master of a channel without a known one is inferred (`_infer_master`); broadcast
   commands are never applied to a channel's master, direct ones are.
C. Stale reports (`_intervals`): a heartbeat or guarding response at most obey_s after the
   latest command applied to N (file order) that reports N's state just before that
   command (the state before OFFLINE if it was OFFLINE) changes nothing on the timeline
   and is ignored by S004, S005, N002's state alternation and B001 (a).
D. The heartbeat period in force at t (`NodeModel.period_at`): 1017h in force if > 0,
   else the whole-trace median; H002 per pair, guarding classification, H001.
E. H001 gaps (`_heartbeat_timeouts`): start at a heartbeat, or at a confirmed non-zero
   1017h write when no gap runs; end at a heartbeat or boot-up, or without a finding at a
   reset or a 1017h = 0 write; the limit is fixed at the gap's start.
F. N002 intervals: also shorts within 20 % of each other and longs too.

If the current package changes behaviour on purpose, the test that compares against
this oracle must change (or be narrowed), and this file only with a new SPEC.
"""

from __future__ import annotations

import bisect
import os
import statistics
import tempfile
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from nmtcheck import emcy, sdo
from nmtcheck.checks.base import Param, Problem, Rule, rule
from nmtcheck.engine import Finding
from nmtcheck.frames import (
    EC_BASE,
    EMCY_BASE,
    RPDO_BASES,
    SDO_TX_BASE,
    TPDO_BASES,
    FrameBatch,
    is_restricted_id,
)
from nmtcheck.network import Network
from nmtcheck.profiles import Profile
from nmtcheck.readers import InputStats, open_input

# =================================================================================================
# afef50f:nmtcheck/checks/base.py (the two helpers the rules use)
# =================================================================================================


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


def count_note(n: int, what: str = "frames") -> str:
    return f" ({n} {what})" if n > 1 else ""


# =================================================================================================
# afef50f:nmtcheck/decode.py
# Batches -> sparse NMT events, a compact store of node frames, and per-ID aggregates.
# =================================================================================================


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

STORE_BUDGET_BYTES = 16 << 20  # per store; past it chunks go to a temporary directory


def node_key(chan: np.ndarray | int, node: np.ndarray | int) -> np.ndarray | int:
    """One integer per (channel, node-ID): channel * 128 + node."""
    return chan * 128 + node


class ChunkStore:
    """Append-only columnar chunks, kept in memory up to a budget, then on disk.

    A spilled chunk is one raw file per column (`ndarray.tofile`): no archive,
    no checksum, read back with `np.fromfile` at disk-cache speed.
    """

    def __init__(self, budget: int = STORE_BUDGET_BYTES) -> None:
        self._budget = budget
        self._in_memory = 0
        self._chunks: list[dict[str, np.ndarray] | dict[str, tuple[str, np.dtype, tuple]]] = []
        self._tmp: tempfile.TemporaryDirectory[str] | None = None

    @property
    def spilled(self) -> int:
        """How many chunks live on disk."""
        return sum(1 for c in self._chunks if isinstance(next(iter(c.values())), tuple))

    def append(self, **cols: np.ndarray) -> None:
        size = sum(a.nbytes for a in cols.values())
        if self._in_memory + size <= self._budget:
            self._chunks.append(cols)
            self._in_memory += size
            return
        if self._tmp is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="nmtcheck-")
        spilled: dict[str, tuple[str, np.dtype, tuple]] = {}
        for name, col in cols.items():
            path = os.path.join(self._tmp.name, f"chunk{len(self._chunks)}.{name}")
            np.ascontiguousarray(col).tofile(path)
            spilled[name] = (path, col.dtype, col.shape)
        self._chunks.append(spilled)

    def __iter__(self) -> Iterator[dict[str, np.ndarray]]:
        for chunk in self._chunks:
            yield {name: np.fromfile(col[0], col[1]).reshape(col[2])
                   if isinstance(col, tuple) else col for name, col in chunk.items()}

    def close(self) -> None:
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None
        self._chunks.clear()


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

    events: np.ndarray  # EVENT_DTYPE, file order
    frame_times: ChunkStore  # per batch: ts, base index, lines (see _lines)
    node_frames: ChunkStore  # per batch: key, kind, can_id, ts, idx, line
    restricted: dict[tuple[int, int], IdUse] = field(default_factory=dict)
    # node key -> (frame index, ts, kind) of the node's first transmitted frame
    first_tx: dict[int, tuple[int, float, int]] = field(default_factory=dict)
    last_tx: dict[int, float] = field(default_factory=dict)

    def close(self) -> None:
        self.frame_times.close()
        self.node_frames.close()

    def first_frame_at_or_after(self, moments: list[float]) -> list[tuple[int, int] | None]:
        """(frame index, line) of the first frame whose time is >= each moment."""
        result: list[tuple[int, int] | None] = [None] * len(moments)
        if not moments:
            return result
        order = np.argsort(np.asarray(moments, np.float64), kind="stable")
        pending = list(order)
        for chunk in self.frame_times:
            if not pending:
                break
            ts = chunk["ts"]
            runmax = np.maximum.accumulate(ts)  # tolerate timestamps that go backwards
            qs = np.asarray([moments[i] for i in pending], np.float64)
            pos = np.searchsorted(runmax, qs, side="left")
            still = []
            for q, p in zip(pending, pos, strict=True):
                if p < len(ts):
                    result[q] = (int(chunk["base"][0]) + int(p), _line_at(chunk, int(p)))
                else:
                    still.append(q)
            pending = still
        return result


    def first_node_frame_after(
        self, queries: list[tuple[int, float, int]]
    ) -> list[tuple[float, int, int, int] | None]:
        """For each (node key, moment, frame index): (ts, idx, line, kind) of the node's first
        transmitted non-event frame (TPDO, SDO response, EMCY) at or after the moment and
        after that frame in the file."""
        result: list[tuple[float, int, int, int] | None] = [None] * len(queries)
        if not queries:
            return result
        qkeys = np.asarray([q[0] for q in queries], np.int64)
        qts = np.asarray([q[1] for q in queries], np.float64)
        for chunk in self.node_frames:
            tx = np.flatnonzero(chunk["kind"] != KIND_RPDO)
            if not tx.size:
                continue
            key = chunk["key"][tx].astype(np.int64)
            ts = chunk["ts"][tx]
            idx = chunk["idx"][tx]
            order = np.lexsort((idx, ts, key))
            skey, sts, sidx = key[order], ts[order], idx[order]
            lo = np.searchsorted(skey, qkeys, side="left")
            hi = np.searchsorted(skey, qkeys, side="right")
            for q in np.flatnonzero(hi > lo):
                a, b = int(lo[q]), int(hi[q])
                p = a + int(np.searchsorted(sts[a:b], qts[q], side="left"))
                while p < b and sidx[p] <= queries[q][2]:
                    p += 1
                if p < b:
                    row = tx[order[p]]
                    cand = (float(chunk["ts"][row]), int(chunk["idx"][row]),
                            int(chunk["line"][row]), int(chunk["kind"][row]))
                    cur = result[q]
                    if cur is None or cand[0] < cur[0]:
                        result[q] = cand
        return result


def _node_of(can_id: np.ndarray, bases: Iterable[int]) -> tuple[np.ndarray, np.ndarray]:
    """Node-ID (1..127) and a match mask for IDs base+N of any of the bases."""
    node = np.zeros(can_id.shape, np.int64)
    mask = np.zeros(can_id.shape, bool)
    cid = can_id.astype(np.int64)
    for base in bases:
        m = (cid > base) & (cid <= base + 127)
        node = np.where(m, cid - base, node)
        mask |= m
    return node, mask


def _id_tables() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per 11-bit CAN-ID (index 2048: any other ID): the frame kind (KIND_*, error control
    included), the node-ID, and whether CiA 301 reserves the ID. One gather per batch
    replaces a dozen range comparisons per frame."""
    ids = np.arange(2049, dtype=np.uint32)
    kind = np.zeros(2049, np.int8)
    node = np.zeros(2049, np.int16)
    for k, bases in ((KIND_TPDO, TPDO_BASES), (KIND_RPDO, RPDO_BASES),
                     (KIND_SDO_TX, (SDO_TX_BASE,)), (KIND_EMCY, (EMCY_BASE,)),
                     (KIND_EC, (EC_BASE,))):
        n, m = _node_of(ids, bases)
        m[2048] = False
        kind[m] = k
        node[m] = n[m]
    restricted = is_restricted_id(ids)
    restricted[2048] = False
    return kind, node, restricted


_KIND_OF_ID, _NODE_OF_ID, _RESTRICTED_ID = _id_tables()


_CONFIG_INDICES = np.array([0x1016, 0x1017, 0x100C, 0x100D, 0x1400, 0x1401, 0x1402, 0x1403,
                            0x1800, 0x1801, 0x1802, 0x1803])


def node_events(cid: np.ndarray, b: FrameBatch) -> np.ndarray:
    """EMCYs, SDO downloads to the objects that configure error control and PDOs, their
    confirmations, and every SDO abort: sparse frames the timeline decodes one by one."""
    data_frame = ~b.rtr & (b.dlc >= 4)
    emcy = ~b.rtr & (cid >= 0x081) & (cid <= 0x0FF)
    sdo = data_frame & (cid >= 0x581) & (cid <= 0x67F) & (cid != 0x600)
    rows = np.flatnonzero(sdo)
    if not rows.size:
        return emcy
    # Only the SDO frames' payloads are looked at (a few per thousand frames).
    data = b.data[rows]
    scid = cid[rows]
    index = data[:, 1].astype(np.int64) | (data[:, 2].astype(np.int64) << 8)
    config = np.isin(index, _CONFIG_INDICES)
    cmd = data[:, 0]
    request = (scid >= 0x601) & ((cmd & 0xE0) == 0x20) & config
    response = (scid <= 0x5FF) & (((cmd == 0x60) & config) | (cmd == 0x80))
    emcy[rows[request | response]] = True
    return emcy


def _lines(line: np.ndarray) -> dict[str, np.ndarray]:
    """A batch's line numbers for the frame-time store: usually consecutive (text logs
    without junk lines) or all 0 (binary logs), then two numbers instead of a column."""
    first = line[:1].copy()
    if line.shape[0] and line[0] == 0 and not line.any():
        return {"line_first": first, "line_step": np.zeros(1, np.int64)}
    if line.shape[0] and bool((np.diff(line) == 1).all()):
        return {"line_first": first, "line_step": np.ones(1, np.int64)}
    return {"line": line}


def _line_at(chunk: dict[str, np.ndarray], pos: int) -> int:
    if "line" in chunk:
        return int(chunk["line"][pos])
    return int(chunk["line_first"][0]) + int(chunk["line_step"][0]) * pos


def _first_last(keys: np.ndarray, rows: np.ndarray, kinds: np.ndarray, b: FrameBatch,
                first_tx: dict[int, tuple[int, float, int]], last_tx: dict[int, float]) -> None:
    """Update each node key's first (index, ts, kind) and last ts from one batch's transmitted
    frames (`rows`, with their `keys`); ufunc.at instead of sorting."""
    size = int(keys.max()) + 1
    pos = np.arange(keys.shape[0])
    last = np.full(size, -1)
    np.maximum.at(last, keys, pos)
    present = np.flatnonzero(last >= 0)
    new = [k for k in present.tolist() if k not in first_tx]
    if new:
        first = np.full(size, keys.shape[0])
        np.minimum.at(first, keys, pos)
        for k in new:
            row = rows[first[k]]
            first_tx[k] = (int(b.index[row]), float(b.ts[row]), int(kinds[row]))
    for k, p in zip(present.tolist(), b.ts[rows[last[present]]].tolist(), strict=True):
        last_tx[k] = p


def _written_pdo_cob_ids(ev: np.ndarray) -> set[int]:
    """COB-IDs that SDO downloads in these events write to a PDO communication parameter."""
    cid = ev["can_id"].astype(np.int64)
    data = ev["data"]
    index = data[:, 1].astype(np.int64) | (data[:, 2].astype(np.int64) << 8)
    hit = ((cid >= 0x601) & (cid <= 0x67F) & ((data[:, 0] & 0xE2) == 0x22) & (data[:, 3] == 1)
           & (((index >= 0x1400) & (index <= 0x1403)) | ((index >= 0x1800) & (index <= 0x1803))))
    cob = data[hit, 4].astype(np.int64) | (data[hit, 5].astype(np.int64) << 8)
    return {int(c) & 0x7FF for c in cob.tolist()}


def decode(batches: Iterable[FrameBatch], pdo_cob_ids: Iterable[int] = ()) -> Decoded:
    """Stream the batches once; keep only sparse events, the compact store and aggregates.

    `pdo_cob_ids`: configured PDO COB-IDs outside the pre-defined set (network file,
    EDS/DCF); COB-IDs written by SDO in the trace are added as they are seen.
    """
    keep = np.zeros(2049, bool)  # 11-bit IDs stored for later attribution
    for c in pdo_cob_ids:
        keep[c & 0x7FF] = True
    event_parts: list[np.ndarray] = []
    frame_times = ChunkStore()
    node_frames = ChunkStore()
    restricted: dict[tuple[int, int], IdUse] = {}
    first_tx: dict[int, tuple[int, float, int]] = {}
    last_tx: dict[int, float] = {}

    for b in batches:
        # (copies of one-element slices: a view would keep the whole column alive)
        frame_times.append(ts=b.ts, base=b.index[:1].copy(), **_lines(b.line))
        co = ~b.ext & ~b.err
        cid = b.can_id.astype(np.int64)
        ec = co & (cid >= 0x701) & (cid <= 0x77F)
        ev_mask = co & ((cid == 0) | ec | node_events(cid, b))
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
            event_parts.append(ev)
            for c in _written_pdo_cob_ids(ev):
                keep[c] = True

        # Kind and node of every 11-bit data frame, by table lookup on the CAN-ID.
        id11 = np.minimum(b.can_id, 2048)
        kinds = _KIND_OF_ID[id11]
        kinds[(kinds == 0) & keep[id11]] = KIND_CONFIGURED
        kinds[~(co & ~b.rtr)] = 0
        nodes = _NODE_OF_ID[id11]
        keys = (b.chan.astype(np.int32) << 7) | nodes  # node key: channel * 128 + node
        sel = np.flatnonzero((kinds > 0) & (kinds != KIND_EC))
        if sel.size:  # in file order: the rules take the first offending frame of each run
            node_frames.append(
                key=keys[sel].astype(np.int32), kind=kinds[sel],
                can_id=b.can_id[sel].astype(np.uint16), ts=b.ts[sel],
                idx=b.index[sel], line=b.line[sel],
            )

        # Each node's first and last transmitted frame (anything but RPDOs, which others send).
        tx_sel = np.flatnonzero((kinds > 0) & (kinds != KIND_RPDO) & (kinds != KIND_CONFIGURED))
        if tx_sel.size:
            _first_last(keys[tx_sel], tx_sel, kinds, b, first_tx, last_tx)

        res = co & _RESTRICTED_ID[id11]
        if res.any():
            sel = np.flatnonzero(res)
            keys = b.chan[sel].astype(np.int64) * 4096 + cid[sel]
            uniq, first_pos, counts = np.unique(keys, return_index=True, return_counts=True)
            for k, p, c in zip(uniq.tolist(), first_pos.tolist(), counts.tolist(), strict=True):
                key = (k // 4096, k % 4096)
                use = restricted.get(key)
                if use is None:
                    row = sel[p]
                    restricted[key] = IdUse(int(b.index[row]), float(b.ts[row]),
                                            int(b.line[row]), int(c))
                else:
                    use.count += int(c)

    events = np.concatenate(event_parts) if event_parts else np.empty(0, EVENT_DTYPE)
    return Decoded(events, frame_times, node_frames, restricted, first_tx, last_tx)


# =================================================================================================
# afef50f:nmtcheck/timeline.py
# Sparse events -> per (channel, node) NMT state timeline (SPEC §2).
# =================================================================================================


UNKNOWN = "UNKNOWN"
INITIALISING = "INITIALISING"
PRE_OPERATIONAL = "PRE-OPERATIONAL"
OPERATIONAL = "OPERATIONAL"
STOPPED = "STOPPED"
OFFLINE = "OFFLINE"
STATES = (UNKNOWN, INITIALISING, PRE_OPERATIONAL, OPERATIONAL, STOPPED, OFFLINE)
STATE_INDEX = {s: i for i, s in enumerate(STATES)}

STATE_OF_CODE = {0x00: PRE_OPERATIONAL, 0x04: STOPPED, 0x05: OPERATIONAL, 0x7F: PRE_OPERATIONAL}
CODE_NAMES = {0x00: "boot-up", 0x04: "STOPPED", 0x05: "OPERATIONAL", 0x7F: "PRE-OPERATIONAL"}

CS_START, CS_STOP, CS_PREOP, CS_RESET_NODE, CS_RESET_COMM = 0x01, 0x02, 0x80, 0x81, 0x82
COMMAND_STATE = {CS_START: OPERATIONAL, CS_STOP: STOPPED, CS_PREOP: PRE_OPERATIONAL,
                 CS_RESET_NODE: INITIALISING, CS_RESET_COMM: INITIALISING}
COMMAND_NAMES = {CS_START: "start", CS_STOP: "stop", CS_PREOP: "enter pre-operational",
                 CS_RESET_NODE: "reset node", CS_RESET_COMM: "reset communication"}
RESETS = (CS_RESET_NODE, CS_RESET_COMM)
EPS = 1e-7  # timestamps are microseconds at best: ignore float noise in comparisons


def any_between(sorted_values: list[Any], lo: Any, hi: Any) -> bool:
    """Whether a sorted list holds a value v with lo < v < hi.

    Bisection, because rules ask this per heartbeat pair against every reset/command.
    """
    k = bisect.bisect_right(sorted_values, lo)
    return k < len(sorted_values) and sorted_values[k] < hi


def state_name(code: int) -> str:
    return CODE_NAMES.get(code, f"{code:02X}h")


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


@dataclass
class EcFrame:
    """A frame on 700h+N: a remote request, or a data frame with its classification."""

    ts: float
    idx: int
    line: int
    rtr: bool
    dlc: int
    value: int  # data byte 0
    kind: str = ""  # request | bootup | heartbeat | guard | malformed
    # SPEC 2026-11 (C): a report of the state from before the latest command, sent within
    # obey_s of it: not evidence (set by _intervals)
    stale: bool = False

    @property
    def code(self) -> int:
        return self.value & 0x7F

    @property
    def toggle(self) -> int:
        return self.value >> 7

    @property
    def reports_state(self) -> bool:
        return self.kind in ("bootup", "heartbeat", "guard")


@dataclass
class Timeout:
    """A heartbeat (H001) or guarding (G002) timeout: the node is OFFLINE from `moment`."""

    rule: str
    moment: float
    after_ts: float  # the frame the wait started from
    after_idx: int
    limit_s: float
    gap_s: float | None  # length of the gap if it closed, else None (trace ended it)
    requests: int = 1  # G002: unanswered requests in the run
    ended_by: float | None = None  # ts of the node's next frame (end of OFFLINE)


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


@dataclass
class NodeEvent:
    """Something a node said that is not a finding: EMCY, SDO abort, configuration write."""

    ts: float
    idx: int
    line: int
    kind: str  # emcy | sdo-abort | sdo-write | sdo-segmented
    text: str
    code: int | None = None


@dataclass
class Interval:
    start: float
    end: float
    state: str
    source: str


@dataclass
class NodeConfig:
    """What is known of a node's configuration (network file for now)."""

    heartbeat_ms: float | None = None
    consumer_timeout_ms: float | None = None
    consumer_node: int | None = None  # whose 1016h entry set consumer_timeout_ms, if known
    guard_time_ms: float | None = None
    life_time_factor: int | None = None
    tpdo_cob_ids: dict[int, int | None] = field(default_factory=dict)  # PDO 1..4 -> COB-ID
    rpdo_cob_ids: dict[int, int | None] = field(default_factory=dict)  # None: not valid
    expected: bool = False


@dataclass
class NodeModel:
    """Everything known about one node on one channel."""

    chan: int
    channel: str
    node: int
    config: NodeConfig
    ec: list[EcFrame] = field(default_factory=list)
    commands: list[Command] = field(default_factory=list)
    first_show_idx: int | None = None
    first_show_ts: float | None = None
    first_tx: tuple[int, float, int] | None = None  # idx, ts, kind of N's first frame
    last_seen: float | None = None
    period_s: float | None = None
    period_source: str = "none"  # configured | measured | none
    median_s: float | None = None  # SPEC 2026-11 (D): the whole-trace median interval
    timeouts: list[Timeout] = field(default_factory=list)
    intervals: list[Interval] = field(default_factory=list)
    writes: list[ConfigWrite] = field(default_factory=list)  # to N's own objects
    consumer_writes: list[ConfigWrite] = field(default_factory=list)  # 1016h entries naming N
    events: list[NodeEvent] = field(default_factory=list)

    def config_at(self, ts: float) -> NodeConfig:
        """The configuration in force at `ts`: files, then SDO writes confirmed before it."""
        active = [w for w in self.writes if w.ts <= ts < w.until]
        consumers = [w for w in self.consumer_writes if w.ts <= ts < w.until]
        if not active and not consumers:
            return self.config
        cfg = replace(self.config, tpdo_cob_ids=dict(self.config.tpdo_cob_ids),
                      rpdo_cob_ids=dict(self.config.rpdo_cob_ids))
        for w in active:
            if w.index == 0x1017:
                cfg.heartbeat_ms = float(w.value)  # 0 written by SDO: heartbeat disabled
            elif w.index == 0x100C:
                cfg.guard_time_ms = float(w.value) or None
            elif w.index == 0x100D:
                cfg.life_time_factor = w.value or None
            elif 0x1800 <= w.index <= 0x1803 or 0x1400 <= w.index <= 0x1403:
                table = cfg.tpdo_cob_ids if w.index >= 0x1800 else cfg.rpdo_cob_ids
                table[(w.index & 0x3) + 1] = None if w.value & 0x80000000 else w.value & 0x7FF
        for w in consumers:
            time_ms = float(w.value & 0xFFFF)
            if time_ms and (cfg.consumer_timeout_ms is None or time_ms < cfg.consumer_timeout_ms):
                cfg.consumer_timeout_ms, cfg.consumer_node = time_ms, w.node
        return cfg

    @property
    def key(self) -> int:
        return self.chan * 128 + self.node

    def heartbeat_pairs(self) -> list[tuple[EcFrame, EcFrame]]:
        """Consecutive heartbeats with no boot-up or reset command of the node between them:
        the intervals the period is measured from (SPEC §2) and H003 compares."""
        resets = [c.idx for c in self.commands if c.is_reset]  # commands are in file order
        pairs: list[tuple[EcFrame, EcFrame]] = []
        prev: EcFrame | None = None
        for f in self.ec:
            if f.kind == "bootup":
                prev = None
            elif f.kind == "heartbeat":
                if prev is not None and not any_between(resets, prev.idx, f.idx):
                    pairs.append((prev, f))
                prev = f
        return pairs

    @property
    def heartbeats(self) -> list[EcFrame]:
        return [f for f in self.ec if f.kind == "heartbeat"]

    @property
    def bootups(self) -> list[EcFrame]:
        return [f for f in self.ec if f.kind == "bootup"]

    @property
    def is_producer(self) -> bool:
        if self.config.heartbeat_ms is not None and self.config.heartbeat_ms > 0:
            return True
        if any(w.index == 0x1017 and w.value for w in self.writes):
            return True
        return len(self.heartbeats) >= 2

    def period_at(self, ts: float) -> float | None:
        """SPEC 2026-11 (D): the heartbeat period in force at `ts`: the producer time (1017h)
        in force if > 0 (SDO-written and confirmed, else from the files), else the
        whole-trace median; None if neither is known or it is not positive."""
        hb = self.config_at(ts).heartbeat_ms
        if hb is not None and hb > 0:
            return hb / 1000.0
        if self.median_s is not None and self.median_s > 0:
            return self.median_s
        return None

    def hb_timeout_s(self, timeout_factor: float, at: float) -> float | None:
        """The heartbeat timeout in force at `at`: the smallest non-zero consumer time in
        force, else factor x the period in force (SPEC 2026-11, D and E).

        None when there is none, or when 1017h = 0 written by SDO is in force (heartbeat
        disabled: N is no producer until a non-zero write or its next boot-up).
        """
        cfg = self.config_at(at)
        if cfg.heartbeat_ms == 0.0:
            return None
        if cfg.consumer_timeout_ms:
            return cfg.consumer_timeout_ms / 1000.0
        period = self.period_at(at)
        return timeout_factor * period if period else None

    def _starts(self) -> np.ndarray:
        """Interval start times, built once per timeline (lookups happen per frame)."""
        cached = self.__dict__.get("_starts_cache")
        if cached is None or cached[0] is not self.intervals or len(cached[1]) != len(
                self.intervals):
            cached = (self.intervals, np.asarray([iv.start for iv in self.intervals]))
            self.__dict__["_starts_cache"] = cached
        return cached[1]

    def state_at(self, ts: float) -> str:
        """State after the evidence of a frame at `ts` (intervals starting at ts included)."""
        return self.intervals[self.interval_index(ts)].state

    def interval_index(self, ts: float) -> int:
        return max(int(np.searchsorted(self._starts(), ts, side="right")) - 1, 0)

    @property
    def error_control(self) -> str:
        hb = any(f.kind == "heartbeat" for f in self.ec)
        guard = any(f.kind == "guard" for f in self.ec)
        return {(True, True): "both", (True, False): "heartbeat", (False, True): "guarding"}.get(
            (hb, guard), "none")


@dataclass
class TimelineParams:
    timeout_factor: float = 1.5
    early_factor: float = 0.5
    response_timeout_s: float = 1.0
    # SPEC 2026-11 (A)
    obey_s: float = 0.1  # S004 obey_ms: reports this soon after a command may be stale
    master_window_s: float = 1.0  # [timeline] master_window_ms: master boot-up -> broadcast
    reset_window_s: float = 10.0  # B002 reset_window_ms
    bootup_timeout_s: float = 5.0  # B001 bootup_timeout_ms


@dataclass
class ChannelModel:
    chan: int
    name: str
    nmt: list[NmtFrame]
    nodes: dict[int, NodeModel]
    # SPEC 2026-11 (A): (node, source network|device-file|inferred, detail), or None
    master: tuple[int, str, str] | None = None
    master_note: str = ""  # why none was inferred


@dataclass
class InputModel:
    """The decoded input with its per-node models."""

    decoded: Decoded
    start: float
    end: float
    channels: list[ChannelModel]
    params: dict[str, dict[str, Any]] = field(default_factory=dict)  # every rule's parameters
    expected: list[tuple[int, str | None]] = field(default_factory=list)  # network file nodes


def _nmt_problem(rtr: bool, dlc: int, cs: int, target: int) -> str | None:
    if rtr:
        return "remote frame on CAN-ID 000h (NMT commands are data frames)"
    if dlc != 2:
        return f"DLC {dlc} (an NMT command has DLC 2)"
    if cs not in COMMAND_STATE:
        return f"unknown command specifier {cs:02X}h"
    if target > 127:
        return f"node-ID {target} above 127"
    return None


def build(decoded: Decoded, channels: list[str], start: float, end: float,
          params: TimelineParams, configs: dict[tuple[str | None, int], NodeConfig],
          masters: dict[str, tuple[int, str, str]] | None = None) -> InputModel:
    """Build every node's model and timeline from the decoded input.

    SPEC 2026-11 (A): `masters` = channel name -> (node, source, detail) of the NMT master
    known from the network file or the device files; other channels' masters are inferred.
    """
    ev = decoded.events
    models: list[ChannelModel] = []
    timeouts_to_end: list[tuple[NodeModel, Timeout]] = []
    for chan, name in enumerate(channels):
        rows = ev[ev["chan"] == chan]
        nmt: list[NmtFrame] = []
        nodes: dict[int, NodeModel] = {}

        def node_model(n: int, name: str = name, chan: int = chan,
                       nodes: dict[int, NodeModel] = nodes) -> NodeModel:
            m = nodes.get(n)
            if m is None:
                cfg = configs.get((name, n)) or configs.get((None, n)) or NodeConfig()
                m = nodes[n] = NodeModel(chan, name, n, cfg)
            return m

        # Nodes that transmitted anything (TPDO, SDO, EMCY, error control) exist from their
        # first frame.
        for key, first in decoded.first_tx.items():
            if key // 128 == chan and 1 <= key % 128 <= 127:
                m = node_model(key % 128)
                m.first_tx = first
                m.first_show_idx, m.first_show_ts = first[0], first[1]
                m.last_seen = decoded.last_tx.get(key)
        requests_only: dict[int, list[EcFrame]] = {}
        sdo_rows: list[tuple[float, int, int, int, int, list[int]]] = []
        for r in rows.tolist():
            ts, idx, line, _chan, can_id, rtr, dlc, data = r
            data = [int(x) for x in data]  # plain ints: numpy uint8 would overflow on shifts
            if 0x081 <= can_id <= 0x0FF:
                code, text = emcy.describe(data, dlc)
                node_model(can_id - 0x080).events.append(
                    NodeEvent(ts, idx, line, "emcy", text, code))
                continue
            if 0x581 <= can_id <= 0x67F:
                sdo_rows.append((ts, idx, line, can_id, dlc, data))
                continue
            if can_id == 0:
                cs, target = int(data[0]), int(data[1])
                frame = NmtFrame(ts, idx, line, rtr, dlc, cs, target,
                                 _nmt_problem(rtr, dlc, cs, target))
                nmt.append(frame)
                if frame.problem is None and target != 0:
                    m = node_model(target)
                    if m.first_show_idx is None or idx < m.first_show_idx:
                        m.first_show_idx, m.first_show_ts = idx, ts
                continue
            n = can_id - 0x700
            f = EcFrame(ts, idx, line, rtr, dlc, int(data[0]) if dlc >= 1 and not rtr else 0)
            if rtr:
                f.kind = "request"
                if n in nodes:
                    nodes[n].ec.append(f)
                else:
                    requests_only.setdefault(n, []).append(f)
            else:
                node_model(n).ec.append(f)
        for n, reqs in requests_only.items():
            if n in nodes:  # node showed up through other traffic: keep its requests, in order
                nodes[n].ec = sorted(nodes[n].ec + reqs, key=lambda f: f.idx)
        # SPEC 2026-11 (B): the channel's NMT master, known or inferred.
        master: tuple[int, str, str] | None = None
        master_note = ""
        known = (masters or {}).get(name)
        if known is not None:
            master = (int(known[0]), str(known[1]), str(known[2]))
        else:
            master, master_note = _infer_master(nmt, nodes, params)
        # Commands per node, broadcasts only for nodes seen before the command and never to
        # the channel's master (it does not receive its own frames); direct ones always.
        for frame in nmt:
            if frame.problem is not None:
                continue
            for n, m in nodes.items():
                if frame.target == n or (
                    frame.target == 0 and m.first_show_idx is not None
                    and m.first_show_idx < frame.idx
                    and (master is None or n != master[0])
                ):
                    m.commands.append(Command(frame.ts, frame.idx, frame.line, frame.cs,
                                              frame.target == 0))
        _sdo_config(sdo_rows, nodes, node_model)
        # SPEC 2026-11 (D): the guarding classification needs the period in force, which
        # needs the written values' validity (until the next boot-up: boot-ups are known
        # after the first pass), which needs the whole-trace median of the first pass.
        for m in nodes.values():
            _classify(m, params, with_period=False)
        _write_validity(nodes)
        for m in nodes.values():
            _find_period(m)
            _classify(m, params, with_period=True)
            _find_period(m)
        for m in nodes.values():
            _heartbeat_timeouts(m, params, end)
            _guard_timeouts(m, params, end)
            for t in m.timeouts:
                timeouts_to_end.append((m, t))
        models.append(ChannelModel(chan, name, nmt, dict(sorted(nodes.items())), master,
                                   master_note))

    _offline_ends(decoded, timeouts_to_end)
    for cm in models:
        for m in cm.nodes.values():
            m.intervals = _intervals(m, start, end, params.obey_s)
    return InputModel(decoded, start, end, models)


# SPEC 2026-11 (B): master inference ---------------------------------------------------------

def _reported_state(f: EcFrame) -> str | None:
    """The state a data frame on 700h+N reports: boot-up -> PRE-OPERATIONAL, else the
    byte's bits 0..6 (00h/7Fh -> PRE-OPERATIONAL, 04h, 05h); None for other codes."""
    if f.value == 0x00:
        return PRE_OPERATIONAL
    return STATE_OF_CODE.get(f.value & 0x7F)


def _infer_master(nmt: list[NmtFrame], nodes: dict[int, NodeModel], params: TimelineParams
                  ) -> tuple[tuple[int, str, str] | None, str]:
    """The one node that starts like an NMT master, or None and why not.

    For each valid broadcast F (file order): B = the channel's last boot-up before F, with
    no other valid NMT frame between B and F, and F at most master_window_s after B; B's
    node M qualifies if (2) no valid reset to 0 or M came within reset_window_s before B
    and (3) M's own frames show it did not obey F.
    """
    valid = [f for f in nmt if f.problem is None]
    # every node's error-control data frames (DLC 1, not remote), in file order
    frames = {n: [f for f in m.ec if not f.rtr and f.dlc == 1] for n, m in nodes.items()}
    bootups = sorted(((f, n) for n, fs in frames.items() for f in fs if f.value == 0x00),
                     key=lambda x: x[0].idx)
    qualify: dict[int, str] = {}
    prev_idx = -1  # the previous valid NMT frame
    for i, cmd in enumerate(valid):
        if cmd.target == 0:
            before = [x for x in bootups if x[0].idx < cmd.idx]
            for boot, node in reversed(before):  # beyond the SPEC (README): every one
                if not (boot.idx > prev_idx and cmd.ts - boot.ts <= params.master_window_s + EPS):
                    break
                if (node not in qualify
                        and not _answers_a_reset(valid, boot, node, params)
                        and _did_not_obey(frames[node], valid, i, node, params)):
                    qualify.setdefault(node, f"boot-up at {boot.ts:.6f}, then broadcast "
                                             f"{COMMAND_NAMES[cmd.cs]} at {cmd.ts:.6f} "
                                             f"not obeyed")
        prev_idx = cmd.idx
    if len(qualify) == 1:
        (node, why), = qualify.items()
        return (node, "inferred", why), ""
    if qualify:
        return None, "several nodes qualify: " + ", ".join(str(n) for n in sorted(qualify))
    return None, "no node qualifies"


def _answers_a_reset(valid: list[NmtFrame], boot: EcFrame, node: int,
                     params: TimelineParams) -> bool:
    """(2): a valid reset to 0 or `node` before the boot-up (file order), within
    reset_window_s of it."""
    return any(f.cs in RESETS and f.target in (0, node) and f.idx < boot.idx
               and f.ts >= boot.ts - params.reset_window_s - EPS for f in valid)


def _did_not_obey(frames: list[EcFrame], valid: list[NmtFrame], i: int, node: int,
                  params: TimelineParams) -> bool:
    """(3): `node`'s frames after broadcast valid[i] show it did not obey it."""
    cmd = valid[i]
    after = [f for f in frames if f.idx > cmd.idx]
    if cmd.cs in RESETS:
        # frames within obey_s may have been queued before the command: not counted
        rest = [f for f in after if f.value == 0x00 or f.ts - cmd.ts > params.obey_s + EPS]
        if not rest:
            return False
        first = rest[0]
        return first.value != 0x00 or first.ts - cmd.ts > params.bootup_timeout_s + EPS
    # start / stop / enter pre-operational: the state M reported last before the command
    before_state = None
    for f in reversed([f for f in frames if f.idx < cmd.idx]):
        before_state = _reported_state(f)
        if before_state is not None:
            break
    if before_state is None or before_state == COMMAND_STATE[cmd.cs]:
        return False
    next_cmd = next((f for f in valid[i + 1:] if f.target in (0, node)), None)
    boot = next((f for f in after if f.value == 0x00), None)  # beyond the SPEC (README)
    heartbeats = [f for f in after if f.value != 0x00
                  and f.ts > cmd.ts + params.obey_s + EPS
                  and (next_cmd is None or f.idx < next_cmd.idx)
                  and (boot is None or f.idx < boot.idx)]
    return bool(heartbeats) and _reported_state(heartbeats[0]) == before_state


def _sdo_config(rows: list[tuple[float, int, int, int, int, list[int]]],
                nodes: dict[int, NodeModel], node_model: Any) -> None:
    """Pair SDO requests with the server's answer: confirmed writes, aborts, segmented ones."""
    pending: dict[int, tuple[int, int, int | None, float]] = {}  # node -> index, sub, value, ts
    for ts, idx, line, can_id, dlc, data in rows:
        if dlc < 4:
            continue
        cmd, index, sub = data[0], data[1] | data[2] << 8, data[3]
        if can_id >= 0x601:  # request to server N
            n = can_id - 0x600
            if cmd & 0xE0 == 0x20 and sdo.is_config_index(index, sub):
                pending[n] = (index, sub, sdo.expedited_value(data), ts, idx)
            else:
                pending.pop(n, None)
            continue
        n = can_id - 0x580
        m = node_model(n)
        req = pending.get(n)
        matches = req is not None and req[:2] == (index, sub)
        if cmd == 0x80:
            code = int.from_bytes(bytes(data[4:8]), "little")
            what = f" to {sdo.object_name(index, sub)}" if matches else f" ({index:04X}h sub {sub})"
            m.events.append(NodeEvent(ts, idx, line, "sdo-abort",
                                      f"SDO abort{what}: {code:08X}h {sdo.abort_text(code)}",
                                      code))
            if matches:
                pending.pop(n, None)
        elif cmd == 0x60 and req is not None and matches:
            pending.pop(n, None)
            value = req[2]
            if value is None:
                m.events.append(NodeEvent(ts, idx, line, "sdo-segmented",
                                          f"segmented download to {sdo.object_name(index, sub)}"
                                          f" confirmed; its value is not applied"))
                continue
            m.writes.append(ConfigWrite(ts, idx, line, n, index, sub, value))
            m.writes[-1].request_idx = req[4]
            m.writes[-1].request_ts = req[3]
            m.events.append(NodeEvent(ts, idx, line, "sdo-write",
                                      f"{sdo.object_name(index, sub)} = {value} "
                                      f"({value:X}h) written by SDO"))


def _write_validity(nodes: dict[int, NodeModel]) -> None:
    """A written value holds until the node's next boot-up or reset; 1016h entries also
    count for the producer they name."""
    for m in nodes.values():
        ends = sorted([f.ts for f in m.ec if f.kind == "bootup"]
                      + [c.ts for c in m.commands if c.is_reset])
        for w in m.writes:
            w.until = next((t for t in ends if t > w.ts), float("inf"))
            if w.index == 0x1016:
                producer = nodes.get((w.value >> 16) & 0xFF)
                if producer is not None and producer is not m:
                    producer.consumer_writes.append(w)


def _classify(m: NodeModel, params: TimelineParams, with_period: bool) -> None:
    """Boot-up, heartbeat or guarding response for each data frame on 700h+N (SPEC §2).

    SPEC 2026-11 (D): "follows N's previous heartbeat by less than early_factor x period"
    uses the period in force at that previous heartbeat; the first pass (`with_period`
    False) uses none.
    """
    pending: EcFrame | None = None
    hb_since_boot = 0
    last_hb: EcFrame | None = None
    for f in m.ec:
        if f.rtr:
            pending = f
            continue
        if f.dlc != 1:
            f.kind = "malformed"
            continue
        if f.value == 0x00:
            # Always a boot-up, even with a request pending: a node in Initialisation does
            # not answer guarding, and reading it as a response would raise false G001/B001.
            f.kind = "bootup"
            hb_since_boot = 0
            last_hb = None
            pending = None
            continue
        answerable = (pending is not None
                      and f.ts - pending.ts <= params.response_timeout_s + EPS)
        is_guard = False
        if answerable:
            if hb_since_boot >= 2:
                period_s = m.period_at(last_hb.ts) if with_period and last_hb else None
                early = (period_s is not None and last_hb is not None
                         and f.ts - last_hb.ts < params.early_factor * period_s - EPS)
                is_guard = bool(f.value & 0x80) or early
            else:
                is_guard = True
        if is_guard:
            f.kind = "guard"
            pending = None
        else:
            f.kind = "heartbeat"
            hb_since_boot += 1
            last_hb = f


def _find_period(m: NodeModel) -> None:
    """Configured producer time, else the median heartbeat interval (no boot-up/reset inside).

    SPEC 2026-11 (D): the median is kept apart too (`median_s`): the period in force falls
    back to it where no non-zero 1017h is in force.
    """
    intervals = [b.ts - a.ts for a, b in m.heartbeat_pairs()]
    m.median_s = float(statistics.median(intervals)) if intervals else None
    if m.config.heartbeat_ms:
        m.period_s, m.period_source = m.config.heartbeat_ms / 1000.0, "configured"
        return
    if intervals:
        m.period_s, m.period_source = m.median_s, "measured"
    else:
        m.period_s, m.period_source = None, "none"


def _heartbeat_timeouts(m: NodeModel, params: TimelineParams, end: float) -> None:
    """H001, SPEC 2026-11 (E): each heartbeat gap that outlasts the timeout fixed at its start.

    Walk N's heartbeats, boot-ups, reset commands and confirmed 1017h writes in file order.
    A gap starts at a heartbeat, or at a non-zero 1017h write when no gap runs (a boot-up
    starts none). It ends at the next heartbeat (which starts the next one) or boot-up;
    a reset or a 1017h = 0 write ends it too, and a timeout that expired before them still
    counts. A non-zero write while a gap runs changes nothing. While a 1017h = 0 written
    by SDO is in force N is no producer (SPEC §3): its heartbeats start no gap then.
    """
    if not m.is_producer:
        return
    marks: list[tuple[int, float, str]] = []
    marks += [(f.idx, f.ts, f.kind) for f in m.ec if f.kind in ("heartbeat", "bootup")]
    marks += [(c.idx, c.ts, "reset") for c in m.commands if c.is_reset]
    marks += [(w.idx, w.ts, "write-on" if w.value else "write-off") for w in m.writes
              if w.index == 0x1017]
    marks.sort()
    gap: tuple[float, int, float | None] | None = None  # start ts, start idx, limit
    for idx, ts, what in marks:
        if what == "write-on":
            if gap is None:
                gap = (ts, idx, m.hb_timeout_s(params.timeout_factor, ts))
            continue
        if gap is not None:
            _gap_timeout(m, gap, ts, closed=True)
            gap = None
        if what == "heartbeat" and m.config_at(ts).heartbeat_ms != 0.0:
            at = ts
            for w in m.writes:  # beyond the SPEC (README)
                if w.index == 0x1017 and w.request_ts <= ts < w.ts:
                    at = w.ts
            gap = (ts, idx, m.hb_timeout_s(params.timeout_factor, at))
    if gap is not None:
        _gap_timeout(m, gap, end, closed=False)


def _gap_timeout(m: NodeModel, gap: tuple[float, int, float | None], until: float,
                 closed: bool) -> None:
    """Record an H001 timeout if the gap [start, until] outlasts its limit."""
    start, start_idx, limit = gap
    if limit and until - start > limit + EPS:
        m.timeouts.append(Timeout("H001", start + limit, start, start_idx, limit,
                                  until - start if closed else None))


def _guard_timeouts(m: NodeModel, params: TimelineParams, end: float) -> None:
    """G002: runs of remote requests to N that got no guarding response in time."""
    limit = params.response_timeout_s
    run: Timeout | None = None
    pending: EcFrame | None = None

    def close(request: EcFrame, next_request: float | None) -> None:
        nonlocal run
        deadline = request.ts + limit
        if next_request is None and deadline > end - EPS:
            return  # the trace ended before the answer was due
        moment = deadline if next_request is None else min(deadline, next_request)
        if run is None:
            run = Timeout("G002", moment, request.ts, request.idx, limit, None)
            m.timeouts.append(run)
        else:
            run.requests += 1

    for f in m.ec:
        if f.kind == "request":
            if pending is not None:
                close(pending, f.ts)
            pending = f
        elif f.kind == "guard":  # classification only accepts answers to a pending request
            pending = None
            run = None
        elif f.kind == "bootup" and pending is not None:
            # A request still within its wait when the node booted was lost to the restart,
            # which B001/B002 judge; one that had already timed out is a real G002.
            if f.ts - pending.ts > limit + EPS:
                close(pending, None)
            pending = None
            run = None
    if pending is not None:
        close(pending, None)


def _offline_ends(decoded: Decoded, items: list[tuple[NodeModel, Timeout]]) -> None:
    """Each timeout lasts until the node's next frame of any kind after its moment."""
    if not items:
        return
    found = decoded.first_node_frame_after([(m.key, t.moment, t.after_idx) for m, t in items])
    for (m, t), hit in zip(items, found, strict=True):
        best = hit[0] if hit is not None else None
        for f in m.ec:
            if f.kind != "request" and f.ts >= t.moment and f.idx > t.after_idx:
                if best is None or f.ts < best:
                    best = f.ts
                break
        t.ended_by = best


def _intervals(m: NodeModel, start: float, end: float, obey_s: float) -> list[Interval]:
    """Walk the node's evidence in order and cut the timeline into state intervals.

    SPEC 2026-11 (C): a heartbeat or guarding response at most `obey_s` after the latest
    command applied to N before it (file order) that reports the state N had just before
    that command (if N was OFFLINE then: the state before OFFLINE) is stale: marked, and
    treated like a frame that reports no state.
    """
    steps: list[tuple[float, int, int, str, object]] = []
    for f in m.ec:
        if f.kind != "request":
            steps.append((f.ts, f.idx, 1, "ec", f))
    for c in m.commands:
        steps.append((c.ts, c.idx, 1, "cmd", c))
    for t in m.timeouts:
        steps.append((t.moment, -1, 0, "timeout", t))
        if t.ended_by is not None:
            steps.append((t.ended_by, -1, 2, "back", t))
    steps.sort(key=lambda s: (s[0], s[2], s[1]))

    out: list[Interval] = [Interval(start, end, UNKNOWN, "start")]
    saved: tuple[str, str] | None = None  # state to return to after OFFLINE

    def go(ts: float, state: str, source: str) -> None:
        cur = out[-1]
        if cur.state == state:
            return
        if ts <= cur.start:  # the current interval would be empty: replace it
            out.pop()
            if out and out[-1].state == state:
                return
        out.append(Interval(max(ts, start), end, state, source))

    offline_until: float | None = None
    before_offline: str | None = None  # the state N had when it went OFFLINE
    before_command: dict[int, str | None] = {}  # command idx -> N's state just before it
    commands = sorted(m.commands, key=lambda c: c.idx)

    def stale(f: EcFrame, state: str) -> bool:
        latest = None
        for c in commands:
            if c.idx < f.idx:
                latest = c
        if latest is not None and any(g.kind == "bootup" and latest.idx < g.idx < f.idx
                                      for g in m.ec):
            return False  # beyond the SPEC (README)
        return (latest is not None and f.ts - latest.ts <= obey_s + EPS
                and before_command.get(latest.idx) == state)

    for ts, _idx, _order, what, obj in steps:
        cur = out[-1].state
        if what == "timeout":
            assert isinstance(obj, Timeout)
            if cur in (UNKNOWN, OFFLINE):
                continue
            saved = (cur, out[-1].source)
            before_offline = cur
            offline_until = obj.ended_by
            go(ts, OFFLINE, "timeout")
        elif what == "back":
            if cur == OFFLINE and saved is not None and offline_until == ts:
                go(ts, saved[0], saved[1])
                saved = None
        elif what == "cmd":
            assert isinstance(obj, Command)
            before_command[obj.idx] = before_offline if cur == OFFLINE else cur
            target = COMMAND_STATE[obj.cs]
            if cur == OFFLINE:
                saved = (target, "command")
            else:
                go(ts, target, "command")
        else:
            assert isinstance(obj, EcFrame)
            f = obj
            state = (STATE_OF_CODE[0x00] if f.kind == "bootup"
                     else STATE_OF_CODE.get(f.code) if f.reports_state else None)
            if state is not None and f.kind != "bootup" and stale(f, state):
                f.stale = True  # a boot-up is never stale
                continue  # beyond the SPEC (README) (the 'back' step ends OFFLINE)
            if state is not None:
                source = {"bootup": "bootup", "heartbeat": "heartbeat", "guard": "guarding"}[f.kind]
                go(ts, state, source)
                saved = None
            elif cur == OFFLINE and saved is not None:
                go(ts, saved[0], saved[1])
                saved = None
    for a, b in zip(out, out[1:], strict=False):
        a.end = b.start
    out[-1].end = max(end, out[-1].start)
    return out


# =================================================================================================
# afef50f:nmtcheck/checks/bootup.py
# Boot-up rules (B): the boot-up message 700h+N / 00h that ends every Initialisation.
# =================================================================================================


def _auto_window_s(m: NodeModel, value_ms: float) -> float:
    """A window given in ms, or 0 = 3 x the node's heartbeat period, at least 1 s."""
    if value_ms > 0:
        return value_ms / 1000.0
    return max(3 * (m.period_s or 0.0), 1.0)


@rule("B001", "missing-bootup", "error",
      Param("bootup_timeout_ms", float, "how long a reset node may take to send its boot-up"),
      Param("late_start_ms", float,
            "first heartbeat later than this after the trace start without a boot-up "
            "(0 = 3 x the node's heartbeat period, at least 1000 ms)"),
      exempt_from_unknown=True)
def missing_bootup(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """A node did not announce its (re)start with a boot-up message.

    **What it checks.** (a) After a reset-node or reset-communication command to
    N (direct or broadcast), N shows a sign of life (heartbeat, guarding
    response, TPDO, SDO response, EMCY) before its boot-up, or sends no boot-up
    within `bootup_timeout_ms` while the trace goes on. (b) N's first frame in
    the trace is a heartbeat that arrives more than `late_start_ms` after the
    trace's first frame: N came up during the recording without a boot-up.

    **Why it matters.** CiA 301 makes the boot-up the last act of Initialisation
    on every path (power-on, reset node, reset communication). Masters use it
    to start configuring the slave (CiA 302-2); a node that skips it is never
    configured, and a master cannot tell a reboot from a glitch.

    **Example.** `000#8103` (reset node 3) followed by `703#05` with no `703#00`
    in between.
    """
    timeout = p["bootup_timeout_ms"] / 1000.0
    nodes = [m for cm in model.channels for m in cm.nodes.values()]
    # One pass over the node-frame store answers every reset's "first frame after it".
    queries = [(m.key, c.ts, c.idx) for m in nodes for c in m.commands if c.is_reset]
    answers = iter(model.decoded.first_node_frame_after(queries))
    for cm in model.channels:
        for m in cm.nodes.values():
            resets = [c for c in m.commands if c.is_reset]
            bootups = m.bootups
            boot_idx = [b.idx for b in bootups]
            # SPEC 2026-11 (C): a stale report is no sign of life after the reset
            life = [f for f in m.ec if f.kind in ("heartbeat", "guard", "malformed")
                    and not f.stale]
            life_idx = [f.idx for f in life]
            for i, c in enumerate(resets):
                next_reset = resets[i + 1].idx if i + 1 < len(resets) else None
                k = bisect.bisect_right(boot_idx, c.idx)
                boot = bootups[k] if k < len(bootups) else None
                limit_idx = min(x for x in (boot.idx if boot else None, next_reset, 1 << 62)
                                if x is not None)
                k = bisect.bisect_right(life_idx, c.idx)
                sign = life[k] if k < len(life) and life[k].idx < limit_idx else None
                other = next(answers)
                if other is not None and other[1] < limit_idx and (sign is None
                                                                   or other[1] < sign.idx):
                    yield Problem(cm.name, m.node, other[0],
                                  f"{KIND_NAMES[other[3]]} from node {m.node} "
                                  f"{other[0] - c.ts:.3f} s after {c.name} without a boot-up",
                                  other[1], other[2])
                    continue
                if sign is not None:
                    yield Problem(cm.name, m.node, sign.ts,
                                  f"{sign.kind} from node {m.node} {sign.ts - c.ts:.3f} s after "
                                  f"{c.name} without a boot-up", sign.idx, sign.line)
                    continue
                if next_reset is not None and (boot is None or next_reset < boot.idx):
                    nr = resets[i + 1]
                    if nr.ts - c.ts <= timeout + EPS:
                        continue  # a newer reset restarts the wait
                if (boot is None or boot.ts - c.ts > timeout + EPS) and (
                        model.end > c.ts + timeout + EPS):
                    yield Problem(cm.name, m.node, c.ts + timeout,
                                  f"no boot-up from node {m.node} within {timeout:.3f} s "
                                  f"after {c.name}")
            # (b) the node was already running when it first appeared, without a boot-up
            if m.first_tx is not None and m.first_tx[2] == KIND_EC:
                first = next((f for f in m.ec if f.idx == m.first_tx[0]), None)
                late = _auto_window_s(m, p["late_start_ms"])
                if first is not None and first.kind == "heartbeat" and (
                        first.ts - model.start > late + EPS):
                    yield Problem(cm.name, m.node, first.ts,
                                  f"node {m.node} first appears {first.ts - model.start:.3f} s "
                                  f"into the trace with a heartbeat and no boot-up "
                                  f"(limit {late:.3f} s)", first.idx, first.line)


def _repeats(m: NodeModel, window: float) -> list[list[EcFrame]]:
    """Runs of 00h frames that follow each other within the window with no reset between."""
    runs: list[list[EcFrame]] = []
    prev: EcFrame | None = None
    resets = sorted(c.idx for c in m.commands if c.is_reset)
    for b in m.bootups:
        if prev is not None and b.ts - prev.ts <= window + EPS and not any_between(
                resets, prev.idx, b.idx):
            if runs and runs[-1][-1] is prev:
                runs[-1].append(b)
            else:
                runs.append([prev, b])
        prev = b
    return runs


@rule("B003", "bootup-repeated", "error",
      Param("repeat_window_ms", float,
            "a second 00h within this window is a repeat "
            "(0 = 3 x the node's heartbeat period, at least 1000 ms)"))
def bootup_repeated(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """A node keeps sending state 00h instead of announcing its boot-up once.

    **What it checks.** A second 00h frame from N follows the previous one within
    `repeat_window_ms` with no reset command to N in between. One finding per run.

    **Why it matters.** 00h is the boot-up message, sent once per Initialisation;
    it is never a periodic heartbeat state. A node that heartbeats 00h is stuck in
    (or pretends to be in) Initialisation, and every master re-starts its boot
    procedure on each one. canopen 2.4.1's LocalNode does exactly this after a
    received reset command.

    **Example.** `000#8102`, then `702#00` every 100 ms for the rest of the trace.
    """
    for cm in model.channels:
        for m in cm.nodes.values():
            for run in _repeats(m, _auto_window_s(m, p["repeat_window_ms"])):
                first = run[1]
                yield Problem(cm.name, m.node, first.ts,
                              f"node {m.node} sent boot-up (00h) {len(run)} times in a row "
                              f"over {run[-1].ts - run[0].ts:.3f} s without a reset command",
                              first.idx, first.line)


@rule("B002", "unexpected-bootup", "warning",
      Param("reset_window_ms", float, "how long a reset command explains a later boot-up"))
def unexpected_bootup(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """A node rebooted on its own: a boot-up no reset command explains.

    **What it checks.** N sends a boot-up after having sent other frames earlier in
    the trace, and no reset command to N (direct or broadcast) within the preceding
    `reset_window_ms` is still unanswered. Each reset explains one boot-up. Boot-ups
    that B003 counts as repeats are left to B003.

    **Why it matters.** This is how spontaneous reboots show up on the bus:
    watchdog resets, brown-outs, crashes. The node lost its configuration and its
    NMT state; the application on it restarted.

    **Example.** `703#05` every 100 ms, then `703#00` with no `000#8103` before it.
    """
    window = p["reset_window_ms"] / 1000.0
    repeat_ms = model.params.get("B003", {}).get("repeat_window_ms", 0.0)
    for cm in model.channels:
        for m in cm.nodes.values():
            repeated = {id(b) for run in _repeats(m, _auto_window_s(m, repeat_ms))
                        for b in run[1:]}
            resets = [c for c in m.commands if c.is_reset]
            unanswered: list[float] = []
            ri = 0
            for b in m.bootups:
                while ri < len(resets) and resets[ri].idx < b.idx:
                    unanswered.append(resets[ri].ts)
                    ri += 1
                unanswered = [t for t in unanswered if b.ts - t <= window + EPS]
                if unanswered:
                    unanswered.pop(0)
                    continue
                if id(b) in repeated:
                    continue
                if m.first_tx is not None and m.first_tx[0] < b.idx:
                    yield Problem(cm.name, m.node, b.ts,
                                  f"node {m.node} sent a boot-up with no reset command before it "
                                  f"(spontaneous reboot?)", b.idx, b.line)


# =================================================================================================
# afef50f:nmtcheck/checks/canid.py
# CAN-ID and frame-format rules (C): reserved IDs and malformed NMT / error-control frames.
# =================================================================================================


@rule("C001", "restricted-can-id", "error",
      Param("allow", list, "reserved CAN-IDs that legitimate CiA profiles use (LSS, flying "
                           "master, global fail-safe command)"),
      exempt_from_unknown=True)
def restricted_can_id(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """An 11-bit frame uses a CAN-ID that CiA 301 reserves.

    **What it checks.** Any 11-bit frame on 001h-07Fh, 101h-180h, 6E0h-6FFh or
    780h-7FFh (780h is 1920 decimal), except the IDs in `allow`. One finding per
    CAN-ID and channel, at its first use, with the number of frames.

    **Why it matters.** Table 40 reserves these IDs so that configurable COBs
    never collide with NMT, SYNC, LSS, SRDO or future services. A device using
    one is misconfigured and may collide with a device that uses it correctly.

    **Example.** `123#00` sits in the reserved 101h-180h range.
    """
    allow = {int(x) for x in p["allow"]}
    names = [cm.name for cm in model.channels]
    for (chan, can_id), use in sorted(model.decoded.restricted.items(),
                                      key=lambda kv: kv[1].first_idx):
        if can_id in allow or chan >= len(names):
            continue
        yield Problem(names[chan], None, use.first_ts,
                      f"CAN-ID {can_id:03X}h is reserved by CiA 301{count_note(use.count)}",
                      use.first_idx, use.first_line)


@rule("C002", "malformed-nmt-command", "error")
def malformed_nmt_command(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """A frame on CAN-ID 000h is not a valid NMT module-control command.

    **What it checks.** A frame on CAN-ID 0 is a remote frame, has DLC other than 2,
    an unknown command specifier, or a node-ID above 127. Such a frame is not
    applied to any node's state. A 2-byte frame (unknown command specifier) is
    attributed to the node its second byte names; frames of the wrong length or
    remote frames belong to the network (node null). Consecutive frames with the
    same defect for the same node (within one of its timeline intervals) give one
    finding with their count.

    **Why it matters.** Stacks disagree on such frames: CANopenNode drops any DLC
    other than 2, Lely accepts longer ones, python-canopen raises on shorter ones.
    Part of the network obeys, the rest does not.

    **Example.** `000#0105000000000000` (DLC 8).
    """
    def node_of(f: NmtFrame) -> int | None:
        # Only a 2-byte data frame has a node-ID byte; in a frame of the wrong length the
        # second byte addresses nobody, so the finding belongs to the network (node null).
        return f.target if 1 <= f.target <= 127 and not f.rtr and f.dlc == 2 else None

    for cm in model.channels:
        bad = [f for f in cm.nmt if f.problem is not None]

        def same_run(a: NmtFrame, b: NmtFrame, cm: ChannelModel = cm) -> bool:
            n = node_of(a)
            if a.problem != b.problem or n != node_of(b):
                return False
            m = cm.nodes.get(n) if n is not None else None
            return m is None or m.interval_index(a.ts) == m.interval_index(b.ts)

        for run in runs(bad, same_run):
            f = run[0]
            node = node_of(f)
            yield Problem(cm.name, node, f.ts,
                          f"malformed NMT frame: {f.problem}{count_note(len(run))}",
                          f.idx, f.line)


def _ec_runs(model: InputModel, bad: Any) -> Iterator[tuple[str, int, list[EcFrame]]]:
    """Runs of consecutive error-control frames of one node for which `bad` holds,
    each within one timeline interval."""
    for cm in model.channels:
        for m in cm.nodes.values():
            frames = [f for f in m.ec if f.kind != "request"]
            current: list[EcFrame] = []
            for f in frames:
                if current and (not bad(f) or m.interval_index(f.ts)
                                != m.interval_index(current[-1].ts)):
                    yield cm.name, m.node, current
                    current = []
                if bad(f):
                    current.append(f)
            if current:
                yield cm.name, m.node, current


@rule("C003", "malformed-error-control", "error", exempt_from_unknown=True)
def malformed_error_control(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """A frame on 701h-77Fh is not a valid boot-up, heartbeat or guarding response.

    **What it checks.** A data frame on 701h-77Fh has DLC other than 1, or is a
    heartbeat with bit 7 (reserved) set. Remote requests with DLC 0 or 1 are
    normal. Malformed frames are not used as state evidence.

    **Why it matters.** CANopenNode's consumer drops frames with DLC other than 1 and
    Lely's drops heartbeats with bit 7 set: those consumers see a heartbeat
    timeout although the producer is sending.

    **Example.** `703#0500` (DLC 2).
    """
    def bad(f: EcFrame) -> bool:
        return f.kind == "malformed" or (f.kind == "heartbeat" and bool(f.value & 0x80))

    for channel, node, run in _ec_runs(model, bad):
        f = run[0]
        why = (f"DLC {f.dlc} (must be 1)" if f.kind == "malformed"
               else f"heartbeat {f.value:02X}h has the reserved bit 7 set")
        yield Problem(channel, node, f.ts, f"malformed error-control frame from node {node}: "
                      f"{why}{count_note(len(run))}", f.idx, f.line)


@rule("C004", "unknown-nmt-state", "warning", exempt_from_unknown=True)
def unknown_nmt_state(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """A heartbeat or guarding response reports a state CiA 301 does not define.

    **What it checks.** The state (bits 0..6) of a heartbeat or guarding response is
    not 00h, 04h, 05h or 7Fh. The node's timeline keeps its previous state.

    **Why it matters.** Legacy DS301 v3 codes (01h-03h) and vendor codes (python
    canopen's 50h/60h) are not understood by CiA 301 consumers, which may treat
    the node as failed.

    **Example.** `703#02` (legacy "pre-operational" of DS301 v3).
    """
    def bad(f: EcFrame) -> bool:
        return f.kind in ("heartbeat", "guard") and f.code not in STATE_OF_CODE

    for channel, node, run in _ec_runs(model, bad):
        f = run[0]
        yield Problem(channel, node, f.ts, f"node {node} reports unknown NMT state "
                      f"{f.code:02X}h{count_note(len(run))}", f.idx, f.line)


# =================================================================================================
# afef50f:nmtcheck/checks/guarding.py
# Node-guarding rules (G): remote request on 700h+N, answer with toggle bit 7 (legacy).
# =================================================================================================


@rule("G001", "guard-toggle", "error")
def guard_toggle(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """A node-guarding response did not alternate its toggle bit.

    **What it checks.** A guarding response of N has the same toggle bit (bit 7) as
    N's previous response, or the first response after N's boot-up (or a reset
    command to N) has toggle bit 1.

    **Why it matters.** The master treats a response with an unchanged toggle as
    not received (CiA 301 §7.2.8.3.2.1): repeated, the master raises a node-guarding
    event and reacts as if the node were gone.

    **Example.** Responses `705#85`, `705#05`, `705#05`: the third repeats toggle 0.
    """
    for cm in model.channels:
        for m in cm.nodes.values():
            expected: int | None = None
            resets = sorted([c.idx for c in m.commands if c.is_reset])
            ri = 0
            bad: list[tuple[int, EcFrame, str]] = []  # (position, frame, why)
            n = 0
            for f in m.ec:
                while ri < len(resets) and resets[ri] < f.idx:
                    expected = 0
                    ri += 1
                if f.kind == "bootup":
                    expected = 0
                    n += 1  # a boot-up separates runs
                elif f.kind == "guard":
                    n += 1
                    if expected is not None and f.toggle != expected:
                        why = ("first response after boot-up/reset has toggle 1"
                               if expected == 0 and f.value & 0x80 and _first_after_reset(m.ec, f)
                               else f"toggle bit {f.toggle} repeats the previous response's")
                        bad.append((n, f, why))
                    expected = 1 - f.toggle
            # consecutive offending responses within one timeline interval: one finding
            def next_response(a: tuple[int, EcFrame, str], b: tuple[int, EcFrame, str],
                              m: NodeModel = m) -> bool:
                return b[0] == a[0] + 1 and m.interval_index(a[1].ts) == m.interval_index(b[1].ts)

            for run in runs(bad, next_response):
                _n, f, why = run[0]
                yield Problem(cm.name, m.node, f.ts,
                              f"guarding response {f.value:02X}h from node {m.node}: {why}"
                              f"{count_note(len(run), 'responses')}", f.idx, f.line)


def _first_after_reset(ec: list[EcFrame], f: EcFrame) -> bool:
    before = [g for g in ec if g.idx < f.idx and g.kind in ("guard", "bootup")]
    return not before or before[-1].kind == "bootup"


@rule("G002", "guard-no-response", "error",
      Param("response_timeout_ms", float, "how long a guarding request may wait for its answer"))
def guard_no_response(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """A node-guarding request went unanswered.

    **What it checks.** A remote request on 700h+N gets no response from N before the
    next request to N or within `response_timeout_ms`. Time = the next request or
    the request's time + `response_timeout_ms`, whichever is earlier. One finding
    per run of unanswered requests; N is OFFLINE from then until its next frame.

    **Why it matters.** This is the node-guarding event: the master assumes N lost
    and applies its error handling.

    **Example.** `705#R` every 100 ms with no `705#..` data frame in between.
    """
    for cm in model.channels:
        for m in cm.nodes.values():
            for t in m.timeouts:
                if t.rule == "G002":
                    n = f" ({t.requests} requests in a row)" if t.requests > 1 else ""
                    yield Problem(cm.name, m.node, t.moment,
                                  f"no guarding response from node {m.node} to the remote "
                                  f"request at {t.after_ts:.6f}{n}")


@rule("G003", "guard-interval-exceeded", "warning")
def guard_interval_exceeded(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """The master guarded a node less often than the node's life time allows.

    **What it checks.** Guard time (100Ch) and life time factor (100Dh) of N are
    known (network file, EDS/DCF, or written by SDO in the trace) and the interval
    between two guarding requests to N exceeds guard time x life time factor.

    **Why it matters.** N runs its life-guarding timer from the requests: past the
    node life time it raises a life-guarding event (EMCY 8130h, 1029h behaviour)
    although nothing is wrong with N. The master is too slow.

    **Example.** 100Ch = 100 ms, 100Dh = 3: requests 0.5 s apart exceed 0.3 s.
    """
    for cm in model.channels:
        for m in cm.nodes.values():
            resets = sorted([c.idx for c in m.commands if c.is_reset]
                            + [b.idx for b in m.bootups])
            reqs = [f for f in m.ec if f.kind == "request"]

            def life_s(at: float, m: NodeModel = m) -> float | None:
                """Node life time in force at `at` (files, or 100Ch/100Dh written by SDO)."""
                cfg = m.config_at(at)
                if not cfg.guard_time_ms or not cfg.life_time_factor:
                    return None
                return cfg.guard_time_ms * cfg.life_time_factor / 1000.0

            late = []
            for i, (a, b) in enumerate(zip(reqs, reqs[1:], strict=False)):
                life = life_s(a.ts)
                if (life is not None and b.ts - a.ts > life + EPS
                        and not any_between(resets, a.idx, b.idx)):
                    late.append((i, a, b))
            # consecutive late requests within one timeline interval: one finding
            def next_gap(x: tuple[int, EcFrame, EcFrame], y: tuple[int, EcFrame, EcFrame],
                         m: NodeModel = m) -> bool:
                return y[0] == x[0] + 1 and m.interval_index(x[2].ts) == m.interval_index(y[2].ts)

            for run in runs(late, next_gap):
                _i, a, b = run[0]
                cfg = m.config_at(a.ts)
                gt, ltf = cfg.guard_time_ms or 0.0, cfg.life_time_factor or 0
                yield Problem(cm.name, m.node, b.ts,
                              f"guarding requests to node {m.node} {b.ts - a.ts:.3f} s apart "
                              f"(node life time {gt * ltf / 1000.0:.3f} s = {gt:g} ms x {ltf})"
                              f"{count_note(len(run), 'requests')}", b.idx, b.line)


@rule("G004", "guarding-with-heartbeat", "warning")
def guarding_with_heartbeat(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """A node uses node guarding and heartbeat at the same time.

    **What it checks.** Since its last boot-up, N both answers node-guarding
    requests and produces heartbeats.

    **Why it matters.** CiA 301 does not allow both error-control methods at once:
    with 1017h non-zero the heartbeat protocol is used and guarding is off. Stacks
    disagree on which wins, so masters and consumers see different things.

    **Example.** `705#05` every 100 ms and `705#R` answered by `705#85`.
    """
    for cm in model.channels:
        for m in cm.nodes.values():
            seen_hb = seen_guard = False
            reported = False
            for f in m.ec:
                if f.kind == "bootup":
                    seen_hb = seen_guard = reported = False
                elif f.kind in ("heartbeat", "guard"):
                    seen_hb |= f.kind == "heartbeat"
                    seen_guard |= f.kind == "guard"
                    if seen_hb and seen_guard and not reported:
                        reported = True
                        yield Problem(cm.name, m.node, f.ts,
                                      f"node {m.node} answers node guarding and produces "
                                      f"heartbeats", f.idx, f.line)


# =================================================================================================
# afef50f:nmtcheck/checks/heartbeat.py
# Heartbeat rules (H): the periodic 700h+N / state frame of CiA 301 §7.2.8.3.2.2.
# =================================================================================================


@rule("H001", "heartbeat-timeout", "error",
      Param("timeout_factor", float,
            "timeout = factor x producer period when no consumer time is configured"))
def heartbeat_timeout(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """A heartbeat producer fell silent for longer than its consumers wait.

    **What it checks.** N produces heartbeats (two or more seen, or a producer time
    configured) and a gap after one of its heartbeats (or after a confirmed non-zero
    1017h write when no gap runs; a boot-up starts none) exceeds the timeout fixed at
    the gap's start: the consumer time in force (the smallest non-zero one for N),
    else `timeout_factor` x the period in force. The gap ends at N's next heartbeat or
    boot-up; a reset command to N or a 1017h = 0 write ends it, so only a timeout that
    expired before counts. The trace continuing past the
    timeout after N's last heartbeat counts too. One finding per gap, at the
    moment the timeout expired; the node is OFFLINE from then until its next frame.

    **Why it matters.** This is the heartbeat event of CiA 301: every consumer of
    N raises EMCY 8130h and applies its error behaviour (1029h), CiA 302 masters
    reset the node or stop the whole network.

    **Example.** `703#05` every 100 ms, then nothing for 0.4 s: with the median
    period 0.1 s and factor 1.5 the timeout expires 0.15 s after the last one.
    """
    for cm in model.channels:
        for m in cm.nodes.values():
            for t in m.timeouts:
                if t.rule != "H001":
                    continue
                if t.gap_s is None:
                    what = f"no heartbeat from node {m.node} for the rest of the trace"
                else:
                    what = f"no heartbeat from node {m.node} for {t.gap_s:.3f} s"
                cfg = m.config_at(t.after_ts)
                if cfg.consumer_timeout_ms:
                    whose = (f" of node {cfg.consumer_node}" if cfg.consumer_node is not None
                             else "")
                    limit = f"consumer time {t.limit_s:.3f} s{whose}"
                else:
                    limit = f"timeout {t.limit_s:.3f} s"
                yield Problem(cm.name, m.node, t.moment, f"{what} ({limit})")


@rule("H002", "heartbeat-too-early", "warning",
      Param("early_factor", float, "heartbeats closer than factor x period are too early"))
def heartbeat_too_early(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """Two heartbeats of a node come much closer together than its period.

    **What it checks.** Two consecutive heartbeats of N are closer than
    `early_factor` x N's heartbeat period in force at the first of them, except the
    first heartbeat after a boot-up, after an NMT command to N, or one that reports a
    different state
    (stacks may send one at once on a state change).

    **Why it matters.** A producer that sends too often wastes bus bandwidth and
    usually means a misconfigured 1017h, two devices sharing the node-ID, or a
    stack that re-triggers its timer.

    **Example.** Period 100 ms, heartbeats at 0.000, 0.020, 0.100 s.
    """
    factor = p["early_factor"]
    for cm in model.channels:
        for m in cm.nodes.values():
            # SPEC 2026-11 (D): each pair against the period in force at its first heartbeat
            cmd_idx = sorted([c.idx for c in m.commands]
                             + [w.request_idx for w in m.writes if w.index == 0x1017])
            early: list[tuple[EcFrame, EcFrame, float]] = []
            prev: EcFrame | None = None
            for f in m.ec:
                if f.kind == "bootup":
                    prev = None
                elif f.kind == "heartbeat":
                    if (prev is not None and f.code == prev.code
                            and not any_between(cmd_idx, prev.idx, f.idx)):
                        period = m.period_at(prev.ts)
                        if period is not None and f.ts - prev.ts < factor * period - EPS:
                            early.append((prev, f, period))
                    prev = f

            def chained(a: tuple[EcFrame, EcFrame, float], b: tuple[EcFrame, EcFrame, float],
                        m: NodeModel = m) -> bool:
                return a[1] is b[0] and m.interval_index(a[1].ts) == m.interval_index(b[1].ts)

            for run in runs(early, chained):
                prev_f, f, period = run[0]
                yield Problem(cm.name, m.node, f.ts,
                              f"heartbeat ({state_name(f.code)}) {f.ts - prev_f.ts:.3f} s after "
                              f"the previous one (period {period:.3f} s, limit "
                              f"{factor * period:.3f} s){count_note(len(run), 'heartbeats')}",
                              f.idx, f.line)


@rule("H003", "heartbeat-period-mismatch", "warning",
      Param("tolerance", float, "allowed relative difference of the median interval"))
def heartbeat_period_mismatch(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """A node's heartbeat period differs from its configured producer time.

    **What it checks.** N's producer time (1017h) is known (network file, EDS/DCF,
    or an SDO write of 1017h confirmed in the trace) and, over at least 5
    heartbeat intervals while that value holds, the median interval differs from
    it by more than `tolerance` (a fraction). Intervals containing a boot-up or a
    reset are left out. One finding per configured value, at the last heartbeat
    counted.

    **Why it matters.** Consumers are configured from the producer time: a node
    that ignores its 1017h (or whose DCF is stale) either floods the bus or trips
    its consumers' heartbeat timeouts under load.

    **Example.** 1017h = 100 ms written by the master at boot, heartbeats every
    500 ms afterwards.
    """
    tolerance = p["tolerance"]
    for cm in model.channels:
        for m in cm.nodes.values():
            by_value: dict[float, list[tuple[float, EcFrame]]] = {}
            for prev, f in m.heartbeat_pairs():
                value = m.config_at(prev.ts).heartbeat_ms
                if value:
                    by_value.setdefault(value, []).append((f.ts - prev.ts, f, prev))
            for value, items in by_value.items():
                if len(items) < 5:
                    continue
                median = statistics.median(d for d, *_ in items)
                configured = value / 1000.0
                if abs(median - configured) > tolerance * configured + EPS:
                    last = items[-1][1]
                    yield Problem(cm.name, m.node, last.ts,
                                  f"node {m.node} heartbeats every {median:.3f} s (median of "
                                  f"{len(items)} intervals) but its producer time is "
                                  f"{configured:.3f} s (tolerance {tolerance:.0%})",
                                  last.idx, last.line)
                    continue
                # beyond the SPEC (README): a run of >= 5 consecutive intervals off one way
                best = None
                for off in ([d > configured * (1 + tolerance) + EPS for d, *_ in items],
                            [d < configured * (1 - tolerance) - EPS for d, *_ in items]):
                    lo = None
                    for k, o in enumerate(off + [False]):
                        if o and lo is None:
                            lo = k
                        elif not o and lo is not None:
                            if k - lo >= 5 and (best is None or k - lo > best[1] - best[0]):
                                best = (lo, k)
                            lo = None
                if best is None:
                    continue
                lo, hi = best
                median = statistics.median(d for d, *_ in items[lo:hi])
                last = items[hi - 1][1]
                yield Problem(cm.name, m.node, last.ts,
                              f"node {m.node} heartbeats every {median:.3f} s (median of "
                              f"{hi - lo} consecutive intervals from "
                              f"{items[lo][2].ts - model.start:.3f} s) but its producer time is "
                              f"{configured:.3f} s (tolerance {tolerance:.0%})",
                              last.idx, last.line)


# =================================================================================================
# afef50f:nmtcheck/checks/network.py
# Network rules (N): the expected nodes and node-ID conflicts.
# =================================================================================================


@rule("N001", "missing-node", "error", exempt_from_unknown=True)
def missing_node(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """A node of the network description never transmitted.

    **What it checks.** A node listed in the network file (`--network`) never
    transmits on a channel it is expected on: every channel of the trace, unless
    its table names one. One finding per node and channel, at the trace's first
    frame.

    **Why it matters.** A missing node is the most basic integration failure:
    unpowered, wrong node-ID, wrong bit rate, or wiring.

    **Example.** `[nodes.8]` in the network file and no frame from node 8.
    """
    names = [cm.name for cm in model.channels]
    first = model.decoded.first_frame_at_or_after([model.start])[0] if model.expected else None
    line = first[1] if first is not None and first[0] == 0 else None  # frame 0's line
    for node, channel in model.expected:
        for name in [channel] if channel is not None else names:
            cm = next((c for c in model.channels if c.name == name), None)
            m = cm.nodes.get(node) if cm is not None else None
            if m is None or m.first_tx is None:
                yield Problem(name, node, model.start,
                              f"node {node} is in the network description but never transmits "
                              f"on {name}", 0, line)


def _segments(frames: list[EcFrame], cmd_idx: list[int]) -> Iterator[list[EcFrame]]:
    """Heartbeats split at boot-ups and NMT commands."""
    seg: list[EcFrame] = []
    marks = sorted(cmd_idx)
    for f in frames:
        if f.kind == "bootup" or (seg and any_between(marks, seg[-1].idx, f.idx)):
            if len(seg) > 1:
                yield seg
            seg = []
        if f.kind == "heartbeat":
            seg.append(f)
    if len(seg) > 1:
        yield seg


@rule("N002", "duplicate-node-id", "warning")
def duplicate_node_id(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """Two devices seem to share one node-ID.

    **What it checks.** Within N's heartbeats the reported state goes A, B, A, B with
    no NMT command to N or boot-up in between (stale reports left out), or over at least
    4 consecutive intervals N's heartbeat intervals alternate short/long with long >= 1.5
    x short, the shorts within 20 % of each other and the longs too.
    One finding per node, at the first evidence.

    **Why it matters.** Two devices with the same node-ID collide on every COB-ID of
    the pre-defined set: SDOs get two answers, PDOs mix, and the heartbeat shows
    whichever device spoke last.

    **Example.** `705#05`, `705#7F`, `705#05`, `705#7F` at 50 ms spacing.
    """
    for cm in model.channels:
        for m in cm.nodes.values():
            hit: tuple[EcFrame, str] | None = None
            for seg in _segments(m.ec, [c.idx for c in m.commands]):
                # SPEC 2026-11 (C): the state alternation ignores stale reports
                fresh = [f for f in seg if not f.stale]
                codes = [f.code for f in fresh]
                for i in range(len(fresh) - 3):
                    a, b = codes[i], codes[i + 1]
                    if a != b and codes[i + 2] == a and codes[i + 3] == b:
                        hit = hit or (fresh[i + 3], f"its heartbeat alternates between "
                                      f"{state_name(a)} and {state_name(b)}")
                        break
                seg = fresh  # beyond the SPEC (README)
                gaps = [y.ts - x.ts for x, y in zip(seg, seg[1:], strict=False)]
                for i in range(len(gaps) - 3):
                    w = gaps[i:i + 4]
                    if min(w) <= 0:
                        continue
                    steps = ["L" if w[k] >= 1.5 * w[k + 1] - EPS
                             else "S" if w[k + 1] >= 1.5 * w[k] - EPS
                             else "" for k in range(3)]
                    alt = all(steps) and steps[0] == steps[2] != steps[1]
                    # SPEC 2026-11 (F): the two shorts within 20 % of each other, the
                    # two longs too (a stalled fixed-rate producer's late + catch-up
                    # heartbeat is not two producers)
                    if alt:
                        pairs = (w[0], w[2]), (w[1], w[3])
                        alt = all(max(x) <= 1.2 * min(x) + EPS for x in pairs)
                    if alt:
                        f = seg[i + 4]
                        if hit is None or f.idx < hit[0].idx:
                            hit = (f, "its heartbeat intervals alternate short/long "
                                      f"({', '.join(f'{x:.3f}' for x in w)} s)")
                        break
            if hit is not None:
                f, why = hit
                yield Problem(cm.name, m.node, f.ts,
                              f"node-ID {m.node} may be used by two devices: {why}",
                              f.idx, f.line)


# =================================================================================================
# afef50f:nmtcheck/checks/state.py
# State and communication rules (S): what a node may send in which NMT state (Table 37).
# =================================================================================================


@dataclass
class _Run:
    """Offending frames of one node within one timeline interval."""

    ts: float
    idx: int
    line: int
    can_id: int
    kind: int
    count: int


@dataclass
class _PdoOverride:
    """Frames on `can_id` of channel `chan` within [start, until) belong to `key` as `kind`
    (kind 0: the default COB-ID of a PDO that was moved or made invalid: nobody's)."""

    chan: int
    can_id: int
    key: int
    kind: int
    start: float
    until: float


def _pdo_overrides(model: InputModel) -> list[_PdoOverride]:
    """Where configured PDO COB-IDs (network file, EDS/DCF, SDO writes) differ from the
    pre-defined connection set."""
    out: list[_PdoOverride] = []
    for cm in model.channels:
        for m in cm.nodes.values():
            for kind, table, bases, index in (
                    (KIND_TPDO, m.config.tpdo_cob_ids, TPDO_BASES, 0x1800),
                    (KIND_RPDO, m.config.rpdo_cob_ids, RPDO_BASES, 0x1400)):
                spans: list[tuple[int, int | None, float, float]] = [
                    (n, cob, -np.inf, np.inf) for n, cob in table.items()]
                for w in m.writes:  # SDO-written COB-IDs hold until the next boot-up/reset
                    if index <= w.index <= index + 3:
                        cob = None if w.value & 0x80000000 else w.value & 0x7FF
                        spans.append(((w.index & 3) + 1, cob, w.ts, w.until))
                for n, cob, start, until in spans:
                    default = bases[n - 1] + m.node
                    if cob != default:
                        out.append(_PdoOverride(m.chan, default, -1, 0, start, until))
                        if cob is not None:
                            out.append(_PdoOverride(m.chan, cob, m.key, kind, start, until))
    # later (SDO-written) spans are applied after the static ones and win
    out.sort(key=lambda o: o.start)
    return out


def _attribute(chunk: dict[str, np.ndarray], overrides: list[_PdoOverride]
               ) -> tuple[np.ndarray, np.ndarray]:
    """Each stored frame's (node key, kind), with the configured PDO COB-IDs applied."""
    if not overrides:
        return chunk["key"], chunk["kind"]
    key = chunk["key"].astype(np.int64).copy()
    kind = chunk["kind"].copy()
    chan = key // 128
    for o in overrides:
        hit = ((chunk["can_id"] == o.can_id) & (chan == o.chan) & (chunk["ts"] >= o.start)
               & (chunk["ts"] < o.until))
        if o.kind == 0:
            hit &= np.isin(kind, (KIND_TPDO, KIND_RPDO))
        key[hit] = o.key
        kind[hit] = o.kind
    return key, kind


def _scan(model: InputModel, kinds: tuple[int, ...], states: tuple[str, ...],
          grace_s: float, grace_from: str | None) -> list[tuple[NodeModel, int, _Run]]:
    """Frames of `kinds` sent while the node is in one of `states`.

    Frames at most `grace_s` after the node left `grace_from` are excused (S001);
    with `grace_from` None, frames at most `grace_s` after the node entered its
    current state (S003). Returning from OFFLINE to the state it had before is
    not a new entry.
    """
    by_key = {m.key: m for cm in model.channels for m in cm.nodes.values()}
    tables: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    offline = STATE_INDEX[OFFLINE]
    grace_code = STATE_INDEX[grace_from] if grace_from else -2
    for key, m in by_key.items():
        starts = np.asarray([iv.start for iv in m.intervals], np.float64)
        codes = np.asarray([STATE_INDEX[iv.state] for iv in m.intervals], np.int8)
        since = np.full(len(codes), -np.inf)  # when the grace period of each interval began
        for i in range(len(codes)):
            if grace_from is None:
                back = i >= 2 and codes[i - 1] == offline and codes[i - 2] == codes[i]
                since[i] = since[i - 2] if back else starts[i]
            elif i >= 1 and codes[i - 1] == grace_code:
                since[i] = starts[i]
            elif i >= 1 and codes[i - 1] != offline:
                since[i] = since[i - 1]  # e.g. OPERATIONAL -> STOPPED -> PRE-OPERATIONAL
        tables[key] = (starts, codes, since)
    wanted = np.asarray([STATE_INDEX[s] for s in states], np.int8)
    found: dict[tuple[int, int], _Run] = {}
    overrides = _pdo_overrides(model)
    for chunk in model.decoded.node_frames:
        chunk_key, chunk_kind = _attribute(chunk, overrides)
        sel = np.flatnonzero(np.isin(chunk_kind, kinds))
        if not sel.size:
            continue
        keys = chunk_key[sel]
        order = np.argsort(keys, kind="stable")
        sk = keys[order]
        bounds = np.flatnonzero(np.diff(sk)) + 1
        for part in np.split(order, bounds):
            key = int(keys[part[0]])
            table = tables.get(key)
            if table is None:
                continue
            starts, codes, since = table
            rows = sel[part]
            ts = chunk["ts"][rows]
            iv = np.maximum(np.searchsorted(starts, ts, side="right") - 1, 0)
            bad = np.isin(codes[iv], wanted)
            bad &= ~((ts - since[iv]) <= grace_s + EPS)
            for j in np.flatnonzero(bad):
                row = rows[j]
                k = (key, int(iv[j]))
                run = found.get(k)
                if run is None:
                    found[k] = _Run(float(chunk["ts"][row]), int(chunk["idx"][row]),
                                    int(chunk["line"][row]), int(chunk["can_id"][row]),
                                    int(chunk_kind[row]), 1)
                else:
                    run.count += 1
    return [(by_key[key], iv, run) for (key, iv), run in sorted(
        found.items(), key=lambda kv: kv[1].idx)]


@rule("S001", "pdo-while-not-operational", "error",
      Param("grace_ms", float, "PDOs this soon after leaving OPERATIONAL are still in flight"))
def pdo_while_not_operational(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """A node transmitted a PDO while not OPERATIONAL.

    **What it checks.** N transmits a TPDO (default COB-IDs 180h/280h/380h/480h + N)
    while its state is PRE-OPERATIONAL or STOPPED, unless N left OPERATIONAL at most
    `grace_ms` before (frames already queued). Consecutive offending PDOs within
    one timeline interval give one finding with their count.

    **Why it matters.** CiA 301 Table 37: PDOs exist only in OPERATIONAL. Process
    data sent before the master started the node (or after it stopped it) reaches
    consumers that were told the producer is not running: outputs move while
    the network is being configured or is meant to be halted.

    **Example.** `702#00` (boot-up), then `182#0102` before any `000#01..`.
    """
    yield from _pdo_problems(model, (KIND_TPDO,), p["grace_ms"] / 1000.0, OPERATIONAL, "sent")


@rule("S002", "pdo-to-not-operational", "info")
def pdo_to_not_operational(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """An RPDO was sent to a node that is not OPERATIONAL and will ignore it.

    **What it checks.** An RPDO of N (default 200h/300h/400h/500h + N) is on the bus
    while N is PRE-OPERATIONAL or STOPPED.

    **Why it matters.** N does not process PDOs outside OPERATIONAL (Table 37): the
    command in that PDO is lost. Usually the master started sending set-points
    before starting the node.

    **Example.** `203#0000` while node 3's heartbeat says 7Fh.
    """
    yield from _pdo_problems(model, (KIND_RPDO,), 0.0, None, "on the bus for the node")


def _pdo_problems(model: InputModel, kinds: tuple[int, ...], grace_s: float,
                  grace_from: str | None, verb: str) -> Iterator[Problem]:
    for m, iv, run in _scan(model, kinds, (PRE_OPERATIONAL, STOPPED), grace_s, grace_from):
        state = m.intervals[iv].state
        yield Problem(m.channel, m.node, run.ts,
                      f"{KIND_NAMES[run.kind]} {run.can_id:03X}h {verb} while node {m.node} is "
                      f"{state}{count_note(run.count)}", run.idx, run.line)


@rule("S003", "comm-while-stopped", "error",
      Param("grace_ms", float, "frames this soon after entering STOPPED are still in flight"))
def comm_while_stopped(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """A STOPPED node answered an SDO or sent an EMCY.

    **What it checks.** N transmits an SDO response (580h+N) or an EMCY (80h+N) while
    STOPPED, unless it entered STOPPED at most `grace_ms` before.

    **Why it matters.** In STOPPED only NMT and error control are allowed (Table 37).
    EMCYs are held pending and sent after leaving STOPPED. A node that keeps
    talking was not really stopped.

    **Example.** `000#0204` (stop node 4), then `584#4B00100000000000`.
    """
    grace = p["grace_ms"] / 1000.0
    for m, iv, run in _scan(model, (KIND_SDO_TX, KIND_EMCY), (STOPPED,), grace, None):
        yield Problem(m.channel, m.node, run.ts,
                      f"{KIND_NAMES[run.kind]} {run.can_id:03X}h from node {m.node} while "
                      f"{m.intervals[iv].state}{count_note(run.count)}", run.idx, run.line)


@rule("S004", "command-not-obeyed", "error",
      Param("obey_ms", float, "time a node has to carry out a command before its reports count"))
def command_not_obeyed(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """A node kept reporting another state after an NMT command.

    **What it checks.** After an NMT start, stop or enter-pre-operational command to
    N (direct or broadcast), an error-control message from N more than `obey_ms`
    after the command, with no newer command to N in between, reports a state
    other than the commanded one. The command counts as obeyed once N reports the
    commanded state; a boot-up or a newer command ends the check. One finding per
    command.

    **Why it matters.** NMT commands are unconfirmed: the master believes N changed
    state. A node that ignores them runs outside the state the system relies on
    (e.g. keeps driving outputs after a stop).

    **Example.** `000#0104` (start node 4), then `704#7F` 0.5 s later.
    """
    obey = p["obey_ms"] / 1000.0
    for cm in model.channels:
        for m in cm.nodes.values():
            cmds = [c for c in m.commands if not c.is_reset]
            all_cmd_idx = sorted(c.idx for c in m.commands)
            ec_idx = [f.idx for f in m.ec]
            for c in cmds:
                target = {0x01: OPERATIONAL, 0x02: STOPPED, 0x80: PRE_OPERATIONAL}[c.cs]
                k = bisect.bisect_right(all_cmd_idx, c.idx)
                newer = all_cmd_idx[k] if k < len(all_cmd_idx) else None
                for f in m.ec[bisect.bisect_right(ec_idx, c.idx):]:
                    if not f.reports_state or f.stale:  # SPEC 2026-11 (C)
                        continue
                    if (newer is not None and f.idx > newer) or f.kind == "bootup":
                        break
                    state = STATE_OF_CODE.get(f.code)
                    if state is None:
                        continue
                    if state == target:
                        break
                    if f.ts - c.ts > obey + EPS:
                        yield Problem(cm.name, m.node, f.ts,
                                      f"node {m.node} reports {state} {f.ts - c.ts:.3f} s after "
                                      f"NMT {c.name} (expected {target})", f.idx, f.line)
                        break


@rule("S005", "unexplained-state-change", "info")
def unexplained_state_change(model: InputModel, p: dict[str, Any]) -> Iterator[Problem]:
    """A node changed its NMT state on its own.

    **What it checks.** N's reported state changes between two of its error-control
    messages with no NMT command to N in between and no boot-up.

    **Why it matters.** Local control is allowed (self-start, 1029h error behaviour,
    application events) but it is the first thing to look at when a node leaves
    OPERATIONAL unexpectedly: it usually reacted to an error it saw.

    **Example.** `703#05`, `703#05`, `703#7F` with no NMT command to node 3.
    """
    for cm in model.channels:
        for m in cm.nodes.values():
            if cm.master is not None and m.node == cm.master[0]:
                continue  # beyond the SPEC (README)
            cmd_idx = [c.idx for c in m.commands]
            prev: EcFrame | None = None
            for f in m.ec:
                if f.kind == "bootup":
                    prev = None
                    continue
                if f.kind not in ("heartbeat", "guard") or f.code not in STATE_OF_CODE:
                    continue
                if f.stale:  # SPEC 2026-11 (C)
                    continue
                if (prev is not None and STATE_OF_CODE[f.code] != STATE_OF_CODE[prev.code]
                        and not any_between(cmd_idx, prev.idx, f.idx)):
                    yield Problem(cm.name, m.node, f.ts,
                                  f"node {m.node} changed from {state_name(prev.code)} to "
                                  f"{state_name(f.code)} without an NMT command", f.idx, f.line)
                prev = f


# =================================================================================================
# afef50f:nmtcheck/checks/__init__.py (the rule table) and nmtcheck/engine.py (check_input)
# =================================================================================================


RULES: list[Rule] = [
    missing_bootup,
    unexpected_bootup,
    bootup_repeated,
    heartbeat_timeout,
    heartbeat_too_early,
    heartbeat_period_mismatch,
    guard_toggle,
    guard_no_response,
    guard_interval_exceeded,
    guarding_with_heartbeat,
    pdo_while_not_operational,
    pdo_to_not_operational,
    comm_while_stopped,
    command_not_obeyed,
    unexplained_state_change,
    restricted_can_id,
    malformed_nmt_command,
    malformed_error_control,
    unknown_nmt_state,
    missing_node,
    duplicate_node_id,
]

BY_CODE: dict[str, Rule] = {r.code: r for r in RULES}


def _timeline_table_ms(profile: Profile, key: str, default: float) -> float:
    """A parameter of the profile's `[timeline]` table (SPEC §5), in ms."""
    return float(getattr(profile, "timeline", {}).get(key, default))


def timeline_params(profile: Profile) -> TimelineParams:
    """The timeline uses rules' parameters (SPEC §2): the timeouts define OFFLINE; S004's
    obey_ms makes reports stale; B002's reset_window_ms and B001's bootup_timeout_ms and the
    `[timeline]` master_window_ms infer the NMT master (SPEC 2026-11, A)."""
    return TimelineParams(
        timeout_factor=profile["H001"].params["timeout_factor"],
        early_factor=profile["H002"].params["early_factor"],
        response_timeout_s=profile["G002"].params["response_timeout_ms"] / 1000.0,
        obey_s=profile["S004"].params["obey_ms"] / 1000.0,
        master_window_s=_timeline_table_ms(profile, "master_window_ms", 1000.0) / 1000.0,
        reset_window_s=profile["B002"].params["reset_window_ms"] / 1000.0,
        bootup_timeout_s=profile["B001"].params["bootup_timeout_ms"] / 1000.0,
    )


@dataclass
class ReferenceResult:
    stats: InputStats
    model: InputModel
    findings: list[Finding] = field(default_factory=list)


def _as_master(value: Any) -> tuple[int, str, str]:
    """(node, source, detail) from a tuple or an object with those attributes."""
    if isinstance(value, tuple):
        node, source, *rest = value
        return int(node), str(source), str(rest[0]) if rest else ""
    return int(value.node), str(value.source), str(getattr(value, "detail", ""))


def reference_check(path: str, profile: Profile, codes: list[str] | None = None,
                    network: Network | None = None,
                    masters: dict[str, Any] | None = None) -> ReferenceResult:
    """`nmtcheck.engine.check_input` of afef50f, run with this file's timeline and rules.

    `codes`: the rules to run (default: all), in catalogue order as the engine runs them.
    The network's node configurations are copied into this file's `NodeConfig`.
    `masters`: channel name -> (node, source, detail) of the known NMT masters (SPEC
    2026-11, A); the reading of network and device files is the package's, so by default
    they come from `network.master_for(channel)`.
    """
    rules = [r for r in RULES if codes is None or r.code in codes]
    opened = open_input(path)
    pdo_ids = {c for cfg, _channel in (network.nodes.values() if network else ())
               for c in [*cfg.tpdo_cob_ids.values(), *cfg.rpdo_cob_ids.values()] if c is not None}
    decoded = decode(opened.batches, pdo_ids)
    stats = opened.stats
    try:
        if stats.frames == 0:
            start = end = 0.0
        else:
            start, end = float(stats.start or 0.0), float(stats.end or 0.0)
            if len(decoded.events):
                end = max(end, float(decoded.events["ts"].max()))
        configs = ({key: NodeConfig(**{f.name: getattr(cfg, f.name) for f in fields(NodeConfig)})
                    for key, cfg in network.configs().items()} if network else {})
        if masters is None and network is not None:
            masters = {name: found for name in stats.channels
                       if (found := network.master_for(name)) is not None}
        known = {name: _as_master(v) for name, v in (masters or {}).items()}
        model = build(decoded, stats.channels, start, end, timeline_params(profile), configs,
                      known)
        model.params = {code: s.params for code, s in profile.items()}
        model.expected = network.expected() if network else []
        result = ReferenceResult(stats, model)
        problems: list[tuple[Rule, Problem]] = []
        for r in rules:
            problems.extend((r, p) for p in r.check(model, profile[r.code].params))
        _locate(model, problems)
        nodes = {(cm.name, m.node): m for cm in model.channels for m in cm.nodes.values()}
        for r, p in problems:
            if p.node is not None and not r.exempt_from_unknown:
                m = nodes.get((p.channel, p.node))
                if m is None or m.state_at(p.time) == UNKNOWN:
                    continue
            settings = profile[r.code]
            result.findings.append(Finding(0, r.code, r.name, settings.severity, p.channel,
                                           p.node, p.time, p.frame_index, p.line, p.message))
        result.findings.sort(key=lambda f: (f.time, f.frame_index or 0, f.rule))
        return result
    finally:
        decoded.close()


def _locate(model: InputModel, problems: list[tuple[Rule, Problem]]) -> None:
    """Give moment findings the first frame at or after their moment."""
    moments = [p for _r, p in problems if p.frame_index is None]
    found = model.decoded.first_frame_at_or_after([p.time for p in moments])
    for p, hit in zip(moments, found, strict=True):
        if hit is not None:
            p.frame_index, p.line = hit
