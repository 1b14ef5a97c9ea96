"""Fleet runs on a real Dask cluster: a module-wide `distributed.LocalCluster` of worker
processes, reached as `--executor dask://HOST:PORT` by the real command line, with a log
that kills its worker every time (the test-only NMTCHECK_TEST_CRASH hook: os._exit)."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import SAMPLES, cluster_process

pytest.importorskip("pyarrow")
distributed = pytest.importorskip("distributed")
import pandas as pd  # noqa: E402

import nmtcheck  # noqa: E402

LOGS = ["heartbeat_loss.log", "healthy.log", "guard_toggle.log", "reset_no_bootup.log"]


CLUSTER = """
import sys, dask, distributed
with dask.config.set({"distributed.scheduler.allowed-failures": 1}):
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                       dashboard_address=":0", silence_logs=50,
                                       env={"NMTCHECK_TEST_CRASH": "CRASHME"})
print(cluster.scheduler_address, flush=True)
sys.stdin.read()  # until the tests are done
cluster.close()
"""


@pytest.fixture(scope="module")
def scheduler() -> Iterator[str]:
    """Two single-threaded worker processes with Dask's default worker settings; a worker
    dies on any log whose name holds CRASHME, and the scheduler gives a task 2 tries.

    The cluster and every Dask client live in other processes: a client leaves threads
    running in its process for good, and this test process forks (other tests check
    the forked parse worker, which is not started while other threads run)."""
    with cluster_process(CLUSTER) as address:
        yield address


def run_py(code: str, *args: str) -> str:
    """`code` in a fresh Python (see `scheduler`); its standard output."""
    res = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True,
                         timeout=300)
    assert res.returncode == 0, res.stderr
    return res.stdout


def cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "nmtcheck", *args], cwd=cwd, text=True,
                          capture_output=True, timeout=300)


def test_dask_cluster_run_retries_then_marks_the_crashing_log(scheduler: str,
                                                              tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    logs.mkdir()
    for name in LOGS:
        shutil.copy(SAMPLES / name, logs / name)
    shutil.copy(SAMPLES / "healthy.log", logs / "CRASHME.log")
    address = "dask://" + scheduler.removeprefix("tcp://")
    res = cli("check", "logs/*.log", "--results", "dask-results", "--executor", address,
              "--isolated", cwd=tmp_path)
    assert res.returncode == 2, res.stdout + res.stderr  # a log that was not checked
    assert "5 logs: 5 checked" in res.stdout and "crashed 1" in res.stdout
    # the cluster has Dask's defaults that slow nmtcheck down: the run set its own on the
    # workers, those that replaced the workers the crashing log killed included
    assert "nmtcheck: warning" not in res.stderr, res.stderr
    assert [(i["malloc_trim"], i["profile"], i["tick_s"], i["nthreads"])
            for i in workers_info(scheduler)] == [(None, False, 1.0, 1)] * 2

    data = nmtcheck.read_results(tmp_path / "dask-results").inputs.set_index("url")
    crashme = str(logs / "CRASHME.log")
    assert data.loc[crashme, "status"] == "crashed"
    assert data.loc[crashme, "attempts"] == 2
    assert "Dask worker died" in data.loc[crashme, "error"]
    assert (data.drop(crashme)["status"] == "ok").all()

    # the same findings as the local pool's
    (logs / "CRASHME.log").unlink()
    local = cli("check", "logs/*.log", "--results", "local-results", "--isolated", cwd=tmp_path)
    assert local.returncode == 1

    def findings(where: str) -> list[tuple[str, str, object, float]]:
        f = nmtcheck.read_results(tmp_path / where).findings
        return sorted((r.url, r.rule, -1 if r.node is pd.NA else r.node, r.time)
                      for r in f.itertuples())

    assert findings("dask-results") == findings("local-results") != []


def workers_info(address: str) -> list[dict[str, object]]:
    """worker_info of each worker of the cluster at `address`, in address order."""
    out = run_py("""
import json, sys, distributed
from nmtcheck.fleet.dask_workers import worker_info
with distributed.Client(sys.argv[1], timeout="20s") as client:
    info = client.run(worker_info)
print(json.dumps([info[k] for k in sorted(info)]))
""", address)
    return list(json.loads(out.strip().splitlines()[-1]))


def test_dask_local_starts_workers_without_the_slow_defaults() -> None:
    # a nanny sets its pre-spawn variables in its own process: the module's cluster's did
    out = run_py("""
import json, os
os.environ.pop("MALLOC_TRIM_THRESHOLD_", None)
from nmtcheck.fleet.executors import make_executor
from nmtcheck.fleet.dask_workers import worker_info
ex = make_executor("dask-local:1")
try:
    print(json.dumps([ex.name, ex.slots, list(ex.client.run(worker_info).values())]))
finally:
    ex.close()
""")
    name, slots, info = json.loads(out.strip().splitlines()[-1])
    assert (name, slots) == ("dask-local:1", 1)
    assert len(info) == 1
    assert {k: info[0][k] for k in ("nmtcheck", "malloc_trim", "profile", "tick_s", "nthreads")
            } == {"nmtcheck": nmtcheck.__version__, "malloc_trim": None, "profile": False,
                  "tick_s": 1.0, "nthreads": 1}
    assert info[0]["applied"] == {"malloc": True, "loop": True}


def test_client_worker_version_skew_is_a_usage_error(scheduler: str) -> None:
    out = run_py("""
import sys
import nmtcheck
nmtcheck.__version__ = "0.0.0-client"
from nmtcheck.errors import UsageError
from nmtcheck.fleet.executors import make_executor
try:
    make_executor(sys.argv[1])
    print("no error")
except UsageError as exc:
    print(f"UsageError: {exc}")
""", "dask://" + scheduler.removeprefix("tcp://"))
    assert re.search(r"UsageError: .*the workers run nmtcheck .*this client 0\.0\.0", out), out
