"""Chain links and chains (SPEC §9.3.4, §9.3.5): the cause that explains a cause.

A node that drops to PRE-OPERATIONAL on its own (S005) is explained by its EMCY
(`error_behaviour`); that EMCY by the finding its code names: a SYNC timeout (8100h, link
`sync_timeout`) by the Y001 gap it reports, a heartbeat consumer's 8130h
(`heartbeat_consumer`) by the producer's H001; and that finding by its own first cause,
such as the NMT stop of the SYNC producer (`producer_state`). One cause per parent below
depth 1, at most `causes_depth_max` deep, each beginning at or before the effect it
explains; entries in pre-order (each depth-1 cause followed by its descendants).

Y001's own causes are links too: the producer's change, a silence or error frames that
began inside the gap, a logger's drop before the finding.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from nmtcheck.explain.entries import cause_entry
from nmtcheck.processes import emcy as emcy_stage
from nmtcheck.processes import pdo as pdo_stage
from nmtcheck.processes import sync as sync_stage
from nmtcheck.processes.comm_values import UNKNOWN
from nmtcheck.protocol import emcy
from nmtcheck.protocol.nmt import BOOTUP, EPS, GUARD, HEARTBEAT, STATE_OF_CODE
from nmtcheck.timeline.moments import at

if TYPE_CHECKING:
    from nmtcheck.results import Finding

NMT_NAMES = {0x01: "start", 0x02: "stop", 0x80: "enter pre-operational", 0x81: "reset node",
             0x82: "reset communication"}
# what a finding entry may be explained by in turn (never a configuration write, §9.3.5)
FINDING_CAUSE_KINDS = ("emcy", "error_frames", "frames_lost", "silence", "nmt", "node_state",
                       "node_silent", "boot_process")


# CANopenNode's markers that take a node out of OPERATIONAL with CO_NMT_ERR_ON_BUSOFF_HB
# (bus-off, heartbeat consumer, a monitored node's boot-up: CO_NMT_Heartbeat.c 224-228)
_CN_NMT_MARKERS = (0x12, 0x1B, 0x1C)
_PRE_OP, _OPERATIONAL, _STOPPED = "PRE-OPERATIONAL", "OPERATIONAL", "STOPPED"
# the reports of a PDO producer that stop its TPDOs: STOPPED, PRE-OPERATIONAL, a boot-up
PDO_STOP_STATES = (0x04, 0x7F, 0x00)


# An EMCY sent in the same cycle as the last report of the old state, just before it: a
# stack sends a heartbeat that is due with the state it had when the cycle began
# (CANopenNode's CO_process sends the RPDO timeout's EMCY, then the due 05h heartbeat, then
# applies the error register), so that report is no evidence the EMCY came later
SAME_CYCLE_S = 0.005


def same_cycle_start(analysis: Any, channel: str, m: Any, a: int) -> float:
    """The start of (tp, tf] for the links, `tp` being N's report at position `a` of its
    error-control rows: earlier by N's EMCY right before that report in the same cycle
    (at most SAME_CYCLE_S before it, only N's own error-control frames and EMCYs between in
    the file), a choice beyond SPEC §9.3.4, whose window would leave that EMCY out."""
    tp, tp_idx = float(m.ec.ts[a]), int(m.ec.idx[a])
    e = analysis.nodes.get((channel, m.node)) if analysis is not None else None
    if e is None or not len(e):
        return tp
    near = np.flatnonzero((e.idx < tp_idx) & (e.ts >= tp - SAME_CYCLE_S - EPS))
    for k in near.tolist():  # the earliest such EMCY with only N's frames after it
        between = tp_idx - int(e.idx[k]) - 1
        own = int(np.count_nonzero((m.ec.idx > e.idx[k]) & (m.ec.idx < tp_idx))) + int(
            np.count_nonzero((e.idx > e.idx[k]) & (e.idx < tp_idx)))
        if between == own:
            return float(e.ts[k]) - 2 * EPS  # (tp, tf] holds it
    return tp


def state_link(analysis: Any, channel: str, node: int, tp: float, tf: float,
               old: str | None, new: str | None) -> dict[str, Any] | None:
    """The EMCY of N in (tp, tf] that §9.3.4's `error_behaviour` (OPERATIONAL to
    PRE-OPERATIONAL or STOPPED) or `error_cleared` (PRE-OPERATIONAL to OPERATIONAL) link
    names, as a cause entry; the earliest that qualifies, None if none does."""
    e = analysis.nodes.get((channel, node)) if analysis is not None else None
    if e is None or not len(e):
        return None
    behaviour = e.behaviour.value if e.behaviour.known else None
    mask = e.register_mask if e.register_mask is not None else 0x10
    for k in np.flatnonzero((e.ts > tp + EPS) & (e.ts <= tf + EPS) & (e.dlc >= 3)).tolist():
        code, register = int(e.code[k]), int(e.register[k])
        data = e.data_bytes(k)
        if old == _OPERATIONAL and new in (_PRE_OP, _STOPPED):
            wanted = {0: _PRE_OP, 2: _STOPPED, 1: None}.get(int(behaviour)) if (
                behaviour is not None) else new
            cn = emcy.canopennode_detail(data, int(e.dlc[k])) is not None and (
                data[3] in _CN_NMT_MARKERS or (0x28 <= data[3] <= 0x2F and register & 1))
            if wanted == new and ((code >> 8) == 0x81 or register & mask or cn):
                name = "error_behaviour"
            else:
                continue
        elif old == _PRE_OP and new == _OPERATIONAL:
            if code < 0x100 and not register & mask:
                name = "error_cleared"
            else:
                continue
        else:
            return None
        return cause_entry("emcy", float(e.ts[k]), int(e.idx[k]), int(e.line[k]),
                           e.describe(k), node, count=1, code=f"{code:04X}h", link=name)
    return None


def sync_gap_entries(ctx: Any, f: Finding) -> tuple[list[dict[str, Any]], float] | None:
    """Y001's causes and reactions (§9.3.4): `producer_state` (a command reaching the SYNC
    producer, its boot-up, its report of STOPPED), `bus_silence` and `bus_errors` (a
    stretch beginning in the gap), `frames_lost` (a drop before the finding); after the
    effect, the consumers' EMCYs (their responses) and the producer's reports."""
    analysis = sync_stage.of(ctx.model)
    gap = analysis.gaps.get((str(f.channel), round(f.time, 9))) if analysis else None
    cm = ctx.channels.get(str(f.channel))
    if gap is None or cm is None or analysis is None:
        return None
    sc = analysis.channels[cm.name]
    tl, tf = gap.last_ts, f.time
    te = min(tl + gap.period, tf)
    producer = int(sc.producer.value) if sc.producer.known and sc.producer.value else None
    out = gap_links(ctx, cm, producer, (tl, gap.last_idx), te, tf, tf + ctx.after,
                    "producing SYNC", (0x04,))
    out += ctx._emcy_other(cm, -1 if producer is None else producer, [(te + EPS, tf + ctx.after)])
    return out, te


def pdo_gap_entries(ctx: Any, f: Finding) -> tuple[list[dict[str, Any]], float] | None:
    """D004's causes and reactions (§9.3.4): the producer's change (`producer_state`), a
    silence or error frames that began in the gap, a logger's drop before the finding;
    after the effect (t_l + the stream's period), the consumer's EMCY and the reports."""
    analysis = pdo_stage.of(ctx.model)
    key = (str(f.channel), int(f.node or 0), round(f.time, 9))
    gap = analysis.gaps.get(key) if analysis is not None else None
    cm = ctx.channels.get(str(f.channel))
    if gap is None or cm is None:
        return None
    tl, tf = gap.last_ts, f.time
    te = min(tl + gap.period, tf)
    out = gap_links(ctx, cm, gap.producer, (tl, gap.last_idx), te, tf, tf + ctx.after,
                    f"producer of {gap.cob_id:03X}h", PDO_STOP_STATES)
    m = cm.nodes.get(int(f.node or 0))
    if m is not None:
        out += ctx._emcy(m, m.node, [(te + EPS, tf + ctx.after)])
        out += _state_report(m, te, tf + ctx.after)
    return out, te


def gap_links(ctx: Any, cm: Any, producer: int | None, last: tuple[float, int], te: float,
              tf: float, reach: float, role: str, states: tuple[int, ...]
              ) -> list[dict[str, Any]]:
    """The §9.3.4 links of a stream's gap, in the table's order: the producer's change up to
    `reach` (`producer_state`; a later one is a reaction) and its silence
    (`producer_silent`), a silence or error frames beginning in (t_l, t_e], a logger's
    drop up to t_f. `last`: the gap's last frame (time, frame index)."""
    tl = last[0]
    out: list[dict[str, Any]] = []
    if producer is not None:
        out += _producer_changes(cm, producer, tl, reach, role, states)
        out += producer_silent(ctx, cm, producer, last, te, tf, role)
    out += [dict(c, link="bus_silence") for c in ctx._silence(cm, None, [(tl, te)])
            if c["time"] >= tl - EPS]
    out += [dict(c, link="bus_errors") for c in ctx._error_frames(cm, [(tl, te)])]
    out += [dict(c, link="frames_lost") for c in ctx._frames_lost(cm, [(tl, tf)])]
    return out


def producer_silent(ctx: Any, cm: Any, producer: int, last: tuple[float, int], te: float,
                    tf: float, role: str) -> list[dict[str, Any]]:
    """`producer_silent` (§9.3.4): the producer sent no frame of any kind after the gap's
    last frame `last` (time, frame index) up to the effect's t_f, and that silence is a
    timeout of its own: an H001 or G002 gap of the producer holds t_e, or, where it has
    no error-control limit, its next frame comes over 1.5 x its measured heartbeat period
    after its last one. A 10 ms SYNC gap inside a 200 ms heartbeat period is no evidence
    of silence. The entry runs from the producer's last frame to its next one."""
    m = cm.nodes.get(producer)
    if m is None:
        return []
    tl, tl_idx = last
    ec = m.ec
    sent = ~ec.rtr
    before = np.flatnonzero(sent & (ec.idx <= tl_idx))
    after = np.flatnonzero(sent & (ec.idx > tl_idx))
    last_ts, last_idx, last_line = tl, tl_idx, None
    if before.size and float(ec.ts[before[-1]]) >= tl - EPS and int(ec.idx[before[-1]]) > tl_idx:
        k = int(before[-1])
        last_ts, last_idx, last_line = float(ec.ts[k]), int(ec.idx[k]), int(ec.line[k])
    nxt = float(ec.ts[after].min()) if after.size else np.inf
    found = ctx.model.decoded.first_node_frame_after(
        np.asarray([m.key]), np.asarray([tl]), np.asarray([tl_idx]))
    if int(found.idx[0]) >= 0:
        nxt = min(nxt, float(found.ts[0]))
    if nxt <= tf + EPS:
        return []
    own = [to for to in m.timeouts if to.rule in ("H001", "G002")
           and to.after_ts <= te + EPS and (to.ended_by is None or to.ended_by > te + EPS)]
    if own:
        to = own[-1]
        why = f"its {to.rule} timeout at {at(to.moment, cm.start, False)}"
    else:
        cfg = m.config_at(tl)
        limited = bool(cfg.heartbeat_ms or cfg.consumer_timeout_ms or cfg.life_time_s)
        period = m.median_s
        since = float(ec.ts[before[-1]]) if before.size else tl
        if limited or not period or nxt - since <= 1.5 * period + EPS:
            return []
        why = f"over 1.5 x its heartbeat period ({period * 1000:g} ms, measured)"
    until = "the end of the log" if not np.isfinite(nxt) else at(nxt, cm.start, False)
    return [cause_entry("node_silent", last_ts, last_idx, last_line,
                        f"node {producer} ({role}) sent nothing from "
                        f"{at(last_ts, cm.start, False)} to "
                        f"{until}: {why}", producer,
                        end=None if not np.isfinite(nxt) else nxt, link="producer_silent")]


def _state_report(m: Any, lo: float, hi: float) -> list[dict[str, Any]]:
    """N's first report in (lo, hi] of a state other than OPERATIONAL (kind
    `node_state`): a consumer that left OPERATIONAL after its deadline."""
    ec = m.ec
    sel = np.flatnonzero((ec.kind == HEARTBEAT) & (ec.ts > lo + EPS) & (ec.ts <= hi + EPS)
                         & ~np.isin(ec.value & 0x7F, (0x05,)))
    return [cause_entry("node_state", float(ec.ts[k]), int(ec.idx[k]), int(ec.line[k]),
                        f"node {m.node} reports {STATE_OF_CODE.get(int(ec.value[k]) & 0x7F)}",
                        m.node) for k in sel[:1].tolist()]


def _producer_changes(cm: Any, producer: int, lo: float, hi: float, role: str,
                      states: tuple[int, ...]) -> list[dict[str, Any]]:
    """A command that reaches the producer, its boot-up, its report of one of `states`
    (the codes that stop it producing), in (lo, hi] (link `producer_state`)."""
    nmt = cm.nmt
    target = nmt.target.astype(np.int64)
    sel = np.flatnonzero(nmt.valid & ((target == producer) | (target == 0))
                         & (nmt.ts > lo + EPS) & (nmt.ts <= hi + EPS))
    out = [cause_entry("nmt", float(nmt.ts[k]), int(nmt.idx[k]), int(nmt.line[k]),
                       f"NMT {_command(nmt, k)}, node {producer} {role}", producer,
                       link="producer_state") for k in sel.tolist()]
    m = cm.nodes.get(producer)
    if m is not None:
        ec = m.ec
        span = (ec.ts > lo + EPS) & (ec.ts <= hi + EPS)
        # its heartbeat, or its answer to a guarding request (toggle bit masked)
        stopped = span & np.isin(ec.kind, (HEARTBEAT, GUARD)) & np.isin(ec.value & 0x7F, states)
        for kind, sel in (("bootup", span & (ec.kind == BOOTUP)), ("node_state", stopped)):
            out += [cause_entry(kind, float(ec.ts[k]), int(ec.idx[k]), int(ec.line[k]),
                                f"node {producer} ({role}) "
                                + ("boots up" if kind == "bootup" else
                                   f"reports {STATE_OF_CODE.get(int(ec.value[k]) & 0x7F)}"),
                                producer, link="producer_state")
                    for k in np.flatnonzero(sel)[:1].tolist()]
    return out


def _command(nmt: Any, k: int) -> str:
    """`stop to node 3`, `reset node to all nodes`: an NMT command in words."""
    name = NMT_NAMES.get(int(nmt.cs[k]), f"{int(nmt.cs[k]):02X}h")
    target = int(nmt.target[k])
    return f"{name} to {'all nodes' if target == 0 else f'node {target}'}"


def event_causes(ctx: Any, channel: str, node: int, entry: dict[str, Any],
                 findings: list[Finding], depth_max: int, delay: float
                 ) -> list[dict[str, Any]]:
    """The causes of an EMCY event (§9.3.6: each EMCY in `events[]` carries its chain):
    the finding its code links to and that finding's own cause, or for a CAN error EMCY
    (8120h, 8140h) the error frames before it (`can_errors`)."""
    code = int(str(entry["code"]).rstrip("h"), 16)
    if code in (0x8120, 0x8140):
        found = _can_errors(ctx, channel, node, code, float(entry["time"]))
        return [found] if found is not None else []
    chain = emcy_chain(ctx, At(channel), entry, findings, depth_max + 1, delay)
    return [dict(c, depth=int(c["depth"]) - 1,
                 parent=None if c["parent"] == 0 else int(c["parent"]) - 1) for c in chain]


@dataclass(frozen=True)
class At:
    """Where an event happened, as `emcy_chain` reads a finding's."""

    channel: str


def _can_errors(ctx: Any, channel: str, node: int, code: int, t_c: float
                ) -> dict[str, Any] | None:
    """`can_errors` (§9.3.4): for 8140h (CANopenNode sends it after recovering from
    bus-off), error frames after N's last frame before it; for 8120h, in the causes
    window before it. With no error frame in the whole input, an entry that says so."""
    cm = ctx.channels.get(channel)
    if cm is None:
        return None
    errors = ctx.spool.error_frames()
    if not len(errors["ts"]):
        return cause_entry("error_frames", t_c, None, None,
                           "the log holds no error frames (record them, e.g. candump -e)",
                           link="can_errors")
    lo = t_c - ctx.before
    m = cm.nodes.get(node)
    if code == 0x8140 and m is not None:
        before = m.ec.ts[m.ec.ts < t_c - EPS]
        lo = float(before.max()) if len(before) else lo
    found = ctx._error_frames(cm, [(lo + EPS, t_c)])
    return dict(found[0], link="can_errors") if found else None


def emcy_chain(ctx: Any, f: Any, entry: dict[str, Any], findings: list[Finding],
               depth_max: int, delay: float) -> list[dict[str, Any]]:
    """The descendants of an EMCY cause entry of node `entry["node"]` (§9.3.5): the
    finding its code links to, then that finding's own first cause; `parent` are indices
    relative to `entry` (0), fixed by the caller."""
    if depth_max < 2 or entry.get("kind") != "emcy" or entry.get("code") is None:
        return []
    code = int(str(entry["code"]).rstrip("h"), 16)
    t_c = float(entry["time"])
    found: Finding | None = None
    link = ""
    held = 1
    if code == 0x8100:
        (found, held), link = _sync_timeout(ctx, f, entry, findings, t_c, delay), "sync_timeout"
        if found is None:
            return _sync_gap(ctx, f, entry, t_c, delay, depth_max)
    elif code == 0x8250:
        (found, held), link = _rpdo_timeout(ctx, f, entry, findings, t_c, delay), "rpdo_timeout"
        if found is None:
            return _pdo_gap(ctx, f, entry, t_c, delay, depth_max)
    elif code == 0x8240:
        found, link = _sync_length(ctx, f, entry, findings, t_c, delay), "sync_length"
    elif code == 0x8130:
        detail = _cn_detail(ctx, f, entry)
        if detail is not None and detail["error_bit"] == "1Ch":  # a monitored node rebooted
            boot = _remote_reset(ctx, f, entry, t_c, delay)
            return [dict(boot, depth=2, parent=0)] if boot is not None else []
        guard = _life_guarding(ctx, f, int(entry["node"]), t_c)
        if guard is not None and detail is not None and int(str(detail["info"])) == 0 and (
                not _consumes(ctx, f, int(entry["node"]), t_c)):
            return [dict(guard, depth=2, parent=0)]  # CN's info 0: the first 1016h entry
        (found, held), link = _heartbeat_consumer(ctx, f, findings, t_c), "heartbeat_consumer"
        if found is None and guard is not None:
            return [dict(guard, depth=2, parent=0)]
    if found is None:
        return []
    entry["alternatives"] = max(held - 1, 0)  # the others that held (§9.3.5)
    child = cause_entry("finding", found.time, found.frame_index, found.line,
                        f"{found.rule} {found.name}: {found.message}", found.node, link=link)
    child.update(rule=found.rule, depth=2, parent=0)
    out = [child]
    if depth_max >= 3:
        # §9.3.4's `lss_bit_timing` is the last link of the table: it explains the
        # finding when none of the others does
        first = next((c for c in found.causes or ()
                      if c["kind"] in FINDING_CAUSE_KINDS and c["time"] <= found.time + EPS),
                     None) or next((c for c in found.causes or ()
                                    if c["kind"] == "lss_bit_timing"
                                    and c["time"] <= found.time + EPS), None)
        if first is not None:
            out.append(dict(first, depth=3, parent=1))
    return out


def _sync_timeout(ctx: Any, f: Finding, entry: dict[str, Any], findings: list[Finding],
                  t_c: float, delay: float) -> tuple[Finding | None, int]:
    """`sync_timeout`: the Y001 on the channel whose gap contains t_c, or ended at most
    `delay` before it; with CANopenNode's marker (byte 3 = 18h) the gap whose last SYNC
    lies `info` us before t_c. Another CANopenNode marker never links (8100h/15h is a
    TPDO outside the window)."""
    analysis = sync_stage.of(ctx.model)
    if analysis is None:
        return None, 0
    detail = _cn_detail(ctx, f, entry)
    if detail is not None and detail["error_bit"] != "18h":
        return None, 0
    best = None
    held = 0  # the candidates that held (one is taken, §9.3.5)
    for y in findings:
        if y.rule != "Y001" or y.channel != f.channel or y.time > t_c + EPS:
            continue
        gap = analysis.gaps.get((str(y.channel), round(y.time, 9)))
        if gap is None:
            continue
        if detail is not None:
            ok = abs(t_c - int(str(detail["info"])) / 1e6 - gap.last_ts) <= delay + EPS
        else:
            ok = gap.last_ts < t_c and (gap.next_ts > t_c or gap.next_ts >= t_c - delay)
        if ok:
            best = y
            held += 1
    return best, held


def _rpdo_timeout(ctx: Any, f: Finding, entry: dict[str, Any], findings: list[Finding],
                  t_c: float, delay: float) -> tuple[Finding | None, int]:
    """`rpdo_timeout`: a D004 of the EMCY's node whose gap contains t_c, or ended at most
    `delay` before it; with CANopenNode's marker (byte 3 = 17h) the gap whose last RPDO
    lies `info` us before t_c. The D004's time is at or before t_c."""
    analysis = pdo_stage.of(ctx.model)
    if analysis is None:
        return None, 0
    detail = _cn_detail(ctx, f, entry)
    node = int(entry["node"])
    best = None
    held = 0  # the candidates that held (one is taken, §9.3.5)
    for d in findings:
        if d.rule != "D004" or d.channel != f.channel or d.node != node or (
                d.time > t_c + EPS):
            continue
        gap = analysis.gaps.get((str(d.channel), node, round(d.time, 9)))
        if gap is None:
            continue
        if detail is not None and detail["error_bit"] == "17h":
            ok = abs(t_c - int(str(detail["info"])) / 1e6 - gap.last_ts) <= delay + EPS
        else:
            ok = gap.last_ts < t_c and (gap.next_ts > t_c or d.time >= t_c - delay)
        if ok:
            best = d
            held += 1
    return best, held


def _sync_length(ctx: Any, f: Finding, entry: dict[str, Any], findings: list[Finding],
                 t_c: float, delay: float) -> Finding | None:
    """`sync_length`: the Y002 whose offending SYNC is the latest in [t_c - delay, t_c];
    another CANopenNode marker than 19h never links."""
    detail = _cn_detail(ctx, f, entry)
    if detail is not None and detail["error_bit"] != "19h":
        return None
    hits = [y for y in findings if y.rule == "Y002" and y.channel == f.channel
            and t_c - delay - EPS <= y.time <= t_c + EPS]
    return hits[-1] if hits else None


def _remote_reset(ctx: Any, f: Finding, entry: dict[str, Any], t_c: float, delay: float
                  ) -> dict[str, Any] | None:
    """`heartbeat_remote_reset` (CANopenNode 8130h with byte 3 = 1Ch): the boot-up of a
    producer that had sent heartbeats before, at most `delay` plus the consumer's EMCY
    inhibit time before t_c (the latest such boot-up)."""
    cm = ctx.channels.get(str(f.channel))
    if cm is None:
        return None
    consumer = int(entry["node"])
    inhibit = 0.0
    analysis = emcy_stage.of(ctx.model)
    e = analysis.nodes.get((str(f.channel), consumer)) if analysis is not None else None
    if e is not None and len(e.inhibit) and not np.isnan(e.inhibit[-1]):
        inhibit = float(e.inhibit[-1]) * 1e-4
    best: tuple[float, dict[str, Any]] | None = None
    for n, m in cm.nodes.items():
        if n == consumer:
            continue
        ec = m.ec
        boots = np.flatnonzero((ec.kind == BOOTUP) & (ec.ts <= t_c + EPS)
                               & (ec.ts >= t_c - delay - inhibit - EPS))
        for k in boots[-1:].tolist():
            beat_before = bool(((ec.kind == HEARTBEAT) & (ec.ts < ec.ts[k])).any())
            if beat_before and (best is None or ec.ts[k] > best[0]):
                best = (float(ec.ts[k]), cause_entry(
                    "bootup", float(ec.ts[k]), int(ec.idx[k]), int(ec.line[k]),
                    f"boot-up of node {n}, whose heartbeat node {consumer} watches", n,
                    link="heartbeat_remote_reset"))
    return best[1] if best is not None else None


def _life_guarding(ctx: Any, f: Any, node: int, t_c: float) -> dict[str, Any] | None:
    """`life_guarding` (§9.3.4): C is guarded (requests on 700h + C were seen), its life
    time T_l = 100Ch x 100Dh is known, and no request reached it in (t_c - T_l, t_c]: the
    guarding pause, from the last request to C, explains its 8130h (LE `nmt.c` 1373-1379,
    CN `CO_Node_Guarding.c` 223)."""
    cm = ctx.channels.get(str(f.channel))
    m = cm.nodes.get(node) if cm is not None else None
    if m is None or not m.ec.rtr.any():
        return None
    life = m.config_at(t_c).life_time_s
    requests = np.flatnonzero(m.ec.rtr & (m.ec.ts <= t_c + EPS))
    if not life or not requests.size:
        return None
    k = int(requests[-1])
    last = float(m.ec.ts[k])
    if last > t_c - life + EPS:
        return None
    return cause_entry("guarding_gap", last, int(m.ec.idx[k]), int(m.ec.line[k]),
                       f"no guarding request to node {node} from {at(last, cm.start, False)} on "
                       "(life time "
                       f"{life * 1000:g} ms)", node, end=t_c, link="life_guarding")


def _consumes(ctx: Any, f: Any, node: int, t_c: float) -> bool:
    """Whether a heartbeat consumer time of C is known at t_c (its 1016h, from the files or
    written by SDO): CANopenNode's 8130h info 0 then names that entry, not guarding."""
    cm = ctx.channels.get(str(f.channel))
    m = cm.nodes.get(node) if cm is not None else None
    return m is not None and m.config_at(t_c).consumer_timeout_ms is not None


def _heartbeat_consumer(ctx: Any, f: Finding, findings: list[Finding], t_c: float
                        ) -> tuple[Finding | None, int]:
    """`heartbeat_consumer`: the H001 of a producer whose gap contains t_c, at or before
    t_c (the latest such H001)."""
    best = None
    held = 0  # the candidates that held (one is taken, §9.3.5)
    cm = ctx.channels.get(str(f.channel))
    for h in findings:
        if h.rule != "H001" or h.channel != f.channel or h.time > t_c + EPS or cm is None:
            continue
        m = cm.nodes.get(int(h.node or 0))
        if m is None:
            continue
        for to in m.timeouts:
            if to.rule == "H001" and abs(to.moment - h.time) < 1e-6 and to.after_ts < t_c and (
                    to.ended_by is None or to.ended_by > t_c):
                best = h
                held += 1
    return best, held


def _cn_detail(ctx: Any, f: Finding, entry: dict[str, Any]) -> dict[str, object] | None:
    """CANopenNode's detail of the EMCY frame an entry points at, if it carries one."""
    analysis = emcy_stage.of(ctx.model)
    e = analysis.nodes.get((str(f.channel), int(entry["node"]))) if analysis else None
    if e is None:
        return None
    k = np.flatnonzero(e.idx == entry["frame_index"])
    if not k.size:
        return None
    j = int(k[0])
    return emcy.canopennode_detail(e.data_bytes(j), int(e.dlc[j]))


# -- the measured stand-ins of §9.3.4: a gap that explains an EMCY where the rule that
# judges it could not (no deadline, no SYNC period): basis `measured`, never a finding


def _pdo_gap(ctx: Any, f: Any, entry: dict[str, Any], t_c: float, delay: float,
             depth_max: int) -> list[dict[str, Any]]:
    """`rpdo_timeout`'s stand-in `pdo_gap`, where D004 did not evaluate C's RPDOs: one of
    C's RPDO streams (configured, else pre-defined) has its last frame t_l < t_c, none in
    (t_l, t_c], and t_c - t_l > 2 x its median interval over >= 3 intervals; with
    CANopenNode's marker (17h) the stream whose t_l is nearest t_c - info us, else the
    latest t_l. Below it, the gap's own first cause (producer_state, producer_silent, a
    silence, error frames, a logger's drop)."""
    cm = ctx.channels.get(str(f.channel))
    analysis = pdo_stage.of(ctx.model)
    if cm is None or analysis is None:
        return []
    node = int(entry["node"])
    mine = [st for st in analysis.streams if st.channel == cm.network_name
            and any(c.node == node for c in st.consumers)]
    if any(c.node == node and c.event_timer_ms.known and c.event_timer_ms.value
           for st in mine for c in st.consumers):
        return []  # D004 judged C's RPDOs: its silence is the verdict
    cobs = {st.cob_id for st in mine}
    extra = [pdo_stage.Stream(cm.network_name, cm.chan, base + node, None,
                              [pdo_stage.Party(node, k + 1, "rpdo")], UNKNOWN, ctx.model)
             for k, base in enumerate(pdo_stage.RPDO_BASES) if base + node not in cobs]
    pdo_stage.load_frames(extra, ctx.model)
    detail = _cn_detail(ctx, f, entry)
    aim = (t_c - int(str(detail["info"])) / 1e6 if detail is not None
           and detail["error_bit"] == "17h" else None)
    best: tuple[float, Any, int, float] | None = None
    for st in [*mine, *extra]:
        ts, idx, _line = st.frames()
        before = np.flatnonzero(ts < t_c - EPS)
        if len(before) < 4:
            continue
        k = int(before[-1])
        median = float(np.median(np.diff(ts[before])))
        if median <= 0 or t_c - ts[k] <= 2 * median:
            continue
        score = abs(float(ts[k]) - aim) if aim is not None else -float(ts[k])
        if best is None or score < best[0]:
            best = (score, st, k, median)
    if best is None:
        return []
    _score, st, k, median = best
    ts, idx, line = st.frames()
    tl = float(ts[k])
    nxt = float(ts[k + 1]) if k + 1 < len(ts) else None
    gap = cause_entry("pdo_gap", tl, int(idx[k]), int(line[k]),
                      f"no RPDO {st.cob_id:03X}h for node {node} after "
                      f"{at(tl, cm.start, False)}: {(t_c - tl) * 1000:.3f} ms before the EMCY, "
                      f"over 2 x its median interval {median * 1000:.3f} ms (measured)", node,
                      end=nxt, link="rpdo_timeout")
    gap.update(basis="measured", depth=2, parent=0)
    out = [gap]
    if depth_max >= 3:
        producer = st.producer.node if st.producer is not None else None
        first = _gap_cause(ctx, cm, producer, (tl, int(idx[k])), min(tl + median, t_c), t_c,
                           f"producer of {st.cob_id:03X}h", PDO_STOP_STATES)
        if first is not None:
            out.append(dict(first, depth=3, parent=1))
    return out


def _sync_gap(ctx: Any, f: Any, entry: dict[str, Any], t_c: float, delay: float,
              depth_max: int) -> list[dict[str, Any]]:
    """`sync_timeout`'s stand-in `sync_gap`, where no Y001 gap holds t_c: the SYNC gap
    (t_s, t_n) around t_c, t_s < t_c and t_n > t_c - delay, longer than 1.5 x the median
    SYNC interval before t_s over >= 5 intervals. An 8100h with another CANopenNode
    marker than 18h never links."""
    detail = _cn_detail(ctx, f, entry)
    if detail is not None and detail["error_bit"] != "18h":
        return []
    cm = ctx.channels.get(str(f.channel))
    analysis = sync_stage.of(ctx.model)
    sc = analysis.channels.get(cm.name) if analysis is not None and cm is not None else None
    if sc is None or not len(sc):
        return []
    data = np.flatnonzero(~sc.rtr)
    before = data[sc.ts[data] < t_c - EPS]
    if len(before) < 6:
        return []
    k = int(before[-1])
    after = data[data > k]
    t_n = float(sc.ts[after[0]]) if len(after) else np.inf
    median = float(np.median(np.diff(sc.ts[before])))
    t_s = float(sc.ts[k])
    if median <= 0 or t_n - t_s <= 1.5 * median or t_n <= t_c - delay:
        return []
    span = ("the rest of the log" if not np.isfinite(t_n)
            else f"{(t_n - t_s) * 1000:.3f} ms")
    gap = cause_entry("sync_gap", t_s, int(sc.idx[k]), int(sc.line[k]),
                      f"no SYNC after {at(t_s, cm.start, False)} for {span}: over 1.5 x "
                      f"the median SYNC interval {median * 1000:.3f} ms (measured)",
                      None, end=None if not np.isfinite(t_n) else t_n, link="sync_timeout")
    gap.update(basis="measured", depth=2, parent=0)
    out = [gap]
    if depth_max >= 3:
        producer = (int(sc.producer.value) if sc.producer.known and sc.producer.value
                    else None)
        first = _gap_cause(ctx, cm, producer, (t_s, int(sc.idx[k])),
                           min(t_s + median, t_c), t_c, "producing SYNC", (0x04,))
        if first is not None:
            out.append(dict(first, depth=3, parent=1))
    return out


def _gap_cause(ctx: Any, cm: Any, producer: int | None, last: tuple[float, int], te: float,
               tf: float, role: str, states: tuple[int, ...]) -> dict[str, Any] | None:
    """A stand-in gap's first cause by §9.3.4's links in their order (`gap_links`, the
    producer's change only up to t_e)."""
    found = gap_links(ctx, cm, producer, last, te, tf, te, role, states)
    return next((c for c in found if c["time"] <= tf + EPS), None)
