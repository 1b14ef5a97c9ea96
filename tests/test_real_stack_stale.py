"""Stale frames around reset commands and a boot retried after a failure, as real stacks
send them (issue 37 item 7): SPEC §2 stale reports (guarding answers and the one stale
boot-up) and SPEC_BOOT §8.1.2/§8.3.2 (a boot-up after a failed boot starts a new process).

Each trace is small candump -L text written here, checked through the public engine; where
the live tracker judges the rule (G001, B002, B003), it must agree with the offline check.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from conftest import Checker, candump
from traces import hb

from nmtcheck.engine import select_rules
from nmtcheck.live.frames import LiveFrame
from nmtcheck.live.session import Session
from nmtcheck.readers import InputStats
from nmtcheck.readers.candump import _parse_line
from nmtcheck.settings.profiles import load_profile

PROFILE = load_profile("default")
RULES = select_rules(PROFILE, [], [])


def live(text: str, tmp_path: Path) -> list[tuple[str, int | None]]:
    """(rule, node) of every live finding of `text` fed frame by frame (no timer); a
    certain one that the offline check of the recording does not confirm fails here."""
    session = Session(PROFILE, RULES, None, str(tmp_path / "live.log"), timer=False)
    stats = InputStats("x")
    for lineno, raw in enumerate(text.encode().splitlines(keepends=True), 1):
        row = _parse_line(raw, lineno, stats)
        if row is not None:
            ts, iface, cid, ext, rtr, err, fd, dlc, data = row
            session.feed(LiveFrame(ts, iface.decode(), cid, ext, rtr, err, fd, dlc, data))
    outcome = session.close()
    assert [(lf.rule, lf.node) for lf in outcome.live
            if lf.certain and lf.confirmed != "confirmed"] == []
    return [(lf.rule, lf.node) for lf in outcome.live]


# --- 1. a guarding answer that left the device before the reset reached it -------------

def guarded(tail: list[tuple[float, str]]) -> str:
    """Node 4, started and guarded every 100 ms, answers 05h with toggles 0, 1, 0; then a
    request at 0.4 and `000#8104` 50 us later; `tail` is what node 4 sends after that."""
    fr = [(0.0, "704#00"), (0.01, "000#0104")]
    for i, answer in enumerate(("05", "85", "05")):
        t = 0.1 * (i + 1)
        fr += [(t, "704#R"), (t + 0.002, f"704#{answer}")]
    fr += [(0.4, "704#R"), (0.40005, "000#8104")]
    return candump(fr + tail)


# the answer (toggle 1, after the toggle-0 answer at 0.302) goes out 0.1 ms after the reset
# command; the boot-up follows, then guarding again from toggle 0
QUEUED_ANSWER = [(0.40015, "704#85"), (0.402, "704#00"), (0.5, "704#R"), (0.502, "704#7F"),
                 (0.6, "704#R"), (0.602, "704#FF")]


def test_g001_answer_queued_before_the_reset_keeps_the_old_toggle(checker: Checker,
                                                                  tmp_path: Path) -> None:
    # SPEC §2: within obey_ms of the reset it reports the state from before it (05h): stale,
    # it alternates with the answer before the reset, no G001 (before: G001 at 0.40015)
    text = guarded(QUEUED_ANSWER)
    assert checker.findings(text) == []
    assert live(text, tmp_path) == []


@pytest.mark.parametrize(("tail", "expected"), [
    # the queued answer repeats the toggle of the answer before the reset
    ([(0.40015, "704#05"), (0.402, "704#00"), (0.5, "704#R"), (0.502, "704#7F")],
     [("G001", 4, 0.4)]),
    # after the boot-up the first answer must still have toggle 0
    ([(0.40015, "704#85"), (0.402, "704#00"), (0.5, "704#R"), (0.502, "704#FF")],
     [("G001", 4, 0.502)]),
    # no boot-up: the reset, processed after the queued answer, still restarts the toggle
    ([(0.40015, "704#85"), (0.5, "704#R"), (0.502, "704#85")],
     [("B001", 4, 0.502), ("G001", 4, 0.502)]),
    ([(0.40015, "704#85"), (0.5, "704#R"), (0.502, "704#05")], [("B001", 4, 0.502)]),
    # an answer later than obey_ms after the reset is no stale report: toggle 0 expected
    ([(0.52, "704#85"), (0.55, "704#00"), (0.6, "704#R"), (0.602, "704#7F")],
     [("B001", 4, 0.52), ("G001", 4, 0.52)]),
], ids=["queued-repeat", "after-bootup", "no-bootup-repeat", "no-bootup-ok", "late-answer"])
def test_g001_still_fires_around_a_reset(checker: Checker, tmp_path: Path,
                                         tail: list[tuple[float, str]],
                                         expected: list[tuple[str, int, float]]) -> None:
    text = guarded(tail)
    assert checker.findings(text) == expected
    assert sorted(live(text, tmp_path)) == sorted((r, n) for r, n, _t in expected)


def test_g001_clean_guarding_across_a_reset_is_silent(checker: Checker) -> None:
    text = guarded([(0.402, "704#00"), (0.5, "704#R"), (0.502, "704#7F"), (0.6, "704#R"),
                    (0.602, "704#FF")])
    assert checker.findings(text) == []


# --- 2. a device that powers on while the master's 000#8200 is on the bus --------------

def powers_on(node3: list[tuple[float, str]], command: str = "000#8200") -> str:
    """Master 1 and node 2 boot at 0 and send heartbeats; `command` at 0.5 (node 2 boots
    again 0.3 ms after a broadcast reset); node 3 sends `node3`, then heartbeats from 1 s."""
    fr = ([(0.0, "701#00"), (0.0001, "702#00"), (0.5, command)] + hb(1, 0.1, 3.0, "05")
          + node3 + hb(3, 1.0, 3.0))
    if command == "000#8200":
        fr += [(0.5003, "702#00"), *hb(2, 0.1001, 0.5), *hb(2, 0.6001, 3.0)]
    else:
        fr += hb(2, 0.1001, 3.0)
    return candump(sorted(fr))


# CANopenNode: node 3's power-on boot-up 0.2 ms after the command, its answer 0.3 ms later
POWER_ON = [(0.5002, "703#00"), (0.5005, "703#00")]


@pytest.mark.parametrize("command", ["000#8200", "000#8203"], ids=["broadcast", "direct"])
def test_power_on_bootup_during_a_reset_is_no_repeat(checker: Checker, tmp_path: Path,
                                                     command: str) -> None:
    # SPEC §2 (amended 2026-12-07): node 3's first frame, within obey_ms of a reset to it
    # (a broadcast although node 3 was not seen yet), its next boot-up within obey_ms: the
    # first is stale, neither is B003 nor B002 (before: B003 at 0.5005)
    text = powers_on(POWER_ON, command)
    assert checker.findings(text) == []
    assert live(text, tmp_path) == []


@pytest.mark.parametrize(("node3", "expected"), [
    # a second boot-up 300 ms later: a spontaneous reboot, judged as before
    ([(0.5002, "703#00"), (0.8, "703#00")], [("B003", 3, 0.8)]),
    # the first boot-up 150 ms after the command: not stale
    ([(0.65, "703#00"), (0.6505, "703#00")], [("B003", 3, 0.65)]),
    # node 3 was seen before: the broadcast explains its first boot-up, not the second
    ([(0.3, "703#7F"), (0.5002, "703#00"), (0.5005, "703#00")], [("B003", 3, 0.5)]),
    # a third boot-up within the repeat window repeats the answer
    ([*POWER_ON, (0.6, "703#00")], [("B003", 3, 0.6)]),
], ids=["slow-second", "late-first", "seen-before", "third"])
def test_b003_still_fires_for_a_real_repeat(checker: Checker, tmp_path: Path,
                                            node3: list[tuple[float, str]],
                                            expected: list[tuple[str, int, float]]) -> None:
    text = powers_on(node3)
    assert checker.findings(text, select="B") == expected
    assert [f for f in live(text, tmp_path) if f[0].startswith("B")] == [
        (r, n) for r, n, _t in expected]


@pytest.mark.parametrize("heartbeats", [True, False], ids=["heartbeats", "bootups-only"])
def test_power_on_bootup_changes_no_state(checker: Checker, heartbeats: bool) -> None:
    """The stale boot-up is no evidence (SPEC §2): node 3 is UNKNOWN until the boot-up that
    answers the reset (the walk, and the shortcut for a node of boot-ups only)."""
    fr = [(0.0, "701#00"), (0.5, "000#8200"), *POWER_ON, *hb(1, 0.1, 3.0, "05")]
    res = checker.run(candump(sorted(fr + (hb(3, 1.0, 3.0) if heartbeats else []))))
    node3 = next(m for m in res.nodes() if m.node == 3)
    first = next(iv for iv in node3.intervals if iv.state != "UNKNOWN")
    assert (first.state, round(first.start - 1000.0, 6)) == ("PRE-OPERATIONAL", 0.5005)
    assert res.findings == []


# --- 3. a mandatory slave that fails its boot with B and boots after a power cycle -----

BOOT_NET = ("master = 1\n[boot]\nmanager = true\nboot_time_ms = 3000\n[nodes.4]\n"
            "mandatory = true\nmanager_consumer_ms = 300\n")


def failed_then_booted(power_cycle: bool = True) -> str:
    """As samples/lely/boot/sequence node 4 (mandatory, no SDO answer, 1F89h = 3000 ms):
    the power-on boot-up, `000#8200`, the boot-up answering it, then rounds of 4 probes
    of 1000h (`604#40 00 10 00`) each aborted after 100 ms (`604#80 ... 05040000h`) with
    1 s between rounds; Lely reports B at the end of the third round (3.2 s). The master
    stays PRE-OPERATIONAL (heartbeat 7Fh every 200 ms). With `power_cycle`, node 4 boots
    again at 9.0 s, answers the probe and the identity reads, takes its configuration,
    sends its first heartbeat, and is started at 9.1 s (Lely: booted)."""
    fr = [(0.0, "701#00"), (0.000004, "704#00"), (0.000016, "000#8200"),
          (0.000241, "704#00")]
    t = 0.000021
    for _round in range(3):
        for _probe in range(4):
            fr += [(t, "604#4000100000000000"), (t + 0.1, "604#8000100000000405")]
            t = round(t + 0.100015, 6)
        t = round(t + 1.0, 6)
    fr += hb(1, 0.2, 10.01, "7F", period=0.2)
    if power_cycle:
        fr += [(9.0, "704#00"), (9.000020, "604#4000100000000000"),
               (9.000035, "584#4300100092010200"), (9.000050, "604#4018100200000000"),
               (9.000065, "584#4318100201000000"), (9.000080, "604#4018100300000000"),
               (9.000095, "584#4318100301000000"), (9.000110, "604#2316100158020100"),
               (9.000125, "584#6016100100000000"), (9.000140, "604#2B17100064000000"),
               (9.000155, "584#6017100000000000"), (9.1, "704#7F"),
               (9.100020, "000#0104")] + hb(4, 9.2, 10.0, "05")
    return candump(sorted(fr))


def _p_and_b(res: Any) -> list[tuple[str, int | None, float]]:
    """(rule, node, seconds from 0 of the trace, to the µs) of every finding."""
    return [(f.rule, f.node, round(f.time - 1000.0, 6)) for f in res.findings]


def test_boot_after_a_failed_boot_is_a_new_process(checker: Checker) -> None:
    # SPEC_BOOT §8.1.2 item 5 / §8.3.2: the first process failed B (P002, its probes
    # stopped at 3.2 s); the boot-up at 9.0 s starts a new one, which ends ok with the
    # start at 9.1 s. Before: one process `FAILED B` at 9.1 s, and P006 instead of P002.
    res = checker.run(failed_then_booted(), network=BOOT_NET)
    assert _p_and_b(res) == [("P002", 4, 3.200186), ("B002", 4, 9.0)]
    p002 = next(f for f in res.findings if f.rule == "P002")
    assert p002.boot_letter == "B" and "network boot halted" in p002.message
    assert res.boot is not None
    rep = res.boot.nodes[("can0", 4)]
    assert (rep.status, rep.letter, rep.processes) == ("ok", None, 2)
    x = rep.process
    assert x is not None and x.started_at is not None
    assert (x.anchor, round(x.start - 1000.0, 6)) == ("bootup", 9.0)
    assert round(x.started_at.time - 1000.0, 6) == 9.10002
    assert [s.step for s in x.steps] == ["bootup", "device_type", "product_code",
                                        "revision_number", "config", "config",
                                        "error_control", "start"]


def test_failed_boot_without_a_later_bootup_stays_failed(checker: Checker) -> None:
    res = checker.run(failed_then_booted(power_cycle=False), network=BOOT_NET)
    assert _p_and_b(res) == [("P002", 4, 3.200186)]
    assert res.boot is not None
    rep = res.boot.nodes[("can0", 4)]
    assert (rep.status, rep.letter, rep.processes) == ("failed", "B", 1)


def test_bootup_between_probe_rounds_is_a_retried_boot(checker: Checker) -> None:
    """samples/lely/boot/sequence node 5: it powers on while the manager still probes (the
    probing never stopped): one process, booted after the retry, no finding."""
    net = BOOT_NET.replace("nodes.4", "nodes.5")
    fr = [(0.0, "701#00"), (0.000016, "000#8200")]
    t = 0.000021
    for _probe in range(4):
        fr += [(t, "605#4000100000000000"), (t + 0.1, "605#8000100000000405")]
        t = round(t + 0.100015, 6)
    t = round(t + 1.0, 6)
    fr += [(t, "605#4000100000000000"), (t + 0.088, "705#00"),
           (t + 0.1, "605#8000100000000405"), (t + 0.100015, "605#4000100000000000"),
           (t + 0.100030, "585#4300100092010200"), (t + 0.2, "705#7F"),
           (t + 0.200020, "000#0105")] + hb(1, 0.2, 3.0, "7F", period=0.2) + hb(
        5, t + 0.3, 3.0, "05")
    res = checker.run(candump(sorted(fr)), network=net)
    assert [f for f in _p_and_b(res) if f[0].startswith("P")] == []
    assert res.boot is not None
    rep = res.boot.nodes[("can0", 5)]
    assert (rep.status, rep.processes) == ("ok", 1)
