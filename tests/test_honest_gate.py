"""Issue 23: a gate never looks greener than it is (SPEC §4, §7): the verdict in every
format, broken configuration files, one unreadable input among several, directories,
rules that could not run, limits measured from the trace, `-o` checked first, start_utc."""

from __future__ import annotations

import json
import os
import re
import subprocess
from pathlib import Path

import pytest
from conftest import SAMPLES, Checker, assert_one_line_error, candump
from conftest import run_cli as run
from lxml import etree

HEALTHY = SAMPLES / "healthy.log"
HB_LOSS = SAMPLES / "heartbeat_loss.log"
SAMPLE_LOGS = sorted(SAMPLES.glob("*.log"))
WORDS = {"pass": "PASS", "fail": "FAIL", "not-gated": "NOT GATED"}


def _reports(tmp_path: Path, *args: str) -> tuple[subprocess.CompletedProcess[str],
                                                  dict[str, str]]:
    """`check ARGS` with a report of every format written; (result, format -> text)."""
    outs = {"json": "r.json", "html": "r.html", "junit": "r.xml", "markdown": "r.md",
            "text": "r.txt"}
    res = run("check", *args, *[a for p in outs.values() for a in ("-o", str(tmp_path / p))],
              cwd=tmp_path)
    return res, {k: (tmp_path / p).read_text(encoding="utf-8") for k, p in outs.items()
                 if (tmp_path / p).exists()}


def _verdicts(reports: dict[str, str]) -> dict[str, str]:
    """The verdict word each format shows."""
    badge = re.search(r'id="verdict">([^<]+)<', reports["html"])
    junit = etree.fromstring(reports["junit"].encode())
    props = {p.get("value") for p in junit.iter("property") if p.get("name") == "verdict"}
    assert badge is not None and len(props) == 1
    return {"json": WORDS[json.loads(reports["json"])["summary"]["verdict"]],
            "html": badge.group(1), "junit": props.pop(),
            "markdown": reports["markdown"].splitlines()[0].split(" ", 3)[-1],
            "text": reports["text"].strip().splitlines()[-1].split(":")[0]}


# 1. the verdict ---------------------------------------------------------------------------

def test_fail_on_never_is_not_gated_in_every_format_never_pass(tmp_path: Path) -> None:
    res, reports = _reports(tmp_path, str(HB_LOSS), "--fail-on", "never")
    assert res.returncode == 0
    assert set(_verdicts(reports).values()) == {"NOT GATED"}
    assert res.stdout.strip().splitlines()[-1] == (
        "NOT GATED: 1 error, 0 warnings, 0 info in 1 input (--fail-on never)")
    assert 'class="verdict not-gated"' in reports["html"]
    assert reports["markdown"].startswith("## nmtcheck: ⚪ NOT GATED")
    assert "PASS" not in reports["markdown"] and ">PASS<" not in reports["html"]


@pytest.mark.parametrize("log", SAMPLE_LOGS, ids=lambda p: p.name)
def test_every_sample_verdict_agrees_with_the_exit_code(tmp_path: Path, log: Path) -> None:
    res, reports = _reports(tmp_path, str(log))
    assert res.returncode in (0, 1), res.stderr
    expected = "PASS" if res.returncode == 0 else "FAIL"
    assert _verdicts(reports) == dict.fromkeys(reports, expected)
    assert res.stdout.strip().splitlines()[-1].startswith(expected + ":")


# 2. a broken configuration file ----------------------------------------------------------

@pytest.mark.parametrize("name", ["pyproject.toml", "nmtcheck.toml"])
def test_a_broken_configuration_file_is_exit_2_naming_file_and_line(tmp_path: Path,
                                                                    name: str) -> None:
    (tmp_path / ".git").mkdir()  # the repository root: the search stops here
    (tmp_path / "nmtcheck.toml").write_text('fail-on = "never"\n')  # what was used before
    sub = tmp_path / "sub"
    sub.mkdir()
    (sub / name).write_text('[tool.nmtcheck\nfail-on = "never"\n')
    res = run("check", str(HB_LOSS), cwd=sub)
    assert_one_line_error(res, f"{name}:1:", "invalid TOML")


# 3. several inputs, one unreadable; directories ------------------------------------------

def test_one_unreadable_input_hides_nothing_and_is_named_in_every_report(
        tmp_path: Path) -> None:
    bad = tmp_path / "bad.log"
    bad.write_bytes(b"\x00" * 100)
    res, reports = _reports(tmp_path, str(HB_LOSS), str(bad), str(HEALTHY))
    assert res.returncode == 2
    (line,) = res.stderr.strip().splitlines()
    assert line.startswith(f"nmtcheck: {bad}: unknown log format (supported: ")
    doc = json.loads(reports["json"])
    assert [i["error"] is None for i in doc["inputs"]] == [True, False, True]
    assert doc["inputs"][1]["error"].startswith("unknown log format")
    assert [f["rule"] for f in doc["findings"]] == ["H001"]  # the good inputs' findings
    assert doc["summary"]["verdict"] == "fail"
    assert set(_verdicts(reports).values()) == {"FAIL"}
    suite = etree.fromstring(reports["junit"].encode()).findall("testsuite")[1]
    assert suite.get("name") == str(bad) and suite.get("failures") == "1"
    assert "unknown log format" in suite.find("testcase/failure").get("message")
    assert f"{bad}: cannot be checked: unknown log format" in reports["html"]
    assert f"{bad}: cannot be checked: unknown log format" in reports["text"]
    assert "in 3 inputs, 1 of them could not be read" in res.stdout.strip().splitlines()[-1]


def test_unreadable_inputs_with_jobs_are_results_too(tmp_path: Path) -> None:
    res = run("check", str(HB_LOSS), str(tmp_path / "missing.log"), str(HEALTHY), "-j", "2",
              "--format", "json", cwd=tmp_path)
    assert res.returncode == 2
    doc = json.loads(res.stdout)
    assert [i["error"] for i in doc["inputs"]] == [None, "no such file", None]


def test_a_directory_means_every_log_below_it(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    (logs / "day1").mkdir(parents=True)
    (logs / "day1" / "a.log").write_bytes(HB_LOSS.read_bytes())
    (logs / "b.asc").write_bytes((SAMPLES / "healthy.asc").read_bytes())
    (logs / "notes.txt").write_text("what we did on day 1\n")  # no log format: skipped
    (logs / "network.toml").write_text("[nodes.3]\n")  # no log format: skipped
    (logs / ".hidden.log").write_bytes(HB_LOSS.read_bytes())  # hidden: not looked at
    res = run("check", "logs", "--format", "json", cwd=tmp_path)
    assert res.returncode == 1, res.stderr
    doc = json.loads(res.stdout)
    assert [i["path"] for i in doc["inputs"]] == ["logs/b.asc", "logs/day1/a.log"]
    assert doc["not_logs"] == ["logs/network.toml", "logs/notes.txt"]
    text = run("check", "logs", cwd=tmp_path).stdout
    assert text.startswith("2 files below the directories given are no log (skipped): "
                           "logs/network.toml, logs/notes.txt")
    (tmp_path / "nologs").mkdir()
    (tmp_path / "nologs" / "x.txt").write_text("hello\n")
    assert_one_line_error(run("check", "nologs", cwd=tmp_path), "nologs",
                          "no log file below this directory", "1 file whose content")


def test_a_damaged_recording_below_a_directory_fails_the_gate(tmp_path: Path) -> None:
    """A file whose suffix a recorder writes (.log, .blf, .mf4, .asc, ...) but whose
    content is no log format is a cut-off or empty recording, not some other file:
    skipped, it let the gate pass. It is an unreadable input, exit 2, named (SPEC §4,
    amended 2026-12-07: `.log` too, candump -l's own suffix). notes.txt whose content is
    no log stays skipped."""
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "a.log").write_bytes(HEALTHY.read_bytes())
    (logs / "build.log").write_text("make: Nothing to be done for 'all'.\n")
    (logs / "notes.txt").write_text("what we did on day 1\n")
    (logs / "cut.blf").write_bytes(b"LOG")  # a BLF cut after 3 bytes
    (logs / "empty.MF4").write_bytes(b"")
    res = run("check", "logs", "--format", "json", cwd=tmp_path)
    assert res.returncode == 2, res.stderr
    doc = json.loads(res.stdout)
    assert [(i["path"], i["error"] is None) for i in doc["inputs"]] == [
        ("logs/a.log", True), ("logs/build.log", False), ("logs/cut.blf", False),
        ("logs/empty.MF4", False)]
    assert doc["not_logs"] == ["logs/notes.txt"]
    assert "nmtcheck: logs/cut.blf: unknown log format" in res.stderr


# 4. rules that could not run -------------------------------------------------------------

def test_rules_without_what_they_need_are_not_evaluated_not_passed(tmp_path: Path) -> None:
    res, reports = _reports(tmp_path, str(HEALTHY))
    assert res.returncode == 0
    (inp,) = json.loads(reports["json"])["inputs"]
    reasons = {e["rule"]: e["reason"] for e in inp["not_evaluated"]}
    assert reasons == {"H003": "no producer time configured or written",
                       "H004": "no heartbeat consumer time (1016h) configured or written",
                       "G003": "no guard time/life time factor configured or written",
                       "N001": "no network file (--network): no node is expected",
                       "D001": "no TPDO of type 254/255 with a known non-zero event timer",
                       "D002": "no TPDO of type 254/255 with a known non-zero inhibit time",
                       "D003": "no TPDO with a known synchronous transmission type",
                       "D004": "no RPDO with a known non-zero event timer (deadline)",
                       "D005": "no PDO mapping known"}
    junit = etree.fromstring(reports["junit"].encode())
    skipped = [c for c in junit.iter("testcase") if c.find("skipped") is not None]
    assert {c.get("name").split()[0] for c in skipped} == set(reasons)
    assert all(c.find("failure") is None for c in skipped)
    case = next(c for c in skipped if c.get("name").startswith("H003"))
    assert case.find("skipped").get("message") == (
        "not evaluated: no producer time configured or written")
    assert int(junit.get("skipped")) == len(skipped)
    checked, _sep, rest = reports["html"].partition('id="rules-not-evaluated"')
    for code in reasons:
        assert f'id="rule-{code}"' not in checked.split('id="rules"', 1)[1]
        assert f"<b>{code}</b>" in rest
    assert 'id="rule-H001"' in checked
    assert "not evaluated: H003 (no producer time configured or written)" in reports["text"]


def test_with_the_network_file_they_are_evaluated(tmp_path: Path) -> None:
    res = run("check", str(HEALTHY), "--network", str(SAMPLES / "network.toml"),
              "--format", "json", cwd=tmp_path)
    (inp,) = json.loads(res.stdout)["inputs"]
    # no 1016h in the DCFs; their TPDOs are event-driven with an event timer and a mapping,
    # but none has an inhibit time, none is synchronous, and no RPDO has a deadline
    assert {e["rule"] for e in inp["not_evaluated"]} == {"H004", "D002", "D003", "D004"}


def test_no_timestamps_lists_the_time_rules(checker: Checker) -> None:
    res = checker.run("702#00\n702#7F\n702#7F\n")
    assert {"H001", "H002", "G002", "S004"} <= set(res.not_evaluated)
    assert res.not_evaluated["H001"].startswith("no timestamps")


# 5. limits measured from the trace -------------------------------------------------------

def test_a_measured_limit_says_so_and_names_the_missing_configuration(tmp_path: Path) -> None:
    res = run("check", str(HB_LOSS), "--format", "json", cwd=tmp_path)
    (f,) = json.loads(res.stdout)["findings"]
    assert (f["rule"], f["basis"]) == ("H001", "measured")
    text = run("check", str(HB_LOSS), cwd=tmp_path).stdout
    assert ("(timeout 0.150 s)  [limit measured from the trace: --network or --dcf gives the "
            "configured one]") in text
    net = tmp_path / "net.toml"
    net.write_text("[nodes.3]\nconsumer_timeout_ms = 250\n")
    res = run("check", str(HB_LOSS), "--network", str(net), "--format", "json", cwd=tmp_path)
    (f,) = [f for f in json.loads(res.stdout)["findings"] if f["rule"] == "H001"]
    assert f["basis"] == "configured"
    text = run("check", str(HB_LOSS), "--network", str(net), cwd=tmp_path).stdout
    assert "H001" in text and "limit measured" not in text


def test_a_producer_time_written_by_sdo_is_an_assumed_basis(checker: Checker) -> None:
    """SPEC §7 (amended 2026-12-07): 1.5 x a producer time written by SDO is nmtcheck's
    assumption about a consumer the log never shows (issue 38, item 3)."""
    frames = [(0.0, "703#00"), (0.01, "603#2B17100064000000"), (0.011, "583#6017100000000000")]
    frames += [(0.1 * i, "703#7F") for i in range(1, 6)] + [(1.5, "703#7F")]
    res = checker.run(candump(frames), select="H001,H002")
    bases = {(f.rule, f.basis) for f in res.findings}
    assert bases == {("H001", "assumed")}


# 6. -o is checked before any log is read ---------------------------------------------------

def test_output_to_a_missing_directory_fails_before_any_log_is_read(tmp_path: Path) -> None:
    fifo = tmp_path / "never-written.log"  # reading it would block: it must not be opened
    os.mkfifo(fifo)
    res = run("check", str(fifo), "-o", str(tmp_path / "no" / "such" / "r.json"), cwd=tmp_path)
    assert_one_line_error(res, "--output", "does not exist")


# 8. when the recording started ----------------------------------------------------------

def test_start_utc_for_absolute_stamps_only(tmp_path: Path) -> None:
    res = run("check", str(HEALTHY), str(SAMPLES / "healthy.asc"), "--format", "json",
              cwd=tmp_path)
    first, second = json.loads(res.stdout)["inputs"]
    assert first["start_utc"] == "2026-11-21T22:22:48.821951Z"
    assert second["start_utc"] is None  # ASC stamps count from the measurement's start
    text = run("check", str(HEALTHY), cwd=tmp_path).stdout
    assert "recording started 2026-11-21T22:22:48.821951Z" in text.splitlines()[0]


# 13. a misspelt rule ----------------------------------------------------------------------

def test_a_misspelt_rule_gets_a_suggestion(tmp_path: Path) -> None:
    assert_one_line_error(run("check", str(HEALTHY), "--select", "heartbeat-timout",
                              cwd=tmp_path), "did you mean 'heartbeat-timeout'?")
    assert_one_line_error(run("check", str(HEALTHY), "--ignore", "H01", cwd=tmp_path),
                          "did you mean 'H001'?")


# 14. no stray results dataset in the repository ------------------------------------------

def test_the_checkout_carries_no_parquet_results() -> None:
    repo = SAMPLES.parent
    stray = [p for p in repo.rglob("*.parquet")
             if not any(part.startswith(".") for part in p.relative_to(repo).parts)]
    assert stray == []
    ignored = (repo / ".gitignore").read_text(encoding="utf-8").splitlines()
    assert "/dask-results/" in ignored and "/local-results/" in ignored
