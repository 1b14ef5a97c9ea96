"""What nmtcheck sets on the Dask workers it runs on, from the client (issue 40), and what
it reports about what it cannot set.

A run registers `WorkerSettings` (a Dask WorkerPlugin, kept by the scheduler: a worker
that joins or restarts later gets it too). In each worker process it

- imports what a task needs (nmtcheck.fleet.preload) and lets pyarrow look for pandas
  once, so that no task pays 0.3-0.5 s of imports in the middle of a run;
- undoes Dask's `MALLOC_TRIM_THRESHOLD_=65536` (distributed.nanny.pre-spawn-environ):
  glibc read it as the worker started, so mallopt sets the thresholds again
  (malloc.keep_freed_memory: what the local pool's workers use). With it, every numpy
  temporary was handed back to the system and faulted in again: 5-7x slower per log;
- stops the worker's statistical profiler (a sample of every thread every 10 ms) and has
  the event loop wake once a second for its tick and memory monitor and every 2 s for
  its system monitor, instead of every 20, 100 and 500 ms, each time taking the GIL from
  the running check (10-15 % per log when measured, 2026-11-26).

What a worker lacks that nmtcheck cannot give it from here is said in one line by the
executor: threads. A check is CPU-bound Python, so the threads of one worker process share
one core through the GIL; the thread count is fixed when the worker starts. (A Dask
resource of one per worker, set by the plugin, would hold a worker to one check at a time,
but the scheduler does not look at waiting tasks again when a restarted worker's resource
arrives: a run whose log killed a worker waited for good.) A worker without nmtcheck, or
with another version, is an error. Dask is imported by this module: only the Dask
executors import it.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Hashable
from typing import Any

from distributed.diagnostics.plugin import WorkerPlugin

PLUGIN_NAME = "nmtcheck-worker-settings"
TICK_S = 1.0  # distributed.admin.tick.interval
MEMORY_MONITOR_S = 1.0  # distributed.worker.memory.monitor-interval
SYSTEM_MONITOR_S = 2.0  # distributed.admin.system-monitor.interval
MALLOC_ENV = "MALLOC_TRIM_THRESHOLD_"

# in a worker: what WorkerSettings did to it (worker_info reports it)
_applied: dict[str, Any] = {}


class WorkerSettings(WorkerPlugin):
    """nmtcheck's settings for a worker process, applied as it registers the plugin."""

    name = PLUGIN_NAME
    idempotent = False  # a run registers it again: a newer nmtcheck's settings replace it

    def setup(self, worker: Any) -> None:
        configure(worker)


def configure(worker: Any) -> None:
    """Apply the settings the module's docstring lists to `worker` (its own process)."""
    import importlib

    import dask

    from nmtcheck.fleet.malloc import keep_freed_memory
    from nmtcheck.fleet.prestart import PRELOAD

    importlib.import_module(PRELOAD)  # the imports a task needs, now (as --preload would)
    _pyarrow_finds_pandas()
    if os.environ.pop(MALLOC_ENV, None) is not None:
        _applied["malloc_env_removed"] = True
    keep_freed_memory()
    _applied["malloc"] = True
    callbacks = worker.periodic_callbacks
    for name in ("profile", "profile-cycle"):
        pc = callbacks.pop(name, None)
        if pc is not None:
            pc.stop()
    dask.config.set({"distributed.worker.profile.enabled": False,
                     "distributed.admin.tick.interval": f"{TICK_S}s",
                     "distributed.worker.memory.monitor-interval": f"{MEMORY_MONITOR_S}s",
                     "distributed.admin.system-monitor.interval": f"{SYSTEM_MONITOR_S}s"})
    for name, seconds in (("tick", TICK_S), ("memory_monitor", MEMORY_MONITOR_S),
                          ("monitor", SYSTEM_MONITOR_S)):
        pc = callbacks.get(name)
        if pc is not None and pc.callback_time < seconds * 1e3:
            pc.callback_time = seconds * 1e3  # from its next wake-up on
    if getattr(worker, "_tick_interval", 0) < TICK_S:  # what the tick's own check expects
        worker._tick_interval = TICK_S
    _applied["loop"] = True


def _pyarrow_finds_pandas() -> None:
    """pyarrow looks for pandas at its first conversion of Python objects: 0.3-0.5 s, at a
    worker's first Parquet write unless done here. A Dask worker may run other people's
    tasks, so pandas is not kept away from it (as it is from nmtcheck's own workers)."""
    try:
        import pyarrow as pa
    except ImportError:  # said where a table is written
        return
    pa.table({"x": [0]})


def worker_info(dask_worker: Any = None) -> dict[str, Any]:
    """Run on each worker (Client.run): what the client compares with its own, and the
    settings the worker has now."""
    import dask
    from dask.utils import parse_timedelta

    from nmtcheck import __version__

    info: dict[str, Any] = {
        "nmtcheck": __version__,
        "malloc_trim": os.environ.get(MALLOC_ENV),
        "profile": bool(dask.config.get("distributed.worker.profile.enabled", True)),
        "tick_s": parse_timedelta(dask.config.get("distributed.admin.tick.interval")),
        "applied": dict(_applied)}
    if dask_worker is not None:
        callbacks = dask_worker.periodic_callbacks
        tick = callbacks.get("tick")
        info.update(nthreads=dask_worker.state.nthreads,
                    profile="profile" in callbacks,
                    tick_s=tick.callback_time / 1e3 if tick is not None else info["tick_s"],
                    host=dask_worker.address.rpartition(":")[0],
                    cores=len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
                    else os.cpu_count())
    return info


def lacking(info: dict[str, dict[str, Any]]) -> list[str]:
    """What the workers (worker_info of each) lack that nmtcheck cannot set from the
    client, each as a short clause; empty when nothing is."""
    out = []
    threads = sorted({int(i.get("nthreads", 1)) for i in info.values()})
    if threads[-1] > 1:
        out.append(f"workers with up to {threads[-1]} threads each: a check holds the GIL, "
                   "so a worker's threads share one core; start them with --nthreads 1 and "
                   "one worker process per core (--nworkers N)")
    unset = [what for what, bad in (
        (f"{MALLOC_ENV} set", any(i.get("malloc_trim") for i in info.values())),
        ("the profiler on", any(i.get("profile") for i in info.values())),
        ("an event loop tick under 1 s",
         any(float(i.get("tick_s") or 0) < TICK_S for i in info.values()))) if bad]
    if unset:  # the plugin failed on some worker: the settings stayed Dask's
        out.append(f"workers still have {', '.join(unset)} (nmtcheck's worker plugin could "
                   "not set them: 5-7x slower per log when measured)")
    return out


def traced(trace: str, key: Hashable, fn: Callable[..., Any], *args: Any) -> Any:
    """`fn(*args)` with the run's phase trace on in this worker (trace.py): the driver's
    NMTCHECK_FLEET_TRACE does not reach a worker of a running cluster."""
    from nmtcheck.fleet.trace import TRACE_ENV, mark

    before = os.environ.get(TRACE_ENV)
    os.environ[TRACE_ENV] = trace
    try:
        mark("task_start", key=repr(key))
        out = fn(*args)
        mark("task_end", key=repr(key))
        return out
    finally:
        if before is None:
            os.environ.pop(TRACE_ENV, None)
        else:
            os.environ[TRACE_ENV] = before
