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
                 "linked/**/*.log"]


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
