"""Reports that cannot hurt whoever opens them, written atomically, and clean interruption:
CSV cells a spreadsheet would run as formulas, JUnit XML from any byte in a name,
`-o` through a temporary file and a rename, SIGTERM/SIGINT/SIGHUP exit codes and
temporary files."""

from __future__ import annotations

import csv
import io
import os
import signal
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from conftest import REPO, SAMPLES

from nmtcheck.cli.main import write_atomically, write_reports
from nmtcheck.engine import check_inputs
from nmtcheck.errors import UsageError
from nmtcheck.reporters import format_for_path, streamer
from nmtcheck.settings.profiles import load_profile


def run(*args: str, cwd: Path, env: dict[str, str] | None = None
        ) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "nmtcheck", *args], cwd=cwd,
                          capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(REPO), **(env or {})})


def _log_on(channel: str) -> str:
    """samples/heartbeat_loss.log (an H001) with its interface renamed."""
    return (SAMPLES / "heartbeat_loss.log").read_text().replace(" can0 ", f" {channel} ")


@pytest.mark.parametrize("evil", ["=1+2", "@SUM(1)", "+cmd", "-2+3", "=cmd|'/Ccalc'!A0"])
def test_csv_cells_never_start_a_formula(tmp_path: Path, evil: str) -> None:
    log = tmp_path / f"{evil.replace('/', '_')}.log"
    log.write_text(_log_on(evil))
    res = run("check", "--format", "csv", "--", log.name, cwd=tmp_path)
    assert res.returncode == 1, res.stderr
    rows = list(csv.DictReader(io.StringIO(res.stdout)))
    assert rows and rows[0]["channel"] == "'" + evil and rows[0]["path"].startswith("'")
    for row in rows:
        for key in ("path", "channel", "message"):
            assert not row[key].startswith(("=", "+", "-", "@")), (key, row[key])
    timeline = run("timeline", "--format", "csv", "--", log.name, cwd=tmp_path)
    cells = [r["channel"] for r in csv.DictReader(io.StringIO(timeline.stdout))]
    assert cells and all(c == "'" + evil for c in cells)


def test_junit_is_well_formed_for_control_characters_in_names(tmp_path: Path) -> None:
    (tmp_path / "trace.log").write_text(_log_on("ca\x01n0"))
    res = run("check", "trace.log", "--format", "junit", cwd=tmp_path)
    assert res.returncode == 1, res.stderr
    root = ET.fromstring(res.stdout.encode())  # raises on a document that is not well-formed
    assert any("ca\\x01n0" in (case.get("classname") or "") for case in root.iter("testcase"))


def test_reports_replace_a_symlink_instead_of_writing_through_it(tmp_path: Path) -> None:
    target = tmp_path / "precious.json"
    target.write_text("keep me\n")
    (tmp_path / "link.json").symlink_to(target)
    res = run("check", str(SAMPLES / "healthy.log"), "-o", "link.json", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert target.read_text() == "keep me\n"
    link = tmp_path / "link.json"
    assert not link.is_symlink() and '"findings"' in link.read_text()
    assert [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")] == []


def test_a_failed_write_keeps_the_previous_report(tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    report = tmp_path / "report.json"
    report.write_text("previous\n")

    def disk_full(_fd: int) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", disk_full)
    with pytest.raises(OSError):
        write_atomically(report, "new and longer\n" * 1000)
    assert report.read_text() == "previous\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.json"]


def test_which_outputs_were_written_when_one_fails(tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "out.csv").mkdir()  # a directory where a file should go
    res = run("check", str(SAMPLES / "healthy.log"), "-o", "a.json", "-o", "out.csv",
              cwd=tmp_path)
    assert res.returncode == 2  # found before any log is read (SPEC §4): nothing written
    assert "--output out.csv: is a directory" in res.stderr
    assert not (tmp_path / "a.json").exists()
    # a write that fails later (the directory appeared meanwhile): the message says which
    # reports were written before it
    monkeypatch.chdir(tmp_path)
    results = check_inputs([str(SAMPLES / "healthy.log")], 1, load_profile("default"), [])
    files = [(p, streamer(format_for_path(p))) for p in ("a.json", "out.csv")]
    with pytest.raises(UsageError, match=r"--output out.csv: cannot write: .*written: a.json"):
        write_reports(results, files, {})
    assert (tmp_path / "a.json").is_file()


def _big_log(path: Path, frames: int = 1_500_000) -> None:
    """Enough PDO traffic that the node-frame store spills to disk early."""
    lines = [f"({1000 + i * 0.0001:.6f}) can0 18{2 + i % 3}#0102030405060708\n"
             for i in range(frames)]
    path.write_text("(999.000000) can0 702#00\n(999.000000) can0 703#00\n"
                    "(999.000000) can0 704#00\n(999.001000) can0 000#0100\n" + "".join(lines))


@pytest.mark.parametrize(("sig", "code"), [(signal.SIGTERM, 143), (signal.SIGINT, 130),
                                           (signal.SIGHUP, 129)])
def test_a_signal_ends_the_run_cleanly(tmp_path: Path, sig: signal.Signals, code: int) -> None:
    log = tmp_path / "big.log"
    _big_log(log)
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    proc = subprocess.Popen([sys.executable, "-m", "nmtcheck", "check", str(log), "-q"],
                            cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, env={**os.environ, "PYTHONPATH": str(REPO),
                                            "TMPDIR": str(tmp)})
    deadline = time.monotonic() + 60
    # until the first spill directory exists (not Python's probe of the temporary directory)
    while (not any(p.name.startswith("nmtcheck-") for p in tmp.iterdir())
           and proc.poll() is None and time.monotonic() < deadline):
        time.sleep(0.01)
    assert proc.poll() is None, "finished before it spilled: make the log bigger"
    proc.send_signal(sig)
    _out, err = proc.communicate(timeout=60)
    assert proc.returncode == code
    assert err == f"nmtcheck: interrupted ({sig.name})\n"
    assert list(tmp.iterdir()) == []


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full (Linux)")
@pytest.mark.parametrize("args", [["check", "--format", "json"], ["check"], ["timeline"]])
def test_stdout_on_a_full_device_is_one_line_and_exit_2(tmp_path: Path, args: list[str]) -> None:
    with open("/dev/full", "w") as full:
        res = subprocess.run([sys.executable, "-m", "nmtcheck", *args,
                              str(SAMPLES / "heartbeat_loss.log")], cwd=tmp_path, stdout=full,
                             stderr=subprocess.PIPE, text=True,
                             env={**os.environ, "PYTHONPATH": str(REPO)})
    assert res.returncode == 2
    assert res.stderr == "nmtcheck: cannot write to standard output: No space left on device\n"


def test_third_party_logging_never_reaches_stderr(tmp_path: Path) -> None:
    """asammdf logs its own errors (and canopen, python-can theirs): only nmtcheck's one
    line may reach stderr."""
    code = ("import logging, sys; from nmtcheck.cli import main as cli, common as cli_common; "
            "load = cli_common.load_profile; "
            "cli_common.load_profile = lambda *a: (logging.getLogger('asammdf').error("
            "'NoneType: None'),"
            " load(*a))[1]; "
            "sys.argv = ['nmtcheck', 'check', sys.argv[1], '-q']; cli.main()")
    res = subprocess.run([sys.executable, "-c", code, str(tmp_path / "missing.log")],
                         cwd=tmp_path, capture_output=True, text=True,
                         env={**os.environ, "PYTHONPATH": str(REPO)})
    assert res.returncode == 2
    assert res.stderr.count("\n") == 1 and res.stderr.startswith("nmtcheck: ")


def test_blank_and_comment_lines_are_counted_in_bulk(tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    """A log of blank and comment lines costs what counting lines costs: the per-line
    parser sees only the first comment lines (their line numbers are kept) and the
    frames; the counts are what parsing every line gives."""
    from nmtcheck.readers import candump, open_input

    log = tmp_path / "mostly_blank.log"
    head = "(1700000000.000000) can0 701#05\n"
    log.write_text(head + "\n" * 50_000 + "# note\n" * 30_000 + "  \t\n" * 1000
                   + "(1700000001.000000) can0 701#05\n" + "# note\n" * 5_000)
    calls = 0
    parse = candump._parse_line

    def counted(raw: bytes, lineno: int, stats: object) -> object:
        nonlocal calls
        calls += 1
        return parse(raw, lineno, stats)  # type: ignore[arg-type]

    monkeypatch.setattr(candump, "_parse_line", counted)
    opened = open_input(str(log), "candump")
    frames = sum(len(b) for b in opened.batches)
    stats = opened.stats
    assert frames == 2
    # comment lines are notes, not skipped records (SPEC §1, revised 2026-11-26: logs as
    # people paste them), and --strict does not stop at them
    assert stats.skipped == 0 and stats.notes == 35_000
    assert calls < 20_000  # not one call per line (86 k lines)
    monkeypatch.setattr(candump, "_parse_line", parse)
    strict = run("check", str(log), "--strict", cwd=tmp_path)
    assert strict.returncode == 0, strict.stderr
