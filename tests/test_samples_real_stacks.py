"""Samples recorded from real CiA 302 masters give exactly their expected findings.

Each folder under samples/ holds logs recorded from one real stack, with a README
saying what happens on the bus, and a network.toml. For every log the expected
findings are given as (rule, node, window in seconds from the log's first frame); a
finding outside its window, a missing one or any other finding (info included) fails.
Every log is checked with and without its network description, and its channel's
NMT master must be found: named by the network file with it, inferred without it.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import SAMPLES

from nmtcheck.engine import InputResult, check_input, select_rules
from nmtcheck.network import load_network
from nmtcheck.profiles import load_profile

Expected = list[tuple[str, int, float, float]]

# python-canopen 2.4.1 with a CiA 302-style master (samples/record_master_samples.py)
CANOPEN_MASTER: dict[str, Expected] = {
    "healthy": [],
    "late_master": [],  # slaves boot 2 s before the master and stay silent until 1017h
    "broadcast": [],  # pre-operational/start to all; the master does not obey its own
    "period_change": [],  # 1017h 100 -> 300 ms by SDO; the node follows at once
    "reboot": [("B002", 3, 2.26, 2.28)],  # spontaneous reboot of node 3
    # node 3 unplugged: heartbeat timeout, misses the master's reset, comes back running
    "unplugged": [("H001", 3, 2.05, 2.07), ("B001", 3, 3.41, 3.43)],
}

# Lely CANopen (lely-core) master and slaves on Lely's virtual CAN (samples/lely/)
LELY: dict[str, Expected] = {}

CASES = [("canopen_master", name, exp) for name, exp in CANOPEN_MASTER.items()] + [
    ("lely", name, exp) for name, exp in LELY.items()]


def _check(path: Path, network: Path | None) -> InputResult:
    profile = load_profile("default")
    net = load_network(str(network)) if network else None
    return check_input(str(path), 0, profile, select_rules(profile, [], []), network=net)


@pytest.mark.parametrize("with_network", [False, True], ids=["bare", "network"])
@pytest.mark.parametrize(("stack", "name", "expected"), CASES,
                         ids=[f"{s}/{n}" for s, n, _e in CASES])
def test_real_stack_sample(stack: str, name: str, expected: Expected,
                           with_network: bool) -> None:
    folder = SAMPLES / stack
    res = _check(folder / f"{name}.log", folder / "network.toml" if with_network else None)
    assert res.stats.skipped == 0 and res.stats.frames > 100
    start = res.stats.start or 0.0
    got = [(f.rule, f.node, round(f.time - start, 4)) for f in res.findings]
    assert len(got) == len(expected), got
    for (rule, node, t), (e_rule, e_node, lo, hi) in zip(got, expected, strict=True):
        assert (rule, node) == (e_rule, e_node) and lo <= t <= hi, (got, expected)
    (cm,) = res.model.channels
    assert cm.master is not None and cm.master.node == 1
    assert cm.master.source == ("network" if with_network else "inferred")


def test_every_recorded_log_has_an_expectation() -> None:
    for stack, table in (("canopen_master", CANOPEN_MASTER), ("lely", LELY)):
        logs = {p.stem for p in (SAMPLES / stack).glob("*.log")}
        assert logs == set(table), stack
