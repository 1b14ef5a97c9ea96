"""A fleet on a running Dask cluster started the way docs/guides/fleet.md says (issue 40):
`dask scheduler`, then `dask worker ADDRESS --nworkers 2 --nthreads 1`, with Dask's
default worker settings, no preload and no environment variables. nmtcheck sets its worker
settings from the client; the dataset must equal the local pool's."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import SAMPLES, cluster_process

pytest.importorskip("pyarrow")
distributed = pytest.importorskip("distributed")
import pandas as pd  # noqa: E402

import nmtcheck  # noqa: E402
from nmtcheck.fleet.dask_workers import TICK_S, lacking  # noqa: E402

DASK = Path(sys.executable).with_name("dask")
# recordings of real stacks (python-canopen) and the hand-made samples
LOGS = [*sorted((SAMPLES / "canopen_master").glob("*.log")),
        *(SAMPLES / n for n in ("healthy.log", "heartbeat_loss.log", "reset_no_bootup.log",
                                "sdo_config.log", "pdo_preop.log"))]
RUN_COLUMNS = {"run_id", "checked_at", "seconds", "batch_id"}  # differ from run to run


def _stop(proc: subprocess.Popen[bytes]) -> None:
    """End a process this test started, and its children (its own session)."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


@pytest.fixture(scope="module")
def running_cluster(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """A loopback scheduler and two single-threaded worker processes, as a user starts
    them; the scheduler's address (tcp://127.0.0.1:PORT)."""
    if not DASK.exists():
        pytest.skip("no dask command next to this Python")
    where = tmp_path_factory.mktemp("cluster")
    info = where / "scheduler.json"
    env = {k: v for k, v in os.environ.items() if not k.startswith("DASK_")}
    env["DASK_TEMPORARY_DIRECTORY"] = str(where)
    log = open(where / "cluster.log", "wb")  # noqa: SIM115 - closed at teardown
    procs = [subprocess.Popen([str(DASK), "scheduler", "--host", "127.0.0.1", "--port", "0",
                               "--dashboard-address", ":0", "--scheduler-file", str(info)],
                              stdout=log, stderr=log, env=env, start_new_session=True)]
    try:
        deadline = time.monotonic() + 60
        while not info.exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        address = json.loads(info.read_text())["address"]
        procs.append(subprocess.Popen([str(DASK), "worker", address, "--nworkers", "2",
                                       "--nthreads", "1", "--dashboard-address", ":0"],
                                      stdout=log, stderr=log, env=env, start_new_session=True))
        out = subprocess.run([sys.executable, "-c", """
import sys, distributed
with distributed.Client(sys.argv[1], timeout="60s") as client:
    client.wait_for_workers(2, timeout=120)
""", address], capture_output=True, text=True, timeout=180)
        assert out.returncode == 0, out.stderr
        yield address
    finally:
        for proc in reversed(procs):
            _stop(proc)
        log.close()


def cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "nmtcheck", *args], cwd=cwd, text=True,
                          capture_output=True, timeout=600)


def tables(results: Path) -> dict[str, pd.DataFrame]:
    """Every table of a results dataset but the runs', without the per-run columns, in a
    fixed row order."""
    res = nmtcheck.read_results(results)
    out = {}
    for f in dataclasses.fields(res):
        df = getattr(res, f.name)
        if not isinstance(df, pd.DataFrame) or f.name == "runs":
            continue
        df = df.drop(columns=[c for c in RUN_COLUMNS if c in df.columns])
        cols = sorted(df.columns)
        df = df[cols].astype(str).sort_values(cols).reset_index(drop=True)
        out[f.name] = df
    return out


def test_running_cluster_gives_the_local_pools_dataset(running_cluster: str,
                                                       tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    logs.mkdir()
    for src in LOGS:
        shutil.copy(src, logs / f"{src.parent.name}-{src.name}")
    address = "dask://" + running_cluster.removeprefix("tcp://")
    remote = cli("check", "logs/*.log", "--results", "dask-results", "--executor", address,
                 "--isolated", cwd=tmp_path)
    local = cli("check", "logs/*.log", "--results", "local-results", "--executor", "local:2",
                "--isolated", cwd=tmp_path)
    assert remote.returncode == local.returncode == 1, remote.stderr + local.stderr
    # Dask's defaults on the workers, which nmtcheck set right: nothing to warn about
    assert remote.stderr == "", remote.stderr
    assert f"{len(LOGS)} logs: {len(LOGS)} checked" in remote.stdout
    def verdict(out: str) -> list[str]:  # the counts, not the dataset's name or the run's
        return [line for line in out.splitlines() if "-results" not in line]

    assert verdict(remote.stdout) == verdict(local.stdout) != []
    got, want = tables(tmp_path / "dask-results"), tables(tmp_path / "local-results")
    assert set(got) == set(want) and len(want["findings"]) > 0 and len(want["boot"]) > 0
    for name in want:
        pd.testing.assert_frame_equal(got[name], want[name], obj=name)
    runs = nmtcheck.read_results(tmp_path / "dask-results").runs
    assert runs["executor"].tolist() == [address]


def test_running_cluster_workers_get_nmtchecks_settings(running_cluster: str) -> None:
    """After a run (the previous test, or this one's executor): every worker has the
    settings."""
    code = """
import json, sys, distributed
from nmtcheck.fleet.executors import make_executor
from nmtcheck.fleet.dask_workers import worker_info
ex = make_executor(sys.argv[1])
try:
    info = ex.client.run(worker_info)
    print(json.dumps([ex.slots, [info[k] for k in sorted(info)]]))
finally:
    ex.close()
"""
    out = subprocess.run([sys.executable, "-c", code,
                          "dask://" + running_cluster.removeprefix("tcp://")],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0 and out.stderr == "", out.stderr
    slots, info = json.loads(out.stdout.strip().splitlines()[-1])
    assert slots == 2
    assert [(i["malloc_trim"], i["profile"], i["tick_s"], i["applied"]) for i in info] == [
        (None, False, TICK_S, {"malloc_env_removed": True, "malloc": True, "loop": True})] * 2


THREADED = """
import sys, distributed
cluster = distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=True,
                                   dashboard_address=":0", silence_logs=50)
print(cluster.scheduler_address, flush=True)
sys.stdin.read()
cluster.close()
"""


def test_workers_with_threads_are_named_in_one_line(tmp_path: Path) -> None:
    """Workers of 2 threads share a core per process: the run says in one line how to start
    workers that use the cores; the dataset is still complete."""
    logs = tmp_path / "logs"
    logs.mkdir()
    for name in ("healthy.log", "heartbeat_loss.log", "reset_no_bootup.log"):
        shutil.copy(SAMPLES / name, logs / name)
    with cluster_process(THREADED) as address:
        res = cli("check", "logs/*.log", "--results", "ds", "--executor",
                  "dask://" + address.removeprefix("tcp://"), "--isolated", cwd=tmp_path)
    assert res.returncode == 1, res.stderr
    assert "3 logs: 3 checked" in res.stdout
    warning = [line for line in res.stderr.splitlines() if "nmtcheck: warning" in line]
    assert len(warning) == 1 and len(res.stderr.splitlines()) == 1, res.stderr
    assert "workers with up to 2 threads each: a check holds the GIL" in warning[0]
    assert "--nthreads 1" in warning[0] and "--nworkers N" in warning[0]
    assert len(nmtcheck.read_results(tmp_path / "ds").inputs) == 3


def test_lacking_names_only_what_the_plugin_cannot_set() -> None:
    good = {"nthreads": 1, "malloc_trim": None, "profile": False, "tick_s": 1.0}
    assert lacking({"a": good, "b": good}) == []
    threaded = lacking({"a": good, "b": {**good, "nthreads": 4}})
    assert len(threaded) == 1 and "up to 4 threads" in threaded[0]
    untouched = lacking({"a": {**good, "malloc_trim": "65536", "profile": True,
                               "tick_s": 0.02}})
    assert untouched == ["workers still have MALLOC_TRIM_THRESHOLD_ set, the profiler on, an "
                         "event loop tick under 1 s (nmtcheck's worker plugin could not set "
                         "them: 5-7x slower per log when measured)"]


@pytest.mark.skipif(not hasattr(os, "confstr") or not os.confstr("CS_GNU_LIBC_VERSION"),
                    reason="glibc's malloc only")
def test_keep_freed_memory_undoes_dasks_malloc_trim_threshold() -> None:
    """A Dask worker starts with MALLOC_TRIM_THRESHOLD_=65536, which glibc reads at start:
    the mallopt calls the worker plugin makes afterwards still keep freed columns."""
    from test_fleet_overhead import ENV, FREED_MEMORY_PROBE

    def faults(mode: str) -> int:
        out = subprocess.run([sys.executable, "-c", FREED_MEMORY_PROBE, mode],
                             env={**ENV, "MALLOC_TRIM_THRESHOLD_": "65536"},
                             capture_output=True, text=True, check=True)
        return int(out.stdout)

    assert faults("default") > 2000  # Dask's setting: every log's columns faulted in anew
    assert faults("keep") < 500


def test_a_short_listing_is_cut_to_the_running_clusters_workers() -> None:
    """On `dask://` only the started executor knows how many workers there are: 8 logs on
    a cluster of 4 worker threads make 4 batches (the client's own core count does not
    count), and an empty listing starts no executor."""
    from nmtcheck.fleet.run import _batches, _slots
    from nmtcheck.fleet.storage import FileInfo

    assert _slots("dask://scheduler:8786") is None and _slots("local:3") == 3
    started: list[int] = []

    def workers() -> int:
        started.append(4)
        return 4

    files = [FileInfo(f"log{i}.log", size=100) for i in range(8)]
    batches = list(_batches(iter(files), 32, 64 << 20, workers))
    assert [len(b) for b in batches] == [2, 2, 2, 2] and started == [4]
    assert [fi for b in batches for fi in b] == files
    assert list(_batches(iter([]), 32, 64 << 20, workers)) == [] and started == [4]


NO_NMTCHECK = """
import sys, distributed
cluster = distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                   dashboard_address=":0", silence_logs=50)
print(cluster.scheduler_address, flush=True)
sys.stdin.read()
cluster.close()
"""


def test_workers_without_nmtcheck_are_a_one_line_usage_error(tmp_path: Path) -> None:
    """Workers whose Python has Dask but not nmtcheck (started with -S and a copy of Dask's
    site-packages made of links to everything but nmtcheck: no .pth file, no nmtcheck,
    whether it is installed in place or as a wheel): exit 2, one line."""
    site = Path(distributed.__file__).resolve().parent.parent
    without = tmp_path / "site-packages"
    without.mkdir()
    for entry in site.iterdir():
        if not entry.name.lower().startswith(("nmtcheck", "__editable__")):
            (without / entry.name).symlink_to(entry)
    env = {**os.environ, "PYTHONPATH": str(without)}
    shutil.copy(SAMPLES / "healthy.log", tmp_path / "healthy.log")
    proc = subprocess.Popen([sys.executable, "-S", "-c", NO_NMTCHECK], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True, env=env, cwd=tmp_path)
    assert proc.stdout is not None and proc.stdin is not None
    try:
        address = proc.stdout.readline().strip()
        res = cli("check", "healthy.log", "--results", "ds", "--executor",
                  "dask://" + address.removeprefix("tcp://"), "--isolated", cwd=tmp_path)
    finally:
        proc.stdin.close()
        proc.wait(timeout=60)
    assert res.returncode == 2 and len(res.stderr.splitlines()) == 1, res.stderr
    assert "a worker cannot run nmtcheck" in res.stderr
    assert "No module named 'nmtcheck'" in res.stderr and "Traceback" not in res.stderr
