"""Where tasks run: `local[:N]` (the stdlib process pool, made to survive a dead worker),
`dask-local[:N]` (a Dask LocalCluster of worker processes) and `dask://HOST:PORT` (a running
Dask cluster). One small interface, so another engine (Ray) is one more class in EXECUTORS.

A worker that dies (segfault in a reader library, the OOM killer) takes the tasks it was
running with it. Both engines retry them a few times and then give up on the task
(`Crashed`): the stdlib pool by noting which tasks had started when the pool broke, Dask by
its scheduler's `allowed-failures` (KilledWorker). Dask is imported only by its executors.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import select
import shutil
import signal
import tempfile
import threading
import time
import warnings
from collections.abc import Callable, Hashable
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any, Protocol

from nmtcheck.errors import UsageError
from nmtcheck.fleet.malloc import keep_freed_memory
from nmtcheck.fleet.prestart import local_context

ALLOWED_FAILURES = 2  # a task on a worker that died is retried this many times
DRIVER_GONE_EXIT = 75  # a worker's exit status when it ends because its driver died
RMTREE_TRIES = 10  # passes over the pool's folder by a worker whose driver died
WATCH_POLL_S = 0.5  # where no pidfd can watch the driver, how often it is looked for


@dataclass
class Crashed:
    """A task whose worker died every time it ran it."""

    attempts: int
    reason: str


class Executor(Protocol):
    name: str
    slots: int  # tasks that run at once

    def submit(self, key: Hashable, fn: Callable[..., Any], *args: Any) -> None: ...
    def done(self) -> list[tuple[Hashable, Any]]: ...  # blocks until one task ends
    def pending(self) -> int: ...
    def shared(self, value: Any) -> Any: ...  # a large argument sent once, not per task
    def close(self) -> None: ...


# --- the stdlib pool --------------------------------------------------------------------

_started: Any = None  # in a pool worker: where it says which task it starts


def watch_driver(pid: int, tmpdir: str | None = None, mp_tmpdir: str | None = None
                 ) -> threading.Thread:
    """End this process at once (os._exit) when process `pid`, the run's driver, has ended,
    however it ended: `kill -9`, the OOM killer, a crash. A worker is a child of the fork
    server, not of the driver, and the pool's pipes may stay open in other processes of
    the run, so neither a parent-death signal nor an EOF would tell it reliably: a pidfd
    (Linux 5.3+) becomes readable when the driver ends; elsewhere the driver is looked
    for every WATCH_POLL_S. Without this a killed run's workers went on checking the
    tasks already queued to them, then held their memory for minutes (issue 24). The
    pool's temporary directory `tmpdir`, which the driver can no longer remove, goes
    first (every worker tries; what a worker still writes there is unlinked with it), and
    so does the driver's multiprocessing directory `mp_tmpdir` (`pymp-*`, the fork
    server's socket), which only the driver's exit would have removed."""

    def gone() -> None:
        for path in (tmpdir, mp_tmpdir):
            # again while it is there: another worker (or this one's task, still running
            # until os._exit) may add a file after a pass listed the folder
            for _ in range(RMTREE_TRIES):
                if path is None or not os.path.lexists(path):
                    break
                shutil.rmtree(path, ignore_errors=True)
                if os.path.lexists(path):
                    time.sleep(0.02)
        os._exit(DRIVER_GONE_EXIT)

    def watch() -> None:
        try:
            fd = os.pidfd_open(pid)  # type: ignore[attr-defined,unused-ignore]
        except ProcessLookupError:
            gone()
        except (AttributeError, OSError):
            fd = None
        if fd is not None:
            while True:
                ready, _w, _x = select.select([fd], [], [])
                if ready:
                    gone()
        while True:
            time.sleep(WATCH_POLL_S)
            try:
                os.kill(pid, 0)
            except ProcessLookupError:
                gone()
            except PermissionError:  # there, but another user's: a reused PID, never ours
                gone()

    thread = threading.Thread(target=watch, name="nmtcheck-driver-watch", daemon=True)
    thread.start()
    return thread


def _init_worker(queue: Any, environ: dict[str, str] | None, driver: int | None = None,
                 tmpdir: str | None = None, mp_tmpdir: str | None = None) -> None:
    global _started
    from nmtcheck.fleet.trace import mark

    mark("worker")
    _started = queue
    if driver is not None:
        watch_driver(driver, tmpdir, mp_tmpdir)
    # A forked worker inherits the CLI's handlers, which turn a signal into an exception
    # with a traceback: a worker the pool (or Ctrl-C) stops just ends; the parent reports.
    for name in ("SIGTERM", "SIGHUP", "SIGINT"):
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), signal.SIG_DFL)
    if environ is not None:  # the client's environment now, as a forked worker would have it
        os.environ.clear()
        os.environ.update(environ)
    if tmpdir is not None:  # the pool's own: what a dead worker spilled goes with the pool
        os.environ["TMPDIR"] = tempfile.tempdir = tmpdir
    keep_freed_memory()


def _run(key: Hashable, fn: Callable[..., Any], args: tuple[Any, ...]) -> Any:
    from nmtcheck.fleet.trace import mark

    mark("task_start", key=repr(key))
    if _started is not None:
        _started.put((key, os.getpid()))  # SimpleQueue: written before the work, unbuffered
    out = fn(*args)
    mark("task_end", key=repr(key))
    return out


def _mp_tmpdir() -> str | None:
    """This process's multiprocessing directory (`pymp-*`: the fork server's socket), if
    it made one: removed by multiprocessing when this process exits, by the workers when
    it is killed (watch_driver)."""
    import multiprocessing.process

    config = getattr(multiprocessing.process.current_process(), "_config", {})
    tmp = config.get("tempdir") if isinstance(config, dict) else None
    return tmp if isinstance(tmp, str) else None


class ResilientPool:
    """A ProcessPoolExecutor that survives a dead worker: when the pool breaks, the tasks
    that had finished keep their results, the tasks that had started are suspects (one
    attempt used), the rest are resubmitted to a fresh pool at no cost. A task that was
    running at more than `allowed_failures` breaks ends as `Crashed`."""

    def __init__(self, workers: int, allowed_failures: int = ALLOWED_FAILURES,
                 mp_context: Any = None) -> None:
        self.workers = max(1, workers)
        self.allowed_failures = allowed_failures
        self._ctx = mp_context or multiprocessing.get_context()
        self._pool: ProcessPoolExecutor | None = None
        self._queue: Any = None
        self._tasks: dict[Future[Any], tuple[Hashable, Callable[..., Any], tuple[Any, ...]]] = {}
        self._failures: dict[Hashable, int] = {}
        self._ready: list[tuple[Hashable, Any]] = []
        self._dead_starts = 0
        self._tmp: tempfile.TemporaryDirectory[str] | None = None
        # the keys the workers said they started, read off `_queue` as tasks end: each
        # task writes one before its work, and a pipe nobody reads fills after some
        # 2,700 of them, when every worker blocks on its write and the pool hangs
        self._started: set[Hashable] = set()

    def _ensure(self) -> ProcessPoolExecutor:
        if self._pool is None:
            self._queue = self._ctx.SimpleQueue()
            # a fork server's workers would have the environment of the fork server's start
            environ = None if self._ctx.get_start_method() == "fork" else dict(os.environ)
            # The workers' temporary files (a long log's spilled columns, fetched objects)
            # go below a directory of this pool's, removed once its workers have ended: a
            # worker that dies (a crash, the OOM killer) cannot clean up after itself, and
            # what it spilled can be 40 bytes per frame of its log.
            from nmtcheck.spool import spill_directory

            try:
                self._tmp = spill_directory("nmtcheck-workers-")
            except OSError:  # no room, no rights: the workers' own spill says so, as before
                self._tmp = None
            self._pool = ProcessPoolExecutor(self.workers, mp_context=self._ctx,
                                             initializer=_init_worker,
                                             initargs=(self._queue, environ, os.getpid(),
                                                       self._tmp.name if self._tmp else None,
                                                       _mp_tmpdir()))
        return self._pool

    def _shutdown(self) -> None:
        """End this pool's workers, then remove what they left in their directory."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
        self._pool = None
        if self._tmp is not None:
            with contextlib.suppress(OSError):
                self._tmp.cleanup()
            self._tmp = None

    def submit(self, key: Hashable, fn: Callable[..., Any], *args: Any) -> None:
        self._submit(key, fn, args)

    def _submit(self, key: Hashable, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
        try:
            fut = self._ensure().submit(_run, key, fn, args)
        except BrokenProcessPool:  # broke between two calls: restart, then submit
            self._restart()
            fut = self._ensure().submit(_run, key, fn, args)
        self._tasks[fut] = (key, fn, args)

    def pending(self) -> int:
        return len(self._tasks) + len(self._ready)

    def attempts(self, key: Hashable) -> int:
        return self._failures.get(key, 0) + 1

    def done(self) -> list[tuple[Hashable, Any]]:
        """Ended tasks as (key, result | Crashed | Exception); blocks until there is one."""
        while not self._ready:
            if not self._tasks:
                return []
            finished, _ = wait(list(self._tasks), return_when=FIRST_COMPLETED)
            if any(isinstance(f.exception(), BrokenProcessPool) for f in finished):
                self._recover()
                continue
            self._started |= self._started_keys()
            for f in finished:
                key, _fn, _args = self._tasks.pop(f)
                self._started.discard(key)
                exc = f.exception()
                self._ready.append((key, f.result() if exc is None else exc))
        out, self._ready = self._ready, []
        return out

    def _started_keys(self) -> set[Hashable]:
        keys = set()
        try:
            while self._queue is not None and not self._queue.empty():
                keys.add(self._queue.get()[0])
        except (OSError, EOFError):
            pass
        return keys

    def _recover(self) -> None:
        wait(list(self._tasks))  # a broken pool fails all its futures: let it finish doing so
        started = self._started | self._started_keys()
        lost = []
        for f, (key, fn, args) in list(self._tasks.items()):
            exc = f.exception()
            del self._tasks[f]
            if exc is None:
                self._ready.append((key, f.result()))
            elif isinstance(exc, BrokenProcessPool):
                lost.append((key, fn, args))
            else:
                self._ready.append((key, exc))
        # The tasks that were running when the pool broke. None: the workers died before
        # starting any task (they cannot start: an import error, a broken environment);
        # the pool is restarted a few times and then the error is the run's, not a log's.
        suspects = {k for k, _fn, _a in lost if k in started}
        if lost and not suspects:
            self._dead_starts += 1
            if self._dead_starts > self.allowed_failures:
                raise UsageError("the worker processes die before they start a task (run "
                                 "with -j 1 or --executor local:1 to see why)")
        else:
            self._dead_starts = 0
        self._restart()
        for key, fn, args in lost:
            if key in suspects:
                self._failures[key] = self._failures.get(key, 0) + 1
                if self._failures[key] > self.allowed_failures:
                    self._ready.append((key, Crashed(
                        self._failures[key], f"its worker process died each of the "
                        f"{self._failures[key]} times it ran (a crash or the OOM killer)")))
                    continue
            self._submit(key, fn, args)

    def _restart(self) -> None:
        self._shutdown()
        self._started_keys()  # drop what the dead pool's workers wrote
        self._started.clear()

    def close(self) -> None:
        self._shutdown()


def warm_up(spec: str, remote: bool = False) -> None:
    """Called as a run begins: start what the executor `spec` will need and can start
    without a worker (the local pool's fork server, 0.2 s of imports), unless
    prestart has already started it; `remote`: the run reads or writes URLs (fsspec)."""
    if spec.partition(":")[0] == "local":
        local_context(start=True, remote=remote)


class LocalExecutor:
    """`local[:N]` (the default): N worker processes of this machine, nothing to install.
    The workers are started by a fork server, not forked from this process, whose fsspec
    and progress threads would be copied mid-flight."""

    def __init__(self, workers: int | None = None) -> None:
        self.slots = workers or os.cpu_count() or 1
        self.name = f"local:{self.slots}"
        self._pool = ResilientPool(self.slots, mp_context=local_context())

    def submit(self, key: Hashable, fn: Callable[..., Any], *args: Any) -> None:
        self._pool.submit(key, fn, *args)

    def done(self) -> list[tuple[Hashable, Any]]:
        return self._pool.done()

    def pending(self) -> int:
        return self._pool.pending()

    def shared(self, value: Any) -> Any:
        return value

    def close(self) -> None:
        self._pool.close()


# --- Dask -------------------------------------------------------------------------------

# What nmtcheck sets on the Dask workers it starts. Dask's defaults cost nmtcheck 5-7x here:
# MALLOC_TRIM_THRESHOLD_=65536 (nanny.pre-spawn-environ) makes glibc give memory back to
# the system after every numpy temporary, and the statistical profiler samples every
# worker thread every 10 ms. Then 10-15 % more per log (2 cores, 2026-11-26: a log's check
# 0.57-0.59 s in a dask-local worker, 0.50-0.52 s in a local one): the worker's event loop
# wakes every 20 ms (the tick that watches for a blocked loop), measures its memory every
# 100 ms and its system every 500 ms, each time taking the GIL from the task's thread.
# Once a second is enough for a task of seconds that is never paused or spilled.
DASK_CONFIG: dict[str, Any] = {
    "distributed.worker.profile.enabled": False,
    # None unsets a variable of Dask's defaults (dask.config.set merges dictionaries)
    "distributed.nanny.pre-spawn-environ": {"MALLOC_TRIM_THRESHOLD_": None},
    "distributed.admin.tick.interval": "1s",
    "distributed.worker.memory.monitor-interval": "1s",
    "distributed.admin.system-monitor.interval": "2s",
    "distributed.scheduler.allowed-failures": ALLOWED_FAILURES,
    # each worker imports the checker, the readers and pyarrow as it starts (part of the
    # cluster's start-up), not at its first task
    "distributed.worker.preload": ["nmtcheck.fleet.preload"],
}


def _allowed_failures(dask_scheduler: Any) -> int:
    """Run on the scheduler: how often it lets a task's worker die before KilledWorker."""
    return int(dask_scheduler.allowed_failures)


def _import_dask() -> Any:
    try:
        import distributed
    except ImportError:
        raise UsageError("--executor dask: Dask is not installed; install it with "
                         "pip install '.[dask]' in the nmtcheck checkout") from None
    return distributed


# A dask-local run's directory: the prefix, then the driver's process id
DASK_SCRATCH = "nmtcheck-dask-"


def _remove_dead_runs_scratch() -> None:
    """Remove the directories of dask-local runs whose driver has ended without removing
    its own: `kill -9`, or a signal while the cluster started (its worker processes may
    still make their folders there after the driver removed it). Only this user's, and
    only where no process has that id any more (a reused id keeps the directory)."""
    from nmtcheck.spool import SCRATCH

    root = SCRATCH.get() or tempfile.gettempdir()
    with contextlib.suppress(OSError):
        for entry in os.scandir(root):
            pid = entry.name.removeprefix(DASK_SCRATCH).partition("-")[0]
            if not entry.name.startswith(DASK_SCRATCH) or not pid.isdigit() or len(pid) > 9:
                continue
            with contextlib.suppress(OSError):
                if (not entry.is_dir(follow_symlinks=False)
                        or entry.stat(follow_symlinks=False).st_uid != os.getuid()):
                    continue
                try:
                    os.kill(int(pid), 0)
                except ProcessLookupError:
                    shutil.rmtree(entry.path, ignore_errors=True)
                except PermissionError:  # another user's process: the id is in use
                    pass


class DaskExecutor:
    """`dask-local[:N]` starts a LocalCluster of N single-threaded worker processes with
    nmtcheck's settings; `dask://HOST:PORT` connects to a running scheduler. On both it
    checks that the workers run this nmtcheck, registers nmtcheck's worker settings
    (dask_workers.WorkerSettings) and says in one line what they still lack."""

    def __init__(self, address: str | None, workers: int | None = None) -> None:
        from nmtcheck.fleet.trace import TRACE_ENV, mark

        distributed = _import_dask()
        import dask

        self._cluster = None
        self._scratch: tempfile.TemporaryDirectory[str] | None = None
        if address is None:
            n = workers or os.cpu_count() or 1
            # the cluster's lock files and worker directories below a directory of the
            # run's, removed with it: Dask's default, `dask-scratch-space` in the temporary
            # directory, stayed after every run
            from nmtcheck.spool import spill_directory

            _remove_dead_runs_scratch()
            with contextlib.suppress(OSError):  # no room, no rights: Dask's default
                self._scratch = spill_directory(f"{DASK_SCRATCH}{os.getpid()}-")
            scratch = {"temporary-directory": self._scratch.name} if self._scratch else {}
            try:
                with dask.config.set({**DASK_CONFIG, **scratch}):
                    self._cluster = distributed.LocalCluster(
                        n_workers=n, threads_per_worker=1, processes=True,
                        dashboard_address=":0", silence_logs=40,
                        local_directory=self._scratch.name if self._scratch else None)
                    self.client = distributed.Client(self._cluster)
            except BaseException:  # a signal while the cluster starts: what started goes
                if self._cluster is not None:
                    with contextlib.suppress(Exception):
                        self._cluster.close()
                self._remove_scratch()
                raise
            self.name = f"dask-local:{n}"
        else:
            try:
                self.client = distributed.Client(address, timeout="20s")
            except OSError as exc:
                raise UsageError(f"--executor dask://{address.removeprefix('tcp://')}: cannot "
                                 f"connect to the scheduler: {exc}") from None
            self.name = f"dask://{address.removeprefix('tcp://')}"
        mark("dask_connected")
        try:
            self._set_up_workers()
            self._tries = 1 + int(self.client.run_on_scheduler(_allowed_failures))
        except BaseException:
            self.close()
            raise
        self.slots = max(1, sum(self.client.nthreads().values()))
        self._trace = os.environ.get(TRACE_ENV)
        self._ac = distributed.as_completed()
        self._futures: dict[Any, Hashable] = {}
        self._killed = distributed.KilledWorker

    def _set_up_workers(self) -> None:
        """Check the workers' versions, register nmtcheck's settings on them, warn in one
        line about what they still lack."""
        from nmtcheck import __version__
        from nmtcheck.fleet.dask_workers import WorkerSettings, lacking, worker_info
        from nmtcheck.fleet.trace import mark

        try:
            self.client.get_versions(check=True)  # Dask's own client/scheduler/worker skew
        except ValueError as exc:
            raise UsageError(f"--executor {self.name}: {exc}") from None
        try:
            info = self.client.run(worker_info)
        except Exception as exc:  # noqa: BLE001 - unpickled on a worker: Dask wraps its error
            raise UsageError(f"--executor {self.name}: a worker cannot run nmtcheck "
                             f"({type(exc).__name__}: {exc}): install nmtcheck {__version__} "
                             "with the dask extra where the workers run") from None
        mark("dask_versions")
        skew = sorted({i["nmtcheck"] for i in info.values()} - {__version__})
        if skew:
            raise UsageError(f"--executor {self.name}: the workers run nmtcheck "
                             f"{', '.join(skew)}, this client {__version__}: install the same "
                             "version on both (results name the version that checked them)")
        problems = []
        try:
            self.client.register_plugin(WorkerSettings())
        except Exception as exc:  # noqa: BLE001 - the run goes on with Dask's settings
            problems.append(f"nmtcheck's worker settings failed on a worker "
                            f"({type(exc).__name__}: {exc})")
        mark("dask_plugin")
        info = self.client.run(worker_info)
        problems += lacking(info)
        mark("dask_info")
        if problems:
            warnings.warn(f"{self.name}: {'; '.join(problems)}", stacklevel=3)

    def submit(self, key: Hashable, fn: Callable[..., Any], *args: Any) -> None:
        if self._trace:
            from nmtcheck.fleet.dask_workers import traced

            fn, args = traced, (self._trace, key, fn, *args)
        fut = self.client.submit(fn, *args, pure=False)
        self._futures[fut] = key
        self._ac.add(fut)

    def done(self) -> list[tuple[Hashable, Any]]:
        if not self._futures:
            return []
        out = []
        for fut in [next(self._ac), *self._ac.next_batch(block=False)]:
            key = self._futures.pop(fut)
            if fut.status == "finished":
                out.append((key, fut.result()))
            else:
                exc = fut.exception()
                if isinstance(exc, self._killed):
                    out.append((key, Crashed(self._tries, f"its Dask worker died each of the "
                                             f"{self._tries} times it ran it")))
                else:
                    out.append((key, exc))
            fut.release()
        return out

    def pending(self) -> int:
        return len(self._futures)

    def shared(self, value: Any) -> Any:
        # Sent with each task (a few kB): scattered data would be lost with the last worker
        # holding it when a log kills workers.
        return value

    def close(self) -> None:
        self.client.close()
        if self._cluster is not None:
            self._cluster.close()
        self._remove_scratch()

    def _remove_scratch(self) -> None:
        if self._scratch is not None:
            with contextlib.suppress(OSError):
                self._scratch.cleanup()
            self._scratch = None


EXECUTORS = ("local[:N]", "dask-local[:N]", "dask://HOST:PORT")


def make_executor(spec: str) -> Executor:
    """An executor from `--executor`."""
    name, _, arg = spec.partition(":")
    if name in ("local", "dask-local"):
        workers = None
        if arg:
            if not arg.isdigit() or int(arg) < 1:
                raise UsageError(f"--executor {spec}: the worker count must be a positive "
                                 f"number (e.g. {name}:4)")
            workers = int(arg)
        return LocalExecutor(workers) if name == "local" else DaskExecutor(None, workers)
    if name in ("dask", "tcp", "tls") and arg.startswith("//"):
        address = arg[2:]
        if not address:
            raise UsageError(f"--executor {spec}: expected dask://HOST:PORT")
        return DaskExecutor(("tls://" if name == "tls" else "tcp://") + address)
    raise UsageError(f"--executor {spec}: unknown executor (available: {', '.join(EXECUTORS)})")
