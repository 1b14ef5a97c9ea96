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



_KNOWN_CS = np.zeros(256, bool)
_KNOWN_CS[list(COMMAND_STATE) + list(RESETS)] = True
_RESET_CS = np.zeros(256, bool)
_RESET_CS[list(RESETS)] = True


class NmtTable:
    """A channel's frames on CAN-ID 000h as columns, valid or not (a hostile log may
    hold millions of them): a `NmtFrame` is made only for what a rule reports."""

    def __init__(self, ts: np.ndarray, idx: np.ndarray, line: np.ndarray, rtr: np.ndarray,
                 dlc: np.ndarray, cs: np.ndarray, target: np.ndarray) -> None:
        self.ts = np.asarray(ts, np.float64)
        self.idx = np.asarray(idx, np.int64)
        self.line = np.asarray(line, np.int64)
        self.rtr = np.asarray(rtr, bool)
        self.dlc = np.asarray(dlc, np.int16)
        self.cs = np.asarray(cs, np.uint8)
        self.target = np.asarray(target, np.uint8)
        self.valid = ~self.rtr & (self.dlc == 2) & _KNOWN_CS[self.cs] & (self.target <= 127)

    @classmethod
    def empty(cls) -> NmtTable:
        z = np.zeros(0)
        return cls(z, z, z, z, z, z, z)

    def __len__(self) -> int:
        return len(self.ts)

    def __getitem__(self, pos: int) -> NmtFrame:
        rtr, dlc, cs, target = (bool(self.rtr[pos]), int(self.dlc[pos]), int(self.cs[pos]),
                                int(self.target[pos]))
        return NmtFrame(float(self.ts[pos]), int(self.idx[pos]), int(self.line[pos]), rtr, dlc,
                        cs, target, _nmt_problem(rtr, dlc, cs, target))

    def __iter__(self) -> Iterator[NmtFrame]:
        return (self[i] for i in range(len(self)))


class CommandTable:
    """The valid NMT commands that apply to one node, as columns: a log of nothing but
    NMT commands gives every node one per frame."""

    def __init__(self, ts: np.ndarray, idx: np.ndarray, line: np.ndarray, cs: np.ndarray,
                 broadcast: np.ndarray) -> None:
        self.ts = np.asarray(ts, np.float64)
        self.idx = np.asarray(idx, np.int64)
        self.line = np.asarray(line, np.int64)
        self.cs = np.asarray(cs, np.uint8)
        self.broadcast = np.asarray(broadcast, bool)
        self.is_reset = _RESET_CS[self.cs]

    @classmethod
    def empty(cls) -> CommandTable:
        z = np.zeros(0)
        return cls(z, z, z, z, z)

    @classmethod
    def of(cls, nmt: NmtTable, pos: np.ndarray) -> CommandTable:
        return cls(nmt.ts[pos], nmt.idx[pos], nmt.line[pos], nmt.cs[pos], nmt.target[pos] == 0)

    def __len__(self) -> int:
        return len(self.ts)

    def __getitem__(self, pos: int) -> Command:
        return Command(float(self.ts[pos]), int(self.idx[pos]), int(self.line[pos]),
                       int(self.cs[pos]), bool(self.broadcast[pos]))

    def __iter__(self) -> Iterator[Command]:
        return (self[i] for i in range(len(self)))

    def name(self, pos: int) -> str:
        return COMMAND_NAMES[int(self.cs[pos])] + (" (broadcast)" if self.broadcast[pos] else "")

    @property
    def reset_idx(self) -> np.ndarray:
        """File positions of the reset commands (sorted: commands are in file order)."""
        return self.idx[self.is_reset]

    @property
    def reset_ts(self) -> np.ndarray:
        return self.ts[self.is_reset]


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


SOURCES = ("start", "command", "timeout", "bootup", "heartbeat", "guarding")
SOURCE_INDEX = {s: i for i, s in enumerate(SOURCES)}


class IntervalTable:
    """A node's state intervals as columns (state and source as indices into `STATES`
    and `SOURCES`): a node that changes state on every heartbeat has millions of them.
    An `Interval` is made only when one is looked at."""

    def __init__(self, start: np.ndarray, end: np.ndarray, state: np.ndarray,
                 source: np.ndarray) -> None:
        self.start = np.asarray(start, np.float64)
        self.end = np.asarray(end, np.float64)
        self.state = np.asarray(state, np.int8)
        self.source = np.asarray(source, np.int8)

    @classmethod
    def empty(cls) -> IntervalTable:
        z = np.zeros(0)
        return cls(z, z, z, z)

    def __len__(self) -> int:
        return len(self.start)

    def __getitem__(self, pos: int) -> Interval:
        return Interval(float(self.start[pos]), float(self.end[pos]), STATES[self.state[pos]],
                        SOURCES[self.source[pos]])

    def __iter__(self) -> Iterator[Interval]:
        for a, b, st, so in zip(self.start.tolist(), self.end.tolist(), self.state.tolist(),
                                self.source.tolist(), strict=True):
            yield Interval(a, b, STATES[st], SOURCES[so])


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
    commands: CommandTable = field(default_factory=CommandTable.empty)
    first_show_idx: int | None = None
    first_show_ts: float | None = None
    first_tx: tuple[int, float, int] | None = None  # idx, ts, kind of N's first frame
    last_seen: float | None = None
    period_s: float | None = None
    period_source: str = "none"  # configured | measured | none
    median_s: float | None = None  # the median heartbeat interval, whatever is configured
    timeouts: list[Timeout] = field(default_factory=list)
    intervals: IntervalTable = field(default_factory=IntervalTable.empty)
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
        ok &= ~between(self.commands.reset_idx, self.ec.idx[a], self.ec.idx[b])
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
        return self.intervals.start

    def state_at(self, ts: float) -> str:
        """State after the evidence of a frame at `ts` (intervals starting at ts included)."""
        return STATES[self.intervals.state[self.interval_index(ts)]]

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
    nmt: NmtTable
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
        is_nmt = rows["can_id"] == 0
        nmt = _nmt_table(rows[is_nmt])
        _first_shown_by_commands(nmt, node_model)
        sdo_rows: list[tuple[float, int, int, int, int, list[int]]] = []
        for r in rows[~is_nmt].tolist():
            ts, idx, line, _chan, can_id, rtr, dlc, data = r
            data = [int(x) for x in data]  # plain ints: numpy uint8 would overflow on shifts
            if 0x081 <= can_id <= 0x0FF:
                code, text = emcy.describe(data, dlc)
                node_model(can_id - 0x080).events.append(
                    NodeEvent(ts, idx, line, "emcy", text, code))
            elif 0x581 <= can_id <= 0x67F:
                sdo_rows.append((ts, idx, line, can_id, dlc, data))
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


def _nmt_table(rows: np.ndarray) -> NmtTable:
    data = rows["data"]
    return NmtTable(rows["ts"], rows["idx"], rows["line"], rows["rtr"], rows["dlc"],
                    data[:, 0], data[:, 1])


def _first_shown_by_commands(nmt: NmtTable, node_model: Callable[[int], NodeModel]) -> None:
    """A valid direct command shows its target node exists, from that command on."""
    direct = np.flatnonzero(nmt.valid & (nmt.target != 0))
    if not direct.size:
        return
    targets = nmt.target[direct]
    for n in np.unique(targets).tolist():
        first = direct[np.argmax(targets == n)]
        m = node_model(n)
        idx = int(nmt.idx[first])
        if m.first_show_idx is None or idx < m.first_show_idx:
            m.first_show_idx, m.first_show_ts = idx, float(nmt.ts[first])


def _apply_commands(nmt: NmtTable, nodes: dict[int, NodeModel],
                    master: Master | None) -> None:
    """Each valid command to the nodes it applies to: a direct one to its target, a
    broadcast to every node seen before it but the channel's master, which does not
    receive its own frames (SPEC §2)."""
    broadcast = nmt.valid & (nmt.target == 0)
    for n, m in nodes.items():
        mine = nmt.valid & (nmt.target == n)
        if (master is None or n != master.node) and m.first_show_idx is not None:
            mine |= broadcast & (m.first_show_idx < nmt.idx)
        m.commands = CommandTable.of(nmt, np.flatnonzero(mine))


def _channel_master(name: str, nmt: NmtTable, tables: dict[int, EcTable],
                    params: TimelineParams, known: dict[str, Master], start: float
                    ) -> tuple[Master | None, str]:
    """The channel's master from the files, else inferred; with a note on how or why not."""
    if name in known:
        return known[name], known[name].detail
    return infer_master(nmt, tables, params, start)


def infer_master(nmt: NmtTable, tables: dict[int, EcTable], params: TimelineParams,
                 start: float = 0.0) -> tuple[Master | None, str]:
    """A master announces itself by its start-up: its own boot-up, at once a broadcast
    command, and then it does not obey that command (it never receives its own frames).

    SPEC §2's three conditions, checked for the boot-ups before each broadcast (within
    the window, no other command between); only a single qualifying node is taken. SPEC
    asks for the last boot-up only; on a common power-on (Lely's recordings) the
    slaves' boot-ups follow the master's by microseconds, so every one is a candidate
    and the slaves drop out by obeying the broadcast.
    """
    if not (nmt.valid & (nmt.target == 0)).any():
        return None, "not inferred: no broadcast NMT command"
    valid = _Valid(nmt)
    # each node's data frames of DLC 1 (boot-ups and heartbeats), once per channel
    reports = {n: np.flatnonzero(~t.rtr & (t.dlc == 1)) for n, t in tables.items()}
    boots = sorted((int(tables[n].idx[p]), float(tables[n].ts[p]), n)
                   for n, pos in reports.items() for p in pos[tables[n].value[pos] == 0].tolist())
    boot_idx = [b[0] for b in boots]
    found: dict[int, str] = {}
    for i in np.flatnonzero(valid.target == 0).tolist():
        f_idx, f_ts, f_cs = valid.idx[i], valid.ts[i], valid.cs[i]
        prev_idx = valid.idx[i - 1] if i else -1
        # every boot-up since the previous command and within the window: at a common
        # power-on the slaves' boot-ups may come after the master's
        k = bisect.bisect_left(boot_idx, f_idx) - 1
        while k >= 0 and boot_idx[k] > prev_idx and (
                f_ts - boots[k][1] <= params.master_window_s + EPS):
            b_idx, b_ts, node = boots[k]
            k -= 1
            if node not in found and not _answers_reset(valid, i, node, b_idx, b_ts,
                                                        params) and _disobeyed(
                    tables[node], reports[node], valid, i, node, params):
                found[node] = (f"boot-up at {b_ts - start:.6f} s, then broadcast "
                               f"{COMMAND_NAMES[f_cs]} at {f_ts - start:.6f} s that node "
                               f"{node} did not obey")
    if len(found) == 1:
        (node, why), = found.items()
        return Master(node, "inferred", why), why
    if found:
        return None, ("not inferred: several nodes start like a master ("
                      + ", ".join(str(n) for n in sorted(found)) + ")")
    return None, "not inferred: no node starts like a master"


class _Valid:
    """The valid commands of a channel as plain lists (the master inference walks a few
    of them at a time, by position)."""

    def __init__(self, nmt: NmtTable) -> None:
        v = nmt.valid
        self.ts: list[float] = nmt.ts[v].tolist()
        self.idx: list[int] = nmt.idx[v].tolist()
        self.cs: list[int] = nmt.cs[v].tolist()
        self.target = nmt.target[v]

    def next_to(self, i: int, node: int) -> int | None:
        """File position of the first command after the i-th that reaches `node` (direct
        or broadcast), looked for in growing windows: usually it is close."""
        j, step = i + 1, 64
        while j < len(self.idx):
            seg = self.target[j:j + step]
            hit = np.flatnonzero((seg == 0) | (seg == node))
            if hit.size:
                return self.idx[j + int(hit[0])]
            j, step = j + step, step * 2
        return None


def _answers_reset(valid: _Valid, before: int, node: int, b_idx: int, b_ts: float,
                   params: TimelineParams) -> bool:
    """Whether a reset command to `node` (direct or broadcast) came in the B002 window
    before its boot-up: a node that obeys a broadcast reset is not its sender."""
    for j in range(before - 1, -1, -1):
        if valid.idx[j] > b_idx:
            continue
        if valid.ts[j] < b_ts - params.reset_window_s - EPS:
            return False
        if valid.cs[j] in RESETS and int(valid.target[j]) in (0, node):
            return True
    return False


def _disobeyed(t: EcTable, data: np.ndarray, valid: _Valid, i: int, node: int,
               params: TimelineParams) -> bool:
    """Whether the node's own frames (`data`: positions of its boot-ups and heartbeats)
    show it did not obey broadcast `valid[i]`.

    Walks only the few frames around the command, so a hostile log with a million
    boot-ups and broadcasts stays linear enough.
    """
    f_idx, f_ts, f_cs = valid.idx[i], valid.ts[i], valid.cs[i]
    p = int(np.searchsorted(t.idx[data], f_idx, side="right"))
    after = (int(q) for q in data[p:p + 256])  # the answer is in the next few frames
    if f_cs in RESETS:
        for q in after:
            boot = int(t.value[q]) == 0
            dt = float(t.ts[q]) - f_ts
            if not boot and dt <= params.obey_s + EPS:
                continue  # may have been queued before the command
            return not boot or dt > params.bootup_timeout_s + EPS
        return False
    prior = None
    for q in data[max(p - 256, 0):p][::-1].tolist():
        prior = STATE_OF_CODE.get(int(t.value[q]) & 0x7F)
        if prior is not None:
            break
    if prior is None or prior == COMMAND_STATE[f_cs]:
        return False
    next_cmd = valid.next_to(i, node)
    for q in after:
        if next_cmd is not None and int(t.idx[q]) > next_cmd or int(t.value[q]) == 0:
            return False
        if float(t.ts[q]) - f_ts <= params.obey_s + EPS:
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
        ends = sorted(m.ec.ts[m.ec.kind == BOOTUP].tolist() + m.commands.reset_ts.tolist())
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
    extra = [(t, i, _RESET) for t, i in zip(m.commands.reset_ts.tolist(),
                                            m.commands.reset_idx.tolist(), strict=True)]
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
    # A gap opened by a confirmed write is timed by the value in force after it.
    at = ts[gap].copy()
    by_heartbeat = what[gap] == _HB
    for w in m.writes:
        if w.index == 0x1017:
            at[by_heartbeat & (ts[gap] >= w.request_ts) & (ts[gap] < w.ts)] = w.ts
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


_CODE_STATE = np.full(128, -1, np.int8)  # state index a code (data byte & 7Fh) reports
for _code, _state in STATE_OF_CODE.items():
    _CODE_STATE[_code] = STATE_INDEX[_state]
_EC_SOURCE = {BOOTUP: SOURCE_INDEX["bootup"], HEARTBEAT: SOURCE_INDEX["heartbeat"],
              GUARD: SOURCE_INDEX["guarding"]}
_EV_TIMEOUT, _EV_EC, _EV_BACK = 0, 1, 2  # order of steps at one moment; commands are 1 too
_EV_CMD = 3


def _intervals(m: NodeModel, start: float, end: float, obey_s: float) -> IntervalTable:
    """Walk the node's evidence in order and cut the timeline into state intervals.

    A heartbeat or guarding response up to `obey_s` after a command that reports the
    state from before the command was queued before the node processed it: it is marked
    stale in `m.ec.stale` and is no evidence (SPEC §2). The walk sees plain ints and
    floats, never objects: a node may change state on every heartbeat.
    """
    ec, cmds = m.ec, m.commands
    windows = [(t, t + obey_s) for t in cmds.ts.tolist()] + [
        (t, t) for t in [t.moment for t in m.timeouts]
        + [t.ended_by for t in m.timeouts if t.ended_by is not None]]
    pos = _evidence(m, windows)
    backs = [t for t in m.timeouts if t.ended_by is not None]
    # the steps as columns: time, order at one moment, file position, what, reference
    ts = np.concatenate([ec.ts[pos], cmds.ts, [t.moment for t in m.timeouts],
                         [t.ended_by for t in backs]]).astype(np.float64)
    order = np.concatenate([np.ones(len(pos) + len(cmds), np.int8),
                            np.zeros(len(m.timeouts), np.int8), np.full(len(backs), 2, np.int8)])
    idx = np.concatenate([ec.idx[pos], cmds.idx,
                          np.full(len(m.timeouts) + len(backs), -1, np.int64)])
    what = np.concatenate([np.full(len(pos), _EV_EC, np.int8), np.full(len(cmds), _EV_CMD, np.int8),
                           np.full(len(m.timeouts), _EV_TIMEOUT, np.int8),
                           np.full(len(backs), _EV_BACK, np.int8)])
    ref = np.concatenate([pos, np.arange(len(cmds)), np.arange(len(m.timeouts)),
                          [m.timeouts.index(t) for t in backs]]).astype(np.int64)
    steps = np.lexsort((idx, order, ts))
    kind = ec.kind.tolist()
    code_state = _CODE_STATE[ec.value & 0x7F].tolist()
    cmd_state = [STATE_INDEX[COMMAND_STATE[c]] for c in cmds.cs.tolist()]
    ended_by = [t.ended_by for t in m.timeouts]

    unknown, offline, pre_op = STATE_INDEX[UNKNOWN], STATE_INDEX[OFFLINE], STATE_INDEX[
        PRE_OPERATIONAL]
    src_timeout, src_command = SOURCE_INDEX["timeout"], SOURCE_INDEX["command"]
    starts: list[float] = [start]
    states: list[int] = [unknown]
    sources: list[int] = [SOURCE_INDEX["start"]]

    def go(at: float, state: int, source: int) -> None:
        if states[-1] == state:
            return
        if at <= starts[-1]:  # the current interval would be empty: replace it
            starts.pop()
            states.pop()
            sources.pop()
            if states and states[-1] == state:
                return
        starts.append(max(at, start))
        states.append(state)
        sources.append(source)

    saved: tuple[int, int] | None = None  # state and source to return to after OFFLINE
    offline_until: float | None = None
    last_cmd: tuple[float, int] | None = None  # the latest command: ts, state before it
    pre_offline: int | None = None  # the state N had when it went OFFLINE
    stale = ec.stale
    for at, w, r in zip(ts[steps].tolist(), what[steps].tolist(), ref[steps].tolist(),
                        strict=True):
        cur = states[-1]
        if w == _EV_EC:
            k = kind[r]
            state = code_state[r]
            if k in (HEARTBEAT, GUARD) and last_cmd is not None and (
                    at - last_cmd[0] <= obey_s + EPS) and state == last_cmd[1]:
                stale[r] = True
                continue
            if k == BOOTUP:
                last_cmd = None  # nothing after a boot-up was queued before the command
                go(at, pre_op, _EC_SOURCE[k])
                saved = None
            elif k in (HEARTBEAT, GUARD) and state >= 0:
                go(at, state, _EC_SOURCE[k])
                saved = None
            elif cur == offline and saved is not None:
                go(at, *saved)
                saved = None
        elif w == _EV_CMD:
            last_cmd = (at, pre_offline if cur == offline and pre_offline is not None else cur)
            if cur == offline:
                saved = (cmd_state[r], src_command)
            else:
                go(at, cmd_state[r], src_command)
        elif w == _EV_TIMEOUT:
            if cur in (unknown, offline):
                continue
            saved = (cur, sources[-1])
            pre_offline = cur  # what a stale report after a command here would still say
            offline_until = ended_by[r]
            go(at, offline, src_timeout)
        elif cur == offline and saved is not None and offline_until == at:  # back
            go(at, *saved)
            saved = None
    begin = np.asarray(starts, np.float64)
    finish = np.append(begin[1:], max(end, starts[-1]))
    return IntervalTable(begin, finish, np.asarray(states, np.int8),
                         np.asarray(sources, np.int8))
