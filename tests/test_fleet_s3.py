"""Fleet runs against a real S3-protocol server: moto's ThreadedMotoServer over HTTP, read
and written through s3fs with `--storage-option endpoint_url=...` and credentials from the
environment only."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from conftest import SAMPLES, shared_path

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
