"""One node's boot-slave processes, step by step (SPEC §8.3): the node's inputs as columns,
its processes and attempts (8.3.2), the steps of each (identity, configuration download,
restore, state check), the failures and the letter A-O they give. The channel-level pass
(`boot.py`) judges the plain processes at once (`plainly_judged`) and evaluates the rest
(`evaluate`)."""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from nmtcheck.processes import sdo_transfers as st
from nmtcheck.processes.boot_config import Expected, NodeBoot
from nmtcheck.processes.boot_records import (
    CS_RESET_COMM,
    CS_RESET_NODE,
    CS_START,
    IDENTITY_STEPS,
    LETTERS,
    RESTORE_VALUE,
    BootParams,
    Failure,
    Process,
    Step,
    Where,
)
from nmtcheck.protocol import sdo
from nmtcheck.protocol.nmt import BOOTUP, EPS, GUARD, HEARTBEAT, REQUEST
from nmtcheck.timeline.model import ChannelModel, NodeModel

# --- per node inputs ---------------------------------------------------------------------

@dataclass
class Marks:
    """Sorted (by frame index) moments of one kind, as columns."""

    ts: np.ndarray
    idx: np.ndarray
    line: np.ndarray

    @classmethod
    def empty(cls) -> Marks:
        return cls(np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64))

    def __len__(self) -> int:
        return len(self.ts)

    def at(self, k: int) -> Where:
        return Where(float(self.ts[k]), int(self.idx[k]), int(self.line[k]))

    def first_after(self, idx: int) -> int:
        """Position of the first mark later in the file than frame `idx` (len: none)."""
        return int(np.searchsorted(self.idx, idx, side="right"))


def take(ts: np.ndarray, idx: np.ndarray, line: np.ndarray, sel: np.ndarray) -> Marks:
    order = np.argsort(idx[sel], kind="stable")
    return Marks(ts[sel][order], idx[sel][order], line[sel][order])


@dataclass
class NodeInputs:
    """What the reconstruction of one node needs, as columns."""

    node: int
    t: st.TransferTable
    anchors: Marks
    anchor_kind: np.ndarray  # per anchor: 0 bootup, 1 reset, 2 master-bootup
    bootups: Marks
    resets: Marks
    starts: Marks
    reports: Marks  # heartbeats / guarding responses that are evidence (not stale)
    report_value: np.ndarray
    rtrs: Marks
    op_pos: np.ndarray  # positions of the OPERATIONAL reports among `reports`
    first_tx_idx: int | None
    cfg: NodeBoot | None
    c_n: float | None  # the manager's consumer time for N (s)


def node_inputs(cm: ChannelModel, n: int, m: NodeModel | None, t: st.TransferTable,
                 master_bootups: Marks, cfg: NodeBoot | None) -> NodeInputs:
    nmt = cm.nmt
    master = cm.master.node if cm.master is not None else None
    ok = nmt.valid
    tgt = nmt.target.astype(np.int64)
    mine = (tgt == n) | ((tgt == 0) & (n != master))
    resets = take(nmt.ts, nmt.idx, nmt.line, np.flatnonzero(
        ok & mine & ((nmt.cs == CS_RESET_NODE) | (nmt.cs == CS_RESET_COMM))))
    starts = take(nmt.ts, nmt.idx, nmt.line, np.flatnonzero(ok & mine & (nmt.cs == CS_START)))
    if m is not None:
        ec = m.ec
        bootups = take(ec.ts, ec.idx, ec.line, np.flatnonzero(ec.kind == BOOTUP))
        rep = np.flatnonzero(np.isin(ec.kind, (HEARTBEAT, GUARD)) & ~ec.stale)
        reports = take(ec.ts, ec.idx, ec.line, rep)
        report_value = (ec.value[rep][np.argsort(ec.idx[rep], kind="stable")] & 0x7F)
        rtrs = take(ec.ts, ec.idx, ec.line, np.flatnonzero(ec.kind == REQUEST))
        first_tx = m.first_tx.idx if m.first_tx is not None else None
        ec_first = int(ec.idx[ec.kind != REQUEST].min()) if np.any(ec.kind != REQUEST) else None
        cands = [x for x in (first_tx, ec_first) if x is not None]
        first_tx_idx = min(cands) if cands else None
    else:
        bootups = reports = rtrs = Marks.empty()
        report_value = np.zeros(0, np.uint8)
        first_tx_idx = None
    mb = Marks.empty() if n == master else master_bootups
    parts = [(bootups, 0), (resets if n != master else Marks.empty(), 1), (mb, 2)]
    ts = np.concatenate([p.ts for p, _ in parts])
    idx = np.concatenate([p.idx for p, _ in parts])
    line = np.concatenate([p.line for p, _ in parts])
    kind = np.concatenate([np.full(len(p), k) for p, k in parts])
    order = np.argsort(idx, kind="stable")
    anchors = Marks(ts[order], idx[order], line[order])
    c_n = cfg.manager_consumer_ms / 1000.0 if cfg is not None and cfg.manager_consumer_ms else None
    return NodeInputs(n, t, anchors, kind[order], bootups, resets, starts, reports, report_value,
                 rtrs, np.flatnonzero(report_value == 0x05), first_tx_idx, cfg, c_n)


# --- processes ---------------------------------------------------------------------------

END_HOW = ("start", "operational", "superseded", "trace-end")
ANCHOR_KINDS = ("bootup", "reset", "master-bootup")
NO_END = 1 << 62


@dataclass
class Procs:
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


def _anchor_ends(nd: NodeInputs) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
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


def node_processes(nd: NodeInputs, p: BootParams) -> Procs:
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
        failed = ((t.result[probes] != st.OK) & (t.result[probes] != st.OPEN)).tolist()
        p_ts = t.start_ts[probes].tolist()
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
        # the open process's probes: the last one's time, the longest interval between
        # two, whether one failed (P002's "the manager stopped probing")
        cur_last: float | None = None
        cur_gap = 0.0
        cur_failed = False
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
                # A process whose probes all failed and stopped (P002 holds at the anchor:
                # it failed B) has ended: the boot-up after it starts a new process
                # (8.1.2 item 5, 8.3.2), as one with an answered probe is superseded.
                # Lely reports B for a mandatory slave at 1F89h, and boots it afresh
                # when a power cycle brings its boot-up.
                if k >= 0 and aidx[k] > aidx[cur] and w and (cur_ans or (
                        not cur_ans and cur_failed and cur_last is not None
                        and ats[k] >= cur_last + max(2.0, 2 * cur_gap) - EPS)):
                    last = probe_rows[i - 1]
                    if rs[max(stop[k], last)] - rs[last] == 0:  # superseded (8.3.2 item 1)
                        close(i - 1, aidx[k], ats[k], 2)
                        cur, cur_ans = k, False
                        cur_end = open_(i, k)
                        cur_last, cur_gap, cur_failed = None, 0.0, False
            elif k >= 0 and w and prev < aidx[k]:
                cur, cur_ans = k, False
                cur_end = open_(i, k)
                cur_last, cur_gap, cur_failed = None, 0.0, False
            if cur >= 0:
                cur_ans = cur_ans or good
                if cur_last is not None:
                    cur_gap = max(cur_gap, p_ts[i] - cur_last)
                cur_last = p_ts[i]
                cur_failed = cur_failed or failed[i]
            prev = pidx
        if cur >= 0:
            close(len(probe_rows) - 1, cur_end, a_end_ts_l[cur], a_how_l[cur])
    return Procs(np.asarray(anchor, np.int64), np.asarray(lo, np.int64),
                  np.asarray(hi, np.int64), np.asarray(answ, bool),
                  np.asarray(e_idx, np.int64), np.asarray(e_ts, np.float64),
                  np.asarray(e_how, np.int8), np.asarray(k_a, bool), probes)


def process_object(nd: NodeInputs, c: Procs, i: int) -> Process:
    """Process i as an object, for the full evaluation (`evaluate`)."""
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
class Plain:
    """The processes `evaluate` would only confirm, judged at once (`plainly_judged`)."""

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


def plainly_judged(nd: NodeInputs, c: Procs, last_frame_ts: float, p: BootParams,
                    mandatory: bool) -> Plain:
    """The processes whose outcome is certain without `evaluate`: not keep-alive; every
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
    out = Plain(np.zeros(n, bool), np.zeros(n, bool), np.zeros(n, np.int16),
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


def _plainly_refused(t: st.TransferTable, c: Procs, cand: np.ndarray, inside: np.ndarray,
                     proc: np.ndarray, lo: np.ndarray, refused: np.ndarray, dev: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Of the candidates (one refused or aborted download, every other transfer as for an
    ok process), those `evaluate` certainly fails with that download alone (P003 J, no
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


def signature(nd: NodeInputs, c: Procs) -> bool:
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


def _first_report_in(nd: NodeInputs, lo_idx: int, lo: float, hi: float) -> int | None:
    """Position of N's first heartbeat (state != 00h) or guarding response after frame
    `lo_idx` with time in (lo, hi]; None if none."""
    k = nd.reports.first_after(lo_idx)
    z = k + int(np.searchsorted(nd.reports.ts[k:], hi + EPS, side="right")) if np.isfinite(
        hi) else len(nd.reports)
    sel = np.flatnonzero((nd.reports.ts[k:z] > lo + EPS) & (nd.reports.ts[k:z] <= hi + EPS)
                         & (nd.report_value[k:z] != 0))
    return k + int(sel[0]) if sel.size else None


def _bootup_in(nd: NodeInputs, lo: float, hi: float) -> bool:
    b = nd.bootups.ts
    a = int(np.searchsorted(b, lo + EPS, side="right"))
    return a < len(b) and bool(b[a] <= hi + EPS)


def evaluate(x: Process, nd: NodeInputs, p: BootParams, trace_end: float, last_frame_ts: float,
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


def _verdict(x: Process, nd: NodeInputs, p: BootParams, steps: list[Step], last: list[Step],
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


def _k_failure(x: Process, nd: NodeInputs, last: list[Step], attempt: int, p: BootParams,
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
    # `{started}`: "; started anyway at ..." where x was (its time from the trace's start:
    # boot.py fills it in)
    out.append(Failure("P004", "K", Where(hi, -1, 0),
                       f"no heartbeat of node {{node}} within C_N = {nd.c_n * 1000:g} ms "
                       f"after the last SDO transfer (line {t_c.line}){{started}}", t_c,
                       moment=True))
    return out


def _keep_alive_reset(x: Process, nd: NodeInputs, t_i: Where, p: BootParams, last_frame_ts: float,
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


def _restore_failure(last: list[Step], nd: NodeInputs, p: BootParams, last_frame_ts: float
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
