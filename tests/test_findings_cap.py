"""--max-findings: at most N findings per rule and input are kept; the rest are counted,
stated in every report and still count for the verdict (a log with a million state
changes must not need gigabytes)."""

from __future__ import annotations

import csv
import io
import json
import os
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from conftest import REPO, candump


def _flapping(tmp_path: Path) -> Path:
    """Node 2 changes state on every heartbeat (S005 each time); node 3 is silent for long
    stretches after its heartbeats (one H001 per gap)."""
    fr = [(0.0, "702#00"), (0.0, "703#00")]
    fr += [(0.01 * i, "702#" + ("05" if i % 2 else "7F")) for i in range(1, 301)]
    fr += [(0.5 * i, "703#7F") for i in range(1, 8)] + [(0.5 * i + 0.1, "703#7F")
                                                       for i in range(1, 8)]
    log = tmp_path / "flap.log"
    log.write_text(candump(sorted(fr)))
    return log


def run(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "nmtcheck", "check", *args], cwd=cwd,
                          capture_output=True, text=True,
                          env={**os.environ, "PYTHONPATH": str(REPO)})


def test_capped_findings_are_counted_and_stated(tmp_path: Path) -> None:
    log = _flapping(tmp_path)
    full = json.loads(run(str(log), "--format", "json", "--max-findings", "0",
                          cwd=tmp_path).stdout)
    s005 = sum(1 for f in full["findings"] if f["rule"] == "S005")
    h001 = sum(1 for f in full["findings"] if f["rule"] == "H001")
    assert s005 > 200 and h001 > 3 and full["omitted"] == []
    res = run(str(log), "--format", "json", "--max-findings", "3", cwd=tmp_path)
    assert res.returncode == 1  # the H001 errors still fail the gate
    capped = json.loads(res.stdout)
    assert sum(1 for f in capped["findings"] if f["rule"] == "S005") == 3
    assert {(o["rule"], o["count"]) for o in capped["omitted"]} == {
        ("S005", s005 - 3), ("H001", h001 - 3)}
    assert capped["summary"] == full["summary"]  # every finding counts for the verdict


@pytest.mark.parametrize("fmt", ["text", "concise", "markdown", "github", "html"])
def test_every_text_report_says_what_was_left_out(tmp_path: Path, fmt: str) -> None:
    out = run(str(_flapping(tmp_path)), "--format", fmt, "--max-findings", "3",
              cwd=tmp_path).stdout
    assert "more S005 unexplained-state-change (info) finding(s) left out" in out


def test_csv_junit_sarif_carry_the_counts(tmp_path: Path) -> None:
    log = str(_flapping(tmp_path))
    rows = list(csv.DictReader(io.StringIO(run(log, "--format", "csv", "--max-findings", "3",
                                               cwd=tmp_path).stdout)))
    assert any(r["rule"] == "S005" and "left out" in r["message"] for r in rows)
    junit = ET.fromstring(run(log, "--format", "junit", "--max-findings", "3",
                              cwd=tmp_path).stdout.encode())
    assert any(p.get("name") == "omitted.S005" for p in junit.iter("property"))
    sarif = json.loads(run(log, "--format", "sarif", "--max-findings", "3",
                           cwd=tmp_path).stdout)
    assert sarif["runs"][0]["artifacts"][0]["properties"]["omitted"]["S005"] > 0
    stats = run(log, "--statistics", "--max-findings", "3", cwd=tmp_path).stdout
    full = run(log, "--statistics", "--max-findings", "0", cwd=tmp_path).stdout
    assert stats == full  # statistics count every finding
