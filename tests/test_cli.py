"""End to end through the installed `nmtcheck` command: exit codes, outputs, one-line errors."""

from __future__ import annotations

import csv
import io
import json
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import SAMPLES, assert_one_line_error, candump
from conftest import run_cli as run

HEALTHY = SAMPLES / "healthy.log"
HB_LOSS = SAMPLES / "heartbeat_loss.log"






def test_healthy_sample_passes(tmp_path: Path) -> None:
    res = run("check", str(HEALTHY), cwd=tmp_path)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "PASS: 0 errors," in res.stdout
    assert "skipped records: 0" in res.stdout


def test_fault_sample_fails_with_exit_1(tmp_path: Path) -> None:
    res = run("check", str(HB_LOSS), cwd=tmp_path)
    assert res.returncode == 1
    assert "H001 heartbeat-timeout" in res.stdout
    assert res.stdout.strip().splitlines()[-1].startswith("FAIL: 1 error,")


def test_fail_on_never_and_ignore(tmp_path: Path) -> None:
    assert run("check", str(HB_LOSS), "--fail-on", "never", cwd=tmp_path).returncode == 0
    res = run("check", str(HB_LOSS), "--ignore", "H", cwd=tmp_path)
    assert res.returncode == 0 and "H001" not in res.stdout
    res = run("check", str(HB_LOSS), "--select", "B,S", cwd=tmp_path)
    assert res.returncode == 0


def test_json_heartbeat_period_is_the_one_in_force_at_the_end(tmp_path: Path) -> None:
    """CANopenNode slaves power on at 1000 ms (network.toml) and their master writes 100 ms,
    or 0 for the guarded node 4: the report gave 1000 ms for all three."""
    folder = SAMPLES / "canopennode"
    res = run("check", str(folder / "healthy.log"), "--network", str(folder / "network.toml"),
              "--format", "json", cwd=tmp_path)
    periods = {n["node"]: n["heartbeat_period_ms"] for n in json.loads(res.stdout)["nodes"]}
    assert periods == {1: 200.0, 2: 100.0, 3: 100.0, 4: None}
    # a written value a reset voids has no known value at the end: the measured median
    frames = [(0.0, "702#00"), (0.1, "602#2B17100064000000"), (0.1005, "582#6017100000000000")]
    frames += [(0.1 + 0.1 * i, "702#05") for i in range(1, 10)]
    frames += [(1.05, "000#8102"), (1.06, "702#00")] + [(1.06 + 0.1 * i, "702#7F")
                                                        for i in range(1, 10)]
    log = tmp_path / "reset.log"
    log.write_text(candump(frames))
    net = tmp_path / "net.toml"
    net.write_text("[nodes.2]\nheartbeat_ms = 1000\n")
    res = run("check", str(log), "--network", str(net), "--format", "json", cwd=tmp_path)
    (node,) = json.loads(res.stdout)["nodes"]
    assert node["heartbeat_period_ms"] == pytest.approx(100.0, abs=1.0)  # median, not 1000


def test_fail_on_warning_counts_warnings(tmp_path: Path) -> None:
    log = tmp_path / "early.log"
    # B002 (warning): node 2 reboots on its own
    frames = [(0.0, "702#00")] + [(0.1 * i, "702#7F") for i in range(1, 30)]
    frames += [(3.0, "702#00"), (3.1, "702#7F")]
    log.write_text(candump(frames))
    assert run("check", str(log), cwd=tmp_path).returncode == 0
    assert run("check", str(log), "--fail-on", "warning", cwd=tmp_path).returncode == 1


def test_json_report_has_spec_fields(tmp_path: Path) -> None:
    res = run("check", str(HB_LOSS), "--format", "json", cwd=tmp_path)
    assert res.returncode == 1
    rep = json.loads(res.stdout)
    assert set(rep) >= {"tool", "inputs", "nodes", "timeline", "findings", "summary"}
    assert rep["tool"]["name"] == "nmtcheck"
    inp = rep["inputs"][0]
    assert {"path", "format", "frames", "skipped", "extended", "error_frames", "start",
            "end"} <= set(inp)
    assert inp["format"] == "candump" and inp["frames"] > 0
    node = rep["nodes"][0]
    assert {"input", "channel", "node", "first_seen", "last_seen", "final_state", "bootups",
            "error_control", "heartbeat_period_ms"} <= set(node)
    assert node["error_control"] in ("heartbeat", "guarding", "both", "none")
    states = {"UNKNOWN", "INITIALISING", "PRE-OPERATIONAL", "OPERATIONAL", "STOPPED", "OFFLINE"}
    sources = {"bootup", "heartbeat", "guarding", "command", "timeout", "start"}
    for iv in rep["timeline"]:
        assert iv["state"] in states and iv["source"] in sources
        assert iv["start"] <= iv["end"]
    (f,) = rep["findings"]
    assert {"input", "rule", "name", "severity", "channel", "node", "time", "frame_index", "line",
            "message"} <= set(f)
    assert (f["rule"], f["name"], f["severity"], f["node"]) == ("H001", "heartbeat-timeout",
                                                               "error", 3)
    assert rep["summary"] == {"error": 1, "warning": 0, "info": 0, "verdict": "fail",
                              "order_only": []}
    # The timeout's frame is the first frame at or after the moment it expired.
    assert f["line"] == f["frame_index"] + 1
    offline = [iv for iv in rep["timeline"] if iv["state"] == "OFFLINE"]
    assert offline and offline[0]["start"] == pytest.approx(f["time"])


def test_outputs_by_suffix(tmp_path: Path) -> None:
    res = run("check", str(HB_LOSS), "-o", "r.json", "-o", "r.csv", "-q", cwd=tmp_path)
    assert res.returncode == 1
    rep = json.loads((tmp_path / "r.json").read_text())
    rows = list(csv.DictReader(io.StringIO((tmp_path / "r.csv").read_text())))
    assert len(rows) == len(rep["findings"]) == 1
    assert rows[0]["rule"] == "H001" and rows[0]["node"] == "3"


def test_timeline_formats(tmp_path: Path) -> None:
    text = run("timeline", str(HEALTHY), cwd=tmp_path)
    assert text.returncode == 0 and "OPERATIONAL" in text.stdout
    rows = list(csv.DictReader(io.StringIO(run("timeline", str(HEALTHY), "--format", "csv",
                                               cwd=tmp_path).stdout)))
    assert {r["node"] for r in rows} == {"2", "3", "4"}
    data = json.loads(run("timeline", str(HEALTHY), "--format", "json", cwd=tmp_path).stdout)
    assert {d["state"] for d in data} >= {"PRE-OPERATIONAL", "OPERATIONAL", "STOPPED"}


def test_rules_catalogue_and_doc(tmp_path: Path) -> None:
    res = run("rules", cwd=tmp_path)
    assert res.returncode == 0
    # SPEC §3 (I007 since 2026-12-07), group P (§8.4), groups Y, D, E and L (§9.2)
    assert len(res.stdout.strip().splitlines()) == 58
    doc = run("rules", "H001", cwd=tmp_path)
    assert "heartbeat-timeout" in doc.stdout and "timeout_factor" in doc.stdout
    assert "Why it matters" in doc.stdout and "Example" in doc.stdout
    assert_one_line_error(run("rules", "X999", cwd=tmp_path), "X999")


@pytest.mark.parametrize("make, needle", [
    (lambda p: str(p / "missing.log"), "no such file"),
    (lambda p: str(p), "no log file below this directory"),
    (lambda p: ((p / "empty.log").write_text("") and str(p / "empty.log")) or str(p / "empty.log"),
     "empty file"),
    (lambda p: (p / "x.bin").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(100)) and str(p / "x.bin"),
     "unknown log format"),
])
def test_bad_inputs_exit_2_one_line(tmp_path: Path, make, needle: str) -> None:  # type: ignore[no-untyped-def]
    path = make(tmp_path)
    assert_one_line_error(run("check", path, cwd=tmp_path), path, needle)


def test_strict_names_file_and_line(tmp_path: Path) -> None:
    log = tmp_path / "bad.log"
    log.write_text(candump([(0, "702#00"), (0.1, "702#7F")]) + "garbage here\n")
    ok = run("check", str(log), "--format", "json", cwd=tmp_path)
    assert ok.returncode == 0
    inp = json.loads(ok.stdout)["inputs"][0]
    assert (inp["skipped"], inp["skipped_lines"]) == (1, [3])
    assert_one_line_error(run("check", str(log), "--strict", cwd=tmp_path), f"{log}:3")


def test_profile_errors_name_file_and_key(tmp_path: Path) -> None:
    prof = tmp_path / "p.toml"
    prof.write_text('extends = "default"\n[rules.H001]\ntimeout_factor = "fast"\n')
    assert_one_line_error(run("check", str(HEALTHY), "--rules", str(prof), cwd=tmp_path),
                          str(prof), "H001", "timeout_factor")
    prof.write_text('extends = "default"\n[rules.Z123]\nenabled = false\n')
    assert_one_line_error(run("check", str(HEALTHY), "--rules", str(prof), cwd=tmp_path),
                          "Z123")
    prof.write_text('extends = "default"\n[rules.H001]\ntimeout_factor = -1.5\n')
    assert_one_line_error(run("check", str(HEALTHY), "--rules", str(prof), cwd=tmp_path),
                          "H001", "timeout_factor", ">= 0")
    prof.write_text('extends = "default"\n[rules.H001]\nfactor = 2\n')
    assert_one_line_error(run("check", str(HEALTHY), "--rules", str(prof), cwd=tmp_path),
                          "factor", "unknown parameter")


def test_profile_extends_and_overrides(tmp_path: Path) -> None:
    prof = tmp_path / "loose.toml"
    prof.write_text('extends = "default"\n[rules.H001]\ntimeout_factor = 20.0\n')
    assert run("check", str(HB_LOSS), "--rules", str(prof), cwd=tmp_path).returncode == 0
    prof.write_text('extends = "default"\n[rules.H001]\nseverity = "warning"\n')
    res = run("check", str(HB_LOSS), "--rules", str(prof), cwd=tmp_path)
    assert res.returncode == 0 and "warning H001" in res.stdout
    assert run("check", str(HB_LOSS), "--rules", "lenient", cwd=tmp_path).returncode == 1


def test_network_file_missing_node_and_errors(tmp_path: Path) -> None:
    net = tmp_path / "net.toml"
    net.write_text("[nodes.2]\nheartbeat_ms = 100\n[nodes.9]\n")
    res = run("check", str(HEALTHY), "--network", str(net), "--format", "json", cwd=tmp_path)
    assert res.returncode == 1
    (f,) = json.loads(res.stdout)["findings"]
    assert (f["rule"], f["node"], f["frame_index"]) == ("N001", 9, 0)
    net.write_text("[nodes.2]\nheartbeat = 100\n")
    assert_one_line_error(run("check", str(HEALTHY), "--network", str(net), cwd=tmp_path),
                          str(net), "heartbeat")
    for key in ("heartbeat_ms", "consumer_timeout_ms", "guard_time_ms", "life_time_factor"):
        net.write_text(f"[nodes.2]\n{key} = -100\n")  # times and factors are never negative
        assert_one_line_error(run("check", str(HEALTHY), "--network", str(net), cwd=tmp_path),
                              str(net), key, ">= 0")


def test_unavailable_format_and_usage_errors(tmp_path: Path) -> None:
    assert_one_line_error(run("check", str(HEALTHY), "--format", "pdf", cwd=tmp_path), "pdf")
    assert_one_line_error(run("check", str(HEALTHY), "--select", "Q", cwd=tmp_path), "Q")
    assert_one_line_error(run("check", cwd=tmp_path), "LOGS")
    assert_one_line_error(run("check", str(HEALTHY), "--channel", "can9", cwd=tmp_path), "can9")


def test_installed_command_outside_checkout(tmp_path: Path) -> None:
    """The wheel ships rules/: the console script works from any directory."""
    exe = Path(sys.executable).with_name("nmtcheck")
    if not exe.exists():
        pytest.skip("nmtcheck console script not installed in this environment")
    res = subprocess.run([str(exe), "rules", "B003"], cwd=tmp_path, capture_output=True,
                         text=True, timeout=60)
    assert res.returncode == 0 and "repeat_window_ms" in res.stdout
