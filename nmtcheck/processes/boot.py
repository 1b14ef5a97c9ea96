"""The CiA 302-2 boot-slave process, reconstructed per node from the log (SPEC §8.3).

Per channel the group runs when configured, or when the log shows a boot signature
(§8.2.4). Per node N: the SDO transfers on 600h/580h+N (`sdo_transfers`), N's anchors
(its boot-ups, reset commands to N or to all, the master's boot-ups), probes (uploads of
1000h:00), processes and attempts, the steps of each, the end and status, the
Lely-compatible letter A-O with its `co_nmt_es2str` text, and the proving frame. The
P rules (`checks/boot.py`) report what `analyse` found; the reports show the boot status.

Nothing here is per frame, nor per process where a log boots a node a million times: SDO
frames and transfers are columns per server, a node's processes are columns (`_Procs`,
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

import itertools
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from nmtcheck.protocol import sdo
from nmtcheck.processes import sdo_transfers as st
from nmtcheck.processes.boot_config import BootConfig, Expected, NodeBoot
from nmtcheck.timeline.model import ChannelModel, InputModel, NodeModel
from nmtcheck.protocol.nmt import BOOTUP, EPS, GUARD, HEARTBEAT, REQUEST
from nmtcheck.timeline.tables import blank

# Lely's co_nmt_es2str (src/co/nmt.c)
LETTERS = {
    "A": "The CANopen device is not listed in object 1F81.",
    "B": "No response received for upload request of object 1000.",
    "C": "Value of object 1000 from CANopen device is different to value in object 1F84 "
         "(Device type).",
    "D": "Value of object 1018 sub-index 01 from CANopen device is different to value in "
         "object 1F85 (Vendor-ID).",
    "E": "Heartbeat event. No heartbeat message received from CANopen device.",
    "F": "Node guarding event. No confirmation for guarding request received from CANopen "
         "device.",
    "G": "Objects for program download are not configured or inconsistent.",
    "H": "Software update is required, but not allowed.",
    "I": "Software update is required, but program download failed.",
    "J": "Configuration download failed.",
    "K": "Heartbeat event during start error control service. No heartbeat message received "
         "from CANopen device during start error control service.",
    "L": "CANopen device is initially in NMT state OPERATIONAL.",
    "M": "Value of object 1018 sub-index 02 from CANopen device is different to value in "
         "object 1F86 (Product code).",
    "N": "Value of object 1018 sub-index 03 from CANopen device is different to value in "
         "object 1F87 (Revision number).",
    "O": "Value of object 1018 sub-index 04 from CANopen device is different to value in "
         "object 1F88 (Serial number).",
}

IDENTITY_STEPS = {1: ("vendor_id", "D", 0x1F85), 2: ("product_code", "M", 0x1F86),
                  3: ("revision_number", "N", 0x1F87), 4: ("serial_number", "O", 0x1F88)}
RESTORE_VALUE = 0x64616F6C  # "load"
CS_START, CS_RESET_NODE, CS_RESET_COMM = 0x01, 0x81, 0x82
MAX_STEPS = 64
KEEP_PROCESSES = 64  # per node, besides those with a finding and the last one


@dataclass
class BootParams:
    probe_window_s: float = 1.0
    sdo_timeout_s: float = 1.0
    restore_timeout_s: float = 1.0
    rtr_timeout_s: float = 0.1
    reset_timeout_s: float = 1.0
    stall_s: float = 10.0


@dataclass(slots=True)
class Where:
    time: float
    frame_index: int
    line: int


@dataclass(slots=True)
class Step:
    step: str
    time: float
    frame_index: int
    line: int
    attempt: int = 0
    row: int = -1  # the transfer's row, for transfer steps
    index: int | None = None
    sub: int | None = None
    result: str | None = None
    value: int | None = None
    expected: int | None = None
    expected_source: str | None = None
    abort_code: int | None = None
    end: Where | None = None
    direction: int = -1

    def as_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"step": self.step, "time": round(self.time, 6),
                             "frame_index": self.frame_index, "line": self.line or None}
        if self.row >= 0:
            d.update({"index": f"{self.index:04X}h", "sub": self.sub,
                      "end_time": None if self.end is None else round(self.end.time, 6),
                      "end_frame_index": None if self.end is None else self.end.frame_index,
                      "end_line": None if self.end is None else (self.end.line or None),
                      "result": self.result, "value": _hex(self.value),
                      "expected": _hex(self.expected), "expected_source": self.expected_source,
                      "abort_code": None if self.abort_code is None
                      else f"{self.abort_code:08X}h"})
        return d


def _hex(v: int | None) -> str | None:
    return None if v is None else f"0x{v:08X}"


@dataclass(slots=True)
class Failure:
    code: str  # P001 ... P004
    letter: str
    at: Where  # the proving frame (for K/E/F: the wait's expiry moment, frame -1)
    message: str
    evidence: Where | None = None
    moment: bool = False  # the finding is a moment (P004): its frame is found later


@dataclass(slots=True)
class Process:
    node: int
    start: float
    start_idx: int
    start_line: int
    anchor: str  # bootup | reset | master-bootup
    probes: list[int] = field(default_factory=list)  # transfer rows
    answered: bool = False
    end: float | None = None
    end_idx: int | None = None
    end_how: str = "trace-end"  # start | operational | superseded | trace-end
    started_at: Where | None = None
    operational_at: Where | None = None
    keep_alive: bool = False
    probed_before_bootup: bool = False
    steps: list[Step] = field(default_factory=list)
    attempts: int = 1
    failure: Failure | None = None  # the first failure of the last attempt
    failures: int = 0
    status: str = "incomplete"
    letter: str | None = None
    letter_source: str | None = None
    reason: str | None = None
    evidence: Where | None = None
    findings: list[str] = field(default_factory=list)
    last_frame: Where | None = None
    transfers: int = 0
    last_step: str = "none"  # kept when the steps of an old, healthy process are dropped

    def as_dict(self) -> dict[str, Any]:
        steps = [s.as_dict() for s in self.steps]
        if len(steps) > MAX_STEPS:
            cfg = [s for s in self.steps if s.step == "config"]
            rest = [s.as_dict() for s in self.steps if s.step != "config"]
            summary = {"step": "config", "count": len(cfg),
                       "failed": sum(1 for s in cfg if s.result not in ("ok", "open")),
                       "time": round(cfg[0].time, 6) if cfg else None,
                       "end_time": round(max((s.end.time if s.end else s.time) for s in cfg), 6)
                       if cfg else None}
            steps = sorted([*rest, summary], key=lambda d: d["time"] or 0.0)[:MAX_STEPS]
        return {"start": round(self.start, 6),
                "end": None if self.end is None else round(self.end, 6),
                "anchor": self.anchor, "attempts": self.attempts, "keep_alive": self.keep_alive,
                "probed_before_bootup": self.probed_before_bootup,
                "started_at": None if self.started_at is None else round(self.started_at.time, 6),
                "steps": steps,
                "evidence": None if self.evidence is None else {
                    "time": round(self.evidence.time, 6),
                    "frame_index": self.evidence.frame_index,
                    "line": self.evidence.line or None},
                "findings": list(self.findings)}


@dataclass
class BootFinding:
    code: str
    channel: str
    node: int
    time: float
    frame_index: int | None
    line: int | None
    message: str
    letter: str | None
    evidence: Where | None


STATUSES = ("ok", "failed", "incomplete")


@dataclass
class Spans:
    """Every process of a node in brief, as columns (whole processes are kept only where a
    finding or the report needs them: a log may boot a node a million times)."""

    start: np.ndarray
    end: np.ndarray  # inf: open at the trace end
    status: np.ndarray  # index into STATUSES
    letter: np.ndarray  # "" when none
    last_step: list[str]  # distinct names, for `step`
    step: np.ndarray  # index into last_step
    ev_time: np.ndarray  # the evidence frame (NaN: none)
    ev_idx: np.ndarray
    ev_line: np.ndarray

    @classmethod
    def of(cls, procs: list[Process]) -> Spans:
        names = sorted({x.last_step for x in procs})
        ev = [x.evidence for x in procs]
        return cls(np.asarray([x.start for x in procs], np.float64),
                   np.asarray([np.inf if x.end is None else x.end for x in procs], np.float64),
                   np.asarray([STATUSES.index(x.status) for x in procs], np.int8),
                   np.asarray([x.letter or "" for x in procs], "U1"), names,
                   np.asarray([names.index(x.last_step) for x in procs], np.int16),
                   np.asarray([np.nan if w is None else w.time for w in ev], np.float64),
                   np.asarray([-1 if w is None else w.frame_index for w in ev], np.int64),
                   np.asarray([0 if w is None else w.line for w in ev], np.int64))

    @classmethod
    def empty(cls) -> Spans:
        spans = blank(cls, lambda: cls.of([]))  # one per node: its columns made once
        spans.last_step = []  # appended to in place
        return spans

    def __len__(self) -> int:
        return len(self.start)

    def compact_names(self) -> None:
        """`last_step` as `of` makes it: the names in use, sorted."""
        used = sorted({self.last_step[k] for k in np.unique(self.step).tolist()})
        remap = np.zeros(max(len(self.last_step), 1), np.int16)
        for k, name in enumerate(self.last_step):
            if name in used:
                remap[k] = used.index(name)
        self.step = remap[self.step]
        self.last_step = used


@dataclass
class NodeBootReport:
    channel: str
    node: int
    status: str  # ok | failed | incomplete | not-managed
    letter: str | None = None
    letter_source: str | None = None
    reason: str | None = None
    assignment: dict[str, Any] | None = None
    processes: int = 0
    process: Process | None = None
    candidates: str = ""
    spans: Spans = field(default_factory=lambda: Spans.empty())  # every process, compact

    def as_dict(self) -> dict[str, Any]:
        return {"status": self.status, "letter": self.letter,
                "letter_source": self.letter_source, "reason": self.reason,
                "assignment": self.assignment, "processes": self.processes,
                "process": None if self.process is None else self.process.as_dict()}


@dataclass
class ChannelBoot:
    name: str
    manager: str  # network | master-dcf | inferred | none | off
    starts_slaves: tuple[bool, str] = (False, "inferred")
    start_all: tuple[bool, str] = (False, "inferred")
    sdo_timeout_inferred_ms: float | None = None
    manager_sdo_timeout_ms: float | None = None
    network_boots: list[dict[str, Any]] = field(default_factory=list)
    note: str = ""

    @property
    def ran(self) -> bool:
        return self.manager in ("network", "master-dcf", "inferred")

    def as_dict(self) -> dict[str, Any]:
        return {"manager": self.manager,
                "starts_slaves": {"value": self.starts_slaves[0], "source": self.starts_slaves[1]},
                "start_all": {"value": self.start_all[0], "source": self.start_all[1]},
                "sdo_timeout_inferred_ms": self.sdo_timeout_inferred_ms,
                "network_boots": self.network_boots}

    def heading(self) -> str:
        if not self.ran:
            return (f"manager {self.manager}: no CiA 302 boot-slave process seen"
                    if self.manager == "none" else "manager off: the P group is turned off")
        how = "all at once" if self.start_all[0] else "individually"
        starts = (f"starts slaves {how} ({self.starts_slaves[1]})" if self.starts_slaves[0]
                  else f"starts no slave ({self.starts_slaves[1]})")
        return f"manager {self.manager}; {starts}"


@dataclass
class BootAnalysis:
    """What the boot stage found. A log may fail a million boot processes: past `cap`
    findings of a code (the engine's per-rule cap, 0: none) a finding is only counted in
    `omitted`, since the engine would only count it too; `findings` holds the others, in
    the order the P rules hand them on (channel, node, process)."""

    channels: dict[str, ChannelBoot] = field(default_factory=dict)
    nodes: dict[tuple[str, int], NodeBootReport] = field(default_factory=dict)
    findings: list[BootFinding] = field(default_factory=list)
    cap: int = 0
    counts: dict[str, int] = field(default_factory=dict)  # per code: made and omitted
    omitted: dict[tuple[str, str], int] = field(default_factory=dict)  # (code, channel)

    def for_rule(self, code: str) -> Iterator[BootFinding]:
        return (f for f in self.findings if f.code == code)

    def make(self, code: str, channel: str) -> bool:
        """Count a finding of `code`; whether it is made (under the cap)."""
        seen = self.counts.get(code, 0)
        if self.cap and seen >= self.cap:
            self.omit(code, channel, 1)
            return False
        self.counts[code] = seen + 1
        return True

    def omit(self, code: str, channel: str, k: int) -> None:
        """Count k findings of `code` past the cap."""
        self.counts[code] = self.counts.get(code, 0) + k
        self.omitted[(code, channel)] = self.omitted.get((code, channel), 0) + k

    def batches(self, code: str) -> Iterator[tuple[str, list[BootFinding], int]]:
        """Per channel (in order): the findings of `code` made, then how many follow them
        uncounted past the cap."""
        made: dict[str, list[BootFinding]] = {}
        for f in self.for_rule(code):
            made.setdefault(f.channel, []).append(f)
        for ch in self.channels:
            rows, left = made.get(ch, []), self.omitted.get((code, ch), 0)
            if rows or left:
                yield ch, rows, left


_ATTR = "_nmtcheck_boot"


def attach(model: InputModel, analysis: BootAnalysis) -> None:
    """Keep the analysis with the model, for the P rules (which see only the model)."""
    setattr(model, _ATTR, analysis)


def of(model: InputModel) -> BootAnalysis | None:
    found: BootAnalysis | None = getattr(model, _ATTR, None)
    return found


# --- per node inputs ---------------------------------------------------------------------

@dataclass
class _Marks:
    """Sorted (by frame index) moments of one kind, as columns."""

    ts: np.ndarray
    idx: np.ndarray
    line: np.ndarray

    @classmethod
    def empty(cls) -> _Marks:
        return cls(np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64))

    def __len__(self) -> int:
        return len(self.ts)

    def at(self, k: int) -> Where:
        return Where(float(self.ts[k]), int(self.idx[k]), int(self.line[k]))

    def first_after(self, idx: int) -> int:
        """Position of the first mark later in the file than frame `idx` (len: none)."""
        return int(np.searchsorted(self.idx, idx, side="right"))


def _take(ts: np.ndarray, idx: np.ndarray, line: np.ndarray, sel: np.ndarray) -> _Marks:
    order = np.argsort(idx[sel], kind="stable")
    return _Marks(ts[sel][order], idx[sel][order], line[sel][order])


@dataclass
class _Node:
    """What the reconstruction of one node needs, as columns."""

    node: int
    t: st.TransferTable
    anchors: _Marks
    anchor_kind: np.ndarray  # per anchor: 0 bootup, 1 reset, 2 master-bootup
    bootups: _Marks
    resets: _Marks
    starts: _Marks
    reports: _Marks  # heartbeats / guarding responses that are evidence (not stale)
    report_value: np.ndarray
    rtrs: _Marks
    op_pos: np.ndarray  # positions of the OPERATIONAL reports among `reports`
    first_tx_idx: int | None
    cfg: NodeBoot | None
    c_n: float | None  # the manager's consumer time for N (s)


def _node_inputs(cm: ChannelModel, n: int, m: NodeModel | None, t: st.TransferTable,
                 master_bootups: _Marks, cfg: NodeBoot | None) -> _Node:
    nmt = cm.nmt
    master = cm.master.node if cm.master is not None else None
    ok = nmt.valid
    tgt = nmt.target.astype(np.int64)
    mine = (tgt == n) | ((tgt == 0) & (n != master))
    resets = _take(nmt.ts, nmt.idx, nmt.line, np.flatnonzero(
        ok & mine & ((nmt.cs == CS_RESET_NODE) | (nmt.cs == CS_RESET_COMM))))
    starts = _take(nmt.ts, nmt.idx, nmt.line, np.flatnonzero(ok & mine & (nmt.cs == CS_START)))
    if m is not None:
        ec = m.ec
        bootups = _take(ec.ts, ec.idx, ec.line, np.flatnonzero(ec.kind == BOOTUP))
        rep = np.flatnonzero(np.isin(ec.kind, (HEARTBEAT, GUARD)) & ~ec.stale)
        reports = _take(ec.ts, ec.idx, ec.line, rep)
        report_value = (ec.value[rep][np.argsort(ec.idx[rep], kind="stable")] & 0x7F)
        rtrs = _take(ec.ts, ec.idx, ec.line, np.flatnonzero(ec.kind == REQUEST))
        first_tx = m.first_tx.idx if m.first_tx is not None else None
        ec_first = int(ec.idx[ec.kind != REQUEST].min()) if np.any(ec.kind != REQUEST) else None
        cands = [x for x in (first_tx, ec_first) if x is not None]
        first_tx_idx = min(cands) if cands else None
    else:
        bootups = reports = rtrs = _Marks.empty()
        report_value = np.zeros(0, np.uint8)
        first_tx_idx = None
    mb = _Marks.empty() if n == master else master_bootups
    parts = [(bootups, 0), (resets if n != master else _Marks.empty(), 1), (mb, 2)]
    ts = np.concatenate([p.ts for p, _ in parts])
    idx = np.concatenate([p.idx for p, _ in parts])
    line = np.concatenate([p.line for p, _ in parts])
    kind = np.concatenate([np.full(len(p), k) for p, k in parts])
    order = np.argsort(idx, kind="stable")
    anchors = _Marks(ts[order], idx[order], line[order])
    c_n = cfg.manager_consumer_ms / 1000.0 if cfg is not None and cfg.manager_consumer_ms else None
    return _Node(n, t, anchors, kind[order], bootups, resets, starts, reports, report_value,
                 rtrs, np.flatnonzero(report_value == 0x05), first_tx_idx, cfg, c_n)


# --- processes ---------------------------------------------------------------------------

END_HOW = ("start", "operational", "superseded", "trace-end")
ANCHOR_KINDS = ("bootup", "reset", "master-bootup")
NO_END = 1 << 62


@dataclass
class _Procs:
    """A node's processes (8.3.2) as columns, in time order: a flood of boot-ups and probes
    makes hundreds of thousands, and only those a report or finding needs become
    `Process` objects."""

    anchor: np.ndarray  # position among the node's anchors (the start)
    p_lo: np.ndarray  # the process's probes: positions p_lo..p_hi (inclusive) of `probes`
    p_hi: np.ndarray
    answered: np.ndarray  # a probe answered with a value
    end_idx: np.ndarray  # NO_END: none (trace end)
    end_ts: np.ndarray
    end_how: np.ndarray  # index into END_HOW
    keep_alive: np.ndarray
    probes: np.ndarray  # the node's probe rows (transfer table)

    def __len__(self) -> int:
        return len(self.anchor)


def _anchor_ends(nd: _Node) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per anchor, for a process that would start there: keep-alive, and the natural end
    (the first start to N, or N's first OPERATIONAL report): frame, time and how."""
    a = nd.anchors
    if nd.cfg is not None and nd.cfg.assignment is not None:
        # keep-alive: the manager checks the state of every slave whose 1F81h has bits 0
        # and 4, however its process began (Lely NB 1396; recorded:
        # samples/lely/boot/keepalive, where the slaves' power-on boot-ups come after the
        # manager's). Without the configuration, 8.3.5: anchored on the manager's boot-up,
        # no reset to N since, N seen before.
        ka = np.full(len(a), bool(nd.cfg.bit(0) and nd.cfg.bit(4)))
    elif nd.first_tx_idx is not None:
        ka = (nd.anchor_kind == 2) & (nd.first_tx_idx < a.idx)
    else:
        ka = np.zeros(len(a), bool)
    end_idx = np.full(len(a), NO_END, np.int64)
    end_ts = np.full(len(a), np.inf)
    how = np.full(len(a), 3, np.int8)
    if len(nd.starts):
        s = np.searchsorted(nd.starts.idx, a.idx, side="right")
        has = s < len(nd.starts)
        sc = np.minimum(s, len(nd.starts) - 1)
        end_idx = np.where(has, nd.starts.idx[sc], end_idx)
        end_ts = np.where(has, nd.starts.ts[sc], end_ts)
        how[has] = 0
    if len(nd.op_pos):
        rep = np.searchsorted(nd.reports.idx, a.idx, side="right")
        op = np.searchsorted(nd.op_pos, rep)
        has = op < len(nd.op_pos)
        k = nd.op_pos[np.minimum(op, len(nd.op_pos) - 1)]
        if nd.c_n is not None:
            # a heartbeat-checked keep-alive slave: its first 05h only passes the state
            # check; Lely then waits for the next heartbeat (error control) and ends with L
            # there (NB 1441-1448, 2149-2190; recorded in samples/lely/boot/keepalive)
            nxt = np.minimum(k + 1, len(nd.reports) - 1)
            k = k + (ka & has & (k == rep) & (k + 1 < len(nd.reports))
                     & (nd.report_value[nxt] == 0x05))
        o_idx = nd.reports.idx[k]
        first = has & (o_idx < end_idx)
        end_idx = np.where(first, o_idx, end_idx)
        end_ts = np.where(first, nd.reports.ts[k], end_ts)
        how[first] = 1
    return ka, end_idx, end_ts, how


def _processes(nd: _Node, p: BootParams) -> _Procs:
    """N's processes (8.3.2); probes that belong to none (ad-hoc reads) are left out. One
    pass over the probes with plain Python values: what a process needs of its anchor
    (keep-alive, natural end) is computed for every anchor at once."""
    t = nd.t
    probes = np.flatnonzero(t.is_probe())
    a = nd.anchors
    anchor: list[int] = []
    lo: list[int] = []
    hi: list[int] = []
    e_idx: list[int] = []
    e_how: list[int] = []
    e_ts: list[float] = []
    answ: list[bool] = []
    k_a: list[bool] = []
    if len(a) and len(probes):
        ka, a_end_idx, a_end_ts, a_how = _anchor_ends(nd)
        p_idx = t.start_idx[probes]
        a_of = np.searchsorted(a.idx, p_idx, side="left") - 1
        win = (a_of >= 0) & (t.start_ts[probes] - a.ts[np.maximum(a_of, 0)]
                             <= p.probe_window_s + EPS)
        ok = (t.result[probes] == st.OK) & t.has_value[probes]
        # restarts the manager caused (a software update or restore) do not supersede
        restart = np.isin(t.index, (0x1F50, 0x1F51, 0x1F57)) | (
            (t.index == 0x1011) & (t.direction == st.DOWNLOAD) & (t.value == RESTORE_VALUE))
        rs = np.concatenate([[0], np.cumsum(restart)]).tolist()
        stop = np.searchsorted(t.start_idx, a.idx).tolist()
        aidx, ats = a.idx.tolist(), a.ts.tolist()
        a_end_idx_l, a_end_ts_l, a_how_l = a_end_idx.tolist(), a_end_ts.tolist(), a_how.tolist()
        probe_rows = probes.tolist()
        cur = -1  # the open process's anchor (-1: none)
        cur_end = NO_END
        cur_ans = False
        prev = -1

        def close(i: int, end: int, ts: float, how: int) -> None:
            anchor.append(cur)
            hi.append(i)
            answ.append(cur_ans)
            e_idx.append(end)
            e_ts.append(ts)
            e_how.append(how)

        def open_(i: int, k: int) -> int:
            lo.append(i)
            k_a.append(bool(ka[k]))
            return int(a_end_idx_l[k])

        for i, (pidx, k, w, good) in enumerate(zip(p_idx.tolist(), a_of.tolist(),
                                                   win.tolist(), ok.tolist(), strict=True)):
            if cur >= 0 and cur_end < pidx:
                close(i - 1, cur_end, a_end_ts_l[cur], a_how_l[cur])
                cur = -1
            if cur >= 0:
                if k >= 0 and aidx[k] > aidx[cur] and w and cur_ans:
                    last = probe_rows[i - 1]
                    if rs[max(stop[k], last)] - rs[last] == 0:  # superseded (8.3.2 item 1)
                        close(i - 1, aidx[k], ats[k], 2)
                        cur, cur_ans = k, False
                        cur_end = open_(i, k)
            elif k >= 0 and w and prev < aidx[k]:
                cur, cur_ans = k, False
                cur_end = open_(i, k)
            if cur >= 0 and good:
                cur_ans = True
            prev = pidx
        if cur >= 0:
            close(len(probe_rows) - 1, cur_end, a_end_ts_l[cur], a_how_l[cur])
    return _Procs(np.asarray(anchor, np.int64), np.asarray(lo, np.int64),
                  np.asarray(hi, np.int64), np.asarray(answ, bool),
                  np.asarray(e_idx, np.int64), np.asarray(e_ts, np.float64),
                  np.asarray(e_how, np.int8), np.asarray(k_a, bool), probes)


def _process(nd: _Node, c: _Procs, i: int) -> Process:
    """Process i as an object, for the full evaluation (`_evaluate`)."""
    a = int(c.anchor[i])
    x = Process(nd.node, float(nd.anchors.ts[a]), int(nd.anchors.idx[a]),
                int(nd.anchors.line[a]), ANCHOR_KINDS[int(nd.anchor_kind[a])])
    x.keep_alive = bool(c.keep_alive[i])
    x.probes = c.probes[int(c.p_lo[i]):int(c.p_hi[i]) + 1].tolist()
    x.answered = bool(c.answered[i])
    how = int(c.end_how[i])
    if how != 3:
        x.end_idx, x.end, x.end_how = int(c.end_idx[i]), float(c.end_ts[i]), END_HOW[how]
    return x


IDENTITY_ROWS = {"device_type": (0x1000, 0), "vendor_id": (0x1018, 1),
                 "product_code": (0x1018, 2), "revision_number": (0x1018, 3),
                 "serial_number": (0x1018, 4)}


@dataclass
class _Plain:
    """The processes `_evaluate` would only confirm, judged at once (`_plainly_judged`)."""

    ok: np.ndarray  # completed by a start, no failure: status ok, no letter
    incomplete: np.ndarray  # superseded before stall_ms, no failure: status incomplete
    step: np.ndarray  # of the incomplete ones: the last step (index into STEP_NAMES)
    ev_time: np.ndarray  # and the evidence (their last frame)
    ev_idx: np.ndarray
    ev_line: np.ndarray
    # completed by a start, failed by one refused or aborted configuration download and
    # nothing else (P003 J): its span, for when its finding is past the cap (None: none)
    failed: np.ndarray | None = None
    fail_row: np.ndarray | None = None  # the download's row (the evidence: its end)


STEP_NAMES = ("device_type", "vendor_id", "product_code", "revision_number", "serial_number",
              "software_check", "software_update", "config_check", "restore", "config",
              "error_control")


def _step_codes(t: st.TransferTable, r: np.ndarray) -> np.ndarray:
    """`_step_name` of rows r, as indices into STEP_NAMES."""
    index, sub, up = t.index[r], t.sub[r], t.direction[r] == st.UPLOAD
    conds = [(index == 0x1000) & (sub == 0) & up]
    conds += [(index == 0x1018) & up & (sub == k) for k in (1, 2, 3, 4)]
    conds += [up & (((index == 0x1F56) & (sub == 1)) | ((index == 0x1F52) & (sub >= 1)
                                                         & (sub <= 2))),
              np.isin(index, (0x1F50, 0x1F51, 0x1F57)),
              up & (index == 0x1020) & (sub >= 1) & (sub <= 2),
              ~up & (index == 0x1011) & (t.value[r] == RESTORE_VALUE)]
    found: np.ndarray = np.select(conds, list(range(len(conds))), STEP_NAMES.index("config"))
    return found


def _plainly_judged(nd: _Node, c: _Procs, last_frame_ts: float, p: BootParams,
                    mandatory: bool) -> _Plain:
    """The processes whose outcome is certain without `_evaluate`: not keep-alive; every
    transfer ended `ok` before the process's end; an upload of 1000h answered; no identity
    value differs from a non-zero expected one; no restore; with C_N known, N's heartbeat
    within C_N of the last transfer (P004 K). Such a process ended by a start is `ok` (no
    failure, no P007); one superseded (8.3.2) is `incomplete`, and when it ended before
    stall_ms (no P008) with no boot-up or reset inside, of a node that is not mandatory
    (no P006), nothing but its span is needed. Conservative: a process not proven so is
    evaluated in full, and the P rules see exactly what they saw before."""
    t = nd.t
    n = len(c)
    good = ((c.end_how == 0) | (c.end_how == 2)) & ~c.keep_alive
    out = _Plain(np.zeros(n, bool), np.zeros(n, bool), np.zeros(n, np.int16),
                 np.full(n, np.nan), np.full(n, -1, np.int64), np.zeros(n, np.int64),
                 np.zeros(n, bool), np.full(n, -1, np.int64))
    if not good.any() or len(t) == 0:
        return out
    start_idx = nd.anchors.idx[c.anchor]
    lo = np.searchsorted(t.start_idx, start_idx)
    hi = np.searchsorted(t.start_idx, np.where(good, c.end_idx, start_idx))
    hi = np.maximum(hi, lo)
    # processes whose transfer ranges overlap are left to the full evaluation, so that a
    # row belongs to at most one candidate
    ov = hi[:-1] > lo[1:]
    good[:-1] &= ~ov
    good[1:] &= ~ov
    rows = np.arange(len(t))
    proc = np.searchsorted(lo, rows, side="right") - 1
    pc = np.maximum(proc, 0)
    inside = (proc >= 0) & (rows < hi[pc]) & good[pc]
    refused = ((t.result == st.REFUSED) | (t.result == st.ABORTED)) & (
        t.direction == st.DOWNLOAD)
    bad = ((t.result != st.OK) & ~refused) | (t.end_idx > c.end_idx[pc])
    bad |= (t.index == 0x1011) & (t.direction == st.DOWNLOAD) & (t.value == RESTORE_VALUE)
    up = t.direction == st.UPLOAD
    for name, (index, sub) in IDENTITY_ROWS.items():
        e = _expected(nd.cfg, name).value
        if e:
            bad |= up & (t.index == index) & (t.sub == sub) & t.has_value & (
                t.value != np.uint64(e))
    # where its last transfer matters (t_c for K, the last frame of an incomplete one), it
    # is its last row: ends strictly increasing
    same = np.zeros(len(t), bool)
    same[1:] = (proc[1:] == proc[:-1]) & ((t.end_ts[1:] <= t.end_ts[:-1])
                                          | (t.end_idx[1:] <= t.end_idx[:-1]))
    bad |= same & ((c.end_how[pc] == 2) | (nd.c_n is not None))
    other = np.bincount(proc[inside], weights=bad[inside], minlength=n) > 0
    refusals = np.bincount(proc[inside], weights=refused[inside], minlength=n)
    hit = other | (refusals > 0)
    # a probe may open a process after its anchor's start (8.3.2): then no 1000h upload
    # was answered before the start (P007)
    dev = inside & up & (t.index == 0x1000) & (t.sub == 0)
    answered = np.bincount(proc[dev], minlength=n) > 0
    if not mandatory:
        out.failed, out.fail_row = _plainly_refused(t, c, good & ~other & (refusals == 1),
                                                    inside, proc, lo, refused, dev)
    good &= ~hit & answered
    last = np.maximum(hi - 1, 0)
    tc_ts, tc_idx = t.end_ts[last], t.end_idx[last]
    nz = nd.report_value != 0
    z_idx, z_ts = nd.reports.idx[nz], nd.reports.ts[nz]
    j = np.searchsorted(z_idx, tc_idx, side="right")
    has_z = j < len(z_ts)
    jc = np.minimum(j, max(len(z_ts) - 1, 0))
    if nd.c_n is not None and good.any():
        if np.any(np.diff(nd.reports.ts) < 0):
            return out
        limit = tc_ts + nd.c_n
        found = has_z & (z_ts[jc] > tc_ts + EPS) & (z_ts[jc] <= limit + EPS) if len(
            z_ts) else np.zeros(n, bool)
        good &= found | (last_frame_ts < limit - EPS)
    out.ok = good & (c.end_how == 0)
    inc = good & (c.end_how == 2) & (c.end_ts <= nd.anchors.ts[c.anchor] + p.stall_s + EPS)
    if mandatory or not inc.any():
        return out
    # no boot-up or reset of N inside (after the anchor): the last step is the last
    # transfer or N's first heartbeat after it (error control)
    for marks in (nd.bootups, nd.resets):
        k = np.searchsorted(marks.idx, start_idx, side="right")
        inc &= ~((k < len(marks)) & (marks.idx[np.minimum(k, max(len(marks) - 1, 0))]
                                     < c.end_idx)) if len(marks) else True
    # error control: the first report (state != 00h) after the last transfer, if its
    # time is after the transfer's end (else `_first_report_in` looks further: evaluated)
    if len(z_ts):
        after = z_ts[jc] > (tc_ts - EPS) + EPS
        inc &= ~has_z | after
        ec = has_z & after & (z_idx[jc] < c.end_idx)
    else:
        ec = np.zeros(n, bool)
    zk = np.flatnonzero(nz)[jc] if len(z_ts) else np.zeros(n, np.int64)
    out.incomplete = inc
    out.step[inc] = np.where(ec[inc], STEP_NAMES.index("error_control"),
                             _step_codes(t, last[inc]))
    r = nd.reports
    out.ev_time[inc] = np.where(ec[inc], r.ts[zk[inc]] if len(r) else 0.0, t.end_ts[last[inc]])
    out.ev_idx[inc] = np.where(ec[inc], r.idx[zk[inc]] if len(r) else 0, t.end_idx[last[inc]])
    out.ev_line[inc] = np.where(ec[inc], r.line[zk[inc]] if len(r) else 0,
                                t.end_line[last[inc]])
    return out


def _plainly_refused(t: st.TransferTable, c: _Procs, cand: np.ndarray, inside: np.ndarray,
                     proc: np.ndarray, lo: np.ndarray, refused: np.ndarray, dev: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Of the candidates (one refused or aborted download, every other transfer as for an
    ok process), those `_evaluate` certainly fails with that download alone (P003 J, no
    P007): ended by a start; one attempt (the only 1000h upload is the first transfer, a
    probe, answered); no download of the same object again (no retry to recover it); no
    software update (letter I, Lely's 1F51h exception). The process's last step is the
    start. Returns the mask and each one's download row."""
    n = len(c)
    fail_row = np.full(n, -1, np.int64)
    cand = cand & (c.end_how == 0)
    if not cand.any():
        return cand, fail_row
    pc = np.maximum(proc, 0)
    sw = inside & np.isin(t.index, (0x1F50, 0x1F51, 0x1F57))
    cand &= np.bincount(proc[sw], minlength=n) == 0
    cand &= np.bincount(proc[dev], minlength=n) == 1
    first = np.minimum(lo, max(len(t) - 1, 0))
    cand &= dev[first] & (proc[first] == np.arange(n)) & (t.probe_byte[first] == 0x40) & (
        t.has_value[first])
    dl = np.flatnonzero(inside & (t.direction == st.DOWNLOAD))
    key = pc[dl] * (1 << 24) + t.index[dl].astype(np.int64) * 256 + t.sub[dl]
    _u, inv, cnt = np.unique(key, return_inverse=True, return_counts=True)
    again = np.zeros(len(t), bool)
    again[dl] = cnt[inv.reshape(-1)] > 1
    cand &= np.bincount(proc[inside], weights=(refused & again)[inside], minlength=n) == 0
    rows = np.flatnonzero(inside & refused)
    fail_row[proc[rows]] = rows
    return cand & (fail_row >= 0), fail_row


def _signature(nd: _Node, c: _Procs) -> bool:
    """8.2.4: a probe that opens a process, followed before N's next anchor by an upload of
    1018h:01-04, a second probe or a start to N."""
    if len(c) == 0:
        return False
    t = nd.t
    a = nd.anchors
    first = c.probes[c.p_lo]
    f_idx = t.start_idx[first]
    nx = np.searchsorted(a.idx, a.idx[c.anchor], side="right")
    nxt = np.where(nx < len(a), a.idx[np.minimum(nx, len(a) - 1)], NO_END)
    flag = ((t.index == 0x1018) & (t.sub >= 1) & (t.sub <= 4) & (t.direction == st.UPLOAD)
            ) | t.is_probe()
    cs = np.concatenate([[0], np.cumsum(flag)])
    stop = np.maximum(np.searchsorted(t.start_idx, nxt), first + 1)
    if np.any(cs[stop] - cs[first + 1] > 0):
        return True
    if len(nd.starts):
        s = np.searchsorted(nd.starts.idx, f_idx, side="right")
        return bool(np.any((s < len(nd.starts))
                           & (nd.starts.idx[np.minimum(s, len(nd.starts) - 1)] < nxt)))
    return False


# --- steps and failures ------------------------------------------------------------------

def _step_name(t: st.TransferTable, r: int) -> str:
    index, sub, up = int(t.index[r]), int(t.sub[r]), t.direction[r] == st.UPLOAD
    if index == 0x1000 and sub == 0 and up:
        return "device_type"
    if index == 0x1018 and up and sub in IDENTITY_STEPS:
        return IDENTITY_STEPS[sub][0]
    if up and (index, sub) in ((0x1F56, 1), (0x1F52, 1), (0x1F52, 2)):
        return "software_check"
    if index in (0x1F50, 0x1F51, 0x1F57):
        return "software_update"
    if up and index == 0x1020 and sub in (1, 2):
        return "config_check"
    if index == 0x1011 and not up and int(t.value[r]) == RESTORE_VALUE:
        return "restore"
    return "config"


def _expected(cfg: NodeBoot | None, name: str) -> Expected:
    if cfg is None or name not in cfg.identity:
        return Expected(None, None)
    return cfg.identity[name]


def _transfer_step(t: st.TransferTable, r: int, attempt: int, cfg: NodeBoot | None) -> Step:
    name = _step_name(t, r)
    res = int(t.result[r])
    ends = res != st.OPEN
    s = Step(name, float(t.start_ts[r]), int(t.start_idx[r]), int(t.start_line[r]), attempt, r,
             int(t.index[r]), int(t.sub[r]), st.RESULTS[res],
             int(t.value[r]) if t.has_value[r] else None,
             end=Where(float(t.end_ts[r]), int(t.end_idx[r]), int(t.end_line[r])) if ends else None,
             abort_code=int(t.abort_code[r]) if res in (st.REFUSED, st.ABORTED) else None,
             direction=int(t.direction[r]))
    if name == "device_type" or name in ("vendor_id", "product_code", "revision_number",
                                         "serial_number"):
        e = _expected(cfg, name)
        s.expected, s.expected_source = e.value, e.source
    if res == st.ABORTED and s.abort_code == st.TIMEOUT_ABORT:
        s.result = "timeout"
    return s


def _abort(code: int | None) -> str:
    if code is None:
        return ""
    return f"abort {code:08X}h ({sdo.abort_text(code)})"


def _fail_text(s: Step) -> str:
    if s.result == "unanswered":
        return "unanswered"
    if s.result in ("refused", "aborted", "timeout"):
        who = "refused by the node" if s.result == "refused" else "aborted by the manager"
        return f"{who}: {_abort(s.abort_code)}"
    return str(s.result)


def _identity_failures(steps: list[Step], completed_by_start: bool) -> list[Failure]:
    """P001 conditions among one attempt's steps (recovered transfers are no failure)."""
    out: list[Failure] = []
    for i, s in enumerate(steps):
        if s.row < 0 or s.step not in ("device_type", "vendor_id", "product_code",
                                        "revision_number", "serial_number"):
            continue
        letter = "C" if s.step == "device_type" else IDENTITY_STEPS[int(s.sub or 0)][1]
        obj = "1000h" if s.step == "device_type" else f"1018:{s.sub:02X}"
        exp_obj = 0x1F84 if s.step == "device_type" else IDENTITY_STEPS[int(s.sub or 0)][2]
        later = [u for u in steps[i + 1:] if u.row >= 0 and u.index == s.index
                 and u.sub == s.sub and u.result == "ok"]
        if s.result == "ok" and s.value is not None:
            if s.expected and s.value != s.expected:
                if any(u.value == s.expected for u in later):
                    continue
                if s.expected_source == "node-dcf" and completed_by_start:
                    continue
                where = s.end or Where(s.time, s.frame_index, s.line)
                out.append(Failure("P001", letter, where,
                                   f"{obj} = 0x{s.value:08X}, expected 0x{s.expected:08X} "
                                   f"({exp_obj:04X}h:{{node}}, {s.expected_source})"))
        elif (s.step != "device_type" and s.result not in ("ok", "open")
              and not completed_by_start and not later):
            where = s.end or Where(s.time, s.frame_index, s.line)
            out.append(Failure("P001", letter, where,
                               f"upload of {obj} {_fail_text(s)} (the manager reads it only "
                               f"when {exp_obj:04X}h:{{node}} is not 0)"))
    return out


def _download_failures(steps: list[Step]) -> list[Failure]:
    """P003 (a) among one attempt's steps."""
    out: list[Failure] = []
    for i, s in enumerate(steps):
        if s.row < 0 or s.direction != st.DOWNLOAD or s.result in ("ok", "open"):
            continue
        if (s.index == 0x1F51 and s.sub == 1 and s.value in (0, 1)
                and s.result in ("unanswered", "timeout")):
            continue  # Lely ignores these (the slave may restart)
        if any(u.row >= 0 and u.index == s.index and u.sub == s.sub
               and u.direction == st.DOWNLOAD and u.result == "ok" for u in steps[i + 1:]):
            continue  # recovered by a retry
        letter = "I" if s.index in (0x1F50, 0x1F51) else "J"
        where = s.end or Where(s.time, s.frame_index, s.line)
        value = f" = 0x{s.value:08X}" if s.value is not None else ""
        out.append(Failure("P003", letter, where,
                           f"download of {s.index:04X}h:{s.sub:02X}{value} {_fail_text(s)}"))
    return out


def _first_report_in(nd: _Node, lo_idx: int, lo: float, hi: float) -> int | None:
    """Position of N's first heartbeat (state != 00h) or guarding response after frame
    `lo_idx` with time in (lo, hi]; None if none."""
    k = nd.reports.first_after(lo_idx)
    z = k + int(np.searchsorted(nd.reports.ts[k:], hi + EPS, side="right")) if np.isfinite(
        hi) else len(nd.reports)
    sel = np.flatnonzero((nd.reports.ts[k:z] > lo + EPS) & (nd.reports.ts[k:z] <= hi + EPS)
                         & (nd.report_value[k:z] != 0))
    return k + int(sel[0]) if sel.size else None


def _bootup_in(nd: _Node, lo: float, hi: float) -> bool:
    b = nd.bootups.ts
    a = int(np.searchsorted(b, lo + EPS, side="right"))
    return a < len(b) and bool(b[a] <= hi + EPS)


def _evaluate(x: Process, nd: _Node, p: BootParams, trace_end: float, last_frame_ts: float,
              t_end_idx: int) -> None:
    """Steps, attempts, failures, status and letter of one process."""
    t = nd.t
    end_idx = x.end_idx if x.end_idx is not None else t_end_idx + 1
    rows = np.arange(int(np.searchsorted(t.start_idx, x.start_idx)),
                     int(np.searchsorted(t.start_idx, end_idx)))
    x.transfers = len(rows)
    completed_by_start = x.end_how == "start"
    # attempts: a probe starts a new one when the current one had an answered probe or a failure
    attempt = 0
    steps: list[Step] = []
    cur: list[Step] = []
    answered = False
    for r in rows.tolist():
        s = _transfer_step(t, r, attempt, nd.cfg)
        if s.step == "device_type" and t.probe_byte[r] == 0x40 and cur and (
                answered or _identity_failures(cur, False) or _download_failures(cur)):
            attempt += 1
            s.attempt = attempt
            cur = []
            answered = False
        if s.step == "device_type" and s.result == "ok" and s.value is not None:
            answered = True
        cur.append(s)
        steps.append(s)
    x.attempts = attempt + 1
    last = [s for s in steps if s.attempt == attempt]
    # NMT and error-control steps
    extra: list[Step] = []
    lo, hi = x.start_idx, end_idx
    if x.anchor == "reset":
        extra.append(Step("reset", x.start, x.start_idx, x.start_line))
    for k in range(nd.resets.first_after(lo), len(nd.resets)):
        if nd.resets.idx[k] >= hi:
            break
        w = nd.resets.at(k)
        extra.append(Step("reset", w.time, w.frame_index, w.line, _attempt_at(steps, w)))
    first_answer = next((s.end.frame_index for s in steps if s.step == "device_type"
                         and s.result == "ok" and s.end is not None), None)
    k0 = nd.bootups.first_after(lo - 1)
    for k in range(k0, len(nd.bootups)):
        if nd.bootups.idx[k] >= hi:
            break
        w = nd.bootups.at(k)
        name = "reboot" if first_answer is not None and w.frame_index > first_answer else "bootup"
        extra.append(Step(name, w.time, w.frame_index, w.line, _attempt_at(steps, w)))
    probes = [s for s in steps if s.step == "device_type"]
    if probes and x.anchor != "bootup":
        first_b = next((e for e in extra if e.step == "bootup"), None)
        x.probed_before_bootup = first_b is not None and probes[0].frame_index < first_b.frame_index
    if x.end_how == "start" and x.end is not None and x.end_idx is not None:
        k = nd.starts.first_after(x.start_idx)
        w = nd.starts.at(k)
        x.started_at = w
        extra.append(Step("start", w.time, w.frame_index, w.line, attempt))
    if x.end_how == "operational" and x.end_idx is not None:
        k = int(np.searchsorted(nd.reports.idx, x.end_idx))
        w = nd.reports.at(k)
        x.operational_at = w
        extra.append(Step("operational", w.time, w.frame_index, w.line, attempt))
    last_tr = max((s.end.frame_index if s.end else s.frame_index for s in steps), default=lo)
    last_tr_ts = max((s.end.time if s.end else s.time for s in steps), default=x.start)
    # error control: N's first heartbeat / guarding response after the attempt's last transfer
    ec = _first_report_in(nd, last_tr, last_tr_ts - EPS, np.inf)
    if ec is not None and nd.reports.idx[ec] < hi and x.end_how != "operational":
        w = nd.reports.at(ec)
        name = "state_check" if x.keep_alive else "error_control"
        extra.append(Step(name, w.time, w.frame_index, w.line, attempt))
    x.steps = sorted(steps + extra, key=lambda s: (s.frame_index, s.step != "reset"))
    frames = [(s.end or Where(s.time, s.frame_index, s.line)) for s in x.steps]
    x.last_frame = max(frames, key=lambda w: w.frame_index) if frames else None
    _verdict(x, nd, p, steps, last, attempt, last_frame_ts, completed_by_start)


def _verdict(x: Process, nd: _Node, p: BootParams, steps: list[Step], last: list[Step],
             attempt: int, last_frame_ts: float, completed_by_start: bool) -> None:
    """Failures of the last attempt (first by time), P007, status and letter."""
    fails = _identity_failures(last, completed_by_start) + _download_failures(last)
    fails += _k_failure(x, nd, last, attempt, p, last_frame_ts, fails)
    fails += _b_failure(x, last, last_frame_ts)
    if not any(f.code == "P003" for f in fails):
        fails += _restore_failure(last, nd, p, last_frame_ts)
    fails.sort(key=lambda f: (f.at.time, f.at.frame_index))
    x.failures = len(fails)
    if fails:
        x.failure = fails[0]
    if x.started_at is not None and not any(f.code in ("P003", "P004") for f in fails):
        early = _early_start(x.started_at, steps, fails)
        if early is not None:
            x.failure = early
            x.status = "failed"
            x.reason = "started before boot completed"
            x.letter = None
            x.evidence = x.started_at
            return
    completed = x.end_how in ("start", "operational")
    if x.failure is not None:
        x.status = "failed"
        x.letter = x.failure.letter
        x.letter_source = "observed"
        x.reason = LETTERS.get(x.letter)
        x.evidence = x.failure.evidence or x.failure.at
    elif completed:
        x.status = "ok"
        if x.end_how == "operational":
            x.letter, x.letter_source, x.reason = "L", "observed", LETTERS["L"]
            x.evidence = x.operational_at
        else:
            x.evidence = x.started_at
    else:
        x.status = "incomplete"
        x.evidence = x.last_frame


def _early_start(t0: Where, steps: list[Step], fails: list[Failure]) -> Failure | None:
    """P007: a start while a transfer is open, no probe answered yet, or a P001 condition."""
    before = [s for s in steps if s.frame_index < t0.frame_index]
    open_tr = [s for s in before if s.end is None or s.end.frame_index > t0.frame_index]
    answered_before = any(s.step == "device_type" and s.result == "ok" and s.end is not None
                          and s.end.frame_index < t0.frame_index for s in before)
    p001 = [f for f in fails if f.code == "P001" and f.at.frame_index < t0.frame_index]
    if not (open_tr or not answered_before or p001):
        return None
    why = (f"while the transfer of {open_tr[0].index:04X}h:{open_tr[0].sub:02X} "
           f"(line {open_tr[0].line}) was open" if open_tr
           else "before any answer to the probe (1000h)" if not answered_before
           else f"after {p001[0].message}")
    return Failure("P007", "", t0, f"start {why}")


def _attempt_at(steps: list[Step], w: Where) -> int:
    a = 0
    for s in steps:
        if s.frame_index <= w.frame_index:
            a = s.attempt
    return a


def _k_failure(x: Process, nd: _Node, last: list[Step], attempt: int, p: BootParams,
               last_frame_ts: float, others: list[Failure]) -> list[Failure]:
    """P004: (a) K after the configuration; (b) E/F in a keep-alive process."""
    if x.end_how == "operational":
        return []
    out: list[Failure] = []
    answered = any(s.step == "device_type" and s.result == "ok" and s.value is not None
                   for s in last)
    if not last:
        return out
    t_c_step = max(last, key=lambda s: (s.end.time if s.end else s.time))
    t_c = t_c_step.end or Where(t_c_step.time, t_c_step.frame_index, t_c_step.line)
    if x.keep_alive:
        ident = [s for s in last if s.step in ("device_type", "vendor_id", "product_code",
                                                "revision_number", "serial_number")
                 and s.end is not None]
        t_i = max(ident, key=lambda s: s.end.time if s.end else 0.0).end if ident else None
        if t_i is not None:
            if nd.c_n is not None:
                hi = t_i.time + nd.c_n
                if (_first_report_in(nd, t_i.frame_index, t_i.time, hi) is None
                        and not _bootup_in(nd, t_i.time, hi) and last_frame_ts >= hi - EPS):
                    out.append(Failure("P004", "E", Where(hi, -1, 0),
                                       f"no heartbeat of node {{node}} within "
                                       f"{nd.c_n * 1000:g} ms after the identity check "
                                       f"(line {t_i.line})", t_i, moment=True))
                    return out
            k = nd.rtrs.first_after(t_i.frame_index)
            if k < len(nd.rtrs):
                r = nd.rtrs.at(k)
                hi = r.time + p.rtr_timeout_s
                if (_first_report_in(nd, r.frame_index, r.time, hi) is None
                        and last_frame_ts >= hi - EPS and (x.end_idx is None
                                                          or r.frame_index < x.end_idx)):
                    out.append(Failure("P004", "F", Where(hi, -1, 0),
                                       f"no answer to the guarding request (line {r.line}) "
                                       f"within {p.rtr_timeout_s * 1000:g} ms", r, moment=True))
                    return out
            out += _keep_alive_reset(x, nd, t_i, p, last_frame_ts, rtr=nd.c_n is None)
        return out
    if nd.c_n is None or not answered or others:
        return out
    hi = t_c.time + nd.c_n
    if last_frame_ts < hi - EPS:
        return out
    if _first_report_in(nd, t_c.frame_index, t_c.time, hi) is not None:
        return out
    if _bootup_in(nd, t_c.time, hi):
        return out
    started = (f"; started anyway at {x.started_at.time:.6f} (line {x.started_at.line})"
               if x.started_at is not None else "")
    out.append(Failure("P004", "K", Where(hi, -1, 0),
                       f"no heartbeat of node {{node}} within C_N = {nd.c_n * 1000:g} ms "
                       f"after the last SDO transfer (line {t_c.line}){started}", t_c,
                       moment=True))
    return out


def _keep_alive_reset(x: Process, nd: _Node, t_i: Where, p: BootParams, last_frame_ts: float,
                      rtr: bool) -> list[Failure]:
    """P004 (b): the state check found N not OPERATIONAL and reset it; N must then send a
    heartbeat or guarding response, or the manager go on with SDO, within reset_timeout.
    A boot-up alone does not end the wait (SPEC_BOOT 8.4, P004)."""
    k = nd.resets.first_after(t_i.frame_index)
    if k >= len(nd.resets) or (x.end_idx is not None and nd.resets.idx[k] >= x.end_idx):
        return []
    r = nd.resets.at(k)
    hi = r.time + p.reset_timeout_s
    if last_frame_ts < hi - EPS or _first_report_in(nd, r.frame_index, r.time, hi) is not None:
        return []
    t = nd.t
    after = (t.start_idx > r.frame_index) & (t.start_ts <= hi + EPS)
    if np.any(after):
        return []
    boot = "; its boot-up came, which the manager does not take as the answer" if _bootup_in(
        nd, r.time, hi) else ""
    letter = "F" if rtr else "E"
    return [Failure("P004", letter, Where(hi, -1, 0),
                    f"node {{node}} reset by the keep-alive state check (line {r.line}) sent no "
                    f"heartbeat or guarding response within {p.reset_timeout_s * 1000:g} ms"
                    f"{boot}", r, moment=True)]


def _restore_failure(last: list[Step], nd: _Node, p: BootParams, last_frame_ts: float
                     ) -> list[Failure]:
    """P003 (b): after the restore step's reset command, no boot-up of N within
    restore_timeout (Lely NC 48)."""
    for s in last:
        if s.step != "restore" or s.result != "ok" or s.end is None:
            continue
        k = nd.resets.first_after(s.end.frame_index)
        if k >= len(nd.resets):
            continue
        r = nd.resets.at(k)
        hi = r.time + p.restore_timeout_s
        if last_frame_ts >= hi - EPS and not _bootup_in(nd, r.time, hi):
            return [Failure("P003", "J", r,
                            f"no boot-up of node {{node}} within "
                            f"{p.restore_timeout_s * 1000:g} ms of the reset (line {r.line}) "
                            f"that follows the restore of defaults (1011h:{s.sub:02X}, line "
                            f"{s.line})", r)]
    return []


def _b_failure(x: Process, last: list[Step], last_frame_ts: float) -> list[Failure]:
    """P002: no probe answered in the whole process, one failed, and the manager stopped."""
    probes = [s for s in x.steps if s.step == "device_type" and s.row >= 0]
    if not probes or any(s.result == "ok" and s.value is not None for s in probes):
        return []
    failed = [s for s in probes if s.result not in ("ok", "open")]
    if not failed:
        return []
    times = [s.time for s in probes]
    longest = max((b - a for a, b in itertools.pairwise(times)), default=0.0)
    wait = max(2.0, 2 * longest)
    if last_frame_ts < probes[-1].time + wait - EPS:
        return []
    f = failed[-1]
    where = f.end or Where(f.time, f.frame_index, f.line)
    code = f" ({_abort(f.abort_code)})" if f.abort_code is not None else ""
    return [Failure("P002", "B", where,
                    f"{len(probes)} probe(s) of 1000h unanswered{code}; the manager stopped "
                    f"probing")]


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
        mb = _Marks.empty()
        if master is not None and master in cm.nodes:
            ec = cm.nodes[master].ec
            mb = _take(ec.ts, ec.idx, ec.line, np.flatnonzero(ec.kind == BOOTUP))
        keys = servers.get(cm.chan, set())
        nodes = sorted({k % 128 for k in keys} | set(cfg.nodes))
        per_node: dict[int, tuple[_Node, list[Process]]] = {}
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
               mb: _Marks, cfg: BootConfig, p: BootParams, cap: int, seen: dict[str, int]
               ) -> tuple[_Node, list[Process], Spans, int, bool, np.ndarray, _Dropped] | None:
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
    nd = _node_inputs(cm, n, cm.nodes.get(n), t, mb, cfg.nodes.get(n))
    c = _processes(nd, p)
    sig = _signature(nd, c)
    tm = (t.result == st.ABORTED) & (t.abort_code == st.TIMEOUT_ABORT)
    aborts = t.end_ts[tm] - t.start_ts[tm]
    mandatory = n in cfg.nodes and cfg.nodes[n].mandatory
    judged = _plainly_judged(nd, c, cm.end, p, mandatory)
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
        x = _process(nd, c, i)
        _evaluate(x, nd, p, cm.end, cm.end, 1 << 62)
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


def _plain_spans(nd: _Node, c: _Procs, judged: _Plain) -> Spans:
    """The spans of every process, filled in for those judged at once: an ok one ends
    with the start command (its last step and its evidence), an incomplete one as
    `_plainly_judged` found; the others are filled in as they are evaluated."""
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


def _not_managed(out: BootAnalysis, cm: ChannelModel, cfg: BootConfig) -> None:
    for n in cm.nodes:
        out.nodes[(cm.name, n)] = NodeBootReport(cm.name, n, "not-managed",
                                                 assignment=_assignment(cfg.nodes.get(n)))


def _node_report(out: BootAnalysis, cm: ChannelModel, n: int, nd: _Node, procs: list[Process],
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


def _candidates(x: Process, nd: _Node) -> str:
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


def _findings(out: BootAnalysis, cm: ChannelModel, per_node: dict[int, tuple[_Node,
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
                     f"{x.start:.6f}, line {x.start_line}) had not completed", None, f.at, x)
        return

    def text() -> str:
        msg = f.message.replace("{node}", str(n))
        more = f" ({x.failures} failures in the process)" if x.failures > 1 else ""
        started = ""
        if f.code == "P003" and x.started_at is not None:
            started = (f"; node {n} was started anyway at {x.started_at.time:.6f} "
                       f"(line {x.started_at.line})")
        halt = "; mandatory: network boot halted" if mandatory else ""
        return (f"{msg}{more}{started}{halt}: Lely-compatible letter {f.letter} "
                f"({LETTERS[f.letter]})")

    _add(out, f.code, cm, n, f.at, None if f.moment else f.at, text, f.letter,
         f.evidence or f.at, x)
    p_fired.setdefault(n, []).append(x)


def _p006(out: BootAnalysis, cm: ChannelModel,
          per_node: dict[int, tuple[_Node, list[Process]]], cfg: BootConfig, cb: ChannelBoot,
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
                 f"(1F89h) of the manager's boot-up at {w.time:.6f} (line {w.line}): the "
                 f"manager halts the network boot-up{note}", letter, ev6,
                 cur[-1] if cur else None)
            p006.add(n)
        entry["complete"] = complete
    cb.network_boots = nbs
    return p006


def _p008(out: BootAnalysis, cm: ChannelModel,
          per_node: dict[int, tuple[_Node, list[Process]]], cb: ChannelBoot, p: BootParams,
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
                 f"node {n}'s boot process (from {x.start:.6f}, line {x.start_line}) "
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
