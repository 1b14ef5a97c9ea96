"""Issue 39: special files never hang the gate (item 2), no workflow command from a
hostile name in any command (3), damage that passes (5), leftovers (6), Python API
misuse (7)."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import SAMPLES, assert_one_line_error

HEALTHY = SAMPLES / "healthy.log"
HB_LOSS = SAMPLES / "heartbeat_loss.log"


def run_quickly(*args: str, cwd: Path, timeout: float = 60) -> subprocess.CompletedProcess[str]:
    """The command line with a short limit: a FIFO opened or a loop expanded runs past it."""
    return subprocess.run([sys.executable, "-m", "nmtcheck", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=timeout)


# 2. special files and symlink loops --------------------------------------------------------

def _special_tree(tmp_path: Path) -> Path:
    """logs/ with two real logs, a FIFO and a socket named .log, two symlink loops and a
    link to a log taken already."""
    logs = tmp_path / "logs"
    (logs / "day1" / "deep").mkdir(parents=True)
    (logs / "day1" / "a.log").write_bytes(HEALTHY.read_bytes())
    (logs / "day1" / "deep" / "b.log").write_bytes(HB_LOSS.read_bytes())
    os.mkfifo(logs / "day1" / "live.log")
    sock = socket.socket(socket.AF_UNIX)
    sock.bind(str(logs / "day1" / "sock.log"))
    sock.close()
    (logs / "day1" / "deep" / "up").symlink_to("..")  # two loops: 2^depth paths in glob
    (logs / "day1" / "back").symlink_to("../day1")
    (logs / "same.log").symlink_to("day1/a.log")
    return logs


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
@pytest.mark.parametrize("pattern", ["logs/**/*.log", "logs/**", "**/*.log"])
def test_a_recursive_glob_takes_each_real_log_once_and_opens_no_special_file(
        tmp_path: Path, pattern: str) -> None:
    _special_tree(tmp_path)
    res = run_quickly("check", pattern, "--format", "json", cwd=tmp_path)
    assert res.returncode == 1, res.stderr  # heartbeat_loss.log has an H001 error
    doc = json.loads(res.stdout)
    assert sorted(os.path.realpath(tmp_path / i["path"]) for i in doc["inputs"]) == sorted(
        os.path.realpath(tmp_path / p) for p in ("logs/day1/a.log", "logs/day1/deep/b.log"))
    assert sorted(doc["not_logs"]) == ["logs/day1/live.log", "logs/day1/sock.log"]


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_a_plain_glob_names_and_skips_a_fifo(tmp_path: Path) -> None:
    logs = _special_tree(tmp_path)
    res = run_quickly("check", "logs/day1/*.log", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith("2 files below the directories given are no log (skipped): "
                                 "logs/day1/live.log (not a regular file), logs/day1/sock.log "
                                 "(not a regular file)"), res.stdout
    assert (logs / "day1" / "a.log").exists()


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_a_directory_with_loops_and_special_files_is_done_at_once(tmp_path: Path) -> None:
    _special_tree(tmp_path)
    res = run_quickly("check", "logs", "--format", "json", cwd=tmp_path)
    doc = json.loads(res.stdout)
    assert [i["path"] for i in doc["inputs"]] == ["logs/same.log", "logs/day1/deep/b.log"]
    assert doc["not_logs"] == ["logs/day1/live.log", "logs/day1/sock.log"]


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
@pytest.mark.parametrize("name", ["live.log", "sock.log"])
def test_a_special_file_given_by_name_is_an_unreadable_input(tmp_path: Path, name: str
                                                             ) -> None:
    _special_tree(tmp_path)
    path = f"logs/day1/{name}"
    res = run_quickly("check", path, cwd=tmp_path)
    assert_one_line_error(res, path, "not a regular file")
    both = run_quickly("check", path, str(HEALTHY), "--format", "json", cwd=tmp_path)
    assert both.returncode == 2
    errors = {i["path"]: i["error"] for i in json.loads(both.stdout)["inputs"]}
    assert "not a regular file" in errors[path] and errors[str(HEALTHY)] is None


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this system")
def test_a_pattern_that_matches_only_special_files_is_a_usage_error(tmp_path: Path) -> None:
    _special_tree(tmp_path)
    assert_one_line_error(run_quickly("check", "logs/**/live*", cwd=tmp_path),
                          "logs/**/live*: no log file matches this pattern",
                          "none of them a regular file")


GLOB_PATTERNS = ["**", "**/*.log", "*/*/*.log", "DEV0/**", "DEV0/**/*.log", "**/0001/*.log",
                 "DEV[!0]/**", "**/er/*", "**/**/a.log", "DEV0/**/0001/**", ".hidden/**",
                 "linked/**/*.log", "**/.cache/*.log", "**/.*.log", "*/**/.z.log"]


@pytest.mark.parametrize("pattern", GLOB_PATTERNS)
def test_recursive_patterns_match_what_glob_matches_without_loops(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, pattern: str) -> None:
    """The walk that replaced glob's for `**` takes the files glob takes, in a tree
    without loops or special files (hidden names, a linked directory, nesting)."""
    import glob

    from nmtcheck.cli.inputs import expand_logs

    for rel in ("a.log", "DEV0/0001/a.log", "DEV0/0001/b.txt", "DEV0/0002/er/c.log",
                "DEV1/0001/a.log", ".hidden/x.log", "DEV0/.cache/y.log", "DEV1/.z.log"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text("x\n")
    (tmp_path / "linked").symlink_to(tmp_path / "DEV1", target_is_directory=True)
    monkeypatch.chdir(tmp_path)

    def globbed(pattern: str) -> list[str]:  # glob's files, each real one once
        real: dict[str, str] = {}
        for m in sorted(glob.glob(pattern, recursive=True)):
            if not os.path.isdir(m):
                real.setdefault(os.path.realpath(m), m)
        return sorted(real.values())

    assert list(expand_logs((pattern,))) == globbed(pattern)
    assert list(expand_logs((f"{tmp_path}/{pattern}",))) == globbed(f"{tmp_path}/{pattern}")


# 3. no command acts on a hostile name ------------------------------------------------------

INJECTION = "\n::error file=x.c,line=1::pwned\n::add-mask::secret\n"
RAW_CONTROLS = ("\x00", "\x07", "\x1b", "\r", "\x85", "\u2028")


def _assert_inert(res: subprocess.CompletedProcess[str], where: str) -> None:
    for stream in (res.stdout, res.stderr):
        for line in stream.splitlines():
            assert not line.lstrip().startswith("::"), (where, line)
        for ch in RAW_CONTROLS:
            assert ch not in stream, (where, repr(ch))


def _mcap_heartbeats(topic: str) -> bytes:
    """Schemaless JSON frames of node 5 on `topic`: heartbeats with a 2 s gap (an H001)."""
    import io

    from mcap.writer import Writer

    out = io.BytesIO()
    writer = Writer(out)
    writer.start()
    channel = writer.register_channel(topic, "json", 0)
    t = 1_700_000_000 * 10**9
    for i in range(20):
        stamp = t + (i * 100 if i < 10 else 2000 + i * 100) * 10**6
        payload = json.dumps({"can_id": 0x705, "data": "05", "dlc": 1}).encode()
        writer.add_message(channel, log_time=stamp, publish_time=stamp, data=payload)
    writer.finish()
    return out.getvalue()


@pytest.fixture
def hostile(tmp_path: Path) -> Path:
    """logs/ with a file whose name and a topic that hold workflow commands."""
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / ("run" + INJECTION.replace("/", "_") + "\x07.log")).write_bytes(
        HB_LOSS.read_bytes())
    (logs / "topic.mcap").write_bytes(_mcap_heartbeats("/can" + INJECTION + "\x1b[2J"))
    return tmp_path


def test_every_command_shows_a_hostile_name_and_runs_none(hostile: Path) -> None:
    cwd = hostile
    runs = {f"check {fmt}": run_quickly("check", "logs", "--format", fmt, cwd=cwd)
            for fmt in ("text", "concise", "markdown", "csv", "github", "json")}
    for fmt in ("text", "csv", "json"):
        runs[f"timeline {fmt}"] = run_quickly("timeline", "logs", "--format", fmt, cwd=cwd)
    runs["fleet check"] = run_quickly("check", "logs/**", "--results", "res", cwd=cwd,
                                      timeout=300)
    for fmt in ("text", "csv", "html"):
        runs[f"fleet summary {fmt}"] = run_quickly("fleet", "summary", "res", "--format", fmt,
                                                   cwd=cwd)
    runs["rules"] = run_quickly("rules", "H001" + INJECTION, cwd=cwd)
    runs["monitor"] = run_quickly("monitor", "-i", "virtual", "-c", "vcan" + INJECTION,
                                  "--duration", "0.5", cwd=cwd)
    github = runs.pop("check github")  # its own workflow commands, one per finding
    assert github.returncode == 1, github.stderr
    for line in github.stdout.splitlines():
        assert line.startswith(("::error file=logs/", "::warning file=logs/",
                                "::notice file=logs/")) or not line.startswith("::"), line
    for where, res in runs.items():
        assert res.returncode in (0, 1, 2), (where, res.stderr)
        _assert_inert(res, where)
    for where in ("timeline text", "fleet summary text", "fleet summary csv",
                  "fleet summary html", "check text"):
        assert "\\x0a::error file=x.c" in runs[where].stdout, (where, runs[where].stdout)
    assert runs["fleet check"].returncode == 1, runs["fleet check"].stderr
    assert runs["timeline text"].returncode == 0, runs["timeline text"].stderr


# 5. damage that passes ---------------------------------------------------------------------

def _numbered_after(src: Path, dst: Path, first: int) -> None:
    """`src` with its lines from `first` on turned into `cat -n`'s (the real tool)."""
    lines = src.read_bytes().splitlines(keepends=True)
    numbered = subprocess.run(["cat", "-n"], input=b"".join(lines[first - 1:]),
                              capture_output=True, check=True).stdout
    dst.write_bytes(b"".join(lines[:first - 1]) + numbered)


def test_a_log_mostly_skipped_is_not_read_and_fails_the_gate(tmp_path: Path) -> None:
    _numbered_after(HEALTHY, tmp_path / "damaged.log", 21)
    res = run_quickly("check", "damaged.log", cwd=tmp_path)
    assert_one_line_error(res, "damaged.log", "331 of 351 records could not be parsed",
                          "first at line 21", "not read")
    both = run_quickly("check", "damaged.log", str(HEALTHY), "--format", "json", cwd=tmp_path)
    assert both.returncode == 2
    inputs = json.loads(both.stdout)["inputs"]
    assert "331 of 351 records" in inputs[0]["error"] and inputs[1]["error"] is None


def test_a_log_damaged_in_a_few_lines_is_read_with_an_i003(tmp_path: Path) -> None:
    _numbered_after(HEALTHY, tmp_path / "tail.log", 331)  # 21 of 351 lines: read, I003
    res = run_quickly("check", "tail.log", "--format", "json", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    doc = json.loads(res.stdout)
    assert doc["inputs"][0]["error"] is None
    assert [f["rule"] for f in doc["findings"]] == ["I003"]


def test_the_share_of_skipped_records_that_makes_an_input_unreadable_is_a_parameter(
        tmp_path: Path) -> None:
    _numbered_after(HEALTHY, tmp_path / "damaged.log", 21)
    (tmp_path / "lax.toml").write_text("[rules.I003]\nunreadable_share = 1.0\n")
    res = run_quickly("check", "damaged.log", "--rules", "lax.toml", "--format", "json",
                      cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert [f["rule"] for f in json.loads(res.stdout)["findings"]] == ["I003"]
    (tmp_path / "bad.toml").write_text("[rules.I003]\nunreadable_share = 1.5\n")
    assert_one_line_error(run_quickly("check", "damaged.log", "--rules", "bad.toml",
                                      cwd=tmp_path), "bad.toml", "unreadable_share")


@pytest.mark.parametrize("value", ["nan", "inf", "+inf", "1e308", "-nan"])
def test_a_network_or_profile_number_that_is_no_finite_time_is_refused(
        tmp_path: Path, value: str) -> None:
    (tmp_path / "net.toml").write_text(f"[nodes.5]\nheartbeat_ms = {value}\n")
    assert_one_line_error(run_quickly("check", str(HB_LOSS), "--network", "net.toml",
                                      cwd=tmp_path), "net.toml", "heartbeat_ms", "finite")
    (tmp_path / "p.toml").write_text(f"[rules.H001]\ntimeout_factor = {value}\n")
    assert_one_line_error(run_quickly("check", str(HB_LOSS), "--rules", "p.toml",
                                      cwd=tmp_path), "p.toml", "timeout_factor", "finite")
    (tmp_path / "boot.toml").write_text(f"[boot]\nboot_time_ms = {value}\n")
    assert_one_line_error(run_quickly("check", str(HB_LOSS), "--network", "boot.toml",
                                      cwd=tmp_path), "boot.toml", "boot_time_ms")
    (tmp_path / "nmtcheck.toml").write_text(f"[timeline]\nmaster_window_ms = {value}\n")
    assert_one_line_error(run_quickly("check", str(HB_LOSS), cwd=tmp_path),
                          "nmtcheck.toml", "master_window_ms", "finite")


@pytest.mark.parametrize("name, text", [
    ("net.toml", "x = " + "[" * 5000 + "]" * 5000 + "\n"),
    ("net.toml", "x = " + "{a = " * 5000 + "1" + "}" * 5000 + "\n"),
    ("p.toml", "x = " + "[" * 5000 + "]" * 5000 + "\n"),
    ("nmtcheck.toml", "x = " + "[" * 5000 + "]" * 5000 + "\n"),
])
def test_deeply_nested_toml_is_a_one_line_error(tmp_path: Path, name: str, text: str) -> None:
    (tmp_path / name).write_text(text)
    args = {"net.toml": ["--network", "net.toml"], "p.toml": ["--rules", "p.toml"],
            "nmtcheck.toml": []}[name]
    res = run_quickly("check", str(HB_LOSS), *args, cwd=tmp_path)
    assert_one_line_error(res, name, "invalid TOML", "nested")
    assert "internal error" not in res.stderr


@pytest.mark.parametrize("text", [
    'fail-on = "{big}"\n', 'format = "{big}"\n', 'select = ["{big}"]\n', 'rules = "{big}"\n',
    '"{big}" = 1\n', '[rules.H001]\ntimeout_factor = "{big}"\n',
])
def test_a_huge_configuration_value_is_quoted_short(tmp_path: Path, text: str) -> None:
    (tmp_path / "nmtcheck.toml").write_text(text.replace("{big}", "x" * 10_000_000))
    res = run_quickly("check", str(HB_LOSS), cwd=tmp_path)
    assert_one_line_error(res, "nmtcheck.toml")
    assert len(res.stderr) < 400, res.stderr[:500]
    (tmp_path / "net.toml").write_text(f'[nodes.5]\nchannel = {"1" * 10_000_000}\n')
    res = run_quickly("check", str(HB_LOSS), "--network", "net.toml", "--isolated",
                      cwd=tmp_path)
    assert_one_line_error(res, "net.toml")
    assert len(res.stderr) < 400, res.stderr[:500]


# 7. Python API misuse ----------------------------------------------------------------------

@pytest.mark.parametrize("kwargs, error, needle", [
    ({"select": "H001"}, TypeError, "select"),
    ({"ignore": "H002"}, TypeError, "ignore"),
    ({"topics": "/can"}, TypeError, "topics"),
    ({"jobs": -3}, ValueError, "jobs"),
    ({"jobs": 1.5}, TypeError, "jobs"),
    ({"jobs": True}, TypeError, "jobs"),
    ({"max_findings": -1}, ValueError, "max_findings"),
    ({"max_findings": "10"}, TypeError, "max_findings"),
    ({"strict": "no"}, TypeError, "strict"),
    ({"network": 5}, TypeError, "network"),
    ({"rules": ["default"]}, TypeError, "rules"),
    ({"channel": 0}, TypeError, "channel"),
])
def test_api_check_names_the_argument_it_cannot_take(kwargs: dict[str, object],
                                                     error: type[Exception],
                                                     needle: str) -> None:
    import nmtcheck

    with pytest.raises(error, match=rf"^{needle}: ") as caught:
        nmtcheck.check(HEALTHY, **kwargs)
    assert "matches no rule" not in str(caught.value)


def test_api_check_refuses_a_file_object_for_a_path(tmp_path: Path) -> None:
    import nmtcheck

    with open(HEALTHY) as f, pytest.raises(TypeError, match=r"^paths: .*TextIOWrapper"):
        nmtcheck.check(f)
    with pytest.raises(TypeError, match=r"^paths: "):
        nmtcheck.check([HEALTHY, 3])
    with pytest.raises(TypeError, match=r"^paths: "):
        nmtcheck.check(str(HEALTHY).encode())
    with pytest.raises(ValueError, match=r"^paths: "):
        nmtcheck.check([])


def test_api_takes_what_it_documents() -> None:
    import nmtcheck

    report = nmtcheck.check((HB_LOSS,), select=("H001",), ignore=[], jobs=0, max_findings=0)
    assert list(report.findings["rule"]) == ["H001"]
    assert report.failed("error") and not report.failed("never")


@pytest.mark.parametrize("fail_on", ["bogus", "ERRORS", None, 1])
def test_report_failed_names_what_it_takes(fail_on: object) -> None:
    import nmtcheck

    report = nmtcheck.check(HB_LOSS)
    with pytest.raises((ValueError, TypeError), match=r"^fail_on: .*error, warning, info, never"):
        report.failed(fail_on)


def test_monitor_refuses_what_is_no_message_and_a_string_for_a_list() -> None:
    from nmtcheck.live import Monitor

    with pytest.raises(TypeError, match=r"^select: "):
        Monitor(select="H001")
    with Monitor() as monitor:
        with pytest.raises(TypeError, match=r"^msg: .*can\.Message.*NoneType"):
            monitor.on_message_received(None)
        import can

        monitor.on_message_received(can.Message(timestamp=1.0, arbitration_id=0x705,
                                                data=b"\x05", is_extended_id=False))
    assert monitor.result() is not None and monitor.result().stats.frames == 1


# 6. leftovers ------------------------------------------------------------------------------

@pytest.mark.parametrize("stop", ["end", "SIGTERM", "after kill -9"])
def test_a_dask_local_run_leaves_nothing_in_the_temporary_directory(tmp_path: Path,
                                                                    stop: str) -> None:
    """Dask's LocalCluster puts `dask-scratch-space` (its lock files and the workers'
    directories) in the temporary directory and never removes it: the run gives it one
    of its own, removed with the cluster however the run ends; one a killed run left
    (its driver's process gone) goes at the next dask-local run."""
    pytest.importorskip("distributed")
    import signal
    import time

    logs = tmp_path / "logs"
    logs.mkdir()
    count = 1 if stop == "end" else 200
    for k in range(count):
        (logs / f"h{k:03d}.log").write_bytes(HB_LOSS.read_bytes())
    temp = tmp_path / "temp"
    temp.mkdir()
    if stop == "after kill -9":
        gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                              capture_output=True, text=True, check=True)
        left = temp / f"nmtcheck-dask-{gone.stdout.strip()}-x1y2z3" / "dask-scratch-space"
        left.mkdir(parents=True)
        (left / "global.lock").write_bytes(b"")
        (temp / "nmtcheck-dask-1-a").mkdir()  # pid 1 (init) lives: kept
        (temp / "other-tool").mkdir()  # not nmtcheck's: kept
    proc = subprocess.Popen([sys.executable, "-m", "nmtcheck", "check", "logs/*.log",
                             "--results", "results", "--isolated", "--executor",
                             "dask-local:1"], cwd=tmp_path,
                            env={**os.environ, "TMPDIR": str(temp)},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    if stop == "SIGTERM":
        deadline = time.monotonic() + 120
        while not list(temp.glob("nmtcheck-dask-*/dask-scratch-space/worker-*")) and (
                time.monotonic() < deadline):
            time.sleep(0.1)  # the cluster is up, its worker started: the run under way
        time.sleep(1.0)
        proc.send_signal(signal.SIGTERM)
    _out, err = proc.communicate(timeout=180)
    assert proc.returncode == (128 + signal.SIGTERM if stop == "SIGTERM" else 1), err
    kept = ["nmtcheck-dask-1-a", "other-tool"] if stop == "after kill -9" else []
    assert sorted(p.name for p in temp.iterdir()) == kept


def test_an_error_line_is_one_short_line_whatever_it_quotes() -> None:
    from nmtcheck.safe_text import ERROR_LINE_CHARS, error_line

    line = error_line("nmtcheck: x.toml: " + "y" * 10_000_000 + "\n::error::z: the end")
    assert "\n" not in line and len(line) < ERROR_LINE_CHARS + 60
    assert line.startswith("nmtcheck: x.toml: yyy") and line.endswith("::error::z: the end")
    assert "characters left out" in line
    assert error_line("short: fine") == "short: fine"


# 1. wandering clocks: the recording-gap search scans each node once ------------------------

def _wandering_heartbeats(path: Path, frames: int) -> None:
    """bench/pathological.py's `wander`: heartbeats of 8 nodes every 10 ms written in bus
    order, each node's stamps off by up to 0.1 s (a sine of its own period)."""
    import numpy as np

    i = np.arange(frames)
    node = i % 8 + 1
    true = (i // 8) * 0.010 + node * 0.001
    stamp = true + 0.1 * np.sin(2 * np.pi * true / (6 + 0.7 * node) + node) + 0.1
    path.write_text("".join(f"({t:.6f}) can0 {0x700 + n:03X}#05\n"
                            for t, n in zip(stamp.tolist(), node.tolist(), strict=True)))


def test_recording_gaps_scan_each_node_once_whatever_the_candidates(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every H001 of wandering clocks is a candidate recording gap, and each asks every
    node of the channel which limits ran there: that was a scan of the node's frames per
    candidate (1 M such frames took 19 s, 11 s of it here); now each node's frames are
    scanned once and each candidate is a lookup."""
    import types

    from nmtcheck.api import check
    from nmtcheck.timeline import recording_gaps

    log = tmp_path / "wander.log"
    _wandering_heartbeats(log, 24_000)
    scans = 0
    real = recording_gaps.np  # type: ignore[attr-defined]

    def flatnonzero(a: object) -> object:
        nonlocal scans
        scans += 1
        return real.flatnonzero(a)

    proxy = types.SimpleNamespace(**{k: getattr(real, k) for k in dir(real)
                                     if not k.startswith("__")})
    proxy.flatnonzero = flatnonzero
    monkeypatch.setattr(recording_gaps, "np", proxy)
    candidates = 0
    running = recording_gaps._running

    def counted(*args: object) -> list[float]:
        nonlocal candidates
        candidates += 1
        return running(*args)  # type: ignore[arg-type]

    monkeypatch.setattr(recording_gaps, "_running", counted)
    report = check([str(log)])
    assert (report.findings["rule"] == "H001").sum() > 20  # the clocks make many
    assert candidates > 200  # node x candidate gap questions
    assert scans <= 2 * 8  # each node's frames once (heartbeats, and requests if any)
