"""Differential test: the columnar error-control code of fd98c85 against the object-per-frame
code it replaced (afef50f, kept in tests/reference_model.py, revised for the SPEC of 2026-11:
stale reports, the NMT master, the heartbeat period in force, H001 gaps, N002 intervals).

Random candump traces of 1-4 nodes (boot-ups, heartbeats 04h/05h/7Fh with jitter, early
and equal-timestamp frames, invalid codes, bit 7, wrong DLC, node guarding with toggling
and missing responses, NMT commands direct and broadcast, silences, SDO writes of
1017h/1016h/100Ch/100Dh, the odd TPDO; a master's boot-up with a broadcast after it,
1017h written after a boot-up, commands just before a heartbeat, twin producers) run
through the current pipeline and through the reference; every finding (all rules), every
channel's master and every node's timeline, classification, stale reports, period and
timeouts must be the same. Timestamps sit on a coarse grid so that frames, commands
and timeout moments often coincide.

NMTCHECK_HYPOTHESIS=explore runs 40 times as many random examples.
"""

from __future__ import annotations

import copy
import os
import re
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


def _stale(m: Any) -> list[int]:
    """Frame indices of the node's stale reports (SPEC §2): a column of the package's
    EcTable, a flag of the reference's EcFrame."""
    ec = m.ec
    if isinstance(ec, list):
        return [f.idx for f in ec if f.stale]
    return [int(i) for i in ec.idx[ec.stale]]


def _master_view(cm: Any) -> tuple[Any, ...]:
    """(node, source) of the channel's master; if none, whether several nodes qualified and
    which (the numbers in the note), as the texts of the two sides may differ."""
    if cm.master is not None:
        m = cm.master
        return (m[0], m[1]) if isinstance(m, tuple) else (m.node, m.source)
    note = cm.master_note
    if "several" in note:
        return ("several", sorted(int(x) for x in re.findall(r"\d+", note)))
    return ("none",)


def _node_view(m: Any) -> dict[str, Any]:
    return {
        "intervals": [(iv.state, iv.start, iv.end, iv.source) for iv in m.intervals],
        "ec": [(f.idx, f.kind) for f in m.ec],
        "stale": _stale(m),
        "period": (m.period_s, m.period_source),
        "timeouts": [(t.rule, t.moment, t.after_ts, t.after_idx, t.limit_s, t.gap_s,
                      t.requests, t.ended_by) for t in m.timeouts],
        "commands": [(c.idx, c.cs, c.broadcast) for c in m.commands],
        "writes": [(w.idx, w.index, w.sub, w.value, w.until) for w in m.writes],
    }


def _outcome(res: Any) -> tuple[list[tuple[Any, ...]], dict[tuple[str, int], dict[str, Any]],
                               dict[str, tuple[Any, ...]]]:
    # the I-rules judge the input (read by the package's readers on both sides), not the
    # network: the reference does not have them
    findings = [(f.rule, f.channel, f.node, f.time, f.frame_index, f.line, f.message,
                 f.severity) for f in res.findings if not f.rule.startswith("I")]
    nodes = {(cm.name, n): _node_view(m) for cm in res.model.channels
             for n, m in cm.nodes.items()}
    masters = {cm.name: _master_view(cm) for cm in res.model.channels}
    return findings, nodes, masters


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
            if code == "timeline":
                profile.timeline[name] = value
            else:
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
    assert new[2] == old[2], "channel masters differ (new, old)"
    assert new[0] == old[0], "findings differ (new, old)"
    assert new[1].keys() == old[1].keys(), "nodes differ"
    for key in old[1]:
        for what in ("intervals", "ec", "stale", "period", "timeouts", "commands", "writes"):
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
    ("timeline", "master_window_ms"): [0.0, 40.0, 2000.0],  # the profile's [timeline]
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


def _master_start(draw: st.DrawFn, nodes: list[int], channels: list[str], grid: int,
                  horizon: int, second: int | None, pair: bool = False
                  ) -> tuple[int, list[tuple[int, str]]]:
    """A node starting like an NMT master (SPEC §2): its boot-up, within master_window_ms a
    broadcast, and then its heartbeats go on in its old state, or it obeys (boot-up after
    a reset, the commanded state) - with variations that break each condition. `second`:
    the node that started so before (a second candidate: mostly another node, and no
    reset, which would make its boot-up an answer to the first one's); `pair`: a second
    one will follow. Returns the node."""
    node = draw(st.sampled_from([*nodes, 1, 1, 9] if second is None
                                else [n for n in (1, 9, 4) if n != second]))
    bus = draw(st.sampled_from(channels))
    ec = f"{0x700 + node:03X}"
    period = draw(st.sampled_from([50_000, 100_000]))
    if second is None:
        t = draw(st.integers(0, max(horizon, grid) // grid)) * grid
    else:  # mostly after the first one's start
        t = max(horizon + draw(st.sampled_from([-500_000, grid, 500_000, 11_000_000])), 0)
    out = []
    if not pair and draw(st.integers(0, 4)) == 0:  # a reset before: the boot-up answers it
        out.append((max(t - draw(st.sampled_from([grid, 500_000])), 0),
                    f"000#{draw(st.sampled_from([0x81, 0x82])):02X}"
                    f"{draw(st.sampled_from([0, node])):02X}"))
    out.append((t, f"{ec}#00"))
    t += draw(st.sampled_from([0, grid, 50_000, 300_000, 1_000_000, 1_200_000]))
    if draw(st.integers(0, 5)) == 0:  # another NMT command in between
        out.append((t, f"000#01{draw(st.sampled_from(nodes)):02X}"))
        t += grid
    cs = draw(st.sampled_from([0x01, 0x02, 0x02, 0x81] if second is not None or pair
                              else [0x82, 0x82, 0x81, 0x01, 0x01, 0x02, 0x80]))
    out.append((t, f"000#{cs:02X}00"))
    state = 0x7F
    obeys = draw(st.sampled_from(["no", "no", "no", "yes", "late"]))
    t += draw(st.sampled_from([1, 1000, grid, period]))
    for k in range(draw(st.integers(2, 12))):
        if k == 0 and obeys != "no":
            if cs in (0x81, 0x82):
                if obeys == "yes":
                    out.append((t, f"{ec}#00"))
                else:  # after bootup_timeout_ms: still a master (goes on, boots late)
                    t += 5_100_000
                    out.append((t, f"{ec}#00"))
            else:
                state = {0x01: 0x05, 0x02: 0x04, 0x80: 0x7F}[cs]
                if obeys == "late":
                    out.append((t, f"{ec}#7F"))  # within obey_ms maybe: stale
        out.append((t, f"{ec}#{state:02X}"))
        t += period
    return node, [(t_, bus + f) for t_, f in out]


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
                 "guarding", "guarding", "mixed", "sdo", "tpdo", "bootup_1017", "twins"]))
            if action == "bootup":
                frames.append((t, f"{ec}#00"))
                toggle = 0
                t += draw(st.sampled_from([0, grid, period]))
            elif action == "bootup_1017":
                # a boot-up, the master writes 1017h (or 0) some time later, the first
                # heartbeat comes on time or late (H001 gaps start at the write)
                frames.append((t, f"{ec}#00"))
                toggle = 0
                t += draw(st.sampled_from([grid, period, 3 * period, 700_000]))
                value = draw(st.sampled_from([period // 1000, period // 1000, 2 * period // 1000,
                                              0]))
                frames += _sdo_write(node, t, 0x1017, 0, value, 2,
                                     draw(st.sampled_from(["60", "60", "60", "none"])))
                t += 1000 + draw(st.sampled_from([0, period // 2, period, 2 * period,
                                                  1_000_000]))
            elif action == "twins":
                # two producers out of phase (short/long intervals alternating, jitter) or a
                # fixed-rate producer that stalls once and catches up
                short = draw(st.sampled_from([period // 5, period // 3, period * 2 // 5]))
                if draw(st.booleans()):
                    steps = [short, period - short] * draw(st.integers(2, 5))
                    steps = [d + draw(st.sampled_from([0, 0, -2000, 2000, short // 4]))
                             for d in steps]
                else:
                    steps = [period] * draw(st.integers(0, 3)) + [period * 2 - short, short] + [
                        period] * draw(st.integers(1, 4))
                codes = [state] * len(steps)
                if draw(st.integers(0, 3)) == 0:  # the twins report different states
                    twin = draw(st.sampled_from(STATES))
                    codes = [state if k % 2 == 0 else twin for k in range(len(steps))]
                for d, code in zip(steps, codes, strict=True):
                    frames.append((t, f"{ec}#{code:02X}"))
                    t += max(d, 0)
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
    # a master: its boot-up, a broadcast soon after, and its heartbeats going on (or it
    # obeys after all); sometimes a second node starts the same way (two candidates)
    started: int | None = None
    after = horizon
    starts = draw(st.sampled_from([0, 0, 1, 1, 2, 2]))
    for k in range(starts):
        started, more = _master_start(draw, nodes, channels, grid, after, started,
                                      pair=starts == 2 and k == 0)
        after = more[2][0]  # about the broadcast: a second one starts after it
        frames += more
    # NMT commands, often exactly at the time of some other frame, just before a
    # heartbeat (stale reports) or just after a boot-up (a master's broadcast)
    for _ in range(draw(st.integers(0, 6))):
        cs = draw(st.sampled_from([0x01, 0x02, 0x80, 0x81, 0x82]))
        target = draw(st.sampled_from([0, *nodes]))
        where = draw(st.sampled_from(["frame", "frame", "grid", "grid", "before", "bootup"]))
        bootups = [f for f in frames if f[1].endswith("#00") and "000#" not in f[1]]
        if where == "bootup" and bootups:
            t = draw(st.sampled_from(bootups))[0] + draw(st.sampled_from([0, grid, 50_000]))
            target = draw(st.sampled_from([0, 0, target]))
        elif where in ("frame", "before") and frames:
            t = draw(st.sampled_from(frames))[0]
            if where == "before":  # the frame follows the command within obey_ms
                t = max(t - draw(st.sampled_from([1, 1000, grid, 50_000, 100_000])), 0)
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
        if draw(st.integers(0, 3)) == 0:  # the master named (perhaps another node)
            network = f"master = {draw(st.sampled_from([*nodes, 1]))}\n" + network
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


# --- SPEC 2026-11: the NMT master, stale reports, period in force, H001 gaps, N002 -----

def _sdo_1017(node: int, t: float, value_ms: int) -> list[tuple[float, str]]:
    """A confirmed expedited write of 1017h (1 ms later)."""
    return [(t, f"{0x600 + node:03X}#2B171000{value_ms & 0xFF:02X}{value_ms >> 8:02X}0000"),
            (round(t + 0.001, 6), f"{0x580 + node:03X}#6017100000000000")]


# name -> (frames, what the reference must find: rule codes (a multiset, in time order,
# of the findings of the nodes named), the channel's master view, stale frame count)
SPEC_CASES: dict[str, tuple[list[tuple[float, str]], dict[str, Any]]] = {
    # A/B: slaves 2 and 3 up, then the master (1) boots and resets all; its heartbeats go
    # on, the slaves obey (silent, then boot); a start-all later: the slaves go
    # OPERATIONAL, the master stays PRE-OPERATIONAL (no S004, no B001 for it)
    "master_bootup_then_reset_all": (
        [(0.0, "702#00"), (0.01, "703#00")] + _hb(2, 0.1, 0.6) + _hb(3, 0.11, 0.6)
        + [(0.5, "701#00"), (0.6, "000#8200")] + _hb(1, 0.7, 3.0)
        + [(0.8, "702#00"), (0.85, "703#00")] + _hb(2, 0.9, 1.55) + _hb(3, 0.95, 1.6)
        + [(1.5, "000#0100")] + _hb(2, 1.6, 3.0, "05") + _hb(3, 1.65, 3.0, "05"),
        {"master": (1, "inferred"), "rules_of": {1: [], 2: [], 3: []}}),
    # B: a start broadcast right after the boot-up, not obeyed by its sender
    "master_start_not_obeyed": (
        [(0.0, "705#00"), (0.0, "701#00"), (0.2, "000#0100")] + _hb(1, 0.3, 1.5)
        + _hb(5, 0.1, 1.5, "05")[:1] + _hb(5, 0.25, 1.5, "05"),
        {"master": (1, "inferred"), "rules_of": {1: []}}),
    # B: two nodes start like a master: none is inferred, the broadcasts apply to both
    # (a reset-all before node 4's boot-up would make that boot-up an answer to it)
    "two_candidate_masters": (
        [(0.0, "701#00"), (0.1, "000#0100")] + _hb(1, 0.2, 4.0)
        + [(2.0, "704#00"), (2.05, "000#0200")] + _hb(4, 2.1, 4.0),
        {"master": ("several", [1, 4])}),
    # B (3): the node obeys the reset (boot-up again): not a master
    "bootup_reset_all_obeyed": (
        [(0.0, "701#00"), (0.1, "000#8200"), (0.3, "701#00")] + _hb(1, 0.4, 1.0),
        {"master": ("none",)}),
    # B (2): the boot-up answers a reset-all before it: not a master
    "bootup_answers_a_reset": (
        [(0.0, "701#7F"), (0.05, "000#8100"), (0.1, "701#00"), (0.2, "000#0100")]
        + _hb(1, 0.3, 1.0),
        {"master": ("none",)}),
    # B (1): another NMT command between the boot-up and the broadcast; and a broadcast
    # later than master_window_ms
    "bootup_command_between_or_too_late": (
        [(0.0, "701#00"), (0.05, "000#0102"), (0.1, "000#0100")] + _hb(1, 0.2, 1.0)
        + [(1.5, "706#00"), (2.6, "000#0200")] + _hb(6, 1.6, 3.0),
        {"master": ("none",)}),
    # B (3): after a broadcast reset the sender's heartbeat within obey_ms does not count,
    # the next one does
    "master_reset_heartbeat_within_obey": (
        [(0.0, "701#00"), (0.1, "000#8100"), (0.15, "701#7F"), (0.3, "701#7F")],
        {"master": (1, "inferred")}),
    # C: a guarding response 1 us after a start still says PRE-OPERATIONAL: stale (no
    # S005 when the node answers OPERATIONAL next, no timeline change)
    "stale_guard_response_after_start": (
        [(0.0, "705#00"), (0.1, "705#R"), (0.101, "705#7F"), (0.3, "705#R"),
         (0.3005, "000#0105"), (0.300501, "705#FF"), (0.5, "705#R"), (0.501, "705#05"),
         (0.7, "705#R"), (0.701, "705#85")],
        {"stale": 1, "rules_of": {5: []}}),
    # C: a heartbeat right after a stop still says OPERATIONAL; one after a reset is no
    # sign of life (no B001) but starts a heartbeat gap that the boot-up 0.3 s later ends
    # too late (H001); one after a command while OFFLINE reports the state before (H001)
    "stale_heartbeats": (
        [(0.0, "702#00"), (0.05, "000#0102")] + _hb(2, 0.1, 1.0, "05")
        + [(1.0, "000#0202"), (1.02, "702#05")] + _hb(2, 1.1, 2.0, "04")
        + [(2.0, "000#8102"), (2.001, "702#04"), (2.3, "702#00")] + _hb(2, 2.4, 3.0)
        + [(3.5, "000#0102"), (3.55, "702#7F")] + _hb(2, 3.6, 4.0, "05"),
        {"stale": 3, "rules_of": {2: ["H001", "H001"]}}),
    # E: no gap from the boot-up; the gap starts at the confirmed 1017h write, the first
    # heartbeat comes late
    "bootup_then_late_first_heartbeat_after_1017_write": (
        [(0.0, "702#00")] + _sdo_1017(2, 0.4, 100) + _hb(2, 0.9, 2.0),
        {"rules_of": {2: ["H001"]}}),
    # E: a boot-up and a late first heartbeat without any write: no H001
    "bootup_then_late_first_heartbeat": (
        [(0.0, "702#00"), (0.0, "703#00")] + _hb(2, 2.0, 3.0) + _hb(3, 0.1, 3.0),
        {"rules_of": {2: []}}),
    # E: a longer 1017h written while a gap runs does not move the limit fixed at the
    # gap's start; a 0 write ends a gap (one that already expired is still found); a
    # reset ends one
    "h001_limit_fixed_at_gap_start": (
        [(0.0, "702#00")] + _hb(2, 0.1, 1.0) + _sdo_1017(2, 1.0, 500) + _hb(2, 1.3, 2.0, period=0.5)
        + _sdo_1017(2, 2.6, 0) + [(2.7, "702#7F")] + _sdo_1017(2, 2.72, 100)
        + [(3.0, "702#7F"), (3.05, "000#8102"), (3.5, "702#00")],
        {"rules_of": {2: ["H001", "H001", "H001"]}}),
    # F: a fixed-rate producer stalls once and catches up: not two producers
    "stalled_fixed_rate_producer": (
        _hb(4, 0.0, 0.5) + [(0.68, "704#7F"), (0.7, "704#7F")] + _hb(4, 0.8, 1.5),
        {"no_rule": "N002"}),
    # F: two producers out of phase (shorts and longs each within 20 %)
    "two_producers_out_of_phase": (
        [(round(k * 0.05 + (0.02 if k % 2 else 0.0), 6), "704#05") for k in range(10)],
        {"rule": "N002"}),
    # F: short/long but the shorts differ by more than 20 %
    "alternating_uneven_shorts": (
        [(t, "704#05") for t in (0.0, 0.02, 0.1, 0.13, 0.2, 0.22, 0.3)],
        {"no_rule": "N002"}),
    # D: 1017h written, then a longer one; heartbeats twice as often as the new value
    # wants are early against it, whatever the whole-trace median says
    "h002_after_1017_written_then_changed": (
        [(0.0, "703#00")] + _sdo_1017(3, 0.05, 100) + _hb(3, 0.1, 1.0, "7F")
        + _sdo_1017(3, 1.0, 500) + _hb(3, 1.1, 3.0, "7F", period=0.2),
        {"rule": "H002"}),
    # D: the guarding classification uses the period in force at the previous heartbeat:
    # 1017h = 200 ms written, a frame 60 ms after a heartbeat with a request pending is a
    # guarding response (the median of the 40 ms heartbeats before would say heartbeat)
    "guard_response_against_the_period_in_force": (
        [(0.0, "706#00")] + _hb(6, 0.04, 1.0, period=0.04) + _sdo_1017(6, 1.0, 200)
        + _hb(6, 1.2, 2.2, period=0.2) + [(1.63, "706#R"), (1.66, "706#7F")],
        {"stale": 0, "rule": "G004"}),
    # A/B: the master named in the network file: broadcasts do not apply to it, and no
    # inference (node 4 would qualify)
    "master_from_the_network_file": (
        [(0.0, "701#00"), (0.0, "702#00")] + _hb(1, 0.1, 2.0) + _hb(2, 0.1, 2.0)
        + [(0.5, "704#00"), (0.55, "000#0100")] + _hb(4, 0.6, 2.0) + _hb(2, 0.6, 2.0, "05"),
        {"network": "master = 1\n", "master": (1, "network"), "rules_of": {1: []}}),
    # A: a channel's own master wins over the top-level one
    "master_of_a_channel_from_the_network_file": (
        [(0.0, "701#00"), (0.0, "can1 702#00"), (0.1, "000#0100"), (0.1, "can1 000#0100")]
        + _hb(1, 0.2, 1.0) + [(t, "can1 " + f) for t, f in _hb(2, 0.2, 1.0)],
        {"network": "master = 1\n[channels.can1]\nmaster = 2\n", "master": (1, "network"),
         "rules_of": {1: [], 2: []}}),
    # A: master_window_ms in the profile's [timeline] table: 40 ms is too short here
    "master_window_from_the_profile": (
        [(0.0, "701#00"), (0.1, "000#8200")] + _hb(1, 0.2, 1.0),
        {"params": (("timeline", "master_window_ms", 40.0),), "master": ("none",)}),
    # B: after a boot-up, the master's broadcast and its heartbeats going on: within obey_ms
    # (S004's) they do not count yet; with obey_ms 300 the only one is inside it
    "master_with_a_longer_obey_ms": (
        [(0.0, "701#00"), (0.1, "000#0100"), (0.3, "701#7F")],
        {"params": (("S004", "obey_ms", 300.0),), "master": ("none",)}),
}


@pytest.mark.parametrize("name", sorted(SPEC_CASES))
def test_spec_2026_11_cases_match_the_object_reference(name: str, tmp_path: Path) -> None:
    frames, want = SPEC_CASES[name]
    text = text_of(ms(sorted(frames, key=lambda f: f[0])))
    log = tmp_path / "trace.log"
    log.write_text(text)
    profile = copy.deepcopy(PROFILE)
    for code, param, value in want.get("params", ()):
        (profile.timeline if code == "timeline" else profile[code].params)[param] = value
    net = None
    if "network" in want:
        (tmp_path / "net.toml").write_text(want["network"])
        net = load_network(str(tmp_path / "net.toml"))
    ref = reference_check(str(log), profile, network=net)
    cm = ref.model.channels[0]
    if "master" in want:
        assert _master_view(cm) == want["master"]
    if "stale" in want:
        assert sum(len(_stale(m)) for m in cm.nodes.values()) == want["stale"]
    for node, rules in want.get("rules_of", {}).items():
        assert [f.rule for f in ref.findings if f.node == node] == rules
    if "rule" in want:
        assert want["rule"] in {f.rule for f in ref.findings}
    if "no_rule" in want:
        assert want["no_rule"] not in {f.rule for f in ref.findings}
    compare(tmp_path, text, want.get("network"), want.get("params", ()))


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
    assert [f.rule for f in res.findings] == ["I005"]  # timestamps-backwards: the input's
    assert [iv.state for iv in node.intervals] == ["STOPPED"]
