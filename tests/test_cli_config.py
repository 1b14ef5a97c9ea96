"""Configuration discovery (SPEC §5): nmtcheck.toml / pyproject.toml [tool.nmtcheck], found
upward from the current directory up to the repository root; the command line wins."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import SAMPLES, assert_one_line_error
from conftest import run_cli as run

from nmtcheck.settings.config import find_config

HB_LOSS = SAMPLES / "heartbeat_loss.log"






@pytest.fixture
def repo(tmp_path: Path) -> Path:
    """A repository root (it has .git) with a sub-directory holding a log."""
    root = tmp_path / "repo"
    (root / ".git").mkdir(parents=True)
    (root / "logs").mkdir()
    (root / "logs" / "hb.log").write_bytes(HB_LOSS.read_bytes())
    return root


def report(cwd: Path, *args: str) -> dict:  # type: ignore[type-arg]
    res = run("check", "hb.log", "--format", "json", *args, cwd=cwd)
    assert res.returncode in (0, 1), res.stderr
    return json.loads(res.stdout)  # type: ignore[no-any-return]


def test_no_configuration_file(repo: Path) -> None:
    assert find_config(repo / "logs") is None
    assert report(repo / "logs")["config"] == {"file": None, "profile": "default",
                                               "overrides": []}


def test_pyproject_tool_table_found_upward(repo: Path) -> None:
    (repo / "pyproject.toml").write_text(
        '[project]\nname = "x"\n\n[tool.nmtcheck]\nfail-on = "never"\nrules = "lenient"\n')
    assert find_config(repo / "logs") == (repo / "pyproject.toml").resolve()
    res = run("check", "hb.log", cwd=repo / "logs")
    assert res.returncode == 0, res.stdout  # fail-on never from the file
    assert res.stdout.startswith("configuration: ../pyproject.toml (profile lenient)")
    assert report(repo / "logs")["config"] == {"file": "../pyproject.toml",
                                               "profile": "lenient", "overrides": []}


def test_pyproject_without_tool_table_is_passed_over(repo: Path) -> None:
    (repo / "logs" / "pyproject.toml").write_text('[project]\nname = "x"\n')
    (repo / "nmtcheck.toml").write_text('fail-on = "never"\n')
    assert find_config(repo / "logs") == (repo / "nmtcheck.toml").resolve()


def test_nmtcheck_toml_wins_in_one_directory(repo: Path) -> None:
    (repo / "pyproject.toml").write_text('[tool.nmtcheck]\nfail-on = "never"\n')
    (repo / "nmtcheck.toml").write_text('fail-on = "warning"\n')
    assert find_config(repo) == (repo / "nmtcheck.toml").resolve()


def test_search_stops_at_the_repository_root(repo: Path) -> None:
    (repo.parent / "nmtcheck.toml").write_text('fail-on = "never"\n')
    assert find_config(repo / "logs") is None
    assert run("check", "hb.log", cwd=repo / "logs").returncode == 1
    # without the .git the parent's file applies
    (repo / ".git").rmdir()
    assert find_config(repo / "logs") == (repo.parent / "nmtcheck.toml").resolve()


def test_command_line_wins_and_isolated_ignores(repo: Path) -> None:
    (repo / "nmtcheck.toml").write_text(
        'fail-on = "never"\nformat = "concise"\nignore = ["H001"]\n')
    logs = repo / "logs"
    res = run("check", "hb.log", cwd=logs)
    assert res.returncode == 0 and res.stdout.startswith("nmtcheck NOT GATED")  # concise
    assert "H001" not in res.stdout
    res = run("check", "hb.log", "--fail-on", "error", "--ignore", "S", "--format", "text",
              cwd=logs)
    assert res.returncode == 1 and "H001 heartbeat-timeout" in res.stdout
    assert res.stdout.startswith("configuration: ../nmtcheck.toml")
    res = run("check", "hb.log", "--isolated", cwd=logs)
    assert res.returncode == 1 and "configuration:" not in res.stdout
    assert report(logs, "--isolated")["config"]["file"] is None


def test_rule_tables_extend_the_named_profile(repo: Path) -> None:
    (repo / "nmtcheck.toml").write_text(
        '[rules]\nextends = "lenient"\n\n[rules.H001]\nseverity = "warning"\n'
        '[timeline]\nmaster_window_ms = 500\n')
    logs = repo / "logs"
    rep = report(logs)
    assert rep["config"] == {"file": "../nmtcheck.toml", "profile": "lenient",
                             "overrides": ["H001", "timeline"]}
    (f,) = rep["findings"]
    assert (f["rule"], f["severity"]) == ("H001", "warning")
    assert run("check", "hb.log", cwd=logs).returncode == 0
    # --rules on the command line replaces the file's whole rule setup
    assert run("check", "hb.log", "--rules", "default", cwd=logs).returncode == 1


def test_tables_without_extends_extend_default(repo: Path) -> None:
    (repo / "nmtcheck.toml").write_text('[rules.H001]\ntimeout_factor = 20.0\n')
    rep = report(repo / "logs")
    assert rep["findings"] == [] and rep["config"]["profile"] == "default"


def test_paths_are_relative_to_the_file(repo: Path) -> None:
    (repo / "cfg").mkdir()
    (repo / "cfg" / "mine.toml").write_text('[rules.H001]\ntimeout_factor = 20.0\n')
    (repo / "cfg" / "net.toml").write_text("[nodes.9]\n")
    (repo / "nmtcheck.toml").write_text('rules = "cfg/mine.toml"\nnetwork = "cfg/net.toml"\n')
    rep = report(repo / "logs")
    assert [(f["rule"], f["node"]) for f in rep["findings"]] == [("N001", 9)]
    assert rep["config"]["profile"] == "cfg/mine.toml"


def test_explicit_config(repo: Path, tmp_path: Path) -> None:
    other = tmp_path / "elsewhere.toml"
    other.write_text('fail-on = "never"\n')
    res = run("check", "hb.log", "--config", str(other), cwd=repo / "logs")
    assert res.returncode == 0 and "configuration:" in res.stdout
    assert_one_line_error(run("check", "hb.log", "--config", str(tmp_path / "nope.toml"),
                              cwd=repo / "logs"), "nope.toml")
    assert_one_line_error(run("check", "hb.log", "--config", str(other), "--isolated",
                              cwd=repo / "logs"), "--isolated")


def test_select_names_and_timeline_use_the_file(repo: Path) -> None:
    (repo / "nmtcheck.toml").write_text('select = ["heartbeat-too-early", "B"]\n')
    assert run("check", "hb.log", cwd=repo / "logs").returncode == 0
    (repo / "nmtcheck.toml").write_text('[rules.H001]\ntimeout_factor = 20.0\n')
    res = run("timeline", "hb.log", cwd=repo / "logs")
    assert res.returncode == 0 and "OFFLINE" not in res.stdout
    assert "OFFLINE" in run("timeline", "hb.log", "--isolated", cwd=repo / "logs").stdout


@pytest.mark.parametrize("text, needles", [
    ('fail-on = "sometimes"\n', ["nmtcheck.toml", "fail-on"]),
    ('format = "pdf"\n', ["nmtcheck.toml", "format", "pdf"]),
    ('colour = "red"\n', ["nmtcheck.toml", "colour", "unknown key"]),
    ("select = 5\n", ["nmtcheck.toml", "select"]),
    ('select = ["Q"]\n', ["nmtcheck.toml", "select", "'Q'"]),
    ('ignore = ["heartbeat-timeot"]\n', ["nmtcheck.toml", "ignore", "heartbeat-timeot"]),
    ("rules = 3\n", ["nmtcheck.toml", "rules"]),
    ('[rules.H001]\ntimeout_factor = "fast"\n', ["nmtcheck.toml", "H001", "timeout_factor"]),
    ("[rules.Z123]\nenabled = false\n", ["nmtcheck.toml", "Z123"]),
    ('rules = "no-such-profile"\n', ["no-such-profile"]),
    ('network = "missing.toml"\n', ["missing.toml"]),
    ("this is not toml\n", ["nmtcheck.toml", "invalid TOML"]),
])
def test_errors_name_file_and_key(repo: Path, text: str, needles: list[str]) -> None:
    (repo / "nmtcheck.toml").write_text(text)
    assert_one_line_error(run("check", "hb.log", cwd=repo / "logs"), *needles)


def test_pyproject_errors_name_the_table(repo: Path) -> None:
    (repo / "pyproject.toml").write_text('[tool.nmtcheck]\nfail-on = 3\n')
    assert_one_line_error(run("check", "hb.log", cwd=repo / "logs"), "pyproject.toml",
                          "[tool.nmtcheck]", "fail-on")
