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
    got = report.findings.drop(columns=["path", "time_offset", "time_utc"]).to_dict("records")
    for row in got:  # pandas turns a column with missing values into floats / NaN
        for k, v in row.items():
            if isinstance(v, float) and v != v:
                row[k] = None
            elif k in ("node", "frame_index", "line") and v is not None:
                row[k] = int(v)
    # the SPEC §8 fields (causes, boot_letter, ...) exist only on the findings they apply to
    got = [{k: v for k, v in row.items() if k in f or v is not None}
           for row, f in zip(got, findings, strict=True)]
    assert got == findings
    assert set(report.findings["path"]) == {str(p) for p in LOGS}
    assert len(report.timeline) == len(js["timeline"])  # type: ignore[arg-type]
    assert set(report.timeline["state"]) <= {"UNKNOWN", "INITIALISING", "PRE-OPERATIONAL",
                                             "OPERATIONAL", "STOPPED", "OFFLINE"}
    nodes = report.nodes.set_index(["input", "node"])
    assert nodes.loc[(0, 3), "error_control"] == "heartbeat"
    assert "measured_worst_heartbeat_gap_ms" in report.nodes.columns
    summary = js["summary"]
    assert isinstance(summary, dict)
    assert report.summary == {k: v for k, v in summary.items()
                              if k not in ("verdict", "order_only")}  # the counts
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


def test_time_columns_offset_everywhere_utc_where_absolute() -> None:
    """candump stamps are epoch times, ASC ones seconds from the measurement's start: the
    `time` column mixes both, `time_offset` is comparable, `time_utc` a real date."""
    report = nmtcheck.check([SAMPLES / "heartbeat_loss.log", SAMPLES / "heartbeat_loss.asc"])
    f = report.findings.set_index("input")
    assert str(f["time_utc"].dtype) == "datetime64[ns, UTC]"
    assert f.loc[0, "time_offset"] == pytest.approx(f.loc[1, "time_offset"], abs=1e-3)
    assert f.loc[0, "time_utc"] == pd.Timestamp("2026-11-21T22:22:55.816286", tz="UTC")
    assert pd.isna(f.loc[1, "time_utc"])
    t = report.timeline
    assert {"start_offset", "end_offset", "start_utc", "end_utc"} <= set(t.columns)
    assert (t["start_offset"] >= 0).all()


def test_to_json_is_text_and_a_notebook_shows_the_verdict() -> None:
    report = nmtcheck.check(LOGS)
    text = report.to_json()
    assert isinstance(text, str) and json.loads(text) == json.loads(json.dumps(report.to_dict()))
    html = report._repr_html_()
    assert html.startswith("<p><b>nmtcheck: FAIL</b>") and "<table" in html
