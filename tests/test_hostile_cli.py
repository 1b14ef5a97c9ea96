"""Hostile input through the real command line: standard input, globs, paths that are not
logs, truncated files, a 100 MB line under a memory limit. The outcome is always a report
(exit 0/1) or one line on stderr with exit 2 — never a traceback."""

from __future__ import annotations

import builtins
import gzip
import json
import os
import random
import resource
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import zstandard
from conftest import REPO, SAMPLES
from hostile_logs import (
    BINARY_WRITERS,
    TEXT_WRITERS,
    Frame,
    format_of,
    mf4,
    network_frames,
)

from nmtcheck.errors import InputError
from nmtcheck.readers import open_input

HEALTHY = SAMPLES / "healthy.log"
HB_LOSS = SAMPLES / "heartbeat_loss.log"
FRAMES = network_frames()
ENV = {**os.environ, "PYTHONPATH": str(REPO), "OPENBLAS_NUM_THREADS": "1",
       "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def run(*args: str | bytes, cwd: Path, stdin: bytes | None = None,
        limit_bytes: int | None = None) -> subprocess.CompletedProcess[bytes]:
    """`python -m nmtcheck ARGS` (bytes output: file names need not be UTF-8), optionally
    under an address-space limit."""
    def limit() -> None:
        if limit_bytes is not None:
            resource.setrlimit(resource.RLIMIT_AS, (limit_bytes, limit_bytes))

    return subprocess.run([sys.executable, "-m", "nmtcheck", *args], cwd=cwd, env=ENV,
                          input=stdin if stdin is not None else b"", capture_output=True,
                          timeout=120, preexec_fn=limit)


def assert_report(res: subprocess.CompletedProcess[bytes], code: int | None = None) -> str:
    """A report: exit 0 or 1 (or `code`), nothing on stderr."""
    out = res.stdout.decode("utf-8", "replace")
    assert res.returncode in ((0, 1) if code is None else (code,)), out + res.stderr.decode()
    assert res.stderr == b"", res.stderr.decode()
    return out


def assert_one_line_error(res: subprocess.CompletedProcess[bytes], *needles: str) -> str:
    """Exit 2, nothing on stdout, exactly one stderr line naming what went wrong."""
    err = res.stderr.decode("utf-8", "replace")
    assert res.returncode == 2, res.stdout.decode() + err
    assert res.stdout == b""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("nmtcheck: "), err
    assert "Traceback" not in err and "internal error" not in err, err
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


def json_inputs(res: subprocess.CompletedProcess[bytes]) -> list[dict[str, Any]]:
    inputs: list[dict[str, Any]] = json.loads(res.stdout)["inputs"]
    return inputs


# --- standard input -----------------------------------------------------------------------


def test_candump_piped_into_check_dash_is_sniffed_and_checked(tmp_path: Path) -> None:
    """`candump -L can0 | nmtcheck check -`: the same verdict and findings as the file."""
    from_file = run("check", str(HB_LOSS), "--format", "json", cwd=tmp_path)
    piped = run("check", "-", "--format", "json", cwd=tmp_path, stdin=HB_LOSS.read_bytes())
    assert from_file.returncode == piped.returncode == 1
    a, b = json.loads(from_file.stdout), json.loads(piped.stdout)
    assert b["inputs"][0]["path"] == "<stdin>" and b["inputs"][0]["format"] == "candump"
    assert b["findings"] == a["findings"]
    assert b["inputs"][0]["frames"] == a["inputs"][0]["frames"] > 0


@pytest.mark.parametrize("writer", ["asc", "trc", "blf", "mcap", "pcapng"])
def test_every_format_is_sniffed_from_a_stream(tmp_path: Path, writer: str) -> None:
    data = {**TEXT_WRITERS, **BINARY_WRITERS}[writer](FRAMES)
    res = run("check", "-", "--format", "json", cwd=tmp_path, stdin=gzip.compress(data))
    [entry] = json_inputs(res)
    assert res.returncode == 1  # the network's H001 and S001
    assert (entry["format"], entry["frames"], entry["truncated"]) == (
        format_of(writer), len(FRAMES), False)


def test_mf4_from_a_stream_is_spooled(tmp_path: Path) -> None:
    pytest.importorskip("asammdf")
    mf4(FRAMES, str(tmp_path / "x.mf4"))
    res = run("check", "-", "--format", "json", cwd=tmp_path,
              stdin=(tmp_path / "x.mf4").read_bytes())
    assert json_inputs(res)[0]["frames"] == len(FRAMES)


def test_stdin_and_files_in_one_call_with_jobs(tmp_path: Path) -> None:
    """Standard input is read in this process even with -j (workers have none)."""
    res = run("check", str(HEALTHY), "-", str(HEALTHY), "-j", "2", "--format", "json",
              cwd=tmp_path, stdin=HB_LOSS.read_bytes())
    assert res.returncode == 1
    assert [(i["path"], i["frames"] > 0) for i in json_inputs(res)] == [
        (str(HEALTHY), True), ("<stdin>", True), (str(HEALTHY), True)]


def test_empty_and_closed_and_repeated_stdin(tmp_path: Path) -> None:
    assert_one_line_error(run("check", "-", cwd=tmp_path, stdin=b""), "<stdin>", "empty file")
    closed = subprocess.run(f"'{sys.executable}' -m nmtcheck check - <&-", shell=True,
                            cwd=tmp_path, env=ENV, capture_output=True, timeout=60)
    assert_one_line_error(closed, "<stdin>", "no standard input")
    assert_one_line_error(run("check", "-", "-", cwd=tmp_path, stdin=HEALTHY.read_bytes()),
                          "only once")


def test_timeline_from_stdin(tmp_path: Path) -> None:
    res = run("timeline", "-", cwd=tmp_path, stdin=HEALTHY.read_bytes())
    assert "<stdin>: times in seconds" in assert_report(res, 0)


# --- several files, globs -----------------------------------------------------------------


def test_quoted_globs_are_expanded_with_one_combined_verdict(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    (logs / "sub").mkdir(parents=True)
    (logs / "b.log").write_bytes(HEALTHY.read_bytes())
    (logs / "a.log").write_bytes(HEALTHY.read_bytes())
    (logs / "sub" / "c.log").write_bytes(HB_LOSS.read_bytes())
    (logs / "dir.log").mkdir()  # a pattern names files: a matching directory is left out
    healthy = run("check", "logs/*.log", "--format", "json", cwd=tmp_path)
    assert healthy.returncode == 0
    assert [i["path"] for i in json_inputs(healthy)] == ["logs/a.log", "logs/b.log"]
    every = run("check", "logs/**/*.log", "--format", "json", cwd=tmp_path)
    assert every.returncode == 1  # one failing input fails the combined verdict
    assert [i["path"] for i in json_inputs(every)] == [
        "logs/a.log", "logs/b.log", "logs/sub/c.log"]
    text = assert_report(run("check", "logs/*.log", "logs/sub/?.log", cwd=tmp_path), 1)
    assert text.count(" (candump): ") == 3 and "FAIL: 1 error," in text


def test_a_pattern_matching_nothing_and_a_literal_name_with_brackets(tmp_path: Path) -> None:
    assert_one_line_error(run("check", "nothing/*.log", cwd=tmp_path), "nothing/*.log",
                          "no log file matches")
    (tmp_path / "run[1].log").write_bytes(HEALTHY.read_bytes())  # exists: not a pattern
    assert "run[1].log (candump)" in assert_report(run("check", "run[1].log", cwd=tmp_path), 0)


def test_one_unreadable_input_among_several_is_exit_2_naming_it(tmp_path: Path) -> None:
    # the good input is still checked and reported (SPEC §4); the bad one is named on
    # stderr, in the report, and makes the exit code 2
    (tmp_path / "bad.log").write_bytes(b"\x00" * 100)
    res = run("check", str(HEALTHY), str(tmp_path / "bad.log"), cwd=tmp_path)
    assert res.returncode == 2
    (line,) = res.stderr.decode().strip().splitlines()
    assert line.startswith("nmtcheck: ") and "bad.log: unknown log format" in line
    out = res.stdout.decode()
    assert "healthy.log (candump): 351 frames" in out
    assert "bad.log: cannot be checked: unknown log format" in out
    assert out.strip().splitlines()[-1].startswith("FAIL: 0 errors, 0 warnings, 0 info "
                                                          "in 2 inputs, 1 of them could not")


# --- paths that are not logs --------------------------------------------------------------


def test_directory_missing_file_and_broken_links(tmp_path: Path) -> None:
    assert_one_line_error(run("check", str(tmp_path), cwd=tmp_path),
                          "no log file below this directory")
    assert_one_line_error(run("check", "missing.log", cwd=tmp_path), "missing.log: no such file")
    (tmp_path / "dangling.log").symlink_to(tmp_path / "gone.log")
    assert_one_line_error(run("check", "dangling.log", cwd=tmp_path),
                          "dangling.log: a symbolic link to a file that does not exist")
    (tmp_path / "loop1.log").symlink_to(tmp_path / "loop2.log")
    (tmp_path / "loop2.log").symlink_to(tmp_path / "loop1.log")
    assert_one_line_error(run("check", "loop1.log", cwd=tmp_path), "loop1.log: cannot open:",
                          "symbolic links")


def test_unreadable_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "secret.log"
    path.write_bytes(HEALTHY.read_bytes())
    path.chmod(0)
    if os.geteuid() != 0:
        assert_one_line_error(run("check", str(path), cwd=tmp_path), "secret.log: cannot open:",
                              "Permission denied")
        return
    real_open = builtins.open  # root reads anything: make the open fail as it would

    def deny(file: Any, *args: Any, **kw: Any) -> Any:
        if str(file) == str(path):
            raise PermissionError(13, "Permission denied", str(file))
        return real_open(file, *args, **kw)

    monkeypatch.setattr(builtins, "open", deny)
    with pytest.raises(InputError, match=r"secret\.log: cannot open: Permission denied"):
        open_input(str(path))


@pytest.mark.parametrize("name", ["field log 2024.log", "Prüfstand_ß_日本.log", "-dash.log"])
def test_names_with_spaces_and_non_ascii(tmp_path: Path, name: str) -> None:
    (tmp_path / name).write_bytes(HB_LOSS.read_bytes())
    arg = f"./{name}" if name.startswith("-") else name
    res = run("check", arg, "--format", "json", "-o", "r.txt", cwd=tmp_path)
    assert res.returncode == 1 and json_inputs(res)[0]["path"] == arg
    assert f"{arg} (candump): " in (tmp_path / "r.txt").read_text(encoding="utf-8")
    assert_one_line_error(run("check", f"missing {name}", cwd=tmp_path), f"missing {name}")


def test_file_name_that_is_not_utf8(tmp_path: Path) -> None:
    """Bytes of a file name that are not UTF-8 are shown as \\xNN in every report."""
    name = b"log\xff\xfe.log"
    (tmp_path / os.fsdecode(name)).write_bytes(HB_LOSS.read_bytes())
    res = run("check", name, "-o", "r.json", "-o", "r.sarif", "-o", "r.html", cwd=tmp_path)
    assert "log\\xff\\xfe.log (candump): " in assert_report(res, 1)
    assert json.loads((tmp_path / "r.json").read_text())["inputs"][0]["path"] == (
        "log\\xff\\xfe.log")
    assert_one_line_error(run("check", b"gone\xff.log", cwd=tmp_path), "gone\\xff.log")


@pytest.mark.parametrize("content, needle", [
    (b"", "empty file"),
    (b"\xef\xbb\xbf", "empty file"),
    (b" \n\r\n\t\n", "unknown log format"),
    (b"\x00" * 5000, "unknown log format"),
    (bytes(range(256)) * 20, "unknown log format"),
    (b"\xff\xfe\xfd" * 1000 + b"\n", "unknown log format"),
    (b"\x1f\x8b\x08\x00", "cannot decompress (gzip)"),
    (b"\xfd7zXZ\x00garbage", "cannot decompress (xz)"),
    (b"BZh9" + b"\x00" * 40, "cannot decompress (bzip2)"),
])
def test_files_that_are_not_logs(tmp_path: Path, content: bytes, needle: str) -> None:
    (tmp_path / "x.log").write_bytes(content)
    assert_one_line_error(run("check", "x.log", cwd=tmp_path), "x.log: ", needle)


# --- truncated files ----------------------------------------------------------------------


def _cut(data: bytes, fraction: float) -> bytes:
    return data[:int(len(data) * fraction)]


@pytest.mark.parametrize("name, make", [
    ("cut.log.gz", lambda: _cut(gzip.compress(TEXT_WRITERS["candump"](FRAMES) * 50), 0.5)),
    ("cut.trc.zst", lambda: _cut(zstandard.ZstdCompressor().compress(TEXT_WRITERS["trc"](
        [Frame(i / 1000, 0x181, random.Random(i).randbytes(8)) for i in range(5000)])), 0.5)),
    ("cut.blf", lambda: _cut(BINARY_WRITERS["blf"](FRAMES), 0.6)),
    ("cut.blf.gz", lambda: gzip.compress(_cut(BINARY_WRITERS["blf-plain"](FRAMES), 0.6))),
    ("nofooter.mcap", lambda: BINARY_WRITERS["mcap"](FRAMES)[:-37]),
    ("cut.mcap", lambda: _cut(BINARY_WRITERS["mcap"](FRAMES), 0.7)),
    ("cut.pcap", lambda: _cut(BINARY_WRITERS["pcap"](FRAMES), 0.7)),
    ("cut.pcapng", lambda: _cut(BINARY_WRITERS["pcapng"](FRAMES), 0.7)),
])
def test_truncated_files_are_read_up_to_the_cut_and_reported(tmp_path: Path, name: str,
                                                             make: Any) -> None:
    (tmp_path / name).write_bytes(make())
    res = run("check", name, "--format", "json", "-o", "r.txt", "--fail-on", "never",
              cwd=tmp_path)
    [entry] = json_inputs(res)
    assert res.returncode == 0 and entry["truncated"] is True
    assert 10 < entry["frames"] <= {"cut.log.gz": 50 * len(FRAMES), "cut.trc.zst": 5000}.get(
        name, len(FRAMES))
    assert "TRUNCATED: the input ends early" in (tmp_path / "r.txt").read_text()
    strict = run("check", name, "--strict", cwd=tmp_path)
    assert_one_line_error(strict, name)


def test_whole_files_are_not_reported_truncated(tmp_path: Path) -> None:
    for writer, write in {**TEXT_WRITERS, **BINARY_WRITERS}.items():
        (tmp_path / f"{writer}.gz").write_bytes(gzip.compress(write(FRAMES)))
    res = run("check", "*.gz", "--format", "json", cwd=tmp_path)
    assert [(i["truncated"], i["frames"]) for i in json_inputs(res)] == [
        (False, len(FRAMES))] * (len(TEXT_WRITERS) + len(BINARY_WRITERS))
    assert "TRUNCATED" not in assert_report(run("check", "*.gz", cwd=tmp_path))


# --- a 100 MB line, memory bounded --------------------------------------------------------

LONG_LINE_BYTES = 100 << 20
HEADROOM = 128 << 20  # what reading may add to a small log's peak, however long the line
# Checks each format's small log, then limits the address space to the peak so far plus
# HEADROOM, then checks each format's log followed by a 100 MB line without a newline (a
# log cut by a power loss while a binary blob was being written): one JSON line per format.
MEMORY_PROBE = """
import json, resource, sys
sys.path.insert(0, sys.argv[1])
from hostile_logs import TEXT_WRITERS, format_of, network_frames
from nmtcheck.engine import check_input, select_rules
from nmtcheck.errors import NmtcheckError
from nmtcheck.settings.profiles import load_profile
profile = load_profile("default")
rules = select_rules(profile, [], [])
tmp, writers = sys.argv[2], sys.argv[3:]
seeds = {w: TEXT_WRITERS[w](network_frames()) for w in writers}
for w in writers:
    open(f"{tmp}/small", "wb").write(seeds[w])
    check_input(f"{tmp}/small", 0, profile, rules, input_format=format_of(w))
peak = [int(l.split()[1]) * 1024 for l in open("/proc/self/status") if l.startswith("VmPeak")]
resource.setrlimit(resource.RLIMIT_AS, (peak[0] + HEADROOM, peak[0] + HEADROOM))
for w in writers:
    with open(f"{tmp}/big", "wb") as f:
        f.write(seeds[w])
        f.write(b"7" * LONG_LINE_BYTES)
    try:
        s = check_input(f"{tmp}/big", 0, profile, rules, input_format=format_of(w)).stats
        out = {"frames": s.frames, "skipped": s.skipped, "lines": s.skipped_lines}
    except (NmtcheckError, MemoryError) as exc:
        out = {"error": f"{type(exc).__name__}: {exc}"}
    print(json.dumps({"writer": w, "records": seeds[w].count(b"\\n"), **out}), flush=True)
""".replace("HEADROOM", str(HEADROOM)).replace("LONG_LINE_BYTES", str(LONG_LINE_BYTES))


def _long_line_outcomes(tmp_path: Path, writers: list[str]) -> list[dict[str, Any]]:
    res = subprocess.run([sys.executable, "-c", MEMORY_PROBE, str(REPO / "tests"),
                          str(tmp_path), *writers], cwd=tmp_path, env=ENV,
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    return [json.loads(line) for line in res.stdout.splitlines()]


def _assert_one_skipped_record(outcome: dict[str, Any]) -> None:
    expected = {"frames": len(FRAMES), "skipped": 1, "lines": [outcome["records"] + 1]}
    assert {k: outcome.get(k) for k in expected} == expected, outcome


def test_a_100_mb_line_without_newline_is_one_skipped_record_in_bounded_memory(
        tmp_path: Path) -> None:
    """Every text reader, the line readers (Source.lines) and the block readers (candump,
    ASC) alike: the line is never held whole."""
    outcomes = _long_line_outcomes(tmp_path, sorted(TEXT_WRITERS))
    assert [o["writer"] for o in outcomes] == sorted(TEXT_WRITERS)
    for outcome in outcomes:
        _assert_one_skipped_record(outcome)


@pytest.mark.parametrize("fraction", [0.3, 0.999])
def test_a_cut_mf4_file_is_one_line_on_stderr(tmp_path: Path, fraction: float) -> None:
    """asammdf cannot read a cut MF4 file at all (exit 2); its half-built object used to
    print a traceback from __del__ after the message."""
    pytest.importorskip("asammdf")
    mf4(FRAMES, str(tmp_path / "whole.mf4"))
    (tmp_path / "cut.mf4").write_bytes(_cut((tmp_path / "whole.mf4").read_bytes(), fraction))
    assert_one_line_error(run("check", "cut.mf4", cwd=tmp_path), "cut.mf4: cannot read MF4")
