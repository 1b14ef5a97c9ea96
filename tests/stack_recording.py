"""Reading a CANopenNode recording of samples/canopennode/ (a candump log and the hub's
`.events` file beside it, README there) as the stack saw it: its frames, the lines its
callbacks printed, the EMCYs it says it sent; and nmtcheck's findings on the log."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from nmtcheck.engine import check_input, select_rules
from nmtcheck.results import InputResult
from nmtcheck.settings.network import load_network
from nmtcheck.settings.profiles import load_profile

DEVICES = {"master": 1, "s2": 2, "s3": 3, "s4": 4}
Found = list[tuple[str, int | None, float]]
EVENT = re.compile(r"# (\d+\.\d{6}) (\w+): (.*)")
EMCY_SENT = re.compile(r"EMCY sent: code (\w{4}) register (\w\w) bit (\w\w) info (\w{8})")


@dataclass(frozen=True)
class Frame:
    line: int
    t: float  # seconds after the log's first frame
    can_id: int
    data: str  # hex, or "R…" for a remote frame


@dataclass(frozen=True)
class Event:
    t: float  # seconds after the log's first frame
    device: str
    text: str


def _stamp(line: str) -> float:
    return float(line.split()[0].strip("()"))


def t0(log: Path) -> float:
    """The stamp of the log's first frame: every time here counts from it."""
    return _stamp(log.read_text().splitlines()[0])


def frames(log: Path) -> list[Frame]:
    lines = log.read_text().splitlines()
    start = _stamp(lines[0])
    out = []
    for k, line in enumerate(lines, 1):
        can_id, _, data = line.split()[2].partition("#")
        out.append(Frame(k, round(_stamp(line) - start, 6), int(can_id, 16), data))
    return out


def events(log: Path) -> list[Event]:
    """The devices' lines of the .events file (the hub's own `# hub t=` lines left out),
    timed like the log."""
    start = t0(log)
    out = []
    for line in log.with_suffix(".events").read_text().splitlines():
        m = EVENT.fullmatch(line)
        if m:
            out.append(Event(round(float(m[1]) - start, 6), m[2], m[3]))
    return out


def emcys_sent(log: Path) -> list[tuple[float, int, str]]:
    """(time, node, the 8 data bytes as on the bus) of every EMCY the stack says it sent."""
    out = []
    for e in events(log):
        m = EMCY_SENT.match(e.text)
        if m:
            code, reg, bit, info = (int(v, 16) for v in m.groups())
            data = code.to_bytes(2, "little") + bytes([reg, bit]) + info.to_bytes(4, "little")
            out.append((e.t, DEVICES[e.device], data.hex().upper()))
    return out


def states(log: Path, device: str) -> list[tuple[float, str]]:
    """(time, state) of every NMT state change the device's callback reported."""
    return [(e.t, e.text.split()[2]) for e in events(log)
            if e.device == device and e.text.startswith("NMT state ")
            and "INITIALIZING" not in e.text]


def status(log: Path) -> dict[str, str]:
    """Each device's `status:` line near the end of the run."""
    return {e.device: e.text for e in events(log) if e.text.startswith("status: ")}


def emcys_are_on_the_bus(log: Path) -> list[Frame]:
    """Every EMCY the stack says it sent is a frame of the log on 80h + N with the same
    eight bytes, at most 1 ms from the callback's stamp (the hub stamps a frame when it
    takes it), in the same order; and the log holds no other EMCY."""
    emcys = [f for f in frames(log) if 0x81 <= f.can_id <= 0xFF]
    sent = emcys_sent(log)
    assert len(emcys) == len(sent), (emcys, sent)
    for frame, (t, node, data) in zip(emcys, sent, strict=True):
        assert (frame.can_id, frame.data) == (0x80 + node, data)
        assert abs(frame.t - t) < 0.001, (frame, t)
    return emcys


def check(log: Path, network: Path | None) -> InputResult:
    """nmtcheck's default profile on the log, with the network file or without."""
    profile = load_profile("default")
    net = load_network(str(network)) if network is not None else None
    return check_input(str(log), 0, profile, select_rules(profile, [], []), network=net)


def found(res: InputResult) -> Found:
    """(code, node, seconds after the log's start) of every finding."""
    start = res.stats.start or 0.0
    return [(f.rule, f.node, round(f.time - start, 6)) for f in res.findings]
