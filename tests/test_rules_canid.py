"""CAN-ID and frame-format rules C001 (restricted-can-id), C002 (malformed-nmt-command),
C003 (malformed-error-control), C004 (unknown-nmt-state)."""

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


def found(res) -> list[tuple[str, int | None, float]]:
    return [(f.rule, f.node, round(f.time - 1000.0, 3)) for f in res.findings]


def base() -> list[tuple[float, str]]:
    """Node 2 boots and heartbeats PRE-OPERATIONAL every 100 ms for 2 s."""
    return [(0.0, "702#00")] + hb(2, 0.1, 2.0)


def test_healthy_trace_is_clean(checker):
    assert checker.findings(candump(healthy()), select="C") == []
    assert checker.findings(candump(healthy()), select="C", network=HEALTHY_NET) == []


# --- C001 -------------------------------------------------------------------------------

def test_c001_restricted_ids_complete_list(checker):
    fr = base() + [(0.21, "123#00"), (0.31, "123#01"), (0.41, "123#R"), (0.51, "050#00"),
                   (0.61, "6E0#11"), (0.71, "780#00")]
    res = checker.run(candump(sorted(fr)))
    assert found(res) == [("C001", None, 0.21), ("C001", None, 0.51), ("C001", None, 0.61),
                          ("C001", None, 0.71)]
    assert res.findings[0].message == "CAN-ID 123h is reserved by CiA 301 (3 frames)"
    assert res.findings[0].frame_index == 3 and res.findings[0].line == 4


@pytest.mark.parametrize("can_id", ["001", "07F", "101", "180", "6E0", "6FF", "780", "7FF"])
def test_c001_range_edges_are_restricted(checker, can_id):
    fr = base() + [(0.55, f"{can_id}#00")]
    if can_id == "001":  # global fail-safe command (CiA 304): allowed by default
        assert checker.findings(candump(sorted(fr))) == []
    else:
        assert checker.findings(candump(sorted(fr))) == [("C001", None, 0.55)]


@pytest.mark.parametrize("can_id", ["080", "100", "181", "6DF", "77F", "7E4", "7E5", "071",
                                    "076"])
def test_c001_allowed_and_unrestricted_ids(checker, can_id):
    fr = base() + [(0.55, f"{can_id}#00")]
    assert checker.findings(candump(sorted(fr)), select="C001") == []


def test_c001_allow_list_from_profile(checker, tmp_path):
    fr = base() + [(0.55, "123#00"), (0.65, "7E5#00")]
    prof = profile(tmp_path, "[rules.C001]\nallow = [0x123]\n")
    assert checker.findings(candump(sorted(fr)), profile=prof) == [("C001", None, 0.65)]


def test_c001_one_finding_per_id_and_channel(checker):
    text = candump(sorted(base() + [(0.55, "123#00"), (0.75, "123#00")])) + candump(
        [(1.95, "123#00"), (2.0, "123#00")], channel="can1")
    res = checker.run(text)
    assert [(f.rule, f.channel, round(f.time - 1000.0, 3)) for f in res.findings] == [
        ("C001", "can0", 0.55), ("C001", "can1", 1.95)]


def test_c001_extended_frames_are_not_checked(checker):
    fr = base() + [(0.55, "00000123#00"), (0.65, "00000780#00")]
    assert checker.findings(candump(sorted(fr))) == []


# --- C002 -------------------------------------------------------------------------------

def test_c002_malformed_nmt_frames_complete_list(checker):
    fr = base() + [(0.21, "000#R"), (0.31, "000#010200"), (0.41, "000#0302"),
                   (0.51, "000#0180"), (0.61, "000#01")]
    res = checker.run(candump(sorted(fr)))
    # only the 2-byte frame with an unknown specifier names a node (node 2)
    assert found(res) == [("C002", None, 0.21), ("C002", None, 0.31), ("C002", 2, 0.41),
                          ("C002", None, 0.51), ("C002", None, 0.61)]
    assert [f.message for f in res.findings] == [
        "malformed NMT frame: remote frame on CAN-ID 000h (NMT commands are data frames)",
        "malformed NMT frame: DLC 3 (an NMT command has DLC 2)",
        "malformed NMT frame: unknown command specifier 03h",
        "malformed NMT frame: node-ID 128 above 127",
        "malformed NMT frame: DLC 1 (an NMT command has DLC 2)",
    ]
    assert all(f.severity == "error" for f in res.findings)


def test_c002_malformed_command_is_not_applied(checker):
    # a start with DLC 8: the node keeps PRE-OPERATIONAL, so its 7Fh heartbeats are no S004
    fr = base() + [(0.45, "000#0102000000000000")]
    res = checker.run(candump(sorted(fr)))
    assert found(res) == [("C002", None, 0.45)]
    node = res.model.channels[0].nodes[2]
    assert [iv.state for iv in node.intervals] == ["PRE-OPERATIONAL"]
    assert node.commands == []


def test_c002_malformed_broadcast_is_not_applied(checker):
    fr = base() + [(0.45, "000#8100AA")]  # reset all, DLC 3: no B001 for node 2
    res = checker.run(candump(sorted(fr)))
    assert found(res) == [("C002", None, 0.45)]
    assert [iv.state for iv in res.model.channels[0].nodes[2].intervals] == ["PRE-OPERATIONAL"]


def test_c002_consecutive_frames_one_finding_per_node(checker):
    fr = [(0.0, "702#00"), (0.01, "703#00")] + hb(2, 0.1, 2.0) + hb(3, 0.11, 2.0) + [
        (0.45, "000#0302"), (0.46, "000#0302"), (0.47, "000#0303"), (0.48, "000#0303"),
        (0.49, "000#0303")]
    res = checker.run(candump(sorted(fr)))
    assert found(res) == [("C002", 2, 0.45), ("C002", 3, 0.47)]
    assert [f.message[-10:] for f in res.findings] == ["(2 frames)", "(3 frames)"]


def test_c002_not_for_a_node_in_unknown_state(checker):
    # SPEC §3: C002 is not exempt from the UNKNOWN rule; broadcasts have no node
    fr = [(0.0, "000#0305"), (0.05, "000#010000")] + base() + [(0.5, "705#00")]
    assert checker.findings(candump(sorted(fr))) == [("C002", None, 0.05)]


# --- C003 -------------------------------------------------------------------------------

def test_c003_wrong_dlc_complete_list(checker):
    fr = base() + [(0.55, "702#7F00"), (1.05, "702#")]
    res = checker.run(candump(sorted(fr)))
    assert found(res) == [("C003", 2, 0.55), ("C003", 2, 1.05)]
    assert res.findings[0].message == (
        "malformed error-control frame from node 2: DLC 2 (must be 1)")
    assert res.findings[1].message == (
        "malformed error-control frame from node 2: DLC 0 (must be 1)")


def test_c003_heartbeat_with_bit_7(checker):
    fr = [x for x in base() if x[0] != 0.5] + [(0.5, "702#FF")]
    res = checker.run(candump(sorted(fr)))
    assert found(res) == [("C003", 2, 0.5)]
    assert res.findings[0].message.endswith("heartbeat FFh has the reserved bit 7 set")


def test_c003_remote_requests_with_dlc_0_or_1_are_normal(checker):
    fr = [(0.0, "705#00"), (0.1, "705#R"), (0.102, "705#7F"), (0.2, "705#R1"),
          (0.202, "705#FF"), (0.3, "705#R0"), (0.302, "705#7F")]
    assert checker.findings(candump(fr)) == []


def test_c003_guarding_response_with_bit_7_is_not_c003(checker):
    fr = [(0.0, "705#00"), (0.1, "705#R"), (0.102, "705#7F"), (0.2, "705#R"), (0.202, "705#FF")]
    assert checker.findings(candump(fr), select="C") == []


def test_c003_consecutive_frames_one_finding_per_interval(checker):
    fr = ([(0.0, "702#00")] + hb(2, 0.1, 0.5) + [(0.45, "000#0102")] + hb(2, 0.5, 1.0, "85")
          + [(0.95, "000#0202")] + hb(2, 1.0, 1.5, "84"))
    res = checker.run(candump(sorted(fr)), select="C")
    assert found(res) == [("C003", 2, 0.5), ("C003", 2, 1.0)]
    assert [f.message[-10:] for f in res.findings] == ["(5 frames)", "(5 frames)"]


def test_c003_exempt_from_unknown(checker):
    # node 3's only error-control frames are malformed: it stays UNKNOWN, C003 still fires
    fr = base() + [(0.55, "703#7F00"), (0.65, "703#7F00")]
    res = checker.run(candump(sorted(fr)))
    assert found(res) == [("C003", 3, 0.55)]
    assert [iv.state for iv in res.model.channels[0].nodes[3].intervals] == ["UNKNOWN"]


# --- C004 -------------------------------------------------------------------------------

def test_c004_unknown_state_complete_list(checker):
    fr = [x for x in base() if x[0] not in (0.5, 0.6)] + [(0.5, "702#02"), (0.6, "702#02")]
    res = checker.run(candump(sorted(fr)))
    assert found(res) == [("C004", 2, 0.5)]
    assert res.findings[0].severity == "warning"
    assert res.findings[0].message == "node 2 reports unknown NMT state 02h (2 frames)"
    # the timeline keeps the previous state
    assert [iv.state for iv in res.model.channels[0].nodes[2].intervals] == ["PRE-OPERATIONAL"]


@pytest.mark.parametrize("code", ["00", "04", "05", "7F"])
def test_c004_known_states(checker, code):
    fr = [(0.0, "702#00")] + hb(2, 0.1, 1.0, code)
    assert checker.findings(candump(fr), select="C004") == []


def test_c004_guarding_response(checker):
    fr = [(0.0, "705#00"), (0.1, "705#R"), (0.102, "705#7F"), (0.2, "705#R"), (0.202, "705#E0")]
    assert checker.findings(candump(fr)) == [("C004", 5, 0.202)]


def test_c004_exempt_from_unknown(checker):
    fr = base() + hb(3, 0.15, 1.0, "60")
    res = checker.run(candump(sorted(fr)))
    assert found(res) == [("C004", 3, 0.15)]
    assert [iv.state for iv in res.model.channels[0].nodes[3].intervals] == ["UNKNOWN"]
