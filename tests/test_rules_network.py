"""Network rules N001 (missing-node) and N002 (duplicate-node-id)."""

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


def found(res) -> list[tuple[str, int | None, float]]:
    start = res.stats.start
    return [(f.rule, f.node, round(f.time - start, 3)) for f in res.findings]


def two_devices(offset: float, t1: float = 1.0, state_a: str = "7F", state_b: str = "7F"
                ) -> list[tuple[float, str]]:
    """Two devices, already running, heartbeating as node 5 every 100 ms, the second `offset`
    s after the first and once less (as many short as long intervals: the median period
    is 50 ms, no heartbeat timeout)."""
    return sorted([(0.0, "080#")] + hb(5, 0.1, t1, state_a)
                  + hb(5, 0.1 + offset, t1 - 0.1 + offset, state_b))


def test_healthy_trace_is_clean(checker):
    assert checker.findings(candump(healthy()), select="N") == []
    assert checker.findings(candump(healthy()), select="N", network=HEALTHY_NET) == []
    assert checker.findings(candump(healthy()), network=HEALTHY_NET) == []


# --- N001 -------------------------------------------------------------------------------

def test_n001_missing_node_complete_list(checker):
    fr = [(0.2, "702#00"), (0.21, "703#00")] + hb(2, 0.3, 1.0) + hb(3, 0.31, 1.0)
    net = "[nodes.2]\n[nodes.3]\n[nodes.8]\n"
    res = checker.run(candump(sorted(fr)), network=net)
    assert found(res) == [("N001", 8, 0.0)]
    f = res.findings[0]
    assert (f.severity, f.channel, f.frame_index, f.line) == ("error", "can0", 0, 1)
    assert f.time == res.stats.start


def test_n001_addressed_but_silent_node(checker):
    # node 8 gets an NMT start, an RPDO and guarding requests, but never transmits
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 1.0)
          + [(0.45, "000#0108"), (0.5, "208#00"), (0.55, "708#R"), (0.65, "708#R")])
    assert checker.findings(candump(sorted(fr)), select="N",
                            network="[nodes.2]\n[nodes.8]\n") == [("N001", 8, 0.0)]


def test_n001_any_transmitted_frame_counts(checker):
    # node 3 only sends a TPDO (its NMT state stays UNKNOWN): it is present
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0) + [(0.5, "183#00")]
    assert checker.findings(candump(sorted(fr)), network="[nodes.2]\n[nodes.3]\n") == []


def test_n001_every_channel_unless_one_is_named(checker):
    can0 = [(0.0, "702#00"), (0.01, "703#00")] + hb(2, 0.1, 1.0) + hb(3, 0.11, 1.0)
    can1 = [(0.02, "702#00")] + hb(2, 0.12, 1.0)
    text = candump(sorted(can0)) + candump(can1, channel="can1")
    res = checker.run(text, network="[nodes.2]\n[nodes.3]\n", select="N")
    assert [(f.rule, f.node, f.channel) for f in res.findings] == [("N001", 3, "can1")]
    res = checker.run(text, network='[nodes.2]\n[nodes.3]\nchannel = "can0"\n', select="N")
    assert res.findings == []
    res = checker.run(text, network='[nodes.2]\nchannel = "can2"\n', select="N")
    assert [(f.rule, f.node, f.channel) for f in res.findings] == [("N001", 2, "can2")]


# --- N002 -------------------------------------------------------------------------------

def test_n002_short_long_alternation_complete_list(checker):
    # heartbeats at 0.1, 0.135, 0.2, 0.235, 0.3: intervals 35 / 65 ms alternate
    res = checker.run(candump(two_devices(0.035)))
    assert found(res) == [("N002", 5, 0.3)]
    assert res.findings[0].severity == "warning"
    assert "alternate short/long (0.035, 0.065, 0.035, 0.065 s)" in res.findings[0].message


def test_n002_state_pattern_a_b_a_b(checker):
    res = checker.run(candump(two_devices(0.05, state_a="05", state_b="7F")), select="N")
    assert found(res) == [("N002", 5, 0.25)]
    assert "alternates between OPERATIONAL and PRE-OPERATIONAL" in res.findings[0].message


def test_n002_one_finding_per_node(checker):
    fr = two_devices(0.035, t1=3.0)
    assert checker.findings(candump(fr), select="N") == [("N002", 5, 0.3)]


def test_n002_state_pattern_split_by_command_or_bootup(checker):
    fr = [(0.0, "705#00"), (0.1, "705#05"), (0.2, "705#7F"), (0.25, "000#0105"),
          (0.3, "705#05"), (0.4, "705#7F")]
    assert checker.findings(candump(fr), select="N") == []
    fr = [(0.0, "705#00"), (0.1, "705#05"), (0.2, "705#7F"), (0.25, "705#00"),
          (0.3, "705#05"), (0.4, "705#7F")]
    assert checker.findings(candump(fr), select="N") == []


def test_n002_alternation_needs_four_intervals(checker):
    fr = [(0.0, "705#00"), (0.1, "705#7F"), (0.135, "705#7F"), (0.2, "705#7F"),
          (0.235, "705#7F")]
    assert checker.findings(candump(fr), select="N") == []


def test_n002_alternation_needs_long_at_least_1_5_short(checker):
    assert checker.findings(candump(two_devices(0.045)), select="N") == []  # 55 / 45 ms
    assert checker.findings(candump(two_devices(0.04)), select="N") == [("N002", 5, 0.3)]
