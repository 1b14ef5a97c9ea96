"""Each channel's SYNC, reconstructed once per input (SPEC §9.1.1, §9.1.5): its COB-ID and
producer, the period, window and counter overflow in force with their sources, its frames
and its segments. The Y rules (`checks/sync.py`) and the reports read it; nothing here
judges.

A SYNC segment runs from a SYNC frame to the next segment end: a reset command that
reaches the producer (a broadcast one too), its boot-up, a confirmed SDO write of its
1005h or 1006h, or the trace end. With the producer unknown, every broadcast reset and a
write of 1005h or 1006h to any node end it too (errs towards silence). A stop of the
producer does not end a segment: the consumers miss the SYNC, and Y001 says so.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from nmtcheck.processes.attached import Attached
from nmtcheck.processes.comm_values import UNKNOWN, Value, in_force
from nmtcheck.protocol.nmt import BOOTUP
from nmtcheck.timeline.decode import DEFAULT_SYNC_ID
from nmtcheck.timeline.model import ChannelModel, InputModel

COB_ID_MASK = 0x7FF
PRODUCER_BIT = 1 << 30  # 1005h bit 30: this device produces SYNC
_RESETS = (0x81, 0x82)
_SEGMENT_WRITES = (0x1005, 0x1006)


@dataclass(frozen=True)
class SegmentValues:
    """P (Y001), P_prod (Y005), W and C (1019h) in force in one SYNC segment."""

    period: Value
    producer_period: Value
    window: Value
    overflow: Value


@dataclass
class SyncChannel:
    """One channel's SYNC: where each value came from, and its frames as columns."""

    channel: str
    cob_id: int
    cob_id_source: str  # network | device-file | default
    producer: Value  # the node producing SYNC, if known
    period: Value  # P of Y001 (network, the producer's 1006h, another node's 1006h)
    producer_period: Value  # P_prod of Y005 (network or the producer's 1006h only)
    window: Value  # W (1007h)
    overflow: Value  # C (1019h)
    ts: np.ndarray  # the SYNC frames, file order
    idx: np.ndarray
    line: np.ndarray
    rtr: np.ndarray
    dlc: np.ndarray
    counter: np.ndarray
    segment: np.ndarray  # per frame: the number of segment ends before it (ascending)
    ends: np.ndarray  # the segment ends' times in frame order: segment k ends at ends[k]
    notes: list[str] = field(default_factory=list)  # files that disagree, named
    # per segment (in `segments()` order), the values in force at its first SYNC: an SDO
    # write of 1006h or 1019h takes over from the files from its confirmation (§9.1.3)
    by_segment: list[SegmentValues] = field(default_factory=list)
    # per frame, C (1019h) in force at it (an index into `overflows`): where the producer's
    # is unknown and the nodes' shared value is taken, a write to a consumer in the middle
    # of a segment changes it there
    overflow_at: np.ndarray | None = None
    overflows: list[Value] = field(default_factory=list)

    def end_of(self, pos: np.ndarray) -> np.ndarray:
        """The time each frame's segment ends (inf: at the trace end)."""
        k = self.segment[pos]
        padded = np.append(self.ends, np.inf)
        out: np.ndarray = padded[np.minimum(k, len(self.ends))]
        return out

    def __len__(self) -> int:
        return len(self.ts)

    def segments(self) -> list[np.ndarray]:
        """The positions of each segment's frames."""
        if not len(self.ts):
            return []
        bounds = np.flatnonzero(np.diff(self.segment)) + 1
        return np.split(np.arange(len(self.ts)), bounds)

    def intervals(self) -> np.ndarray:
        """The SYNC intervals inside segments (s)."""
        parts = [np.diff(self.ts[pos]) for pos in self.segments() if len(pos) > 1]
        return np.concatenate(parts) if parts else np.zeros(0)

    def as_dict(self) -> dict[str, Any]:
        """`channels[i].sync` of the JSON report (SPEC §9.4.1)."""
        iv = self.intervals()
        ref = (float(self.period.value or 0) / 1e6 if self.period.known and self.period.value
               else float(np.median(iv)) if len(iv) else None)
        measured: dict[str, Any] = {"intervals": len(iv)}
        if len(iv):
            worst = int(np.argmax(iv))
            starts = np.concatenate([pos[:-1] for pos in self.segments() if len(pos) > 1])
            measured.update({
                "period_min_us": round(float(iv.min()) * 1e6, 1),
                "period_median_us": round(float(np.median(iv)) * 1e6, 1),
                "period_max_us": round(float(iv.max()) * 1e6, 1),
                "jitter_p99_us": round(float(np.percentile(np.abs(iv - ref), 99)) * 1e6, 1)
                if ref is not None else None,
                "worst_gap_us": round(float(iv[worst]) * 1e6, 1),
                "worst_gap_at": round(float(self.ts[starts[worst]]), 6)})
        largest = self.counter[(self.dlc == 1) & ~self.rtr]
        dlcs, counts = np.unique(self.dlc, return_counts=True)
        producer = None if not self.producer.known else {
            "node": self.producer.value, "source": self.producer.source}
        return {"cob_id": f"{self.cob_id:03X}h", "cob_id_source": self.cob_id_source,
                "producer": producer,
                "period_us": self.period.as_dict(),
                "window_us": self.window.as_dict(),
                "counter_overflow": {**self.overflow.as_dict(),
                                     "largest_seen": int(largest.max()) if len(largest)
                                     else None},
                "frames": len(self.ts),
                "dlc": {str(int(d)): int(c) for d, c in zip(dlcs, counts, strict=True)},
                "segments": len(self.segments()), "measured": measured,
                "notes": list(self.notes)}


@dataclass(frozen=True)
class SyncGap:
    """A gap Y001 reported: its last SYNC, the next one (inf: none), the period judged by
    and where that came from (`basis`: configured or measured)."""

    basis: str
    last_ts: float
    last_idx: int
    next_ts: float
    period: float


@dataclass
class SyncAnalysis:
    """Every channel's SYNC (channels with neither SYNC frames nor SYNC configuration have
    none), and each gap Y001 reported, by (channel, finding time): what its causes, the
    basis of its limit (SPEC §7) and the chain links of §9.3.4 read."""

    channels: dict[str, SyncChannel] = field(default_factory=dict)
    gaps: dict[tuple[str, float], SyncGap] = field(default_factory=dict)


_SLOT: Attached[SyncAnalysis] = Attached("sync")
attach = _SLOT.attach  # the engine keeps the analysis with the model
of = _SLOT.of  # the rules and reports read it


def sync_cob_ids(network: Any) -> set[int]:
    """The CAN-IDs the decoder keeps as SYNC frames: 080h, and whatever the files give."""
    ids = {DEFAULT_SYNC_ID}
    if network is None:
        return ids
    for keys in [network.sync, *network.channel_sync.values()]:
        if keys is not None and keys.cob_id is not None:
            ids.add(keys.cob_id & COB_ID_MASK)
    for dev in network.devices.values():
        if dev.sync_cob_id is not None:
            ids.add(dev.sync_cob_id & COB_ID_MASK)
    return ids


def analyse(model: InputModel, network: Any) -> SyncAnalysis:
    """The SYNC of every channel of the model."""
    out = SyncAnalysis()
    cols = model.decoded.sync
    for cm in model.channels:
        sc = _channel(model, cm, network, cols)
        if sc is not None:
            out.channels[cm.name] = sc
    return out


def _channel(model: InputModel, cm: ChannelModel, network: Any,
             cols: dict[str, np.ndarray]) -> SyncChannel | None:
    name = cm.network_name
    keys = network.sync_keys(name) if network is not None else None
    devices = _channel_devices(network, name)
    notes: list[str] = []
    cob_id, cob_source = _cob_id(keys, devices, notes)
    producer = _producer(keys, devices, notes)
    found = np.flatnonzero((cols["chan"] == cm.chan) & (cols["can_id"] == cob_id))
    configured = keys is not None or any(
        d.sync_cob_id is not None or d.sync_period_us for d in devices.values())
    if not len(found) and not configured:
        return None
    # every SYNC of the input is this channel's (the usual case): its columns are the
    # decoded ones, not copies of them (a SYNC costs 36 bytes less: 5 M SYNCs, 180 MB)
    rows: np.ndarray | slice = slice(None) if len(found) == len(cols["ts"]) else found
    ts = cols["ts"][rows]
    idx = cols["idx"][rows]
    p_node = int(producer.value) if producer.known and producer.value is not None else None
    at = float(ts[0]) if len(ts) else cm.start
    pm = cm.nodes.get(p_node) if p_node is not None else None

    def values_at(at: float) -> SegmentValues:
        def of_producer(index: int, net_value: int | None, dev_attr: str) -> Value:
            if net_value is not None:
                return Value(net_value, "network")
            if p_node is None:
                return UNKNOWN
            dev = devices.get(p_node)
            return in_force(pm, p_node, index, 0, at, None,
                            getattr(dev, dev_attr) if dev is not None else None)

        producer_period = of_producer(0x1006, keys.period_us if keys else None,
                                      "sync_period_us")
        period = producer_period if producer_period.known else _consumer_period(
            cm, devices, at)
        window = of_producer(0x1007, keys.window_us if keys else None, "sync_window_us")
        overflow = of_producer(0x1019, keys.counter_overflow if keys else None,
                               "sync_counter_overflow")
        if not overflow.known:
            overflow = _shared_overflow(cm, devices, at, seen)
        return SegmentValues(period, producer_period, window, overflow)

    seen: list[str] = []
    segment, ends = _segments(cm, p_node, idx)
    starts: list[int] = np.flatnonzero(np.diff(segment, prepend=-1)).tolist()
    by_segment = [values_at(float(ts[k])) for k in starts]
    last = by_segment[-1] if by_segment else values_at(at)
    overflow_at, overflows = _overflow_per_frame(cm, ts, starts, by_segment, values_at)
    notes += list(dict.fromkeys(seen))
    return SyncChannel(name, cob_id, cob_source, producer, last.period, last.producer_period,
                       last.window, last.overflow, ts, idx, cols["line"][rows],
                       cols["rtr"][rows], cols["dlc"][rows], cols["counter"][rows], segment,
                       ends, notes, by_segment, overflow_at, overflows)


def _overflow_per_frame(cm: ChannelModel, ts: np.ndarray, starts: list[int],
                        by_segment: list[SegmentValues], values_at: Any
                        ) -> tuple[np.ndarray, list[Value]]:
    """Per SYNC frame, C in force at it: its segment's value, changed where a node's 1019h
    is written (or its write ends with a reset) inside the segment."""
    found: list[Value] = [v.overflow for v in by_segment]
    at = np.zeros(len(ts), np.int64)
    bounds = [*starts, len(ts)]
    for k in range(len(starts)):
        at[bounds[k]:bounds[k + 1]] = k
    segment_of = at.copy()
    marks = []
    for m in cm.nodes.values():
        if len(m.writes):
            w = m.writes.index == 0x1019
            marks += [m.writes.ts[w], m.writes.until[w][np.isfinite(m.writes.until[w])]]
    points = np.unique(np.concatenate(marks)) if marks else np.zeros(0)
    for p in points.tolist():
        lo = int(np.searchsorted(ts, p, side="right"))  # the first SYNC after the change
        if lo >= len(ts):
            continue
        k = int(segment_of[lo])
        value = values_at(p).overflow
        if value == found[int(at[lo])]:
            continue
        found.append(value)
        at[lo:bounds[k + 1]] = len(found) - 1
    return at, found


def _channel_devices(network: Any, channel: str) -> dict[int, Any]:
    """The device files of the nodes that may be on the channel."""
    if network is None:
        return {}
    return {n: d for n, d in network.devices.items()
            if network.node_channel(n) in (None, channel)}


def _cob_id(keys: Any, devices: dict[int, Any], notes: list[str]) -> tuple[int, str]:
    """`[sync] cob_id`, else the 1005h the device files agree on, else 080h (§9.1.1)."""
    if keys is not None and keys.cob_id is not None:
        return keys.cob_id & COB_ID_MASK, "network"
    found = {n: d.sync_cob_id & COB_ID_MASK for n, d in devices.items()
             if d.sync_cob_id is not None}
    values = set(found.values())
    if len(values) == 1:
        return values.pop(), "device-file"
    if len(values) > 1:
        notes.append("the device files disagree on 1005h (" + ", ".join(
            f"node {n}: {v:03X}h" for n, v in sorted(found.items())) + "); 080h taken")
    return DEFAULT_SYNC_ID, "default"


def _producer(keys: Any, devices: dict[int, Any], notes: list[str]) -> Value:
    """`[sync] producer`, else the one node whose 1005h has bit 30 set; never inferred
    from frames (a SYNC frame carries no sender)."""
    if keys is not None and keys.producer is not None:
        return Value(keys.producer, "network")
    claims = sorted(n for n, d in devices.items()
                    if d.sync_cob_id is not None and d.sync_cob_id & PRODUCER_BIT)
    if len(claims) == 1:
        return Value(claims[0], "device-file")
    if len(claims) > 1:
        notes.append(f"nodes {', '.join(map(str, claims))} all have 1005h bit 30 set: "
                     "the SYNC producer is not known")
    return UNKNOWN


def _consumer_period(cm: ChannelModel, devices: dict[int, Any], at: float) -> Value:
    """The smallest non-zero 1006h of the channel's other nodes: the first consumer to
    time out (§9.1.1)."""
    best = UNKNOWN
    for n in sorted(set(devices) | set(cm.nodes)):
        dev = devices.get(n)
        v = in_force(cm.nodes.get(n), n, 0x1006, 0, at, None,
                     dev.sync_period_us if dev is not None else None)
        if v.known and v.value and (not best.known or v.value < (best.value or 0)):
            best = v
    return best


def _shared_overflow(cm: ChannelModel, devices: dict[int, Any], at: float,
                     notes: list[str]) -> Value:
    """The 1019h every node of the channel with a known one has; unknown if they differ
    (the report names them)."""
    found: dict[int, Value] = {}
    for n in sorted(set(devices) | set(cm.nodes)):
        dev = devices.get(n)
        v = in_force(cm.nodes.get(n), n, 0x1019, 0, at, None,
                     dev.sync_counter_overflow if dev is not None else None)
        if v.known:
            found[n] = v
    values = {v.value for v in found.values()}
    if len(values) == 1:
        return next(iter(found.values()))
    if len(values) > 1:
        notes.append("the nodes disagree on 1019h (" + ", ".join(
            f"node {n}: {v.value}" for n, v in found.items()) + "): counter overflow unknown")
    return UNKNOWN


def _segments(cm: ChannelModel, producer: int | None, idx: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """Per SYNC frame (its frame index `idx`), the number of segment ends before it; and
    the segment ends' times in frame order (a frame of segment k ends at the k-th)."""
    nmt = cm.nmt
    reset = nmt.valid & np.isin(nmt.cs, _RESETS)
    target = nmt.target.astype(np.int64)
    hit = reset & (target == 0) if producer is None else reset & (
        (target == 0) | (target == producer))
    ends = [(nmt.idx[hit], nmt.ts[hit])]
    writers = cm.nodes.values() if producer is None else [
        m for m in (cm.nodes.get(producer),) if m is not None]
    for m in writers:
        if len(m.writes):
            w = np.isin(m.writes.index, _SEGMENT_WRITES)
            ends.append((m.writes.idx[w], m.writes.ts[w]))
        if producer is not None:
            boot = m.ec.kind == BOOTUP
            ends.append((m.ec.idx[boot], m.ec.ts[boot]))
    mark_idx = np.concatenate([e[0] for e in ends]).astype(np.int64)
    mark_ts = np.concatenate([e[1] for e in ends]).astype(np.float64)
    order = np.argsort(mark_idx, kind="stable")
    segment: np.ndarray = np.searchsorted(mark_idx[order], idx, side="left")
    return segment, mark_ts[order]
