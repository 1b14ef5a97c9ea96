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

from nmtcheck.engine import check_input, select_rules
from nmtcheck.results import InputResult
from nmtcheck.settings.network import load_network
from nmtcheck.settings.profiles import load_profile

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
    # every interval of node 2 from 4 s on (250 ms) exceeds the assumed timeout (1.5 x the
    # 100 ms written by SDO, no consumer time known): one H001 with the count (issue 38)
    "self_1017": [("H001", 2, 4.14, 4.16), ("H003", 2, 9.74, 9.76)],
}

# Lely start-ups of a CiA 302 manager (samples/lely/README.md, "Further recordings"), each
# in its own folder with its network.toml: (bare, with the network file, master inferred
# without it, or None where SPEC §2 infers none)
LELY_MANAGER: dict[str, tuple[Expected, Expected, int | None]] = {
    # keep-alive slave: resets node by node (000#8203..827F), the ~123 absent IDs are no
    # B001; the burst leaves out node-IDs 1 and 2 (the keep-alive slave), so no master
    # can be inferred
    "keepalive/keepalive": ([], [], None),
    # 000#8100 with TPDOs queued before it (2-3 us later): no sign of life, no S001
    "reset_all/reset_all": ([], [], 1),
    # mandatory node 3 lost: the master resets all, itself included (701#00 after its own
    # 000#8100, no B002), then 000#8200, which it ignores; nodes 2 and 4 boot twice, once
    # per reset (no B003); node 3 comes back without a boot-up (B001). With the file the
    # master's RPDOs (182h, 184h) while it waits pre-operational are S002 (info).
    "mandatory/mandatory_lost": (
        [("H001", 3, 5.04, 5.06), ("B001", 3, 6.99, 7.01)],
        [("H001", 3, 5.19, 5.21), ("B001", 3, 6.99, 7.01), ("S002", 1, 5.35, 5.36)], 1),
    # the same, but node 3 reboots: its boot-up answers the resets of 5.20 s
    "mandatory/mandatory_reboot": (
        [("H001", 3, 5.04, 5.06)], [("H001", 3, 5.19, 5.21), ("S002", 1, 5.35, 5.36)], 1),
}

CASES = [("canopen_master", name, exp, exp, 1) for name, exp in CANOPEN_MASTER.items()] + [
    ("lely", name, LELY_BARE.get(name, exp), exp, 1) for name, exp in LELY.items()] + [
    ("lely", name, bare, net, master) for name, (bare, net, master) in LELY_MANAGER.items()]


def _check(path: Path, network: Path | None) -> InputResult:
    profile = load_profile("default")
    net = load_network(str(network)) if network else None
    return check_input(str(path), 0, profile, select_rules(profile, [], []), network=net)


@pytest.mark.parametrize("with_network", [False, True], ids=["bare", "network"])
@pytest.mark.parametrize(("stack", "name", "bare", "networked", "master"), CASES,
                         ids=[f"{s}/{n}" for s, n, _b, _e, _m in CASES])
def test_real_stack_sample(stack: str, name: str, bare: Expected, networked: Expected,
                           master: int | None, with_network: bool) -> None:
    log = SAMPLES / stack / f"{name}.log"
    res = _check(log, log.parent / "network.toml" if with_network else None)
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
    if not with_network and master is None:
        assert cm.master is None and cm.master_note.startswith("not inferred: "), cm.master_note
        return
    assert cm.master is not None and cm.master.node == 1
    assert cm.master.source == ("network" if with_network else "inferred")


def test_every_recorded_log_has_an_expectation() -> None:
    for stack, table in (("canopen_master", CANOPEN_MASTER), ("lely", LELY),
                         ("lely", LELY_MANAGER)):
        logs = {str(p.relative_to(SAMPLES / stack).with_suffix(""))
                for p in (SAMPLES / stack).glob("*/*.log" if table is LELY_MANAGER else "*.log")
                # lely/comm and the LSS logs: test_samples_lely_comm.py, test_samples_lss.py
                if p.parent.name not in ("comm", "lss")}
        assert logs == set(table), stack


# CANopenNode v4 (samples/canopennode/, README there): a master application on
# CANopenNode's own NMT master and SDO client, three slaves that power on heartbeating
# every 1000 ms and are set to 100 ms by SDO. The master applies its own NMT commands
# (boots again after its own 000#8200), so no master can be inferred from the trace:
# without `master = 1` the master's own state changes are S005 (info).
CANOPENNODE: dict[str, Expected] = {
    "healthy": [],  # power-on at 1000 ms, written 100 ms: no H001 on the power-on period
    "late_master": [],  # the slaves heartbeat at 1000 ms for 2 s before the master starts
    "write_1017": [],  # node 4 switched from heartbeat to guarding by 1017h = 0
    "self_start": [],  # node 3 starts itself (TPDO 16 us after its boot-up)
    "master_obeys": [],  # the master boots again after its 000#8200, 7Fh after 000#8000
    "broadcast": [],  # pre-operational/start to all
    "stopped_sdo": [],  # a stopped node ignores SDO; EMCY held until the next start
    "guard_toggle": [("G001", 4, 2.16, 2.17)],  # one repeated toggle (patched build)
    # a second device with node-ID 3 (B002: its boot-up), heartbeats alternate 05h/7Fh
    "duplicate_id": [("B002", 3, 3.52, 3.53), ("N002", 3, 5.50, 5.51)]
    + [("S005", 3, 4.50, 9.51)] * 11,
    # node 3 unplugged: heartbeat timeout (1.5 x 100 ms), back pre-operational, no reset
    "unplugged_heartbeat": [("H001", 3, 5.12, 5.13), ("S005", 3, 7.02, 7.03)],
    "unplugged_guarded": [("G002", 4, 5.17, 5.18), ("S005", 4, 7.08, 7.09)],
    # node 2 powered off and on: heartbeat timeout, then its unannounced boot-up
    "power_cycle": [("H001", 2, 4.11, 4.12), ("B002", 2, 4.60, 4.61)],
    "nmt_direct": [],  # stop, pre-operational, start, reset node/communication to one node
    # the master unplugged: the slaves' consumers fire, they drop to pre-operational
    "master_unplugged": [("H001", 1, 4.50, 4.52), ("S005", 2, 4.51, 4.52),
                         ("S005", 3, 4.51, 4.52), ("G003", 4, 6.07, 6.08),
                         ("S005", 4, 6.07, 6.08)],
    "hb_runtime": [],  # 1017h rewritten while running: each write starts a segment
    "reset_node_all": [],  # 000#8100: every node boots again, the master too
    # guarded node 4 powered off and on: back heartbeating at 1000 ms while the master
    # polls it (no G001 on those heartbeats), answered again once reconfigured
    "guarded_power_cycle": [("G002", 4, 4.17, 4.18), ("B002", 4, 4.30, 4.31),
                            ("G002", 4, 4.47, 4.48)],
    "guarded_power_cycle_stored": [("G002", 4, 4.17, 4.18), ("B002", 4, 4.30, 4.31)],
    "sync_pdo": [],  # SYNC every 50 ms, synchronous TPDOs, node 2 stopped and started
}
CANOPENNODE_NO_MASTER: dict[str, Expected] = {  # the master's own changes are S005
    "guard_toggle": [("S005", 1, 2.26, 2.27)],
    "unplugged_heartbeat": [("S005", 1, 5.27, 5.28)],
    "unplugged_guarded": [("S005", 1, 5.17, 5.18)],
    "guarded_power_cycle": [("S005", 1, 4.17, 4.18)],
    "guarded_power_cycle_stored": [("S005", 1, 4.17, 4.18)],
    "master_unplugged": [("S005", 1, 6.17, 6.18)],
    "hb_runtime": [("S005", 1, 3.30, 3.31)],
    "nmt_direct": [("S005", 1, 5.00, 5.01)],
}
_NETWORKS = {
    "bare": None,
    "network": "",  # as recorded: master = 1, the power-on producer times
    "no-master": "master = 1\n",  # the same without `master =`
    # the producer times the master writes (100 ms), as a DCF of the configured network
    # would give them
    "configured": "heartbeat_ms = 1000     # power-on 1017h\n",
}


@pytest.mark.parametrize("variant", list(_NETWORKS))
@pytest.mark.parametrize("name", list(CANOPENNODE))
def test_canopennode_sample(name: str, variant: str, tmp_path: Path) -> None:
    folder = SAMPLES / "canopennode"
    net_file = folder / ("network_duplicate.toml" if name == "duplicate_id" else "network.toml")
    drop = _NETWORKS[variant]
    if drop is None:
        network = None
    else:
        text = net_file.read_text(encoding="utf-8")
        if drop:
            assert drop in text or name == "duplicate_id"
            text = text.replace(drop, "heartbeat_ms = 100\n" if "1000" in drop else "")
        network = tmp_path / "network.toml"
        network.write_text(text, encoding="utf-8")
    res = _check(folder / f"{name}.log", network)
    assert res.stats.skipped == 0
    start = res.stats.start or 0.0
    got = [(f.rule, f.node, round(f.time - start, 4)) for f in res.findings]
    master_known = variant in ("network", "configured") and name != "duplicate_id"
    expected = list(CANOPENNODE[name])
    if not master_known:
        expected += CANOPENNODE_NO_MASTER.get(name, [])
    assert len(got) == len(expected), got
    for rule, node, t in got:
        fit = next((e for e in expected if e[:2] == (rule, node) and e[2] <= t <= e[3]), None)
        assert fit is not None, (rule, node, t, got)
        expected.remove(fit)
    (cm,) = res.model.channels
    if master_known:
        assert cm.master is not None and (cm.master.node, cm.master.source) == (1, "network")
    else:  # it obeys its own broadcasts: nothing shows it sent them
        assert cm.master is None


def test_every_canopennode_log_has_an_expectation() -> None:
    assert {p.stem for p in (SAMPLES / "canopennode").glob("*.log")} == set(CANOPENNODE)


# -- the same recordings pasted without timestamps (SPEC §1) ------------------------------

TIMELESS_CASES = sorted(
    [p for p in (SAMPLES / "lely").rglob("*.log") if "boot" not in p.parts]
    + list((SAMPLES / "canopennode").glob("*.log")) + list(SAMPLES.glob("*.log")))


def _screen_output(log: Path, out: Path) -> None:
    """`log` (candump -L) as `candump can0` prints it without -t: one frame a line, so the
    line numbers stay the same."""
    lines = []
    for line in log.read_text().splitlines():
        _ts, iface, frame, *_direction = line.split()  # python-canopen's: R or T
        cid, _, data = frame.partition("#")
        if data.startswith("R"):
            lines.append(f"  {iface}  {cid}   [{data[1:] or 0}]  remote request")
        else:
            pairs = " ".join(data[i:i + 2] for i in range(0, len(data), 2))
            lines.append(f"  {iface}  {cid}   [{len(data) // 2}]  {pairs}")
    out.write_text("\n".join(lines) + "\n")


@pytest.mark.parametrize("log", TIMELESS_CASES, ids=lambda p: str(p.relative_to(SAMPLES)))
def test_real_stack_pasted_without_timestamps(log: Path, tmp_path: Path) -> None:
    """Every recording from a real stack, pasted as `candump can0` prints it (no
    timestamps), gives its timestamped findings (same rule, node and line) less those of
    the rules that need time, plus I006: no order-only artefact. A review found Lely's
    and CANopenNode's healthy networks FAIL so: guarding answers with another node's
    frame before them taken for heartbeats (C003, G001, G004), CANopenNode's heartbeat
    queued before a start (S001, S005), frame numbers taken for intervals (N002, B003)."""
    from nmtcheck.engine import TIME_RULES

    network = next((p / "network.toml" for p in log.parents
                    if (p / "network.toml").exists()), None)
    pasted = tmp_path / f"{log.stem}.txt"
    _screen_output(log, pasted)
    timed, timeless = _check(log, network), _check(pasted, network)
    assert timeless.stats.order_only and timeless.stats.frames == timed.stats.frames
    want = sorted((f.rule, f.node, f.line) for f in timed.findings if f.rule not in TIME_RULES)
    got = sorted((f.rule, f.node, f.line) for f in timeless.findings if f.rule != "I006")
    assert got == want


# -- a recording that starts mid-stream, between a guarding request and its answer ---------

_GUARDED = [("canopennode", "master_obeys.log", "704#"), ("lely", "self_1017.log", "704#"),
            ("canopennode", "healthy.log", "704#")]


@pytest.mark.parametrize("folder,name,prefix", _GUARDED, ids=lambda v: str(v))
def test_a_recording_that_starts_with_a_guarding_answer(folder: str, name: str, prefix: str,
                                                        tmp_path: Path) -> None:
    """The log cut so that its first line is node 4's answer to a request the cut left
    out (the recorder started between the two): the answer (`704#85`, `704#05`) was read
    as a heartbeat, then C003 (bit 7 set), G004 (guarding and heartbeats) and H001 "for
    the rest of the trace" for a node that produces no heartbeat. Offline and live."""
    from nmtcheck.live.frames import LiveFrame
    from nmtcheck.live.session import Session

    lines = (SAMPLES / folder / name).read_text().splitlines(keepends=True)
    network = SAMPLES / folder / "network.toml"
    answers = [i for i in range(1, len(lines) - 1)
               if f"{prefix}R" in lines[i - 1] and f" {prefix}" in lines[i]
               and f"{prefix}R" not in lines[i]][5:10]
    assert len(answers) == 5
    original = {f.rule for f in _check(SAMPLES / folder / name, network).findings
                if f.node == 4}
    for first in answers:
        cut = tmp_path / f"cut{first}.log"
        cut.write_text("".join(lines[first:]))
        res = _check(cut, network)
        assert {f.rule for f in res.findings if f.node == 4} <= original, (first, [
            (f.rule, f.line) for f in res.findings])
        session = Session(load_profile("default"), select_rules(load_profile("default"), [],
                                                                []),
                          load_network(str(network)), timer=False)
        for line in lines[first:]:
            stamp, iface, frame = line.split()
            can_id, _, data = frame.partition("#")
            rtr = data.startswith("R")
            payload = b"" if rtr else bytes.fromhex(data)
            session.feed(LiveFrame(float(stamp.strip("()")), iface, int(can_id, 16), False,
                                   rtr, False, False, int(data[1:] or 0) if rtr
                                   else len(payload), payload))
        outcome = session.close()
        assert [(lf.rule, lf.node) for lf in outcome.live
                if lf.certain and lf.confirmed != "confirmed"] == []
