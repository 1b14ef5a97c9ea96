"""Boot-slave failures recorded from Lely's CiA 302 master (samples/lely/boot/): nmtcheck,
from the frames and the scenario's network.toml alone, reconstructs the letter Lely's own
OnBoot(id, state, es, what) reported, and the proving frame at the moment of that call.

Each log has a sidecar `<name>.onboot.jsonl` written by the recorder (record_boot.cpp):
every OnBoot call with its time on the frames' clock. Lely calls OnBoot in the event-loop
turn that handles the proving frame or the expiry of its wait, so the finding's time (the
proving frame, or the moment a wait expired) lies within TOLERANCE_S of it; on these
recordings the largest difference is 0.15 ms, and two recordings of each scenario
differed by at most 0.23 ms per frame (README there)."""

from __future__ import annotations

import json
from typing import Any

import pytest
from conftest import SAMPLES

from nmtcheck.engine import check_input, select_rules
from nmtcheck.results import InputResult
from nmtcheck.settings.network import load_network
from nmtcheck.settings.profiles import load_profile

BOOT = SAMPLES / "lely" / "boot"
TOLERANCE_S = 0.001

# Every finding of each log with its network.toml: (rule, node, seconds from the first
# frame, line). The P findings carry Lely's letter; the others are what the failures
# leave behind (the master's consumer entries for slaves that never produce, 1017h
# written but no heartbeat, a guarding request nobody answers).
FINDINGS: dict[str, list[tuple[str, int, float, int]]] = {
    # nodes 2-6: another device type, vendor-ID, product code, revision, serial number
    # than the master expects; node 7 matches (booted and started)
    "identity": [("P001", 2, 0.000501, 21), ("P001", 3, 0.000667, 32),
                 ("P001", 4, 0.000743, 41), ("P001", 5, 0.000807, 48),
                 ("P001", 6, 0.000856, 53)] + [("H004", 1, 0.3, 63)] * 5,
    # node 2 refuses 1017h (J), node 3 never heartbeats (K), mandatory node 4 has no SDO
    # server (B after 1F89h = 3 s), mandatory node 5 powers on late (retried, ok)
    "sequence": [("P003", 2, 0.000414, 29), ("H004", 1, 0.3, 44), ("H004", 1, 0.3, 44),
                 ("H004", 1, 0.3, 44), ("H001", 3, 0.300417, 44), ("P004", 3, 0.300417, 44),
                 ("P002", 4, 3.199011, 107)],
    # keep-alive nodes: 2 silent (E), 3 no guarding answer (F), 4 OPERATIONAL (L);
    # node 5 starts itself after its reset (L at error control)
    "keepalive": [("P005", 5, 0.100102, 156), ("P004", 3, 0.100686, 157),
                  ("P005", 4, 0.199505, 158), ("H004", 1, 0.3, 161),
                  ("P004", 2, 0.300666, 162), ("G002", 3, 1.000686, 180)],
}

# Lely's letters per log (from the sidecars, which the tests read; written here too so a
# re-recording that changes them fails loudly): node -> es ("" = booted without error)
LELY: dict[str, dict[int, str]] = {
    "identity": {2: "C", 3: "D", 4: "M", 5: "N", 6: "O", 7: ""},
    "sequence": {2: "J", 3: "K", 4: "B", 5: ""},
    "keepalive": {2: "E", 3: "F", 4: "L", 5: "L"},
}


def _check(name: str) -> InputResult:
    folder = BOOT / name
    profile = load_profile("default")
    return check_input(str(folder / f"{name}.log"), 0, profile, select_rules(profile, [], []),
                       network=load_network(str(folder / "network.toml")))


def _onboot(name: str) -> list[dict[str, Any]]:
    text = (BOOT / name / f"{name}.onboot.jsonl").read_text(encoding="utf-8")
    return [json.loads(line) for line in text.splitlines()]


@pytest.fixture(scope="module", params=list(FINDINGS))
def recording(request: pytest.FixtureRequest) -> tuple[str, InputResult]:
    return request.param, _check(request.param)


def test_sidecar_is_lelys_verdict(recording: tuple[str, InputResult]) -> None:
    name, _res = recording
    calls = _onboot(name)
    assert {c["node"]: c["es"] for c in calls} == LELY[name]
    assert len(calls) == len(LELY[name])  # one call per node


def test_every_finding_pinned(recording: tuple[str, InputResult]) -> None:
    name, res = recording
    start = res.stats.start or 0.0
    assert res.stats.skipped == 0
    got = [(f.rule, f.node, round(f.time - start, 6), f.line) for f in res.findings]
    assert got == FINDINGS[name]


def test_letter_and_time_match_lely(recording: tuple[str, InputResult]) -> None:
    name, res = recording
    assert res.boot is not None
    assert res.boot.channels["vcan0"].manager == "master-dcf"
    for call in _onboot(name):
        node, es, t = call["node"], call["es"], call["time"]
        rep = res.boot.nodes[("vcan0", node)]
        p = [f for f in res.findings if f.node == node and f.rule.startswith("P")]
        if es == "":  # booted: ok, no P finding, and the start Lely sent in the same call
            assert (rep.status, rep.letter, p) == ("ok", None, []), (node, rep.status)
            assert rep.process is not None and rep.process.started_at is not None
            assert abs(rep.process.started_at.time - t) <= TOLERANCE_S
            continue
        assert (rep.letter, rep.letter_source) == (es, "observed"), (node, rep.letter, es)
        assert rep.status == ("ok" if es == "L" else "failed")
        (f,) = p
        assert f.boot_letter == es
        assert abs(f.time - t) <= TOLERANCE_S, (node, es, f.time - t)
        # the proving frame is a frame of the log, not later than Lely's call
        assert f.evidence is not None and f.evidence["time"] <= t + TOLERANCE_S


def test_keepalive_proving_frames() -> None:
    """Lely decides keep-alive by 1F81h bit 4 alone: the slaves' power-on boot-ups come
    after the master's, yet nodes 2 and 3 get a state check (E from the identity answer,
    F from the unanswered RTR), and node 4's first 05h only passes that check: its L is
    the next heartbeat, where Lely's error-control wait ends."""
    res = _check("keepalive")
    assert res.boot is not None
    ev = {f.node: f.evidence["line"] for f in res.findings
          if f.rule.startswith("P") and f.evidence is not None}
    assert ev == {2: 150, 3: 154, 4: 158, 5: 156}
    for node in (2, 3, 4):
        x = res.boot.nodes[("vcan0", node)].process
        assert x is not None and x.keep_alive and x.anchor == "bootup"
    x5 = res.boot.nodes[("vcan0", 5)].process
    assert x5 is not None and not x5.keep_alive and x5.started_at is None


def test_retried_mandatory_boot_is_ok() -> None:
    """Node 5 (mandatory) is probed from the master's 000#8200 on, before its boot-up;
    it misses a whole round of four requests and the 1 s wait, answers after its late
    power-on, and is started: ok, anchored on the reset."""
    res = _check("sequence")
    assert res.boot is not None
    rep = res.boot.nodes[("vcan0", 5)]
    x = rep.process
    assert x is not None and rep.status == "ok" and x.anchor == "reset"
    probes = [s.result for s in x.steps if s.step == "device_type"]
    assert probes[:4] == ["timeout"] * 4 and probes[-1] == "ok"
    assert any(s.step == "bootup" for s in x.steps)


def test_every_boot_recording_has_an_expectation() -> None:
    logs = {p.stem for p in BOOT.glob("*/*.log")}
    assert logs == set(FINDINGS) == set(LELY)
    for name in logs:
        assert (BOOT / name / f"{name}.onboot.jsonl").is_file()
        assert (BOOT / name / "network.toml").is_file()


def test_logs_stay_small() -> None:
    for p in BOOT.glob("*/*.log"):
        assert p.stat().st_size < 300_000, p

