"""Node-guarding rules G001 (guard-toggle), G002 (guard-no-response),
G003 (guard-interval-exceeded), G004 (guarding-with-heartbeat)."""

from __future__ import annotations

from pathlib import Path

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


def guard(node: int, t0: float, toggles: str, state: int = 0x7F, period: float = 0.1,
          dt: float = 0.002) -> list[tuple[float, str]]:
    """A remote request every `period` from t0, each answered after `dt` with the toggle
    bits given as a string of 0/1 ('-' = no answer)."""
    out = []
    for i, tog in enumerate(toggles):
        t = round(t0 + i * period, 6)
        out.append((t, f"{0x700 + node:03X}#R"))
        if tog != "-":
            out.append((round(t + dt, 6), f"{0x700 + node:03X}#{int(tog) << 7 | state:02X}"))
    return out


GUARD_NET = "[nodes.5]\nguard_time_ms = 100\nlife_time_factor = 3\n"  # life time 0.3 s


def profile(tmp_path: Path, text: str) -> str:
    path = tmp_path / "profile.toml"
    path.write_text('extends = "default"\n' + text)
    return str(path)


def test_healthy_trace_is_clean(checker):
    assert checker.findings(candump(healthy()), select="G") == []
    assert checker.findings(candump(healthy()), select="G", network=HEALTHY_NET) == []


def test_healthy_guarding_is_clean(checker):
    fr = ([(0.0, "705#00")] + guard(5, 0.1, "0101") + [(0.45, "000#0105")]
          + guard(5, 0.5, "010101", state=0x05))
    assert checker.findings(candump(sorted(fr)), network=GUARD_NET) == []


# --- G001 -------------------------------------------------------------------------------

def test_g001_repeated_toggle_complete_list(checker):
    fr = [(0.0, "705#00")] + guard(5, 0.1, "0100101")
    res = checker.run(candump(fr))
    assert [(f.rule, f.node, round(f.time - 1000.0, 3)) for f in res.findings] == [
        ("G001", 5, 0.402)]
    assert res.findings[0].message.startswith("guarding response 7Fh from node 5")


def test_g001_stuck_toggle_is_one_finding_with_count(checker):
    fr = [(0.0, "705#00")] + guard(5, 0.1, "010000")
    res = checker.run(candump(fr), select="G")
    assert [(f.rule, f.node, round(f.time - 1000.0, 3)) for f in res.findings] == [
        ("G001", 5, 0.402)]
    assert "(3 responses)" in res.findings[0].message


def test_g001_separate_repeats_are_separate_findings(checker):
    fr = [(0.0, "705#00")] + guard(5, 0.1, "01100")
    assert checker.findings(candump(fr), select="G") == [("G001", 5, 0.302),
                                                         ("G001", 5, 0.502)]


def test_g001_first_response_after_bootup_has_toggle_1(checker):
    fr = [(0.0, "705#00")] + guard(5, 0.1, "1010")
    assert checker.findings(candump(fr), select="G") == [("G001", 5, 0.102)]
    # and again after a later boot-up (reset by the master)
    fr = ([(0.0, "705#00")] + guard(5, 0.1, "0101") + [(0.5, "000#8105"), (0.6, "705#00")]
          + guard(5, 0.7, "10"))
    assert checker.findings(candump(fr), select="G") == [("G001", 5, 0.702)]


def test_g001_first_response_without_bootup_may_have_toggle_1(checker):
    fr = [(0.0, "705#R"), (0.002, "705#FF")] + guard(5, 0.1, "0101")
    assert checker.findings(candump(fr), select="G") == []


def test_g001_bootup_separates_findings(checker):
    fr = [(0.0, "705#00")] + guard(5, 0.1, "011") + [(0.35, "705#00")] + guard(5, 0.4, "10")
    assert checker.findings(candump(fr), select="G") == [("G001", 5, 0.302),
                                                         ("G001", 5, 0.402)]


# --- G002 -------------------------------------------------------------------------------

def test_g002_run_of_unanswered_requests_complete_list(checker):
    # requests at 0.6, 0.7, 0.8 get no answer; the one at 0.9 does
    fr = [(0.0, "705#00")] + guard(5, 0.1, "01010---1")
    res = checker.run(candump(fr))
    assert [(f.rule, f.node, round(f.time - 1000.0, 3)) for f in res.findings] == [
        ("G002", 5, 0.7)]
    assert "(3 requests in a row)" in res.findings[0].message


def test_g002_time_is_request_plus_response_timeout_when_earlier(checker):
    fr = [(0.0, "705#00")] + guard(5, 0.1, "01-0", period=2.0)
    assert checker.findings(candump(fr)) == [("G002", 5, 5.1)]


def test_g002_two_runs_two_findings(checker):
    fr = [(0.0, "705#00")] + guard(5, 0.1, "0--1--0")
    assert checker.findings(candump(fr)) == [("G002", 5, 0.3), ("G002", 5, 0.6)]


def test_g002_trace_ends_before_the_answer_is_due(checker):
    fr = [(0.0, "705#00")] + guard(5, 0.1, "010-") + [(0.9, "080#")]
    assert checker.findings(candump(fr)) == []
    fr = [(0.0, "705#00")] + guard(5, 0.1, "010-") + [(1.5, "080#")]
    assert checker.findings(candump(fr)) == [("G002", 5, 1.4)]


def test_g002_late_answer_does_not_count(checker):
    # answered 1.5 s after the request: later than response_timeout_ms (1000)
    fr = [(0.0, "705#00")] + guard(5, 0.1, "01") + [(1.0, "705#R"), (2.5, "705#7F"),
                                                      (3.0, "705#R"), (3.002, "705#FF")]
    assert checker.findings(candump(fr), select="G002") == [("G002", 5, 2.0)]


def test_g002_response_timeout_ms_from_profile(checker, tmp_path):
    fr = [(0.0, "705#00")] + guard(5, 0.1, "0101", period=0.2, dt=0.08)
    prof = profile(tmp_path, "[rules.G002]\nresponse_timeout_ms = 50\n")
    assert checker.findings(candump(fr), select="G") == []
    # every answer comes too late: one run of four unanswered requests
    res = checker.run(candump(fr), select="G002", profile=prof)
    assert [(f.rule, f.node, round(f.time - 1000.0, 3)) for f in res.findings] == [
        ("G002", 5, 0.15)]
    assert "(4 requests in a row)" in res.findings[0].message


# --- G003 -------------------------------------------------------------------------------

def test_g003_interval_exceeded_complete_list(checker):
    fr = [(0.0, "705#00")] + guard(5, 0.1, "0101") + guard(5, 0.9, "0101")
    res = checker.run(candump(fr), network=GUARD_NET)
    assert [(f.rule, f.node, round(f.time - 1000.0, 3)) for f in res.findings] == [
        ("G003", 5, 0.9)]
    assert res.findings[0].severity == "warning"
    assert "0.500 s apart" in res.findings[0].message


def test_g003_consecutive_late_requests_are_one_finding(checker):
    fr = [(0.0, "705#00")] + guard(5, 0.1, "0101") + guard(5, 0.9, "0101", period=0.5)
    res = checker.run(candump(fr), select="G", network=GUARD_NET)
    assert [(f.rule, f.node, round(f.time - 1000.0, 3)) for f in res.findings] == [
        ("G003", 5, 0.9)]
    assert "(4 requests)" in res.findings[0].message


def test_g003_interval_equal_to_life_time_is_clean(checker):
    fr = [(0.0, "705#00")] + guard(5, 0.1, "0101010101", period=0.3)
    assert checker.findings(candump(fr), network=GUARD_NET) == []


def test_g003_needs_guard_time_and_life_time_factor(checker):
    fr = [(0.0, "705#00")] + guard(5, 0.1, "0101") + guard(5, 0.9, "0101")
    assert checker.findings(candump(fr)) == []
    assert checker.findings(candump(fr), network="[nodes.5]\nguard_time_ms = 100\n") == []


# --- G004 -------------------------------------------------------------------------------

def test_g004_guarding_with_heartbeat_complete_list(checker):
    # heartbeat every 100 ms and a guarding response 10 ms after one of them
    fr = [(0.0, "705#00")] + hb(5, 0.1, 1.0) + [(0.505, "705#R"), (0.51, "705#7F"),
                                                  (0.705, "705#R"), (0.71, "705#FF")]
    res = checker.run(candump(sorted(fr)))
    assert [(f.rule, f.node, round(f.time - 1000.0, 3)) for f in res.findings] == [
        ("G004", 5, 0.51)]
    assert res.nodes()[0].error_control == "both"


def test_g004_once_per_bootup(checker):
    fr = ([(0.0, "705#00")] + hb(5, 0.1, 1.0) + [(0.505, "705#R"), (0.51, "705#7F"),
                                                   (0.705, "705#R"), (0.71, "705#FF")]
          + [(1.0, "000#8105"), (1.1, "705#00")] + hb(5, 1.2, 2.0)
          + [(1.305, "705#R"), (1.31, "705#7F")])
    assert checker.findings(candump(sorted(fr)), select="G") == [("G004", 5, 0.51),
                                                                 ("G004", 5, 1.31)]


def test_g004_not_for_one_method_only(checker):
    guarding = [(0.0, "705#00")] + guard(5, 0.1, "0101010101")
    heartbeat = [(0.0, "705#00")] + hb(5, 0.1, 1.0)
    assert checker.findings(candump(guarding), select="G004") == []
    assert checker.findings(candump(heartbeat), select="G004") == []

