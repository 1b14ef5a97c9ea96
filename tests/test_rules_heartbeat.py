"""Heartbeat rules H001 (heartbeat-timeout) and H002 (heartbeat-too-early)."""

from __future__ import annotations

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


def test_healthy_trace_is_clean(checker):
    assert checker.findings(candump(healthy()), select="H") == []
    assert checker.findings(candump(healthy()), select="H", network=HEALTHY_NET) == []
    assert checker.findings(candump(healthy()), select="H", profile="lenient") == []


# --- H001 -------------------------------------------------------------------------------

def test_h001_gap_complete_list(checker):
    # median period 100 ms, timeout 1.5 x 100 ms after the heartbeat at 0.9 s
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + hb(2, 1.5, 2.0)
    res = checker.run(candump(fr))
    assert [(f.rule, f.node, round(f.time - 1000.0, 3)) for f in res.findings] == [
        ("H001", 2, 1.05)]
    f = res.findings[0]
    assert f.severity == "error" and f.name == "heartbeat-timeout"
    assert "0.600 s" in f.message and "timeout 0.150 s" in f.message
    assert f.frame_index == 10  # the first frame at or after the moment: the heartbeat at 1.5 s


def test_h001_one_finding_per_gap(checker):
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + hb(2, 1.5, 2.0) + hb(2, 2.5, 3.0)
    assert checker.findings(candump(fr), select="H") == [("H001", 2, 1.05), ("H001", 2, 2.05)]


def test_h001_gap_within_timeout_is_clean(checker):
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + hb(2, 1.04, 2.0)
    assert checker.findings(candump(fr), select="H") == []


def test_h001_gap_after_bootup(checker):
    fr = [(0.0, "702#00"), (0.1, "702#7F"), (0.2, "702#7F"), (2.0, "702#00")] + hb(2, 2.1, 3.0)
    assert checker.findings(candump(fr), select="H001") == [("H001", 2, 0.35)]


def test_h001_end_of_trace(checker):
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + hb(3, 0.05, 2.0)
    assert checker.findings(candump(sorted(fr)), select="H") == [("H001", 2, 1.05)]


def test_h001_trace_ends_before_the_timeout(checker):
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + hb(3, 0.05, 1.04)
    assert checker.findings(candump(sorted(fr)), select="H") == []


def test_h001_consumer_time_from_network_file(checker):
    gap_140ms = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + hb(2, 1.04, 2.0)
    gap_250ms = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + hb(2, 1.15, 2.0)
    short = "[nodes.2]\nconsumer_timeout_ms = 120\n"
    long = "[nodes.2]\nconsumer_timeout_ms = 300\n"
    assert checker.findings(candump(gap_140ms), select="H") == []
    assert checker.findings(candump(gap_140ms), select="H", network=short) == [
        ("H001", 2, 1.02)]
    assert checker.findings(candump(gap_250ms), select="H") == [("H001", 2, 1.05)]
    assert checker.findings(candump(gap_250ms), select="H", network=long) == []


def test_h001_consumer_time_wins_over_producer_time(checker):
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + hb(2, 1.1, 2.0)  # gap 200 ms
    net = "[nodes.2]\nheartbeat_ms = 100\nconsumer_timeout_ms = 250\n"
    assert checker.findings(candump(fr), select="H", network=net) == []
    assert checker.findings(candump(fr), select="H", network="[nodes.2]\nheartbeat_ms = 100\n"
                            ) == [("H001", 2, 1.05)]


def test_h001_configured_producer_time(checker):
    # one heartbeat only: a producer because 1017h is configured, timeout 1.5 x 100 ms
    fr = [(0.0, "702#00"), (0.1, "702#7F")] + hb(3, 0.0, 1.0)
    net = "[nodes.2]\nheartbeat_ms = 100\n"
    assert checker.findings(candump(sorted(fr)), select="H", network=net) == [
        ("H001", 2, 0.25)]
    assert checker.findings(candump(sorted(fr)), select="H") == []  # not a known producer


def test_h001_configured_period_beats_measured_one(checker):
    # heartbeats every 100 ms but 1017h says 50 ms: timeout 75 ms
    fr = [(0.0, "702#00")] + hb(2, 0.1, 0.5)
    net = "[nodes.2]\nheartbeat_ms = 50\n"
    assert checker.findings(candump(fr), select="H001", network=net) == [
        ("H001", 2, 0.075), ("H001", 2, 0.175), ("H001", 2, 0.275), ("H001", 2, 0.375)]


def test_h001_timeout_factor_from_profile(checker):
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + hb(2, 1.08, 2.0)  # gap 180 ms
    assert checker.findings(candump(fr), select="H001") == [("H001", 2, 1.05)]
    assert checker.findings(candump(fr), select="H001", profile="lenient") == []


def test_h001_reset_ends_a_gap(checker):
    # node 2 is reset 60 ms after its last heartbeat and boots 0.5 s later: no timeout
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(0.96, "000#8102"), (1.5, "702#00")]
          + hb(2, 1.6, 2.0))
    assert checker.findings(candump(sorted(fr))) == []


def test_h001_reset_after_the_timeout_expired(checker):
    # the master resets node 2 because its heartbeat was lost: the timeout still counts
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.3, "000#8102"), (1.5, "702#00")]
          + hb(2, 1.6, 2.0))
    assert checker.findings(candump(fr)) == [("H001", 2, 1.05)]


def test_h001_not_a_producer_with_a_single_heartbeat(checker):
    fr = [(0.0, "702#00"), (0.1, "702#7F")] + hb(3, 0.0, 2.0)
    assert checker.findings(candump(sorted(fr)), select="H") == []


# --- H002 -------------------------------------------------------------------------------

def test_h002_too_early_complete_list(checker):
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.0, "702#7F"), (1.02, "702#7F"),
                                                  (1.04, "702#7F")] + hb(2, 1.1, 2.0)
    res = checker.run(candump(fr))
    assert [(f.rule, f.node, round(f.time - 1000.0, 3)) for f in res.findings] == [
        ("H002", 2, 1.02)]
    assert res.findings[0].severity == "warning"
    assert "(2 heartbeats)" in res.findings[0].message


def test_h002_configured_period(checker):
    # 1017h = 300 ms but the node sends every 100 ms: one run from the second heartbeat
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0)
    net = "[nodes.2]\nheartbeat_ms = 300\n"
    res = checker.run(candump(fr), select="H002", network=net)
    assert [(f.rule, f.node, round(f.time - 1000.0, 3)) for f in res.findings] == [
        ("H002", 2, 0.2)]
    assert "(8 heartbeats)" in res.findings[0].message


def test_h002_not_first_heartbeat_after_bootup(checker):
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(1.0, "702#00"), (1.01, "702#7F")] + hb(
        2, 1.11, 2.0)
    assert checker.findings(candump(fr), select="H002") == []


def test_h002_not_first_heartbeat_after_nmt_command(checker):
    # enter pre-operational while pre-operational: the stack answers with a heartbeat at once
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(0.905, "000#8002"), (0.91, "702#7F")] + hb(
        2, 1.01, 2.0)
    assert checker.findings(candump(sorted(fr)), select="H002") == []
    broadcast = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(0.905, "000#8000"),
                                                         (0.91, "702#7F")] + hb(2, 1.01, 2.0)
    assert checker.findings(candump(sorted(broadcast)), select="H002") == []


def test_h002_not_for_a_heartbeat_reporting_another_state(checker):
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0, "05") + [(0.91, "702#04")] + hb(2, 1.01, 2.0, "04")
    assert checker.findings(candump(sorted(fr)), select="H002") == []


def test_h002_early_factor_boundary(checker):
    # exactly 0.5 x 100 ms is not "closer than" the limit
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(0.95, "702#7F")] + hb(2, 1.0, 2.0)
    assert checker.findings(candump(sorted(fr)), select="H002") == []
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(0.949, "702#7F")] + hb(2, 1.0, 2.0)
    assert checker.findings(candump(sorted(fr)), select="H002") == [("H002", 2, 0.949)]
