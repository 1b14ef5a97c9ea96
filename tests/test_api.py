"""The Python API: `nmtcheck.check` gives the JSON report's lists as DataFrames, and
`nmtcheck.read_results` reads a fleet's dataset."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import SAMPLES

pd = pytest.importorskip("pandas")

import nmtcheck  # noqa: E402
from nmtcheck.errors import InputError, UsageError  # noqa: E402

LOGS = [SAMPLES / "heartbeat_loss.log", SAMPLES / "guard_toggle.asc"]


def json_report(*paths: Path, extra: tuple[str, ...] = ()) -> dict[str, object]:
    out = subprocess.run([sys.executable, "-m", "nmtcheck", "check", *map(str, paths),
                          "--format", "json", "--isolated", *extra], capture_output=True,
                         text=True, cwd=SAMPLES)
    return json.loads(out.stdout)  # type: ignore[no-any-return]


def test_check_gives_the_json_reports_lists_as_dataframes() -> None:
    report = nmtcheck.check(LOGS)
    js = json_report(*LOGS)
    findings = js["findings"]
    assert isinstance(findings, list)
    assert list(report.findings.columns[:11]) == ["input", "path", "rule", "name", "severity",
                                                  "channel", "node", "time", "frame_index",
                                                  "line", "message"]
    got = report.findings.drop(columns="path").to_dict("records")
    for row in got:  # pandas turns a column with missing values into floats / NaN
        for k, v in row.items():
            if isinstance(v, float) and v != v:
                row[k] = None
            elif k in ("node", "frame_index", "line") and v is not None:
                row[k] = int(v)
    assert got == findings
    assert set(report.findings["path"]) == {str(p) for p in LOGS}
    assert len(report.timeline) == len(js["timeline"])  # type: ignore[arg-type]
    assert set(report.timeline["state"]) <= {"UNKNOWN", "INITIALISING", "PRE-OPERATIONAL",
                                             "OPERATIONAL", "STOPPED", "OFFLINE"}
    nodes = report.nodes.set_index(["input", "node"])
    assert nodes.loc[(0, 3), "error_control"] == "heartbeat"
    assert "measured_worst_heartbeat_gap_ms" in report.nodes.columns
    assert report.summary == js["summary"]
    assert report.failed("error") and not report.failed("never")
    assert list(report.inputs["format"]) == ["candump", "asc"]


def test_check_takes_rules_selection_and_network() -> None:
    report = nmtcheck.check(SAMPLES / "heartbeat_loss.log", select=["H001"],
                            network=SAMPLES / "network.toml")
    assert set(report.findings["rule"]) == {"H001"}
    clean = nmtcheck.check([SAMPLES / "healthy.log"])
    assert clean.findings.empty and list(clean.findings.columns)[:3] == ["input", "path", "rule"]
    assert not clean.failed("warning")


def test_api_errors_are_nmtcheck_errors(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no such file"):
        nmtcheck.check([tmp_path / "missing.log"])
    with pytest.raises(UsageError, match="matches no rule"):
        nmtcheck.check(LOGS, select=["X999"])
    pytest.importorskip("pyarrow")
    with pytest.raises(UsageError, match="not an nmtcheck results dataset"):
        nmtcheck.read_results(tmp_path)
