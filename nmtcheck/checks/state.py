"""State and communication rules (S): what a node may send in which NMT state (Table 37).

S001-S003 run vectorised over the whole input: the node frames sent while some node
was PRE-OPERATIONAL or STOPPED (`InputModel.sent_while`) are matched against each
node's finished timeline with `searchsorted`; only offending runs become Python
objects, and they are reported in file order across nodes.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from nmtcheck.checks.base import (
    Found,
    NodeContext,
    Param,
    Params,
    Problem,
    batch,
    count_note,
    input_rule,
    rule,
)
from nmtcheck.protocol.nmt import (
    BOOTUP,
    COMMAND_STATE,
    EPS,
    GUARD,
    HEARTBEAT,
    OFFLINE,
    OPERATIONAL,
    PRE_OPERATIONAL,
    STATE_INDEX,
    STATE_OF_CODE,
    STATES,
    STOPPED,
    between,
    is_one_of,
    state_name,
)
from nmtcheck.timeline.decode import KIND_EMCY, KIND_NAMES, KIND_RPDO, KIND_SDO_TX, KIND_TPDO
from nmtcheck.timeline.model import InputModel, NodeModel
from nmtcheck.timeline.tables import IntervalTable, interval_columns

_STATE_OF_CODE = np.full(128, -1, np.int8)  # state index of a 7-bit state code, -1 if none
for _code, _state in STATE_OF_CODE.items():
    _STATE_OF_CODE[_code] = STATE_INDEX[_state]
_STATE_LIST: list[int] = _STATE_OF_CODE.tolist()
_COMMAND_STATE = np.zeros(256, np.int8)  # state index a command specifier commands
for _cs, _state in COMMAND_STATE.items():
    _COMMAND_STATE[_cs] = STATE_INDEX[_state]


@dataclass
class _Run:
    """Offending frames of one node within one timeline interval."""

    ts: float
    idx: int
    line: int
    can_id: int
    kind: int
    count: int


_CHECKED_STATES = (PRE_OPERATIONAL, STOPPED)  # the states S001-S003 look into


def _scan(model: InputModel, kinds: tuple[int, ...], states: tuple[str, ...],
          grace_s: float, grace_from: str | None, unproven: bool = False,
          self_started: bool = False) -> list[tuple[NodeModel, int, _Run]]:
    """Frames of `kinds` sent while the node is in one of `states`.

    Frames at most `grace_s` after the node left `grace_from` are excused (S001);
    with `grace_from` None, frames at most `grace_s` after the node entered its
    current state (S003). Returning from OFFLINE to the state it had before is
    not a new entry. With `unproven`, frames in a node's `unproven_spans` (after a
    boot-up, nothing shows whether it started itself: SPEC §2) are excused too.

    Every node's intervals are matched at once, as columns (a log of many channels
    has tens of thousands of nodes with a frame or two each).
    """
    by_key = {m.key: m for cm in model.channels for m in cm.nodes.values()}
    cand = model.sent_while(states, kinds)  # only frames this rule may judge
    sel = np.arange(len(cand.kind))
    keys = cand.key[sel]
    order = np.argsort(keys, kind="stable")  # each node's rows in file order, found once
    uniq, count = np.unique(keys[order], return_counts=True)
    found = [by_key.get(k) for k in uniq.tolist()]
    nodes = [m for m in found if m is not None]
    if not nodes:
        return []
    known = np.asarray([m is not None for m in found])
    mine = known[np.repeat(np.arange(len(uniq)), count)]  # rows of a node in the model
    group = np.repeat(np.cumsum(known) - 1, count)[mine]  # its position in `nodes`
    rows = sel[order][mine]  # node after node, each in file order
    ts = cand.ts[rows]
    ivs = _Intervals([m.intervals for m in nodes])
    since = ivs.grace_since(STATE_INDEX[grace_from] if grace_from else None)
    iv = _last_at_or_before(ivs.node, ivs.start, group, ts)
    iv = np.where(iv >= 0, iv, ivs.first[group])  # before the first interval: the first
    bad = is_one_of(ivs.state[iv], [STATE_INDEX[s] for s in states])
    bad &= ~((ts - since[iv]) <= grace_s + EPS)
    if unproven:
        bad &= ~_unproven(nodes, group, ts)
    if self_started:
        bad &= ~_unproven(nodes, group, ts, _self_start_windows)
    hit = np.flatnonzero(bad)
    if not hit.size:
        return []
    # one run per node and interval: its first frame in file order, and how many
    hit = hit[np.argsort(rows[hit], kind="stable")]
    runs, at, size = np.unique(iv[hit], return_index=True, return_counts=True)
    heads = rows[hit[at]]
    out = []
    for r in np.argsort(cand.idx[heads], kind="stable").tolist():
        row, g = int(heads[r]), int(runs[r])
        m = nodes[int(ivs.node[g])]
        out.append((m, g - int(ivs.first[ivs.node[g]]), _Run(
            float(cand.ts[row]), int(cand.idx[row]), int(cand.line[row]),
            int(cand.can_id[row]), int(cand.kind[row]), int(size[r]))))
    return out


class _Intervals:
    """Several nodes' state intervals as one set of columns, node after node: `node`
    (the node's position in the list), `first` (per node, its first row), `local`
    (each row's position within its node)."""

    def __init__(self, tables: list[IntervalTable]) -> None:
        lengths, self.start, _no_end, self.state = interval_columns(tables, with_end=False)
        self.node = np.repeat(np.arange(len(tables)), lengths)
        self.first = np.cumsum(lengths) - lengths
        self.local = np.arange(len(self.start)) - self.first[self.node]

    def grace_since(self, grace_code: int | None) -> np.ndarray:
        """When the grace period of each interval began: with `grace_code`, the start of
        the interval after the last one in that state, carried over the intervals after
        it but OFFLINE ones (-inf: none); without, the interval's own start, or that of
        the interval two back when the node returns from OFFLINE to its state there."""
        prev = np.concatenate([[-1], self.state[:-1]]).astype(np.int16)
        offline = STATE_INDEX[OFFLINE]
        rows = np.arange(len(self.start))
        if grace_code is not None:
            sets = (self.local >= 1) & (prev == grace_code)
            keeps = (self.local >= 1) & ~sets & (prev != offline)  # carried from the one before
            root = np.maximum.accumulate(np.where(keeps, -1, rows))
            since: np.ndarray = np.where(sets[root], self.start[root], -np.inf)
            return since
        two_back = np.concatenate([[-1, -1], self.state[:-2]]).astype(np.int16)[:len(rows)]
        back = (self.local >= 2) & (prev == offline) & (two_back == self.state)
        root = rows.copy()
        for parity in (0, 1):  # a chain of returns steps back two intervals at a time
            chain = rows[parity::2]
            root[parity::2] = np.maximum.accumulate(np.where(back[chain], -1, chain))
        since = self.start[root]
        return since


def _last_at_or_before(g_node: np.ndarray, g_at: np.ndarray, q_node: np.ndarray,
                       q_at: np.ndarray) -> np.ndarray:
    """Per query (node, time), the last row of columns sorted by node then time with
    the same node and a time at or before it (-1: none): one merge for every node, as
    `np.searchsorted(..., side="right") - 1` would find node by node."""
    n = len(g_at)
    if not n:
        return np.full(len(q_at), -1, np.int64)
    order = np.lexsort((np.concatenate([np.zeros(n, np.int8), np.ones(len(q_at), np.int8)]),
                        np.concatenate([g_at, q_at]), np.concatenate([g_node, q_node])))
    last = np.maximum.accumulate(np.where(order < n, order, -1))
    query = order >= n
    out = np.empty(len(q_at), np.int64)
    out[order[query] - n] = last[query]
    same: np.ndarray = (out >= 0) & (g_node[np.maximum(out, 0)] == q_node)
    return np.where(same, out, -1)


def _self_start_windows(m: NodeModel) -> list[tuple[float, float]]:
    """From each boot-up after which N started itself to the frame that shows it did."""
    if not m.self_starts:
        return []
    boots = m.ec.ts[m.ec.kind == BOOTUP]
    out = []
    for ts, _idx in m.self_starts:
        before = boots[boots <= ts + EPS]
        if len(before):
            out.append((float(before[-1]), float(ts)))
    return out


def _unproven(nodes: list[NodeModel], group: np.ndarray, ts: np.ndarray,
              spans_of: Callable[[NodeModel], list[tuple[float, float]]] | None = None
              ) -> np.ndarray:
    """Per frame (of node `nodes[group]` at `ts`), whether it falls in an unproven
    span of its node (the last span starting at or before it, up to its end); with
    `spans_of`, in one of the spans it gives."""
    # every node's spans as one set of columns, not an array per node (200,000 nodes)
    counts = np.zeros(len(nodes), np.int64)
    flat_spans: list[float] = []
    for g, m in enumerate(nodes):
        node_spans = m.unproven_spans if spans_of is None else spans_of(m)
        if node_spans:
            counts[g] = len(node_spans)
            flat_spans.extend(x for span in node_spans for x in span)
    node = np.repeat(np.arange(len(nodes)), counts)
    if not len(node):
        return np.zeros(len(ts), bool)
    flat = np.asarray(flat_spans, np.float64).reshape(-1, 2)
    first_span = np.cumsum(counts) - counts
    lo, hi = flat[:, 0], flat[:, 1]
    # span starts out of time order (timestamps that go back): that node as before
    unsorted = np.unique(node[1:][(node[1:] == node[:-1]) & (lo[1:] < lo[:-1])])
    sorted_rows = ~is_one_of(node, unsorted) if unsorted.size else np.ones(len(node), bool)
    k = _last_at_or_before(node[sorted_rows], lo[sorted_rows], group, ts)
    if sorted_rows.any():  # else every node's spans go back in time: each is done below
        k = np.where(k >= 0, np.flatnonzero(sorted_rows)[np.maximum(k, 0)], -1)
    for g in unsorted.tolist():
        mine = np.flatnonzero(group == g)
        first = int(first_span[g])
        span = np.searchsorted(lo[first:first + counts[g]], ts[mine], side="right") - 1
        k[mine] = np.where(span >= 0, first + span, -1)
    inside: np.ndarray = (k >= 0) & (ts <= hi[np.maximum(k, 0)] + EPS)
    return inside


@input_rule("S001", "pdo-while-not-operational", "error",
            Param("grace_ms", float, "PDOs this soon after leaving OPERATIONAL are still in "
                  "flight", 5.0), scope="node")
def pdo_while_not_operational(model: InputModel, p: Params) -> Iterator[Problem]:
    """A node transmitted a PDO while not OPERATIONAL.

    **What it checks.** N transmits a TPDO (default COB-IDs 180h/280h/380h/480h + N)
    while its state is PRE-OPERATIONAL or STOPPED, unless N left OPERATIONAL at most
    `grace_ms` before (frames already queued), or N started itself (SPEC §2
    Self-start: its first error-control message after the boot-up reports
    OPERATIONAL with no command between; when a reset or a boot-up comes before
    any such message, nothing shows it did not). Consecutive offending PDOs within
    one timeline interval give one finding with their count.

    **Why it matters.** CiA 301 Table 37: PDOs exist only in OPERATIONAL. Process
    data sent before the master started the node (or after it stopped it) reaches
    consumers that were told the producer is not running: outputs move while
    the network is being configured or is meant to be halted.

    **Example.** `702#00` (boot-up), then `182#0102` before any `000#01..`.
    """
    yield from _pdo_problems(model, (KIND_TPDO,), p["grace_ms"] / 1000.0, OPERATIONAL, "sent",
                             unproven=True)


@input_rule("S002", "pdo-to-not-operational", "info", scope="node")
def pdo_to_not_operational(model: InputModel, p: Params) -> Iterator[Problem]:
    """An RPDO was sent to a node that is not OPERATIONAL and will ignore it.

    **What it checks.** An RPDO of N (default 200h/300h/400h/500h + N) is on the bus
    while N is PRE-OPERATIONAL or STOPPED.

    **Why it matters.** N does not process PDOs outside OPERATIONAL (Table 37): the
    command in that PDO is lost. Usually the master started sending set-points
    before starting the node.

    **Example.** `203#0000` while node 3's heartbeat says 7Fh.
    """
    # between a boot-up and the report that shows N started itself, N may already have
    # been OPERATIONAL (a Lely master starts itself at once): no S002 there
    yield from _pdo_problems(model, (KIND_RPDO,), 0.0, None, "on the bus for the node",
                             self_started=True)


def _pdo_problems(model: InputModel, kinds: tuple[int, ...], grace_s: float,
                  grace_from: str | None, verb: str, unproven: bool = False,
                  self_started: bool = False) -> Iterator[Problem]:
    for m, iv, run in _scan(model, kinds, (PRE_OPERATIONAL, STOPPED), grace_s, grace_from,
                            unproven, self_started):
        state = m.intervals[iv].state
        yield Problem(m.channel, m.node, run.ts,
                      f"{KIND_NAMES[run.kind]} {run.can_id:03X}h {verb} while node {m.node} is "
                      f"{state}{count_note(run.count)}", run.idx, run.line)


@input_rule("S003", "comm-while-stopped", "error",
            Param("grace_ms", float, "frames this soon after entering STOPPED are still in "
                  "flight", 5.0), scope="node")
def comm_while_stopped(model: InputModel, p: Params) -> Iterator[Problem]:
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
      Param("obey_ms", float, "time a node has to carry out a command before its reports count",
            100.0))
def command_not_obeyed(m: NodeModel, ctx: NodeContext, p: Params) -> Iterator[Found]:
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
    cmds = m.commands
    if not len(cmds):
        return
    # the master's own broadcasts are applied only where it obeyed them: never a finding
    todo = np.flatnonzero(~cmds.is_reset & ~is_one_of(cmds.idx, m.own_command_idx))
    if not todo.size:  # positions, not objects: there may be a million commands
        return
    ec = m.ec
    reports = ec.where(BOOTUP, HEARTBEAT, GUARD)  # frames that report a state
    reports = reports[~ec.stale[reports]]  # queued before a command: no evidence
    state = _STATE_OF_CODE[ec.code[reports]]
    boot = ec.kind[reports] == BOOTUP
    reports, state, boot = (x[boot | (state >= 0)] for x in (reports, state, boot))
    if not reports.size:
        return
    c_idx, c_ts, c_cs = cmds.idx, cmds.ts, cmds.cs
    target = _COMMAND_STATE[c_cs[todo]]
    newer = np.append(c_idx[1:], np.iinfo(np.int64).max)[todo]
    c_ts = c_ts[todo]
    # the first report after each command; the scan of its reports ends at a boot-up, a
    # report after a newer command, or one of the commanded state, whichever comes first
    rep_idx, rep_ts = ec.idx[reports], ec.ts[reports]
    first = np.searchsorted(rep_idx, c_idx[todo], side="right")
    ends = np.minimum(np.searchsorted(rep_idx, newer, side="right"), _next_where(boot, first))
    for s_idx in np.unique(target).tolist():
        mine = target == s_idx
        ends[mine] = np.minimum(ends[mine], _next_where(state == s_idx, first[mine]))
    # ... and the command is not obeyed if a report more than obey_ms after it comes first
    late = _first_late(rep_ts, c_ts, first, ends, obey)
    hit = np.flatnonzero(late < ends)
    if not hit.size:
        return
    at = reports[late[hit]]
    rep_state, expected, when, pos = state[late[hit]], target[hit], c_ts[hit], todo[hit]

    def message(i: int) -> str:
        return (f"node {m.node} reports {STATES[rep_state[i]]} {ec.ts[at[i]] - when[i]:.3f} s "
                f"after NMT {cmds.name(int(pos[i]))} (expected {STATES[expected[i]]})")

    yield batch(ec.ts[at], message, ec.idx[at], ec.line[at])


def _next_where(flag: np.ndarray, start: np.ndarray) -> np.ndarray:
    """For each start position, the first position >= it where `flag` holds (len if none)."""
    n = len(flag)
    nxt = np.where(flag, np.arange(n), n)
    nxt = np.minimum.accumulate(nxt[::-1])[::-1]
    result: np.ndarray = np.append(nxt, n)[np.minimum(start, n)]
    return result


def _first_late(ts: np.ndarray, c_ts: np.ndarray, first: np.ndarray, ends: np.ndarray,
                obey: float) -> np.ndarray:
    """Per command, the first report at or after `first` more than `obey` after the
    command's time (len(ts) if none; a walk only looks before `ends`): a binary search
    when the reports' times never go back, else a walk (timestamps out of order)."""
    n = len(ts)
    if n < 2 or bool((np.diff(ts) >= 0).all()):
        late = np.maximum(np.searchsorted(ts, c_ts + obey + EPS, side="right"), first)
        # the exact test is ts - c_ts > obey + EPS: move over rounding at the boundary
        while True:
            back = np.flatnonzero((late > first) & (late > 0)
                                  & (ts[np.maximum(late - 1, 0)] - c_ts > obey + EPS))
            if not back.size:
                break
            late[back] -= 1
        while True:
            on = np.flatnonzero((late < n) & ~(ts[np.minimum(late, n - 1)] - c_ts > obey + EPS))
            if not on.size:
                break
            late[on] += 1
        return np.asarray(late, np.int64)
    late = np.full(len(c_ts), n, np.int64)
    times = ts.tolist()
    for j, (k, e, t) in enumerate(zip(first.tolist(), ends.tolist(), c_ts.tolist(),
                                      strict=True)):
        for q in range(k, min(e, n)):
            if times[q] - t > obey + EPS:
                late[j] = q
                break
    return late


@rule("S005", "unexplained-state-change", "info")
def unexplained_state_change(m: NodeModel, ctx: NodeContext, p: Params) -> Iterator[Found]:
    """A node changed its NMT state on its own.

    **What it checks.** N's reported state changes between two of its error-control
    messages with no NMT command to N in between and no boot-up. The channel's NMT
    master is left out: it changes its own state by design (CiA 302).

    **Why it matters.** Local control is allowed (self-start, 1029h error behaviour,
    application events) but it is the first thing to look at when a node leaves
    OPERATIONAL unexpectedly: it usually reacted to an error it saw.

    **Example.** `703#05`, `703#05`, `703#7F` with no NMT command to node 3.
    """
    if ctx.master is not None and m.node == ctx.master.node:
        return  # a master starts and stops itself (CiA 302): that is its job
    k = m.kind_counts()
    if k[HEARTBEAT] + k[GUARD] < 2:  # a change needs two reports
        return
    if m.small is not None and len({_STATE_LIST[v & 0x7F] for k, v in zip(
            m.small.kind, m.small.value, strict=True) if k != BOOTUP} - {-1}) < 2:
        return  # a small node whose heartbeats report one state: no change
    ec = m.ec
    # heartbeats and guarding responses with a CiA 301 state; a boot-up starts anew
    pos = ec.where(BOOTUP, HEARTBEAT, GUARD)
    pos = pos[~ec.stale[pos]]  # queued before a command: no evidence
    kind = ec.kind[pos]
    state = _STATE_OF_CODE[ec.code[pos]]
    pos, kind, state = (x[(kind == BOOTUP) | (state >= 0)] for x in (pos, kind, state))
    a, b = pos[:-1], pos[1:]
    change = np.flatnonzero((kind[:-1] != BOOTUP) & (kind[1:] != BOOTUP)
                            & (state[:-1] != state[1:])
                            & ~between(m.commands.idx, ec.idx[a], ec.idx[b]))
    if not change.size:
        return
    prev_code, code = ec.code[a[change]], ec.code[b[change]]

    def message(i: int) -> str:
        return (f"node {m.node} changed from {state_name(int(prev_code[i]))} to "
                f"{state_name(int(code[i]))} without an NMT command")

    at = b[change]
    yield batch(ec.ts[at], message, ec.idx[at], ec.line[at])
