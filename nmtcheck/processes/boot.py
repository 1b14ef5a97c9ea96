"""The CiA 302-2 boot-slave process, reconstructed per node from the log (SPEC §8.3).

Per channel the group runs when configured, or when the log shows a boot signature
(§8.2.4). Per node N: the SDO transfers on 600h/580h+N (`sdo_transfers`), N's anchors
(its boot-ups, reset commands to N or to all, the master's boot-ups), probes (uploads of
1000h:00), processes and attempts, the steps of each, the end and status, the
Lely-compatible letter A-O with its `co_nmt_es2str` text, and the proving frame. The
P rules (`checks/boot.py`) report what `analyse` found; the reports show the boot status.

Nothing here is per frame, nor per process where a log boots a node a million times: SDO
frames and transfers are columns per server, a node's processes are columns (`Procs`,
one pass over the probes), and the processes that are plainly ok (completed by a start,
every transfer ok, no failure possible: `_plainly_ok`) are judged all at once. Only the
others, and the last of each node (the report's), are evaluated as `Process` objects;
every process is kept as a row of `Spans`, whole processes only where a finding or the
report needs them, and those without their steps unless P006 or P008 may read them.
A flood of failing processes makes a finding each: past the engine's per-rule cap a
finding is only counted (`BootAnalysis.omitted`), the process that only it would read is
not kept, and one failed by a refused download alone (`_plainly_refused`) is not even
evaluated: its span is filled as columns.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from nmtcheck.processes import sdo_transfers as st
from nmtcheck.processes.boot_config import BootConfig, NodeBoot
from nmtcheck.processes.boot_records import (
    CS_START,
    IDENTITY_STEPS,
    LETTERS,
    STATUSES,
    BootAnalysis,
    BootFinding,
    BootParams,
    ChannelBoot,
    NodeBootReport,
    Process,
    Spans,
    Step,
    Where,
    attach,
)
from nmtcheck.processes.boot_steps import (
    STEP_NAMES,
    Marks,
    NodeInputs,
    Plain,
    Procs,
    evaluate,
    node_inputs,
    node_processes,
    plainly_judged,
    process_object,
    signature,
    take,
)
from nmtcheck.protocol.nmt import BOOTUP, EPS
from nmtcheck.timeline.model import ChannelModel, InputModel

# --- channel ----------------------------------------------------------------------------

def analyse(model: InputModel, spool: st.SdoSpool, configs: dict[str, BootConfig],
            p: BootParams, cap: int = 0) -> BootAnalysis:
    """Reconstruct every channel's boot processes; the P findings and the boot report
    (findings past `cap` per code only counted, 0: none)."""
    out = BootAnalysis(cap=cap)
    servers: dict[int, set[int]] = {}  # per channel code, found once (40,000 channels)
    for k in spool.servers():
        servers.setdefault(k // 128, set()).add(k)
    for cm in model.channels:
        cfg = configs.get(cm.name) or BootConfig()
        out.channels[cm.name] = cb = ChannelBoot(cm.name, "none")
        if cfg.table.manager is False:
            cb.manager = "off"
            _not_managed(out, cm, cfg)
            continue
        master = cm.master.node if cm.master is not None else None
        mb = Marks.empty()
        if master is not None and master in cm.nodes:
            ec = cm.nodes[master].ec
            mb = take(ec.ts, ec.idx, ec.line, np.flatnonzero(ec.kind == BOOTUP))
        keys = servers.get(cm.chan, set())
        nodes = sorted({k % 128 for k in keys} | set(cfg.nodes))
        per_node: dict[int, tuple[NodeInputs, list[Process]]] = {}
        dropped: dict[int, _Dropped] = {}
        seen = dict(out.counts)  # what `_findings` will have counted, node by node
        spans: dict[int, Spans] = {}
        counts: dict[int, int] = {}
        aborts: list[np.ndarray] = []
        first_starts: list[float] = []
        signature = False
        for n in nodes:
            if n == 0:
                continue
            found = _node_pass(model, spool, cm, n, cm.chan * 128 + n in keys, mb, cfg, p,
                               cap, seen)
            if found is None:
                continue
            nd, kept, spans[n], counts[n], sig, node_aborts, dropped[n] = found
            per_node[n] = (nd, kept)
            signature = signature or sig
            aborts.append(node_aborts)
            if len(spans[n]):
                first_starts.append(float(spans[n].start[0]))
        if cfg.table.manager is True:
            cb.manager = "network"
        elif cfg.master_dcf_known:
            cb.manager = "master-dcf"
        elif signature:
            cb.manager = "inferred"
        if not cb.ran:
            _not_managed(out, cm, cfg)
            continue
        all_aborts = np.concatenate(aborts) if aborts else np.zeros(0)
        if len(all_aborts):
            cb.sdo_timeout_inferred_ms = round(float(np.median(all_aborts)) * 1000.0, 3)
        cb.manager_sdo_timeout_ms = cfg.table.manager_sdo_timeout_ms
        _channel_properties(cb, cm, cfg, min(first_starts, default=None))
        for n, (nd, kept) in per_node.items():
            _node_report(out, cm, n, nd, kept, cfg, spans[n], counts[n])
        _findings(out, cm, per_node, dropped, cfg, cb, p, cm.end)
    return out


@dataclass
class _Dropped:
    """A node's processes that only their finding reads (failed or L, not the last, node
    not mandatory), in order: those whose finding is made (under the cap, without their
    steps), then how many per code are only counted."""

    procs: list[Process] = field(default_factory=list)
    omitted: dict[str, int] = field(default_factory=dict)


def _code_of(x: Process) -> str | None:
    """The code of the finding `_findings` reports for process x (None: none)."""
    if x.failure is not None:
        return x.failure.code
    return "P005" if x.letter == "L" and x.operational_at is not None else None


def _node_pass(model: InputModel, spool: st.SdoSpool, cm: ChannelModel, n: int, has_sdo: bool,
               mb: Marks, cfg: BootConfig, p: BootParams, cap: int, seen: dict[str, int]
               ) -> tuple[NodeInputs, list[Process], Spans, int, bool, np.ndarray, _Dropped] | None:
    """One node: its transfers, processes (judged at once), the signature test and the
    client's timeout aborts; the transfers are released once judged. A log may boot a node
    a million times: the processes are columns, those plainly ok are judged by
    `_plainly_ok` at once, the others one by one, and whole processes are kept only where
    a finding or the report needs them (not ok, letter L, the last). A failed one that
    only its finding reads is kept only while that finding is under the cap: `seen`
    counts per code the findings `_findings` will have reached (this node's dropped ones
    come before its kept ones)."""
    rows = spool.frames(cm.chan * 128 + n) if has_sdo else None
    if rows is not None and n not in cfg.nodes and not _probed(rows):
        rows = None  # no probe: no process (and no columns for a flood of SDO)
    t = (st.transfers(rows, cm.end, p.sdo_timeout_s) if rows is not None
         else st.TransferTable.empty())
    del rows
    nd = node_inputs(cm, n, cm.nodes.get(n), t, mb, cfg.nodes.get(n))
    c = node_processes(nd, p)
    sig = signature(nd, c)
    tm = (t.result == st.ABORTED) & (t.abort_code == st.TIMEOUT_ABORT)
    aborts = t.end_ts[tm] - t.start_ts[tm]
    mandatory = n in cfg.nodes and cfg.nodes[n].mandatory
    judged = plainly_judged(nd, c, cm.end, p, mandatory)
    if judged.failed is None or len(judged.failed) != len(c):
        judged.failed = np.zeros(len(c), bool)
    if len(c):  # the report shows the last one whole
        judged.ok[-1] = judged.incomplete[-1] = judged.failed[-1] = False
    spans = _plain_spans(nd, c, judged)
    kept: list[Process] = []
    drop = _Dropped()
    names = spans.last_step
    plain_failed = judged.failed.tolist()
    for i in np.flatnonzero(~(judged.ok | judged.incomplete)).tolist():
        if plain_failed[i] and cap and seen.get("P003", 0) >= cap:
            # its P003 is past the cap: counted, its span filled at once, not evaluated
            drop.omitted["P003"] = drop.omitted.get("P003", 0) + 1
            seen["P003"] += 1
            continue
        x = process_object(nd, c, i)
        evaluate(x, nd, p, cm.end, cm.end, 1 << 62)
        x.last_step = x.steps[-1].step if x.steps else "none"
        if x.last_step not in names:
            names.append(x.last_step)
        w = x.evidence
        spans.end[i] = np.inf if x.end is None else x.end
        spans.status[i] = STATUSES.index(x.status)
        spans.letter[i] = x.letter or ""
        spans.step[i] = names.index(x.last_step)
        if w is not None:
            spans.ev_time[i], spans.ev_idx[i], spans.ev_line[i] = w.time, w.frame_index, w.line
        if i == len(c) - 1:
            kept.append(x)  # the report's
        elif x.status != "ok" or x.letter == "L":
            _keep(x, mandatory, p, cap, seen, kept, drop)
    for x in kept:
        code = _code_of(x)
        if code is not None:
            seen[code] = seen.get(code, 0) + 1
    spans.compact_names()
    nd.t = st.TransferTable.empty()
    return nd, kept, spans, len(c), sig, aborts, drop


def _keep(x: Process, mandatory: bool, p: BootParams, cap: int, seen: dict[str, int],
          kept: list[Process], drop: _Dropped) -> None:
    """Keep an evaluated process (not the last, not ok unless L) where P006, P008 or its
    finding reads it: one with a finding (failed, or L) of a node that is not mandatory
    only while that finding is under the cap (`seen`: the findings of its code so far),
    and without its steps."""
    if (x.status == "incomplete" and not mandatory and x.end is not None
            and x.end <= x.start + p.stall_s + EPS):
        return  # ended before P008 could fire; only P006 reads it
    if x.status != "incomplete" and not mandatory:
        x.steps, x.probes = [], []  # only P006 and P008 read an older one's steps
    code = _code_of(x)
    if code is not None and not mandatory:
        if cap and seen.get(code, 0) >= cap:
            drop.omitted[code] = drop.omitted.get(code, 0) + 1
        else:
            drop.procs.append(x)
        seen[code] = seen.get(code, 0) + 1
        return
    kept.append(x)


def _plain_spans(nd: NodeInputs, c: Procs, judged: Plain) -> Spans:
    """The spans of every process, filled in for those judged at once: an ok one ends
    with the start command (its last step and its evidence), an incomplete one as
    `plainly_judged` found; the others are filled in as they are evaluated."""
    n = len(c)
    start = nd.anchors.ts[c.anchor] if n else np.zeros(0)
    ok, inc = judged.ok, judged.incomplete
    sp = Spans(start.astype(np.float64), np.where(c.end_how == 3, np.inf, c.end_ts),
               np.where(inc, STATUSES.index("incomplete"), 0).astype(np.int8),
               np.full(n, "", "U1"), [*STEP_NAMES, "start"], judged.step.copy(),
               judged.ev_time.copy(), judged.ev_idx.copy(), judged.ev_line.copy())
    sp.step[ok] = len(STEP_NAMES)
    if judged.failed is not None and judged.fail_row is not None and judged.failed.any():
        f, r = judged.failed, judged.fail_row[judged.failed]
        sp.status[f] = STATUSES.index("failed")
        sp.letter[f] = "J"
        sp.step[f] = len(STEP_NAMES)
        sp.ev_time[f], sp.ev_idx[f], sp.ev_line[f] = (nd.t.end_ts[r], nd.t.end_idx[r],
                                                      nd.t.end_line[r])
    if ok.any():
        k = np.searchsorted(nd.starts.idx, c.end_idx[ok])
        sp.ev_time[ok] = nd.starts.ts[k]
        sp.ev_idx[ok] = nd.starts.idx[k]
        sp.ev_line[ok] = nd.starts.line[k]
    return sp


def _probed(rows: np.ndarray) -> bool:
    """Whether a server's SDO frames hold a probe (upload request of 1000h:00)."""
    d = rows["data"]
    return bool(np.any(rows["req"] & (d[:, 0] == 0x40) & (d[:, 1] == 0x00) & (d[:, 2] == 0x10)
                       & (d[:, 3] == 0x00)))


def _channel_properties(cb: ChannelBoot, cm: ChannelModel, cfg: BootConfig,
                        first_start: float | None) -> None:
    nmt = cm.nmt
    after = nmt.valid & (nmt.cs == CS_START) & (
        nmt.ts >= (first_start if first_start is not None else np.inf))
    if cfg.startup is not None:
        cb.starts_slaves = (not bool(cfg.startup >> 3 & 1), "config")
        cb.start_all = (bool(cfg.startup >> 1 & 1), "config")
    else:
        cb.starts_slaves = (bool(after.any()), "inferred")
        cb.start_all = (bool((after & (nmt.target == 0)).any()), "inferred")


def _assignment(cfg: NodeBoot | None) -> dict[str, Any] | None:
    if cfg is None or cfg.assignment is None:
        return None
    return {"value": f"0x{cfg.assignment:08X}", "mandatory": cfg.mandatory,
            "keep_alive": bool(cfg.keep_alive), "source": cfg.assignment_source}


# the spans of a node without boot processes, shared (never written: only a managed
# node's own `Spans` is filled): one per node was 270 bytes a node of many channels
_NO_SPANS = Spans.empty()


def _not_managed(out: BootAnalysis, cm: ChannelModel, cfg: BootConfig) -> None:
    for n in cm.nodes:
        out.nodes[(cm.name, n)] = NodeBootReport(cm.name, n, "not-managed",
                                                 assignment=_assignment(cfg.nodes.get(n)),
                                                 spans=_NO_SPANS)


def _node_report(out: BootAnalysis, cm: ChannelModel, n: int, nd: NodeInputs, procs: list[Process],
                 cfg: BootConfig, spans: Spans, count: int) -> None:
    nb = cfg.nodes.get(n)
    rep = NodeBootReport(cm.name, n, "not-managed", assignment=_assignment(nb),
                         processes=count, spans=spans)
    if procs:
        x = procs[-1]
        rep.process = x
        rep.status, rep.letter, rep.letter_source, rep.reason = (x.status, x.letter,
                                                                 x.letter_source, x.reason)
        if x.status == "incomplete":
            rep.candidates = _candidates(x, nd)
    elif nb is not None and nb.assignment is not None:
        if not nb.bit(0):
            rep.letter, rep.letter_source, rep.reason = "A", "config", LETTERS["A"]
        elif nb.bit(2):
            rep.status = "incomplete"
    out.nodes[(cm.name, n)] = rep


def _candidates(x: Process, nd: NodeInputs) -> str:
    """8.4.1: the likely letters of a stalled process, from its last step."""
    last = next((s for s in reversed(x.steps) if s.row >= 0), None)
    hb_after = last is not None and any(
        s.step in ("error_control", "state_check") and s.frame_index > last.frame_index
        for s in x.steps)
    if last is None:
        return "B"
    if hb_after:
        return "no start"
    k = ", K" if True else ""
    if last.step == "device_type" and last.result == "ok":
        return f"C{k}, no start"
    if last.step in ("vendor_id", "product_code", "revision_number", "serial_number"):
        letter = IDENTITY_STEPS[int(last.sub or 0)][1]
        return f"{letter}{k}, no start"
    if last.step == "device_type":
        return "B"
    if last.step == "state_check":
        return "E, F"
    if last.step == "software_check":
        return "H, G"
    if last.step == "software_update":
        return "I"
    if nd.c_n is not None:
        return "K, no start"
    return "no start (the manager's configuration step did not finish)"


def describe_step(s: Step) -> str:
    if s.row < 0:
        return f"{s.step} (line {s.line})"
    value = f" = 0x{s.value:08X}" if s.value is not None else f" {s.result}"
    return f"{s.step} {s.index:04X}:{s.sub:02X}{value} (line {(s.end or s).line})"


def _findings(out: BootAnalysis, cm: ChannelModel, per_node: dict[int, tuple[NodeInputs,
              list[Process]]], dropped: dict[int, _Dropped], cfg: BootConfig, cb: ChannelBoot,
              p: BootParams, last_frame: float) -> None:
    master_boots: list[Where] = []
    if cm.master is not None and cm.master.node in cm.nodes:
        ec = cm.nodes[cm.master.node].ec
        sel = np.flatnonzero(ec.kind == BOOTUP)
        master_boots = [Where(float(ec.ts[k]), int(ec.idx[k]), int(ec.line[k]))
                        for k in sel.tolist()]
    p_fired: dict[int, list[Process]] = {}
    for n, (_nd, procs) in per_node.items():
        mandatory = cfg.nodes.get(n) is not None and cfg.nodes[n].mandatory
        drop = dropped.get(n) or _Dropped()
        for x in drop.procs:
            _process_finding(out, cm, n, x, mandatory, p_fired)
        for code, k in drop.omitted.items():
            out.omit(code, cm.name, k)
        for x in procs:
            _process_finding(out, cm, n, x, mandatory, p_fired)
    p006 = _p006(out, cm, per_node, cfg, cb, master_boots, p_fired, last_frame)
    _p008(out, cm, per_node, cb, p, last_frame, p006)


def _process_finding(out: BootAnalysis, cm: ChannelModel, n: int, x: Process, mandatory: bool,
                     p_fired: dict[int, list[Process]]) -> None:
    """The finding of process x (`_code_of`), its text made only if it is under the cap."""
    f = x.failure
    if f is None:
        w = x.operational_at
        if x.letter == "L" and w is not None:
            line = w.line
            _add(out, "P005", cm, n, w, w,
                 lambda: f"node {n} reports OPERATIONAL (line {line}) during its boot "
                         f"process: Lely-compatible letter L ({LETTERS['L']}); the manager "
                         f"sends no start", "L", w, x)
        return
    if f.code == "P007":
        _add(out, "P007", cm, n, f.at, f.at,
             lambda: f"{f.message.replace('{node}', str(n))}: node {n}'s boot process (from "
                     f"{x.start - cm.start:.6f} s, line {x.start_line}) had not completed",
             None, f.at, x)
        return

    def text() -> str:
        # `{started}`: where boot_steps says the node was started anyway (its time in
        # seconds from the trace's start, as every report gives times)
        anyway = ("" if x.started_at is None else
                  f"; started anyway at {x.started_at.time - cm.start:.6f} s "
                  f"(line {x.started_at.line})")
        msg = f.message.replace("{node}", str(n)).replace("{started}", anyway)
        more = f" ({x.failures} failures in the process)" if x.failures > 1 else ""
        started = ""
        if f.code == "P003" and x.started_at is not None:  # (seconds from the start)
            started = (f"; node {n} was started anyway at "
                       f"{x.started_at.time - cm.start:.6f} s (line {x.started_at.line})")
        halt = "; mandatory: network boot halted" if mandatory else ""
        return (f"{msg}{more}{started}{halt}: Lely-compatible letter {f.letter} "
                f"({LETTERS[f.letter]})")

    _add(out, f.code, cm, n, f.at, None if f.moment else f.at, text, f.letter,
         f.evidence or f.at, x)
    p_fired.setdefault(n, []).append(x)


def _p006(out: BootAnalysis, cm: ChannelModel,
          per_node: dict[int, tuple[NodeInputs, list[Process]]], cfg: BootConfig, cb: ChannelBoot,
          master_boots: list[Where], p_fired: dict[int, list[Process]], last_frame: float
          ) -> set[int]:
    """P006: mandatory slaves per network boot; the nodes it fired for."""
    t_boot = cfg.boot_time_ms / 1000.0
    nbs: list[dict[str, Any]] = []
    mandatory_nodes = sorted(n for n, nb in cfg.nodes.items() if nb.mandatory)
    p006: set[int] = set()
    for i, w in enumerate(master_boots):
        deadline = w.time + t_boot if t_boot > 0 else None
        entry: dict[str, Any] = {"time": round(w.time, 6), "frame_index": w.frame_index,
                                 "mandatory": mandatory_nodes,
                                 "deadline": None if deadline is None else round(deadline, 6),
                                 "complete": None}
        nbs.append(entry)
        if deadline is None or not mandatory_nodes:
            continue
        nxt = master_boots[i + 1].time if i + 1 < len(master_boots) else np.inf
        complete = True
        for n in mandatory_nodes:
            nd, procs = per_node.get(n, (None, []))
            rep = out.nodes.get((cm.name, n))
            done = rep is not None and bool(np.any(
                (rep.spans.status == 0) & (rep.spans.end >= w.time - EPS)
                & (rep.spans.end <= deadline + EPS)))
            if cfg.nodes[n].bit(2) is False and nd is not None:
                done = bool(np.any((nd.reports.ts >= w.time) & (nd.reports.ts <= deadline))
                            | np.any((nd.bootups.ts >= w.time) & (nd.bootups.ts <= deadline)))
            if done:
                continue
            complete = False
            if last_frame < deadline - EPS or nxt < deadline:
                continue
            if any(w.time - EPS <= x.start <= deadline + EPS for x in p_fired.get(n, [])):
                continue
            cur = [x for x in procs if x.start <= deadline + EPS]
            answered = any(s.step == "device_type" and s.result == "ok" and s.end is not None
                           and s.end.time <= deadline for x in cur[-1:] for s in x.steps)
            letter = None if answered else "B"
            ev6: Where | None = None
            if nd is not None:
                frames = [s for x in cur for s in x.steps if s.time <= deadline]
                if frames:
                    s = frames[-1]
                    ev6 = s.end if s.end is not None and s.end.time <= deadline else Where(
                        s.time, s.frame_index, s.line)
            note = f"; Lely-compatible letter B ({LETTERS['B']})" if letter else ""
            _add(out, "P006", cm, n, Where(deadline, -1, 0), None,
                 f"mandatory node {n} did not complete its boot within {t_boot * 1000:g} ms "
                 f"(1F89h) of the manager's boot-up at {w.time - cm.start:.6f} s "
                 f"(line {w.line}): the "
                 f"manager halts the network boot-up{note}", letter, ev6,
                 cur[-1] if cur else None)
            p006.add(n)
        entry["complete"] = complete
    cb.network_boots = nbs
    return p006


def _p008(out: BootAnalysis, cm: ChannelModel,
          per_node: dict[int, tuple[NodeInputs, list[Process]]], cb: ChannelBoot, p: BootParams,
          last_frame: float, p006: set[int]) -> None:
    """P008: stalled processes."""
    if not cb.starts_slaves[0]:
        return
    for n, (nd, procs) in per_node.items():
        if n in p006:
            continue
        for x in procs:
            if x.failure is not None or x.status != "incomplete":
                continue
            moment = x.start + p.stall_s
            if x.end is not None and x.end <= moment + EPS:
                continue
            if last_frame < moment - EPS:
                continue
            if cb.start_all[0] and _waits_for_broadcast(x):
                continue
            last = next((s for s in reversed(x.steps) if s.row >= 0), None)
            cands = _candidates(x, nd)
            what = describe_step(last) if last is not None else "its anchor"
            _add(out, "P008", cm, n, Where(moment, -1, 0), None,
                 f"node {n}'s boot process (from {x.start - cm.start:.6f} s, line "
                 f"{x.start_line}) "
                 f"stopped after {what}; candidates {cands}", None, x.last_frame, x,
                 inferred=cands)


def _waits_for_broadcast(x: Process) -> bool:
    tr = [s for s in x.steps if s.row >= 0]
    if any(s.end is None for s in tr):
        return False
    last = max((s.end.frame_index for s in tr if s.end is not None), default=-1)
    return any(s.step in ("error_control", "state_check") and s.frame_index > last
               for s in x.steps)


def _add(out: BootAnalysis, code: str, cm: ChannelModel, n: int, at: Where,
         frame: Where | None, message: str | Callable[[], str], letter: str | None,
         evidence: Where | None, x: Process | None, inferred: str | None = None) -> None:
    if out.make(code, cm.name):
        out.findings.append(BootFinding(code, cm.name, n, at.time,
                                        None if frame is None else frame.frame_index,
                                        None if frame is None else frame.line,
                                        message if isinstance(message, str) else message(),
                                        letter, evidence))
    if x is not None:
        x.findings.append(code)
        if code == "P006" and letter and x.letter is None:
            pass
    rep = out.nodes.get((cm.name, n))
    if rep is not None and code == "P006" and rep.letter is None and letter:
        rep.status, rep.letter, rep.letter_source = "failed", letter, "observed"
        rep.reason = LETTERS[letter]
    if rep is not None and inferred is not None:
        rep.candidates = inferred


def params_of(profile: Any) -> BootParams:
    """The reconstruction's parameters from a rule profile (SPEC §8.4.3)."""
    tl = profile.timeline

    def rule(code: str, name: str, default: float) -> float:
        settings = profile.get(code)
        return float(settings.params.get(name, default)) if settings is not None else default

    return BootParams(
        probe_window_s=float(tl.get("boot_probe_window_ms", 1000.0)) / 1000.0,
        sdo_timeout_s=float(tl.get("sdo_timeout_ms", 1000.0)) / 1000.0,
        restore_timeout_s=rule("P003", "restore_timeout_ms", 1000.0) / 1000.0,
        rtr_timeout_s=rule("P004", "rtr_timeout_ms", 100.0) / 1000.0,
        reset_timeout_s=rule("P004", "reset_timeout_ms", 1000.0) / 1000.0,
        stall_s=rule("P008", "stall_ms", 10000.0) / 1000.0)


def run(model: InputModel, spool: st.SdoSpool, network: Any, profile: Any, cap: int = 0
        ) -> BootAnalysis | None:
    """The boot stage of the engine: reconstruct, keep the result with the model for the
    P rules, and return it for the reports. Not run on an input without timestamps.
    `cap`: the engine's findings per rule (0: all), past which findings are only counted."""
    if model.timeline.order_only:
        return None
    configs = ({cm.name: network.boot_config(cm.network_name) for cm in model.channels}
               if network is not None else {})
    analysis = analyse(model, spool, configs, params_of(profile), cap)
    attach(model, analysis)
    return analysis
