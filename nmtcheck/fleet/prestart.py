"""The local pool's fork server, started as early as a fleet run can be recognised (issue 25).

The fork server imports what a task needs (nmtcheck.fleet.preload: 0.2 s of CPU) before it
can fork the first worker. Started when the driver reaches run_fleet, that import came
after the command line's own imports (0.16 s) and was waited for, serially. Imported by
nmtcheck/cli/main.py before its heavy imports, this module looks at the command line and, for
`nmtcheck check ... --results DS` with a local executor, starts the server at once: its
imports then run on another core while the driver imports, parses and lists. Anything it
cannot recognise it leaves to run_fleet (warm_up), which starts the server if needed.
At this point the command has one thread and almost nothing imported, so the server (and
the resource tracker before it) is forked from it rather than started as a new
interpreter (forked_helpers). It also asks numpy's BLAS for one thread in the `nmtcheck`
command (single_threaded_blas), before anything imports numpy. Only the standard library
here: the module is imported by every `nmtcheck` command.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator
from typing import Any

PRELOAD = "nmtcheck.fleet.preload"
PRELOAD_REMOTE = "fsspec"  # local files and datasets do without it (storage.LocalFS)
SERVER_EXIT = "nmtcheck.fleet.server_exit"  # last: the server ends at once (server_exit.py)
# numpy's OpenBLAS starts a thread per CPU as numpy is imported, and each spins for about
# 0.1 s of CPU before it sleeps: measured, 0.16 s of CPU to import numpy against 0.07 s
# with one BLAS thread. nmtcheck never multiplies matrices, so that CPU is taken from the
# checks running beside it (a fleet worker, `check -j`, xargs): 8 % of a 1 M-frame check.
SINGLE_BLAS = {"OPENBLAS_NUM_THREADS": "1"}


def single_threaded_blas(environ: Any = None) -> None:
    """Ask numpy's BLAS for one thread (no spinning helper threads) unless the user chose
    a number: for the `nmtcheck` command and the processes it starts, before numpy is
    imported. A program that imports nmtcheck keeps its own environment."""
    environ = os.environ if environ is None else environ
    for name, value in SINGLE_BLAS.items():
        environ.setdefault(name, value)


def _start_server(fork: bool = False) -> None:
    """Start the fork server with one BLAS thread (in its environment only: a program
    that runs a fleet through the Python API keeps its own for everything else); `fork`:
    fork it from this process instead of starting an interpreter (forked_helpers)."""
    from multiprocessing import forkserver

    added = [name for name in SINGLE_BLAS if name not in os.environ]
    single_threaded_blas()
    try:
        with forked_helpers(fork):
            forkserver.ensure_running()  # returns once started; the server imports meanwhile
    finally:
        if not is_command(sys.argv[0] if sys.argv else ""):
            for name in added:
                os.environ.pop(name, None)


@contextlib.contextmanager
def forked_helpers(fork: bool = True) -> Iterator[None]:
    """While this is active, multiprocessing's helper processes (the fork server and the
    resource tracker, which it starts first) are forked from this process instead of each
    starting a new interpreter: a fork takes a millisecond, an interpreter 0.05 s here and
    0.08 s on a 16-core machine, all of it in the chain before the first task. Only for the
    `nmtcheck` command at its start (prestart), before any thread or heavy import exists:
    the child then is what a fresh interpreter would be, plus the few modules imported so
    far. Anything unexpected (threads, another command form) starts the interpreter."""
    from multiprocessing import util

    spawn: Any = util.spawnv_passfds
    if not fork or not hasattr(os, "fork"):
        yield
        return

    def forked_spawnv_passfds(path: Any, args: Any, passfds: Any) -> int:
        import threading

        if len(args) < 2 or args[-2] != "-c" or threading.active_count() != 1:
            return int(spawn(path, args, passfds))
        return _fork_helper(args[-1], {0, 1, 2, *map(int, passfds)})

    util.spawnv_passfds = forked_spawnv_passfds
    try:
        yield
    finally:
        util.spawnv_passfds = spawn


def _fork_helper(code: str, keep: set[int]) -> int:
    """Fork a child that runs `code` (what the interpreter would have run with -c) with
    only the file descriptors `keep` open, as spawnv_passfds leaves them; its pid."""
    sys.stdout.flush()
    sys.stderr.flush()
    pid = os.fork()
    if pid:
        return pid
    status = 1
    try:
        _close_fds_except(keep)
        # multiprocessing's state as a fresh interpreter has it: the parent's fork server
        # and resource tracker records (and a held lock) are the parent's, not this child's
        from multiprocessing import forkserver, resource_tracker

        forkserver._forkserver.__init__()  # type: ignore[misc]
        resource_tracker._resource_tracker.__init__()  # type: ignore[misc]
        sys.modules.pop("nmtcheck.cli.main", None)  # half imported here: never the workers'
        exec(code, {"__name__": "__main__", "__builtins__": __builtins__})
        status = 0
    except SystemExit as exc:  # the fork server ends so when its last client has gone
        status = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except BaseException:  # noqa: BLE001 - as the interpreter would: say why, exit 1
        import traceback

        traceback.print_exc()
    finally:
        os._exit(status)


def _close_fds_except(keep: set[int]) -> None:
    """Close every open file descriptor not in `keep` (spawnv_passfds's close_fds)."""
    for where in ("/proc/self/fd", "/dev/fd"):
        try:
            open_fds = [int(name) for name in os.listdir(where)]
        except (OSError, ValueError):
            continue
        for fd in open_fds:
            if fd not in keep:
                with contextlib.suppress(OSError):  # the listing's own, already closed
                    os.close(fd)
        return
    last = 3
    for fd in sorted(f for f in keep if f >= 3):
        os.closerange(last, fd)
        last = fd + 1
    os.closerange(last, os.sysconf("SC_OPEN_MAX") if hasattr(os, "sysconf") else 65536)


def local_context(start: bool = False, remote: bool = False, fork: bool = False) -> Any:
    """The local pool's start method: a fork server that has imported what a task needs
    (nmtcheck.fleet.preload, and fsspec for a run with `remote` URLs), so that each worker
    is forked from it ready to check; `start` starts that server now, in the background
    (its imports overlap the driver's work). The first start decides what is preloaded."""
    import multiprocessing

    if "forkserver" not in multiprocessing.get_all_start_methods():  # Windows
        return multiprocessing.get_context("spawn")
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload([PRELOAD, PRELOAD_REMOTE, SERVER_EXIT] if remote
                               else [PRELOAD, SERVER_EXIT])
    if start:
        _start_server(fork)
    return ctx


def is_command(argv0: str) -> bool:
    """This process is the `nmtcheck` command (the console script or `python -m nmtcheck`),
    not a program or test that imports nmtcheck."""
    name = os.path.basename(argv0)
    return name == "nmtcheck" or (name == "__main__.py"
                                  and os.path.basename(os.path.dirname(argv0)) == "nmtcheck")


def is_remote(url: str) -> bool:
    """A URL with a protocol other than file:// (storage.is_local's answer, cheaper)."""
    protocol, sep, _ = url.partition("://")
    return bool(sep) and len(protocol) > 1 and protocol not in ("file", "local")


def local_fleet_run(args: list[str]) -> bool:
    """`args` (the command line after the program) ask for a fleet run on the local pool:
    `check` with --results, and no --executor or a local[:N] one."""
    while args and args[0] == "--debug":  # the group's only option
        args = args[1:]
    if not args or args[0] != "check":
        return False
    results = False
    executor = "local"
    it = iter(args[1:])
    for arg in it:
        if arg == "--":
            break
        name, eq, value = arg.partition("=")
        if name == "--results":
            results = True
            if not eq:
                next(it, None)
        elif name == "--executor":
            executor = value if eq else next(it, "")
    return results and executor.partition(":")[0] == "local"


def prestart(argv: list[str] | None = None) -> bool:
    """Start the fork server now if this process is `nmtcheck check --results ...` on the
    local pool; whether it did. Never fails the command: run_fleet starts it otherwise."""
    fork = argv is None  # the command itself, at its start: nothing else runs in it yet
    argv = sys.argv if argv is None else argv
    if not argv or not is_command(argv[0]) or not local_fleet_run(list(argv[1:])):
        return False
    try:
        local_context(start=True, remote=any(is_remote(a.partition("=")[2] or a)
                                             for a in argv[1:]), fork=fork)
    except Exception:  # noqa: BLE001 - an optimisation only: the run starts it again or says why
        return False
    from nmtcheck.fleet.trace import mark

    mark("prestart")
    return True


def main_as_module() -> None:
    """The `nmtcheck` console script runs as a __main__ without a module spec, so the fork
    server's workers each ran it again (multiprocessing does that for a script's main) and
    imported the command line with it: 30 ms of CPU per worker before its first task. The
    workers need nothing of it; give it the spec `python -m nmtcheck` has, whose main
    multiprocessing leaves alone."""
    main = sys.modules.get("__main__")
    if main is not None and getattr(main, "__spec__", None) is None:
        from importlib.machinery import ModuleSpec

        main.__spec__ = ModuleSpec("nmtcheck.__main__", None)


if is_command(sys.argv[0] if sys.argv else ""):
    single_threaded_blas()
    main_as_module()
prestart()
