"""Decoded events -> per (channel, node) NMT state timeline (SPEC §2).

Each node's error-control frames are numpy columns (`EcTable`): they are
classified (boot-up, heartbeat, guarding response), the heartbeat period is
found (configured, else the median interval), heartbeat and guarding timeouts
are computed, and finally the state intervals are built, with OFFLINE from each
timeout to the node's next frame of any kind. Everything is vectorised per node
but the interval walk, which sees only the frames that can change the state.
The sparse events (NMT commands, EMCY, configuration SDOs) are Python objects.
"""

from __future__ import annotations

import bisect
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from nmtcheck import emcy, sdo
from nmtcheck.decode import Decoded

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


REQUEST, BOOTUP, HEARTBEAT, GUARD, MALFORMED = range(5)
EC_KIND_NAMES = ("request", "bootup", "heartbeat", "guard", "malformed")  # by EcTable.kind


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
        self.ts = np.asarray(ts, np.float64)
        self.idx = np.asarray(idx, np.int64)
        self.line = np.asarray(line, np.int64)
        self.rtr = np.asarray(rtr, bool)
        self.dlc = np.asarray(dlc, np.int16)
        self.value = np.asarray(value, np.uint8)
        self.kind = np.where(self.rtr, REQUEST, MALFORMED).astype(np.int8)
        # a report of the pre-command state just after a command (SPEC §2 stale reports)
        self.stale = np.zeros(len(self.ts), bool)

    @classmethod
    def empty(cls) -> EcTable:
        z = np.zeros(0)
        return cls(z, z, z, z, z, z)

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
        """Positions of the frames of these kinds."""
        return np.flatnonzero(np.isin(self.kind, kinds))

    def count(self, kind: int) -> int:
        return int(np.count_nonzero(self.kind == kind))

    @property
    def code(self) -> np.ndarray:
        return self.value & 0x7F

    def after(self, idx: int) -> int:
        """Position of the first frame later in the file than frame index `idx`."""
        return int(np.searchsorted(self.idx, idx, side="right"))


def between(sorted_marks: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Per pair, whether a mark m with lo < m < hi exists (vectorised any_between)."""
    if not len(sorted_marks):
        return np.zeros(len(lo), bool)
    return (np.searchsorted(sorted_marks, lo, side="right")
            < np.searchsorted(sorted_marks, hi, side="left"))


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
    request_ts: float = float("nan")  # the client's request: the server may act on it at once
    request_idx: int = -1


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
    ec: EcTable = field(default_factory=EcTable.empty)
    commands: list[Command] = field(default_factory=list)
    first_show_idx: int | None = None
    first_show_ts: float | None = None
    first_tx: tuple[int, float, int] | None = None  # idx, ts, kind of N's first frame
    last_seen: float | None = None
    period_s: float | None = None
    period_source: str = "none"  # configured | measured | none
    median_s: float | None = None  # the median heartbeat interval, whatever is configured
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

    def config_series(self, times: np.ndarray, get: Callable[[NodeConfig], float | None]
                      ) -> np.ndarray:
        """`get(config_at(t))` for many times at once (NaN where None).

        The configuration only changes where a write is confirmed or stops holding, so
        it is evaluated once per stretch between those moments.
        """
        writes = self.writes + self.consumer_writes
        bps = np.asarray(sorted({w.ts for w in writes}
                                | {w.until for w in writes if w.until != float("inf")}))
        values = [get(self.config_at(at)) for at in [-np.inf, *bps.tolist()]]
        table = np.asarray([np.nan if v is None else v for v in values], np.float64)
        return table[np.searchsorted(bps, times, side="right")]

    def heartbeat_pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """Consecutive heartbeats with no boot-up or reset command of the node between them,
        as two arrays of positions in `ec`: the intervals the period is measured from
        (SPEC §2), H003 compares and the report summarises."""
        cached = self.__dict__.get("_pairs")
        if cached is not None and cached[0] is self.ec.kind:
            return cached[1]
        kind = self.ec.kind
        pos = np.flatnonzero((kind == HEARTBEAT) | (kind == BOOTUP))
        a, b = pos[:-1], pos[1:]
        ok = (kind[a] == HEARTBEAT) & (kind[b] == HEARTBEAT)
        resets = np.asarray([c.idx for c in self.commands if c.is_reset], np.int64)
        ok &= ~between(resets, self.ec.idx[a], self.ec.idx[b])
        pairs = (a[ok], b[ok])
        self.__dict__["_pairs"] = (kind, pairs)
        return pairs

    def heartbeat_intervals(self) -> np.ndarray:
        a, b = self.heartbeat_pairs()
        return self.ec.ts[b] - self.ec.ts[a]

    @property
    def heartbeats(self) -> list[EcFrame]:
        return self.ec.frames(self.ec.where(HEARTBEAT))

    @property
    def bootups(self) -> list[EcFrame]:
        return self.ec.frames(self.ec.where(BOOTUP))

    @property
    def bootup_count(self) -> int:
        return self.ec.count(BOOTUP)

    @property
    def is_producer(self) -> bool:
        if self.config.heartbeat_ms is not None and self.config.heartbeat_ms > 0:
            return True
        if any(w.index == 0x1017 and w.value for w in self.writes):
            return True
        return self.ec.count(HEARTBEAT) >= 2

    def hb_timeout_s(self, timeout_factor: float, at: float | None = None) -> float | None:
        """The heartbeat timeout in force at `at`: consumer time, else factor x period.

        None when there is none, or when 1017h was set to 0 by SDO (heartbeat disabled).
        """
        return self.hb_timeout(self.config if at is None else self.config_at(at),
                               timeout_factor)

    def hb_timeout(self, cfg: NodeConfig, timeout_factor: float) -> float | None:
        """The heartbeat timeout under configuration `cfg`."""
        if cfg.heartbeat_ms == 0.0:
            return None
        if cfg.consumer_timeout_ms:
            return cfg.consumer_timeout_ms / 1000.0
        period = cfg.heartbeat_ms / 1000.0 if cfg.heartbeat_ms else self.period_s
        return timeout_factor * period if period else None

    def periods_at(self, times: np.ndarray) -> np.ndarray:
        """N's heartbeat period in force at each time (SPEC §2): the producer time (1017h)
        in force if non-zero, else the whole-trace median (NaN if neither is known)."""
        series = self.config_series(np.asarray(times, np.float64),
                                    lambda cfg: cfg.heartbeat_ms)
        fallback = self.median_s if self.median_s and self.median_s > 0 else np.nan
        return np.where(series > 0, series / 1000.0, fallback)

    def interval_starts(self) -> np.ndarray:
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
        return max(int(np.searchsorted(self.interval_starts(), ts, side="right")) - 1, 0)

    def interval_indices(self, ts: np.ndarray) -> np.ndarray:
        """`interval_index` for many times at once."""
        return np.maximum(np.searchsorted(self.interval_starts(), ts, side="right") - 1, 0)

    @property
    def error_control(self) -> str:
        hb = bool(self.ec.count(HEARTBEAT))
        guard = bool(self.ec.count(GUARD))
        return {(True, True): "both", (True, False): "heartbeat", (False, True): "guarding"}.get(
            (hb, guard), "none")


@dataclass
class TimelineParams:
    timeout_factor: float = 1.5
    early_factor: float = 0.5
    response_timeout_s: float = 1.0
    obey_s: float = 0.1  # S004: reports within this after a command may be stale
    master_window_s: float = 1.0  # [timeline] master_window_ms: boot-up -> broadcast
    reset_window_s: float = 10.0  # B002: a reset this recent explains a boot-up
    bootup_timeout_s: float = 5.0  # B001: a reset node boots within this


@dataclass(frozen=True)
class Master:
    """A channel's NMT master and how it is known (SPEC §2)."""

    node: int
    source: str  # network | device-file | inferred
    detail: str = ""


@dataclass
class ChannelModel:
    chan: int
    name: str
    nmt: list[NmtFrame]
    nodes: dict[int, NodeModel]
    master: Master | None = None
    master_note: str = ""  # why no master is known, or how it was chosen


@dataclass
class InputModel:
    """The decoded input with its per-node models."""

    decoded: Decoded
    start: float
    end: float
    channels: list[ChannelModel]
    params: dict[str, dict[str, Any]] = field(default_factory=dict)  # every rule's parameters
    expected: list[tuple[int, str | None]] = field(default_factory=list)  # network file nodes
    stats: Any = None  # the reader's InputStats (the I-rules judge the input itself)


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
          masters: dict[str, Master] | None = None) -> InputModel:
    """Build every node's model and timeline from the decoded input.

    `masters`: the NMT master of a channel (by name) known from the network or device
    files; on other channels it is inferred from the start-up pattern (SPEC §2).
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
        ec_tables = _ec_tables(decoded, chan)
        for n, table in ec_tables.items():
            if not table.rtr.all():  # a node exists once it sends; requests alone do not
                node_model(n)
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
        _sdo_config(sdo_rows, nodes, node_model)
        for n, table in ec_tables.items():
            if n in nodes:  # requests to a node nothing else shows are not kept
                nodes[n].ec = table
        master, master_note = _channel_master(name, nmt, ec_tables, params, masters or {},
                                              start)
        _apply_commands(nmt, nodes, master)
        for m in nodes.values():
            _classify(m, params, with_period=False)  # boot-ups bound the SDO-written values
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


def _apply_commands(nmt: list[NmtFrame], nodes: dict[int, NodeModel],
                    master: Master | None) -> None:
    """Each valid command to the nodes it applies to: a direct one to its target, a
    broadcast to every node seen before it but the channel's master, which does not
    receive its own frames (SPEC §2)."""
    for frame in nmt:
        if frame.problem is not None:
            continue
        for n, m in nodes.items():
            if frame.target == n or (
                frame.target == 0 and (master is None or n != master.node)
                and m.first_show_idx is not None and m.first_show_idx < frame.idx
            ):
                m.commands.append(Command(frame.ts, frame.idx, frame.line, frame.cs,
                                          frame.target == 0))


def _channel_master(name: str, nmt: list[NmtFrame], tables: dict[int, EcTable],
                    params: TimelineParams, known: dict[str, Master], start: float
                    ) -> tuple[Master | None, str]:
    """The channel's master from the files, else inferred; with a note on how or why not."""
    if name in known:
        return known[name], known[name].detail
    return infer_master(nmt, tables, params, start)


def infer_master(nmt: list[NmtFrame], tables: dict[int, EcTable], params: TimelineParams,
                 start: float = 0.0) -> tuple[Master | None, str]:
    """A master announces itself by its start-up: its own boot-up, at once a broadcast
    command, and then it does not obey that command (it never receives its own frames).

    SPEC §2's three conditions, checked for the boot-ups before each broadcast (within
    the window, no other command between); only a single qualifying node is taken. SPEC
    asks for the last boot-up only; on a common power-on (Lely's recordings) the
    slaves' boot-ups follow the master's by microseconds, so every one is a candidate
    and the slaves drop out by obeying the broadcast.
    """
    valid = [f for f in nmt if f.problem is None]
    if not any(f.target == 0 for f in valid):
        return None, "not inferred: no broadcast NMT command"
    # each node's data frames of DLC 1 (boot-ups and heartbeats), once per channel
    reports = {n: np.flatnonzero(~t.rtr & (t.dlc == 1)) for n, t in tables.items()}
    boots = sorted((int(tables[n].idx[p]), float(tables[n].ts[p]), n)
                   for n, pos in reports.items() for p in pos[tables[n].value[pos] == 0].tolist())
    boot_idx = [b[0] for b in boots]
    found: dict[int, str] = {}
    prev_idx = -1
    for i, f in enumerate(valid):
        if f.target == 0:
            # every boot-up since the previous command and within the window: at a common
            # power-on the slaves' boot-ups may come after the master's
            k = bisect.bisect_left(boot_idx, f.idx) - 1
            while k >= 0 and boot_idx[k] > prev_idx and (
                    f.ts - boots[k][1] <= params.master_window_s + EPS):
                b_idx, b_ts, node = boots[k]
                k -= 1
                if node not in found and not _answers_reset(valid, i, node, b_idx, b_ts,
                                                            params) and _disobeyed(
                        tables[node], reports[node], valid, i, node, params):
                    found[node] = (f"boot-up at {b_ts - start:.6f} s, then broadcast "
                                   f"{COMMAND_NAMES[f.cs]} at {f.ts - start:.6f} s that node "
                                   f"{node} did not obey")
        prev_idx = f.idx
    if len(found) == 1:
        (node, why), = found.items()
        return Master(node, "inferred", why), why
    if found:
        return None, ("not inferred: several nodes start like a master ("
                      + ", ".join(str(n) for n in sorted(found)) + ")")
    return None, "not inferred: no node starts like a master"


def _answers_reset(valid: list[NmtFrame], before: int, node: int, b_idx: int, b_ts: float,
                   params: TimelineParams) -> bool:
    """Whether a reset command to `node` (direct or broadcast) came in the B002 window
    before its boot-up: a node that obeys a broadcast reset is not its sender."""
    for j in range(before - 1, -1, -1):
        f = valid[j]
        if f.idx > b_idx:
            continue
        if f.ts < b_ts - params.reset_window_s - EPS:
            return False
        if f.cs in RESETS and f.target in (0, node):
            return True
    return False


def _disobeyed(t: EcTable, data: np.ndarray, valid: list[NmtFrame], i: int, node: int,
               params: TimelineParams) -> bool:
    """Whether the node's own frames (`data`: positions of its boot-ups and heartbeats)
    show it did not obey broadcast `valid[i]`.

    Walks only the few frames around the command, so a hostile log with a million
    boot-ups and broadcasts stays linear enough.
    """
    f = valid[i]
    p = int(np.searchsorted(t.idx[data], f.idx, side="right"))
    after = (int(q) for q in data[p:p + 256])  # the answer is in the next few frames
    if f.cs in RESETS:
        for q in after:
            boot = int(t.value[q]) == 0
            dt = float(t.ts[q]) - f.ts
            if not boot and dt <= params.obey_s + EPS:
                continue  # may have been queued before the command
            return not boot or dt > params.bootup_timeout_s + EPS
        return False
    prior = None
    for q in data[max(p - 256, 0):p][::-1].tolist():
        prior = STATE_OF_CODE.get(int(t.value[q]) & 0x7F)
        if prior is not None:
            break
    if prior is None or prior == COMMAND_STATE[f.cs]:
        return False
    next_cmd = None
    for j in range(i + 1, len(valid)):
        if valid[j].target in (0, node):
            next_cmd = valid[j].idx
            break
    for q in after:
        if next_cmd is not None and int(t.idx[q]) > next_cmd or int(t.value[q]) == 0:
            return False
        if float(t.ts[q]) - f.ts <= params.obey_s + EPS:
            continue
        return STATE_OF_CODE.get(int(t.value[q]) & 0x7F) == prior
    return False


def _ec_tables(decoded: Decoded, chan: int) -> dict[int, EcTable]:
    """One column table per node of the channel: views into the decoded columns."""
    tables: dict[int, EcTable] = {}
    ec = decoded.ec
    rows = decoded.ec_rows_between(chan * 128, chan * 128 + 127)
    keys = ec["key"][rows]
    for key in np.unique(keys).tolist():
        r = decoded.ec_rows(key)
        tables[key - chan * 128] = EcTable(ec["ts"][r], ec["idx"][r], ec["line"][r],
                                           ec["rtr"][r], ec["dlc"][r], ec["value"][r])
    return tables


def _sdo_config(rows: list[tuple[float, int, int, int, int, list[int]]],
                nodes: dict[int, NodeModel], node_model: Any) -> None:
    """Pair SDO requests with the server's answer: confirmed writes, aborts, segmented ones."""
    # node -> index, sub, value, ts, idx of the request
    pending: dict[int, tuple[int, int, int | None, float, int]] = {}
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
            m.writes.append(ConfigWrite(ts, idx, line, n, index, sub, value,
                                        request_ts=req[3], request_idx=req[4]))
            m.events.append(NodeEvent(ts, idx, line, "sdo-write",
                                      f"{sdo.object_name(index, sub)} = {value} "
                                      f"({value:X}h) written by SDO"))


def _write_validity(nodes: dict[int, NodeModel]) -> None:
    """A written value holds until the node's next boot-up or reset; 1016h entries also
    count for the producer they name."""
    for m in nodes.values():
        ends = sorted(m.ec.ts[m.ec.kind == BOOTUP].tolist()
                      + [c.ts for c in m.commands if c.is_reset])
        for w in m.writes:
            w.until = next((t for t in ends if t > w.ts), float("inf"))
            if w.index == 0x1016:
                producer = nodes.get((w.value >> 16) & 0xFF)
                if producer is not None and producer is not m:
                    producer.consumer_writes.append(w)


def _classify(m: NodeModel, params: TimelineParams, with_period: bool) -> None:
    """Boot-up, heartbeat or guarding response for each data frame on 700h+N (SPEC §2).

    Without the period (first pass) only boot-ups are final: the period in force needs
    the SDO-written values, which hold until the next boot-up.
    """
    ec = m.ec
    kind = np.where(ec.rtr, REQUEST, np.where(
        ec.dlc != 1, MALFORMED, np.where(ec.value == 0, BOOTUP, HEARTBEAT))).astype(np.int8)
    if kind.size and (kind == REQUEST).any():
        periods = m.periods_at(ec.ts) if with_period else np.full(len(ec), np.nan)
        _classify_guarding(ec, kind, params, periods)
    ec.kind = kind


def _classify_guarding(ec: EcTable, kind: np.ndarray, params: TimelineParams,
                       periods: np.ndarray) -> None:
    """Where remote requests are pending, a data frame may be a guarding response: the
    order matters, so this walks the frames (plain Python ints, no objects).

    `periods`: the heartbeat period in force at each frame (NaN: unknown).
    """
    pending: float | None = None  # ts of the pending request
    hb_since_boot = 0
    last_hb: float | None = None
    early: float | None = None  # the early limit at the last heartbeat
    timeout = params.response_timeout_s + EPS
    for i, (k, ts, value, period) in enumerate(zip(
            kind.tolist(), ec.ts.tolist(), ec.value.tolist(), periods.tolist(), strict=True)):
        if k == REQUEST:
            pending = ts
        elif k == BOOTUP:
            # Always a boot-up, even with a request pending: a node in Initialisation does
            # not answer guarding, and reading it as a response would raise false G001/B001.
            hb_since_boot = 0
            last_hb = None
            pending = None
        elif k == HEARTBEAT:
            is_guard = False
            if pending is not None and ts - pending <= timeout:
                if hb_since_boot >= 2:
                    is_guard = bool(value & 0x80) or (
                        early is not None and last_hb is not None and ts - last_hb < early)
                else:
                    is_guard = True
            if is_guard:
                kind[i] = GUARD
                pending = None
            else:
                hb_since_boot += 1
                last_hb = ts
                early = None if period != period else params.early_factor * period - EPS


def _find_period(m: NodeModel) -> None:
    """Configured producer time, else the median heartbeat interval (no boot-up/reset inside).

    The median is kept apart too: it is the period where 1017h = 0 is in force.
    """
    intervals = m.heartbeat_intervals()
    m.median_s = float(np.median(intervals)) if intervals.size else None
    if m.config.heartbeat_ms:
        m.period_s, m.period_source = m.config.heartbeat_ms / 1000.0, "configured"
    elif m.median_s is not None:
        m.period_s, m.period_source = m.median_s, "measured"
    else:
        m.period_s, m.period_source = None, "none"


_HB, _BOOT, _RESET, _OFF, _ON = range(5)  # what happens to a heartbeat gap (H001)


def _heartbeat_timeouts(m: NodeModel, params: TimelineParams, end: float) -> None:
    """H001: each heartbeat gap that outlasts the timeout in force at its start (SPEC §3).

    A gap starts at a heartbeat, or at a confirmed non-zero 1017h write when none runs
    (a boot-up starts none: a node's power-on producer time is often 0 until the master
    writes 1017h). It ends at the next heartbeat, boot-up, reset command or 1017h = 0;
    a timeout that expired before a reset or a 0 write still counts.
    """
    if not m.is_producer:
        return
    ec = m.ec
    pos = np.flatnonzero((ec.kind == HEARTBEAT) | (ec.kind == BOOTUP))
    extra = [(c.ts, c.idx, _RESET) for c in m.commands if c.is_reset]
    extra += [(w.ts, w.idx, _ON if w.value else _OFF) for w in m.writes if w.index == 0x1017]
    ts = np.concatenate([ec.ts[pos], np.asarray([e[0] for e in extra], np.float64)])
    idx = np.concatenate([ec.idx[pos], np.asarray([e[1] for e in extra], np.int64)])
    what = np.concatenate([np.where(ec.kind[pos] == HEARTBEAT, _HB, _BOOT).astype(np.int8),
                           np.asarray([e[2] for e in extra], np.int8)])
    order = np.argsort(idx, kind="stable")
    ts, idx, what = ts[order], idx[order], what[order]
    if not ts.size:
        return
    # A write of a non-zero 1017h starts a gap only when none runs: right after a boot-up,
    # a reset or a 0 write, or first of all. Other such writes change nothing.
    # A heartbeat while 1017h = 0 is in force (disabled by SDO) starts no gap either.
    hb_ms = m.config_series(ts, lambda cfg: cfg.heartbeat_ms)
    silent = (what == _HB) & (hb_ms == 0)
    prev = np.concatenate([[_BOOT], what[:-1]])
    prev_silent = np.concatenate([[False], silent[:-1]])
    opens = ((what == _HB) & ~silent) | ((what == _ON) & (
        np.isin(prev, (_BOOT, _RESET, _OFF)) | prev_silent))
    ends = np.flatnonzero(what != _ON)  # every event but a non-zero write ends a gap
    gap = np.flatnonzero(opens)
    k = np.searchsorted(ends, gap, side="right")
    closed = k < len(ends)
    until = np.full(len(gap), end, np.float64)
    until[closed] = ts[ends[k[closed]]]
    # A heartbeat sent while a 1017h write is being confirmed already follows the new value
    # (stacks apply it before they answer): its gap is timed by that value.
    at = ts[gap].copy()
    for w in m.writes:
        if w.index == 0x1017:
            at[(ts[gap] >= w.request_ts) & (ts[gap] < w.ts)] = w.ts
    limit = m.config_series(at, lambda cfg: m.hb_timeout(cfg, params.timeout_factor))
    fire = (limit > 0) & (until - ts[gap] > limit + EPS)
    for g, lim, u, c in zip(gap[fire].tolist(), limit[fire].tolist(), until[fire].tolist(),
                            closed[fire].tolist(), strict=True):
        start = float(ts[g])
        m.timeouts.append(Timeout("H001", start + lim, start, int(idx[g]), lim,
                                  u - start if c else None))


def _guard_timeouts(m: NodeModel, params: TimelineParams, end: float) -> None:
    """G002: runs of remote requests to N that got no guarding response in time."""
    limit = params.response_timeout_s
    run: Timeout | None = None
    pending: tuple[float, int] | None = None  # ts, idx of the pending request

    def close(request: tuple[float, int], next_request: float | None) -> None:
        nonlocal run
        deadline = request[0] + limit
        if next_request is None and deadline > end - EPS:
            return  # the trace ended before the answer was due
        moment = deadline if next_request is None else min(deadline, next_request)
        if run is None:
            run = Timeout("G002", moment, request[0], request[1], limit, None)
            m.timeouts.append(run)
        else:
            run.requests += 1

    ec = m.ec
    pos = ec.where(REQUEST, GUARD, BOOTUP)  # heartbeats play no part here
    for k, ts, idx in zip(ec.kind[pos].tolist(), ec.ts[pos].tolist(), ec.idx[pos].tolist(),
                          strict=True):
        if k == REQUEST:
            if pending is not None:
                close(pending, ts)
            pending = (ts, idx)
        elif k == GUARD:  # classification only accepts answers to a pending request
            pending = None
            run = None
        elif pending is not None:  # boot-up
            # A request still within its wait when the node booted was lost to the restart,
            # which B001/B002 judge; one that had already timed out is a real G002.
            if ts - pending[0] > limit + EPS:
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
        ec = m.ec
        p = ec.after(t.after_idx)
        step = 16
        while p < len(ec):  # usually the very next frames: look in growing windows
            window = slice(p, p + step)
            ok = np.flatnonzero((ec.kind[window] != REQUEST) & (ec.ts[window] >= t.moment))
            if ok.size:
                ts = float(ec.ts[p + ok[0]])
                if best is None or ts < best:
                    best = ts
                break
            p += step
            step *= 2
        t.ended_by = best


# state index a data byte reports, -1 if none (boot-up handled apart)
_STATE_OF_BYTE = np.full(256, -1, np.int8)
for _code, _state in STATE_OF_CODE.items():
    _STATE_OF_BYTE[_code] = _STATE_OF_BYTE[_code | 0x80] = STATE_INDEX[_state]


def _evidence(m: NodeModel, windows: list[tuple[float, float]]) -> np.ndarray:
    """Positions (in time order) of the node's error-control frames that can change its
    timeline: a frame that reports the same as the frame before it changes nothing, so
    runs of equal heartbeats reduce to their first. Frames inside a window [lo, hi]
    (after a command or timeout) are kept, and the first one after it."""
    ec = m.ec
    pos = np.flatnonzero(ec.kind != REQUEST)
    pos = pos[np.lexsort((ec.idx[pos], ec.ts[pos]))]
    if not pos.size:
        return pos
    kind = ec.kind[pos]
    target = np.where(kind == BOOTUP, STATE_INDEX[PRE_OPERATIONAL],
                      np.where((kind == HEARTBEAT) | (kind == GUARD),
                               _STATE_OF_BYTE[ec.value[pos] & 0xFF], -1))
    keep = np.ones(len(pos), bool)
    keep[1:] = target[1:] != target[:-1]
    keep |= kind == BOOTUP  # sparse, and each one ends what came before it
    if windows:
        sts = ec.ts[pos]
        w = np.asarray(windows, np.float64)
        lo = np.searchsorted(sts, w[:, 0], side="left")
        hi = np.minimum(np.searchsorted(sts, w[:, 1] + EPS, side="right"), len(pos) - 1)
        mark = np.zeros(len(pos) + 1, np.int64)
        np.add.at(mark, lo, 1)
        np.add.at(mark, hi + 1, -1)
        keep |= np.cumsum(mark[:-1]) > 0
    return pos[keep]


def _intervals(m: NodeModel, start: float, end: float, obey_s: float) -> list[Interval]:
    """Walk the node's evidence in order and cut the timeline into state intervals.

    A heartbeat or guarding response up to `obey_s` after a command that reports the
    state from before the command was queued before the node processed it: it is marked
    stale in `m.ec.stale` and is no evidence (SPEC §2).
    """
    steps: list[tuple[float, int, int, str, object]] = []
    windows = [(c.ts, c.ts + obey_s) for c in m.commands] + [
        (t, t) for t in [t.moment for t in m.timeouts]
        + [t.ended_by for t in m.timeouts if t.ended_by is not None]]
    for f in m.ec.frames(_evidence(m, windows)):
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
    last_cmd: tuple[float, str] | None = None  # the latest command: ts, state before it
    pre_offline: str | None = None  # the state N had when it went OFFLINE
    for ts, _idx, _order, what, obj in steps:
        cur = out[-1].state
        if what == "timeout":
            assert isinstance(obj, Timeout)
            if cur in (UNKNOWN, OFFLINE):
                continue
            saved = (cur, out[-1].source)
            pre_offline = cur  # what a stale report after a command here would still say
            offline_until = obj.ended_by
            go(ts, OFFLINE, "timeout")
        elif what == "back":
            if cur == OFFLINE and saved is not None and offline_until == ts:
                go(ts, saved[0], saved[1])
                saved = None
        elif what == "cmd":
            assert isinstance(obj, Command)
            last_cmd = (ts, pre_offline if cur == OFFLINE and pre_offline else cur)
            target = COMMAND_STATE[obj.cs]
            if cur == OFFLINE:
                saved = (target, "command")
            else:
                go(ts, target, "command")
        else:
            assert isinstance(obj, EcFrame)
            f = obj
            if (f.kind in ("heartbeat", "guard") and last_cmd is not None
                    and ts - last_cmd[0] <= obey_s + EPS
                    and STATE_OF_CODE.get(f.code) == last_cmd[1]):
                m.ec.stale[f.pos] = True
                continue
            if f.kind == "bootup":
                last_cmd = None  # nothing after a boot-up was queued before the command
            if f.reports_state and (f.kind == "bootup" or f.code in STATE_OF_CODE):
                state = STATE_OF_CODE[0x00] if f.kind == "bootup" else STATE_OF_CODE[f.code]
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
