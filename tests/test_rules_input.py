"""Input rules I001–I005 (SPEC §3): each fires on its input problem and stays silent on a
clean input; findings have channel and node None and come once per input and rule."""

from __future__ import annotations

import gzip
import json
import subprocess
import sys
import zlib
from pathlib import Path

import pytest
from conftest import SAMPLES, Checker, candump
from lxml import etree

from nmtcheck.engine import check_input, select_rules
from nmtcheck.reporters import renderer
from nmtcheck.results import InputResult
from nmtcheck.settings.profiles import load_profile

HEALTHY = SAMPLES / "healthy.log"
HB_LOSS = SAMPLES / "heartbeat_loss.log"
INPUT_CODES = ("I001", "I002", "I003", "I004", "I005")

# A healthy little network: node 2 boots and heartbeats every 100 ms.
CLEAN = [(0.0, "702#00")] + [(0.1 * i, "702#05") for i in range(1, 20)]


def run(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "nmtcheck", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=120)


def input_findings(res: InputResult) -> list[tuple[str, str | None, int | None]]:
    return [(f.rule, f.channel, f.node) for f in res.findings if f.rule.startswith("I")]


def check_file(path: Path, **kw: object) -> InputResult:
    profile = load_profile("default")
    return check_input(str(path), 0, profile, select_rules(profile, [], []), **kw)  # type: ignore[arg-type]


def test_clean_input_gives_no_input_finding(checker: Checker) -> None:
    res = checker.run(candump(CLEAN))
    assert input_findings(res) == []
    assert input_findings(check_file(HEALTHY)) == []


# I001 nothing-to-check ------------------------------------------------------------------

def test_i001_only_extended_frames(checker: Checker) -> None:
    text = "".join(f"({1000 + 0.1 * i:.6f}) can0 18FF0102#0011\n" for i in range(5))
    res = checker.run(text)
    assert input_findings(res) == [("I001", None, None)]
    (f,) = res.findings
    assert f.severity == "error" and f.frame_index == 0 and f.line == 1
    assert f.time == pytest.approx(1000.0)
    assert "5 extended" in f.message


def test_i001_every_record_skipped_fails_the_cli(tmp_path: Path) -> None:
    """The issue's example: a candump log read as TRC used to PASS with 0 frames."""
    res = run("check", str(HB_LOSS), "--input-format", "trc", cwd=tmp_path)
    assert res.returncode == 1, res.stdout + res.stderr
    assert "I001 nothing-to-check" in res.stdout and "I003 skipped-records" in res.stdout
    assert res.stdout.strip().splitlines()[-1].startswith("FAIL: 1 error, 1 warning,")
    xml = run("check", str(HB_LOSS), "--input-format", "trc", "--format", "junit",
              cwd=tmp_path)
    root = etree.fromstring(xml.stdout.encode())
    assert root.get("failures") == "1"
    failure = root.find(".//testcase[@classname='input'][@name='I001 nothing-to-check']"
                        "/failure")
    assert failure is not None and failure.get("type") == "I001"
    data = json.loads(run("check", str(HB_LOSS), "--input-format", "trc", "--format", "json",
                          cwd=tmp_path).stdout)
    i001 = next(f for f in data["findings"] if f["rule"] == "I001")
    assert (i001["channel"], i001["node"], i001["time"]) == (None, None, 0.0)


def test_i001_can_be_ignored_and_empty_file_stays_exit_2(tmp_path: Path) -> None:
    res = run("check", str(HB_LOSS), "--input-format", "trc", "--ignore", "I", cwd=tmp_path)
    assert res.returncode == 0 and "I00" not in res.stdout
    empty = tmp_path / "empty.log"
    empty.write_text("")
    res = run("check", str(empty), cwd=tmp_path)
    assert res.returncode == 2 and "empty file" in res.stderr


# I002 truncated-input -------------------------------------------------------------------

def _cut_gzip(path: Path, first: str, rest: str) -> None:
    """A .gz whose first line can be decompressed and whose stream is then cut off."""
    comp = zlib.compressobj(9, zlib.DEFLATED, 31)
    head = comp.compress(first.encode()) + comp.flush(zlib.Z_FULL_FLUSH)
    tail = comp.compress(rest.encode()) + comp.flush()
    path.write_bytes(head + tail[: len(tail) // 3])


def test_i002_cut_off_gzip(tmp_path: Path) -> None:
    lines = candump(CLEAN).splitlines(keepends=True)
    log = tmp_path / "cut.log.gz"
    _cut_gzip(log, lines[0], "".join(lines[1:]) * 50)
    res = check_file(log)
    assert res.stats.truncated and res.stats.frames >= 1
    assert [f.rule for f in res.findings if f.rule == "I002"] == ["I002"]
    f = next(f for f in res.findings if f.rule == "I002")
    assert (f.channel, f.node, f.severity) == (None, None, "warning")
    assert f.frame_index == res.stats.frames - 1  # the last record read
    assert f.time == pytest.approx(res.stats.end)


def test_i002_cut_to_one_frame(tmp_path: Path) -> None:
    log = tmp_path / "one.log.gz"
    comp = zlib.compressobj(9, zlib.DEFLATED, 31)
    head = comp.compress(b"(1000.000000) can0 702#00\n") + comp.flush(zlib.Z_FULL_FLUSH)
    log.write_bytes(head + comp.compress(b"(1000.100000) can0 702#05\n" * 200)[:3])
    res = check_file(log)
    assert res.stats.truncated and res.stats.frames == 1
    (f,) = [f for f in res.findings if f.rule == "I002"]
    assert (f.frame_index, f.line) == (0, 1) and "after 1 frame:" in f.message


def test_i002_silent_on_whole_gzip(tmp_path: Path) -> None:
    log = tmp_path / "whole.log.gz"
    log.write_bytes(gzip.compress(candump(CLEAN).encode()))
    assert input_findings(check_file(log)) == []


# I003 skipped-records --------------------------------------------------------------------

def test_i003_counts_and_lines(checker: Checker) -> None:
    text = candump(CLEAN[:5]) + "garbage here\n" + candump(CLEAN[5:]) + "more garbage\n"
    res = checker.run(text)
    assert input_findings(res) == [("I003", None, None)]
    (f,) = [f for f in res.findings if f.rule == "I003"]
    assert f.severity == "warning"
    assert "2 records could not be parsed" in f.message and "lines 6, 22" in f.message
    assert f.line == 6 and f.frame_index == 5  # the frame after the first skipped line


def test_i003_max_skipped_tolerates(checker: Checker, tmp_path: Path) -> None:
    prof = tmp_path / "tolerant.toml"
    prof.write_text("[rules.I003]\nmax_skipped = 1\n")
    text = candump(CLEAN) + "garbage\n"
    assert input_findings(checker.run(text, profile=str(prof))) == []
    assert input_findings(checker.run(text + "garbage\n", profile=str(prof))) == [
        ("I003", None, None)]


def test_i003_parameter_is_a_whole_number(tmp_path: Path) -> None:
    prof = tmp_path / "bad.toml"
    for value in ("1.5", '"two"', "-1"):
        prof.write_text(f"[rules.I003]\nmax_skipped = {value}\n")
        res = run("check", str(HEALTHY), "--rules", str(prof), cwd=tmp_path)
        assert res.returncode == 2 and "max_skipped" in res.stderr and str(prof) in res.stderr


# I004 frames-lost ------------------------------------------------------------------------

def test_i004_dropcount(checker: Checker) -> None:
    text = candump(CLEAN[:10]) + "DROPCOUNT: dropped 7 messages\n" + candump(CLEAN[10:])
    res = checker.run(text)
    assert input_findings(res) == [("I004", None, None)]
    (f,) = [f for f in res.findings if f.rule == "I004"]
    # at the first frame after the record (line 11), which names it
    assert "7 frames lost in 1 DROPCOUNT record" in f.message
    assert (f.frame_index, f.line) == (10, 11) and "(the record at line 11)" in f.message


def test_i004_silent_without_loss(checker: Checker) -> None:
    text = candump(CLEAN) + "DROPCOUNT: dropped 0 messages\n"
    assert input_findings(checker.run(text)) == []


# I005 timestamps-backwards ---------------------------------------------------------------

def test_i005_backwards(checker: Checker) -> None:
    frames = CLEAN[:8] + [(0.05, "702#05")] + CLEAN[8:] + [(0.2, "702#05")]
    res = checker.run(candump(frames))
    assert ("I005", None, None) in input_findings(res)
    (f,) = [f for f in res.findings if f.rule == "I005"]
    assert "2 times" in f.message and "line 9" in f.message
    assert (f.frame_index, f.line) == (8, 9)
    assert f.time == pytest.approx(1000.05)


def test_i005_silent_on_equal_timestamps(checker: Checker) -> None:
    frames = [*CLEAN[:5], (0.4, "702#05"), *CLEAN[5:]]
    assert input_findings(checker.run(candump(frames))) == []


# every reporter copes with a finding of no channel -----------------------------------------

@pytest.mark.parametrize("fmt", ["text", "concise", "json", "csv", "html", "junit", "sarif",
                                 "github", "markdown"])
def test_every_format_renders_input_findings(fmt: str, checker: Checker) -> None:
    text = candump(CLEAN) + "garbage\n"
    results = [checker.run(text), checker.run("(1000.0) can0 18FF0102#00\n")]
    out = renderer(fmt)(results, {"fail_on": "error"})
    assert "I003" in out and "I001" in out
    assert "None" not in out.replace("\"None\"", "")  # no channel printed as Python's None
    if fmt == "html":  # no timeline row and no jump link for a finding of no channel
        row = out.split('data-rule="I003"')[1].split("</tr>")[0]
        assert 'class="jump"' not in row and "<td>input</td>" in row
        assert "tl-0-None" not in out and "tl-1-None" not in out


def test_input_rules_come_first_in_text_and_name_the_file(checker: Checker) -> None:
    res = checker.run(candump(CLEAN) + "garbage\n")
    out = renderer("text")([res], {"fail_on": "error"})
    assert f"  {res.stats.path} input:" in out


def test_parallel_jobs_keep_input_rules(tmp_path: Path) -> None:
    a = tmp_path / "a.log"
    a.write_text(candump(CLEAN) + "garbage\n")
    b = tmp_path / "b.log"
    b.write_text("(1000.0) can0 18FF0102#00\n")
    res = run("check", str(a), str(b), "-j", "2", "--format", "json", cwd=tmp_path)
    assert res.returncode == 1
    rules = sorted((f["input"], f["rule"]) for f in json.loads(res.stdout)["findings"])
    assert rules == [(0, "I003"), (1, "I001")]


def test_every_input_rule_is_documented(tmp_path: Path) -> None:
    for code in INPUT_CODES:
        doc = run("rules", code, cwd=tmp_path)
        assert doc.returncode == 0 and "Why it matters" in doc.stdout, doc.stderr


def test_sarif_and_junit_with_input_findings_validate(checker: Checker) -> None:
    import jsonschema
    from conftest import shared_file

    results = [checker.run(candump(CLEAN) + "garbage\n"),
               checker.run("(1000.0) can0 18FF0102#00\n")]
    log = json.loads(renderer("sarif")(results, {"fail_on": "error"}))
    schema = json.loads(shared_file("schemas/sarif-schema-2.1.0.json").read_text("utf-8"))
    jsonschema.validate(log, schema, cls=jsonschema.Draft4Validator)
    i001 = next(r for r in log["runs"][0]["results"] if r["ruleId"] == "I001")
    assert "logicalLocations" not in i001["locations"][0]
    root = etree.fromstring(renderer("junit")(results, {"fail_on": "error"}).encode())
    assert root.get("failures") == "1"
