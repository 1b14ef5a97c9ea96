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
from collections.abc import Callable, Iterable, Iterator

import numpy as np

from nmtcheck.timeline.decode import KIND_TPDO, Decoded, node_groups
from nmtcheck.readers.frames import node_key
from nmtcheck.timeline.model import (
    CaptureSpan,
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
    SmallEc,
    TimelineParams,
    Timeout,
    reset_cs,
)
from nmtcheck.protocol.nmt import (
    BOOTUP,
    COMMAND_NAMES,
    COMMAND_STATE,
    EPS,
    GUARD,
    HEARTBEAT,
    MALFORMED,
    OFFLINE,
    OPERATIONAL,
    PRE_OPERATIONAL,
    REQUEST,
    RESETS,
    SOURCE_INDEX,
    STATE_INDEX,
    STATE_OF_CODE,
    UNKNOWN,
    between,
    is_one_of,
)
from nmtcheck.processes.sdo_config import pair_sdo_writes, write_validity
from nmtcheck.timeline.tables import shared_empty


def build(decoded: Decoded, channels: list[str], start: float, end: float,
          params: TimelineParams, configs: dict[tuple[str | None, int], NodeConfig],
          masters: dict[str, Master] | None = None,
          captures: dict[int, CaptureSpan] | None = None) -> InputModel:
    """Build every node's model and timeline from the decoded input.

    `masters`: the NMT master of a channel (by name) known from the network or device
    files; on other channels it is inferred from the start-up pattern (SPEC §2).
    `captures`: the channels of a later capture in the input, by code, with their span:
    each is the trace of its own recording (nmtcheck/readers/captures.py).
    """
    # each channel's rows, found once: a log may have tens of thousands of channels
    ev_rows, nmt_rows = _rows_by_channel(decoded.events["chan"]), _rows_by_channel(
        decoded.nmt["chan"])
    sent: dict[int, list[int]] = {}
    for key in decoded.first_tx:
        sent.setdefault(key // 128, []).append(key)
    ec_groups, emcy_groups = node_groups(decoded.ec), node_groups(decoded.emcy)
    ec_cols = _ec_columns(decoded.ec)
    models = []
    for chan, name in enumerate(channels):
        span = (captures or {}).get(chan)
        cm = _channel(decoded, chan, name, span.start if span else start,
                      span.end if span else end, params, configs, masters or {},
                      ev_rows.get(chan), nmt_rows.get(chan), sent.get(chan, []),
                      ec_groups.get(chan, []), emcy_groups.get(chan, []), ec_cols)
        if span is not None:
            cm.log_name, cm.first_index, cm.first_line = (span.log_name, span.first_index,
                                                          span.first_line)
        models.append(cm)
    # OFFLINE lasts until the node's next frame of any kind: one pass for all channels
    _offline_ends(decoded, [(m, t) for cm in models for m in cm.nodes.values()
                            for t in m.timeouts])
    _self_starts(decoded, [(m, cm.end) for cm in models for m in cm.nodes.values()])
    for cm in models:
        reports = _reports_by_node(cm) if params.order_only else {}
        for m in cm.nodes.values():
            m.intervals = (_bootups_only(m.ec, cm.start, cm.end) if _only_bootups(m)
                           else _intervals(m, cm.start, cm.end, params.obey_s, reports))
    return InputModel(decoded, start, end, models, params)


_NO_CONFIG = NodeConfig()  # nothing from files: shared by such nodes, never changed


class _Nodes(dict[int, NodeModel]):
    """A channel's nodes, each made on first mention with its configuration from files."""

    def __init__(self, chan: int, name: str,
                 configs: dict[tuple[str | None, int], NodeConfig]) -> None:
        super().__init__()
        self.chan, self.name, self.configs = chan, name, configs

    def __call__(self, n: int) -> NodeModel:
        m = self.get(n)
        if m is None:
            cfg = self.configs.get((self.name, n)) or self.configs.get((None, n)) or _NO_CONFIG
            m = self[n] = NodeModel(self.chan, self.name, n, cfg)
        return m


def _rows_by_channel(chan: np.ndarray) -> dict[int, np.ndarray | None]:
    """Per channel code, the positions of its rows (None: every row is that channel's,
    the usual case, so no copy is made)."""
    if not len(chan):
        return {}
    first = int(chan[0])
    if bool((chan == first).all()):
        return {first: None}
    order = np.argsort(chan, kind="stable")
    codes, starts = np.unique(chan[order], return_index=True)
    bounds = np.append(starts, len(order))
    return {int(c): order[bounds[i]:bounds[i + 1]] for i, c in enumerate(codes.tolist())}


def _channel(decoded: Decoded, chan: int, name: str, start: float, end: float,
             params: TimelineParams, configs: dict[tuple[str | None, int], NodeConfig],
             masters: dict[str, Master], ev_rows: np.ndarray | None,
             nmt_rows: np.ndarray | None, sent: list[int],
             ec_groups: list[tuple[int, slice]],
             emcy_groups: list[tuple[int, slice]], ec_cols: dict[str, np.ndarray]
             ) -> ChannelModel:
    """One channel's nodes, commands and master, each node classified and timed (the
    state intervals come last, once every node's timeouts have their ends).

    `ev_rows`/`nmt_rows`: the channel's rows of the decoded events and NMT frames (None:
    all of them); `sent`: the node keys of the channel that transmitted; `ec_groups`,
    `emcy_groups`: each node's rows of the decoded error-control and EMCY columns;
    `ec_cols`: the error-control columns of `_ec_columns`."""
    ev = decoded.events
    if ev_rows is None:
        rows = ev if not len(ev) or int(ev["chan"][0]) == chan else ev[:0]
    else:
        rows = ev[ev_rows]
    nmt = _nmt_table(decoded.nmt, chan, nmt_rows)
    nodes = _Nodes(chan, name, configs)
    _nodes_that_sent(decoded, sent, nodes)
    ec_tables = _ec_tables(decoded, chan, ec_groups, ec_cols)
    for n, table in ec_tables.items():
        if not table.rtr.all():  # a node exists once it sends; requests alone do not
            nodes(n)
    _first_shown_by_commands(nmt, nodes)
    _emcy(decoded, emcy_groups, nodes)
    pair_sdo_writes(rows, nodes)  # SDO traffic: the configuration written in the trace
    for n, table in ec_tables.items():
        if n in nodes:  # requests to a node nothing else shows are not kept
            nodes[n].ec = table
    master, master_note = _channel_master(name, nmt, ec_tables, params, masters, start)
    if len(nmt):  # else every node keeps its empty command table
        _apply_commands(nmt, nodes, master, params)
    requests = {n: _classify(m, params, with_period=False, start=start)  # boot-ups bound the
                for n, m in nodes.items()}  # SDO-written values
    write_validity(nodes)
    for n, m in nodes.items():
        m.small = _small(m, params)
        _find_period(m)
        if requests[n]:  # without requests the second pass classifies alike
            _classify(m, params, with_period=True, start=start)
            _find_period(m)
        if params.order_only:  # frame numbers are no time: nothing was measured
            m.order_only = True
            m.median_s = m.period_s = None
            m.period_source = "none"
    for n, m in nodes.items():
        if not params.order_only:  # no timestamps: no timeouts either (SPEC §1)
            _heartbeat_timeouts(m, params, end)
            if requests[n]:  # G002 needs a request
                _guard_timeouts(m, params, end)
    return ChannelModel(chan, name, nmt, dict(sorted(nodes.items())), master, master_note,
                        start, end)


def _nodes_that_sent(decoded: Decoded, keys: list[int], nodes: _Nodes) -> None:
    """Nodes that transmitted anything (TPDO, SDO, EMCY, error control) exist from their
    first frame."""
    for key in keys:
        first = decoded.first_tx[key]
        if 1 <= key % 128 <= 127:
            m = nodes(key % 128)
            m.first_tx = first
            m.first_show_idx, m.first_show_ts = first.idx, first.ts
            m.last_seen = decoded.last_tx.get(key)


def _emcy(decoded: Decoded, groups: list[tuple[int, slice]], nodes: _Nodes) -> None:
    """Each node's EMCYs: views into the decoded columns (grouped by node)."""
    cols = decoded.emcy
    for n, r in groups:
        nodes(n).events.emcy = EmcyTable(cols["ts"][r], cols["idx"][r], cols["line"][r],
                                         cols["dlc"][r], cols["data"][r])


def _nmt_table(cols: dict[str, np.ndarray], chan: int, rows: np.ndarray | None) -> NmtTable:
    """The channel's frames on 000h (`rows`; None: all of them): views of the decoded
    columns when the input has one channel (a log of nothing but NMT frames must not be
    held twice)."""
    names = ("ts", "idx", "line", "rtr", "dlc", "cs", "target")
    if rows is None:
        if not len(cols["chan"]) or int(cols["chan"][0]) != chan:
            return shared_empty(NmtTable)  # most channels of a many-channel log
        return NmtTable(*(cols[name] for name in names))
    return NmtTable(*(cols[name][rows] for name in names))


def _first_shown_by_commands(nmt: NmtTable, node_model: Callable[[int], NodeModel]) -> None:
    """A valid direct command shows its target node exists, from that command on."""
    if not len(nmt):
        return
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
                    master: Master | None, params: TimelineParams) -> None:
    """Each valid command to the nodes it applies to: a direct one to its target, a
    broadcast to every node seen before it; to the channel's master only where its own
    frames show that it obeyed (SPEC §2: a CAN controller does not receive its own
    frames, so Lely's master ignores its own `000#8200`, while CANopenNode applies its
    own commands to itself, and Lely's master obeys its own `000#8100`)."""
    broadcast = nmt.valid & (nmt.target == 0)
    for n, m in nodes.items():
        mine = nmt.valid & (nmt.target == n)
        if m.first_show_idx is not None:
            seen = broadcast & (m.first_show_idx < nmt.idx)
            if master is not None and n == master.node:
                own = np.flatnonzero(seen)
                obeyed = own[_master_obeyed(m, nmt, own, mine, params)]
                m.own_command_idx = nmt.idx[obeyed]
                seen = np.zeros(len(nmt), bool)
                seen[obeyed] = True
            mine |= seen
        m.commands = CommandTable(nmt, np.flatnonzero(mine))


def _next_of(marks: np.ndarray, after: np.ndarray, values: np.ndarray | None = None,
             none: float = np.iinfo(np.int64).max) -> np.ndarray:
    """Per entry of `after`, the first of the sorted `marks` greater than it (or that
    mark's entry of `values`), `none` where there is none."""
    k = np.searchsorted(marks, after, side="right")
    if not len(marks):
        return np.full(len(after), none)
    got = (marks if values is None else values)[np.minimum(k, len(marks) - 1)]
    return np.where(k < len(marks), got, none)


def _master_obeyed(m: NodeModel, nmt: NmtTable, own: np.ndarray, direct: np.ndarray,
                   params: TimelineParams) -> np.ndarray:
    """Which of the master's own broadcasts (positions `own` in `nmt`) its frames show it
    obeyed: after a reset, a boot-up within `bootup_timeout_ms` that no other reset to it
    explains; after start/stop/pre-operational, its next error-control message that is
    not a stale one reporting the commanded state."""
    if not own.size:
        return np.zeros(0, bool)
    t = m.ec
    data = np.flatnonzero(~t.rtr & (t.dlc == 1))
    d_idx, d_ts, d_val = t.idx[data], t.ts[data], t.value[data].astype(np.int64)
    boot = d_val == 0
    c_idx, c_ts, c_cs = nmt.idx[own], nmt.ts[own], nmt.cs[own].astype(np.int64)
    is_reset = reset_cs(c_cs)
    obeyed = np.zeros(len(own), bool)
    # resets: the first boot-up after the command, unless another reset reaching the
    # master comes first
    b_idx, b_ts = d_idx[boot], d_ts[boot]
    k = np.searchsorted(b_idx, c_idx, side="right")
    has = k < len(b_idx)
    kb = np.minimum(k, max(len(b_idx) - 1, 0))
    reaching = np.flatnonzero(nmt.valid & reset_cs(nmt.cs) & ((nmt.target == 0) | direct))
    next_reset = _next_of(nmt.idx[reaching], c_idx)
    if len(b_idx):
        obeyed |= is_reset & has & (b_idx[kb] < next_reset) & (
            b_ts[kb] - c_ts <= params.bootup_timeout_s + EPS)
    # start, stop, pre-operational: the next report that is not stale, before a boot-up
    code = d_val & 0x7F
    state = np.full(len(data), -1, np.int64)
    for c, st in STATE_OF_CODE.items():
        state[code == c] = STATE_INDEX[st]
    state[boot] = -2
    p = np.searchsorted(d_idx, c_idx, side="right")
    prior = np.where(p > 0, state[np.maximum(p - 1, 0)], -1) if len(data) else p * 0 - 1
    wanted = np.asarray([STATE_INDEX[COMMAND_STATE[c]] for c in c_cs.tolist()], np.int64)
    undecided = ~is_reset
    reach_idx = nmt.idx[nmt.valid & ((nmt.target == 0) | direct)]
    for j in range(4):  # a stale report or two may come first
        q = p + j
        ok = undecided & (q < len(data))
        if not ok.any():
            break
        qq = np.minimum(q, max(len(data) - 1, 0))
        st, dt = state[qq], d_ts[qq] - c_ts
        # a later command reaching the master came first: that one decides
        later_cmd = ok & (np.searchsorted(reach_idx, c_idx, side="right")
                          < np.searchsorted(reach_idx, d_idx[qq], side="left"))
        stale = ok & ~later_cmd & (st == prior) & (st != wanted) & (
            (dt <= params.obey_s + EPS) | (params.order_only and j == 0)) & (st >= 0)
        decide = ok & ~stale
        obeyed |= decide & ~later_cmd & (st == wanted)
        undecided &= ~decide
    return obeyed


def _channel_master(name: str, nmt: NmtTable, tables: dict[int, EcTable],
                    params: TimelineParams, known: dict[str, Master], start: float
                    ) -> tuple[Master | None, str]:
    """The channel's master from the files, else inferred; with a note on how or why not."""
    if name in known:
        return known[name], known[name].detail
    if not len(nmt):  # what _burst_master concludes of no command at all
        return None, "not inferred: no broadcast NMT command or burst of resets"
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
        return _burst_master(nmt, tables, params, start)
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


MAX_BURSTS_LOOKED_AT = 16


def _burst_master(nmt: NmtTable, tables: dict[int, EcTable], params: TimelineParams,
                  start: float) -> tuple[Master | None, str]:
    """A CiA 302 manager with keep-alive slaves resets node by node instead of
    broadcasting (SPEC §2): after its boot-up, a burst of direct resets to at least two
    other node-IDs, no other command between, that leaves out exactly one node-ID 1-127:
    its own. The boot-up must answer no reset."""
    valid = _Valid(nmt)
    direct_reset = reset_cs(valid.cs) & (valid.target != 0)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], direct_reset.astype(np.int8), [0]])))
    notes: list[str] = []
    bursts = 0
    for lo, hi in zip(edges[::2][:MAX_BURSTS_LOOKED_AT].tolist(),
                      edges[1::2][:MAX_BURSTS_LOOKED_AT].tolist(), strict=True):
        targets = set(valid.target[lo:hi].tolist())
        if len(targets) < 2:
            continue
        bursts += 1
        left_out = sorted(set(range(1, 128)) - targets)
        b_ts = float(valid.ts[lo])
        if len(left_out) != 1:
            notes.append(f"the reset burst at {b_ts - start:.6f} s leaves out node-IDs "
                         f"{', '.join(map(str, left_out[:5]))}"
                         f"{' …' if len(left_out) > 5 else ''}")
            continue
        (node,) = left_out
        t = tables.get(node)
        if t is None:
            continue
        boots = np.flatnonzero(~t.rtr & (t.dlc == 1) & (t.value == 0) & (t.idx < valid.idx[lo])
                               & (t.ts >= b_ts - params.master_window_s - EPS))
        if lo > 0:
            boots = boots[t.idx[boots] > valid.idx[lo - 1]]
        for q in boots[::-1].tolist():
            if not _answers_reset(valid, lo, node, int(t.idx[q]), float(t.ts[q]), params):
                why = (f"boot-up at {float(t.ts[q]) - start:.6f} s, then a burst of resets "
                       f"to every other node-ID at {b_ts - start:.6f} s")
                return Master(node, "inferred", why), why
    if notes:
        return None, "not inferred: " + "; ".join(notes[:2])
    if not bursts:
        return None, "not inferred: no broadcast NMT command or burst of resets"
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
        for n, q in enumerate(after):
            boot = int(t.value[q]) == 0
            dt = float(t.ts[q]) - f_ts
            if not boot and (dt <= params.obey_s + EPS or (params.order_only and n == 0)):
                continue  # may have been queued before the command
            return not boot or dt > params.bootup_timeout_s + EPS
        return True  # no boot-up from it as far as the trace goes
    prior = None
    for q in data[max(p - 256, 0):p][::-1].tolist():
        prior = STATE_OF_CODE.get(int(t.value[q]) & 0x7F)
        if prior is not None:
            break
    if prior is None or prior == COMMAND_STATE[f_cs]:
        return False
    next_cmd = valid.next_to(i, node)
    for n, q in enumerate(after):
        if (next_cmd is not None and int(t.idx[q]) > next_cmd) or int(t.value[q]) == 0:
            return False
        if float(t.ts[q]) - f_ts <= params.obey_s + EPS or (params.order_only and n == 0):
            continue
        return STATE_OF_CODE.get(int(t.value[q]) & 0x7F) == prior
    return False


def _ec_columns(ec: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The decoded error-control columns in `EcTable`'s dtypes, with every frame's kind
    as far as it is known without the node's history (request, malformed, boot-up,
    heartbeat: final unless the node has requests, see `_classify`) and a stale mark,
    made once for all nodes: each node's table is a view of its rows."""
    rtr, dlc, value = (np.asarray(ec["rtr"], bool), np.asarray(ec["dlc"], np.int16),
                       np.asarray(ec["value"], np.uint8))
    return {"ts": np.asarray(ec["ts"], np.float64), "idx": np.asarray(ec["idx"], np.int64),
            "line": np.asarray(ec["line"], np.int64), "rtr": rtr, "dlc": dlc, "value": value,
            "kind": _plain_kinds(rtr, dlc, value), "stale": np.zeros(len(rtr), bool)}


def _plain_kinds(rtr: np.ndarray, dlc: np.ndarray, value: np.ndarray) -> np.ndarray:
    """Request, malformed (DLC not 1), boot-up (00h) or heartbeat, frame by frame."""
    kind: np.ndarray = np.where(rtr, REQUEST, np.where(
        dlc != 1, MALFORMED, np.where(value == 0, BOOTUP, HEARTBEAT))).astype(np.int8)
    return kind


def _ec_tables(decoded: Decoded, chan: int, groups: list[tuple[int, slice]],
               cols: dict[str, np.ndarray]) -> dict[int, EcTable]:
    """One column table per node of the channel: views into the columns of
    `_ec_columns`, with the node's dropped heartbeat runs when the log was long enough
    to compact them."""
    kind, stale = cols["kind"], cols["stale"]
    tables = {n: EcTable.view(cols, r, kind, stale) for n, r in groups}
    if decoded.ec_runs:
        for n, table in tables.items():
            table.runs = decoded.ec_runs.get(node_key(chan, n))
    if decoded.ec_guard_runs:
        for n, table in tables.items():
            table.guard_runs = decoded.ec_guard_runs.get(node_key(chan, n))
    return tables


def _classify(m: NodeModel, params: TimelineParams, with_period: bool, start: float) -> bool:
    """Boot-up, heartbeat or guarding response for each data frame on 700h+N (SPEC §2).

    Without the period (first pass) only boot-ups are final: the period in force needs
    the SDO-written values, which hold until the next boot-up. Returns whether N has
    remote requests: without them the kinds `_ec_columns` gave are final, both passes
    alike, and G002 has nothing.
    """
    ec = m.ec
    if not m.kind_counts()[REQUEST]:
        return False
    kind = _plain_kinds(ec.rtr, ec.dlc, ec.value)
    periods = m.periods_at(ec.ts) if with_period else np.full(len(ec), np.nan)
    # a log that starts mid-stream: a request sent before the recording began may be
    # pending at its first frame (order only: no time tells how long before)
    before = -np.inf if params.order_only else start
    _classify_guarding(ec, kind, params, periods, _heartbeat_disabled(m, kind), before)
    ec.kind = kind
    return True


def _heartbeat_disabled(m: NodeModel, kind: np.ndarray) -> np.ndarray:
    """Per error-control frame, whether a confirmed 1017h = 0 write holds (in file order:
    the latest 1017h write before it, with no boot-up or reset command of N between):
    N produces no heartbeat, so an answer to a pending request is a guarding response (a
    master switching N from heartbeat to guarding)."""
    ec, w = m.ec, m.writes
    hb = np.flatnonzero(w.index == 0x1017)
    if not hb.size:
        return np.zeros(len(ec), bool)
    w_idx = w.idx[hb]
    order = np.argsort(w_idx, kind="stable")
    w_idx, w_val = w_idx[order], w.value[hb][order]
    k = np.searchsorted(w_idx, ec.idx, side="left") - 1  # the latest write before
    has = k >= 0
    latest = np.where(has, w_idx[np.maximum(k, 0)], -1)
    ends = np.sort(np.concatenate([ec.idx[kind == BOOTUP], m.commands.reset_idx]))
    ended = between(ends, latest, ec.idx) | is_one_of(ec.idx, ends)
    disabled: np.ndarray = has & (w_val[np.maximum(k, 0)] == 0) & ~ended
    return disabled


def _classify_guarding(ec: EcTable, kind: np.ndarray, params: TimelineParams,
                       periods: np.ndarray, disabled: np.ndarray, start: float) -> None:
    """Where remote requests are pending, a data frame may be a guarding response.

    `periods`: the heartbeat period in force at each frame (NaN: unknown). `start`: the
    trace's first frame, taken for a request sent before the recording began: in a log
    that starts mid-stream, N's first report within the response timeout answers it
    where a request to N comes before N's next report (a guarding answer `704#85` there
    was a heartbeat with bit 7 set, C003, then G004 and H001 "for the rest of the trace").

    A node that only answers guarding (the usual one) is classified with array operations:
    a data frame answers the request right before it (no boot-up or other data frame
    between) within the response timeout. That is the walk's answer wherever the walk's
    other test (a node that also produced two heartbeats since its boot-up: the toggle
    bit and the early limit decide) is not reached, time does not go backwards (a
    request a late heartbeat left pending could then be answered), and no frame with
    toggle 0 follows a request left unanswered (a heartbeat of a node polled while it
    ignores guarding may look like an answer); else the walk decides."""
    timeout = params.response_timeout_s + EPS
    rel = np.flatnonzero((kind == REQUEST) | (kind == BOOTUP) | (kind == HEARTBEAT))
    k = kind[rel]
    ts = ec.ts[rel]
    guard = np.zeros(len(rel), bool)
    if len(rel) > 1:
        guard[1:] = (k[1:] == HEARTBEAT) & (k[:-1] == REQUEST) & (ts[1:] - ts[:-1] <= timeout)
    start = request_before_trace(k, ts, start, timeout)
    if len(rel) and start > -np.inf:  # (no timestamps: the timeout is infinite)
        guard[0] = True
    beat = (k == HEARTBEAT) & ~guard  # counted by the walk's hb_since_boot
    before = np.cumsum(beat) - beat  # heartbeats before each row
    at = np.arange(len(rel))
    last_boot = np.maximum.accumulate(np.where(k == BOOTUP, at, -1))
    since_boot = before - np.where(last_boot >= 0, before[np.maximum(last_boot, 0)], 0)
    after_misses = np.zeros(len(rel), bool)  # MISSED requests unanswered before the pending
    if len(rel) > MISSED + 1:
        run = np.ones(len(rel) - MISSED - 1, bool)
        for j in range(1, MISSED + 2):  # the row j before each
            run &= k[MISSED + 1 - j:len(k) - j] == REQUEST
        after_misses[MISSED + 1:] = run
    values = ec.value[rel]
    toggle0 = guard & (values & 0x80 == 0)
    # the walk's additions can only change something where: an answer with toggle 0
    # follows an unanswered request; N's first report since its boot-up, an answer with
    # toggle 0, is followed by an answer under a 1017h = 0 write; or the trace's first
    # report, taken for an answer, is followed by an answer with its toggle
    data_rows = np.where(k != REQUEST, at, -1)
    prev_data = np.concatenate([[-1], np.maximum.accumulate(data_rows)[:-1]])[:len(rel)]
    first = (prev_data < 0) | (k[np.maximum(prev_data, 0)] == BOOTUP)
    off = guard & disabled[rel]
    off_after = np.flip(np.cumsum(np.flip(off))) > off  # an answer under 1017h = 0 later
    answers = np.flatnonzero(guard)
    start_repeat = (start > -np.inf and len(answers) > 1 and answers[0] == 0
                    and bool((values[answers[1]] ^ values[0]) & 0x80 == 0))
    doubtful = bool((toggle0 & after_misses).any()
                    or (toggle0 & first & ~disabled[rel] & off_after).any() or start_repeat)
    if not bool((guard & (since_boot >= 2) & ~disabled[rel]).any()) and not bool(
            (np.diff(ts) < 0).any()) and not doubtful:
        kind[rel[guard]] = GUARD
        return
    _classify_guarding_walk(ec, kind, params, periods, disabled, start)


def request_before_trace(kind: np.ndarray, ts: np.ndarray, start: float, timeout: float
                         ) -> float:
    """`start` where N's first report (of its requests, boot-ups and reports `kind` at
    `ts`) may answer a request sent before the trace began: it comes within the response
    timeout of the trace's start and a request to N follows it before N's next report;
    else -inf (no such request)."""
    if len(kind) > 1 and kind[0] == HEARTBEAT and kind[1] == REQUEST and (
            -np.inf < start and ts[0] - start <= timeout):
        return start
    return -np.inf


MISSED = 1  # requests a node left unanswered before a frame that may be its heartbeat


def _classify_guarding_walk(ec: EcTable, kind: np.ndarray, params: TimelineParams,
                            periods: np.ndarray, disabled: np.ndarray, start: float) -> None:
    """`_classify_guarding` frame by frame, in order (plain Python ints, no objects): for
    a node that answers guarding and produces heartbeats too.

    Beyond the SPEC's test: of two frames in a row with toggle 0, the second after a
    request N left unanswered (MISSED or more) and the first after one too or N's first
    report since its boot-up, the second is N's heartbeat where, as a response, its
    toggle would repeat the first's, and then so is the first; and such a frame taken for
    the last response was a heartbeat where the first answer after a 1017h = 0 write (the
    master switching N to guarding), or the next answer after the trace's first report
    taken for one, only fits without it. A heartbeat producer that a master polls
    (CANopenNode after a power cycle: 1017h back at its power-on value, which disables its
    guarding slave) sends heartbeats at any phase of the polling, so every one of them
    comes within the response timeout of the latest request, and N never shows the two
    heartbeats the SPEC's test needs: each was a guarding response with toggle 0, then a
    false G001 on it and on the first real response once the master switched N to
    guarding."""
    # ts of the pending request (maybe one before the trace: request_before_trace)
    pending: float | None = start if start > -np.inf else None
    hb_since_boot = 0
    last_hb: float | None = None
    early: float | None = None  # the early limit at the last heartbeat
    timeout = params.response_timeout_s + EPS
    # requests since N's last data frame (before the trace: as if several went unanswered,
    # so that N's first report, taken for an answer, may still turn out a heartbeat)
    requests = MISSED + 1 if pending is not None else 0
    expect: int | None = None  # the next response's toggle (None: either, at the start)
    doubtful: tuple[int, int | None] | None = None  # the last response, if it came after
    # unanswered requests with toggle 0: (its row, the toggle expected before it)
    before_trace = -1  # the row of N's first report, taken for an answer from before it
    first_report = True  # no report of N yet since its boot-up (or the trace's start)
    for i, (k, ts, value, period, off) in enumerate(zip(
            kind.tolist(), ec.ts.tolist(), ec.value.tolist(), periods.tolist(),
            disabled.tolist(), strict=True)):
        if k == REQUEST:
            pending = ts
            requests += 1
        elif k == BOOTUP:
            # Always a boot-up, even with a request pending: a node in Initialisation does
            # not answer guarding, and reading it as a response would raise false G001/B001.
            hb_since_boot = 0
            last_hb = None
            pending = None
            requests = 0
            expect, doubtful = 0, None
            first_report = True
        elif k == HEARTBEAT:
            is_guard = False
            toggle = value >> 7 & 1
            if pending is not None and ts - pending <= timeout:
                repeat = False  # the second of two such frames in a row: heartbeats
                if hb_since_boot >= 2 and not off:
                    is_guard = bool(value & 0x80) or (
                        early is not None and last_hb is not None and ts - last_hb < early)
                else:
                    repeat = (not off and requests > MISSED and toggle == 0 and expect == 1
                              and doubtful is not None)
                    is_guard = not repeat
                if doubtful is not None and (repeat or off or doubtful[0] == before_trace) \
                        and toggle != expect and (doubtful[1] is None or toggle == doubtful[1]):
                    # it was a heartbeat too, or one before the master switched N to
                    # guarding (1017h = 0), or the trace's first: then this answer's fits
                    kind[doubtful[0]] = HEARTBEAT
                    hb_since_boot += 1
                    expect, doubtful = doubtful[1], None
            if is_guard:
                kind[i] = GUARD
                if requests > MISSED and pending == start:
                    before_trace = i
                pending = None
                doubtful = (i, expect) if (requests > MISSED or first_report) and (
                    toggle == 0 and not off) else None
                expect = 1 - toggle
            else:
                hb_since_boot += 1
                last_hb = ts
                early = None if period != period else params.early_factor * period - EPS
            requests = 0
            first_report = False


def _find_period(m: NodeModel) -> None:
    """Configured producer time, else the median heartbeat interval (no boot-up/reset inside).

    The median is kept apart too: it is the period where 1017h = 0 is in force.
    """
    if m.small is not None and m.kind_counts()[HEARTBEAT] >= 2:
        m.median_s, m.seg_bounds, m.seg_median = _small_period(m.small)
    elif m.kind_counts()[HEARTBEAT] < 2 and m.ec.runs is None:
        # no interval at all (most nodes of a log of many channels): what the two below
        # find of none, without their set-up
        m.median_s = None
        m.seg_bounds, m.seg_median = _NO_SEGMENTS, _ONE_NAN
    else:
        intervals = m.heartbeat_gaps()
        m.median_s = intervals.median() if intervals.count else None
        m.seg_bounds, m.seg_median = _segment_medians(m)
    if m.config.heartbeat_ms:
        m.period_s, m.period_source = m.config.heartbeat_ms / 1000.0, "configured"
    elif m.median_s is not None:
        m.period_s, m.period_source = m.median_s, "measured"
    else:
        m.period_s, m.period_source = None, "none"


_NO_SEGMENTS, _ONE_NAN = np.zeros(0), np.full(1, np.nan)  # read only: shared by nodes
_NO_SEGMENTS.flags.writeable = _ONE_NAN.flags.writeable = False


SMALL_NODE_FRAMES = 32  # a node of at most this many frames may take the list paths


def _small(m: NodeModel, params: TimelineParams) -> SmallEc | None:
    """N's frames as lists when N is a small plain node: a few boot-ups and heartbeats,
    no request, guarding response or malformed frame, no command, no SDO write, no
    dropped run, timestamps. The heartbeat stages (`_small_period`,
    `_small_heartbeat_timeouts`, `_small_self_start`, `_small_steps`) and rules then
    walk a few Python numbers instead of setting up numpy per node; each computes what
    its numpy path does (tests/test_many_channels.py compares them)."""
    ec = m.ec
    if (params.order_only or ec.runs is not None or not 0 < len(ec) <= SMALL_NODE_FRAMES
            or len(m.commands) or len(m.writes) or len(m.consumer_writes)):
        return None
    k = m.kind_counts()
    if k[REQUEST] or k[GUARD] or k[MALFORMED] or not k[HEARTBEAT]:
        return None
    return SmallEc(ec.ts.tolist(), ec.kind.tolist(), ec.value.tolist(), ec.idx.tolist())


def _small_period(s: SmallEc) -> tuple[float | None, np.ndarray, np.ndarray]:
    """`_find_period`'s median and `_segment_medians` for a small node: its pairs are
    consecutive heartbeats (no command), its segment bounds its boot-ups' times."""
    ts, kind = s.ts, s.kind
    pairs = [(ts[i], ts[i + 1]) for i in range(len(ts) - 1)
             if kind[i] == HEARTBEAT and kind[i + 1] == HEARTBEAT]
    if not pairs:
        return None, _NO_SEGMENTS, _ONE_NAN
    median = _list_median(sorted(b - a for a, b in pairs))
    bounds = sorted({t for t, k in zip(ts, kind, strict=True) if k == BOOTUP})
    medians = [np.nan] * (len(bounds) + 1)
    per_seg: dict[int, list[float]] = {}
    for a, b in pairs:
        seg = bisect.bisect_right(bounds, a)
        if seg == bisect.bisect_right(bounds, b):  # a pair across a bound belongs to none
            per_seg.setdefault(seg, []).append(b - a)
    for seg, gaps in per_seg.items():
        medians[seg] = _list_median(sorted(gaps))
    return median, np.asarray(bounds, np.float64), np.asarray(medians, np.float64)


def _list_median(gaps: list[float]) -> float:
    """numpy's median of sorted values: the middle one, or the mean of the two."""
    n = len(gaps)
    return (gaps[(n - 1) // 2] + gaps[n // 2]) / 2.0


def _segment_medians(m: NodeModel) -> tuple[np.ndarray, np.ndarray]:
    """The median heartbeat interval of each producer-time segment (SPEC §2): segments
    run between N's boot-ups, reset commands to N and confirmed 1017h writes to N, so
    that heartbeats sent under a power-on producer time never judge those sent under
    the one the master wrote. Returns the segments' bounds and one median per segment
    (NaN: no interval of its own); an interval across a bound belongs to none."""
    ec = m.ec
    a, b = m.heartbeat_pairs()
    if not a.size:  # no interval: every segment's median is NaN, wherever they are bounded
        return np.zeros(0), np.full(1, np.nan)
    bounds = np.unique(np.concatenate([
        ec.ts[ec.kind == BOOTUP], m.commands.reset_ts,
        m.writes.ts[m.writes.index == 0x1017]]).astype(np.float64))
    medians = np.full(len(bounds) + 1, np.nan)
    seg_a = np.searchsorted(bounds, ec.ts[a], side="right")
    seg_b = np.searchsorted(bounds, ec.ts[b], side="right")
    inside = seg_a == seg_b
    seg, gaps = seg_a[inside], (ec.ts[b] - ec.ts[a])[inside]
    if not seg.size:
        return bounds, medians
    if ec.runs is not None:  # a long log: its dropped runs count as their intervals
        for s in np.unique(seg).tolist():
            medians[s] = m.heartbeat_gaps(np.flatnonzero(inside & (seg_a == s))).median()
        return bounds, medians
    order = np.lexsort((gaps, seg))  # by segment, then by length: medians by position
    seg, gaps = seg[order], gaps[order]
    first = np.flatnonzero(np.concatenate([[True], seg[1:] != seg[:-1]]))
    count = np.diff(np.append(first, len(seg)))
    lo = first + (count - 1) // 2
    hi = first + count // 2
    medians[seg[first]] = (gaps[lo] + gaps[hi]) / 2.0
    return bounds, medians


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
    if m.small is not None:
        _small_heartbeat_timeouts(m, m.small, params, end)
        return
    ec = m.ec
    pos = np.flatnonzero((ec.kind == HEARTBEAT) | (ec.kind == BOOTUP))
    resets = m.commands.reset_idx
    writes = m.writes.take(np.flatnonzero(m.writes.index == 0x1017)) if len(
        m.writes) else m.writes
    # the events as columns: heartbeats and boot-ups, reset commands, 1017h writes
    ts = np.concatenate([ec.ts[pos], m.commands.reset_ts, writes.ts])
    idx = np.concatenate([ec.idx[pos], resets, writes.idx])
    what = np.concatenate([np.where(ec.kind[pos] == HEARTBEAT, _HB, _BOOT).astype(np.int8),
                           np.full(len(resets), _RESET, np.int8),
                           np.where(writes.value != 0, _ON, _OFF).astype(np.int8)])
    row = np.concatenate([pos, np.full(len(resets) + len(writes), -1)])  # in ec
    if len(resets) or len(writes):  # else the frames alone, in file order already
        order = np.argsort(idx, kind="stable")
        ts, idx, what, row = ts[order], idx[order], what[order], row[order]
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
        is_one_of(prev, (_BOOT, _RESET, _OFF)) | prev_silent))
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
    limit = m.hb_timeouts_at(at, params.timeout_factor)
    with np.errstate(invalid="ignore"):
        fire = (limit > 0) & (until - ts[gap] > limit + EPS)
    if ec.runs is not None and fire.any() and len(ends):
        # a gap closed by the heartbeat after a dropped run spans the run, whose every
        # interval is within the timeout (`ec_compact.unsafe_nodes` made sure)
        nxt = np.where(closed, ends[np.minimum(k, len(ends) - 1)], -1)
        inner = closed & (what[nxt] == _HB) & (row[nxt] == row[gap] + 1) & (
            ec.runs.at_rows(row[nxt]) >= 0)
        fire &= ~inner
    for g, lim, u, c in zip(gap[fire].tolist(), limit[fire].tolist(), until[fire].tolist(),
                            closed[fire].tolist(), strict=True):
        start = float(ts[g])
        m.timeouts.append(Timeout("H001", start + lim, start, int(idx[g]), lim,
                                  u - start if c else None))


def _small_heartbeat_timeouts(m: NodeModel, s: SmallEc, params: TimelineParams,
                              end: float) -> None:
    """`_heartbeat_timeouts` for a small node: no command and no write, so every frame
    ends a gap, each heartbeat opens one (none while 1017h = 0 is configured) and the
    configuration is the files' throughout."""
    cfg = m.config
    hb = np.nan if cfg.heartbeat_ms is None else float(cfg.heartbeat_ms)
    if hb == 0:  # no gap opens, and none would have a limit
        return
    cons = float(cfg.consumer_timeout_ms or np.nan)
    ts, kind = s.ts, s.kind
    last = len(ts) - 1
    for i, k in enumerate(kind):
        if k != HEARTBEAT:
            continue
        at = ts[i]
        period = hb / 1000.0 if hb > 0 else m.measured_period_at(at)
        limit = cons / 1000.0 if cons > 0 else params.timeout_factor * period
        until = ts[i + 1] if i < last else end
        if limit > 0 and until - at > limit + EPS:
            m.timeouts.append(Timeout("H001", at + limit, at, s.idx[i], limit,
                                      until - at if i < last else None))


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
    ec = m.ec
    pos = ec.where(REQUEST, GUARD, BOOTUP)  # heartbeats play no part here
    kind = ec.kind[pos]
    # Only a request not answered by the frame after it can time out, and a response
    # leaves nothing pending: the walk needs only the stretches from the response before
    # such a request to the response after it (none in a node always answered).
    unanswered = kind == REQUEST
    unanswered[:-1] &= kind[1:] != GUARD
    if not unanswered.any():
        return
    at = np.arange(len(kind))
    last_guard = np.maximum.accumulate(np.where(kind == GUARD, at, -1))
    next_guard = np.minimum.accumulate(np.where(kind == GUARD, at, len(kind))[::-1])[::-1]
    walk = np.zeros(len(kind) + 1, np.int64)
    bad = np.flatnonzero(unanswered)
    np.add.at(walk, last_guard[bad] + 1, 1)
    np.add.at(walk, np.minimum(next_guard[bad] + 1, len(kind)), -1)
    _guard_walk(m, params, end, pos[np.cumsum(walk[:-1]) > 0])


def _guard_walk(m: NodeModel, params: TimelineParams, end: float, pos: np.ndarray) -> None:
    """`_guard_timeouts` over the node's requests, responses and boot-ups at `pos`, in
    order (all of them, or stretches that each begin after a response)."""
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


def _self_starts(decoded: Decoded, nodes: list[tuple[NodeModel, float]]) -> None:
    """Nodes that entered OPERATIONAL by themselves after a boot-up (SPEC §2 Self-start).

    N's first error-control message after a boot-up (no NMT command to N between)
    reporting OPERATIONAL: N started itself, from its first TPDO after the boot-up, else
    from that message. When a reset command to N or N's next boot-up (or the end of the
    trace) comes before any message and no other command did, nothing shows whether N
    started itself: that span goes to `m.unproven_spans` (its PDOs are no S001).
    """
    queries: list[tuple[NodeModel, int, int, int]] = []  # node, boot pos, boot idx, msg idx
    for m, end in nodes:  # (each node with the end of its channel's trace)
        counts = m.kind_counts()
        if not counts[BOOTUP]:
            continue
        if not counts[HEARTBEAT] and not counts[GUARD] and not len(m.commands):
            m.unproven_spans = _unproven_bootups(m, end)  # most nodes of many channels
            continue
        queries.extend(_self_start_queries(m, end) if m.small is None
                       else _small_self_start(m, m.small, end))
    if not queries:
        return
    found = decoded.first_node_frame_after(
        np.asarray([m.key for m, *_ in queries]),
        np.asarray([float(m.ec.ts[p]) for m, p, _, _ in queries]),
        np.asarray([b for _m, _p, b, _ in queries]), kinds=(KIND_TPDO,))
    for (m, _p, _b, report_idx), t_idx, t_ts in zip(queries, found.idx.tolist(),
                                                   found.ts.tolist(), strict=True):
        if 0 <= t_idx < report_idx:
            m.self_starts.append((t_ts, t_idx))
        else:
            q = int(np.searchsorted(m.ec.idx, report_idx))
            m.self_starts.append((float(m.ec.ts[q]), report_idx))


def _self_start_queries(m: NodeModel, end: float) -> list[tuple[NodeModel, int, int, int]]:
    """`_self_starts` for one node with boot-ups: the boot-ups its first message shows it
    started itself after (node, boot-up position, its frame index, the message's), and
    its unproven spans, set on it."""
    ec = m.ec
    boots = ec.where(BOOTUP)
    msgs = ec.where(HEARTBEAT, GUARD)
    msgs = msgs[_CODE_STATE[ec.value[msgs] & 0x7F] >= 0]
    b_idx, b_ts = ec.idx[boots], ec.ts[boots]
    never = np.iinfo(np.int64).max
    next_boot = np.append(b_idx[1:], never)
    next_boot_ts = np.append(b_ts[1:], end)
    msg: np.ndarray = _next_of(ec.idx[msgs], b_idx, msgs, -1).astype(np.int64)
    msg_idx = np.where(msg >= 0, ec.idx[msg], never)
    cmds = m.commands
    next_cmd = _next_of(cmds.idx, b_idx)
    stop = np.minimum(next_boot, _next_of(cmds.reset_idx, b_idx))
    answered = (msg_idx < stop) & (msg_idx < next_cmd)
    started = answered & (_CODE_STATE[ec.value[msg] & 0x7F] == STATE_INDEX[OPERATIONAL])
    # No message before the next boot-up or command to N: nothing shows whether N started
    # itself (SPEC §2 for a reset or a boot-up; beyond it, for any command): the message
    # after a command reports what the command asked, self-started or not. CANopenNode's
    # master starts a self-starting slave before its first heartbeat, and the slave sends
    # its TPDO right after its boot-up: within S001's grace after the reset only where the
    # slave boots within it (16 us on Linux, a real device's reset may take 100s of ms).
    unknown = msg_idx >= np.minimum(next_boot, next_cmd)
    span_end = np.minimum(next_boot_ts, _next_of(cmds.idx, b_idx, cmds.ts, end))
    m.unproven_spans = [(float(a), float(b)) for a, b in zip(
        b_ts[unknown].tolist(), span_end[unknown].tolist(), strict=True)]
    return [(m, int(boots[i]), int(b_idx[i]), int(msg_idx[i]))
            for i in np.flatnonzero(started).tolist()]


def _small_self_start(m: NodeModel, s: SmallEc, end: float
                      ) -> list[tuple[NodeModel, int, int, int]]:
    """`_self_start_queries` for a small node (no command): after each boot-up, its first
    heartbeat with a CiA 301 state before the next boot-up decides; none: unproven."""
    never = np.iinfo(np.int64).max
    ts, kind, value, idx = s.ts, s.kind, s.value, s.idx
    boots = [i for i, k in enumerate(kind) if k == BOOTUP]
    queries, spans = [], []
    for j, p in enumerate(boots):
        nxt = boots[j + 1] if j + 1 < len(boots) else len(kind)
        msg = next((q for q in range(p + 1, len(kind)) if kind[q] == HEARTBEAT
                    and _CODE_STATE_LIST[value[q] & 0x7F] >= 0), -1)
        msg_idx = idx[msg] if msg >= 0 else never
        if msg_idx < (idx[nxt] if nxt < len(kind) else never):
            if _CODE_STATE_LIST[value[msg] & 0x7F] == _OPERATIONAL:
                queries.append((m, p, idx[p], msg_idx))
        else:
            spans.append((ts[p], min(ts[nxt], end) if nxt < len(kind) else end))
    m.unproven_spans = spans
    return queries


def _unproven_bootups(m: NodeModel, end: float) -> list[tuple[float, float]]:
    """What `_self_start_queries` finds for a node with boot-ups but no message and no
    command: no self-start, and each boot-up to the next (or the end) unproven."""
    b_ts = m.ec.ts[m.ec.kind == BOOTUP].tolist()
    return [(a, min(b, end)) for a, b in zip(b_ts, [*b_ts[1:], end], strict=True)]


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
_CODE_STATE_LIST: list[int] = _CODE_STATE.tolist()
_STATE_OF_BYTE_LIST: list[int] = _STATE_OF_BYTE.tolist()
_PRE_OP = STATE_INDEX[PRE_OPERATIONAL]
_OPERATIONAL = STATE_INDEX[OPERATIONAL]
_EC_SOURCE = {BOOTUP: SOURCE_INDEX["bootup"], HEARTBEAT: SOURCE_INDEX["heartbeat"],
              GUARD: SOURCE_INDEX["guarding"]}
_EV_TIMEOUT, _EV_EC, _EV_BACK = 0, 1, 2  # order of steps at one moment; commands are 1 too
_EV_CMD = 3


STEP_CHUNK = 1 << 16


def _reports_by_node(cm: ChannelModel) -> dict[int, np.ndarray]:
    """Each node's heartbeats and guarding answers on the channel, as frame indices."""
    return {n: m.ec.idx[(m.ec.kind == HEARTBEAT) | (m.ec.kind == GUARD)]
            for n, m in cm.nodes.items()}


def _stale_until(m: NodeModel, obey_s: float, reports: dict[int, np.ndarray]) -> np.ndarray:
    """Per command to N, until when a report of N that still says the state from before
    the command was queued before N processed it (stale, SPEC §2): `obey_s` after the
    command; in a log without timestamps, up to N's first report after the command
    (frame numbers are no time, and that report may still be a queued one: CANopenNode's
    heartbeat right after `000#0102` often says 7Fh, its TPDO and 05h come next) if it
    comes before any other node of the channel (`reports`: each node's, frame indices)
    has reported twice after the command: a report a whole heartbeat cycle later was
    not queued before it (B001 missed `703#05` 84 frames after `000#8103`)."""
    cmds = m.commands
    if not m.order_only:
        return cmds.ts + obey_s
    ec = m.ec
    mine = np.flatnonzero((ec.kind == HEARTBEAT) | (ec.kind == GUARD))
    if not mine.size:
        return cmds.ts.astype(np.float64)
    k = np.searchsorted(ec.idx[mine], cmds.idx, side="right")
    first = mine[np.minimum(k, mine.size - 1)]
    cycle = np.full(len(cmds), np.iinfo(np.int64).max)  # another node's second report
    for node, idx in reports.items():
        if node != m.node and idx.size >= 2:
            j = np.searchsorted(idx, cmds.idx, side="right") + 1
            cycle = np.minimum(cycle, np.where(j < idx.size, idx[np.minimum(j, idx.size - 1)],
                                               cycle))
    soon = (k < mine.size) & (ec.idx[first] < cycle)
    return np.where(soon, ec.ts[first].astype(np.float64), cmds.ts)


def _interval_steps(m: NodeModel, until: np.ndarray) -> Iterator[tuple[float, int, int]]:
    """What the interval walk sees, in order: (time, what, reference) for each evidence
    frame, command, timeout and end of a timeout. At one moment a timeout comes first
    and its end last; the rest in file order."""
    ec, cmds = m.ec, m.commands
    windows = list(zip(cmds.ts.tolist(), until.tolist(), strict=True)) + [
        (t, t) for t in [t.moment for t in m.timeouts]
        + [t.ended_by for t in m.timeouts if t.ended_by is not None]]
    pos = _evidence(m, windows)
    if not len(cmds) and not m.timeouts and not m.self_starts:  # the evidence alone, in
        yield from _in_chunks(ec.ts[pos], np.full(len(pos), _EV_EC, np.int8), pos,
                              np.arange(len(pos)))  # in time order already
        return
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
    if m.self_starts:  # a node that started itself: OPERATIONAL from its first TPDO, a
        # step like a command's (references past the commands: see _intervals)
        ts = np.concatenate([ts, [t for t, _i in m.self_starts]])
        order = np.concatenate([order, np.ones(len(m.self_starts), np.int8)])
        idx = np.concatenate([idx, [i for _t, i in m.self_starts]]).astype(np.int64)
        what = np.concatenate([what, np.full(len(m.self_starts), _EV_CMD, np.int8)])
        ref = np.concatenate([ref, len(cmds) + np.arange(len(m.self_starts))])
    steps = np.lexsort((idx, order, ts))
    yield from _in_chunks(ts, what, ref, steps)


def _small_steps(m: NodeModel, s: SmallEc) -> list[tuple[float, int, int]]:
    """`_interval_steps` for a small node (no command, no request): its evidence (the
    first frame, each change of the reported state, every boot-up, and around each
    timeout's moment and end the frames within and the first one after), its
    timeouts, their ends and its self-starts, sorted as the numpy path sorts them."""
    ts, kind, value, idx = s.ts, s.kind, s.value, s.idx
    pos = sorted(range(len(ts)), key=lambda p: (ts[p], idx[p]))
    sts = [ts[p] for p in pos]
    keep = [False] * len(pos)
    prev = None
    for j, p in enumerate(pos):
        target = _PRE_OP if kind[p] == BOOTUP else _STATE_OF_BYTE_LIST[value[p]]
        keep[j] = j == 0 or target != prev or kind[p] == BOOTUP
        prev = target
    marks = [t.moment for t in m.timeouts] + [
        t.ended_by for t in m.timeouts if t.ended_by is not None]
    for t in marks:  # a window [t, t]: the frames at t, and the first one after
        lo = bisect.bisect_left(sts, t)
        hi = min(bisect.bisect_right(sts, t + EPS), len(pos) - 1)
        for j in range(lo, hi + 1):
            keep[j] = True
    evidence = [p for j, p in enumerate(pos) if keep[j]]
    if not m.timeouts and not m.self_starts:
        return [(ts[p], _EV_EC, p) for p in evidence]
    # (time, order at one moment, file position, what, reference), then stable by the
    # first three as `_interval_steps`' lexsort
    rows: list[tuple[float, int, int, int, int]] = [
        (ts[p], 1, idx[p], _EV_EC, p) for p in evidence]
    rows += [(t.moment, 0, -1, _EV_TIMEOUT, i) for i, t in enumerate(m.timeouts)]
    rows += [(t.ended_by, 2, -1, _EV_BACK, i) for i, t in enumerate(m.timeouts)
             if t.ended_by is not None]
    rows += [(t, 1, i, _EV_CMD, j) for j, (t, i) in enumerate(m.self_starts)]
    rows.sort(key=lambda r: (r[0], r[1], r[2]))
    return [(r[0], r[3], r[4]) for r in rows]


def _in_chunks(ts: np.ndarray, what: np.ndarray, ref: np.ndarray, steps: np.ndarray
               ) -> Iterator[tuple[float, int, int]]:
    """The rows `steps` of the step columns, in that order, as Python numbers a chunk at
    a time: a node may have millions of steps."""
    for lo in range(0, len(steps), STEP_CHUNK):
        part = steps[lo:lo + STEP_CHUNK]
        yield from zip(ts[part].tolist(), what[part].tolist(), ref[part].tolist(), strict=True)


def _walk_inputs(m: NodeModel, until: np.ndarray) -> tuple[
        Iterable[tuple[float, int, int]], array[int] | list[int], array[int] | list[int]]:
    """The steps of `_intervals`' walk (`until`: each command's stale window's end), and
    each frame's kind and reported state."""
    if m.small is not None:  # a few frames, no command: lists
        return (_small_steps(m, m.small), m.small.kind,
                [_CODE_STATE_LIST[v & 0x7F] for v in m.small.value])
    # compact arrays, not lists: one entry per frame, read one at a time
    return (_interval_steps(m, until), array("b", m.ec.kind.astype(np.int8).tobytes()),
            array("b", _CODE_STATE[m.ec.value & 0x7F].tobytes()))


def _intervals(m: NodeModel, start: float, end: float, obey_s: float,
               reports: dict[int, np.ndarray]) -> IntervalTable:
    """Walk the node's evidence in order and cut the timeline into state intervals.

    A heartbeat or guarding response up to `obey_s` after a command that reports the
    state from before the command was queued before the node processed it: it is marked
    stale in `m.ec.stale` and is no evidence (SPEC §2). The walk sees plain ints and
    floats, never objects: a node may change state on every heartbeat.
    """
    ec, cmds = m.ec, m.commands
    stale_until = _stale_until(m, obey_s, reports)
    steps, kind, code_state = _walk_inputs(m, stale_until)
    until = stale_until.tolist()
    # per command, then per self-start (SPEC §2): the state it sets and the source
    cmd_state = [STATE_INDEX[COMMAND_STATE[c]] for c in cmds.cs.tolist()] + [
        STATE_INDEX[OPERATIONAL]] * len(m.self_starts)
    cmd_source = [SOURCE_INDEX["command"]] * len(cmds) + [
        SOURCE_INDEX["self-start"]] * len(m.self_starts)
    ended_by = [t.ended_by for t in m.timeouts]

    unknown, offline, pre_op = STATE_INDEX[UNKNOWN], STATE_INDEX[OFFLINE], STATE_INDEX[
        PRE_OPERATIONAL]
    src_timeout = SOURCE_INDEX["timeout"]
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
    # the latest command: until when a report may be stale, the state before it
    last_cmd: tuple[float, int] | None = None
    pre_offline: int | None = None  # the state N had when it went OFFLINE
    stale = ec.stale
    for at, w, r in steps:
        cur = states[-1]
        if w == _EV_EC:
            k = kind[r]
            state = code_state[r]
            if k in (HEARTBEAT, GUARD) and last_cmd is not None and (
                    at <= last_cmd[0] + EPS) and state == last_cmd[1]:
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
            last_cmd = (until[r] if r < len(until) else at + obey_s,  # else a self-start
                        pre_offline if cur == offline and pre_offline is not None else cur)
            if cur == offline:
                saved = (cmd_state[r], cmd_source[r])
            else:
                go(at, cmd_state[r], cmd_source[r])
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


def _only_bootups(m: NodeModel) -> bool:
    """Whether N's frames are boot-ups only (or none), with no command, timeout or
    self-start: its intervals are `_bootups_only`'s."""
    return (not len(m.commands) and not m.timeouts and not m.self_starts
            and m.kind_counts()[BOOTUP] == len(m.ec))


def _bootups_only(ec: EcTable, start: float, end: float) -> IntervalTable:
    """What the walk of `_intervals` makes of a node whose frames are boot-ups only (or
    none), with no command, timeout or self-start: UNKNOWN until its first boot-up,
    PRE-OPERATIONAL from then on (every later boot-up changes nothing). Most nodes of a
    log of many short channels; the walk's set-up costs far more than this."""
    unknown, pre_op = STATE_INDEX[UNKNOWN], STATE_INDEX[PRE_OPERATIONAL]
    if not len(ec):
        starts, states, sources = [start], [unknown], [SOURCE_INDEX["start"]]
    else:
        first = float(ec.ts.min())
        if first <= start:  # the UNKNOWN interval would be empty
            starts, states, sources = [start], [pre_op], [_EC_SOURCE[BOOTUP]]
        else:
            starts, states, sources = [start, first], [unknown, pre_op], [
                SOURCE_INDEX["start"], _EC_SOURCE[BOOTUP]]
    begin = np.asarray(starts, np.float64)
    return IntervalTable(begin, np.append(begin[1:], max(end, starts[-1])),
                         np.asarray(states, np.int8), np.asarray(sources, np.int8))
