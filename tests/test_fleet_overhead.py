"""Issue 25, a fleet run's fixed cost: local files without fsspec (storage.LocalFS answers as
fsspec's LocalFileSystem does), the fork server started by the command line before its own
imports (fleet/prestart.py), and what that must not break: processes left behind, the
phase trace the scaling bench reads."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from conftest import SAMPLES

pytest.importorskip("pyarrow")
fsspec = pytest.importorskip("fsspec")

from nmtcheck.fleet import prestart  # noqa: E402
from nmtcheck.fleet.storage import LocalFS, expand, filesystem, is_local  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
ENV = {**os.environ, "PYTHONPATH": str(REPO)}
LINUX = sys.platform.startswith("linux")


def tree(root: Path) -> Path:
    """Logs in nested folders, hidden names, a name with a space and brackets, a linked
    folder, an empty folder."""
    for rel in ("a.log", "b.LOG", ".hidden.log", "x1.log", "x22.log", "dev 1/s [1]/c.log",
                "DEV0/0001/a.log", "DEV0/0001/b.mf4", "DEV0/0002/deep/er/z.log",
                "DEV1/.cache/h.log", "DEV1/0001/a.log", "DEV2/a.log"):
        p = root / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_bytes(b"(1.0) can0 701#05\n" * (len(rel) + 1))
    (root / "empty").mkdir()
    if LINUX:
        (root / "linked").symlink_to(root / "DEV1", target_is_directory=True)
    return root


PATTERNS = ["*.log", "*", "**", "**/*.log", "*/*.log", "*/*/*.log", "DEV0/**", "DEV0/**/*.log",
            "**/0001/*.log", "DEV?/0001/*", "DEV[01]/*/a.log", "DEV[!0]/**", "x?.log",
            "x*.log", "dev 1/s [[]1]/*.log", "*/.cache/*", ".*", "**/er/*", "nothing/*.log",
            "linked/**/*.log", "[a-b].*"]


@pytest.mark.parametrize("pattern", PATTERNS)
def test_local_glob_matches_fsspec(tmp_path: Path, pattern: str) -> None:
    root = tree(tmp_path / "t")
    ours = LocalFS().glob(f"{root}/{pattern}", detail=True)
    theirs = fsspec.filesystem("file").glob(f"{root}/{pattern}", detail=True)
    assert list(ours) == list(theirs)
    keys = ("name", "size", "type", "mtime", "created", "islink")
    assert [[d[k] for k in keys] for d in ours.values()] == \
        [[d[k] for k in keys] for d in theirs.values()]
    assert pattern == "nothing/*.log" or ours  # every other pattern matches something here


def test_local_find_info_and_bad_patterns_as_fsspec(tmp_path: Path) -> None:
    root = tree(tmp_path / "t")
    ours, theirs = LocalFS(), fsspec.filesystem("file")
    assert ours.find(str(root)) == sorted(theirs.find(str(root)))
    for rel in ("a.log", "DEV0", "linked" if LINUX else "DEV1"):
        mine, ref = ours.info(f"{root}/{rel}"), theirs.info(f"{root}/{rel}")
        assert {k: mine[k] for k in mine} == {k: ref[k] for k in mine}
    with pytest.raises(FileNotFoundError):
        ours.info(f"{root}/missing.log")
    for bad in ("a**.log", "**b/*.log"):
        with pytest.raises(ValueError, match="entire path component"):
            theirs.glob(f"{root}/{bad}")
        with pytest.raises(ValueError, match="entire path component"):
            ours.glob(f"{root}/{bad}")


def test_local_paths_take_localfs_and_urls_fsspec(tmp_path: Path, monkeypatch: pytest.MonkeyPatch
                                                   ) -> None:
    from fsspec.core import split_protocol

    monkeypatch.chdir(tmp_path)
    for url in ("logs/a.log", "/abs/x", "file:///abs/x", "local:///x", "s3://b/k", "gs://b",
                "simplecache::s3://b/k", "data:text/plain,x", "C://x", "memory://x"):
        assert is_local(url) == (split_protocol(url)[0] in (None, "file", "local")), url
    fs, path = filesystem("results")
    assert isinstance(fs, LocalFS) and path == str(tmp_path / "results")
    fs, path = filesystem(f"file://{tmp_path}/results/")
    assert isinstance(fs, LocalFS) and path == str(tmp_path / "results")
    fs, _ = filesystem("results", {"auto_mkdir": True})  # options: fsspec's, as before
    assert not isinstance(fs, LocalFS)
    fs, _ = filesystem("memory://results")
    assert not isinstance(fs, LocalFS)


def test_expand_lists_local_logs_as_fsspec_did(tmp_path: Path, monkeypatch: pytest.MonkeyPatch
                                               ) -> None:
    """The listing a run checks (and the fingerprints its re-runs compare) is the same with
    LocalFS as with fsspec's local filesystem."""
    from nmtcheck.fleet import storage

    root = tree(tmp_path / "t")
    monkeypatch.chdir(tmp_path)
    sources = ["t/**/*.log", f"file://{root}/DEV0/**", str(root / "a.log")]
    ours = list(expand(sources, None, None))

    def fsspec_only(url: str, options: object = None) -> object:
        return fsspec.core.url_to_fs(url, **(options or {}))  # type: ignore[arg-type]

    monkeypatch.setattr(storage, "filesystem", fsspec_only)
    theirs = list(expand(sources, None, None))
    assert ours == theirs and len(ours) > 10
    assert all(fi.fingerprint.startswith("size:") for fi in ours)


@pytest.mark.parametrize(("args", "fleet"), [
    (["check", "l/*.log", "--results", "ds"], True),
    (["--debug", "check", "l/*.log", "--results=ds", "-j", "2"], True),
    (["check", "--executor", "local:2", "l", "--results", "ds"], True),
    (["check", "--executor=local", "--results", "s3://b/ds", "s3://b/*.log"], True),
    (["check", "l/*.log"], False),  # no dataset: `-j` forks from the CLI itself
    (["check", "l/*.log", "--results", "ds", "--executor", "dask-local:2"], False),
    (["check", "l/*.log", "--results", "ds", "--executor=dask://h:1"], False),
    (["check", "--", "--results"], False),  # a log of that name
    (["timeline", "--results", "ds"], False),
    ([], False),
])
def test_prestart_recognises_local_fleet_runs_only(args: list[str], fleet: bool) -> None:
    assert prestart.local_fleet_run(args) is fleet


def test_prestart_only_in_the_nmtcheck_command() -> None:
    assert prestart.is_command("/venv/bin/nmtcheck")
    assert prestart.is_command("/src/nmtcheck/__main__.py")
    assert not prestart.is_command("/venv/bin/pytest")
    assert not prestart.is_command("/src/other/__main__.py")
    assert not prestart.prestart(["/venv/bin/pytest", "check", "x", "--results", "ds"])
    assert prestart.is_remote("s3://b/k") and not prestart.is_remote("file:///x")
    assert not prestart.is_remote("logs/a.log") and not prestart.is_remote("C://x")


def _fleet_logs(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    logs.mkdir()
    for name in ("healthy.log", "heartbeat_loss.log", "guard_toggle.log"):
        shutil.copy(SAMPLES / name, logs / name)


def imported(importtime: str, module: str) -> int:
    """How many processes imported `module`, from their -X importtime lines (indented by
    the nesting of the import: a fork server forked mid-import goes on from its depth)."""
    return sum(line.rpartition("|")[2].strip() == module
               for line in importtime.splitlines() if line.startswith("import time:"))


def _trace(tmp_path: Path, *cmd: str
           ) -> tuple[subprocess.CompletedProcess[str], list[dict[str, Any]]]:
    path = tmp_path / "trace.jsonl"
    path.unlink(missing_ok=True)
    res = subprocess.run([sys.executable, *cmd], cwd=tmp_path, capture_output=True, text=True,
                         timeout=300, env={**ENV, "NMTCHECK_FLEET_TRACE": str(path)})
    marks = [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []
    return res, marks


@pytest.mark.skipif(not LINUX, reason="the fork server is POSIX")
def test_the_command_starts_the_fork_server_before_its_imports_and_traces_each_phase(
        tmp_path: Path) -> None:
    _fleet_logs(tmp_path)
    args = ("check", "logs/*.log", "--results", "ds", "--executor", "local:2", "-q")
    res, marks = _trace(tmp_path, "-m", "nmtcheck", *args)
    assert res.returncode == 1, res.stderr  # findings in heartbeat_loss.log
    driver = [m["phase"] for m in marks if m["phase"] in ("prestart", "cli", "run_fleet")]
    assert driver == ["prestart", "cli", "run_fleet"]  # one process: in this order
    phases = {m["phase"] for m in marks}
    assert {"preload", "worker", "task_start", "checked", "written", "task_end", "results",
            "drained", "closed", "run_row", "run_end"} <= phases
    [server] = {m["pid"] for m in marks if m["phase"] == "preload"}
    workers = {m["pid"] for m in marks if m["phase"] == "worker"}
    assert server not in workers and len(workers) <= 2
    # not the command (a program calling the CLI): the run starts the server itself
    res, marks = _trace(tmp_path, "-c", "from nmtcheck.cli.main import main; main()", *args,
                        "--force")
    assert res.returncode == 1, res.stderr
    assert "prestart" not in {m["phase"] for m in marks}
    assert {"preload", "task_start", "run_end"} <= {m["phase"] for m in marks}


@pytest.mark.skipif(not LINUX, reason="the fork server is POSIX")
def test_a_local_run_imports_fsspec_nowhere_a_storage_option_brings_it_back(
        tmp_path: Path) -> None:
    _fleet_logs(tmp_path)
    cmd = [sys.executable, "-X", "importtime", "-m", "nmtcheck", "check", "logs/*.log",
           "--results", "ds", "--executor", "local:2", "-q"]
    # -X importtime is passed on to the fork server (and so to its workers): every process
    # of the run writes its imports to this stderr
    res = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300,
                         env=ENV)
    assert res.returncode == 1, res.stderr[-2000:]
    assert imported(res.stderr, "nmtcheck.fleet.preload")  # the workers' imports are in there
    assert "fsspec" not in res.stderr
    rerun = subprocess.run([*cmd, "--storage-option", "auto_mkdir=true"], cwd=tmp_path,
                           capture_output=True, text=True, timeout=300, env=ENV)
    assert rerun.returncode == 1, rerun.stderr[-2000:]
    assert imported(rerun.stderr, "fsspec")
    assert "0 checked" in rerun.stdout or "3 already in the results" in rerun.stdout


def _session(sid: int) -> list[int]:
    out = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
            except OSError:
                continue
            fields = stat[stat.rindex(")") + 2:].split()
            if int(fields[3]) == sid and fields[0] != "Z":
                out.append(int(entry))
    return out


@pytest.mark.skipif(not LINUX, reason="reads /proc")
def test_a_run_refused_after_the_fork_server_started_leaves_no_process(tmp_path: Path) -> None:
    """prestart starts the fork server before the command line is even parsed: a run
    that then ends with a usage error must not leave it (or its tracker) behind."""
    proc = subprocess.Popen([sys.executable, "-m", "nmtcheck", "check", "nothing/*.log",
                             "--results", "ds", "--isolated"], cwd=tmp_path, env=ENV,
                            start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    try:
        _out, err = proc.communicate(timeout=120)
        assert proc.returncode == 2 and "no log file matches" in err, err
        deadline = time.monotonic() + 20
        while _session(proc.pid) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _session(proc.pid)
    finally:
        for pid in _session(proc.pid):
            os.kill(pid, 9)


BLAS_PROBE = ("import os, sys; sys.argv[0] = {argv0!r}; import nmtcheck.cli.main; "
              "print(os.environ.get('OPENBLAS_NUM_THREADS'), "
              "getattr(sys.modules['__main__'].__spec__, 'name', None))")


@pytest.mark.parametrize(("argv0", "given", "expected"), [
    ("/venv/bin/nmtcheck", None, "1 nmtcheck.__main__"),
    ("/venv/bin/nmtcheck", "3", "3 nmtcheck.__main__"),  # the user's choice stands
    ("/venv/bin/program", None, "None None"),  # a program that imports nmtcheck: untouched
])
def test_the_command_asks_for_one_blas_thread_and_runs_as_a_module(
        argv0: str, given: str | None, expected: str) -> None:
    env = {k: v for k, v in ENV.items() if k != "OPENBLAS_NUM_THREADS"}
    if given is not None:
        env["OPENBLAS_NUM_THREADS"] = given
    res = subprocess.run([sys.executable, "-c", BLAS_PROBE.format(argv0=argv0)],
                         capture_output=True, text=True, timeout=120, env=env)
    assert res.stdout.split() == expected.split(), res.stderr


@pytest.mark.skipif(not LINUX, reason="the fork server is POSIX")
def test_the_fork_server_has_one_blas_thread_and_the_program_keeps_its_environment() -> None:
    # numpy's OpenBLAS spins a thread per CPU for ~0.1 s of CPU at import: taken from the
    # workers beside it. A program running a fleet keeps its own environment.
    code = ("import os; from concurrent.futures import ProcessPoolExecutor; "
            "from nmtcheck.fleet.prestart import local_context; "
            "ctx = local_context(start=True); "
            "ex = ProcessPoolExecutor(1, mp_context=ctx); "
            "print(ex.submit(os.getenv, 'OPENBLAS_NUM_THREADS').result(), "
            "os.environ.get('OPENBLAS_NUM_THREADS')); ex.shutdown()")
    env = {k: v for k, v in ENV.items() if k != "OPENBLAS_NUM_THREADS"}
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, env=env)
    assert res.stdout.split() == ["1", "None"], res.stderr


CONSOLE_SCRIPT = """\
import re
import sys
from nmtcheck.cli.main import main
if __name__ == "__main__":
    sys.argv[0] = re.sub(r"(-script\\.pyw|\\.exe)?$", "", sys.argv[0])
    sys.exit(main())
"""


@pytest.mark.skipif(not LINUX, reason="the fork server is POSIX")
def test_workers_of_the_console_script_do_not_import_the_command_line_again(
        tmp_path: Path) -> None:
    # pip's console script runs as a __main__ without a spec; multiprocessing re-ran it in
    # every worker (importing click and the CLI: 30 ms each) until prestart gave it one
    _fleet_logs(tmp_path)
    script = tmp_path / "bin" / "nmtcheck"
    script.parent.mkdir()
    script.write_text(CONSOLE_SCRIPT)
    cmd = [sys.executable, "-X", "importtime", str(script), "check", "logs/*.log",
           "--results", "ds", "--executor", "local:2", "-q"]
    res = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=300,
                         env=ENV)
    assert res.returncode == 1, res.stderr[-2000:]
    assert imported(res.stderr, "nmtcheck.fleet.preload") == 1  # the server
    assert imported(res.stderr, "nmtcheck.cli.main") == 1  # the driver only


@pytest.mark.skipif(not LINUX, reason="the fork server is POSIX")
def test_the_fork_server_alone_ends_without_tearing_down_its_modules() -> None:
    # the server's copy of stderr held a caller that captures output 40 ms past the
    # driver's end while numpy and pyarrow were torn down
    ctx = prestart.local_context()
    from multiprocessing import forkserver

    assert forkserver._forkserver._preload_modules[-1] == prestart.SERVER_EXIT  # type: ignore[attr-defined]
    assert prestart.SERVER_EXIT not in sys.modules  # never in a process that checks
    code = ("import atexit; atexit.register(print, 'torn down'); "
            "import nmtcheck.fleet.server_exit; raise SystemExit(3)")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=60, env=ENV)
    assert (res.returncode, res.stdout, res.stderr) == (0, "", "")
    assert ctx.get_start_method() == "forkserver"


FORKED_HELPERS = """\
import os, sys, threading, time
from concurrent.futures import ProcessPoolExecutor
import multiprocessing
from multiprocessing import forkserver, resource_tracker
from nmtcheck.fleet import prestart

if sys.argv[1] == "thread":  # a thread is running: forking would be unsafe
    threading.Thread(target=time.sleep, args=(5,), daemon=True).start()
r, w = os.pipe()  # a descriptor of this program's that the helpers must not keep open
with prestart.forked_helpers(True):
    forkserver.ensure_running()
server = forkserver._forkserver._forkserver_pid
tracker = resource_tracker._resource_tracker._pid
with open("/proc/self/cmdline", "rb") as f:
    me = f.read()
def cmdline(pid):
    with open(f"/proc/{pid}/cmdline", "rb") as f:
        return f.read()
print("server", "forked" if cmdline(server) == me else "started")
print("tracker", "forked" if cmdline(tracker) == me else "started")
os.close(w)
import select
print("pipe", "closed" if select.select([r], [], [], 10)[0] and os.read(r, 1) == b"" else "open")
ctx = multiprocessing.get_context("forkserver")
lock = ctx.Lock()  # a named semaphore: registered with the resource tracker
with ProcessPoolExecutor(2, mp_context=ctx) as pool:
    pids = {f.result() for f in [pool.submit(os.getppid) for _ in range(4)]}
    # what a worker knows of the helpers: as a started server's workers (a free lock, the
    # tracker its driver's), not the driver's own records
    state = pool.submit(eval, "(__import__('multiprocessing.forkserver').forkserver"
                        "._forkserver._lock.locked(), __import__('multiprocessing."
                        "resource_tracker').resource_tracker._resource_tracker._pid)").result()
print("workers of the server", pids == {server})
print("worker state", state)
"""


@pytest.mark.skipif(not LINUX, reason="the fork server is POSIX; /proc")
@pytest.mark.parametrize("mode", ["alone", "thread"])
def test_the_commands_helper_processes_are_forked_not_started(mode: str) -> None:
    # An interpreter's start (0.05 s here, 0.08 s on a 16-core machine) was in the chain
    # before a fleet run's first task; a fork of the command at its start takes 1 ms. The
    # forked helpers must be what a started interpreter is: none of the program's
    # descriptors, workers that run, a resource tracker that has nothing to complain of.
    res = subprocess.run([sys.executable, "-c", FORKED_HELPERS, mode], capture_output=True,
                         text=True, timeout=120, env=ENV)
    assert res.returncode == 0, res.stderr
    how = "forked" if mode == "alone" else "started"
    assert res.stdout.split("\n")[:5] == [f"server {how}", f"tracker {how}", "pipe closed",
                                          "workers of the server True",
                                          "worker state (False, None)"]
    assert res.stderr == ""  # no traceback, no leaked-semaphore warning


FREED_MEMORY_PROBE = """
import resource, sys
import numpy as np
from nmtcheck.fleet.executors import keep_freed_memory
if sys.argv[1] == "keep":
    keep_freed_memory()
def faults():
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt
arrays = [np.ones(1 << 17) for _ in range(20)]  # 20 arrays of 1 MB, as a check's columns
del arrays
before = faults()
for _ in range(2):  # the next two logs
    arrays = [np.ones(1 << 17) for _ in range(20)]
    del arrays
print(faults() - before)
"""


@pytest.mark.skipif(not LINUX or not hasattr(os, "confstr")
                    or not os.confstr("CS_GNU_LIBC_VERSION"), reason="glibc's malloc only")
def test_a_pool_worker_keeps_what_it_frees_for_its_next_log() -> None:
    """A worker's columns came from fresh pages for every log (glibc handed them back):
    with keep_freed_memory (run by every pool worker) the next logs reuse them."""
    def faults(mode: str) -> int:
        out = subprocess.run([sys.executable, "-c", FREED_MEMORY_PROBE, mode], env=ENV,
                             capture_output=True, text=True, check=True)
        return int(out.stdout)

    assert faults("default") > 2000  # 40 MB again: about 10,000 pages faulted in anew
    assert faults("keep") < 500


def test_every_pool_worker_keeps_freed_memory(monkeypatch: pytest.MonkeyPatch) -> None:
    import signal

    from nmtcheck.fleet import executors

    called: list[bool] = []
    monkeypatch.setattr(executors, "keep_freed_memory", lambda: called.append(True))
    monkeypatch.setattr(executors, "_started", None)
    names = [n for n in ("SIGTERM", "SIGHUP", "SIGINT") if hasattr(signal, n)]
    handlers = {n: signal.getsignal(getattr(signal, n)) for n in names}
    try:
        executors._init_worker(None, None)  # as the pool runs it in each new worker
    finally:
        for n, handler in handlers.items():
            signal.signal(getattr(signal, n), handler)
    assert called == [True]
