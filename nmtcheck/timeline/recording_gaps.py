"""Recording gaps (SPEC §3 I007): the whole channel silent for longer than every
heartbeat and guarding limit running there, then its producers resume.

A log cannot tell a recorder that was off (a clock stepped forward, two recordings
joined with `cat`, a logger that paused) from a network that was off: every producer
falls silent at once. Judged as a network, each of them would be an H001 (or G002), and
a gate would fail on what may be the recorder's. The gap is reported once (I007) and the
timeouts do not count the time inside it: their limits count again from its end, so a
node that stays silent after it is still judged, from there. A single node falling silent
while others send is no such gap (the channel has frames): that stays H001. Nor is the
silence of a channel where only one node had a limit running: "every producer falls
silent together" needs two of them.

Silence is looked for in every frame of the input (`Decoded.frame_times`: extended and
error frames too, all channels): a recorder that was off records no channel, while a
channel silent as another one records was the network's, not the recorder's.
"""

from __future__ import annotations

import bisect

import numpy as np

from nmtcheck.protocol.nmt import BOOTUP, EPS, GUARD, HEARTBEAT, REQUEST
from nmtcheck.timeline.decode import Decoded, frame_time_lines
from nmtcheck.timeline.error_control import guard_timeouts
from nmtcheck.timeline.model import (
    ChannelModel,
    NodeModel,
    RecordingGap,
    TimelineParams,
    Timeout,
)

# Producers whose limits must run out together: one node alone falling silent is H001
# (SPEC §3), even on a channel where it is the only one (the gate keeps as an error what
# the log cannot tell apart).
MIN_NODES = 2


def find_recording_gaps(decoded: Decoded, channels: list[ChannelModel],
                        params: TimelineParams, bounds: list[int]) -> None:
    """Find each channel's recording gaps (`cm.recording_gaps`) and take their time out of
    its nodes' H001 and G002 timeouts (before OFFLINE is ended by the nodes' frames).

    `bounds`: the frame index where each capture of the input begins (sorted; a channel
    of a later capture looks at its own capture's frames only)."""
    if params.order_only:
        return
    queries = [(cm, t) for cm in channels for m in cm.nodes.values() for t in m.timeouts]
    if not queries:  # nothing timed out: no gap to look for (a healthy log pays nothing)
        return
    ranges = [_capture_range(cm, bounds) for cm, _t in queries]
    moments = np.asarray([t.moment for _cm, t in queries], np.float64)
    before, after, after_idx, after_line = _around(decoded, moments, ranges)
    by_channel: dict[int, dict[tuple[float, float], tuple[int, int]]] = {}
    for q, (qcm, _t) in enumerate(queries):
        if np.isfinite(before[q]) and np.isfinite(after[q]):  # frames on both sides
            by_channel.setdefault(id(qcm), {}).setdefault(
                (float(before[q]), float(after[q])), (int(after_idx[q]), int(after_line[q])))
    for cm in channels:
        found = by_channel.get(id(cm), {})
        views: dict[int, _Limits] = {}
        for (a, b), (idx, line) in sorted(found.items()):
            running = {m.node: lims for m in cm.nodes.values()
                       if (lims := _running(views.get(m.node) or views.setdefault(
                           m.node, _Limits(m, params)), a))}
            limits = [lim for lims in running.values() for lim in lims]
            if len(running) < MIN_NODES or b - a <= max(limits) + EPS:
                continue  # one node's silence (H001), or a limit the silence did not reach
            if not any(_resumes(cm.nodes[n], b) for n in running):
                continue  # none of them goes on after it
            cm.recording_gaps.append(RecordingGap(a, b, idx, line, max(limits)))
        if cm.recording_gaps:
            for m in cm.nodes.values():
                for k in _take_out(m, cm.recording_gaps, params, cm.end):
                    cm.recording_gaps[k].nodes.append(m.node)


def _resumes(m: NodeModel, at: float) -> bool:
    """Whether `m` sends anything at or after `at`."""
    return (m.last_seen is not None and m.last_seen >= at - EPS) or bool(
        len(m.ec) and float(m.ec.ts.max()) >= at - EPS)


def _capture_range(cm: ChannelModel, bounds: list[int]) -> tuple[int, int]:
    """The frame indices [lo, hi) of the channel's capture."""
    lo = cm.first_index
    hi = next((b for b in bounds if b > lo), np.iinfo(np.int64).max)
    return lo, hi


def _around(decoded: Decoded, moments: np.ndarray, ranges: list[tuple[int, int]]
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """For each moment: the latest frame time at or before it and the earliest after it
    among the frames of its capture range (-inf / inf: none), with the index and line of
    the one after. One pass over the frame times."""
    n = len(moments)
    before, after = np.full(n, -np.inf), np.full(n, np.inf)
    after_idx, after_line = np.full(n, -1, np.int64), np.zeros(n, np.int64)
    groups: dict[tuple[int, int], np.ndarray] = {}
    for q, r in enumerate(ranges):
        groups.setdefault(r, np.zeros(0, np.int64))
        groups[r] = np.append(groups[r], q)
    for chunk in decoded.frame_times:
        ts = chunk["ts"]
        if not len(ts):
            continue
        base = int(chunk["base"][0])
        lines: np.ndarray | None = None
        for (lo, hi), qs in groups.items():
            a, z = max(lo - base, 0), min(hi - base, len(ts))
            if a >= z:
                continue
            part = ts[a:z]
            lo_t, hi_t = float(part.min()), float(part.max())
            if hi_t <= float(moments[qs].min()):  # all before the moments: no sort needed
                before[qs] = np.maximum(before[qs], hi_t)
                continue
            if lo_t > float(moments[qs].max()):  # all after them
                better = lo_t < after[qs]
                if better.any():
                    row = a + int(np.argmin(part))
                    lines = frame_time_lines(chunk) if lines is None else lines
                    sel = qs[better]
                    after[sel], after_idx[sel], after_line[sel] = lo_t, base + row, lines[row]
                continue
            order = np.argsort(part, kind="stable")
            sorted_ts = part[order]
            k = np.searchsorted(sorted_ts, moments[qs], side="right")
            has_before = k > 0
            cand = np.where(has_before, sorted_ts[np.maximum(k - 1, 0)], -np.inf)
            before[qs] = np.maximum(before[qs], cand)
            has_after = k < len(sorted_ts)
            cand = np.where(has_after, sorted_ts[np.minimum(k, len(sorted_ts) - 1)], np.inf)
            better = cand < after[qs]
            if better.any():
                if lines is None:
                    lines = frame_time_lines(chunk)
                rows = a + order[np.minimum(k, len(sorted_ts) - 1)]
                sel = qs[better]
                after[sel] = cand[better]
                after_idx[sel] = base + rows[better]
                after_line[sel] = lines[rows[better]]
    return before, after, after_idx, after_line


class _Limits:
    """What `_running` reads of one node, found once: a channel may have thousands of
    candidate gaps, each asking every node (a scan of the node's frames for each was
    quadratic)."""

    def __init__(self, m: NodeModel, params: TimelineParams) -> None:
        ec = m.ec
        self.m, self.params = m, params
        self.beats = np.zeros(0, np.int64)
        if m.is_producer:
            self.beats = np.flatnonzero((ec.kind == HEARTBEAT) | (ec.kind == BOOTUP))
        self.beat_ts = ec.ts[self.beats]
        self.beat_is_hb = ec.kind[self.beats] == HEARTBEAT
        self.resets = np.sort(m.commands.reset_ts)
        self.requests = np.zeros(0, np.int64)
        if m.kind_counts()[REQUEST]:
            self.requests = ec.where(REQUEST, GUARD, BOOTUP)
        self.request_ts = ec.ts[self.requests]
        self.is_request = ec.kind[self.requests] == REQUEST


def _running(v: _Limits, at: float) -> list[float]:
    """The limits of the node of `v` running at `at`: its heartbeat timeout when a gap
    opened by a heartbeat has not yet expired there, the guarding response timeout when
    a request to it is still pending."""
    out: list[float] = []
    params = v.params
    k = int(np.searchsorted(v.beat_ts, at + EPS, side="right")) - 1
    if k >= 0 and v.beat_is_hb[k]:
        t0 = float(v.beat_ts[k])
        resets = v.resets  # none in (t0, at]
        if np.searchsorted(resets, t0, side="right") == np.searchsorted(
                resets, at + EPS, side="right"):
            limit = float(v.m.hb_timeouts_at(np.asarray([t0]), params.timeout_factor)[0])
            if np.isfinite(limit) and limit > 0 and t0 + limit > at - EPS:
                out.append(limit)
    k = int(np.searchsorted(v.request_ts, at + EPS, side="right")) - 1
    if k >= 0 and v.is_request[k] and (
            float(v.request_ts[k]) + params.response_timeout_s > at - EPS):
        out.append(params.response_timeout_s)
    return out


def _take_out(m: NodeModel, gaps: list[RecordingGap], params: TimelineParams,
              end: float) -> list[int]:
    """Take the gaps' time out of m's timeouts that ran out inside one: an H001 counts
    again from the gap's end (a finding only where the node stays silent for its limit
    after it), a G002 run is walked again with the gaps known. The gaps (their positions
    in `gaps`, in time order) where m had one."""
    starts = [g.start for g in gaps]

    def within(t: Timeout) -> int:
        k = bisect.bisect_left(starts, t.moment) - 1  # the last gap that began before it
        if k >= 0 and t.moment <= gaps[k].end + EPS and t.after_ts <= gaps[k].start + EPS:
            return k
        return -1

    kept: list[Timeout] = []
    touched: set[int] = set()
    walk_again = False
    for t in m.timeouts:
        k = within(t)
        while k >= 0 and t.rule == "H001":
            touched.add(k)
            gap = gaps[k]
            until = end if t.gap_s is None else t.after_ts + t.gap_s
            if until - gap.end <= t.limit_s + EPS:  # it spoke within its limit after it
                break
            t = Timeout("H001", gap.end + t.limit_s, gap.end, t.after_idx, t.limit_s,
                        None if t.gap_s is None else until - gap.end)
            k = within(t)  # silent on after the gap: judged from there (maybe another gap)
        else:
            if t.rule == "G002":  # walked again below: a run's later requests may wait
                walk_again = True  # into a gap even when its first timed out before it
                if k >= 0:
                    touched.add(k)
            elif k >= 0:
                touched.add(k)
            else:
                kept.append(t)
    if not touched and not walk_again:
        return []
    m.timeouts = kept
    if walk_again:
        guard_timeouts(m, params, end, [(g.start, g.end) for g in gaps])
    m.timeouts.sort(key=lambda t: t.moment)
    return sorted(touched)
