"""Decoded events -> per (channel, node) NMT state timeline (SPEC §2).

Each node's error-control frames are numpy columns (`EcTable`): they are
classified (boot-up, heartbeat, guarding response), the heartbeat period is
found (configured, else the median interval), heartbeat and guarding timeouts
are computed, and finally the state intervals are built, with OFFLINE from each
timeout to the node's next frame of any kind. Everything is vectorised per node
but the interval walk, which sees only the frames that can change the state.
NMT commands and EMCYs are columns too; only the configuration SDOs are Python objects.
"""

from __future__ import annotations

import bisect
from array import array
from collections.abc import Callable, Iterator

import numpy as np

from nmtcheck.decode import Decoded, node_groups
from nmtcheck.model import (
    ChannelModel,
    CommandTable,
    EcTable,
    EmcyTable,
    InputModel,
    IntervalTable,
    Master,
    NmtTable,
    NodeConfig,
    NodeModel,
    TimelineParams,
    Timeout,
    reset_cs,
)
from nmtcheck.nmt import (
    BOOTUP,
    COMMAND_NAMES,
    COMMAND_STATE,
    EPS,
    GUARD,
    HEARTBEAT,
    MALFORMED,
    OFFLINE,
    PRE_OPERATIONAL,
    REQUEST,
    RESETS,
    SOURCE_INDEX,
    STATE_INDEX,
    STATE_OF_CODE,
    UNKNOWN,
)
from nmtcheck.sdo_config import pair_sdo_writes, write_validity


def build(decoded: Decoded, channels: list[str], start: float, end: float,
          params: TimelineParams, configs: dict[tuple[str | None, int], NodeConfig],
          masters: dict[str, Master] | None = None) -> InputModel:
    """Build every node's model and timeline from the decoded input.

    `masters`: the NMT master of a channel (by name) known from the network or device
    files; on other channels it is inferred from the start-up pattern (SPEC §2).
    """
    models = [_channel(decoded, chan, name, start, end, params, configs, masters or {})
              for chan, name in enumerate(channels)]
    # OFFLINE lasts until the node's next frame of any kind: one pass for all channels
    _offline_ends(decoded, [(m, t) for cm in models for m in cm.nodes.values()
                            for t in m.timeouts])
    for cm in models:
        for m in cm.nodes.values():
            m.intervals = _intervals(m, start, end, params.obey_s)
    return InputModel(decoded, start, end, models, params)


class _Nodes(dict[int, NodeModel]):
    """A channel's nodes, each made on first mention with its configuration from files."""

    def __init__(self, chan: int, name: str,
                 configs: dict[tuple[str | None, int], NodeConfig]) -> None:
        super().__init__()
        self.chan, self.name, self.configs = chan, name, configs

    def __call__(self, n: int) -> NodeModel:
        m = self.get(n)
        if m is None:
            cfg = self.configs.get((self.name, n)) or self.configs.get((None, n)) or NodeConfig()
            m = self[n] = NodeModel(self.chan, self.name, n, cfg)
        return m


def _channel(decoded: Decoded, chan: int, name: str, start: float, end: float,
             params: TimelineParams, configs: dict[tuple[str | None, int], NodeConfig],
             masters: dict[str, Master]) -> ChannelModel:
    """One channel's nodes, commands and master, each node classified and timed (the
    state intervals come last, once every node's timeouts have their ends)."""
    ev = decoded.events
    mine = ev["chan"] == chan
    rows = ev if mine.all() else ev[mine]  # one channel (the usual case): no copy
    nmt = _nmt_table(decoded.nmt, chan)
    nodes = _Nodes(chan, name, configs)
    _nodes_that_sent(decoded, chan, nodes)
    ec_tables = _ec_tables(decoded, chan)
    for n, table in ec_tables.items():
        if not table.rtr.all():  # a node exists once it sends; requests alone do not
            nodes(n)
    _first_shown_by_commands(nmt, nodes)
    _emcy(decoded, chan, nodes)
    pair_sdo_writes(rows, nodes)  # SDO traffic: the configuration written in the trace
    for n, table in ec_tables.items():
        if n in nodes:  # requests to a node nothing else shows are not kept
            nodes[n].ec = table
    master, master_note = _channel_master(name, nmt, ec_tables, params, masters, start)
    _apply_commands(nmt, nodes, master)
    for m in nodes.values():
        _classify(m, params, with_period=False)  # boot-ups bound the SDO-written values
    write_validity(nodes)
    for m in nodes.values():
        _find_period(m)
        _classify(m, params, with_period=True)
        _find_period(m)
    for m in nodes.values():
        _heartbeat_timeouts(m, params, end)
        _guard_timeouts(m, params, end)
    return ChannelModel(chan, name, nmt, dict(sorted(nodes.items())), master, master_note)


def _nodes_that_sent(decoded: Decoded, chan: int, nodes: _Nodes) -> None:
    """Nodes that transmitted anything (TPDO, SDO, EMCY, error control) exist from their
    first frame."""
    for key, first in decoded.first_tx.items():
        if key // 128 == chan and 1 <= key % 128 <= 127:
            m = nodes(key % 128)
            m.first_tx = first
            m.first_show_idx, m.first_show_ts = first.idx, first.ts
            m.last_seen = decoded.last_tx.get(key)


def _emcy(decoded: Decoded, chan: int, nodes: _Nodes) -> None:
    """Each node's EMCYs: views into the decoded columns (grouped by node)."""
    cols = decoded.emcy
    for n, r in node_groups(cols, chan):
        nodes(n).events.emcy = EmcyTable(cols["ts"][r], cols["idx"][r], cols["line"][r],
                                         cols["dlc"][r], cols["data"][r])


def _nmt_table(cols: dict[str, np.ndarray], chan: int) -> NmtTable:
    """The channel's frames on 000h: views of the decoded columns when the input has one
    channel (a log of nothing but NMT frames must not be held twice)."""
    mine = cols["chan"] == chan
    names = ("ts", "idx", "line", "rtr", "dlc", "cs", "target")
    if mine.all():
        return NmtTable(*(cols[name] for name in names))
    return NmtTable(*(cols[name][mine] for name in names))


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
        m.commands = CommandTable(nmt, np.flatnonzero(mine))


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
        f_idx, f_ts, f_cs = int(valid.idx[i]), float(valid.ts[i]), int(valid.cs[i])
        prev_idx = int(valid.idx[i - 1]) if i else -1
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
    """The valid commands of a channel as columns (the master inference walks a few of
    them at a time, by position; a log may hold millions of them)."""

    def __init__(self, nmt: NmtTable) -> None:
        v = nmt.valid
        self.ts = nmt.ts[v]
        self.idx = nmt.idx[v]
        self.cs = nmt.cs[v]
        self.target = nmt.target[v]

    def next_to(self, i: int, node: int) -> int | None:
        """File position of the first command after the i-th that reaches `node` (direct
        or broadcast), looked for in growing windows: usually it is close."""
        j, step = i + 1, 64
        while j < len(self.idx):
            seg = self.target[j:j + step]
            hit = np.flatnonzero((seg == 0) | (seg == node))
            if hit.size:
                return int(self.idx[j + int(hit[0])])
            j, step = j + step, step * 2
        return None


def _answers_reset(valid: _Valid, before: int, node: int, b_idx: int, b_ts: float,
                   params: TimelineParams) -> bool:
    """Whether a reset command to `node` (direct or broadcast) came in the B002 window
    before its boot-up: a node that obeys a broadcast reset is not its sender. Walks back
    from the `before`-th command in growing windows, skipping commands later in the file
    than the boot-up, until one is older than the window."""
    hi, step = before, 64
    while hi > 0:
        lo = max(hi - step, 0)
        seg = slice(lo, hi)
        considered = valid.idx[seg] <= b_idx
        old = considered & (valid.ts[seg] < b_ts - params.reset_window_s - EPS)
        reset = considered & reset_cs(valid.cs[seg]) & (
            (valid.target[seg] == 0) | (valid.target[seg] == node))
        last_old = np.flatnonzero(old)
        last_reset = np.flatnonzero(reset)
        if last_reset.size and (not last_old.size or last_reset[-1] > last_old[-1]):
            return True
        if last_old.size:
            return False
        hi, step = lo, step * 2
    return False


def _disobeyed(t: EcTable, data: np.ndarray, valid: _Valid, i: int, node: int,
               params: TimelineParams) -> bool:
    """Whether the node's own frames (`data`: positions of its boot-ups and heartbeats)
    show it did not obey broadcast `valid[i]`.

    Walks only the few frames around the command, so a hostile log with a million
    boot-ups and broadcasts stays linear enough.
    """
    f_idx, f_ts, f_cs = int(valid.idx[i]), float(valid.ts[i]), int(valid.cs[i])
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
        if (next_cmd is not None and int(t.idx[q]) > next_cmd) or int(t.value[q]) == 0:
            return False
        if float(t.ts[q]) - f_ts <= params.obey_s + EPS:
            continue
        return STATE_OF_CODE.get(int(t.value[q]) & 0x7F) == prior
    return False


def _ec_tables(decoded: Decoded, chan: int) -> dict[int, EcTable]:
    """One column table per node of the channel: views into the decoded columns."""
    ec = decoded.ec
    return {n: EcTable(ec["ts"][r], ec["idx"][r], ec["line"][r], ec["rtr"][r], ec["dlc"][r],
                       ec["value"][r]) for n, r in node_groups(ec, chan)}


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
    resets = m.commands.reset_idx
    writes = m.writes.take(np.flatnonzero(m.writes.index == 0x1017))
    # the events as columns: heartbeats and boot-ups, reset commands, 1017h writes
    ts = np.concatenate([ec.ts[pos], m.commands.reset_ts, writes.ts])
    idx = np.concatenate([ec.idx[pos], resets, writes.idx])
    what = np.concatenate([np.where(ec.kind[pos] == HEARTBEAT, _HB, _BOOT).astype(np.int8),
                           np.full(len(resets), _RESET, np.int8),
                           np.where(writes.value != 0, _ON, _OFF).astype(np.int8)])
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
    at = _timed_from(ts[gap], what[gap] == _HB, writes.request_ts, writes.ts)
    limit = m.config_series(at, lambda cfg: m.hb_timeout(cfg, params.timeout_factor))
    fire = (limit > 0) & (until - ts[gap] > limit + EPS)
    for g, lim, u, c in zip(gap[fire].tolist(), limit[fire].tolist(), until[fire].tolist(),
                            closed[fire].tolist(), strict=True):
        start = float(ts[g])
        m.timeouts.append(Timeout("H001", start + lim, start, int(idx[g]), lim,
                                  u - start if c else None))


def _timed_from(start: np.ndarray, by_heartbeat: np.ndarray, req: np.ndarray,
                conf: np.ndarray) -> np.ndarray:
    """The moment whose configuration times each gap: its start, but for a gap opened by a
    heartbeat between a 1017h write's request (`req`) and its confirmation (`conf`), the
    confirmation (the last such write in file order). A binary search when the writes'
    request to confirmation spans do not overlap (always, but in a hostile log), else
    write by write."""
    at: np.ndarray = start.copy()
    if not len(req):
        return at
    order = np.argsort(req, kind="stable")
    if bool((np.diff(order) > 0).all()) and bool((conf[:-1] <= req[1:]).all()):
        k = np.searchsorted(req, start, side="right") - 1
        inside = by_heartbeat & (k >= 0) & (start < conf[np.maximum(k, 0)])
        at[inside] = conf[k[inside]]
        return at
    for r, c in zip(req.tolist(), conf.tolist(), strict=True):
        at[by_heartbeat & (start >= r) & (start < c)] = c
    return at


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
    found = decoded.first_node_frame_after(np.asarray([m.key for m, _t in items]),
                                           np.asarray([t.moment for _m, t in items]),
                                           np.asarray([t.after_idx for _m, t in items]))
    for (m, t), hit_idx, hit_ts in zip(items, found.idx.tolist(), found.ts.tolist(),
                                       strict=True):
        best = hit_ts if hit_idx >= 0 else None
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


STEP_CHUNK = 1 << 16


def _interval_steps(m: NodeModel, obey_s: float) -> Iterator[tuple[float, int, int]]:
    """What the interval walk sees, in order: (time, what, reference) for each evidence
    frame, command, timeout and end of a timeout. At one moment a timeout comes first
    and its end last; the rest in file order."""
    ec, cmds = m.ec, m.commands
    windows = [(t, t + obey_s) for t in cmds.ts.tolist()] + [
        (t, t) for t in [t.moment for t in m.timeouts]
        + [t.ended_by for t in m.timeouts if t.ended_by is not None]]
    pos = _evidence(m, windows)
    back_of = [i for i, t in enumerate(m.timeouts) if t.ended_by is not None]
    backs = [m.timeouts[i] for i in back_of]
    # the steps as columns: time, order at one moment, file position, what, reference
    ts = np.concatenate([ec.ts[pos], cmds.ts, [t.moment for t in m.timeouts],
                         [t.ended_by for t in backs]]).astype(np.float64)
    order = np.concatenate([np.ones(len(pos) + len(cmds), np.int8),
                            np.zeros(len(m.timeouts), np.int8), np.full(len(backs), 2, np.int8)])
    idx = np.concatenate([ec.idx[pos], cmds.idx,
                          np.full(len(m.timeouts) + len(backs), -1, np.int64)])
    what = np.concatenate([np.full(len(pos), _EV_EC, np.int8),
                           np.full(len(cmds), _EV_CMD, np.int8),
                           np.full(len(m.timeouts), _EV_TIMEOUT, np.int8),
                           np.full(len(backs), _EV_BACK, np.int8)])
    ref = np.concatenate([pos, np.arange(len(cmds)), np.arange(len(m.timeouts)),
                          back_of]).astype(np.int64)
    steps = np.lexsort((idx, order, ts))
    for lo in range(0, len(steps), STEP_CHUNK):  # a node may have millions of steps: a
        part = steps[lo:lo + STEP_CHUNK]  # chunk of them at a time as Python numbers
        yield from zip(ts[part].tolist(), what[part].tolist(), ref[part].tolist(), strict=True)


def _intervals(m: NodeModel, start: float, end: float, obey_s: float) -> IntervalTable:
    """Walk the node's evidence in order and cut the timeline into state intervals.

    A heartbeat or guarding response up to `obey_s` after a command that reports the
    state from before the command was queued before the node processed it: it is marked
    stale in `m.ec.stale` and is no evidence (SPEC §2). The walk sees plain ints and
    floats, never objects: a node may change state on every heartbeat.
    """
    ec, cmds = m.ec, m.commands
    steps = _interval_steps(m, obey_s)
    # compact arrays, not lists: one entry per frame, read one at a time
    kind = array("b", ec.kind.astype(np.int8).tobytes())
    code_state = array("b", _CODE_STATE[ec.value & 0x7F].tobytes())
    cmd_state = [STATE_INDEX[COMMAND_STATE[c]] for c in cmds.cs.tolist()]
    ended_by = [t.ended_by for t in m.timeouts]

    unknown, offline, pre_op = STATE_INDEX[UNKNOWN], STATE_INDEX[OFFLINE], STATE_INDEX[
        PRE_OPERATIONAL]
    src_timeout, src_command = SOURCE_INDEX["timeout"], SOURCE_INDEX["command"]
    starts = array("d", [start])  # the intervals so far (8 + 1 + 1 bytes each)
    states = array("b", [unknown])
    sources = array("b", [SOURCE_INDEX["start"]])

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
    for at, w, r in steps:
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
        elif w == _EV_TIMEOUT and cur not in (unknown, offline):
            saved = (cur, sources[-1])
            pre_offline = cur  # what a stale report after a command here would still say
            offline_until = ended_by[r]
            go(at, offline, src_timeout)
        elif w == _EV_BACK and cur == offline and saved is not None and offline_until == at:
            go(at, *saved)
            saved = None
    begin = np.frombuffer(starts, np.float64).copy()
    finish = np.append(begin[1:], max(end, starts[-1]))
    return IntervalTable(begin, finish, np.frombuffer(states, np.int8).copy(),
                         np.frombuffer(sources, np.int8).copy())
