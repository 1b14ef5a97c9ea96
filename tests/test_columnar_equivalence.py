"""Differential test: the columnar error-control code of fd98c85 against the object-per-frame
code it replaced (afef50f, frozen in tests/reference_model.py).

Random candump traces of 1-4 nodes (boot-ups, heartbeats 04h/05h/7Fh with jitter, early
and equal-timestamp frames, invalid codes, bit 7, wrong DLC, node guarding with toggling
and missing responses, NMT commands direct and broadcast, silences, SDO writes of
1017h/1016h/100Ch/100Dh, the odd TPDO) run through the current pipeline and through the
reference; every finding (all rules) and every node's timeline, classification, period
and timeouts must be the same. Timestamps sit on a coarse grid so that frames, commands
and timeout moments often coincide.

NMTCHECK_HYPOTHESIS=explore runs 40 times as many random examples.
"""

from __future__ import annotations

import copy
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from conftest import SAMPLES
from hypothesis import HealthCheck, given, note, settings
from hypothesis import strategies as st
from reference_model import reference_check
from traces import HEALTHY_NET, healthy

from nmtcheck.engine import check_input, select_rules
from nmtcheck.network import load_network
from nmtcheck.profiles import load_profile

EXPLORE = os.environ.get("NMTCHECK_HYPOTHESIS") == "explore"
EXAMPLES = 200

PROFILE = load_profile("default")
RULES = select_rules(PROFILE, [], [])

# --- running both implementations -------------------------------------------------------


def _node_view(m: Any) -> dict[str, Any]:
    return {
        "intervals": [(iv.state, iv.start, iv.end, iv.source) for iv in m.intervals],
        "ec": [(f.idx, f.kind) for f in m.ec],
        "period": (m.period_s, m.period_source),
        "timeouts": [(t.rule, t.moment, t.after_ts, t.after_idx, t.limit_s, t.gap_s,
                      t.requests, t.ended_by) for t in m.timeouts],
        "commands": [(c.idx, c.cs, c.broadcast) for c in m.commands],
        "writes": [(w.idx, w.index, w.sub, w.value, w.until) for w in m.writes],
    }


def _outcome(res: Any) -> tuple[list[tuple[Any, ...]], dict[tuple[str, int], dict[str, Any]]]:
    findings = [(f.rule, f.channel, f.node, f.time, f.frame_index, f.line, f.message,
                 f.severity) for f in res.findings]
    nodes = {(cm.name, n): _node_view(m) for cm in res.model.channels
             for n, m in cm.nodes.items()}
    return findings, nodes


def compare(tmp: Path, text: str, network: str | Path | None = None,
            params: tuple[tuple[str, str, float], ...] = ()) -> int:
    """Run the trace through both implementations and assert they agree; returns how many
    findings there were (so callers can tell the trace was not trivially clean).
    `network`: the text of a network file, or the path of one; `params`: (rule, parameter,
    value) to change in the default profile."""
    profile = PROFILE
    if params:
        profile = copy.deepcopy(PROFILE)
        for code, name, value in params:
            profile[code].params[name] = value
    log = tmp / "trace.log"
    log.write_text(text)
    net = None
    if isinstance(network, str):
        netfile = tmp / "net.toml"
        netfile.write_text(network)
        net = load_network(str(netfile))
    elif network is not None:
        net = load_network(str(network))
    new = _outcome(check_input(str(log), 0, profile, RULES, net))
    old = _outcome(reference_check(str(log), profile, network=net))
    assert new[0] == old[0], "findings differ (new, old)"
    assert new[1].keys() == old[1].keys(), "nodes differ"
    for key in old[1]:
        for what in ("intervals", "ec", "period", "timeouts", "commands", "writes"):
            assert new[1][key][what] == old[1][key][what], f"{what} of node {key} differ"
    return len(new[0])


def text_of(frames: list[tuple[int, str]]) -> str:
    """candump -L lines from (microseconds, '[CHANNEL ]ID#DATA'; can0 if none), exact (no
    float formatting)."""
    return "".join(f"({1000 + us // 1_000_000}.{us % 1_000_000:06d}) "
                   f"{f if ' ' in f else 'can0 ' + f}\n" for us, f in frames)


def ms(frames: list[tuple[float, str]]) -> list[tuple[int, str]]:
    return [(round(t * 1_000_000), f) for t, f in frames]


# --- random traces ----------------------------------------------------------------------

NODE_POOL = (1, 2, 3, 5, 42, 127)
STATES = (0x04, 0x05, 0x7F)
ODD_CODES = (0x01, 0x02, 0x7E, 0x85, 0x84, 0xFF, 0x80)  # unknown, or bit 7 set
MALFORMED = ("0500", "", "7F00000000000000", "057F")  # DLC 2, 0, 8, 2


@dataclass
class Trace:
    text: str
    network: str | None
    params: tuple[tuple[str, str, float], ...] = ()  # (rule, parameter, value) off default

    def __repr__(self) -> str:  # readable falsifying examples
        return f"Trace(network={self.network!r}, params={self.params!r}, text=\n{self.text})"


TUNABLE = {  # parameters the timeline or the vectorised rules use, and values to try
    ("H001", "timeout_factor"): [1.2, 2.0], ("H002", "early_factor"): [0.3, 0.8],
    ("H003", "tolerance"): [0.0, 0.5], ("G002", "response_timeout_ms"): [50.0, 300.0],
    ("S004", "obey_ms"): [0.0, 300.0], ("B001", "bootup_timeout_ms"): [150.0, 500.0],
    ("B001", "late_start_ms"): [50.0, 500.0], ("B002", "reset_window_ms"): [100.0, 300.0],
    ("B003", "repeat_window_ms"): [100.0, 300.0],
}


def _sdo_write(node: int, t: int, index: int, sub: int, value: int, size: int,
               answer: str) -> list[tuple[int, str]]:
    """An expedited SDO download request and (maybe) the server's answer 1 ms later."""
    cmd = {1: "2F", 2: "2B", 4: "23"}[size]
    body = f"{index & 0xFF:02X}{index >> 8:02X}{sub:02X}"
    val = value.to_bytes(4, "little").hex().upper()
    out = [(t, f"{0x600 + node:03X}#{cmd}{body}{val}")]
    if answer == "60":
        out.append((t + 1000, f"{0x580 + node:03X}#60{body}00000000"))
    elif answer == "80":
        out.append((t + 1000, f"{0x580 + node:03X}#80{body}22000008"))
    return out


@st.composite
def traces(draw: st.DrawFn) -> Trace:
    grid = draw(st.sampled_from([1000, 5000, 10_000]))  # µs: coarse grids make ties
    nodes = draw(st.lists(st.sampled_from(NODE_POOL), min_size=1, max_size=4, unique=True))
    frames: list[tuple[int, str]] = []
    horizon = 0
    periods: dict[int, int] = {}
    # now and then a second bus: some nodes and commands are on can1
    channels = ["", "", "", "can1 "] if draw(st.integers(0, 4)) == 0 else [""]
    for node in nodes:
        bus = draw(st.sampled_from(channels))
        at = len(frames)
        ec = f"{0x700 + node:03X}"
        period = draw(st.sampled_from([50_000, 100_000, 200_000]))
        periods[node] = period
        t = draw(st.integers(0, 20)) * grid
        state = draw(st.sampled_from(STATES))
        toggle = 0
        for _ in range(draw(st.integers(1, 10))):
            action = draw(st.sampled_from(
                ["bootup", "heartbeats", "heartbeats", "heartbeats", "odd", "silence",
                 "guarding", "guarding", "mixed", "sdo", "tpdo"]))
            if action == "bootup":
                frames.append((t, f"{ec}#00"))
                toggle = 0
                t += draw(st.sampled_from([0, grid, period]))
            elif action == "heartbeats":
                if draw(st.booleans()):
                    state = draw(st.sampled_from(STATES))
                for _ in range(draw(st.integers(1, 15))):
                    frames.append((t, f"{ec}#{state:02X}"))
                    step = draw(st.sampled_from(["on", "on", "on", "jitter", "early", "same",
                                                 "switch"]))
                    if step == "jitter":
                        t += period + draw(st.integers(-3, 3)) * 1000
                    elif step == "early":
                        t += draw(st.sampled_from([period // 5, period // 3, period // 2]))
                    elif step == "same":
                        pass  # the next frame at the same timestamp
                    else:
                        t += period
                        if step == "switch":
                            state = draw(st.sampled_from(STATES))
            elif action == "odd":
                if draw(st.booleans()):
                    frames.append((t, f"{ec}#{draw(st.sampled_from(ODD_CODES)):02X}"))
                else:
                    frames.append((t, f"{ec}#{draw(st.sampled_from(MALFORMED))}"))
                t += draw(st.sampled_from([0, period]))
            elif action == "silence":
                # often exactly one or a few periods/timeouts: the timeout moment lands on the
                # node's own grid
                t += draw(st.sampled_from([period * 3 // 2, period * 2, period * 5,
                                           1_000_000, 1_500_000])) + draw(
                    st.sampled_from([0, 0, grid, -grid]))
            elif action in ("guarding", "mixed"):
                gap = draw(st.sampled_from([100_000, 200_000, 300_000]))
                for _ in range(draw(st.integers(1, 8))):
                    frames.append((t, f"{ec}#R"))
                    answer = draw(st.sampled_from(["ok", "ok", "ok", "ok", "stuck", "none",
                                                   "late"]))
                    delay = draw(st.sampled_from([0, 1000, 2000, grid]))
                    if answer == "late":
                        delay = 1_000_000 + grid
                    if answer != "none":
                        frames.append((t + delay, f"{ec}#{toggle << 7 | state:02X}"))
                        if answer != "stuck":
                            toggle ^= 1
                    if action == "mixed":  # a heartbeat at the very same moment, or between
                        frames.append((t + draw(st.sampled_from([0, delay, gap // 2])),
                                       f"{ec}#{state:02X}"))
                    t += gap + draw(st.sampled_from([0, 0, 0, gap * 3, 1_200_000]))
            elif action == "sdo":
                which = draw(st.sampled_from(["1017", "1016", "100C", "100D"]))
                answer = draw(st.sampled_from(["60", "60", "60", "80", "none"]))
                if which == "1017":
                    w = _sdo_write(node, t, 0x1017, 0, draw(st.sampled_from([0, 50, 100, 200])),
                                   2, answer)
                elif which == "1016":
                    producer = draw(st.sampled_from(nodes))
                    time_ms = draw(st.sampled_from([0, 150, 250, 400]))
                    w = _sdo_write(node, t, 0x1016, draw(st.integers(1, 2)),
                                   producer << 16 | time_ms, 4, answer)
                elif which == "100C":
                    w = _sdo_write(node, t, 0x100C, 0, draw(st.sampled_from([0, 100, 250])),
                                   2, answer)
                else:
                    w = _sdo_write(node, t, 0x100D, 0, draw(st.integers(0, 3)), 1, answer)
                if which in ("100C", "100D") and draw(st.booleans()):  # the pair: G003 armed
                    other = "100D" if which == "100C" else "100C"
                    w += _sdo_write(node, t + 2000, int(other, 16), 0,
                                    draw(st.sampled_from([1, 2])) if other == "100D"
                                    else draw(st.sampled_from([100, 200])),
                                    1 if other == "100D" else 2, "60")
                frames += w
                t += draw(st.sampled_from([0, grid, period]))
            else:  # a TPDO now and then: S001, signs of life for B001, OFFLINE ends
                frames.append((t, f"{0x180 + node:03X}#0102"))
                t += draw(st.sampled_from([0, grid]))
        frames[at:] = [(t_, bus + f) for t_, f in frames[at:]]
        horizon = max(horizon, t)
    # NMT commands, often exactly at the time of some other frame
    for _ in range(draw(st.integers(0, 6))):
        cs = draw(st.sampled_from([0x01, 0x02, 0x80, 0x81, 0x82]))
        target = draw(st.sampled_from([0, *nodes]))
        if frames and draw(st.booleans()):
            t = draw(st.sampled_from(frames))[0]
        else:
            t = draw(st.integers(0, max(horizon, grid) // grid)) * grid
        frames.append((t, f"{draw(st.sampled_from(channels))}000#{cs:02X}{target:02X}"))
    if not frames:  # only silences: an empty log is an input error, not a trace
        frames.append((0, f"{0x700 + nodes[0]:03X}#00"))
    # equal timestamps: which comes first in the file is up to chance
    draw(st.randoms(use_true_random=False)).shuffle(frames)
    frames.sort(key=lambda f: f[0])
    network = None
    if draw(st.booleans()):  # mostly the trace's nodes; another one is missing (N001)
        parts = []
        pool = [*nodes, *nodes, *NODE_POOL]
        for node in dict.fromkeys(draw(st.lists(st.sampled_from(pool), max_size=3))):
            keys = draw(st.sets(st.sampled_from(["hb", "consumer", "guard"])))
            body = ""
            if "hb" in keys:  # the period the node uses, or twice it (H003)
                factor = draw(st.sampled_from([1, 1, 2]))
                body += f"heartbeat_ms = {periods.get(node, 100_000) // 1000 * factor}\n"
            if "consumer" in keys:
                body += f"consumer_timeout_ms = {draw(st.sampled_from([120, 250, 500]))}\n"
            if "guard" in keys:
                body += (f"guard_time_ms = {draw(st.sampled_from([100, 200]))}\n"
                         f"life_time_factor = {draw(st.integers(1, 3))}\n")
            parts.append(f"[nodes.{node}]\n{body}")
        network = "".join(parts)
    params = ()
    if draw(st.integers(0, 3)) == 0:
        chosen = draw(st.lists(st.sampled_from(sorted(TUNABLE)), min_size=1, max_size=4,
                               unique=True))
        params = tuple((code, name, draw(st.sampled_from(TUNABLE[code, name])))
                       for code, name in chosen)
    return Trace(text_of(frames), network, params)


@pytest.fixture(scope="module")
def workdir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("columnar")


@settings(max_examples=EXAMPLES * 40 if EXPLORE else EXAMPLES, deadline=None,
          derandomize=not EXPLORE, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(trace=traces())
def test_columnar_code_matches_the_object_reference(trace: Trace, workdir: Path) -> None:
    note(repr(trace))
    compare(workdir, trace.text, trace.network, trace.params)


# --- hand-written tricky spots ----------------------------------------------------------

def _hb(node: int, t0: float, t1: float, state: str = "7F", period: float = 0.1
        ) -> list[tuple[float, str]]:
    out, i = [], 0
    while (t := round(t0 + i * period, 6)) < t1 - 1e-9:
        out.append((t, f"{0x700 + node:03X}#{state}"))
        i += 1
    return out


CASES: dict[str, list[tuple[float, str]]] = {
    # runs of equal heartbeats with commands at their very timestamps, before and after them
    # in the file; the node obeys late, then not at all
    "equal_heartbeats_around_commands": (
        [(0.0, "702#00")] + _hb(2, 0.1, 0.5) + [(0.5, "000#0102"), (0.5, "702#7F")]
        + _hb(2, 0.6, 1.0) + _hb(2, 1.0, 1.5, "05") + [(1.5, "702#05"), (1.5, "000#0202")]
        + _hb(2, 1.5, 2.0, "05") + [(2.0, "000#8002"), (2.0, "702#05"), (2.0, "702#05")]
        + _hb(2, 2.1, 2.5, "7F")),
    # a heartbeat timeout whose moment (0.9 + 0.15) is the time of a command and of a
    # broadcast, and OFFLINE ended by two equal heartbeats at one timestamp
    "timeout_at_a_command": (
        [(0.0, "702#00"), (0.0, "703#00")] + _hb(2, 0.1, 1.0) + _hb(3, 0.1, 2.0)
        + [(1.05, "000#0102"), (1.05, "000#0100"), (1.3, "702#05"), (1.3, "702#05")]
        + _hb(2, 1.4, 2.0, "05")),
    # timeout moment equal to the node's own next frame time (gap = limit exactly) and one
    # microsecond more
    "timeout_at_the_limit": (
        [(0.0, "702#00")] + _hb(2, 0.1, 1.0) + _hb(2, 1.05, 1.5) + _hb(2, 1.650001, 2.0)),
    # two timeouts ending at the same frame time, commands while OFFLINE, a reset while
    # OFFLINE and the boot-up at the same time as a stale heartbeat
    "offline_commands_and_reset": (
        [(0.0, "702#00")] + _hb(2, 0.1, 0.6) + [(0.8, "000#0102"), (0.8, "000#0202"),
                                                (1.0, "000#8102"), (1.2, "702#7F"),
                                                (1.2, "702#00")] + _hb(2, 1.3, 1.8)),
    # guarding with heartbeats at the same time: the response (toggle 0, 7Fh) is byte for
    # byte the heartbeat
    "guarding_with_heartbeats_at_the_same_time": (
        [(0.0, "705#00")] + _hb(5, 0.1, 2.0)
        + [x for i, t in enumerate((0.2, 0.4, 0.6, 0.8, 1.0, 1.2))
           for x in ((t, "705#R"), (t, f"705#{(i % 2) << 7 | 0x7F:02X}"))]),
    # guarding responses that repeat the toggle, a boot-up with a request pending, a request
    # left unanswered, then heartbeats
    "guarding_toggle_bootup_and_no_answer": (
        [(0.0, "706#00"), (0.1, "706#R"), (0.101, "706#7F"), (0.3, "706#R"), (0.301, "706#7F"),
         (0.5, "706#R"), (0.501, "706#7F"), (0.7, "706#R"), (0.7, "706#00"), (0.9, "706#R"),
         (0.9, "706#FF"), (1.1, "706#R"), (2.5, "706#R"), (2.501, "706#7F")]
        + _hb(6, 2.6, 3.2)),
    # OFFLINE ends found past many frames (the growing windows of _offline_ends): an
    # unanswered request among 20 ms heartbeats, malformed frames through a heartbeat gap
    "offline_end_after_many_frames": (
        [(0.0, "703#00"), (0.05, "703#R")] + _hb(3, 0.02, 1.6, "05", 0.02)
        + [(0.0, "704#00")] + _hb(4, 0.1, 0.5, "7F")
        + [(round(0.41 + i / 500, 6), "704#0500") for i in range(300)] + _hb(4, 1.1, 1.5)),
    # N002: the state alternation (05h/7Fh) and the short/long interval alternation end
    # at the same heartbeat (the state alternation is the one reported)
    "duplicate_node_both_alternations": (
        [(0.0, "702#04"), (0.1, "702#05"), (0.3, "702#7F"), (0.4, "702#05"), (0.6, "702#7F"),
         (0.7, "702#7F")]),
    # equal heartbeats: every frame twice at one timestamp, a state change in between, a
    # too-early run, H003 material
    "doubled_heartbeats": (
        [(0.0, "704#00")] + [f for t, s in zip([i / 10 for i in range(1, 20)],
                                                ["7F"] * 8 + ["05"] * 11, strict=True)
                             for f in ((t, f"704#{s}"), (t, f"704#{s}"))]
        + [(2.0, "704#05"), (2.02, "704#05"), (2.04, "704#05")]),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_tricky_traces_match_the_object_reference(name: str, tmp_path: Path) -> None:
    compare(tmp_path, text_of(ms(sorted(CASES[name], key=lambda f: f[0]))))


def test_tricky_traces_with_configuration_match(tmp_path: Path) -> None:
    """The same traces with producer, consumer and guard times from a network file."""
    net = ("[nodes.2]\nheartbeat_ms = 100\n[nodes.3]\nconsumer_timeout_ms = 150\n"
           "[nodes.4]\nheartbeat_ms = 200\n[nodes.5]\nguard_time_ms = 100\n"
           "life_time_factor = 2\n[nodes.6]\nguard_time_ms = 200\nlife_time_factor = 3\n")
    total = 0
    for name in sorted(CASES):
        total += compare(tmp_path, text_of(ms(sorted(CASES[name], key=lambda f: f[0]))), net)
    assert total > 10


def test_healthy_trace_and_samples_match(tmp_path: Path) -> None:
    text = text_of(ms(healthy()))
    compare(tmp_path, text)
    compare(tmp_path, text, HEALTHY_NET)
    for log in sorted(SAMPLES.glob("*.log")):
        compare(tmp_path, log.read_text(), SAMPLES / "network.toml")
        compare(tmp_path, log.read_text())


# --- where the two differ on purpose ---------------------------------------------------

def test_no_heartbeat_timeout_from_a_period_that_is_not_positive(checker) -> None:
    """Timestamps that go backwards make the measured period (median interval) negative.
    afef50f took `factor x period` < 0 as a timeout and raised H001 at every gap, and
    H002 for a heartbeat "-0.000 s after the previous one"; a period or timeout that is
    not positive now means "none" to both. (Negative times in network and profile
    files, the other way to get one, are rejected when loading: test_cli.)"""
    res = checker.run(text_of([(0, "701#04"), (-1, "701#04")]))
    node = res.model.channels[0].nodes[1]
    assert node.period_s is not None and node.period_s < 0
    assert [f.rule for f in res.findings] == []
    assert [iv.state for iv in node.intervals] == ["STOPPED"]
