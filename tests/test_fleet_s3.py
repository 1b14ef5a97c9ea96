"""Fleet runs against a real S3-protocol server: moto's ThreadedMotoServer over HTTP, read
and written through s3fs with `--storage-option endpoint_url=...` and credentials from the
environment only."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from conftest import SAMPLES, cluster_process, shared_path

pytest.importorskip("pyarrow")
s3fs = pytest.importorskip("s3fs")
moto_server = pytest.importorskip("moto.server")

import nmtcheck  # noqa: E402

BUCKET = "fleet-logs"
CREDENTIALS = {"AWS_ACCESS_KEY_ID": "fleet-test-key", "AWS_SECRET_ACCESS_KEY": "fleet-test-secret",
               "AWS_DEFAULT_REGION": "us-east-1"}
MF4 = "corpus/third_party/css-electronics/2F6913DB_00000004_00000001.MF4"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="module")
def endpoint() -> Iterator[str]:
    port = _free_port()
    server = moto_server.ThreadedMotoServer(ip_address="127.0.0.1", port=port, verbose=False)
    server.start()
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.stop()
        _stop_fsspec_io_thread()


def _stop_fsspec_io_thread() -> None:
    """s3fs runs on fsspec's event loop in a thread of its own, which lives as long as the
    process; stop it (and the loop's resolver threads) so that later tests in this process
    may fork (nmtcheck's parse worker is never forked while other threads run)."""
    import fsspec.asyn

    loop, thread = fsspec.asyn.loop[0], fsspec.asyn.iothread[0]
    if loop is None or thread is None:
        return
    loop.call_soon_threadsafe(loop.stop)
    thread.join(timeout=10)
    loop.run_until_complete(loop.shutdown_default_executor())
    loop.close()
    fsspec.asyn.loop[0] = fsspec.asyn.iothread[0] = None


@pytest.fixture
def s3(endpoint: str, monkeypatch: pytest.MonkeyPatch) -> Any:
    for k, v in CREDENTIALS.items():
        monkeypatch.setenv(k, v)
    fs = s3fs.S3FileSystem(endpoint_url=endpoint, skip_instance_cache=True)
    if fs.exists(BUCKET):
        fs.rm(BUCKET, recursive=True)
    fs.mkdir(BUCKET)
    return fs


def cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "nmtcheck", *args], cwd=cwd, text=True,
                          capture_output=True, timeout=300, env={**os.environ, **CREDENTIALS})


def objects(fs: Any, prefix: str) -> dict[str, tuple[str, object]]:
    fs.invalidate_cache()
    return {p: (i["ETag"], i["LastModified"]) for p, i in fs.find(prefix, detail=True).items()}


def test_s3_fleet_run_incremental_and_manifest(s3: Any, endpoint: str, tmp_path: Path) -> None:
    for i, name in enumerate(["heartbeat_loss.log", "healthy.log", "guard_toggle.log"]):
        s3.put_file(str(SAMPLES / name), f"{BUCKET}/2026/DEV{i % 2}/0000000{i}/00000001.log")
    s3.pipe(f"{BUCKET}/2026/DEV1/00000009/00000001.log", b"\xff\xfe garbage, no CAN log\n")
    s3.pipe(f"{BUCKET}/2026/DEV1/00000009/00000002.MFE", b"encrypted")
    mf4 = shared_path(MF4)
    if mf4 is not None:
        s3.put_file(str(mf4), f"{BUCKET}/2026/2F6913DB/00000004/00000001.MF4")
    common = ("--results", f"s3://{BUCKET}/nmtcheck/", "--storage-option",
              f"endpoint_url={endpoint}", "--path-pattern", "{device}/{session}/{split}.log",
              "--isolated", "--fail-on", "never", "--on-input-error", "continue")
    res = cli("check", f"s3://{BUCKET}/2026/**", *common, cwd=tmp_path)
    n = 6 if mf4 is not None else 5
    assert res.returncode == 0, res.stdout + res.stderr
    assert f"{n} logs: {n} checked" in res.stdout
    assert "input_error 1" in res.stdout and "unsupported 1" in res.stdout
    assert "fleet-test-secret" not in res.stdout + res.stderr

    data = nmtcheck.read_results(f"s3://{BUCKET}/nmtcheck/",
                                 storage_options={"endpoint_url": endpoint})
    inputs = data.inputs.set_index("url")
    hb = inputs.loc[f"s3://{BUCKET}/2026/DEV0/00000000/00000001.log"]
    assert (hb["status"], hb["device"], hb["session"], hb["split"]) == \
        ("ok", "DEV0", "00000000", "00000001")
    assert hb["etag"] and hb["fingerprint"] == f"etag:{hb['etag']}"
    assert hb["size"] == (SAMPLES / "heartbeat_loss.log").stat().st_size
    assert inputs.loc[f"s3://{BUCKET}/2026/DEV1/00000009/00000001.log", "status"] == \
        "input_error"
    assert set(data.findings[data.findings["url"].str.contains("DEV0/00000000")]["rule"]) \
        >= {"H001"}
    if mf4 is not None:
        row = inputs.loc[f"s3://{BUCKET}/2026/2F6913DB/00000004/00000001.MF4"]
        assert (row["status"], row["format"]) == ("ok", "mf4") and row["frames"] > 0

    before = objects(s3, f"{BUCKET}/nmtcheck")
    again = cli("check", f"s3://{BUCKET}/2026/**", *common, cwd=tmp_path)
    assert "0 checked" in again.stdout and f"{n} already in the results" in again.stdout
    assert objects(s3, f"{BUCKET}/nmtcheck") == before  # nothing written

    # a manifest (an S3 Inventory CSV) naming one old and one new object
    s3.put_file(str(SAMPLES / "reset_no_bootup.log"), f"{BUCKET}/2027/DEV3/00000001/00000001.log")
    (tmp_path / "inventory.csv").write_text(
        f'"{BUCKET}","2026/DEV1/00000001/00000001.log","",""\n'
        f'"{BUCKET}","2027/DEV3/00000001/00000001.log","",""\n')
    third = cli("check", "--manifest", "inventory.csv", *common, cwd=tmp_path)
    assert "2 logs: 1 checked" in third.stdout, third.stdout + third.stderr
    new = set(objects(s3, f"{BUCKET}/nmtcheck")) - set(before)
    assert {p.split("/")[2] for p in new} == {"inputs", "findings", "node_stats", "runs"}


DASK_CLUSTER = """
import sys, dask, distributed
with dask.config.set({"distributed.scheduler.allowed-failures": 1}):
    cluster = distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                       dashboard_address=":0", silence_logs=50)
print(cluster.scheduler_address, flush=True)
sys.stdin.read()  # until the test is done
cluster.close()
"""


def _fetched_copies(root: Path) -> list[Path]:
    """What fleet tasks fetched (or the directories they fetched into) below `root`."""
    return [p for p in root.rglob("*") if p.name.startswith("nmtcheck-fleet-")
            or p.name.endswith("CRASHME.log")]


def test_dask_worker_that_dies_leaves_no_fetched_logs(s3: Any, endpoint: str,
                                                      tmp_path: Path) -> None:
    """A Dask worker killed in the middle of a batch (the OOM killer, a crash; here the
    test-only NMTCHECK_TEST_CRASH hook, after the batch's logs were fetched) cannot remove
    what it fetched: the copies go below the worker's own directory, which the next
    worker to start removes, not into /tmp for good."""
    pytest.importorskip("distributed")
    s3.put_file(str(SAMPLES / "healthy.log"), f"{BUCKET}/crash/healthy.log")
    s3.put_file(str(SAMPLES / "healthy.log"), f"{BUCKET}/crash/CRASHME.log")
    temp = tmp_path / "tmp"
    temp.mkdir()
    env = {**os.environ, **CREDENTIALS, "TMPDIR": str(temp), "NMTCHECK_TEST_CRASH": "CRASHME"}
    with cluster_process(DASK_CLUSTER, env) as address:
        assert address, "the Dask cluster did not start"
        res = cli("check", f"s3://{BUCKET}/crash/*.log", "--results", str(tmp_path / "ds"),
                  "--executor", f"dask://{address.removeprefix('tcp://')}",
                  "--storage-option", f"endpoint_url={endpoint}", "--fail-on", "never",
                  "--on-input-error", "continue", cwd=tmp_path)
        assert res.returncode == 0, res.stdout + res.stderr
        assert "crashed 1" in res.stdout, res.stdout
        # the worker that died last is removed when the nanny's next worker starts
        deadline = time.monotonic() + 30
        while _fetched_copies(temp) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert _fetched_copies(temp) == []
        assert list(temp.glob("dask-scratch-space*")), "the workers used another directory"


def test_check_reads_a_log_from_s3_without_results(s3: Any, endpoint: str,
                                                    tmp_path: Path) -> None:
    """`nmtcheck check s3://...` (no --results): the object is fetched to a temporary copy,
    checked as the local file is, and named by its URL in every report; the copy goes."""
    s3.put_file(str(SAMPLES / "heartbeat_loss.log"), f"{BUCKET}/single/heartbeat_loss.log")
    s3.put_file(str(SAMPLES / "healthy.log"), f"{BUCKET}/single/healthy.log")
    s3.pipe(f"{BUCKET}/single/garbage.txt", b"\xff\xfe no CAN log here\n")
    temp = tmp_path / "tmp"
    temp.mkdir()

    def run(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "nmtcheck", "check", *args,
                               "--storage-option", f"endpoint_url={endpoint}", "--isolated"],
                              cwd=tmp_path, text=True, capture_output=True, timeout=300,
                              env={**os.environ, **CREDENTIALS, "TMPDIR": str(temp)})

    url = f"s3://{BUCKET}/single/heartbeat_loss.log"
    remote = run(url, "--format", "json")
    local = subprocess.run([sys.executable, "-m", "nmtcheck", "check", "--isolated",
                            str(SAMPLES / "heartbeat_loss.log"), "--format", "json"],
                           text=True, capture_output=True, timeout=300)
    assert remote.returncode == local.returncode == 1, remote.stderr
    got, want = json.loads(remote.stdout), json.loads(local.stdout)
    assert [i["path"] for i in got["inputs"]] == [url]
    assert [(f["rule"], f["node"], f["time"], f["message"]) for f in got["findings"]] == \
        [(f["rule"], f["node"], f["time"], f["message"]) for f in want["findings"]]
    assert "H001" in {f["rule"] for f in got["findings"]}

    both = run(f"s3://{BUCKET}/single/*.log", "--format", "text")
    assert both.returncode == 1, both.stderr
    assert f"s3://{BUCKET}/single/healthy.log" in both.stdout and url in both.stdout

    missing = run(f"s3://{BUCKET}/single/missing.log")
    assert missing.returncode == 2
    assert missing.stderr.strip() == f"nmtcheck: s3://{BUCKET}/single/missing.log: no such file"
    garbage = run(f"s3://{BUCKET}/single/garbage.txt")
    assert garbage.returncode == 2
    assert garbage.stderr.startswith(f"nmtcheck: s3://{BUCKET}/single/garbage.txt: "), \
        garbage.stderr
    assert str(temp) not in garbage.stderr + garbage.stdout
    assert list(temp.iterdir()) == []  # every fetched copy is gone


def test_a_fetched_copy_is_never_named_by_its_temporary_path(s3: Any, endpoint: str,
                                                             tmp_path: Path) -> None:
    """Errors from a reader, a library or an option name the URL (a review found the copy's
    temporary path in each of these); an object name too long for a local file is read."""
    long_name = "a" * 260 + ".log"  # S3 keys may be 1024 bytes, a local file name 255
    s3.put_file(str(SAMPLES / "healthy.log"), f"{BUCKET}/named/{long_name}")
    s3.put_file(str(SAMPLES / "healthy.log"), f"{BUCKET}/named/healthy.log")
    s3.pipe(f"{BUCKET}/named/garbage.log", b"\xff\xfe no CAN log here\n")
    temp = tmp_path / "tmp"
    temp.mkdir()
    env = {**os.environ, **CREDENTIALS, "TMPDIR": str(temp)}
    option = ("--storage-option", f"endpoint_url={endpoint}")

    def run(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "nmtcheck", *args, *option],
                              cwd=tmp_path, text=True, capture_output=True, timeout=300,
                              env=env)

    healthy, garbage = f"s3://{BUCKET}/named/healthy.log", f"s3://{BUCKET}/named/garbage.log"
    long_url = f"s3://{BUCKET}/named/{long_name}"
    assert run("check", long_url, "--isolated").returncode == 0
    channel = run("check", healthy, "--channel", "can9", "--isolated")
    assert channel.returncode == 2
    assert channel.stderr.startswith(f"nmtcheck: --channel can9: not in {healthy} "), \
        channel.stderr
    as_mf4 = run("check", healthy, "--input-format", "mf4", "--isolated")
    if "asammdf" not in as_mf4.stderr:  # the mf4 extra is installed
        assert as_mf4.returncode == 2
        assert as_mf4.stderr.startswith(f"nmtcheck: {healthy}: cannot read MF4 file")
    several = run("check", healthy, garbage, "-j", "2", "--isolated", "-o", "r.json",
                  "-o", "r.html")
    assert several.returncode == 2
    assert f"nmtcheck: {garbage}: unknown log format" in several.stderr
    errors = [i.get("error") for i in json.loads((tmp_path / "r.json").read_text())["inputs"]]
    assert errors[0] is None and errors[1].startswith("unknown log format"), errors
    timeline = run("timeline", healthy, "--format", "json", "--isolated")
    assert timeline.returncode == 0, timeline.stderr
    for text in (channel.stderr, as_mf4.stderr, several.stdout + several.stderr,
                 (tmp_path / "r.json").read_text(), (tmp_path / "r.html").read_text(),
                 timeline.stdout):
        assert "nmtcheck-fetched" not in text and str(temp) not in text
    assert list(temp.iterdir()) == []
