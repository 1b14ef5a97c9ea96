"""Error-control frames of a very long log, compacted so that memory stays bounded.

A node's heartbeats are the one NMT stream as dense as its period: a field log of days
holds hundreds of millions. Beyond `Compaction.above` rows, the decoder's spool of
error-control rows (on disk) is read back in chunks, and the interior of each steady
run of heartbeats is dropped: plain heartbeats (one data byte, a CiA 301 state, no
remote request) that report the same state as every frame within `margin` frames on
either side, whose intervals all lie within `band` of the node's median interval in
the chunk, and that are neither within `margin` frames of an NMT frame, SDO frame or
boot-up (of any node) of the channel nor within `protect_s` after one (a boot process
anchored on a master's boot-up reads the slaves' next reports); an NMT command that
cannot concern the node's rows does not count (`_barriers`: a command to another node, a
repeat of a start, stop or enter pre-operational the node has obeyed), so that a master
repeating "start all" every 500 ms does not keep every heartbeat. What a rule or report
can tell apart stays: state changes, boot-ups, requests, odd frames, everything near a
command or a configuration write, every irregular interval with its neighbours.

Each dropped run leaves a `GapRuns` row on the kept frame after it: how many frames it
held, its first, smallest and largest interval and where the largest began, and its
intervals' exact value counts, merged per span between events (so a span of a
steady producer costs as many entries as it has distinct intervals, not frames). The
interval statistics (`gaps.Gaps`) read those counts; H001 and H002 cannot fire inside a
run; `validate` checks after the timeline that each run lies inside every limit the
rules apply (timeout, early limit, producer-time tolerance, one segment) and names the
nodes whose runs do not, which are then read back whole from the spool (`restore`).

Node guarding is compacted the same way, by whole exchanges: a steady run of remote
requests each answered by the node (the same state, the toggle bit alternating, at a
steady interval) loses its interior, an even number of answers at a time, so that the
answers kept on either side still alternate. Its `GuardRuns` row keeps what G002 and
G003 judge (the longest wait for an answer, the longest interval between requests)
and the longest silence (for the causes). After the timeline, `readback.unsafe_nodes`
names the nodes whose runs a limit cuts, to be read back whole.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from nmtcheck.spool import ColumnSpool

_STATES = (0x04, 0x05, 0x7F)
EPS = 1e-9


@dataclass(frozen=True)
class Compaction:
    """When and how error-control rows are compacted."""

    above: int = 2_000_000  # rows: a log with fewer is kept whole (no summary anywhere)
    chunk: int = 1 << 20  # rows read back from the spool at a time
    margin: int = 8  # frames (guarding: exchanges) kept on either side of anything a rule sees
    # intervals within this fraction of the chunk's median: real heartbeats jitter (10 ms
    # +-0.5 ms puts intervals 10 % off), while H001 and H002 by default lie 50 % off; a run
    # that a tighter limit cuts is read back whole (`readback.unsafe_nodes`)
    band: float = 0.25
    protect_s: float = 1.0  # frames this long after an NMT or SDO frame are kept
    min_run: int = 32  # shorter runs are kept: a run's summary costs as much as ~12 rows


SETTINGS = Compaction()  # the tests lower `above` and `chunk` to compact small logs


@dataclass
class GapRuns:
    """One node's dropped runs of heartbeats, in file order.

    Run r lies between the node's kept rows `pos[r] - 1` and `pos[r]`: `n[r]` frames were
    dropped there, so `n[r] + 1` intervals; their value counts are those of span
    `span[r]` (shared by the runs of one span, which no event divides)."""

    pos: np.ndarray  # int64: the kept row after each run
    n: np.ndarray  # int64
    first: np.ndarray  # first interval of the run
    gmin: np.ndarray
    gmax: np.ndarray
    gmax_at: np.ndarray  # where the largest interval began
    span: np.ndarray  # int64 index into span_values / span_counts
    span_values: list[np.ndarray] = field(default_factory=list)
    span_counts: list[np.ndarray] = field(default_factory=list)

    @property
    def dropped(self) -> int:
        return int(self.n.sum())

    def hists(self, runs: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """The value counts of the spans these runs (indices) belong to, each span once."""
        return [(self.span_values[s], self.span_counts[s])
                for s in np.unique(self.span[runs]).tolist()]

    def at_rows(self, rows: np.ndarray) -> np.ndarray:
        """Per kept row, the run that ends there (-1: none)."""
        k = np.searchsorted(self.pos, rows)
        kk = np.minimum(k, max(len(self.pos) - 1, 0))
        hit = (k < len(self.pos)) & (self.pos[kk] == rows) if len(self.pos) else k < 0
        return np.where(hit, kk, -1)


@dataclass
class GuardRuns:
    """One node's dropped runs of node guarding, in file order.

    Run r lies between the node's kept rows `pos[r] - 1` (an answer) and `pos[r]` (a
    request): `n[r]` frames were dropped there, half requests and half answers, the
    answers an even number (the answer kept after the run has the toggle bit it had)."""

    pos: np.ndarray  # int64: the kept row after each run
    n: np.ndarray  # int64
    gmax: np.ndarray  # largest interval between two frames, from the kept one before
    gmax_at: np.ndarray  # where it began
    request_gap: np.ndarray  # largest interval between two requests, kept ones around too
    latency: np.ndarray  # longest wait of a dropped request for its answer

    @property
    def dropped(self) -> int:
        return int(self.n.sum())


class _Node:
    """Per node key, what one chunk hands the next."""

    def __init__(self) -> None:
        self.tail: dict[str, np.ndarray] | None = None  # last rows (context + undecided)
        self.tail_odd = np.zeros(0, bool)  # per tail row: it breaks a steady run
        self.odd_base = 0  # rows that break a run before the tail's first row
        self.undecided = 0  # how many rows at the end of `tail` are not yet decided
        self.kept: list[dict[str, np.ndarray]] = []
        self.kept_rows = 0
        self.runs: list[np.ndarray] = []  # rows of (pos, n, first, gmin, gmax, gmax_at, span)
        self.spans: dict[tuple[int, int], int] = {}
        self.span_parts: list[list[tuple[np.ndarray, np.ndarray]]] = []
        self.guard_runs: list[np.ndarray] = []  # rows of GuardRuns' columns


ChannelEvents = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]  # idx, ts, cs, target

_VALID_CS = (0x01, 0x02, 0x80, 0x81, 0x82)
# start, stop, enter pre-operational: the state byte of a node that has carried it out
_COMMANDED_CODE = {0x01: 0x05, 0x02: 0x04, 0x80: 0x7F}


def _events_by_channel(nmt: dict[str, np.ndarray], events: np.ndarray,
                       bootups: dict[str, np.ndarray] | None = None
                       ) -> dict[int, ChannelEvents]:
    """Per channel code, the file indices (sorted) and times of its NMT and SDO frames
    and of every node's boot-ups, with each valid NMT command's specifier and target
    node (-1 for the others): one sort for all channels (a log may have tens of
    thousands). A boot-up divides every node's runs on its channel: a boot process
    anchored on a master's boot-up reads the slaves' next reports (SPEC §8)."""
    valid = ~nmt["rtr"] & (nmt["dlc"] == 2) & np.isin(nmt["cs"], _VALID_CS) & (
        nmt["target"] <= 127)
    boot = bootups or {"chan": np.zeros(0, np.int64), "idx": np.zeros(0, np.int64),
                       "ts": np.zeros(0)}
    chan = np.concatenate([nmt["chan"].astype(np.int64), events["chan"].astype(np.int64),
                           boot["chan"].astype(np.int64)])
    idx = np.concatenate([nmt["idx"], events["idx"], boot["idx"]])
    ts = np.concatenate([nmt["ts"], events["ts"], boot["ts"]])
    none = np.full(len(events) + len(boot["idx"]), -1, np.int16)
    cs = np.concatenate([np.where(valid, nmt["cs"], -1).astype(np.int16), none])
    target = np.concatenate([np.where(valid, nmt["target"], -1).astype(np.int16), none])
    order = np.lexsort((idx, chan))
    chan, idx, ts, cs, target = chan[order], idx[order], ts[order], cs[order], target[order]
    codes, first = np.unique(chan, return_index=True)
    bounds = np.append(first, len(chan)).tolist()
    return {c: (idx[a:b], ts[a:b], cs[a:b], target[a:b])
            for c, a, b in zip(codes.tolist(), bounds[:-1], bounds[1:], strict=True)}


def _barriers(events: ChannelEvents | None, rows: dict[str, np.ndarray], node: int,
              protect_s: float = 0.0) -> tuple[tuple[np.ndarray, np.ndarray] | None, int]:
    """The channel's events among these rows of one node that divide its runs, and how
    many of the channel's events come before the rows. Every event does, except the NMT
    commands that cannot concern the node's rows: a valid command to another node, and
    a repeated start, stop or enter pre-operational that the node has obeyed since the
    same command before it. A master that repeats "start all" to keep its network going
    (every 500 ms, say) would otherwise keep every heartbeat.

    A repeat counts only where nothing could tell it apart: every row of the node from
    the command before through the first report more than `protect_s` (S004's obey
    time) after it reports the commanded state (remote requests aside), time goes
    forward, and no other event of the channel (a boot-up, an SDO configuration frame, a
    malformed frame on 000h) lies in between: a boot process anchored on a master's
    boot-up reads the slaves' next reports. The first command of the kind, any that
    changes a state or that a node ignores stay events, with their `margin` and
    `protect_s`."""
    if events is None or not len(events[0]) or not len(rows["idx"]):
        return None, 0
    e_idx, e_ts, e_cs, e_target = events
    lo = int(np.searchsorted(e_idx, rows["idx"][0]))
    hi = int(np.searchsorted(e_idx, rows["idx"][-1], side="right"))
    idx, ts_e, cs, target = e_idx[lo:hi], e_ts[lo:hi], e_cs[lo:hi], e_target[lo:hi]
    other = (cs >= 0) & (target != 0) & (target != node)
    reaching = np.flatnonzero((cs >= 0) & ~other)
    repeat = np.zeros(len(idx), bool)
    ts = rows["ts"]
    if len(reaching) > 1 and bool((np.diff(ts) >= 0).all()):
        n = len(ts)
        rtr = rows["rtr"]
        state = np.where(~rtr & (rows["dlc"] == 1), rows["value"] & 0x7F, -1)  # toggle bit off
        p = np.searchsorted(rows["idx"], idx[reaching])  # the node's first row after each
        cur, prev = reaching[1:], reaching[:-1]
        p_cur, p_prev = p[1:], p[:-1]
        c_ts = ts_e[cur]
        # through the first report past the obey time (a guarded node's request first)
        end = np.searchsorted(ts, c_ts + protect_s + EPS, side="right")
        end = end + 1 + rtr[np.minimum(end, n - 1)]
        same = (cs[cur] == cs[prev]) & (end <= n)
        end = np.minimum(end, n)
        # time goes forward around both commands
        same &= (p_cur > 0) & (c_ts >= ts[np.maximum(p_cur - 1, 0)]) & (c_ts <= ts[
            np.minimum(p_cur, n - 1)]) & (ts_e[prev] <= c_ts)
        others = np.concatenate([[0], np.cumsum(cs < 0)])  # events not commands, so far
        through = np.searchsorted(idx, rows["idx"][end - 1], side="right")
        same &= others[through] == others[prev + 1]
        for code, want in _COMMANDED_CODE.items():
            cand = same & (cs[cur] == code)
            if cand.any():  # every row since the command before: a request or the state
                ok = np.concatenate([[0], np.cumsum(rtr | (state == want))])
                repeat[cur[cand]] = (ok[end] - ok[p_prev] == end - p_prev)[cand]
    keep = ~(other | repeat)
    return (idx[keep], ts_e[keep]), lo


def compact(spool: ColumnSpool, nmt: dict[str, np.ndarray], events: np.ndarray,
            settings: Compaction, bootups: dict[str, np.ndarray] | None = None
            ) -> tuple[dict[str, np.ndarray], dict[int, GapRuns], dict[int, GuardRuns]]:
    """The spooled error-control rows, grouped by node key as the decoder groups them,
    with the interior of steady heartbeat and guarding runs dropped; and each node's
    runs of either kind."""
    by_chan = _events_by_channel(nmt, events, bootups)
    nodes: dict[int, _Node] = {}
    names = list(spool.dtypes)
    for chunk in spool.chunks(settings.chunk):
        order = np.argsort(chunk["key"], kind="stable")
        keys = chunk["key"][order]
        cut = np.flatnonzero(np.diff(keys)) + 1
        for lo, hi in zip(np.concatenate([[0], cut]).tolist(),
                          np.concatenate([cut, [len(keys)]]).tolist(), strict=True):
            key = int(keys[lo])
            rows = order[lo:hi]
            node = nodes.setdefault(key, _Node())
            _chunk(node, {name: chunk[name][rows] for name in names},
                   by_chan.get(key // 128), key % 128, settings, final=False)
    for key, node in nodes.items():
        if node.tail is not None:
            _chunk(node, {name: node.tail[name][:0] for name in names},
                   by_chan.get(key // 128), key % 128, settings, final=True)
    cols: dict[str, list[np.ndarray]] = {name: [] for name in names}
    runs: dict[int, GapRuns] = {}
    guard_runs: dict[int, GuardRuns] = {}
    for key in sorted(nodes):
        node = nodes[key]
        for part in node.kept:
            for name in names:
                cols[name].append(part[name])
        if node.runs:
            runs[key] = _gap_runs(node)
        if node.guard_runs:
            g = np.vstack(node.guard_runs)
            guard_runs[key] = GuardRuns(g[:, 0].astype(np.int64), g[:, 1].astype(np.int64),
                                        g[:, 2], g[:, 3], g[:, 4], g[:, 5])
    dtypes = spool.dtypes
    return ({name: np.concatenate(parts) if parts else np.zeros(0, dtypes[name])
             for name, parts in cols.items()}, runs, guard_runs)


def _chunk(node: _Node, new: dict[str, np.ndarray], events: ChannelEvents | None,
           node_id: int, s: Compaction, final: bool) -> None:
    """Decide the rows of one node in one chunk (with the previous chunk's tail in
    front); the last rows wait for the next chunk unless this is the last."""
    if node.tail is not None:
        rows = {name: np.concatenate([node.tail[name], col]) for name, col in new.items()}
        start = len(node.tail["ts"]) - node.undecided
        same = _plain_same(rows)
        odd = np.concatenate([node.tail_odd, ~same[len(node.tail["ts"]):]])
    else:
        rows, start = new, 0
        same = _plain_same(rows)
        odd = ~same
    n = len(rows["ts"])
    k = s.margin
    stop = n if final else max(n - 2 * k, start)  # rows [start, stop) are decided now
    barriers, offset = _barriers(events, rows, node_id, s.protect_s)
    before = (offset + np.searchsorted(barriers[0], rows["idx"]) if barriers is not None
              else np.zeros(n, np.int64))  # events before a row that divide its runs
    if events is not None and offset:  # `protect_s` after the event before the rows, too
        last = (events[0][offset - 1:offset], events[1][offset - 1:offset])
        barriers = last if barriers is None else (np.concatenate([last[0], barriers[0]]),
                                                  np.concatenate([last[1], barriers[1]]))
    odd_upto = node.odd_base + np.cumsum(odd)
    if stop > start:
        drop = _droppable(_good(rows, same, barriers, s), before, k, start, stop, final)
        _keep_short_runs(drop, s.min_run)
        # guarding: `margin` counts exchanges (two frames each), as it counts heartbeats;
        # the context kept between chunks (2 * margin + 2 rows) covers such a window
        guard = _droppable(_protected(_guard_good(rows, s), rows, barriers, s), before, 2 * k,
                           start, stop, final)
        _whole_exchanges(guard, rows["rtr"], s.min_run)
        _emit(node, rows, start, stop, drop, before, odd_upto, guard)
    keep_from = max(stop - (2 * k + 2), 0)  # context for the next chunk's windows
    node.odd_base = int(odd_upto[keep_from - 1]) if keep_from else node.odd_base
    # copies: a view would keep the chunk's rows of the node alive, and a log of many
    # captures (a channel each) has a node key ending in every one of them
    node.tail = {name: col[keep_from:].copy() for name, col in rows.items()}
    node.tail_odd = odd[keep_from:].copy()
    node.undecided = n - stop


def _droppable(good: np.ndarray, before: np.ndarray, k: int, start: int, stop: int,
               final: bool) -> np.ndarray:
    """Rows in [start, stop) that may go: every row within `k` of it is good and no
    channel event lies among them (`before`: the channel's events before each row)."""
    n = len(good)
    drop = np.zeros(n, bool)
    bad = np.concatenate([[0], np.cumsum(~good)])
    i = np.arange(n)
    lo, hi = i - k, i + k
    inside = (lo >= 0) & (hi < n)
    lo_c, hi_c = np.clip(lo, 0, n - 1), np.clip(hi, 0, n - 1)
    quiet = inside & (bad[hi_c + 1] - bad[lo_c] == 0) & (before[lo_c] == before[hi_c])
    drop[start:stop] = quiet[start:stop]
    if not final:
        drop[stop - 1] = False  # runs end inside a chunk: its last decided row stays
    return drop


def _runs_of(drop: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The runs of True in `drop` as [start, end) bounds."""
    edges = np.diff(np.concatenate([[0], drop.astype(np.int8), [0]]))
    return np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)


def _whole_exchanges(drop: np.ndarray, rtr: np.ndarray, min_run: int) -> None:
    """Trim each guarding run to whole exchanges (from a request to an answer) and an even
    number of answers: the answers kept on either side then alternate as before. Runs
    shorter than `min_run` after that stay."""
    for s_, e_ in zip(*(b.tolist() for b in _runs_of(drop)), strict=True):
        a, b = s_, e_
        if not rtr[a]:
            a += 1
        if b > a and rtr[b - 1]:
            b -= 1
        if (b - a) % 4:  # an odd number of answers: one exchange more stays
            b -= 2
        drop[s_:e_] = False
        if b - a >= min_run:
            drop[a:b] = True


def _keep_short_runs(drop: np.ndarray, min_run: int) -> None:
    """Runs of fewer than `min_run` dropped rows stay (their summary would cost more)."""
    if min_run <= 1 or not drop.any():
        return
    s_runs, e_runs = _runs_of(drop)
    short = e_runs - s_runs < min_run
    if short.any():
        mark = np.zeros(len(drop) + 1, np.int64)
        np.add.at(mark, s_runs[short], 1)
        np.add.at(mark, e_runs[short], -1)
        drop &= np.cumsum(mark[:-1]) == 0


def _good(rows: dict[str, np.ndarray], same: np.ndarray,
          events: tuple[np.ndarray, np.ndarray] | None, s: Compaction) -> np.ndarray:
    """Rows that may be part of a steady run: plain heartbeats reporting the state of the
    row before them (`same`), an interval in band, not just after an NMT or SDO frame."""
    ts = rows["ts"]
    good: np.ndarray = same.copy()
    good[0] = False
    gap = np.diff(ts, prepend=np.nan)
    plain = good[1:]
    ref = np.median(gap[1:][plain]) if np.count_nonzero(plain) else np.nan
    with np.errstate(invalid="ignore"):
        good &= (gap > 0) & (np.abs(gap - ref) <= s.band * ref)
    return _protected(good, rows, events, s)


def _guard_good(rows: dict[str, np.ndarray], s: Compaction) -> np.ndarray:
    """Rows of a steady guarding exchange: a remote request between two answers, or an
    answer (one byte, a CiA 301 state) between two requests that reports the state of
    the answer before it with the other toggle bit; each at the interval of the rows of
    its kind (request to request, answer to answer) within `band` of their median, time
    going forward."""
    rtr, ts = rows["rtr"], rows["ts"]
    value = rows["value"].astype(np.int64)
    n = len(ts)
    answer = ~rtr & (rows["dlc"] == 1)
    answer &= np.isin(value & 0x7F, _STATES)
    good = np.zeros(n, bool)
    if n < 3:
        return good
    good[1:-1] = (rtr[1:-1] & answer[:-2] & answer[2:]) | (answer[1:-1] & rtr[:-2] & rtr[2:])
    good[2:] &= rtr[2:] | (answer[:-2] & ((value[2:] & 0x7F) == (value[:-2] & 0x7F))
                           & (((value[2:] ^ value[:-2]) & 0x80) != 0))
    good[:2] = False
    gap2 = np.full(n, np.nan)
    gap2[2:] = ts[2:] - ts[:-2]
    ref = np.median(gap2[good]) if good.any() else np.nan
    with np.errstate(invalid="ignore"):
        good &= (gap2 > 0) & (np.abs(gap2 - ref) <= s.band * ref)
        good[1:] &= ts[1:] >= ts[:-1]
    return good


def _protected(good: np.ndarray, rows: dict[str, np.ndarray],
               events: tuple[np.ndarray, np.ndarray] | None, s: Compaction) -> np.ndarray:
    """`good` less the rows within `protect_s` after an NMT or SDO frame of the channel."""
    ts = rows["ts"]
    if events is not None and len(events[0]):
        k = np.searchsorted(events[0], rows["idx"]) - 1
        has = k >= 0
        since = ts - events[1][np.maximum(k, 0)]
        good &= ~(has & (since <= s.protect_s + EPS))
    return good


def _emit(node: _Node, rows: dict[str, np.ndarray], start: int, stop: int, drop: np.ndarray,
          before: np.ndarray, odd_upto: np.ndarray, guard: np.ndarray) -> None:
    """Keep the decided rows that stay, and summarise each run of dropped ones (`drop`:
    heartbeats, `guard`: guarding exchanges)."""
    ts = rows["ts"]
    keep = np.flatnonzero(~(drop | guard)[start:stop]) + start
    first_kept = node.kept_rows  # the node's kept rows so far
    node.kept.append({name: col[keep] for name, col in rows.items()})
    node.kept_rows += len(keep)
    for s_, e_ in zip(*(b.tolist() for b in _runs_of(guard)), strict=True):
        gaps = np.diff(ts[s_ - 1:e_ + 1])  # from the kept answer before to the request after
        j = int(np.argmax(gaps))
        requests = ts[s_ - 2:e_ + 1:2]  # the kept request before, the dropped ones, the next
        node.guard_runs.append(np.asarray([
            first_kept + int(np.searchsorted(keep, e_)), e_ - s_, gaps.max(), ts[s_ - 1 + j],
            np.diff(requests).max(), (ts[s_ + 1:e_:2] - ts[s_:e_:2]).max()], np.float64))
    for s_, e_ in zip(*(b.tolist() for b in _runs_of(drop)), strict=True):
        gaps = np.diff(ts[s_ - 1:e_ + 1])  # from the kept row before to the kept row after
        j = int(np.argmax(gaps))
        b_pos = first_kept + int(np.searchsorted(keep, e_))  # e_ is the kept row after
        span_key = (int(before[s_]), int(odd_upto[s_]))
        span = node.spans.get(span_key)
        if span is None:
            span = node.spans[span_key] = len(node.span_parts)
            node.span_parts.append([])
        parts = node.span_parts[span]
        parts.append(np.unique(gaps, return_counts=True))
        if len(parts) > 16:
            node.span_parts[span] = [_merge(parts)]
        node.runs.append(np.asarray([b_pos, e_ - s_, gaps[0], gaps.min(), gaps.max(),
                                     ts[s_ - 1 + j], span], np.float64))


def _plain_same(rows: dict[str, np.ndarray]) -> np.ndarray:
    """Plain heartbeats (one data byte, a CiA 301 state) reporting the row before's state."""
    value = rows["value"]
    ok: np.ndarray = ~rows["rtr"] & (rows["dlc"] == 1)
    ok &= (value == _STATES[0]) | (value == _STATES[1]) | (value == _STATES[2])
    ok[1:] &= value[1:] == value[:-1]
    return ok


def _merge(parts: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    values = np.concatenate([v for v, _ in parts])
    counts = np.concatenate([c for _, c in parts]).astype(np.int64)
    uniq, inverse = np.unique(values, return_inverse=True)
    return uniq, np.bincount(inverse, weights=counts, minlength=len(uniq)).astype(np.int64)


def _gap_runs(node: _Node) -> GapRuns:
    r = np.vstack(node.runs)
    spans = [_merge(p) for p in node.span_parts]
    return GapRuns(r[:, 0].astype(np.int64), r[:, 1].astype(np.int64), r[:, 2], r[:, 3],
                   r[:, 4], r[:, 5], r[:, 6].astype(np.int64),
                   [v for v, _ in spans], [c for _, c in spans])


def restore(spool: ColumnSpool, cols: dict[str, np.ndarray], runs: dict[int, GapRuns],
            guard_runs: dict[int, GuardRuns], keys: set[int], chunk: int
            ) -> tuple[dict[str, np.ndarray], dict[int, GapRuns], dict[int, GuardRuns]]:
    """The columns with every row of these node keys read back from the spool (their runs
    gone): for nodes whose runs a rule limit cuts through."""
    keep = ~np.isin(cols["key"], list(keys))
    parts: dict[str, list[np.ndarray]] = {name: [col[keep]] for name, col in cols.items()}
    wanted = np.asarray(sorted(keys), np.int64)
    for c in spool.chunks(chunk):
        sel = np.flatnonzero(np.isin(c["key"], wanted))
        for name in parts:
            parts[name].append(c[name][sel])
    joined = {name: np.concatenate(p) for name, p in parts.items()}
    order = np.argsort(joined["key"], kind="stable")  # restored rows after kept: by idx
    out = {name: col[order] for name, col in joined.items()}
    # within a key the restored rows are in file order already; kept rows of other keys too
    return (out, {k: r for k, r in runs.items() if k not in keys},
            {k: r for k, r in guard_runs.items() if k not in keys})


def expanded(ts: np.ndarray, runs: GapRuns | GuardRuns, lo: float, hi: float
             ) -> Iterator[np.ndarray]:
    """Stand-in times inside each run that overlaps [lo, hi], spaced by its largest
    interval: no silence longer than that can hide in a run (for the causes' bus
    silence)."""
    for r in np.flatnonzero((ts[runs.pos - 1] < hi) & (ts[runs.pos] > lo)).tolist():
        a, b = float(ts[runs.pos[r] - 1]), float(ts[runs.pos[r]])
        step = float(runs.gmax[r])
        if step > 0:
            yield np.arange(max(a, lo - step), min(b, hi + step), step)
