"""Which node of a channel is its NMT master (SPEC §2): named by the network or a
device file, else inferred from the log: the node whose boot-up precedes the commands,
or that commands reach only through its own resets, and that obeys no command itself."""

from __future__ import annotations

import bisect

import numpy as np

from nmtcheck.protocol.nmt import (
    COMMAND_NAMES,
    COMMAND_STATE,
    EPS,
    RESETS,
    STATE_INDEX,
    STATE_OF_CODE,
)
from nmtcheck.timeline.model import (
    EcTable,
    Master,
    NmtTable,
    NodeModel,
    TimelineParams,
    reset_cs,
)
from nmtcheck.timeline.moments import at
from nmtcheck.timeline.tables import next_of


def master_obeyed(m: NodeModel, nmt: NmtTable, own: np.ndarray, direct: np.ndarray,
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
    next_reset = next_of(nmt.idx[reaching], c_idx)
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


def channel_master(name: str, nmt: NmtTable, tables: dict[int, EcTable],
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
                untimed = params.order_only
                found[node] = (f"boot-up at {at(b_ts, start, untimed)}, then broadcast "
                               f"{COMMAND_NAMES[f_cs]} at {at(f_ts, start, untimed)} that "
                               f"node {node} did not obey")
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
            notes.append(f"the reset burst at {at(b_ts, start, params.order_only)} leaves "
                         "out node-IDs "
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
                why = (f"boot-up at {at(float(t.ts[q]), start, params.order_only)}, then a "
                       "burst of resets to every other node-ID at "
                       f"{at(b_ts, start, params.order_only)}")
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
