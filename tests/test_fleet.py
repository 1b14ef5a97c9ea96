"""Fleet runs on this machine: the results dataset, incremental re-runs, faults, the local
pool that survives a dead worker, and `nmtcheck fleet summary`. Real sample logs, real
processes (the command line runs as a subprocess where worker environments matter)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
from conftest import SAMPLES, assert_one_line_error

pa = pytest.importorskip("pyarrow")
pytest.importorskip("fsspec")
pd = pytest.importorskip("pandas")

import nmtcheck as api  # noqa: E402
from nmtcheck.fleet.dataset import MARKER, SCHEMA_VERSION  # noqa: E402
from nmtcheck.fleet.executors import Crashed, ResilientPool  # noqa: E402
from nmtcheck.fleet.storage import PathPattern, parse_storage_options  # noqa: E402

LOGS = ["heartbeat_loss.log", "healthy.log", "guard_toggle.log", "reset_no_bootup.log"]


def cli(*args: str, cwd: Path, env: dict[str, str] | None = None
             ) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "nmtcheck", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=300,
                          env={**os.environ, **(env or {})})


def fleet_dir(tmp_path: Path, names: list[str] = LOGS) -> Path:
    """Sample logs laid out as a CANedge-like upload: DEVICE/SESSION/SPLIT.log."""
    root = tmp_path / "logs"
    for i, name in enumerate(names):
        dest = root / f"DEV{i % 2}" / f"0000000{i}" / f"{Path(name).stem}.log"
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(SAMPLES / name, dest)
    return root


def snapshot(results: Path) -> dict[str, float]:
    return {str(p.relative_to(results)): p.stat().st_mtime_ns for p in results.rglob("*")
            if p.is_file()}


def test_local_run_writes_the_dataset_the_json_report_agrees_with(tmp_path: Path) -> None:
    fleet_dir(tmp_path)
    res = cli("check", "logs/**/*.log", "--results", "results", "--isolated",
                   "--path-pattern", "{device}/{session}/{split}.log", cwd=tmp_path)
    assert res.returncode == 1, res.stderr  # the samples have error findings
    assert "4 logs: 4 checked" in res.stdout
    results = tmp_path / "results"
    assert json.loads((results / MARKER).read_text())["schema_version"] == SCHEMA_VERSION

    data = api.read_results(results)
    inputs = data.inputs.set_index("split")
    assert sorted(inputs.index) == sorted(Path(n).stem for n in LOGS)
    assert set(inputs["status"]) == {"ok"}
    assert inputs.loc["heartbeat_loss", "device"] in ("DEV0", "DEV1")
    assert inputs.loc["healthy", "format"] == "candump"
    assert (inputs["frames"] > 100).all()
    # candump times are epoch seconds: the partition is the recording's date
    assert inputs.loc["healthy", "date"] == str(inputs.loc["healthy", "start_time"].date())

    # the same findings as the JSON report of a plain `nmtcheck check`
    js = cli("check", *sorted(str(p) for p in (tmp_path / "logs").rglob("*.log")),
                  "--format", "json", "--isolated", cwd=tmp_path)
    report = json.loads(js.stdout)
    want = sorted((Path(report["inputs"][f["input"]]["path"]).stem, f["rule"], f["node"],
                   round(f["time"], 6)) for f in report["findings"])
    got = sorted((Path(r.url).stem, r.rule, None if pd.isna(r.node) else int(r.node),
                  round(r.time, 6)) for r in data.findings.itertuples())
    assert got == want and got
    h001 = data.findings[data.findings["rule"] == "H001"].iloc[0]
    assert h001["abs_time"].timestamp() == pytest.approx(h001["time"], abs=1e-5)
    assert data.inputs["n_error"].sum() == report["summary"]["error"]

    nodes = data.node_stats
    hb = nodes[(nodes["split"] == "heartbeat_loss") & (nodes["node"] == 3)].iloc[0]
    assert hb["worst_gap_ms"] > 900 and hb["hb_p50_ms"] < hb["worst_gap_ms"]
    assert hb["n_error"] >= 1 and hb["s_offline"] > 0
    assert len(data.runs) == 1 and data.runs.iloc[0]["checked"] == 4


def test_rerun_writes_nothing_and_a_new_log_checks_only_that_log(tmp_path: Path) -> None:
    fleet_dir(tmp_path)
    args = ("check", "logs/**/*.log", "--results", "results", "--isolated",
            "--executor", "local:2")
    first = cli(*args, cwd=tmp_path)
    before = snapshot(tmp_path / "results")
    again = cli(*args, cwd=tmp_path)
    assert again.returncode == first.returncode == 1
    assert "0 checked" in again.stdout and "4 already in the results" in again.stdout
    assert snapshot(tmp_path / "results") == before  # not one file written or replaced

    # the dataset inside the globbed folder is not taken for logs
    inside = cli("check", "logs/**", "--results", "logs/results", "--isolated", cwd=tmp_path)
    assert inside.returncode == 1 and "4 logs: 4 checked" in inside.stdout
    again_inside = cli("check", "logs/**", "--results", "logs/results", "--isolated",
                       cwd=tmp_path)
    assert "4 already in the results" in again_inside.stdout
    shutil.rmtree(tmp_path / "logs" / "results")

    extra = tmp_path / "logs" / "DEV9" / "00000009" / "pdo_preop.log"
    extra.parent.mkdir(parents=True)
    shutil.copy(SAMPLES / "pdo_preop.log", extra)
    third = cli(*args, cwd=tmp_path)
    assert "1 checked" in third.stdout and "4 already in the results" in third.stdout
    after = snapshot(tmp_path / "results")
    assert {k: v for k, v in after.items() if k in before} == before
    new = sorted(set(after) - set(before))
    assert [n.split("/")[0] for n in new if not n.startswith("runs")] == \
        ["findings", "inputs", "node_stats"]

    forced = cli(*args, "--force", cwd=tmp_path)
    assert "5 checked" in forced.stdout
    assert len(api.read_results(tmp_path / "results").inputs) == 5  # the latest check each
    assert len(api.read_results(tmp_path / "results", latest=False).inputs) >= 5


def test_faults_are_rows_and_the_run_goes_on(tmp_path: Path) -> None:
    root = fleet_dir(tmp_path, ["healthy.log"])
    (root / "bad").mkdir()
    (root / "bad" / "garbage.log").write_bytes(b"\x00\x01 not a CAN log at all\n" * 10)
    (root / "bad" / "empty.log").write_bytes(b"")
    (root / "bad" / "00000001.MFE").write_bytes(b"encrypted")
    res = cli("check", "logs/**/*", "--results", "results", "--isolated",
              "--on-input-error", "continue", cwd=tmp_path)
    assert res.returncode == 0, res.stdout + res.stderr  # healthy: no error finding
    assert "input_error 2" in res.stdout and "unsupported 1" in res.stdout
    assert "garbage.log: unknown log format" in res.stdout

    inputs = api.read_results(tmp_path / "results").inputs.set_index("url")
    empty = str(root / "bad" / "empty.log")  # local logs are named by their absolute path
    assert inputs.loc[empty, "error"] == f"{empty}: empty file: no records to check"
    assert inputs.loc[str(root / "bad" / "00000001.MFE"), "status"] == "unsupported"
    # no dated start: partitioned by the object's modification date
    assert inputs.loc[str(root / "bad" / "garbage.log"), "date"] != "unknown"

    summary = cli("fleet", "summary", "results", cwd=tmp_path)  # a fleet without findings
    assert summary.returncode == 0, summary.stderr
    assert "findings: 0 errors" in summary.stdout and "logs not checked" in summary.stdout
    assert "unsupported  " in summary.stdout

    fail = cli("check", "logs/**/*", "--results", "results", "--isolated", cwd=tmp_path)
    assert_one_line_error(fail, "logs/bad/")  # by default an unreadable log never passes,
    # and the verdict counts the logs skipped as already checked too


def test_a_dataset_beside_or_above_the_logs_checks_them(tmp_path: Path) -> None:
    """--results may be the logs' own folder: only the dataset's files are not logs."""
    root = tmp_path / "logs"
    root.mkdir()
    shutil.copy(SAMPLES / "heartbeat_loss.log", root / "a.log")
    res = cli("check", "*.log", "--results", ".", "--isolated", cwd=root)
    assert res.returncode == 1, res.stdout + res.stderr  # its H001 fails the gate
    assert "1 checked" in res.stdout
    again = cli("check", "**/*", "--results", ".", "--isolated", cwd=root)
    assert again.returncode == 1 and "1 already in the results" in again.stdout, again.stdout


def test_a_log_that_kills_its_worker_is_retried_then_crashed(tmp_path: Path) -> None:
    root = fleet_dir(tmp_path)
    shutil.copy(SAMPLES / "healthy.log", root / "CRASHME.log")
    temp = tmp_path / "temp"
    temp.mkdir()
    res = cli("check", "logs/**/*.log", "--results", "results", "--isolated",
                   "--executor", "local:2", cwd=tmp_path,
                   env={"NMTCHECK_TEST_CRASH": "CRASHME", "TMPDIR": str(temp)})
    assert "5 checked" in res.stdout and "crashed 1" in res.stdout, res.stdout + res.stderr
    assert res.returncode == 2  # a log that could not be checked never passes
    # local logs are read where they are: the dead workers leave no fetch directory
    assert [p.name for p in temp.iterdir() if p.name.startswith("nmtcheck-fleet-")] == []

    inputs = api.read_results(tmp_path / "results").inputs.set_index("url")
    crashed = inputs.loc[str(root / "CRASHME.log")]
    assert crashed["status"] == "crashed" and crashed["attempts"] == 3
    assert "worker process died" in crashed["error"]
    assert (inputs.drop(str(root / "CRASHME.log"))["status"] == "ok").all()


def _exit_on(key: str) -> str:
    if key == "die":
        os._exit(9)
    return key.upper()


def test_resilient_pool_loses_only_the_crashing_task() -> None:
    pool = ResilientPool(2, allowed_failures=1)
    keys = ["a", "b", "die", "c", "d", "e", "f", "g"]
    for k in keys:
        pool.submit(k, _exit_on, k)
    got: dict[object, object] = {}
    while pool.pending():
        got.update(pool.done())
    pool.close()
    assert {k: v for k, v in got.items() if k != "die"} == {k: k.upper() for k in keys
                                                            if k != "die"}
    assert isinstance(got["die"], Crashed) and got["die"].attempts == 2


def _cannot_start(*_args: object) -> None:
    os._exit(3)  # a worker that dies before any task: a broken installation, not a log


def test_resilient_pool_gives_up_when_no_worker_can_start(
        monkeypatch: pytest.MonkeyPatch) -> None:
    import multiprocessing

    from nmtcheck.errors import UsageError
    from nmtcheck.fleet import executors

    monkeypatch.setattr(executors, "_init_worker", _cannot_start)
    pool = ResilientPool(1, mp_context=multiprocessing.get_context("fork"))
    pool.submit("a", _exit_on, "a")
    with pytest.raises(UsageError, match="die before they start a task"):
        while pool.pending():
            pool.done()
    pool.close()


def test_parallel_check_survives_a_dead_worker(tmp_path: Path,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """`nmtcheck check -j`: the pool is forked, so a patched check_input reaches the workers."""
    import nmtcheck.engine as engine
    from nmtcheck.errors import InputError
    from nmtcheck.settings.profiles import load_profile

    real = engine.check_input

    def crashing(path: str, *a: object, **kw: object) -> object:
        if "reset_no_bootup" in path:
            os._exit(11)
        return real(path, *a, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(engine, "check_input", crashing)
    profile = load_profile("default")
    rules = engine.select_rules(profile, [], [])
    ok = [str(SAMPLES / n) for n in LOGS if "reset" not in n] * 2
    results = engine.check_inputs(ok, 2, profile, rules)
    assert [r.stats.frames > 0 for r in results] == [True] * len(ok)
    with pytest.raises(InputError, match="died each of the 3 times"):
        engine.check_inputs([*ok, str(SAMPLES / "reset_no_bootup.log")], 2, profile, rules)


def test_fleet_summary_names_the_worst_device_per_rule(tmp_path: Path) -> None:
    fleet_dir(tmp_path, LOGS + ["heartbeat_loss.log"])
    cli("check", "logs/**/*.log", "--results", "results", "--isolated",
             "--path-pattern", "{device}/{session}/{split}.log", cwd=tmp_path)
    res = cli("fleet", "summary", "results", "-o", "fleet.html", "-o", "fleet.csv",
                   cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    lines = res.stdout.splitlines()
    assert "5 logs, 2 devices" in lines[1]
    h001 = lines.index("H001: worst devices")
    # heartbeat_loss.log went to DEV0 (index 0) and DEV0 again (index 4): 2 findings
    assert lines[h001 + 2].split()[:3] == ["DEV0", "2", "2"]
    page = (tmp_path / "fleet.html").read_text()
    assert page.startswith("<!DOCTYPE html>") and "<svg" in page and "DEV0" in page
    table = pd.read_csv(tmp_path / "fleet.csv")
    dev = table[(table["section"] == "devices") & (table["rule"] == "H001")]
    assert dev.iloc[0]["device"] == "DEV0" and dev.iloc[0]["findings"] == 2


def test_duckdb_reads_the_dataset_without_nmtcheck(tmp_path: Path) -> None:
    duckdb = pytest.importorskip("duckdb")
    fleet_dir(tmp_path)
    cli("check", "logs/**/*.log", "--results", "results", "--isolated", cwd=tmp_path)
    code = (
        "import duckdb, sys\n"
        "assert 'nmtcheck' not in sys.modules\n"
        "q = \"select rule, count(*) from read_parquet('results/findings/**/*.parquet', "
        "hive_partitioning=true) group by rule order by rule\"\n"
        "print(duckdb.sql(q).fetchall())\n"
        "print(duckdb.sql(\"select count(*), min(date) from read_parquet("
        "'results/inputs/**/*.parquet', hive_partitioning=true)\").fetchall())\n")
    out = subprocess.run([sys.executable, "-S", "-c", code], cwd=tmp_path, text=True,
                         capture_output=True, env={**os.environ, "PYTHONPATH": os.pathsep.join(
                             p for p in sys.path if "site-packages" in p)})
    assert out.returncode == 0, out.stderr
    rules, inputs = out.stdout.splitlines()
    assert "('H001', 1)" in rules
    assert inputs.startswith("[(4, datetime.date(")
    del duckdb


def test_plain_check_imports_no_fleet_dependency(tmp_path: Path) -> None:
    code = ("import sys\nfrom nmtcheck.cli.main import main\n"
            f"sys.argv = ['nmtcheck', 'check', {str(SAMPLES / 'healthy.log')!r}, '-q']\n"
            "try:\n    main()\nexcept SystemExit:\n    pass\n"
            "print(sorted(m for m in ('pandas', 'pyarrow', 'fsspec', 'dask', 'distributed')"
            " if m in sys.modules))\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, text=True,
                         capture_output=True)
    assert out.stdout.strip().splitlines()[-1] == "[]", out.stdout + out.stderr
    # a local fleet run needs pyarrow, never Dask, nor fsspec (issue 25: storage.LocalFS)
    fleet = code.replace("'-q']", "'-q', '--results', 'res']")
    out = subprocess.run([sys.executable, "-c", fleet], cwd=tmp_path, text=True,
                         capture_output=True)
    # ... and not pandas either: pyarrow is kept from importing it (issue 25: 0.3-0.5 s of
    # start-up per process)
    assert out.stdout.strip().splitlines()[-1] == "['pyarrow']", \
        out.stdout + out.stderr


@pytest.mark.parametrize(("args", "needle"), [
    (["--executor", "local:2"], "--executor needs --results"),
    (["--results", "r", "--executor", "ray"], "--executor ray: unknown executor"),
    (["--results", "r", "--executor", "local:0"], "--executor local:0"),
    (["--results", "r", "--storage-option", "secret=x"], "--storage-option secret"),
    (["--results", "r", "-o", "x.json"], "--output does not go with --results"),
    (["--results", "r", "--path-pattern", "{vin}/{split}.MF4"], "unknown field {vin}"),
    (["--results", "r", "--manifest", "none.txt"], "--manifest none.txt: no such file"),
    (["--results", "r", "-j", "2", "--executor", "local"], "-j/--jobs does not go with"),
    (["--results", "r", "--format", "json"], "--format does not go with --results"),
])
def test_fleet_usage_errors(tmp_path: Path, args: list[str], needle: str) -> None:
    shutil.copy(SAMPLES / "healthy.log", tmp_path)
    assert_one_line_error(cli("check", "healthy.log", "--isolated", *args, cwd=tmp_path),
                          needle)


def test_manifest_lists_logs_one_per_line(tmp_path: Path) -> None:
    root = fleet_dir(tmp_path)
    listed = sorted(str(p.relative_to(tmp_path)) for p in root.rglob("*.log"))[:3]
    (tmp_path / "manifest.txt").write_text("# inventory\n" + "\n".join(listed) + "\n")
    res = cli("check", "--manifest", "manifest.txt", "--results", "results",
                   "--isolated", "--fail-on", "never", cwd=tmp_path)
    assert res.returncode == 0 and "3 logs: 3 checked" in res.stdout, res.stdout + res.stderr


def test_storage_options_and_path_patterns() -> None:
    assert parse_storage_options(["endpoint_url=http://x:9000", "anon=true",
                                  "client_kwargs.region_name=eu", "default_block_size=5"]) == {
        "endpoint_url": "http://x:9000", "anon": True, "client_kwargs": {"region_name": "eu"},
        "default_block_size": 5}
    p = PathPattern("{device}/{session}/{split}.MF4")
    assert p.fields("s3://fleet/2026/2F6913DB/00000004/00000001.MF4") == {
        "device": "2F6913DB", "session": "00000004", "split": "00000001"}
    assert p.fields("s3://fleet/notes.txt") == dict.fromkeys(("device", "session", "split"))


def test_tasks_in_flight_stay_within_the_window(tmp_path: Path,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """A long listing never becomes as many pending tasks: at most 2 per worker slot."""
    from nmtcheck.engine import select_rules
    from nmtcheck.fleet import executors, run
    from nmtcheck.settings.profiles import load_profile

    root = fleet_dir(tmp_path, LOGS * 3)
    seen: list[int] = []

    class Watched(executors.LocalExecutor):
        def submit(self, key: object, fn: object, *args: object) -> None:
            seen.append(self.pending())
            super().submit(key, fn, *args)  # type: ignore[arg-type]

    monkeypatch.setattr(executors, "make_executor", lambda spec: Watched(1))
    profile = load_profile("default")
    codes = [r.code for r in select_rules(profile, [], [])]
    out = run.run_fleet(run.FleetOptions([str(root / "**" / "*.log")], str(tmp_path / "res"),
                                         batch_files=1), profile, codes, None)
    assert out.files == out.status["ok"] == 12
    assert len(seen) == 12 and max(seen) < 2  # submitted only while fewer than 2 in flight


def test_a_file_named_like_a_pattern_is_that_file(tmp_path: Path) -> None:
    root = tmp_path / "logs"
    root.mkdir()
    shutil.copy(SAMPLES / "heartbeat_loss.log", root / "run [1].log")
    res = cli("check", "logs/run [1].log", "--results", "results", "--isolated", cwd=tmp_path)
    assert res.returncode == 1 and "1 checked" in res.stdout, res.stdout + res.stderr


def test_a_field_twice_in_the_path_pattern_is_a_usage_error(tmp_path: Path) -> None:
    res = cli("check", str(SAMPLES / "healthy.log"), "--results", "results", "--isolated",
              "--path-pattern", "{device}/{device}/{split}.log", cwd=tmp_path)
    assert_one_line_error(res, "--path-pattern", "{device} appears twice")


def _spill_then(key: str) -> str:
    """A task that leaves a temporary file, as a check spilling a long log does; "die"
    ends its worker before it can clean up."""
    fd, _path = tempfile.mkstemp(prefix="nmtcheck-spill-")
    os.write(fd, b"x" * 4096)
    if key == "die":
        os._exit(9)
    return tempfile.gettempdir()


def test_what_a_dead_worker_spilled_goes_with_its_pool(tmp_path: Path,
                                                        monkeypatch: pytest.MonkeyPatch
                                                        ) -> None:
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    pool = ResilientPool(2, allowed_failures=1)
    for k in ("a", "die", "b"):
        pool.submit(k, _spill_then, k)
    got: dict[object, object] = {}
    while pool.pending():
        got.update(pool.done())
    assert isinstance(got["die"], Crashed)
    for k in ("a", "b"):  # the workers' temporary directory is the pool's, below TMPDIR
        assert Path(str(got[k])).parent == tmp_path
        assert Path(str(got[k])).name.startswith("nmtcheck-workers-")
    pool.close()
    assert list(tmp_path.iterdir()) == []  # the dead workers' files and the live ones' too


SLOW_STORE = r"""
import sys, time
import fsspec
from fsspec.implementations.memory import MemoryFileSystem

class SlowStore(MemoryFileSystem):  # an object store whose downloads take a minute
    protocol = "slowstore"

    @classmethod
    def _strip_protocol(cls, path):
        return super()._strip_protocol(path.replace("slowstore://", "memory://", 1))

    def get_file(self, rpath, lpath, **kwargs):
        sys.stderr.write("fetching\n")
        sys.stderr.flush()
        time.sleep(60)

fsspec.register_implementation("slowstore", SlowStore, clobber=True)
for i in range(40):
    SlowStore().pipe(f"/bucket/log{i:02d}.log", b"(1.0) can0 701#05\n")
sys.argv = ["nmtcheck", "check", "slowstore://bucket/*.log"]
from nmtcheck.cli.main import main
main()
"""


def test_ctrl_c_while_logs_are_fetched_ends_at_once(tmp_path: Path) -> None:
    """`check URL...` (no --results) fetches up to 16 objects at once: Ctrl-C ends the run at
    once, exit 130, without starting the objects still queued and without waiting for
    the downloads under way (a pool's threads were joined at exit: minutes for an MF4 of
    gigabytes); the copies' directory goes."""
    import signal
    import time

    temp = tmp_path / "tmp"
    temp.mkdir()
    proc = subprocess.Popen([sys.executable, "-c", SLOW_STORE], stderr=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True, cwd=tmp_path,
                            env={**os.environ, "TMPDIR": str(temp)})
    assert proc.stderr is not None
    assert proc.stderr.readline() == "fetching\n"
    time.sleep(0.5)  # the other downloads begin
    proc.send_signal(signal.SIGINT)
    sent = time.monotonic()
    try:
        _out, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert time.monotonic() - sent < 10
    assert proc.returncode == 130, err
    assert err.count("fetching") <= 16 - 1  # the first line was read above
    assert err.strip().splitlines()[-1] == "nmtcheck: interrupted (SIGINT)"
    assert list(temp.iterdir()) == []
