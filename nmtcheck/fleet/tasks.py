"""One task: a batch of logs fetched together, checked one after the other, its rows
written to the results dataset by the task itself. Only counts go back to the client, so
the client's memory does not grow with the fleet.

This module runs inside executor workers (a local process, a Dask worker): it imports only
what checking needs, and keeps nmtcheck's own parse worker off (one core per task: the
executor already runs one task per core).
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from nmtcheck.fleet.storage import FileInfo, PathPattern, fetch_all, is_local, unsupported

# Test-only hook: a worker that checks a URL containing this text dies at once (os._exit),
# as a segfaulting library or the OOM killer would end it. Tests of crash handling set it.
CRASH_ENV = "NMTCHECK_TEST_CRASH"
EPOCH_2000 = 946684800.0  # earlier "times" are offsets from a recording's start, not dates


@dataclass
class TaskConfig:
    """Everything a worker needs besides the files: no credentials (those come from the
    worker's environment)."""

    results: str
    storage_options: dict[str, Any]
    profile: Any  # nmtcheck.settings.profiles.Profile
    rule_codes: list[str]
    network: Any  # nmtcheck.settings.network.Network | None
    input_format: str | None
    strict: bool
    channel: str | None
    reader_options: dict[str, Any]
    max_findings: int
    path_pattern: str | None
    version: str
    digest: str
    run_id: str
    # the workers are nmtcheck's own (local, dask-local): pyarrow may be kept from pandas
    own_workers: bool = False


@dataclass
class BatchCounts:
    """What a task returns: counts, and the first few input errors to name."""

    files: int = 0
    bytes: int = 0
    status: dict[str, int] = field(default_factory=dict)
    severity: dict[str, int] = field(default_factory=lambda: dict.fromkeys(
        ("error", "warning", "info"), 0))
    errors: list[tuple[str, str]] = field(default_factory=list)  # (url, error), at most 5

    def add(self, other: BatchCounts) -> None:
        self.files += other.files
        self.bytes += other.bytes
        for k, v in other.status.items():
            self.status[k] = self.status.get(k, 0) + v
        for k, v in other.severity.items():
            self.severity[k] = self.severity.get(k, 0) + v
        self.errors.extend(other.errors[: max(0, 5 - len(self.errors))])


def input_id(fi: FileInfo, version: str, digest: str) -> str:
    """A check's identity: the same content checked by the same nmtcheck with the same
    profile has the same id (the dataset's join key, and part of the file names)."""
    return hashlib.sha256("\x1f".join((fi.url, fi.fingerprint, version, digest)).encode()
                          ).hexdigest()[:24]


def batch_id(ids: list[str]) -> str:
    return hashlib.sha256("\n".join(sorted(ids)).encode()).hexdigest()[:24]


def check_batch(files: list[FileInfo], cfg: TaskConfig, attempts: int = 1) -> BatchCounts:
    """Fetch the batch (concurrently), check each log, write the batch's Parquet files
    (findings, node_stats, boot, sync_stats, pdo_stats, emcy, then inputs: the commit
    record), return the counts."""
    from nmtcheck.spool import SCRATCH

    token = SCRATCH.set(worker_scratch())
    try:
        return _check_batch(files, cfg, attempts)
    finally:
        SCRATCH.reset(token)


def worker_scratch() -> str | None:
    """In a Dask worker, its own directory, for the batch's fetched logs and spilled
    columns: Dask removes it when the worker closes, and the next worker to start beside
    a worker that died (a crash, the OOM killer) removes the dead one's, so what the dead
    worker fetched does not stay in /tmp for good. Elsewhere None: a local pool's workers
    already have a temporary directory of their pool's (executors.ResilientPool)."""
    import sys

    if "distributed" not in sys.modules:
        return None
    from distributed import get_worker

    try:
        return str(get_worker().local_directory)
    except ValueError:  # not in a Dask worker
        return None


def _check_batch(files: list[FileInfo], cfg: TaskConfig, attempts: int) -> BatchCounts:
    from nmtcheck.spool import spill_directory  # below SCRATCH, made with signals held

    os.environ["NMTCHECK_THREADS"] = "1"
    from nmtcheck.checks import BY_CODE
    from nmtcheck.fleet.dataset import ROW_TABLES, Dataset, arrow_without_pandas

    if cfg.own_workers:
        arrow_without_pandas()

    rules = [BY_CODE[c] for c in cfg.rule_codes]
    pattern = PathPattern(cfg.path_pattern)
    ids = [input_id(fi, cfg.version, cfg.digest) for fi in files]
    bid = batch_id(ids)
    rows: dict[str, list[dict[str, Any]]] = {t: [] for t in ("inputs", *ROW_TABLES)}
    counts = BatchCounts()
    crash_on = os.environ.get(CRASH_ENV)
    wanted = [fi.url for fi in files if unsupported(fi.url) is None]
    # a directory only for fetched copies: local logs are read where they are (and a
    # worker that dies leaves no empty directory behind)
    fetching = any(not is_local(url) for url in wanted)
    with (spill_directory("nmtcheck-fleet-") if fetching
          else contextlib.nullcontext(None)) as tmp:
        local = fetch_all(wanted, Path(tmp or "."), cfg.storage_options)
        for fi, iid in zip(files, ids, strict=True):
            if crash_on and crash_on in fi.url:
                os._exit(70)
            key = {"input_id": iid, "batch_id": bid, "url": fi.url, **pattern.fields(fi.url)}
            started = time.monotonic()
            row = _input_row(fi, key, cfg, attempts)
            why = unsupported(fi.url)
            path, fetch_error = local.get(fi.url, (None, None))
            if why is not None:
                row.update(status="unsupported", error=why)
            elif fetch_error is not None or path is None:
                row.update(status="input_error", error=f"{fi.url}: {fetch_error}")
            else:
                _check_one(path, fi, key, cfg, rules, row, rows)
                if tmp is not None and not is_local(fi.url):
                    os.unlink(path)  # a fetched copy: free the disk as the batch goes on
            row["seconds"] = round(time.monotonic() - started, 6)
            rows["inputs"].append(row)
            _count(counts, fi, row)
    from nmtcheck.fleet.trace import mark

    mark("checked")
    ds = Dataset(cfg.results, cfg.storage_options)
    name = f"part-{bid}"
    for table in (*ROW_TABLES, "inputs"):  # inputs last: the commit record
        ds.write(table, name, rows[table])
    mark("written")
    return counts


def crashed_batch(fi: FileInfo, cfg: TaskConfig, attempts: int, reason: str) -> BatchCounts:
    """The `crashed` row of a log that killed its worker every time it was tried (written by
    the client: no worker survives checking it)."""
    from nmtcheck.fleet.dataset import Dataset

    iid = input_id(fi, cfg.version, cfg.digest)
    bid = batch_id([iid])
    key = {"input_id": iid, "batch_id": bid, "url": fi.url,
           **PathPattern(cfg.path_pattern).fields(fi.url)}
    row = _input_row(fi, key, cfg, attempts)
    row.update(status="crashed", error=f"{fi.url}: {reason}")
    Dataset(cfg.results, cfg.storage_options).write("inputs", f"part-{bid}", [row])
    counts = BatchCounts()
    _count(counts, fi, row)
    return counts


def _count(counts: BatchCounts, fi: FileInfo, row: dict[str, Any]) -> None:
    counts.files += 1
    counts.bytes += fi.size or 0
    counts.status[row["status"]] = counts.status.get(row["status"], 0) + 1
    for sev in ("error", "warning", "info"):
        counts.severity[sev] += row[f"n_{sev}"] or 0
    if row["status"] in ("input_error", "crashed") and len(counts.errors) < 5:
        counts.errors.append((fi.url, row["error"]))


def _input_row(fi: FileInfo, key: dict[str, Any], cfg: TaskConfig, attempts: int
               ) -> dict[str, Any]:
    now = time.time()
    return {**key, "etag": fi.etag, "size": fi.size, "mtime": fi.mtime,
            "fingerprint": fi.fingerprint, "format": None, "status": "ok", "error": None,
            "n_error": 0, "n_warning": 0, "n_info": 0, "omitted": 0, "attempts": attempts,
            "nmtcheck_version": cfg.version, "profile_digest": cfg.digest,
            "run_id": cfg.run_id, "checked_at": now,
            "date": _date(None, fi)}


def _date(start_time: float | None, fi: FileInfo) -> str:
    """The partition: the log's start date; without a dated start (ASC offsets, input
    errors), the object's modification date."""
    from nmtcheck.fleet.dataset import date_of

    return date_of(start_time if start_time is not None else fi.mtime)


def _check_one(path: str, fi: FileInfo, key: dict[str, Any], cfg: TaskConfig,
               rules: list[Any], row: dict[str, Any], rows: dict[str, list[dict[str, Any]]]
               ) -> None:
    from nmtcheck.engine import check_input
    from nmtcheck.errors import InputError, UsageError
    from nmtcheck.fleet import comm_rows, lss_table

    try:
        res = check_input(path, 0, cfg.profile, rules, cfg.network, cfg.input_format,
                          cfg.strict, cfg.channel, cfg.reader_options,
                          max_findings=cfg.max_findings)
    except InputError as exc:
        row.update(status="input_error", error=f"{fi.url}: {exc.message}"
                   + (f" (line {exc.line})" if exc.line else ""))
        return
    except UsageError as exc:  # --channel not in this log: that log's problem, not the run's
        row.update(status="input_error", error=f"{fi.url}: {exc}")
        return
    except Exception as exc:  # noqa: BLE001 - a bug on one log must not end the fleet's run
        row.update(status="crashed", error=f"{fi.url}: internal error: {type(exc).__name__}: "
                   f"{exc} (please report)")
        return
    s = res.stats
    start_time = s.start if s.start is not None and s.start >= EPOCH_2000 else None
    date = _date(start_time, fi)
    row.update(format=s.format, frames=s.frames, skipped=s.skipped, ignored=s.ignored,
               extended=s.extended, error_frames=s.error_frames, remote_frames=s.remote_frames,
               fd_frames=s.fd_frames, dropped=s.dropped, backwards=s.backwards_timestamps,
               truncated=s.truncated, channels=",".join(s.channels), nodes=len(res.nodes()),
               start=s.start, end=s.end, start_time=start_time, date=date,
               omitted=sum(o.count for o in res.omitted))
    by_node: dict[tuple[str | None, int | None], dict[str, int]] = {}
    for f in res.findings:
        row[f"n_{f.severity}"] += 1
        c = by_node.setdefault((f.channel, f.node), dict.fromkeys(("error", "warning", "info"), 0))
        c[f.severity] += 1
        rows["findings"].append({
            **key, "rule": f.rule, "name": f.name, "severity": f.severity, "channel": f.channel,
            "node": f.node, "time": f.time, "frame_index": f.frame_index, "line": f.line or None,
            "message": f.message, "date": date,
            "abs_time": f.time if start_time is not None else None,
            **comm_rows.finding_fields(res, f)})
    for o in res.omitted:  # left out of the rows, not out of the counts
        row[f"n_{o.severity}"] += o.count
    rows["node_stats"].extend(node_rows(res, key, date, by_node))
    rows["boot"].extend({**key, **r, "date": date,
                         "abs_start": r["start"] if start_time is not None else None}
                        for r in boot_rows(res))
    for table, made in (("sync_stats", comm_rows.sync_rows), ("pdo_stats", comm_rows.pdo_rows),
                        ("emcy", comm_rows.emcy_rows)):  # SPEC_COMM §9.4.2
        rows[table].extend({**key, **r, "date": date} for r in made(res))
    rows["lss"].extend(lss_table.rows(res, key, date, start_time is not None))


MAX_BOOT_ROWS_PER_NODE = 1000  # a log may boot a node a million times: failures come first


def boot_rows(res: Any) -> list[dict[str, Any]]:
    """SPEC_BOOT §8.5, the `boot` table: one row per boot process of each node on a channel
    where the P group ran, and one (`process` null) for an assigned node that had none. The
    node's last process (`last`) carries its boot status as `nodes[].boot` states it; the
    earlier ones what the analysis keeps of every process (status, letter, span, last step,
    proving frame). Past MAX_BOOT_ROWS_PER_NODE processes, failed and incomplete ones and
    the last are kept first (`processes` still counts them all)."""
    import math

    import numpy as np

    from nmtcheck.processes.boot_records import LETTERS, STATUSES

    b = getattr(res, "boot", None)
    if b is None:
        return []
    out: list[dict[str, Any]] = []
    for (channel, node), rep in sorted(b.nodes.items()):
        cb = b.channels.get(channel)
        if cb is None or not cb.ran:
            continue
        sp = rep.spans
        if not len(sp) and rep.assignment is None:
            continue  # not managed and not assigned: no boot status to ask about
        a = rep.assignment or {}
        base = {"channel": channel, "node": node, "manager": cb.manager,
                "processes": rep.processes, "assignment": a.get("value"),
                "mandatory": a.get("mandatory"), "assignment_source": a.get("source")}
        if not len(sp):
            out.append({**base, "process": None, "last": True, "status": rep.status,
                        "letter": rep.letter, "letter_text": LETTERS.get(rep.letter or ""),
                        "letter_source": rep.letter_source, "reason": rep.reason})
            continue
        n = len(sp)
        keep = np.arange(n)
        if n > MAX_BOOT_ROWS_PER_NODE:
            bad = (sp.status != 0) | (np.arange(n) == n - 1)
            keep = np.sort(np.concatenate([np.flatnonzero(bad), np.flatnonzero(~bad)])
                           [:MAX_BOOT_ROWS_PER_NODE])
        for k in keep.tolist():
            letter = str(sp.letter[k]) or None
            row = {**base, "process": k, "last": k == n - 1,
                   "status": STATUSES[int(sp.status[k])], "letter": letter,
                   "letter_source": "observed" if letter else None,
                   "reason": LETTERS.get(letter or ""),
                   "start": float(sp.start[k]),
                   "end": float(sp.end[k]) if math.isfinite(sp.end[k]) else None,
                   "last_step": sp.last_step[int(sp.step[k])]}
            if int(sp.ev_idx[k]) >= 0:
                row.update(evidence_time=float(sp.ev_time[k]),
                           evidence_frame_index=int(sp.ev_idx[k]),
                           evidence_line=int(sp.ev_line[k]) or None)
            x = rep.process
            if k == n - 1:  # the node's status (a P006 may fail it after its process)
                row.update(status=rep.status, letter=rep.letter,
                           letter_source=rep.letter_source, reason=rep.reason)
                if x is not None:
                    row.update(anchor=x.anchor, attempts=x.attempts, keep_alive=x.keep_alive,
                               started_at=None if x.started_at is None else x.started_at.time,
                               findings=",".join(x.findings) or None)
            row["letter_text"] = LETTERS.get(row["letter"] or "")
            out.append(row)
    return out


def node_rows(res: Any, key: dict[str, Any], date: str,
              by_node: dict[tuple[str | None, int | None], dict[str, int]]
              ) -> list[dict[str, Any]]:
    """Per node: time in each state, boot-ups, heartbeat interval p50/p95/max, worst gap."""
    import numpy as np

    from nmtcheck.fleet.dataset import STATE_COLUMNS
    from nmtcheck.protocol.nmt import HEARTBEAT, STATES

    out = []
    for m in res.nodes():
        period, _source = m.reported_period(res.model.end_of(m.channel))
        iv = m.intervals  # columns: a node may have millions of intervals
        seconds = np.bincount(iv.state, weights=np.maximum(iv.end - iv.start, 0.0),
                              minlength=len(STATES))
        in_state = dict.fromkeys(STATE_COLUMNS.values(), 0.0)
        for code, total in enumerate(seconds.tolist()):
            in_state[STATE_COLUMNS[STATES[code]]] += total
        a, b = m.heartbeat_pairs()
        gaps = m.ec.ts[b] - m.ec.ts[a]
        starts = m.ec.ts[a]
        runs = m.ec.runs
        if runs is not None:  # a dropped run's pair: its largest interval, where it began
            r = runs.at_rows(b)
            gaps[r >= 0], starts[r >= 0] = runs.gmax[r[r >= 0]], runs.gmax_at[r[r >= 0]]
        hb: dict[str, float | None] = dict.fromkeys(
            ("hb_p50_ms", "hb_p95_ms", "hb_max_ms", "worst_gap_ms", "worst_gap_at"))
        if len(gaps):
            counted = m.heartbeat_gaps()
            worst = int(np.argmax(gaps))
            hb.update(hb_p50_ms=counted.percentile(50) * 1e3,
                      hb_p95_ms=counted.percentile(95) * 1e3,
                      hb_max_ms=float(gaps[worst]) * 1e3, worst_gap_ms=float(gaps[worst]) * 1e3,
                      worst_gap_at=float(starts[worst]))
        sev = by_node.get((m.channel, m.node), {})
        out.append({**key, "channel": m.channel, "node": m.node, "first_seen": m.first_show_ts,
                    "last_seen": m.last_seen,
                    "final_state": m.intervals[-1].state if m.intervals else "UNKNOWN",
                    "bootups": m.bootup_count, "error_control": m.error_control,
                    "heartbeat_period_ms": period * 1e3 if period else None,
                    **{k: round(v, 6) for k, v in in_state.items()},
                    "heartbeats": int(m.ec.count(HEARTBEAT)), **hb,
                    "n_error": sev.get("error", 0), "n_warning": sev.get("warning", 0),
                    "n_info": sev.get("info", 0), "date": date})
    return out
