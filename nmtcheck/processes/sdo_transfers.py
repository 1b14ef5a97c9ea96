"""SDO transfers on the default channels (requests on 600h+N, answers on 580h+N), SPEC §8.3.1.

The decoder's pass over the batches feeds a `SdoSpool` (through `tee`): the SDO frames
of each server N, partitioned by node key, kept in memory up to a budget and then in
one file per server. `transfers(frames)` rebuilds one server's transfers as columns
(`TransferTable`): one server at a time, so the columns are bounded by the busiest
server, never by the log.

Expedited and segmented transfers are found vectorised (initiates, aborts and final
confirmations are classified per frame, a transfer is the run of frames from one
initiate to the next). Block transfers are walked frame by frame from their initiate
to their end, because inside a sub-block a data byte like 40h is segment 64, not an
upload request; everything around them stays vectorised.

A transfer that goes on for millions of segments keeps O(1) rows a batch: the spool drops
the frames in the middle of a steady run of plain segments (`steady_segments`), which
change no transfer's result, times or value.

Results: `ok`, `refused` (abort on 580h+N), `aborted` (abort on 600h+N, whatever index it
names; 0504 0000h is a timeout), `unanswered` (the next initiate came first, or the trace
ended at least `sdo_timeout_s` after the last client frame) and `open` (younger than that
at the trace end).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from nmtcheck.readers.frames import MAX_NODE_ID, SDO_RX_BASE, SDO_TX_BASE, FrameBatch, node_key
from nmtcheck.spool import ColumnSpool, spill_directory, write_spill

SDO_DTYPE = np.dtype([("ts", "f8"), ("idx", "i8"), ("line", "i8"), ("req", "?"),
                      ("dlc", "i1"), ("data", "u1", (8,))])  # 34 bytes a frame

ERR_COLUMNS: dict[str, type] = {"ts": np.float64, "idx": np.int64, "line": np.int64,
                                "chan": np.int32, "cls": np.uint32, "d1": np.uint8}

OK, REFUSED, ABORTED, UNANSWERED, OPEN = range(5)
RESULTS = ("ok", "refused", "aborted", "unanswered", "open")
DOWNLOAD, UPLOAD = 0, 1
EXPEDITED, SEGMENTED, BLOCK = 0, 1, 2
TIMEOUT_ABORT = 0x05040000

# the frames of a plain segmented transfer's steady state, as (request, byte 0) -> phase:
# download segments (c = 0, n = 0) and their confirmations, toggle 0 then 1 (phases 0-3);
# upload segment requests and the server's segments (c = 0, n = 0) (phases 4-7)
_PHASE = np.full(512, -1, np.int8)
for _phase, (_req, _cmd) in enumerate(((1, 0x00), (0, 0x20), (1, 0x10), (0, 0x30),
                                       (1, 0x60), (0, 0x00), (1, 0x70), (0, 0x10))):
    _PHASE[_req * 256 + _cmd] = _phase
_NEXT_PHASE = np.asarray([1, 2, 3, 0, 5, 6, 7, 4], np.int8)


def steady_segments(rows: np.ndarray) -> np.ndarray:
    """The frames of one server's rows (SDO_DTYPE, file order) that `transfers` needs not
    see: those with 4 frames on each side that all follow the same cycle of plain segments
    (segment, confirmation, segment with the other toggle, confirmation). None of them
    starts, ends or aborts a transfer or is the last client frame before one of those,
    and the cycle's kept first frames hold an upload's first 8 bytes; the frames around
    them read the same (a c = 0 segment is the latest client frame before each either way)."""
    n = len(rows)
    drop = np.zeros(n, bool)
    if n < 9:
        return drop
    phase = _PHASE[rows["req"].astype(np.int64) * 256 + rows["data"][:, 0]]
    step = (phase[:-1] >= 0) & (phase[1:] >= 0) & (
        phase[1:] == _NEXT_PHASE[np.maximum(phase[:-1], 0)])  # frame j -> j + 1 in a cycle
    steps = np.concatenate([[0], np.cumsum(step)])
    k = np.arange(4, n - 4)
    drop[4:n - 4] = steps[k + 4] - steps[k - 4] == 8
    return drop


class SdoSpool:
    """The SDO frames of every server, partitioned by node key (chan * 128 + N), and the
    error frames of every channel (for cause chains). Memory stays within `budget`: past
    it, each server's frames go to its own file."""

    def __init__(self, budget: int = 8 << 20) -> None:
        self._parts: dict[int, list[np.ndarray]] = {}
        self._files: set[int] = set()
        self._size = 0
        self._budget = budget
        self._tmp: object | None = None
        self._dir = ""
        self.short = 0  # SDO frames with DLC < 4: not decoded, counted
        self.errors = ColumnSpool(ERR_COLUMNS)
        self._err_cols: dict[str, np.ndarray] | None = None
        # servers sent a download to sub-index 2 of a PDO communication parameter (the
        # transmission type, SPEC §9.2.2 D006): only these are read again for it
        self.pdo_type_servers: set[int] = set()
        self._block_servers: set[int] = set()  # sent a block initiate: every frame is kept
        self.steady_dropped = 0  # frames `steady_segments` dropped

    def add(self, b: FrameBatch) -> None:
        co = ~b.ext & ~b.err & ~b.rtr
        cid = b.can_id.astype(np.int64)
        sdo = co & (((cid > SDO_TX_BASE) & (cid <= SDO_TX_BASE + MAX_NODE_ID))
                    | ((cid > SDO_RX_BASE) & (cid <= SDO_RX_BASE + MAX_NODE_ID)))
        if b.err.any():
            sel = np.flatnonzero(b.err)
            # the class bits and byte 1 (controller problems: RX/TX overflow = frames lost)
            self.errors.append({"ts": b.ts[sel], "idx": b.index[sel], "line": b.line[sel],
                                "chan": b.chan[sel], "cls": b.can_id[sel],
                                "d1": b.data[sel, 1]})
        if not sdo.any():
            return
        short = sdo & (b.dlc < 4)
        self.short += int(np.count_nonzero(short))
        sel = np.flatnonzero(sdo & ~short)
        if not sel.size:
            return
        req = cid[sel] > SDO_RX_BASE
        node = np.where(req, cid[sel] - SDO_RX_BASE, cid[sel] - SDO_TX_BASE)
        keys = node_key(b.chan[sel].astype(np.int64), node)
        rows = np.empty(sel.size, SDO_DTYPE)
        rows["ts"], rows["idx"], rows["line"] = b.ts[sel], b.index[sel], b.line[sel]
        rows["req"], rows["dlc"], rows["data"] = req, b.dlc[sel], b.data[sel]
        data = b.data[sel]
        index = data[:, 1].astype(np.int64) | (data[:, 2].astype(np.int64) << 8)
        pdo_type = req & ((data[:, 0] & 0xE0) == 0x20) & (data[:, 3] == 2) & (
            ((index >= 0x1400) & (index <= 0x15FF)) | ((index >= 0x1800) & (index <= 0x19FF)))
        if pdo_type.any():
            self.pdo_type_servers.update(np.unique(keys[pdo_type]).tolist())
        order = np.argsort(keys, kind="stable")
        skeys = keys[order]
        bounds = np.flatnonzero(np.diff(skeys, prepend=-1, append=-1))
        for a, z in zip(bounds[:-1].tolist(), bounds[1:].tolist(), strict=True):
            key, part = int(skeys[a]), rows[order[a:z]]
            if key not in self._block_servers and _block_candidate(
                    part["req"], part["data"][:, 0]).any():
                self._block_servers.add(key)  # block sub-blocks are walked frame by frame
            if key not in self._block_servers:
                drop = steady_segments(part)
                if drop.any():
                    self.steady_dropped += int(np.count_nonzero(drop))
                    part = part[~drop]
            self._parts.setdefault(key, []).append(part)
            self._size += part.nbytes
        if self._size > self._budget:
            self._flush()

    def _flush(self) -> None:
        if self._tmp is None:
            tmp = spill_directory()
            self._tmp, self._dir = tmp, tmp.name
        for key, parts in self._parts.items():
            if parts:
                with open(os.path.join(self._dir, str(key)), "ab") as f:
                    for p in parts:
                        write_spill(p, f, self._dir)
                self._files.add(key)
                parts.clear()
        self._size = 0

    def servers(self) -> list[int]:
        """The node keys of every server with SDO frames, sorted."""
        return sorted(set(self._files) | {k for k, p in self._parts.items() if p})

    def frames(self, key: int) -> np.ndarray:
        """One server's SDO frames (SDO_DTYPE), in file order."""
        parts = []
        if key in self._files:
            parts.append(np.fromfile(os.path.join(self._dir, str(key)), SDO_DTYPE))
        parts += self._parts.get(key, [])
        return np.concatenate(parts) if parts else np.empty(0, SDO_DTYPE)

    def error_frames(self) -> dict[str, np.ndarray]:
        """Every error frame (ts, idx, line, chan, class bits, data byte 1), file order."""
        if self._err_cols is None:
            self._err_cols = {n: self.errors.column(n) for n in ERR_COLUMNS}
            self.errors.close()
        return self._err_cols

    def close(self) -> None:
        self._parts.clear()
        self.errors.close()
        if self._tmp is not None:
            self._tmp.cleanup()  # type: ignore[attr-defined]
            self._tmp = None


def tee(batches: Iterator[FrameBatch], spool: SdoSpool) -> Iterator[FrameBatch]:
    """The batches unchanged, each one's SDO and error frames also put into `spool`."""
    for b in batches:
        spool.add(b)
        yield b


@dataclass
class TransferTable:
    """One server's SDO transfers as columns, in the order they were initiated."""

    start_ts: np.ndarray  # the initiate
    start_idx: np.ndarray
    start_line: np.ndarray
    end_ts: np.ndarray  # the final confirmation, the abort, or (unanswered) the last
    end_idx: np.ndarray  # client frame; NaN / -1 for `open`
    end_line: np.ndarray
    last_req_ts: np.ndarray  # the last client frame of the transfer
    direction: np.ndarray  # DOWNLOAD | UPLOAD
    mode: np.ndarray  # EXPEDITED | SEGMENTED | BLOCK
    index: np.ndarray
    sub: np.ndarray
    result: np.ndarray  # OK ... OPEN
    value: np.ndarray  # uint64: uploaded value or expedited downloaded value (first 8 bytes)
    has_value: np.ndarray
    abort_code: np.ndarray  # int64, 0 if none
    probe_byte: np.ndarray  # the initiate's byte 0 (a probe is exactly 40h)

    def __len__(self) -> int:
        return len(self.start_ts)

    @classmethod
    def empty(cls) -> TransferTable:
        f = np.zeros(0)
        i = np.zeros(0, np.int64)
        return cls(f, i, i, f, i, i, f, i, i, i, i, i, np.zeros(0, np.uint64),
                   np.zeros(0, bool), i, i)

    def take(self, rows: np.ndarray) -> TransferTable:
        return TransferTable(*(getattr(self, f)[rows] for f in self.__dataclass_fields__))

    @property
    def failed(self) -> np.ndarray:
        found: np.ndarray = (self.result == REFUSED) | (self.result == ABORTED) | (
            self.result == UNANSWERED)
        return found

    def is_probe(self) -> np.ndarray:
        found: np.ndarray = ((self.probe_byte == 0x40) & (self.index == 0x1000)
                             & (self.sub == 0) & (self.direction == UPLOAD))
        return found


def _u32(data: np.ndarray) -> np.ndarray:
    return (data[:, 4].astype(np.int64) | (data[:, 5].astype(np.int64) << 8)
            | (data[:, 6].astype(np.int64) << 16) | (data[:, 7].astype(np.int64) << 24))


def _expedited(cmd: np.ndarray, data: np.ndarray) -> np.ndarray:
    """The value of expedited frames (bytes 4..7, `n` unused bytes when s = 1)."""
    cmd = cmd.astype(np.int64)
    size = np.where(cmd & 0x01, 4 - ((cmd >> 2) & 0x3), 4)
    value = np.zeros(len(cmd), np.uint64)
    for k in range(4):
        value |= np.where(k < size, data[:, 4 + k].astype(np.uint64) << np.uint64(8 * k),
                          np.uint64(0))
    return value


def _block_candidate(req: np.ndarray, cmd: np.ndarray) -> np.ndarray:
    found: np.ndarray = req & (((cmd & 0xE1) == 0xC0) | ((cmd & 0xE3) == 0xA0))
    return found


def transfers(rows: np.ndarray, trace_end: float, sdo_timeout_s: float) -> TransferTable:
    """One server's transfers from its SDO frames (SDO_DTYPE, file order)."""
    n = len(rows)
    if not n:
        return TransferTable.empty()
    req = rows["req"]
    cmd = rows["data"][:, 0]
    cand = np.flatnonzero(_block_candidate(req, cmd))
    if not cand.size:
        return _plain(rows, 0, n, trace_end, sdo_timeout_s)
    parts: list[TransferTable] = []
    cursor = 0
    while cursor < n:
        k = int(np.searchsorted(cand, cursor))
        if k >= cand.size:
            parts.append(_plain(rows, cursor, n, trace_end, sdo_timeout_s))
            break
        p = int(cand[k])
        if p > cursor:
            parts.append(_plain(rows, cursor, p, trace_end, sdo_timeout_s, next_init=True))
        table, cursor = _block(rows, p, trace_end, sdo_timeout_s)
        parts.append(table)
    return _concat(parts)


def _concat(parts: list[TransferTable]) -> TransferTable:
    parts = [p for p in parts if len(p)]
    if not parts:
        return TransferTable.empty()
    return TransferTable(*(np.concatenate([getattr(p, f) for p in parts])
                           for f in TransferTable.__dataclass_fields__))


def _plain(rows: np.ndarray, lo: int, hi: int, trace_end: float, sdo_timeout_s: float,
           next_init: bool = False) -> TransferTable:
    """Expedited and segmented transfers of rows[lo:hi] (no block transfer among them).
    `next_init`: an initiate follows at `hi` (the last transfer is unanswered if open)."""
    r = rows[lo:hi]
    n = len(r)
    req = r["req"]
    data = r["data"]
    cmd = data[:, 0].astype(np.int64)
    spec = cmd >> 5
    index = data[:, 1].astype(np.int64) | (data[:, 2].astype(np.int64) << 8)
    sub = data[:, 3].astype(np.int64)
    init = req & ((spec == 1) | (spec == 2))
    client_abort = req & (cmd == 0x80)
    server_abort = ~req & (cmd == 0x80)
    tid = np.cumsum(init) - 1  # the transfer each frame belongs to (-1: none yet)
    starts = np.flatnonzero(init)
    if not starts.size:
        return TransferTable.empty()
    # frames after an abort belong to no transfer until the next initiate
    ab = client_abort | server_abort
    t = len(starts)
    direction = np.where(spec[starts] == 2, UPLOAD, DOWNLOAD)
    exp_dl = (direction == DOWNLOAD) & ((cmd[starts] & 0x02) != 0)
    # per frame, the transfer's direction / expedited flag
    valid = tid >= 0
    tdir = np.where(valid, direction[np.maximum(tid, 0)], -1)
    texp = valid & exp_dl[np.maximum(tid, 0)]
    # the latest client frame's command before each frame (segment c bit), within the transfer
    last_req = np.maximum.accumulate(np.where(req, np.arange(n), -1))
    prev_req = np.concatenate([[-1], last_req[:-1]])
    prev_cmd = np.where(prev_req >= 0, cmd[np.maximum(prev_req, 0)], 0)
    prev_is_seg = (prev_req >= 0) & (tid[np.maximum(prev_req, 0)] == tid) & (
        (prev_cmd >> 5) == 0) & ((prev_cmd & 0x01) != 0)
    sresp = ~req & valid
    ok_end = (
        # expedited download: 60h with the same index:sub
        (sresp & (tdir == DOWNLOAD) & texp & (cmd == 0x60)
         & (index == index[starts][np.maximum(tid, 0)]) & (sub == sub[starts][np.maximum(tid, 0)]))
        # segmented download: scs 1 answering the client's last segment (c = 1)
        | (sresp & (tdir == DOWNLOAD) & ~texp & ((cmd >> 5) == 1) & prev_is_seg)
        # expedited upload answer: scs 2 with e = 1
        | (sresp & (tdir == UPLOAD) & ((cmd >> 5) == 2) & ((cmd & 0x02) != 0))
        # segmented upload: the server's segment (scs 0) with c = 1
        | (sresp & (tdir == UPLOAD) & ((cmd >> 5) == 0) & ((cmd & 0x01) != 0)
           & (np.arange(n) > starts[np.maximum(tid, 0)])))
    terminal = valid & (ok_end | ab)
    # first terminal frame per transfer
    term_pos = np.flatnonzero(terminal)
    first_term = np.full(t, -1, np.int64)
    if term_pos.size:
        ttid = tid[term_pos]
        uniq, first = np.unique(ttid, return_index=True)
        first_term[uniq] = term_pos[first]
    ends_at = np.append(starts[1:], n)  # the frame after the transfer's last frame
    has_end = first_term >= 0
    end = np.where(has_end, first_term, 0)
    result = np.where(server_abort[end], REFUSED, np.where(client_abort[end], ABORTED, OK))
    # the last client frame of each transfer (up to its end, or up to the next initiate)
    limit = np.where(has_end, end, ends_at - 1)
    last_client = last_req[limit]
    is_last = np.arange(t) == t - 1
    followed = ~is_last | next_init
    last_ts = r["ts"][last_client]
    stale = (trace_end - last_ts) >= sdo_timeout_s - 1e-9
    result = np.where(has_end, result, np.where(followed | stale, UNANSWERED, OPEN))
    end_row = np.where(has_end, end, last_client)
    end_ts = np.where(result == OPEN, np.nan, r["ts"][end_row])
    end_idx = np.where(result == OPEN, -1, r["idx"][end_row])
    end_line = np.where(result == OPEN, 0, r["line"][end_row])
    # values: expedited from the initiate (downloads) or the answer (uploads)
    value = np.zeros(t, np.uint64)
    has_value = np.zeros(t, bool)
    up_exp = (direction == UPLOAD) & (result == OK) & ((cmd[end] >> 5) == 2)
    value[up_exp] = _expedited(cmd[end[up_exp]], data[end[up_exp]])
    has_value |= up_exp
    value[exp_dl] = _expedited(cmd[starts[exp_dl]], data[starts[exp_dl]])
    has_value |= exp_dl
    seg_up = np.flatnonzero((direction == UPLOAD) & (result == OK) & ~up_exp)
    for k in seg_up.tolist():  # segmented uploads: the segments' data (rare)
        value[k], has_value[k] = _segments_value(r, int(starts[k]), int(end[k]))
    mode = np.where(exp_dl | up_exp, EXPEDITED, SEGMENTED)
    mode = np.where((direction == UPLOAD) & (result != OK), EXPEDITED, mode)
    abort_code = np.where(has_end & ab[end], _u32(data[end]), 0)
    return TransferTable(r["ts"][starts], r["idx"][starts], r["line"][starts], end_ts, end_idx,
                         end_line, last_ts, direction, mode, index[starts], sub[starts], result,
                         value, has_value, abort_code, cmd[starts])


def _segments_value(r: np.ndarray, start: int, end: int) -> tuple[np.uint64, bool]:
    """The value of a segmented upload: the server segments' data, little-endian (the
    first 8 bytes of a longer value)."""
    out = bytearray()
    for k in range(start + 1, end + 1):
        if r["req"][k]:
            continue
        c = int(r["data"][k, 0])
        if c >> 5 != 0:
            continue
        size = 7 - ((c >> 1) & 0x7)
        out += bytes(r["data"][k, 1:1 + size].tolist())
    return np.uint64(int.from_bytes(bytes(out[:8]), "little")), True


def _block_command(upload: bool, is_req: bool, c: int, data: np.ndarray) -> str:
    """What a command frame of a block transfer does: sub (a sub-block starts), ack, trim
    (the end request's unused bytes), end (the final confirmation), new (a plain initiate:
    the block transfer was left unanswered) or nothing."""
    if is_req and (c >> 5) in (1, 2):
        return "new"
    if not upload:  # the server answers: initiate response, block ack, end response
        if is_req:
            return ""
        return {0xA0: "sub", 0xA2: "ack", 0xA1: "end"}.get(c & 0xE3, "")
    if is_req:  # the client starts, acknowledges and confirms the end
        return {0xA3: "sub", 0xA2: "ack", 0xA1: "end"}.get(c & 0xE3, "")
    return "trim" if (c & 0xE3) == 0xC1 else ""


def _block(rows: np.ndarray, p: int, trace_end: float, sdo_timeout_s: float
           ) -> tuple[TransferTable, int]:
    """The block transfer initiated at rows[p], walked frame by frame; returns it and the
    position after its last frame."""
    n = len(rows)
    data = rows["data"]
    req = rows["req"]
    c0 = int(data[p, 0])
    upload = (c0 & 0xE3) == 0xA0
    index = int(data[p, 1]) | int(data[p, 2]) << 8
    sub = int(data[p, 3])
    blksize = int(data[p, 4]) if upload else 0
    data_dir_is_req = not upload  # who sends segments
    in_sub = False
    last_seg = False
    seqno = 0
    payload = bytearray()
    result = -1
    end = -1
    last_client = p
    k = p + 1
    while k < n:
        c = int(data[k, 0])
        is_req = bool(req[k])
        if is_req:
            last_client = k
        from_data_side = is_req == data_dir_is_req
        if in_sub and from_data_side and c != 0x80:
            seqno = c & 0x7F
            payload += bytes(data[k, 1:8].tolist())
            if c & 0x80:
                last_seg = True
                in_sub = False
            elif blksize and seqno >= blksize:
                in_sub = False
            k += 1
            continue
        if c == 0x80:
            result, end = (ABORTED if is_req else REFUSED), k
            break
        action = _block_command(upload, is_req, c, data[k])
        if action == "end":
            result, end = OK, k
            break
        if action == "new":
            break
        if action == "sub":
            in_sub = True
            if not upload:
                blksize = int(data[k, 4])
        elif action == "ack":
            blksize = int(data[k, 2]) or blksize
            in_sub = not last_seg
        elif action == "trim":
            unused = (c >> 2) & 0x7
            if unused and len(payload) >= unused:
                del payload[len(payload) - unused:]
        k += 1
    stop = end + 1 if end >= 0 else k
    last_ts = float(rows["ts"][last_client])
    if result < 0:
        result = UNANSWERED if (stop < n or trace_end - last_ts >= sdo_timeout_s - 1e-9) else OPEN
        end = last_client if result == UNANSWERED else -1
    code = int(_u32(data[end:end + 1])[0]) if result in (REFUSED, ABORTED) else 0
    value = int.from_bytes(bytes(payload[:8]), "little") if upload and result == OK else 0
    table = TransferTable(
        np.asarray([rows["ts"][p]]), np.asarray([rows["idx"][p]]), np.asarray([rows["line"][p]]),
        np.asarray([rows["ts"][end] if end >= 0 else np.nan]),
        np.asarray([rows["idx"][end] if end >= 0 else -1], np.int64),
        np.asarray([rows["line"][end] if end >= 0 else 0], np.int64),
        np.asarray([last_ts]), np.asarray([UPLOAD if upload else DOWNLOAD]),
        np.asarray([BLOCK]), np.asarray([index]), np.asarray([sub]), np.asarray([result]),
        np.asarray([value], np.uint64), np.asarray([upload and result == OK]),
        np.asarray([code], np.int64), np.asarray([c0]))
    return table, stop
