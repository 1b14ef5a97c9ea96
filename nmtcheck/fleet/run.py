"""A fleet run: list the logs, skip those already checked, cut the rest into batches, keep a
bounded window of tasks in flight on the executor, add up the counts the tasks return.

The client holds the skip list and the counts, never a log's findings: its memory does not
grow with the number of logs checked (listing is streamed; a glob's own listing is held by
fsspec while it is walked).
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import sys
import threading
import time
import uuid
from collections.abc import Callable, Hashable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from nmtcheck.fleet.storage import FileInfo
from nmtcheck.fleet.trace import mark

if TYPE_CHECKING:
    from nmtcheck.fleet.executors import Executor

BATCH_FILES = 32  # small logs: enough per task that a task is not all latency
BATCH_BYTES = 64 << 20  # a batch is fetched to the worker's disk at once
WINDOW_PER_SLOT = 2  # tasks in flight per executor slot: enough to keep every slot busy
STATUSES = ("ok", "input_error", "crashed", "unsupported")


@dataclass
class FleetOptions:
    sources: list[str]
    results: str
    manifest: str | None = None
    executor: str = "local"
    storage_options: dict[str, Any] = field(default_factory=dict)
    path_pattern: str | None = None
    force: bool = False
    batch_files: int = BATCH_FILES
    batch_bytes: int = BATCH_BYTES
    progress: bool = False


@dataclass
class FleetOutcome:
    files: int = 0
    skipped: int = 0
    bytes: int = 0
    status: dict[str, int] = field(default_factory=lambda: dict.fromkeys(STATUSES, 0))
    skipped_status: dict[str, int] = field(default_factory=dict)  # of the logs skipped
    severity: dict[str, int] = field(default_factory=lambda: dict.fromkeys(
        ("error", "warning", "info"), 0))  # over the whole fleet: checked and skipped logs
    errors: list[tuple[str, str]] = field(default_factory=list)
    run_id: str = ""
    executor: str = ""
    seconds: float = 0.0
    start_seconds: float = 0.0  # of `seconds`: starting the executor (a Dask cluster's start-up)
    driver_cpu: float = 0.0  # CPU seconds of this process (the driver) in the run

    @property
    def checked(self) -> int:
        return self.files - self.skipped


def profile_digest(profile: Any, rule_codes: list[str], network: Any,
                   input_format: str | None, strict: bool, channel: str | None,
                   reader_options: dict[str, Any], max_findings: int) -> str:
    """What makes two checks of one log comparable: rules with their severities and
    parameters, the timeline's parameters, the network description and the reading options."""
    doc = {"rules": {c: [profile[c].severity, profile[c].params] for c in sorted(rule_codes)},
           "timeline": profile.timeline, "network": repr(network), "input_format": input_format,
           "strict": strict, "channel": channel, "reader_options": reader_options,
           "max_findings": max_findings}
    text = json.dumps(doc, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _slots(spec: str) -> int | None:
    """The executor's parallelism as far as its spec tells (for cutting a short listing);
    None for a running cluster, whose workers only the started executor knows."""
    import os

    name, _, arg = spec.partition(":")
    if name not in ("local", "dask-local"):
        return None
    return int(arg) if arg.isdigit() else os.cpu_count() or 1


def _batches(files: Iterator[FileInfo], max_files: int, max_bytes: int,
             slots: int | Callable[[], int] = 1) -> Iterator[list[FileInfo]]:
    """Batches of at most `max_files` logs and `max_bytes`; a listing shorter than
    slots x max_files is cut so that every slot gets a batch. `slots` may be a function,
    called once the listing has a log (it may start the executor)."""
    first = list(itertools.islice(files, 1))
    if not first:
        return
    if callable(slots):
        slots = slots()
    head = first + list(itertools.islice(files, max(0, max_files * slots - 1)))
    if len(head) < max_files * slots:
        max_files = max(1, -(-len(head) // slots))
    files = itertools.chain(head, files)
    batch: list[FileInfo] = []
    size = 0
    for fi in files:
        if batch and (len(batch) >= max_files or size + (fi.size or 0) > max_bytes):
            yield batch
            batch, size = [], 0
        batch.append(fi)
        size += fi.size or 0
    if batch:
        yield batch


class _Progress:
    """Files and bytes done, on stderr (tqdm), once the run takes over a second."""

    def __init__(self, enabled: bool) -> None:
        self._bar = None
        self._bytes = 0
        if enabled:
            from tqdm import tqdm

            self._bar = tqdm(unit=" files", file=sys.stderr, leave=False, delay=1.0,
                             mininterval=0.5, dynamic_ncols=True)

    def total(self, n: int) -> None:
        if self._bar is not None:
            self._bar.total = n
            self._bar.refresh()

    def update(self, files: int, nbytes: int) -> None:
        if self._bar is not None:
            self._bytes += nbytes
            self._bar.set_postfix_str(_size(self._bytes), refresh=False)
            self._bar.update(files)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()


def _size(n: float) -> str:
    for unit in ("B", "kB", "MB", "GB", "TB"):
        if n < 1000 or unit == "TB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n} B"


def run_fleet(opts: FleetOptions, profile: Any, rule_codes: list[str], network: Any,
              input_format: str | None = None, strict: bool = False,
              channel: str | None = None, reader_options: dict[str, Any] | None = None,
              max_findings: int = 10000) -> FleetOutcome:
    """Check every log `opts` names into the results dataset; the counts over the fleet."""
    mark("run_fleet")
    from nmtcheck.fleet.dataset import Dataset
    from nmtcheck.fleet.storage import PathPattern, absolute, check_exists, filesystem

    started = time.time()
    cpu = time.process_time()
    PathPattern(opts.path_pattern)  # a bad pattern is a usage error before any work
    from nmtcheck.fleet.executors import warm_up
    from nmtcheck.fleet.prestart import is_remote

    remote = any(is_remote(u) for u in [*opts.sources, opts.results, opts.manifest or ""])
    warm_up(opts.executor, remote)  # the local pool's fork server imports while the driver lists
    mark("warm_up")
    reader_options = reader_options or {}
    digest = profile_digest(profile, rule_codes, network, input_format, strict, channel,
                            reader_options, max_findings)
    for src in opts.sources:  # a missing filesystem package is exit 2 before any work
        filesystem(src, opts.storage_options)
    if opts.manifest is not None:  # every file an option names is checked before any work
        check_exists(opts.manifest, opts.storage_options, "--manifest")
    opts.results = absolute(opts.results)  # the workers' working directory is another
    ds = Dataset(opts.results, opts.storage_options)
    ds.ensure()
    mark("ensure")
    lock = ds.lock()  # one run at a time: held until this process ends
    mark("lock")
    try:
        out = _locked_run(ds, opts, cfg_args=(profile, rule_codes, network, input_format,
                                             strict, channel, reader_options, max_findings),
                          digest=digest, started=started)
    finally:
        if lock is not None:
            lock.close()
    out.driver_cpu = time.process_time() - cpu
    mark("run_end")
    return out


def _locked_run(ds: Any, opts: FleetOptions, cfg_args: tuple[Any, ...], digest: str,
                started: float) -> FleetOutcome:
    from nmtcheck import __version__
    from nmtcheck.fleet.storage import expand
    from nmtcheck.fleet.tasks import TaskConfig

    (profile, rule_codes, network, input_format, strict, channel, reader_options,
     max_findings) = cfg_args
    ds.remove_uncommitted()  # rows of batches an earlier run never committed
    done = {} if opts.force else ds.done(__version__, digest)
    mark("skip_list")
    run_id = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(started)) + "-" + uuid.uuid4().hex[:8]
    cfg = TaskConfig(opts.results, opts.storage_options, profile, rule_codes, network,
                     input_format, strict, channel, reader_options, max_findings,
                     opts.path_pattern, __version__, digest, run_id)
    out = FleetOutcome(run_id=run_id)
    progress = _Progress(opts.progress)
    listing = expand(opts.sources, opts.manifest, opts.storage_options)
    todo = _todo(listing, opts, done, out, progress)
    dispatch = _Dispatch(opts, cfg, out, progress)
    closing: _Closing | None = None
    try:
        dispatch.run(todo)
        mark("drained")
        closing = _close_in_background(dispatch.executor)
    finally:
        progress.close()
        if closing is None and dispatch.executor is not None:
            dispatch.executor.close()
    try:
        _record_run(ds, out, opts, digest, __version__, dispatch.totals, started)
    except BaseException:
        if closing is not None:  # the run row's error is the one to tell, not the pool's
            closing.join(raising=False)
        raise
    if closing is not None:
        closing.join()
    mark("closed")
    return out


class _Closing(threading.Thread):
    """A local pool closed in the background; join() raises what close() raised."""

    def __init__(self, executor: Any) -> None:
        super().__init__(name="nmtcheck-pool-close")
        self.executor = executor
        self.error: BaseException | None = None

    def run(self) -> None:
        try:
            self.executor.close()
        except BaseException as exc:  # noqa: BLE001 - handed to the driver's thread by join
            self.error = exc

    def join(self, timeout: float | None = None, raising: bool = True) -> None:
        super().join(timeout)
        if self.error is not None and raising:
            raise self.error


def _close_in_background(executor: Any) -> _Closing | None:
    """Every result is in: a local pool's workers end (14 ms for 2 of them here) while
    the driver writes the run's row (12 ms), not before it (issue 25: the run's tail is
    part of its fixed cost). A Dask client is closed in the driver's own thread."""
    from nmtcheck.fleet.executors import LocalExecutor

    if not isinstance(executor, LocalExecutor):
        return None
    closing = _Closing(executor)
    closing.start()
    return closing


def _record_run(ds: Any, out: FleetOutcome, opts: FleetOptions, digest: str, version: str,
                totals: Any, started: float) -> None:
    """The run's counts into `out`, and its row into the dataset if it checked a log."""
    for k, v in totals.status.items():
        out.status[k] = out.status.get(k, 0) + v
    for k, v in totals.severity.items():
        out.severity[k] += v
    out.bytes = totals.bytes
    out.errors = totals.errors + out.errors
    out.seconds = time.time() - started
    if out.checked:
        _write_run(ds, out, opts, digest, version, totals)
        mark("run_row")


def _todo(listing: Iterator[FileInfo], opts: FleetOptions, done: dict[Any, Any],
          out: FleetOutcome, progress: _Progress) -> Iterator[FileInfo]:
    """The logs to check, counting the skipped ones (their verdicts still count)."""
    from nmtcheck.fleet.dataset import DATASET_ENTRIES, done_key
    from nmtcheck.fleet.storage import complete

    # `data/**` with --results data/results: the dataset's own files are no logs (but a
    # log in the folder that holds the dataset is one)
    root = opts.results.rstrip("/") + "/"
    own = tuple(root + name for name in DATASET_ENTRIES)
    for chunk in _chunks((fi for fi in listing if not fi.url.startswith(own)), 256):
        for fi in complete(chunk, opts.storage_options):
            out.files += 1
            prev = done.get(done_key(fi.url, fi.fingerprint))
            if prev is None:
                yield fi
            else:
                _count_skipped(out, fi.url, prev)
    progress.total(out.files - out.skipped)


def _count_skipped(out: FleetOutcome, url: str, prev: Any) -> None:
    """A log an earlier run checked: its verdict, from the results dataset."""
    status, *by_severity = prev
    out.skipped += 1
    for sev, n in zip(out.severity, by_severity, strict=True):
        out.severity[sev] += n
    if status in ("input_error", "crashed") and len(out.errors) < 5:
        out.errors.append((url, f"{status} (in an earlier run)"))
    out.skipped_status[status] = out.skipped_status.get(status, 0) + 1


class _Dispatch:
    """Batches of logs to the executor (started at the first batch: a re-run with nothing
    new starts no worker at all), a bounded window of them in flight; their counts added.

    Logs whose task died are tried again at the end, one at a time with nothing beside
    them, so that a log that kills its worker cannot take innocent logs down with it (the
    stdlib pool loses every running task when one worker dies; Dask counts every task on
    a dead worker as suspect).
    """

    def __init__(self, opts: FleetOptions, cfg: Any, out: FleetOutcome,
                 progress: _Progress) -> None:
        from nmtcheck.fleet.tasks import BatchCounts

        self.opts = opts
        self.cfg = cfg
        self.out = out
        self.progress = progress
        self.executor: Executor | None = None
        self.shared_cfg: Any = None
        self.totals = BatchCounts()
        self.batches: dict[Hashable, list[FileInfo]] = {}
        self.n = 0
        self.quarantine: list[FileInfo] = []
        self.alone = False

    def run(self, todo: Iterator[FileInfo]) -> None:
        opts = self.opts
        slots = _slots(opts.executor)
        for batch in _batches(todo, opts.batch_files, opts.batch_bytes,
                              (lambda: self.start().slots) if slots is None else slots):
            ex = self.start()
            while ex.pending() >= max(2, WINDOW_PER_SLOT * ex.slots):
                self.collect()
            self.submit(batch)
        while self.executor is not None and self.executor.pending():
            self.collect()
        self.alone = True
        for fi in self.quarantine:
            self.submit([fi])
            while self.start().pending():
                self.collect()

    def start(self) -> Executor:
        from nmtcheck.fleet.executors import make_executor

        if self.executor is None:
            started = time.perf_counter()
            mark("listed_first")
            self.executor = make_executor(self.opts.executor)
            mark("executor")
            self.out.start_seconds = time.perf_counter() - started
            self.out.executor = self.executor.name
            own = self.opts.executor.partition(":")[0] in ("local", "dask-local")
            self.shared_cfg = self.executor.shared(dataclasses.replace(self.cfg,
                                                                       own_workers=own))
        return self.executor

    def collect(self) -> None:
        from nmtcheck.fleet.executors import Crashed
        from nmtcheck.fleet.tasks import crashed_batch

        assert self.executor is not None
        results = self.executor.done()
        mark("results", n=len(results))
        for key, result in results:
            files = self.batches.pop(key)
            if isinstance(result, Crashed) and not self.alone:
                self.quarantine.extend(files)
                continue
            if isinstance(result, Crashed):
                result = crashed_batch(files[0], self.cfg, result.attempts, result.reason)
            elif isinstance(result, BaseException):
                from nmtcheck.errors import UsageError

                raise UsageError(f"--results {self.opts.results}: a task failed: "
                                 f"{type(result).__name__}: {result}")
            self.totals.add(result)
            self.progress.update(result.files, result.bytes)

    def submit(self, files: list[FileInfo]) -> None:
        from nmtcheck.fleet.tasks import check_batch

        self.n += 1
        self.batches[self.n] = files
        self.start().submit(self.n, check_batch, files, self.shared_cfg)


def _chunks(it: Iterator[FileInfo], n: int) -> Iterator[list[FileInfo]]:
    chunk: list[FileInfo] = []
    for x in it:
        chunk.append(x)
        if len(chunk) >= n:
            yield chunk
            chunk = []
    if chunk:
        yield chunk


def _write_run(ds: Any, out: FleetOutcome, opts: FleetOptions, digest: str, version: str,
               totals: Any) -> None:
    """One row per run that checked something (a re-run with nothing new writes nothing)."""
    from nmtcheck.fleet.dataset import date_of

    now = time.time()
    row = {"run_id": out.run_id, "started_at": now - out.seconds, "finished_at": now,
           "nmtcheck_version": version, "profile_digest": digest, "executor": out.executor,
           "sources": json.dumps({"sources": opts.sources, "manifest": opts.manifest}),
           "files": out.files, "skipped": out.skipped, "checked": out.checked,
           **{s: totals.status.get(s, 0) for s in STATUSES}, "bytes": totals.bytes,
           **{f"n_{k}": v for k, v in totals.severity.items()}, "seconds": out.seconds,
           "date": date_of(now)}
    ds.write("runs", f"run-{out.run_id}", [row])
