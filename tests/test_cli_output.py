"""Output for CI logs and editors: --format concise, --statistics, the text report's file
names and roll-up, and --select/--ignore by rule name with the more specific pattern winning."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import SAMPLES, candump

from nmtcheck.checks import RULES
from nmtcheck.engine import select_rules
from nmtcheck.errors import UsageError
from nmtcheck.settings.profiles import load_profile

HB_LOSS = SAMPLES / "heartbeat_loss.log"
HEALTHY = SAMPLES / "healthy.log"
CONCISE = re.compile(r"^(?P<path>[^:]+):(?P<line>\d*): (?P<time>\d+\.\d{6})s (?P<code>[A-Z]\d{3}) "
                     r"\[(?P<severity>error|warning|info)\] (?P<rest>.*)$")


def run(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "nmtcheck", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=120)


def repeated_timeouts(path: Path, gaps: int, node: int = 3) -> Path:
    """Node `node` heartbeats every 100 ms and falls silent for 0.5 s `gaps` times."""
    lines, t = [(0.0, f"70{node}#00")], 0.0
    for _ in range(gaps):
        for _ in range(5):
            t += 0.1
            lines.append((t, f"70{node}#7F"))
        t += 0.5
        lines.append((t, f"70{node}#7F"))
    path.write_text(candump(lines))
    return path


# --format concise --------------------------------------------------------------------------

def test_concise_one_line_per_finding(tmp_path: Path) -> None:
    res = run("check", str(HB_LOSS), "--format", "concise", cwd=tmp_path)
    assert res.returncode == 1
    first, verdict = res.stdout.splitlines()
    m = CONCISE.match(first)
    assert m is not None, first
    assert (m["path"], m["line"], m["code"], m["severity"]) == (str(HB_LOSS), "77", "H001",
                                                                "error")
    assert m["time"] == "1.560400" and m["rest"].startswith("no heartbeat from node 3")
    assert verdict.startswith("nmtcheck FAIL: 1 error")


def test_concise_input_and_network_findings(tmp_path: Path) -> None:
    log = tmp_path / "x.log"
    # a reserved CAN-ID (C001, the network's) and an unparseable line (I003, the input's)
    log.write_text(candump([(0.0, "702#00"), (0.1, "702#05"), (0.2, "123#00")]) + "junk\n")
    lines = run("check", str(log), "--format", "concise", cwd=tmp_path).stdout.splitlines()
    matches = [CONCISE.match(x) for x in lines[:-1]]
    assert None not in matches
    by_code = {m["code"]: m for m in matches if m is not None}
    assert by_code["C001"]["rest"].startswith("network: CAN-ID 123h")
    assert by_code["I003"]["rest"].startswith("1 record could not be parsed")  # no node part
    assert by_code["I003"]["line"] == "4"


def test_concise_names_the_channel_when_there_are_several(tmp_path: Path) -> None:
    log = tmp_path / "two.log"
    frames = candump([(0.0, "702#00")] + [(0.1 * i, "702#05") for i in range(1, 5)]
                     + [(1.5, "702#05")], "can1")
    frames += candump([(0.05, "705#00"), (0.06, "705#05")], "can0")
    log.write_text(frames)
    out = run("check", str(log), "--format", "concise", "--select", "H001",
              cwd=tmp_path).stdout
    assert "H001 [error] can1: no heartbeat from node 2 " in out  # the node said once


def test_concise_line_is_empty_for_binary_formats() -> None:
    from nmtcheck.readers import InputStats
    from nmtcheck.reporters.concise import finding_line
    from nmtcheck.results import Finding, InputResult

    stats = InputStats(path="run.blf", format="blf", start=10.0, channels=["1"])
    res = InputResult(0, stats, None)  # type: ignore[arg-type]
    f = Finding(0, "H001", "heartbeat-timeout", "error", "1", 3, 11.5, 42, None, "gap")
    assert finding_line(res, f) == "run.blf:: 1.500000s H001 [error] node 3: gap"


# --statistics ------------------------------------------------------------------------------

def test_statistics_one_line_per_rule(tmp_path: Path) -> None:
    a = repeated_timeouts(tmp_path / "a.log", 4)
    res = run("check", str(a), str(HB_LOSS), "--statistics", cwd=tmp_path)
    assert res.returncode == 1  # the exit code does not change
    lines = res.stdout.splitlines()
    assert re.match(r"^5\s+H001\s+heartbeat-timeout\s+\[error\]$", lines[0]), lines
    assert lines[-1].startswith("FAIL: 5 errors")
    assert not any("no heartbeat" in line for line in lines)  # no single finding
    data = json.loads(run("check", str(a), str(HB_LOSS), "--statistics", "--format", "json",
                          cwd=tmp_path).stdout)
    assert data == [{"code": "H001", "name": "heartbeat-timeout", "severity": "error",
                     "count": 5}]


def test_statistics_keeps_the_output_files(tmp_path: Path) -> None:
    res = run("check", str(HB_LOSS), "--statistics", "-o", "r.json", cwd=tmp_path)
    assert res.returncode == 1
    assert len(json.loads((tmp_path / "r.json").read_text())["findings"]) == 1


def test_statistics_of_a_clean_run(tmp_path: Path) -> None:
    res = run("check", str(HEALTHY), "--statistics", cwd=tmp_path)
    assert res.returncode == 0 and res.stdout.splitlines() == [
        "PASS: 0 errors, 0 warnings, 0 info in 1 input (--fail-on error)"]


# text: the file on every group, repeated findings rolled up ---------------------------------

def test_text_names_the_file_on_every_group_and_rolls_up(tmp_path: Path) -> None:
    a = repeated_timeouts(tmp_path / "a.log", 7)
    res = run("check", str(a), str(HB_LOSS), "-q", cwd=tmp_path)
    out = res.stdout
    assert f"  {a} can0 node 3:" in out and f"  {HB_LOSS} can0 node 3:" in out
    shown = [line for line in out.splitlines() if "H001 heartbeat-timeout:" in line]
    assert len(shown) == 3 + 1  # three of a.log's seven, and heartbeat_loss.log's one
    more = [line for line in out.splitlines() if "… 4 more H001 heartbeat-timeout" in line]
    assert len(more) == 1 and "(error)" in more[0]
    assert "FAIL: 8 errors," in out  # the verdict counts every finding
    # exactly one more than shown is printed, not rolled up
    b = repeated_timeouts(tmp_path / "b.log", 4)
    out = run("check", str(b), "-q", cwd=tmp_path).stdout
    assert out.count("H001 heartbeat-timeout:") == 4 and "more H001" not in out
    # concise lists every one
    out = run("check", str(a), "--format", "concise", cwd=tmp_path).stdout
    assert out.count(" H001 [error] ") == 7


# --select / --ignore: names and specificity -------------------------------------------------

def codes(select: str = "", ignore: str = "", profile: str = "default") -> list[str]:
    prof = load_profile(profile)
    return [r.code for r in select_rules(prof, [s for s in select.split(",") if s],
                                         [s for s in ignore.split(",") if s])]


def test_rule_names_select_and_ignore() -> None:
    assert codes(select="heartbeat-timeout") == ["H001"]
    assert codes(select="Heartbeat-Timeout,G001") == ["H001", "G001"]
    assert "H002" not in codes(ignore="heartbeat-too-early")
    assert codes(select="h001") == ["H001"]


@pytest.mark.parametrize("select, ignore, expected", [
    ("H001", "H", ["H001"]),                     # the example
    ("H", "H001", ["H002", "H003", "H004"]),
    ("H", "heartbeat-timeout", ["H002", "H003", "H004"]),
    ("heartbeat-timeout", "H", ["H001"]),
    ("H00", "H", ["H001", "H002", "H003", "H004"]),       # a longer prefix is more specific
    ("H", "H00", []),
    ("H", "H", []),                              # equal specificity: --ignore wins
    ("H001", "heartbeat-timeout", []),
])
def test_more_specific_pattern_wins(select: str, ignore: str, expected: list[str]) -> None:
    assert codes(select=select, ignore=ignore) == expected


def test_ignore_without_select_keeps_the_profile() -> None:
    everything = [r.code for r in RULES]
    assert codes() == everything
    assert codes(ignore="I") == [c for c in everything if not c.startswith("I")]
    # a rule the profile turns off runs only when selected
    assert "S002" not in codes(profile="lenient")
    assert "S002" in codes(select="S", profile="lenient")
    assert "S002" in codes(select="pdo-to-not-operational", profile="lenient")


def test_unknown_pattern_is_an_error() -> None:
    with pytest.raises(UsageError, match="heartbeat-timeot"):
        codes(select="heartbeat-timeot")


def test_cli_ignore_prefix_select_code(tmp_path: Path) -> None:
    res = run("check", str(HB_LOSS), "--ignore", "H", "--select", "H001", "--format", "json",
              cwd=tmp_path)
    assert res.returncode == 1
    assert [f["rule"] for f in json.loads(res.stdout)["findings"]] == ["H001"]
    res = run("check", str(HB_LOSS), "--ignore", "heartbeat-timeout", cwd=tmp_path)
    assert res.returncode == 0


def test_rules_command_takes_a_name(tmp_path: Path) -> None:
    res = run("rules", "skipped-records", cwd=tmp_path)
    assert res.returncode == 0 and res.stdout.startswith("I003 skipped-records")
    assert "max_skipped" in res.stdout


# -q, concise without the node twice, colour, several timelines, grouped help (issue 23, 13) --

def test_quiet_prints_only_the_findings_and_the_verdict(tmp_path: Path) -> None:
    out = run("check", str(HB_LOSS), "-q", cwd=tmp_path).stdout.splitlines()
    assert out[0] == f"  {HB_LOSS} can0 node 3:"  # no input line, counts, node table, events
    assert [x for x in out if x.strip()][-1].startswith("FAIL: 1 error")
    assert all("frames" not in x and "node events" not in x for x in out)
    assert len([x for x in out if " H001 " in x]) == 1


def test_concise_does_not_repeat_the_node(tmp_path: Path) -> None:
    line = run("check", str(HB_LOSS), "--format", "concise", cwd=tmp_path).stdout.splitlines()[0]
    m = CONCISE.match(line)
    assert m is not None and m["rest"].startswith("no heartbeat from node 3 for"), line
    assert line.count("node 3") == 1


@pytest.mark.parametrize("fmt", ["text", "concise"])
def test_colour_always_never_and_no_color(fmt: str, tmp_path: Path) -> None:
    """Colour on a terminal (auto), `--color always` also into a pipe; `NO_COLOR` and
    `--color never` none; the severities and verdict are coloured, never a message."""
    def out(*extra: str, env: dict[str, str] | None = None) -> str:
        import os

        return subprocess.run([sys.executable, "-m", "nmtcheck", "check", str(HB_LOSS),
                               "--format", fmt, *extra], cwd=tmp_path, capture_output=True,
                              text=True, timeout=120, env={**os.environ, **(env or {})}).stdout

    coloured = out("--color", "always")
    assert "\x1b[31merror\x1b[0m" in coloured and "\x1b[1;31mFAIL\x1b[0m" in coloured
    assert "\x1b" not in out()  # auto, into a pipe
    assert "\x1b" not in out("--color", "never")
    plain = coloured.replace("\x1b[31m", "").replace("\x1b[1;31m", "").replace("\x1b[0m", "")
    assert plain == out()


def test_colour_auto_on_a_terminal_respects_no_color(monkeypatch: pytest.MonkeyPatch) -> None:
    import io

    from nmtcheck.reporters import colour

    class Tty(io.StringIO):
        def isatty(self) -> bool:
            return True

    monkeypatch.delenv("NO_COLOR", raising=False)
    monkeypatch.setenv("TERM", "xterm")
    assert colour.wanted("auto", Tty()) and not colour.wanted("auto", io.StringIO())
    monkeypatch.setenv("NO_COLOR", "1")
    assert not colour.wanted("auto", Tty()) and colour.wanted("always", Tty())


def test_timeline_takes_several_logs_and_orders_events_among_states(tmp_path: Path) -> None:
    log = tmp_path / "emcy.log"
    log.write_text(candump([(0.0, "705#00"), (0.1, "705#7F"), (0.35, "085#1000010000000000"),
                            (0.5, "000#0105"), (0.6, "705#05")]))
    res = run("timeline", str(HEALTHY), str(log), cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    text = res.stdout
    assert text.index(f"{HEALTHY}: times") < text.index(f"{log}: times")
    mine = text[text.index(f"{log}: times"):].splitlines()
    states = [k for k, x in enumerate(mine) if ".." in x]
    event = next(k for k, x in enumerate(mine) if "event:" in x)
    assert states[0] < event < states[-1], mine  # between PRE-OPERATIONAL and OPERATIONAL
    rows = json.loads(run("timeline", str(HEALTHY), str(log), "--format", "json",
                          cwd=tmp_path).stdout)
    assert {r["input"] for r in rows} == {str(HEALTHY), str(log)}


def test_check_help_groups_the_fleet_options(tmp_path: Path) -> None:
    text = run("check", "--help", cwd=tmp_path).stdout
    head, _sep, fleet = text.partition("\nFleet options")
    assert fleet, text
    for flag in ("--results", "--executor", "--manifest", "--path-pattern", "--on-input-error"):
        assert flag in fleet and flag not in head
    assert "--select" in head and "--select" not in fleet
