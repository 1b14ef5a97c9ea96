"""Strict causality (SPEC §9.3.1-9.3.3): a cause begins at or before the moment its effect
began (t_e); everything later is a reaction with a role. Checked on every recorded sample
(with its network file where it has one, and without) and on small traces whose t_e is
known by construction."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

import pytest
from conftest import SAMPLES, Checker

from nmtcheck.engine import check_input, select_rules
from nmtcheck.reporters import csv as csv_report
from nmtcheck.reporters import json as json_report
from nmtcheck.reporters import text
from nmtcheck.settings.network import load_network
from nmtcheck.settings.profiles import load_profile

PROFILE = load_profile("default")
RULES = select_rules(PROFILE, [], [])
ROLES = {"during", "report", "response", "bus"}
# the sample logs as they are recorded (text logs; the .asc copies hold the same frames)
LOGS = sorted(p for p in SAMPLES.rglob("*.log"))
EPS = 1e-6


def _network(log: Path) -> Path | None:
    for folder in (log.parent, *log.parents):
        if (folder / "network.toml").is_file():
            return folder / "network.toml"
        if folder == SAMPLES:
            return None
    return None


def _reports(log: Path) -> list[dict[str, Any]]:
    nets = [None] + ([_network(log)] if _network(log) else [])
    out = []
    for net in nets:
        res = check_input(str(log), 0, PROFILE, RULES,
                          load_network(str(net)) if net is not None else None)
        out.append(json.loads(json_report.render([res], {})))
    return out


@pytest.mark.parametrize("log", LOGS, ids=lambda p: str(p.relative_to(SAMPLES)))
def test_no_cause_after_its_finding_in_any_sample(log: Path) -> None:
    """Walks the JSON report of every sample: no cause is dated after its finding (t_e is
    at most t_f), every reaction has a role, `during` ones lie up to the finding and the
    others after it, and no kind `reboot` is ever a cause."""
    for report in _reports(log):
        for f in report["findings"]:
            if f.get("causes") is None:
                assert "reactions" not in f
                continue
            for c in f["causes"]:
                assert c["kind"] != "reboot", (f["rule"], c)
                assert c["time"] <= f["time"] + EPS, (log.name, f["rule"], f["time"], c)
            for r in f["reactions"]:
                assert r["role"] in ROLES, r
                if r["role"] == "during":
                    assert r["time"] <= f["time"] + EPS, (log.name, f["rule"], r)
                else:
                    assert r["time"] > f["time"] - EPS, (log.name, f["rule"], r)
            assert f["causes_omitted"] >= 0 and f["reactions_omitted"] >= 0


def test_lely_master_reset_after_a_heartbeat_timeout_is_its_response() -> None:
    """The field example of SPEC §9.3.7: Lely's master resets node 3 0.13 ms after its
    heartbeat timeout. The reset answers the timeout: `after:`, role `response`, never a
    cause."""
    log = SAMPLES / "lely" / "unplugged_heartbeat.log"
    res = check_input(str(log), 0, PROFILE, RULES, load_network(str(_network(log))))
    [h] = [f for f in res.findings if f.rule == "H001" and f.node == 3]
    assert not [c for c in h.causes or [] if c["kind"] == "nmt" and c["time"] > h.time]
    resets = [r for r in h.reactions or []
              if r["kind"] == "nmt" and "reset node to node 3" in r["text"]]
    assert resets and all(r["role"] == "response" and r["time"] > h.time for r in resets)
    out = text.render([res], {})
    assert any(line.lstrip().startswith("after:") and "NMT reset node to node 3" in line
               and line.endswith("[response]") for line in out.splitlines())


# node 5 beats every 100 ms; its last heartbeat is at 10.3 s, so the first missing one was
# due at 10.4 s (t_e) and the measured timeout (150 ms) fires at 10.45 s (t_f)
BEATS = "".join(f"({10 + k / 10:.6f}) can0 705#05\n" for k in range(4))


def test_between_the_missed_heartbeat_and_the_timeout_is_during(checker: Checker) -> None:
    """A command to node 5 before the first missed heartbeat was due is a cause; one after
    it, before the timeout fired, is a reaction `during` the effect; the master's reset
    after the timeout is its `response`, and the node's boot-up its `report`."""
    log = (BEATS + "(10.350000) can0 000#8005\n(10.420000) can0 000#0105\n"
           "(10.500000) can0 000#8105\n(10.600000) can0 705#00\n")
    res = checker.run(log)
    [h] = [f for f in res.findings if f.rule == "H001"]
    assert round(h.time, 6) == 10.45
    assert [(c["kind"], c["time"]) for c in h.causes or []] == [("nmt", 10.35)]
    got = [(r["kind"], r["time"], r["role"]) for r in h.reactions or []]
    assert ("nmt", 10.42, "during") in got
    assert ("nmt", 10.5, "response") in got
    assert ("reboot", 10.6, "report") in got


def test_a_stretch_that_began_before_the_effect_is_a_cause(checker: Checker) -> None:
    """Node 2 keeps beating every 50 ms; the channel then falls silent from 10.30 s to
    10.90 s: the silence began before node 5's first missed heartbeat (10.40 s) and lasts
    beyond it, so it is a cause, by its start. Node 2's consumers wait 1 s, longer than the
    silence, so it is no recording gap (I007) and node 5 is judged inside it."""
    other = "".join(f"({10 + k / 20:.6f}) can0 702#05\n" for k in range(7))
    log = "".join(sorted((BEATS + other).splitlines(keepends=True))) + (
        "(10.900000) can0 702#05\n(10.950000) can0 705#05\n")
    res = checker.run(log, network="[nodes.2]\nconsumer_timeout_ms = 1000\n")
    assert not [f for f in res.findings if f.rule == "I007"]
    [h] = [f for f in res.findings if f.rule == "H001" and f.node == 5]
    silences = [c for c in h.causes or [] if c["kind"] == "silence"]
    assert [(c["time"], c["end"]) for c in silences] == [(10.3, 10.9)]
    assert not [r for r in h.reactions or [] if r["kind"] == "silence"]


def test_reactions_have_their_own_cap(checker: Checker) -> None:
    """causes_max caps causes and reactions apart; what each left out is counted."""
    resets = "".join(f"({10.5 + k / 100:.6f}) can0 000#8105\n" for k in range(8))
    res = checker.run(BEATS + resets + "(11.000000) can0 705#00\n")
    [h] = [f for f in res.findings if f.rule == "H001"]
    assert h.causes == [] and h.causes_omitted == 0
    assert len(h.reactions or []) == 5 and h.reactions_omitted == 4  # 8 resets + reboot
    out = text.render([res], {})
    assert "        after: ... 4 more" in out


def test_csv_keeps_causes_and_reactions_as_json(checker: Checker) -> None:
    """SPEC §9.3.6: the CSV report carries `causes` and `reactions` as JSON strings, empty
    for a rule that has none."""
    log = (BEATS + "(10.350000) can0 000#8005\n(10.500000) can0 000#8105\n"
           "(10.600000) can0 705#00\n")
    res = checker.run(log)
    rows = list(csv.DictReader(io.StringIO(csv_report.render([res], {}))))
    [h] = [r for r in rows if r["rule"] == "H001"]
    assert [c["kind"] for c in json.loads(h["causes"])] == ["nmt"]
    assert [(c["kind"], c["role"]) for c in json.loads(h["reactions"])] == [
        ("nmt", "response"), ("reboot", "report")]
    assert all(r["causes"] == "" and r["reactions"] == "" for r in rows
               if r["rule"] not in ("H001", "B002"))
