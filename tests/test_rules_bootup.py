"""Boot-up rules B001 (missing-bootup), B002 (unexpected-bootup), B003 (bootup-repeated)."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import candump

# --- trace helpers (each rule test file carries its own copy) -------------------------

START, STOP, PREOP, RESET4, END = 0.5, 3.0, 4.0, 4.5, 5.0

HEALTHY_NET = "".join(f"[nodes.{n}]\nheartbeat_ms = 100\n" for n in (2, 3, 4, 5, 6)) + (
    "[nodes.7]\nguard_time_ms = 200\nlife_time_factor = 3\n")


def jitter(i: int, node: int) -> float:
    """Deterministic heartbeat jitter, -2..+2 ms."""
    return ((i * 3 + node) % 5 - 2) / 1000.0


def hb(node: int, t0: float, t1: float, state: str = "7F", period: float = 0.1,
       jit: bool = False) -> list[tuple[float, str]]:
    """Heartbeats of `node` reporting `state` from t0 (inclusive) to t1 (exclusive)."""
    out = []
    i = 0
    while (t := t0 + period * i + (jitter(i, node) if jit else 0.0)) < t1 - 1e-9:
        out.append((round(t, 6), f"{0x700 + node:03X}#{state}"))
        i += 1
    return out


def healthy() -> list[tuple[float, str]]:
    """A realistic clean 5 s trace.

    Nodes 2, 3, 4 boot at 0 / 10 / 20 ms, node 5 is already running when the recording
    starts (heartbeat, no boot-up), node 6 is plugged in at 2.0 s and started directly,
    node 7 uses node guarding (every 200 ms, toggling). Heartbeats every 100 ms +-2 ms.
    SDO upload and LSS in PRE-OPERATIONAL, broadcast start at 0.5 s, TPDOs / RPDOs every
    20 ms only while OPERATIONAL (one TPDO still in flight 2 ms after the stop), an EMCY
    and its reset, SYNC and TIME, broadcast stop at 3.0 s, enter pre-operational at 4.0 s,
    reset node 4 at 4.5 s with its boot-up 60 ms later.
    """
    fr: list[tuple[float, str]] = [
        (START, "000#0100"), (2.2, "000#0106"), (STOP, "000#0200"), (PREOP, "000#8000"),
        (RESET4, "000#8104"),
    ]

    def code(t: float, start: float) -> str:
        return "7F" if t < start or t >= PREOP else "05" if t < STOP else "04"

    for n, boot in ((2, 0.0), (3, 0.01), (4, 0.02), (5, None), (6, 2.0)):
        start = 2.2 if n == 6 else START
        if boot is not None:
            fr.append((boot, f"{0x700 + n:03X}#00"))
        t0 = 0.045 if boot is None else boot + 0.1
        t1 = RESET4 if n == 4 else END
        fr += [(t, f[:4] + code(t, start)) for t, f in hb(n, t0, t1, jit=True)]
        t = start + 0.01 + n / 1000
        while t + 0.005 < STOP:
            fr.append((round(t, 6), f"{0x180 + n:03X}#{n:02X}00"))
            fr.append((round(t + 0.005, 6), f"{0x200 + n:03X}#0000"))
            t += 0.02
    fr.append((STOP + 0.002, "182#0200"))  # queued before the stop: within S001 grace_ms
    fr += [(RESET4 + 0.06, "704#00")] + hb(4, RESET4 + 0.16, END, jit=True)
    # node 7: node guarding only
    fr.append((0.03, "707#00"))
    for i, t in enumerate(x / 1000 for x in range(150, 5000, 200)):
        fr.append((t, "707#R"))
        fr.append((t + 0.002, f"707#{(i % 2) << 7 | int(code(t, START), 16):02X}"))
    fr += [(0.2, "602#4018100100000000"), (0.2005, "582#4318100143544D4E"),
           (2.1, "606#4000100000000000"), (2.1005, "586#4300100091010000"),
           (4.3, "604#2B17100064000000"), (4.3005, "584#6017100000000000"),
           (0.25, "7E5#5A00000000000000"), (0.2505, "7E4#5A5A000000000000"),
           (1.5, "083#1000010000000000"), (1.6, "083#0000000000000000"),
           (1.0, "100#00000000A537")]
    fr += [(x / 1000, "080#") for x in range(50, 5000, 50)]
    return sorted(fr, key=lambda x: x[0])


def profile(tmp_path: Path, text: str) -> str:
    path = tmp_path / "profile.toml"
    path.write_text('extends = "default"\n' + text)
    return str(path)


def test_healthy_trace_is_clean(checker):
    assert checker.findings(candump(healthy()), select="B") == []
    assert checker.findings(candump(healthy()), select="B", network=HEALTHY_NET) == []


# --- B001 (a): after a reset command ---------------------------------------------------

def test_b001_heartbeat_before_bootup_complete_list(checker):
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.0, "000#8102")] + hb(2, 1.1, 2.0)
    assert checker.findings(candump(fr)) == [("B001", 2, 1.1)]


@pytest.mark.parametrize("sign", ["182#0102", "582#4318100100000000", "082#0010010000000000"])
def test_b001_tpdo_sdo_emcy_before_bootup(checker, sign):
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.0, "000#8102"), (1.05, sign),
                                                   (1.2, "702#00")] + hb(2, 1.3, 2.0))
    assert checker.findings(candump(fr), select="B") == [("B001", 2, 1.05)]


def test_b001_guarding_response_before_bootup(checker):
    fr = [(0.0, "705#00"), (0.1, "705#R"), (0.102, "705#7F"), (0.2, "705#R"), (0.202, "705#FF"),
          (0.5, "000#8105"), (0.6, "705#R"), (0.602, "705#7F"), (0.7, "705#00")]
    assert checker.findings(candump(fr), select="B001") == [("B001", 5, 0.602)]


def test_b001_broadcast_reset_applies_to_nodes_already_seen(checker):
    # nodes 2 and 3 are seen before the broadcast reset; node 4 only after it
    fr = ([(0.0, "702#00"), (0.01, "703#00")] + hb(2, 0.1, 0.5) + hb(3, 0.11, 0.5)
          + [(0.5, "000#8200"), (0.55, "702#00")] + hb(2, 0.65, 2.0) + hb(3, 0.61, 2.0)
          + hb(4, 0.52, 2.0))
    assert checker.findings(candump(sorted(fr)), select="B") == [("B001", 3, 0.61)]


def test_b001_no_bootup_within_timeout(checker):
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.0, "000#8102")] + hb(3, 0.05, 7.0)
    assert checker.findings(candump(sorted(fr)), select="B001") == [("B001", 2, 6.0)]


def test_b001_bootup_after_the_timeout(checker):
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.0, "000#8102"), (6.5, "702#00")]
          + hb(3, 0.05, 7.0))
    assert checker.findings(candump(sorted(fr)), select="B001") == [("B001", 2, 6.0)]


def test_b001_trace_ends_before_the_timeout(checker):
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.0, "000#8102")] + hb(3, 0.05, 5.9)
    assert checker.findings(candump(sorted(fr)), select="B001") == []


def test_b001_bootup_in_time_is_clean(checker):
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.0, "000#8102"), (1.4, "702#00")]
          + hb(2, 1.5, 7.0))
    assert checker.findings(candump(fr)) == []


def test_b001_newer_reset_restarts_the_wait(checker):
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.0, "000#8102"), (4.0, "000#8102"),
                                                   (8.5, "702#00")] + hb(2, 8.6, 10.0)
          + hb(3, 0.05, 10.0))
    assert checker.findings(candump(sorted(fr)), select="B") == []


def test_b001_bootup_timeout_ms_from_profile(checker, tmp_path):
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.0, "000#8102"), (2.5, "702#00")]
          + hb(2, 2.6, 3.0))
    prof = profile(tmp_path, "[rules.B001]\nbootup_timeout_ms = 1000\n")
    assert checker.findings(candump(fr), select="B001", profile=prof) == [("B001", 2, 2.0)]
    assert checker.findings(candump(fr), select="B001") == []


# --- B001 (b): late start without boot-up ----------------------------------------------

def test_b001_late_start_complete_list(checker):
    fr = [(0.0, "702#00")] + hb(2, 0.1, 3.0) + hb(3, 1.5, 3.0, "05")
    assert checker.findings(candump(sorted(fr))) == [("B001", 3, 1.5)]


def test_b001_early_first_heartbeat_is_clean(checker):
    # recording started while node 3 was running: its first heartbeat within 1 s is fine
    fr = [(0.0, "702#00")] + hb(2, 0.1, 3.0) + hb(3, 0.9, 3.0, "05")
    assert checker.findings(candump(sorted(fr))) == []


def test_b001_late_start_uses_three_heartbeat_periods(checker):
    net = "[nodes.3]\nheartbeat_ms = 500\n"  # late_start = 3 x 500 ms = 1.5 s
    early = [(0.0, "702#00")] + hb(2, 0.1, 4.0) + hb(3, 1.4, 4.0, period=0.5)
    late = [(0.0, "702#00")] + hb(2, 0.1, 4.0) + hb(3, 1.6, 4.0, period=0.5)
    assert checker.findings(candump(sorted(early)), select="B001", network=net) == []
    assert checker.findings(candump(sorted(late)), select="B001", network=net) == [
        ("B001", 3, 1.6)]


def test_b001_late_start_not_when_first_frame_is_not_a_heartbeat(checker):
    with_bootup = [(0.0, "702#00")] + hb(2, 0.1, 3.0) + [(1.5, "703#00")] + hb(3, 1.6, 3.0)
    with_tpdo = [(0.0, "702#00")] + hb(2, 0.1, 3.0) + [(1.5, "183#00")] + hb(3, 1.6, 3.0)
    assert checker.findings(candump(sorted(with_bootup)), select="B001") == []
    assert checker.findings(candump(sorted(with_tpdo)), select="B001") == []


def test_b001_late_start_late_start_ms_from_profile(checker, tmp_path):
    fr = [(0.0, "702#00")] + hb(2, 0.1, 3.0) + hb(3, 1.5, 3.0)
    prof = profile(tmp_path, "[rules.B001]\nlate_start_ms = 2000\n")
    assert checker.findings(candump(sorted(fr)), select="B001", profile=prof) == []


# --- B002 -------------------------------------------------------------------------------

def test_b002_spontaneous_reboot_complete_list(checker):
    fr = [(0.0, "702#00")] + hb(2, 0.1, 2.5) + [(2.5, "702#00")] + hb(2, 2.6, 4.0)
    assert checker.findings(candump(fr)) == [("B002", 2, 2.5)]


@pytest.mark.parametrize("reset", ["000#8102", "000#8202", "000#8100", "000#8200"])
def test_b002_bootup_after_reset_is_clean(checker, reset):
    fr = [(0.0, "702#00")] + hb(2, 0.1, 2.5) + [(2.5, reset), (2.7, "702#00")] + hb(2, 2.8, 4.0)
    assert checker.findings(candump(fr)) == []


def test_b002_each_reset_explains_one_bootup(checker):
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.0, "000#8102"), (1.1, "702#00")]
          + hb(2, 1.2, 3.0) + [(3.0, "702#00")] + hb(2, 3.1, 4.0))
    assert checker.findings(candump(fr)) == [("B002", 2, 3.0)]


def test_b002_reset_older_than_reset_window(checker):
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.0, "000#8102"), (11.5, "702#00")]
          + hb(3, 0.05, 12.0))
    assert checker.findings(candump(sorted(fr)), select="B002") == [("B002", 2, 11.5)]


def test_b002_not_for_first_frame_of_node(checker):
    # node 3 is powered on during the recording: its boot-up is its first frame
    fr = [(0.0, "702#00")] + hb(2, 0.1, 3.0) + [(1.5, "703#00")] + hb(3, 1.6, 3.0)
    assert checker.findings(candump(sorted(fr))) == []


def test_b002_after_other_traffic_of_the_node(checker):
    # node 3 sent a TPDO (state UNKNOWN) before its boot-up: that is a reboot
    fr = [(0.0, "702#00")] + hb(2, 0.1, 3.0) + [(0.3, "183#01"), (1.5, "703#00")] + hb(
        3, 1.6, 3.0)
    assert checker.findings(candump(sorted(fr)), select="B") == [("B002", 3, 1.5)]


def test_b002_never_for_a_b003_repeat(checker):
    fr = [(0.0, "702#00")] + hb(2, 0.1, 2.0) + [(2.0, "702#00"), (2.5, "702#00")] + hb(
        2, 2.6, 3.0)
    assert checker.findings(candump(fr), select="B") == [("B002", 2, 2.0), ("B003", 2, 2.5)]


# --- B003 -------------------------------------------------------------------------------

def test_b003_heartbeat_00_complete_list(checker):
    fr = hb(2, 0.0, 0.5) + [(0.45, "000#8102")] + hb(2, 0.6, 2.0, "00")
    assert checker.findings(candump(sorted(fr))) == [("B003", 2, 0.7)]


def test_b003_one_finding_per_run_reset_splits_runs(checker):
    fr = (hb(2, 0.0, 0.5) + [(0.45, "000#8102")] + hb(2, 0.6, 0.9, "00")
          + [(0.85, "000#8102")] + hb(2, 0.9, 1.5, "00"))
    assert checker.findings(candump(sorted(fr)), select="B") == [("B003", 2, 0.7),
                                                                 ("B003", 2, 1.0)]


def test_b003_window_is_inclusive_and_at_least_one_second(checker):
    exactly = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.0, "702#00")] + hb(2, 1.1, 2.0)
    beyond = [(0.0, "702#00")] + hb(2, 0.1, 1.2) + [(1.2, "702#00")] + hb(2, 1.3, 2.0)
    assert checker.findings(candump(exactly), select="B") == [("B003", 2, 1.0)]
    assert checker.findings(candump(beyond), select="B") == [("B002", 2, 1.2)]


def test_b003_window_is_three_heartbeat_periods(checker):
    net = "[nodes.2]\nheartbeat_ms = 500\n"  # window 1.5 s
    fr = [(0.0, "702#00")] + hb(2, 0.5, 1.4, period=0.5) + [(1.4, "702#00")] + hb(
        2, 1.9, 3.0, period=0.5)
    assert checker.findings(candump(fr), select="B", network=net) == [("B003", 2, 1.4)]


def test_b003_repeat_window_ms_from_profile(checker, tmp_path):
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.0, "702#00")] + hb(2, 1.1, 2.0)
    prof = profile(tmp_path, "[rules.B003]\nrepeat_window_ms = 500\n")
    assert checker.findings(candump(fr), select="B", profile=prof) == [("B002", 2, 1.0)]


def test_b001_tpdo_logged_with_the_resets_timestamp_but_after_it(checker):
    """Sign of life is judged in file order: a TPDO stamped with the reset's own time but
    logged after it still comes before the boot-up."""
    fr = [(0.0, "702#00"), (0.05, "000#0100")] + [(0.1 * i, "702#05") for i in range(1, 10)]
    text = candump(fr) + "(1001.000000) can0 000#8102\n(1001.000000) can0 182#01\n"
    text += candump([(1.05, "702#00")])
    assert checker.findings(text, select="B001") == [("B001", 2, 1.0)]
