"""What the timeline knows of an input: per channel its NMT frames and master, per node
its error-control frames, commands, configuration, timeouts and state intervals.

The dense streams (heartbeats, NMT frames, commands, EMCYs, intervals) are numpy
columns, kept in `tables.py` (NMT, commands, error control, intervals) and
`node_events.py` (EMCY, SDO writes and aborts); an object (`EcFrame`, `NmtFrame`,
`Command`, `NodeEvent`, `Interval`) is made only for what a rule or a report looks at.
"""

from __future__ import annotations

import bisect
import heapq
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any, NamedTuple

import numpy as np

from nmtcheck.protocol.nmt import (
    BOOTUP,
    EC_KIND_NAMES,
    EPS,
    GUARD,
    HEARTBEAT,
    STATE_INDEX,
    STATES,
    between,
    is_one_of,
)
from nmtcheck.readers.frames import RPDO_BASES, TPDO_BASES
from nmtcheck.timeline.decode import (
    KIND_RPDO,
    KIND_TPDO,
    Decoded,
    FirstTx,
    NodeFrames,
    node_frame_lines,
)
from nmtcheck.timeline.gaps import Gaps
from nmtcheck.timeline.node_events import (
    NO_EVENTS,
    ConfigWrite,
    EmcyTable,
    NodeEvent,
    NodeEvents,
    NoEvents,
    SdoEventTable,
    WriteTable,
)
from nmtcheck.timeline.tables import (
    FEW_ROWS,
    Command,
    CommandTable,
    EcFrame,
    EcTable,
    Interval,
    IntervalTable,
    NmtFrame,
    NmtTable,
    interval_columns,
    known_cs,
    plain_rows,
    reset_cs,
    shared_empty,
)

# The tables moved to tables.py and node_events.py are re-exported: `from nmtcheck.timeline.model
# import X` keeps working for every name it gave before (tests/test_imports.py).
__all__ = [
    "QUERY_GROUP",
    "ChannelModel",
    "Command",
    "CommandTable",
    "ConfigWrite",
    "EcFrame",
    "EcTable",
    "EmcyTable",
    "InputModel",
    "Interval",
    "IntervalTable",
    "Master",
    "NmtFrame",
    "NmtTable",
    "NodeConfig",
    "NodeEvent",
    "NodeEvents",
    "NodeModel",
    "SdoEventTable",
    "SentFrames",
    "TimelineParams",
    "Timeout",
    "WriteTable",
    "known_cs",
    "plain_rows",
    "reset_cs",
]

_UNKNOWN = STATES.index("UNKNOWN")
QUERY_GROUP = 1 << 20  # resets asked of the node-frame store in one pass


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
    # this node's own 1016h entries from its device file: producer node -> consumer time (ms)
    consumes: dict[int, float] = field(default_factory=dict)

    @property
    def life_time_s(self) -> float | None:
        """Node life time = guard time x life time factor (G003), None when either is
        unknown or 0."""
        if not self.guard_time_ms or not self.life_time_factor:
            return None
        return self.guard_time_ms * self.life_time_factor / 1000.0


# a new node's defaults, shared (a log may have tens of thousands of nodes), read only
_FEW_COUNTS: dict[tuple[int, ...], tuple[int, ...]] = {}  # see kind_counts()
_NO_BOUNDS, _NO_MEDIAN, _NO_IDX = np.zeros(0), np.full(1, np.nan), np.zeros(0, np.int64)
for _shared in (_NO_BOUNDS, _NO_MEDIAN, _NO_IDX):
    _shared.flags.writeable = False

# error-control objects whose file value gives way once SDO writes them (SPEC §6)
_ERROR_CONTROL_OBJECTS = {0x1017: "heartbeat_ms", 0x100C: "guard_time_ms",
                          0x100D: "life_time_factor"}


class SmallEc(NamedTuple):
    """A small node's error-control frames (boot-ups and heartbeats only, no command, no
    SDO write, no dropped run) as Python lists, in file order: a log of many channels
    has tens of thousands of such nodes, and each numpy set-up costs more than the walk
    over a few Python numbers."""

    ts: list[float]
    kind: list[int]
    value: list[int]
    idx: list[int]


@dataclass
class NodeModel:
    """Everything known about one node on one channel."""

    chan: int
    channel: str
    node: int
    config: NodeConfig
    # a node's tables are shared empty ones until the timeline gives it its own
    ec: EcTable = field(default_factory=lambda: shared_empty(EcTable))
    commands: CommandTable = field(default_factory=lambda: shared_empty(CommandTable))
    first_show_idx: int | None = None
    first_show_ts: float | None = None
    first_tx: FirstTx | None = None  # N's first transmitted frame
    last_seen: float | None = None
    period_s: float | None = None
    period_source: str = "none"  # configured | measured | none
    median_s: float | None = None  # the median heartbeat interval, whatever is configured
    # the measured period per producer-time segment (SPEC §2): segment k runs from
    # seg_bounds[k-1] to seg_bounds[k]; NaN where the segment has no interval of its own
    seg_bounds: np.ndarray = field(default_factory=lambda: _NO_BOUNDS)
    seg_median: np.ndarray = field(default_factory=lambda: _NO_MEDIAN)
    timeouts: list[Timeout] = field(default_factory=list)
    intervals: IntervalTable = field(default_factory=lambda: shared_empty(IntervalTable))
    writes: WriteTable = field(  # to N's own objects
        default_factory=lambda: shared_empty(WriteTable))
    consumer_writes: WriteTable = field(  # 1016h entries naming N
        default_factory=lambda: shared_empty(WriteTable))
    pdo_writes: WriteTable = field(  # N's PDO parameters beyond 1400h-1403h/1800h-1803h:01
        default_factory=lambda: shared_empty(WriteTable))
    events: NodeEvents = field(default_factory=lambda: NO_EVENTS)  # see own_events()
    order_only: bool = False  # the input has no timestamps: no period is measured
    self_starts: list[tuple[float, int]] = field(default_factory=list)  # (ts, frame index)
    # after a boot-up, spans where nothing shows whether N started itself (no S001)
    unproven_spans: list[tuple[float, float]] = field(default_factory=list)
    # the master's own broadcasts that its frames show it obeyed: applied to its timeline,
    # never a finding for it (B001, B002, B003, S004)
    own_command_idx: np.ndarray = field(default_factory=lambda: _NO_IDX)
    # heartbeat_pairs() and the `ec.kind` it was computed from (classification replaces it)
    _pairs: tuple[object, tuple[np.ndarray, np.ndarray]] | None = field(
        default=None, init=False, repr=False, compare=False)
    _kinds: tuple[object, tuple[int, ...]] | None = field(  # kind_counts(), likewise
        default=None, init=False, repr=False, compare=False)
    # a small plain node's frames as Python lists (`timeline._small`): the heartbeat
    # stages and rules take their per-node shortcuts on them; None: the numpy paths
    small: SmallEc | None = field(default=None, repr=False, compare=False)

    def own_events(self) -> NodeEvents:
        """N's events to fill in: its own, not the shared empty ones it starts with."""
        if isinstance(self.events, NoEvents):
            self.events = NodeEvents()
        return self.events

    def reported_period(self, end: float) -> tuple[float | None, str]:
        """N's heartbeat period as the reports give it (seconds, and configured | measured |
        none): the producer time (1017h) in force at the trace's `end`, where a confirmed
        SDO write replaces the files' value (a CANopenNode slave powers on at 1000 ms and
        its master sets 100 ms), else the measured median; none where 1017h = 0 was
        written (no heartbeat at the end). `period_s` itself stays the files' value: the
        rules that use it take it as it was."""
        if self.order_only or not len(self.writes):
            return self.period_s, self.period_source
        producer = self.config_at(end).heartbeat_ms
        if producer:
            return producer / 1000.0, "configured"
        if producer == 0:
            return None, "none"
        return (self.median_s, "measured") if self.median_s is not None else (None, "none")

    def config_at(self, ts: float) -> NodeConfig:
        """The configuration in force at `ts`: files, then SDO writes confirmed before it."""
        if not len(self.writes) and not len(self.consumer_writes):  # the files' (most nodes)
            return self.config
        return next(self._configs_at([ts]))

    def _configs_at(self, moments: list[float]) -> Iterator[NodeConfig]:
        """`config_at` for ascending moments in one sweep over the writes: a log may write
        1017h a million times, and each moment must not look at every write.

        A write is in force from its confirmation until it stops holding (`until`); of a
        node's own writes to one object the last confirmed in force wins, of the 1016h
        entries naming N the shortest consumer time (the first such entry on a tie).
        """
        w, c = self.writes, self.consumer_writes
        w_ts, w_index, w_until = w.ts.tolist(), w.index.tolist(), w.until.tolist()
        c_ts, c_time, c_until = c.ts.tolist(), (c.value & 0xFFFF).tolist(), c.until.tolist()
        own = np.argsort(w.ts, kind="stable").tolist()
        cons = np.argsort(c.ts, kind="stable").tolist()
        latest: dict[int, list[int]] = {}  # per object: heap of -(position in `writes`)
        shortest: list[tuple[int, int]] = []  # heap of (consumer time, position)
        a = k = 0
        for at in moments:
            while a < len(own) and w_ts[own[a]] <= at:
                heapq.heappush(latest.setdefault(w_index[own[a]], []), -own[a])
                a += 1
            while k < len(cons) and c_ts[cons[k]] <= at:
                if c_time[cons[k]]:
                    heapq.heappush(shortest, (c_time[cons[k]], cons[k]))
                k += 1
            active = []
            for heap in latest.values():
                while heap and w_until[-heap[0]] <= at:  # no longer holds
                    heapq.heappop(heap)
                if heap:
                    active.append(-heap[0])
            while shortest and c_until[shortest[0][1]] <= at:
                heapq.heappop(shortest)
            yield self._config_with(active, shortest[0][1] if shortest else None)

    def _config_with(self, active: list[int], consumer: int | None) -> NodeConfig:
        """The files' configuration with these writes (positions in `writes`, one per
        object) and this 1016h entry naming N (a position in `consumer_writes`) applied."""
        base = self._base_config
        if not active and consumer is None:
            return base
        cfg = replace(base, tpdo_cob_ids=dict(base.tpdo_cob_ids),
                      rpdo_cob_ids=dict(base.rpdo_cob_ids))
        for pos in active:
            index, value = int(self.writes.index[pos]), int(self.writes.value[pos])
            if index == 0x1017:
                cfg.heartbeat_ms = float(value)  # 0 written by SDO: heartbeat disabled
            elif index == 0x100C:
                cfg.guard_time_ms = float(value) or None
            elif index == 0x100D:
                cfg.life_time_factor = value or None
            elif 0x1800 <= index <= 0x1803 or 0x1400 <= index <= 0x1403:
                table = cfg.tpdo_cob_ids if index >= 0x1800 else cfg.rpdo_cob_ids
                table[(index & 0x3) + 1] = None if value & 0x80000000 else value & 0x7FF
        if consumer is not None:
            time_ms = float(int(self.consumer_writes.value[consumer]) & 0xFFFF)
            if cfg.consumer_timeout_ms is None or time_ms < cfg.consumer_timeout_ms:
                cfg.consumer_timeout_ms = time_ms
                cfg.consumer_node = int(self.consumer_writes.node[consumer])
        return cfg

    @cached_property
    def _base_config(self) -> NodeConfig:
        """The files' configuration less the error-control objects written by SDO in the
        trace: what a reset does to a written value differs between stacks (Lely restores
        the power-on value, CANopenNode keeps the written one), and a device's power-on
        value before its master writes is not the file's configured one either, so such
        an object has a known value only while a confirmed write holds (SPEC §6)."""
        written = set(np.unique(self.writes.index).tolist()) if len(self.writes) else set()
        if not written & set(_ERROR_CONTROL_OBJECTS):
            return self.config
        cfg = replace(self.config)
        for index, name in _ERROR_CONTROL_OBJECTS.items():
            if index in written:
                setattr(cfg, name, None)
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
        if not len(self.writes) and not len(self.consumer_writes):  # the files' values only
            value = get(self._base_config)  # what `_configs_at` yields without writes
            return np.full(np.shape(times), np.nan if value is None else value, np.float64)
        moments = [t.ts for t in (self.writes, self.consumer_writes)] + [
            t.until[np.isfinite(t.until)] for t in (self.writes, self.consumer_writes)]
        bps = np.unique(np.concatenate(moments))
        values = [get(cfg) for cfg in self._configs_at([-np.inf, *bps.tolist()])]
        table = np.asarray([np.nan if v is None else v for v in values], np.float64)
        return table[np.searchsorted(bps, times, side="right")]

    def heartbeat_pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """Consecutive heartbeats with no boot-up or reset command of the node between them,
        as two arrays of positions in `ec`: the intervals the period is measured from
        (SPEC §2), H003 compares and the report summarises."""
        cached = self._pairs
        ec = self.ec
        stamp = ec.__dict__.get("kind", ec)  # kind_stamp(ec), inline: 20 calls a node
        if cached is not None and cached[0] is stamp:
            return cached[1]
        if self.kind_counts()[HEARTBEAT] < 2:  # no pair (most nodes of many channels)
            self._pairs = None  # nothing to keep: the test above is as quick
            return _NO_IDX, _NO_IDX
        kind = self.ec.kind
        if self.small is not None:  # no command: consecutive heartbeats, from the lists
            k = self.small.kind
            first = [i for i in range(len(k) - 1) if k[i] == k[i + 1] == HEARTBEAT]
            a = np.asarray(first, np.int64)
            self._pairs = (stamp, (a, a + 1))
            return a, a + 1
        pos = np.flatnonzero((kind == HEARTBEAT) | (kind == BOOTUP))
        a, b = pos[:-1], pos[1:]
        ok = (kind[a] == HEARTBEAT) & (kind[b] == HEARTBEAT)
        ok &= ~between(self.commands.reset_idx, self.ec.idx[a], self.ec.idx[b])
        pairs = (a[ok], b[ok])
        self._pairs = (stamp, pairs)
        return pairs

    def kind_counts(self) -> tuple[int, ...]:
        """How many of N's error-control frames are of each kind (indexed by `REQUEST`,
        `BOOTUP`, ...; dropped runs not counted), computed once per classification: a
        rule returns at once for a node with none of the kinds it looks at (most nodes of
        a log of many channels have a frame or two)."""
        cached = self._kinds
        ec = self.ec
        stamp = ec.__dict__.get("kind", ec)  # kind_stamp(ec), inline: 20 calls a node
        if cached is not None and cached[0] is stamp:
            return cached[1]
        counts = tuple(np.bincount(self.ec.kind, minlength=len(EC_KIND_NAMES)).tolist())
        if len(self.ec) <= FEW_ROWS:  # one tuple per distinct count of few frames, shared:
            counts = _FEW_COUNTS.setdefault(counts, counts)  # nodes of many channels
        self._kinds = (stamp, counts)
        return counts

    def heartbeat_intervals(self) -> np.ndarray:
        """The pairs' intervals as they stand in `ec` (a compacted run's pair spans the
        whole run: `heartbeat_gaps` counts its intervals)."""
        a, b = self.heartbeat_pairs()
        gaps: np.ndarray = self.ec.ts[b] - self.ec.ts[a]
        return gaps

    def heartbeat_gaps(self, pairs: np.ndarray | None = None) -> Gaps:
        """The intervals of these heartbeat pairs (positions in `heartbeat_pairs()`; None:
        all) as a multiset: the pair around a dropped run of a long log counts as the
        run's intervals (`ec_compact`)."""
        a, b = self.heartbeat_pairs()
        if pairs is not None:
            a, b = a[pairs], b[pairs]
        gaps = self.ec.ts[b] - self.ec.ts[a]
        runs = self.ec.runs
        if runs is None:
            return Gaps(gaps)
        r = runs.at_rows(b)
        plain = r < 0
        return Gaps.join(gaps[plain], runs.hists(r[~plain]))

    @property
    def heartbeats(self) -> list[EcFrame]:
        return self.ec.frames(self.ec.where(HEARTBEAT))

    @property
    def bootups(self) -> list[EcFrame]:
        return self.ec.frames(self.ec.where(BOOTUP))

    @property
    def bootup_count(self) -> int:
        return self.kind_counts()[BOOTUP]

    @property
    def is_producer(self) -> bool:
        if self.config.heartbeat_ms is not None and self.config.heartbeat_ms > 0:
            return True
        if len(self.writes) and bool(((self.writes.index == 0x1017)
                                      & (self.writes.value != 0)).any()):
            return True
        if self.ec.runs is None:  # no dropped runs: the count of the classification
            return self.kind_counts()[HEARTBEAT] >= 2
        return self.ec.count(HEARTBEAT) >= 2

    def periods_at(self, times: np.ndarray) -> np.ndarray:
        """N's heartbeat period in force at each time (SPEC §2): the producer time (1017h)
        in force if non-zero, else the median interval of the producer-time segment
        holding that time, else the whole-trace median (NaN if none is known)."""
        times = np.asarray(times, np.float64)
        series = self.config_series(times, lambda cfg: cfg.heartbeat_ms)
        return np.where(series > 0, series / 1000.0, self.measured_periods_at(times))

    def measured_periods_at(self, times: np.ndarray) -> np.ndarray:
        """The measured period of the producer-time segment holding each time."""
        fallback = self.median_s if self.median_s and self.median_s > 0 else np.nan
        seg = self.seg_median[np.searchsorted(self.seg_bounds, times, side="right")]
        return np.where(seg > 0, seg, fallback)

    def measured_period_at(self, t: float) -> float:
        """`measured_periods_at` for one time, in Python numbers (the small nodes' paths)."""
        fallback = self.median_s if self.median_s and self.median_s > 0 else np.nan
        seg = float(self.seg_median[bisect.bisect_right(self.seg_bounds.tolist(), t)])
        return seg if seg > 0 else fallback

    def hb_timeouts_at(self, times: np.ndarray, timeout_factor: float) -> np.ndarray:
        """`hb_timeout` at each time, the measured period being the segment's (NaN where
        there is none: no period known, or 1017h = 0 written)."""
        times = np.asarray(times, np.float64)
        hb = self.config_series(times, lambda cfg: cfg.heartbeat_ms)
        cons = self.config_series(times, lambda cfg: cfg.consumer_timeout_ms or None)
        period = np.where(hb > 0, hb / 1000.0, self.measured_periods_at(times))
        return np.where(hb == 0, np.nan,
                        np.where(cons > 0, cons / 1000.0, timeout_factor * period))

    def interval_starts(self) -> np.ndarray:
        return self.intervals.start

    def state_at(self, ts: float) -> str:
        """State after the evidence of a frame at `ts` (intervals starting at ts included)."""
        return STATES[self.intervals.state[self.interval_index(ts)]]

    def known_at(self, ts: np.ndarray) -> np.ndarray:
        """Whether the state is known (not UNKNOWN) at each time: findings of a node in
        UNKNOWN are dropped (SPEC §3)."""
        known: np.ndarray = self.intervals.state[self.interval_indices(ts)] != _UNKNOWN
        return known

    def interval_index(self, ts: float) -> int:
        return max(int(np.searchsorted(self.interval_starts(), ts, side="right")) - 1, 0)

    def interval_indices(self, ts: np.ndarray) -> np.ndarray:
        """`interval_index` for many times at once."""
        return np.maximum(np.searchsorted(self.interval_starts(), ts, side="right") - 1, 0)

    @property
    def error_control(self) -> str:
        k = self.kind_counts()  # dropped runs (`ec.runs`) are heartbeats too
        hb = bool(k[HEARTBEAT]) or (self.ec.runs is not None and bool(self.ec.count(HEARTBEAT)))
        guard = bool(k[GUARD])
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
    bootup_grace_s: float = 0.005  # B001: frames this soon after a reset were queued before
    order_only: bool = False  # no timestamps: the frame index is the time, no timeouts
    repeat_window_ms: float = 0.0  # B003: boot-ups this close repeat (0: auto); B002 skips them


@dataclass
class RecordingGap:
    """No frame on the channel in (start, end) for longer than every heartbeat and
    guarding limit running there (SPEC §3 I007); the frame at `end` (index, line) resumes
    it."""

    start: float
    end: float
    end_idx: int
    end_line: int
    limit_s: float  # the longest heartbeat or guarding limit running at its start
    nodes: list[int] = field(default_factory=list)  # whose limits ran out inside it

    @property
    def seconds(self) -> float:
        return self.end - self.start


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
    # the channel's trace span: the input's, or its capture's (nmtcheck/readers/captures.py)
    start: float = 0.0
    end: float = 0.0
    log_name: str = ""  # its name in the log and the files ("" : `name`)
    first_index: int = 0  # the frame its capture begins at (0: the input's first)
    first_line: int | None = None  # that frame's line, for a later capture
    # the channel's recording gaps (SPEC §3 I007: nmtcheck/timeline/recording_gaps.py)
    recording_gaps: list[RecordingGap] = field(default_factory=list)

    @property
    def network_name(self) -> str:
        """The name the network and device files know the channel by."""
        return self.log_name or self.name


@dataclass
class InputModel:
    """The decoded input with its per-node models."""

    decoded: Decoded
    start: float
    end: float
    channels: list[ChannelModel]
    timeline: TimelineParams = field(default_factory=TimelineParams)  # what it was built with
    expected: list[tuple[int, str | None]] = field(default_factory=list)  # network file nodes
    stats: Any = None  # the reader's InputStats (the I-rules judge the input itself)
    # sent_while() by states and kinds: one pass over the node-frame store each
    _sent_while: dict[tuple[tuple[str, ...], tuple[int, ...] | None], SentFrames] = field(
        default_factory=dict, init=False, repr=False, compare=False)

    def nodes(self) -> Iterator[NodeModel]:
        """Every node, channels in model order, nodes in number order."""
        for cm in self.channels:
            yield from cm.nodes.values()

    def end_of(self, channel: str | None) -> float:
        """The end of a channel's trace: the input's, or its capture's."""
        return self._channel_ends.get(channel, self.end)  # type: ignore[arg-type]

    @cached_property
    def _channel_ends(self) -> dict[str, float]:
        return {cm.name: cm.end for cm in self.channels}

    def events(self) -> Iterator[tuple[NodeModel, NodeEvent]]:
        """Every node's events (EMCY, SDO aborts and writes) in file order, each made when
        it is reached: a log may hold millions of EMCYs."""
        return heapq.merge(*(_tagged(m) for m in self.nodes() if m.events),
                           key=lambda me: me[1].idx)

    def event_count(self) -> int:
        return sum(len(m.events) for m in self.nodes())

    def first_tx_after_resets(self, m: NodeModel) -> NodeFrames:
        """Per reset command to N (in file order): N's first TPDO, SDO response or EMCY at
        or after it, as columns (idx -1: none)."""
        answered, frames = self._first_tx_after_resets.get(m.key, (None, None))
        found = NodeFrames.none(len(m.commands.reset_idx))
        if answered is not None and frames is not None:
            found.ts[answered], found.idx[answered] = frames.ts, frames.idx
            found.line[answered], found.kind[answered] = frames.line, frames.kind
        return found

    @cached_property
    def _first_tx_after_resets(self) -> dict[int, tuple[np.ndarray, NodeFrames]]:
        """Only the answered resets, per node key: a log may reset its nodes millions of
        times and have no other frame. Nodes are asked in groups of about a million
        resets, one pass over the node-frame store each."""
        answers: dict[int, tuple[np.ndarray, NodeFrames]] = {}
        if not len(self.decoded.node_frames):
            return answers
        groups: list[list[NodeModel]] = [[]]
        size = 0
        for m in self.nodes():
            if m.key not in self.decoded.first_tx:  # it never sent anything
                continue
            if size >= QUERY_GROUP:
                groups.append([])
                size = 0
            groups[-1].append(m)
            size += int(np.count_nonzero(m.commands.is_reset))
        for group in filter(None, groups):
            resets = [(m.key, m.commands.reset_ts, m.commands.reset_idx) for m in group]
            found = self.decoded.first_node_frame_after(
                np.concatenate([np.full(len(ts), key) for key, ts, _ in resets]),
                np.concatenate([ts for _, ts, _ in resets]) + self.timeline.bootup_grace_s
                + EPS,
                np.concatenate([idx for _, _, idx in resets]))
            at = 0
            for key, ts, _ in resets:
                mine = found.take(slice(at, at + len(ts)))
                answered = np.flatnonzero(mine.idx >= 0)
                if answered.size:
                    answers[key] = (answered, mine.take(answered))
                at += len(ts)
        return answers

    def sent_while(self, states: tuple[str, ...], kinds: tuple[int, ...] | None = None
                   ) -> SentFrames:
        """The stored node frames (TPDO, RPDO, SDO response, EMCY; only `kinds` if given)
        sent while their node was in one of `states`, with the configured PDO COB-IDs
        applied, in file order.

        Usually a tiny set (a node is OPERATIONAL most of the time), so a rule's exact
        test, grace periods included, runs on it alone. A frame at a time covered by
        such a state of any node is kept: a rule tests its own node's state again.
        `kinds` keeps it tiny where a node talks at length in a state a rule does not
        look at for those frames (an SDO transfer of millions of segments in
        PRE-OPERATIONAL: S003 looks for SDO responses in STOPPED only).
        """
        found = self._sent_while.get((states, kinds))
        if found is None:
            found = self._sent_while[(states, kinds)] = _sent_while(self, states, kinds)
        return found


def _tagged(m: NodeModel) -> Iterator[tuple[NodeModel, NodeEvent]]:
    for e in m.events:
        yield m, e


@dataclass(frozen=True)
class SentFrames:
    """Node frames as columns (see `InputModel.sent_while`)."""

    key: np.ndarray  # chan * 128 + node, after configured PDO COB-IDs
    kind: np.ndarray  # KIND_*, likewise
    can_id: np.ndarray
    ts: np.ndarray
    idx: np.ndarray
    line: np.ndarray


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
    for m in model.nodes():
        for kind, table, bases, index in (
                (KIND_TPDO, m.config.tpdo_cob_ids, TPDO_BASES, 0x1800),
                (KIND_RPDO, m.config.rpdo_cob_ids, RPDO_BASES, 0x1400)):
            spans: list[tuple[int, int | None, float, float]] = [
                (n, cob, -np.inf, np.inf) for n, cob in table.items()]
            if not spans and not len(m.writes):  # most nodes: nothing configured
                continue
            # SDO-written COB-IDs hold until the next boot-up/reset
            pdo = np.flatnonzero((m.writes.index >= index) & (m.writes.index <= index + 3))
            for w in m.writes.take(pdo) if len(pdo) else ():
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


def _other_consumers(chunk: dict[str, np.ndarray], key: np.ndarray, kind: np.ndarray,
                     sel: np.ndarray, overrides: list[_PdoOverride]
                     ) -> tuple[np.ndarray, np.ndarray]:
    """The rows `sel` with their node keys, and again each row an RPDO of several nodes
    reaches (PDO linking to two consumers) under every other consumer's key: each
    consumer is a node the frame is for."""
    rows, keys = [sel], [key[sel].astype(np.int64)]
    for o in overrides:
        if o.kind != KIND_RPDO:
            continue
        ts = chunk["ts"][sel]
        also = sel[(chunk["can_id"][sel] == o.can_id) & (key[sel] // 128 == o.chan)
                   & (ts >= o.start) & (ts < o.until) & (kind[sel] == KIND_RPDO)
                   & (key[sel] != o.key)]
        if also.size:
            rows.append(also)
            keys.append(np.full(also.size, o.key, np.int64))
    if len(rows) == 1:
        return sel, keys[0]
    r, k = np.concatenate(rows), np.concatenate(keys)
    order = np.lexsort((r, k))  # a consumer named by two spans counts once
    r, k = r[order], k[order]
    keep = np.concatenate([[True], (r[1:] != r[:-1]) | (k[1:] != k[:-1])])
    return r[keep], k[keep]


def _windows(model: InputModel, states: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """The union over all nodes of the times they spent in `states`, as sorted [start, end]
    windows: a cheap first filter on time."""
    wanted = [STATE_INDEX[s] for s in states]
    tables = [m.intervals for m in model.nodes() if len(m.intervals)]
    if tables:  # every node's intervals as one set of columns: a log may have 40,000 nodes
        lengths, lo, hi, state = interval_columns(tables)
        ends = np.cumsum(lengths)
        lo[ends - lengths], hi[ends - 1] = -np.inf, np.inf  # the first/last interval of
        keep = is_one_of(state, wanted)  # each node also take stray times
        lo_all, hi_all = lo[keep], hi[keep]
    else:
        lo_all = hi_all = np.zeros(0)
    if not lo_all.size:
        return lo_all.astype(np.float64), hi_all.astype(np.float64)
    by_start = np.lexsort((hi_all, lo_all))
    lo_s, hi_s = lo_all[by_start], hi_all[by_start]
    # vectorised union (a node may have millions of windows): a window opens a new one
    # where it starts after every earlier window ended; each ends at its group's latest end
    reach = np.maximum.accumulate(hi_s)
    opens = np.flatnonzero(np.concatenate([[True], lo_s[1:] > reach[:-1]]))
    return lo_s[opens].astype(np.float64), np.maximum.reduceat(hi_s, opens).astype(np.float64)


def _sent_while(model: InputModel, states: tuple[str, ...], kinds: tuple[int, ...] | None
                ) -> SentFrames:
    if not len(model.decoded.node_frames):  # no PDO, SDO or EMCY at all: nothing to test
        return SentFrames(*(np.zeros(0) for _ in range(6)))
    starts, ends = _windows(model, states)
    parts: list[dict[str, np.ndarray]] = []
    overrides = _pdo_overrides(model)
    for chunk in model.decoded.node_frames if len(starts) else ():
        ts = chunk["ts"]
        w = np.searchsorted(starts, ts, side="right") - 1
        sel = np.flatnonzero((w >= 0) & (ts <= ends[np.maximum(w, 0)] + EPS))
        if not sel.size:
            continue
        key, kind = _attribute(chunk, overrides)
        rows, keys = _other_consumers(chunk, key, kind, sel, overrides)
        if kinds is not None:
            wanted = is_one_of(kind[rows], kinds)
            rows, keys = rows[wanted], keys[wanted]
        order = np.argsort(chunk["idx"][rows], kind="stable")  # file order, each key too
        rows, keys = rows[order], keys[order]
        parts.append({"key": keys, "kind": kind[rows], "can_id": chunk["can_id"][rows],
                      "ts": ts[rows], "idx": chunk["idx"][rows],
                      "line": node_frame_lines(chunk, rows)})
    names = ("key", "kind", "can_id", "ts", "idx", "line")
    return SentFrames(*(np.concatenate([p[n] for p in parts]) if parts else np.zeros(0)
                        for n in names))
