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

# Lely CANopen (lely-core) master and slaves on Lely's virtual CAN (samples/lely/). The
# network file gives the master's DCF with its consumer times (1016h, 300 ms): with it,
# H001 fires when the real master timed out; without it nmtcheck can only assume
# 1.5 x the producer time (150 ms), so the same silences are found earlier.
LELY: dict[str, Expected] = {
    "healthy": [],  # common power-on; the master's boot-up, reset-all, SDO configuration
    "late_master": [],  # slaves boot 3 s before the master and stay silent (1017h = 0)
    "broadcast": [],  # pre-operational/start to all; the master stays OPERATIONAL
    "stop_start_sdo": [],  # the stopped node ignores an SDO request; the client aborts
    # node 4 (guarded) unplugged: guarding timeout, reset by the master, back without boot-up
    "unplugged_guarded": [("G002", 4, 5.09, 5.11), ("B001", 4, 7.00, 7.01)],
    # node 3 unplugged: heartbeat timeout (the master's 300 ms), misses the reset, comes back
    "unplugged_heartbeat": [("H001", 3, 5.19, 5.21), ("B001", 3, 6.99, 7.01)],
    "reboot": [("B002", 3, 5.13, 5.14)],  # spontaneous reboot within the consumer time
    # node 2's application sets its own 1017h to 250 ms (configured 100 ms, consumer 300 ms)
    "self_1017": [("H003", 2, 9.74, 9.76)],
}
LELY_BARE: dict[str, Expected] = {  # where the verdict without the network file differs
    "unplugged_heartbeat": [("H001", 3, 5.04, 5.06), ("B001", 3, 6.99, 7.01)],
    "reboot": [("H001", 3, 5.04, 5.06), ("B002", 3, 5.13, 5.14)],  # 235 ms > 150 ms
    "self_1017": [("H001", 2, 4.14, 9.91)] * 24 + [("H003", 2, 9.74, 9.76)],
}

CASES = [("canopen_master", name, exp, exp) for name, exp in CANOPEN_MASTER.items()] + [
    ("lely", name, LELY_BARE.get(name, exp), exp) for name, exp in LELY.items()]


def _check(path: Path, network: Path | None) -> InputResult:
    profile = load_profile("default")
    net = load_network(str(network)) if network else None
    return check_input(str(path), 0, profile, select_rules(profile, [], []), network=net)


@pytest.mark.parametrize("with_network", [False, True], ids=["bare", "network"])
@pytest.mark.parametrize(("stack", "name", "bare", "networked"), CASES,
                         ids=[f"{s}/{n}" for s, n, _b, _e in CASES])
def test_real_stack_sample(stack: str, name: str, bare: Expected, networked: Expected,
                           with_network: bool) -> None:
    folder = SAMPLES / stack
    res = _check(folder / f"{name}.log", folder / "network.toml" if with_network else None)
    assert res.stats.skipped == 0 and res.stats.frames > 100
    start = res.stats.start or 0.0
    got = [(f.rule, f.node, round(f.time - start, 4)) for f in res.findings]
    expected = list(networked if with_network else bare)
    assert len(got) == len(expected), got
    for rule, node, t in got:  # each finding uses up one expectation it fits
        fit = next((e for e in expected if e[:2] == (rule, node) and e[2] <= t <= e[3]), None)
        assert fit is not None, (rule, node, t, got)
        expected.remove(fit)
    (cm,) = res.model.channels
    assert cm.master is not None and cm.master.node == 1
    assert cm.master.source == ("network" if with_network else "inferred")


def test_every_recorded_log_has_an_expectation() -> None:
    for stack, table in (("canopen_master", CANOPEN_MASTER), ("lely", LELY)):
        logs = {p.stem for p in (SAMPLES / stack).glob("*.log")}
        assert logs == set(table), stack
