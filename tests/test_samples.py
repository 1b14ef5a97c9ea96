"""The recorded samples (real canopen stack over python-can's virtual bus) get their verdicts,
and the candump and ASC recordings of the same traffic give the same findings and timelines."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import SAMPLES

from nmtcheck.engine import check_input, select_rules
from nmtcheck.results import InputResult
from nmtcheck.settings.profiles import load_profile

EXPECTED = {
    "healthy": [],
    "heartbeat_loss": [("H001", 3)],
    "pdo_preop": [("S001", 2)],
    "guard_toggle": [("G001", 5)],
    "ignored_command": [("S004", 4)],
    "reset_no_bootup": [("B003", 3)],
    "sdo_config": [],  # 1017h and a 1016h entry written by SDO at boot, all obeyed
    "ignored_1017": [("H003", 3)],  # node 3 confirms 1017h = 100 ms, heartbeats every 500 ms
}


def _check(path: Path) -> InputResult:
    profile = load_profile("default")
    return check_input(str(path), 0, profile, select_rules(profile, [], []))


@pytest.mark.parametrize("name", sorted(EXPECTED))
@pytest.mark.parametrize("suffix", [".log", ".asc"])
def test_sample_verdict(name: str, suffix: str) -> None:
    res = _check(SAMPLES / f"{name}{suffix}")
    assert res.stats.skipped == 0
    assert [(f.rule, f.node) for f in res.findings] == EXPECTED[name]


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_candump_and_asc_agree(name: str) -> None:
    a, b = _check(SAMPLES / f"{name}.log"), _check(SAMPLES / f"{name}.asc")
    assert a.stats.frames == b.stats.frames

    def findings(r: InputResult) -> list[tuple[str, int | None, float, int | None]]:
        start = r.stats.start or 0.0
        return [(f.rule, f.node, round(f.time - start, 4), f.frame_index) for f in r.findings]

    def timeline(r: InputResult) -> list[tuple[int, str, float, str]]:
        start = r.stats.start or 0.0
        return [(m.node, iv.state, round(iv.start - start, 4), iv.source)
                for m in r.nodes() for iv in m.intervals]

    assert findings(a) == findings(b)
    assert timeline(a) == timeline(b)


def test_healthy_timeline_follows_the_commands() -> None:
    res = _check(SAMPLES / "healthy.log")
    for m in res.nodes():
        states = [iv.state for iv in m.intervals]
        assert states[0] in ("UNKNOWN", "PRE-OPERATIONAL")
        assert "OPERATIONAL" in states and states[-1] == "STOPPED"
        assert m.error_control == "heartbeat"
        assert m.period_s == pytest.approx(0.1, abs=0.005)
    node3 = next(m for m in res.nodes() if m.node == 3)
    # node 3 is sent to pre-operational and started again in the middle
    assert [iv.state for iv in node3.intervals].count("OPERATIONAL") == 2


def test_reset_sample_shows_the_canopen_localnode_defect() -> None:
    """canopen 2.4.1's LocalNode answers a reset by heartbeating 00h with no single boot-up."""
    res = _check(SAMPLES / "reset_no_bootup.log")
    node3 = next(m for m in res.nodes() if m.node == 3)
    assert any(c.is_reset for c in node3.commands)
    assert len(node3.bootups) > 10
    (f,) = res.findings
    assert "boot-up (00h)" in f.message and "times in a row" in f.message
