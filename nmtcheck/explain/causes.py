"""Causes and reactions (SPEC §8.6, §9.3.1-9.3.3): the events that may explain a finding,
and those that came after it began.

Called by the engine after the rules: H001, G002, B001 (a), B002 and S004 findings (and
those of §9.3.5: Y001, D001, D003, D004, L001, L006, S005) get `causes` and `reactions`
(each possibly empty) with what their caps left out. Each finding looks at its node's
columns (EMCYs, error-control frames, commands), the channel's NMT frames and error
frames and the boot analysis, within the finding's window (8.6.2);
nothing is per frame. Causality is strict: an entry is a cause only if it began at or
before the moment the finding's effect began (t_e, `effect_start`); everything later is a
reaction with its role (`during`, `report`, `response`, `bus`): the master's reset after a
heartbeat timeout answers it, it does not explain it. Causes are listed, never ranked as
"the" cause.
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING, Any

import numpy as np

from nmtcheck.explain import lss_link, pdo_links
from nmtcheck.explain.chains import (
    At,
    emcy_chain,
    event_causes,
    pdo_gap_entries,
    same_cycle_start,
    state_link,
    sync_gap_entries,
)
from nmtcheck.explain.entries import (
    capped,
    cause_entry,
    cluster_entry,
    effect_start,
    split,
)
from nmtcheck.processes import emcy as emcy_stage
from nmtcheck.protocol import emcy
from nmtcheck.protocol.nmt import (
    BOOTUP,
    EPS,
    GUARD,
    HEARTBEAT,
    REQUEST,
    SOURCE_INDEX,
    STATE_OF_CODE,
    STATES,
)
from nmtcheck.timeline.decode import key_rows
from nmtcheck.timeline.ec_compact import expanded

if TYPE_CHECKING:
    from nmtcheck.processes.boot_records import BootFinding
    from nmtcheck.processes.sdo_transfers import SdoSpool
    from nmtcheck.results import Finding, InputResult


RULES = ("H001", "G002", "B001", "B002", "S004", "Y001", "D001", "D003", "D004", "L001",
         "L006", "S005")  # S005 last: it reads
# the causes of the findings its chain links to (§9.3.5)
SDO_WRITES = {"H001": (0x1017, 0x1016), "G002": (0x100C, 0x100D, 0x1017),
              "B002": (0x1F51, 0x1011, 0x1010), "S004": (0x1029,), "S005": (0x1029,)}
NMT_NAMES = {0x01: "start", 0x02: "stop", 0x80: "enter pre-operational", 0x81: "reset node",
             0x82: "reset communication"}


CAN_ERR_CRTL = 0x004  # SocketCAN error class: controller problems (linux/can/error.h)
CAN_ERR_CRTL_OVERFLOW = 0x03  # its byte 1: RX (01h) or TX (02h) buffer overflow
MAX_CAUSED_PER_RULE = 1000  # findings of one rule per input that get their causes


def attach(result: InputResult, spool: SdoSpool, profile: Any) -> None:
    """Give P findings their letter and evidence, and the findings of SPEC §8.6 their
    causes."""
    boot_fields(result)
    if result.model.timeline.order_only:
        return
    tl = profile.timeline
    ctx = _Ctx(result, spool, float(tl.get("causes_before_ms", 1000.0)) / 1000.0,
               float(tl.get("causes_after_ms", 500.0)) / 1000.0,
               int(tl.get("causes_max", 5)), float(tl.get("silence_min_ms", 100.0)) / 1000.0,
               float(tl.get("reboot_cluster_ms", 500.0)) / 1000.0,
               float(profile["B002"].params.get("reset_window_ms", 10000.0)) / 1000.0
               if "B002" in profile else 10.0)
    caused: dict[str, int] = {}
    depth_max = int(tl.get("causes_depth_max", 3))
    delay = float(tl.get("emcy_delay_ms", 200.0)) / 1000.0
    order = {r: k for k, r in enumerate(RULES)}
    for f in sorted((f for f in result.findings if f.rule in RULES), key=lambda f: order[f.rule]):
        if f.channel is None or (f.node is None and f.rule not in ("Y001", "L001")):
            continue
        # causes are objects: a bounded number per rule keeps memory bounded on a log
        # with a million timeouts (the first ones are where a diagnosis starts)
        caused[f.rule] = caused.get(f.rule, 0) + 1
        if caused[f.rule] > MAX_CAUSED_PER_RULE:
            continue
        found = (sync_gap_entries(ctx, f) if f.rule == "Y001" else
                 pdo_gap_entries(ctx, f) if f.rule == "D004" else
                 lss_link.lss_entries(ctx.model, f, ctx.before) if f.rule in lss_link.ROOTS
                 else pdo_links.entries(ctx, f) if f.rule in pdo_links.ROOTS
                 else ctx.causes(f))
        if found is None:
            continue
        entries, te = found
        if f.rule in ("H001", "Y001", "D004"):  # §9.3.4 `lss_bit_timing`
            entries = entries + lss_link.bit_timing_entries(ctx.model, f.channel, te,
                                                            ctx.before)
        causes, reactions = split(entries, te, f.time, f.node)
        f.causes, f.causes_omitted = capped(causes, ctx.max)
        f.reactions, f.reactions_omitted = capped(reactions, ctx.max)
        if f.rule == "S005":
            f.causes = with_chains(f.causes, [
                emcy_chain(ctx, f, c, result.findings, depth_max, delay)
                if c.get("link") == "error_behaviour" else [] for c in f.causes])
    _emcy_events(ctx, result, depth_max, delay)
    _interval_causes(ctx, result, depth_max, delay)


def _interval_causes(ctx: _Ctx, result: InputResult, depth_max: int, delay: float) -> None:
    """§9.3.6: a timeline interval that begins with a change of the node's reported state
    and no NMT command (source heartbeat or guarding) carries the causes S005 would list,
    whether S005 is selected or not, the channel's master's too."""
    analysis = emcy_stage.of(result.model)
    if analysis is None or not analysis.nodes:
        return
    reported = np.asarray([SOURCE_INDEX["heartbeat"], SOURCE_INDEX["guarding"]])
    done = 0
    for cm in result.model.channels:
        for n, m in cm.nodes.items():
            if (cm.name, n) not in analysis.nodes:
                continue  # no EMCY: no link can hold
            ivs = m.intervals
            change = np.flatnonzero((np.arange(len(ivs)) > 0) & np.isin(ivs.source, reported)
                                    & (ivs.state != np.roll(ivs.state, 1)))
            reports = np.flatnonzero(np.isin(m.ec.kind, (HEARTBEAT, GUARD)) & ~m.ec.stale)
            for i in change.tolist():
                if done >= MAX_EVENTS_CAUSED:
                    return
                tf = float(ivs.start[i])
                k = int(np.searchsorted(m.ec.ts[reports], tf - EPS, side="left")) - 1
                if k < 0:
                    continue
                start = same_cycle_start(analysis, cm.name, m, int(reports[k]))
                old, new = STATES[int(ivs.state[i - 1])], STATES[int(ivs.state[i])]
                link = state_link(analysis, cm.name, n, start, tf, old, new)
                if link is None:
                    continue
                done += 1
                at = At(cm.name)
                result.interval_causes[(cm.name, n, round(tf, 9))] = with_chains(
                    [link], [emcy_chain(ctx, at, link, result.findings, depth_max, delay)])


MAX_EVENTS_CAUSED = 1000  # EMCY events per input that get their chain (the first ones)
_LINKED_CODES = (0x8100, 0x8120, 0x8130, 0x8140, 0x8240, 0x8250)


def _emcy_events(ctx: _Ctx, result: InputResult, depth_max: int, delay: float) -> None:
    """Each EMCY event whose code a chain link knows gets its causes (§9.3.6)."""
    analysis = emcy_stage.of(result.model)
    if analysis is None:
        return
    done = 0
    for (channel, node), e in analysis.nodes.items():
        code = e.code
        for k in np.flatnonzero(np.isin(code, _LINKED_CODES) & (e.dlc >= 2)).tolist():
            if done >= MAX_EVENTS_CAUSED:
                return
            done += 1
            entry = cause_entry("emcy", float(e.ts[k]), int(e.idx[k]), int(e.line[k]),
                                e.describe(k), node, count=1, code=f"{int(code[k]):04X}h")
            result.event_causes[(channel, node, int(e.idx[k]))] = event_causes(
                ctx, channel, node, entry, result.findings, depth_max, delay)


def with_chains(causes: list[dict[str, Any]], chains: list[list[dict[str, Any]]]
                ) -> list[dict[str, Any]]:
    """Depth-1 causes, each followed at once by its descendants (pre-order, §9.3.5), with
    `parent` made an index into the whole list."""
    out: list[dict[str, Any]] = []
    for c, chain in zip(causes, chains, strict=True):
        at = len(out)
        out.append(c)
        out += [dict(d, parent=at + int(d["parent"])) for d in chain]
    return out


class _Ctx:
    def __init__(self, result: InputResult, spool: SdoSpool, before: float, after: float,
                 cap: int, silence_min: float, cluster: float, reset_window: float) -> None:
        self.res = result
        self.model = result.model
        self.spool = spool
        self.before, self.after, self.max = before, after, cap
        self.silence_min, self.cluster, self.reset_window = silence_min, cluster, reset_window
        self.channels = {cm.name: cm for cm in self.model.channels}
        self._errors: dict[str, np.ndarray] | None = None
        self._drops: dict[str, np.ndarray] | None = None
        self._nmt_by_time: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def causes(self, f: Finding) -> tuple[list[dict[str, Any]], float] | None:
        """Every entry in the finding's windows, and its effect start t_e."""
        cm = self.channels.get(str(f.channel))
        if cm is None:
            return None
        m = cm.nodes.get(int(f.node or 0))
        if m is None:
            return None
        n = m.node
        t = f.time
        if f.rule == "S005":
            return self._state_change(f, m, cm)
        a0, a1 = self._interval(f, m, cm)
        if a0 is None:
            return None
        windows = [(a0 - self.before, a1 + self.after)]
        out: list[dict[str, Any]] = []
        if f.rule in ("H001", "G002"):
            r = self._next_frame(m, a1, f)
            if r is not None:
                windows.append((r[0], r[0] + self.after))
                if r[3] == "bootup":
                    out.append(cause_entry("reboot", r[0], r[1], r[2],
                                      f"node {n} rebooted: its next frame is a boot-up", n))
        if f.rule == "B002":
            windows = [(a0 - self.before, a0 + self.after)]
        out += self._emcy(m, n, windows)
        if f.rule in ("H001", "G002", "B002"):
            out += self._emcy_other(cm, n, windows)
        out += self._error_frames(cm, windows)
        out += self._frames_lost(cm, windows)
        out += self._silence(cm, m, windows)
        cmd_win = [(a0 - self.reset_window, a0)] if f.rule == "B002" else windows
        out += self._nmt(cm, m, n, f, cmd_win, a0)
        out += self._sdo_writes(m, f.rule, cmd_win)
        if f.rule == "B002":
            out += self._cluster(cm, n, a0, f)
        out += self._boot(f, n, a0)
        return out, effect_start(f.rule, a0, t, self._period_at(m, a0))

    def _state_change(self, f: Finding, m: Any, cm: Any
                      ) -> tuple[list[dict[str, Any]], float] | None:
        """S005 (SPEC §9.3.4, §9.3.5): N's own EMCYs and the writes of its 1029h in the
        window, the EMCY that moved N by its error behaviour (or cleared it) linked."""
        ec = m.ec
        at = np.flatnonzero(ec.idx == (f.frame_index if f.frame_index is not None else -1))
        if not at.size:
            return None
        b = int(at[0])
        before = np.flatnonzero((ec.idx < ec.idx[b]) & np.isin(ec.kind, (HEARTBEAT, GUARD))
                                & ~ec.stale)
        if not before.size:
            return None
        a = int(before[-1])
        tp, tf = float(ec.ts[a]), float(ec.ts[b])
        old = STATE_OF_CODE.get(int(ec.value[a]) & 0x7F)
        new = STATE_OF_CODE.get(int(ec.value[b]) & 0x7F)
        windows = [(tp - self.before, tf + self.after)]
        out = self._emcy(m, m.node, windows)
        analysis = emcy_stage.of(self.model)
        start = same_cycle_start(analysis, str(f.channel), m, a)
        link = state_link(analysis, str(f.channel), m.node, start, tf, old, new)
        if link is not None:
            out = [c for c in out if c["frame_index"] != link["frame_index"]] + [link]
            f.message += (f"; explained by EMCY {link['code']} at "
                          f"{link['time'] - self.model.start:.6f} s (line {link['line']})")
        out += self._sdo_writes(m, "S005", windows)
        return out, tf

    def _period_at(self, m: Any, t: float) -> float | None:
        """N's heartbeat period at t (§2): the producer time in force, else the measured
        median; None where neither is known."""
        producer = m.config_at(t).heartbeat_ms
        if producer:
            return float(producer) / 1000.0
        period = m.median_s if m.median_s else m.period_s
        return float(period) if period else None

    # -- the finding's interval ------------------------------------------------------------
    def _interval(self, f: Finding, m: Any, cm: Any) -> tuple[float | None, float]:
        t = f.time
        if f.rule in ("H001", "G002"):
            best = None
            for to in m.timeouts:
                if to.rule == f.rule and abs(to.moment - t) < 1e-6:
                    best = to
                    break
            return (best.after_ts if best is not None else None), t
        if f.rule == "B002":
            return t, t
        cmds = m.commands
        if not len(cmds):
            return None, t
        ts = cmds.ts
        if f.rule == "B001":
            resets = cmds.reset_ts
            k = int(np.searchsorted(resets, t + EPS)) - 1
            return (float(resets[k]) if k >= 0 else None), t
        k = int(np.searchsorted(ts, t + EPS)) - 1
        return (float(ts[k]) if k >= 0 else None), t

    def _next_frame(self, m: Any, a1: float, f: Finding) -> tuple[float, int, int, str] | None:
        """N's first frame after a1: (time, index, line, what)."""
        best: tuple[float, int, int, str] | None = None
        ec = m.ec
        k = np.flatnonzero((ec.ts > a1 + EPS) & (ec.kind != REQUEST))
        if k.size:
            j = int(k[0])
            best = (float(ec.ts[j]), int(ec.idx[j]), int(ec.line[j]),
                    "bootup" if ec.kind[j] == BOOTUP else "ec")
        nf = self.model.decoded.first_node_frame_after(
            np.asarray([m.key]), np.asarray([a1 + EPS]), np.asarray([-1]))
        if nf.idx[0] >= 0 and (best is None or nf.ts[0] < best[0]):
            best = (float(nf.ts[0]), int(nf.idx[0]), int(nf.line[0]), "frame")
        return best

    # -- kinds ----------------------------------------------------------------------------
    def _emcy_rows(self, key: int) -> tuple[np.ndarray, ...]:
        e = self.model.decoded.emcy
        rows = key_rows(e["key"], key, key)
        return e["ts"][rows], e["idx"][rows], e["line"][rows], e["dlc"][rows], e["data"][rows]

    def _emcy(self, m: Any, n: int, windows: list[tuple[float, float]]
              ) -> list[dict[str, Any]]:
        ts, idx, line, dlc, data = self._emcy_rows(m.key)
        sel = _in(ts, windows) & (dlc >= 3) & ((data & 0xFFFF) != 0)
        out: list[dict[str, Any]] = []
        prev = None
        for k in np.flatnonzero(sel).tolist():
            code = int(data[k]) & 0xFFFF
            if prev is not None and prev["code"] == f"{code:04X}h":
                prev["count"] += 1
                continue
            _c, text = emcy.describe(list(int(data[k]).to_bytes(8, sys.byteorder)),
                                     int(dlc[k]))
            prev = cause_entry("emcy", ts[k], int(idx[k]), int(line[k]), text, n, count=1,
                          code=f"{code:04X}h")
            out.append(prev)
        return out

    def _emcy_other(self, cm: Any, n: int, windows: list[tuple[float, float]]
                    ) -> list[dict[str, Any]]:
        out: list[dict[str, Any]] = []
        for o in cm.nodes.values():
            if o.node == n:
                continue
            ts, idx, line, dlc, data = self._emcy_rows(o.key)
            code = (data & 0xFFFF).astype(np.int64)
            sel = np.flatnonzero(_in(ts, windows) & (dlc >= 2) & ((code >> 8) == 0x81))
            seen: set[int] = set()
            for k in sel.tolist():
                c = int(code[k])
                if c in seen:
                    continue
                seen.add(c)
                _c, text = emcy.describe(list(int(data[k]).to_bytes(8, sys.byteorder)),
                                         int(dlc[k]))
                out.append(cause_entry("emcy_other", ts[k], int(idx[k]), int(line[k]), text,
                                  o.node, count=int(np.count_nonzero(code[sel] == c)),
                                  code=f"{c:04X}h"))
        return out

    def _error_frames(self, cm: Any, windows: list[tuple[float, float]]
                      ) -> list[dict[str, Any]]:
        if self._errors is None:
            self._errors = self.spool.error_frames()
        e = self._errors
        sel = np.flatnonzero((e["chan"] == cm.chan) & _in(e["ts"], windows))
        if not sel.size:
            return []
        a, b = int(sel[0]), int(sel[-1])
        return [cause_entry("error_frames", e["ts"][a], int(e["idx"][a]), int(e["line"][a]),
                       f"{sel.size} error frame(s) on the channel", end=float(e["ts"][b]),
                       count=int(sel.size))]

    def _frames_lost(self, cm: Any, windows: list[tuple[float, float]]
                     ) -> list[dict[str, Any]]:
        """The logger's drop records (candump `DROPCOUNT`, placed at the frame after the
        line: the lost frames were due before it; a drop names no channel, so it counts on
        every channel) and the channel's controller-overflow error frames in W."""
        out: list[dict[str, Any]] = []
        d = self._drop_positions()
        sel = np.flatnonzero(_in(d["ts"], windows))
        if sel.size:
            a, b = int(sel[0]), int(sel[-1])
            total = int(d["count"][sel].sum())
            out.append(cause_entry("frames_lost", d["ts"][a], int(d["idx"][a]), int(d["line"][a]),
                              f"the logger reported {total} frame(s) lost "
                              f"({sel.size} {self.res.stats.drop_record} record(s)): a gap "
                              "here may be the logger's", end=float(d["ts"][b]) if b != a else None,
                              count=total))
        if self._errors is None:
            self._errors = self.spool.error_frames()
        e = self._errors
        over = ((e["cls"] & CAN_ERR_CRTL) != 0) & ((e["d1"] & CAN_ERR_CRTL_OVERFLOW) != 0)
        sel = np.flatnonzero(over & (e["chan"] == cm.chan) & _in(e["ts"], windows))
        if sel.size:
            a, b = int(sel[0]), int(sel[-1])
            out.append(cause_entry("frames_lost", e["ts"][a], int(e["idx"][a]), int(e["line"][a]),
                              f"{sel.size} controller overflow error frame(s): the interface "
                              "lost received or queued frames", end=float(e["ts"][b])
                              if b != a else None, count=int(sel.size)))
        return out

    def _drop_positions(self) -> dict[str, np.ndarray]:
        """Each drop record's moment (`Decoded.drop_moments`), found once."""
        if self._drops is None:
            self._drops = self.model.decoded.drop_moments(
                getattr(self.res.stats, "drops", None) or [])
        return self._drops

    def _silence(self, cm: Any, m: Any, windows: list[tuple[float, float]]
                 ) -> list[dict[str, Any]]:
        """A stretch with no frame on the channel of at least max(silence_min, 2 x P_min)."""
        periods = [o.period_s for o in cm.nodes.values() if o is not m and o.period_s]
        if not periods:
            return []
        need = max(self.silence_min, 2 * min(periods))
        lo = min(w[0] for w in windows)
        hi = max(w[1] for w in windows)
        ts = self._channel_times(cm, lo, hi)
        if len(ts) < 2:
            return []
        gaps = np.diff(ts)
        k = np.flatnonzero(gaps >= need - EPS)
        return [cause_entry("silence", ts[j], None, None,
                       f"no frame on the channel for {gaps[j] * 1000:.0f} ms",
                       end=float(ts[j + 1])) for j in k[:3].tolist()]

    def _channel_times(self, cm: Any, lo: float, hi: float) -> np.ndarray:
        """Times of the channel's frames in [lo, hi] from the NMT, error-control and node
        columns (no per-frame store is read in full)."""
        parts = [cm.nmt.ts[(cm.nmt.ts >= lo) & (cm.nmt.ts <= hi)]]
        parts += [o.ec.ts[(o.ec.ts >= lo) & (o.ec.ts <= hi)] for o in cm.nodes.values()]
        for o in cm.nodes.values():  # a long log's dropped heartbeats, exchanges: stand-ins
            for runs in (o.ec.runs, o.ec.guard_runs):
                if runs is not None:
                    parts += [t[(t >= lo) & (t <= hi)] for t in expanded(o.ec.ts, runs, lo, hi)]
        for chunk in self.model.decoded.node_frames.reaching(lo):
            sel = ((chunk["key"] // 128) == cm.chan) & (chunk["ts"] >= lo) & (chunk["ts"] <= hi)
            parts.append(chunk["ts"][sel])
        return np.sort(np.concatenate(parts)) if parts else np.zeros(0)

    def _nmt_in(self, cm: Any, windows: list[tuple[float, float]]) -> np.ndarray:
        """Positions (ascending) of the channel's NMT frames inside the windows, by binary
        search on the frames sorted by time once per channel: a log of nothing but NMT
        commands has millions, and up to MAX_CAUSED_PER_RULE findings of each rule ask."""
        by_time = self._nmt_by_time.get(cm.name)
        if by_time is None:
            order = np.argsort(cm.nmt.ts, kind="stable")
            by_time = self._nmt_by_time[cm.name] = (order, cm.nmt.ts[order])
        order, ts = by_time
        parts = [order[np.searchsorted(ts, lo - EPS, side="left"):
                       np.searchsorted(ts, hi + EPS, side="right")] for lo, hi in windows]
        return np.unique(np.concatenate(parts)) if parts else np.zeros(0, np.int64)

    def _nmt(self, cm: Any, m: Any, n: int, f: Finding, windows: list[tuple[float, float]],
             a0: float) -> list[dict[str, Any]]:
        nmt = cm.nmt
        master = cm.master.node if cm.master is not None else None
        pos = self._nmt_in(cm, windows)
        tgt = nmt.target[pos].astype(np.int64)
        ts, cs = nmt.ts[pos], nmt.cs[pos]
        sel = nmt.valid[pos] & ((tgt == n) | ((tgt == 0) & (n != master)))
        if f.rule in ("S004", "B001"):
            sel &= ~(np.abs(ts - a0) < 1e-9)
        if f.rule == "B001":
            sel &= (cs != 0x81) & (cs != 0x82) & (ts > a0)
        out = []
        for k in pos[sel].tolist():
            name = NMT_NAMES.get(int(nmt.cs[k]), f"{int(nmt.cs[k]):02X}h")
            to = "all nodes" if int(nmt.target[k]) == 0 else f"node {int(nmt.target[k])}"
            text = f"NMT {name} to {to}"
            if f.rule == "B002":
                text += ": this reset was already answered before the boot-up"
            elif f.rule == "B001":
                text += ": likely lost while the node initialises"
            out.append(cause_entry("nmt", nmt.ts[k], int(nmt.idx[k]), int(nmt.line[k]), text, n))
        return out

    def _sdo_writes(self, m: Any, rule: str, windows: list[tuple[float, float]]
                    ) -> list[dict[str, Any]]:
        wanted = SDO_WRITES.get(rule)
        if not wanted:
            return []
        w = m.writes
        sel = np.flatnonzero(np.isin(w.index, wanted) & _in(w.request_ts, windows))
        out = [cause_entry("sdo_write", w.request_ts[k], int(w.request_idx[k]), None,
                      f"SDO write {int(w.index[k]):04X}h:{int(w.sub[k]):02X} = "
                      f"0x{int(w.value[k]):08X} confirmed", m.node) for k in sel.tolist()]
        if rule == "H001":
            cw = m.consumer_writes
            sel = np.flatnonzero(_in(cw.request_ts, windows))
            out += [cause_entry("sdo_write", cw.request_ts[k], int(cw.request_idx[k]), None,
                           f"SDO write 1016h:{int(cw.sub[k]):02X} = 0x{int(cw.value[k]):08X} "
                           f"to node {int(cw.node[k])} confirmed", int(cw.node[k]))
                    for k in sel.tolist()]
        return out

    def _cluster(self, cm: Any, n: int, a0: float, f: Finding) -> list[dict[str, Any]]:
        hits: list[tuple[float, int, int, int]] = []
        for o in cm.nodes.values():
            if o.node == n:
                continue
            ec = o.ec
            k = np.flatnonzero((ec.kind == BOOTUP) & (np.abs(ec.ts - a0) <= self.cluster + EPS))
            if k.size:
                j = int(k[0])
                hits.append((float(ec.ts[j]), o.node, int(ec.idx[j]), int(ec.line[j])))
        if not hits:
            return []
        nodes = ", ".join(str(h[1]) for h in sorted(hits, key=lambda h: h[1]))
        own = (a0, n, f.frame_index if f.frame_index is not None else -1, f.line or 0)
        return [cluster_entry(hits, own, nodes, self.cluster)]

    def _boot(self, f: Finding, n: int, a0: float) -> list[dict[str, Any]]:
        b = self.res.boot
        if b is None:
            return []
        rep = b.nodes.get((str(f.channel), n))
        if rep is None:
            return []
        sp = rep.spans
        at = np.flatnonzero((sp.start <= a0) & (a0 <= sp.end))
        before = np.flatnonzero(sp.end < a0)
        if at.size:
            k = int(at[-1])
        elif before.size and sp.status[int(before[-1])] != 0:
            k = int(before[-1])
        else:
            return []
        status = ("ok", "failed", "incomplete")[int(sp.status[k])]
        letter = f", letter {sp.letter[k]}" if sp.letter[k] else ""
        has_ev = int(sp.ev_idx[k]) >= 0
        return [cause_entry("boot_process", float(sp.ev_time[k]) if has_ev else float(sp.start[k]),
                       int(sp.ev_idx[k]) if has_ev else None,
                       int(sp.ev_line[k]) if has_ev else None,
                       f"boot process {status}{letter}, last step "
                       f"{sp.last_step[int(sp.step[k])]}", n)]


def _in(ts: np.ndarray, windows: list[tuple[float, float]]) -> np.ndarray:
    sel = np.zeros(len(ts), bool)
    for lo, hi in windows:
        sel |= (ts >= lo - EPS) & (ts <= hi + EPS)
    return sel


def boot_fields(result: InputResult) -> None:
    analysis = result.boot
    if analysis is None:
        return
    by_key: dict[tuple[str, str | None, int | None, float], BootFinding] = {
        (f.code, f.channel, f.node, round(f.time, 9)): f for f in analysis.findings}
    for f in result.findings:
        if not f.rule.startswith("P"):
            continue
        bf = by_key.get((f.rule, f.channel, f.node, round(f.time, 9)))
        if bf is None:
            continue
        f.boot_letter = bf.letter
        ev = bf.evidence
        if bf.frame_index is not None and f.frame_index is not None:  # a frame finding
            ev_d: dict[str, Any] | None = {"time": round(f.time, 6),
                                           "frame_index": f.frame_index, "line": f.line or None}
        elif ev is not None:
            ev_d = {"time": round(ev.time, 6), "frame_index": ev.frame_index,
                    "line": ev.line or None}
        else:
            ev_d = None
        f.evidence = ev_d
