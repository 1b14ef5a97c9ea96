"""What the reconstruction of the CiA 302-2 boot-slave process yields (SPEC §8.5): the
Lely-compatible letters, a process with its steps and failures, the per-node report and
the per-channel analysis the P rules and the reports read, and the parameters it ran with."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from nmtcheck.processes.attached import Attached
from nmtcheck.timeline.tables import blank

# Lely's co_nmt_es2str (src/co/nmt.c)
LETTERS = {
    "A": "The CANopen device is not listed in object 1F81.",
    "B": "No response received for upload request of object 1000.",
    "C": "Value of object 1000 from CANopen device is different to value in object 1F84 "
         "(Device type).",
    "D": "Value of object 1018 sub-index 01 from CANopen device is different to value in "
         "object 1F85 (Vendor-ID).",
    "E": "Heartbeat event. No heartbeat message received from CANopen device.",
    "F": "Node guarding event. No confirmation for guarding request received from CANopen "
         "device.",
    "G": "Objects for program download are not configured or inconsistent.",
    "H": "Software update is required, but not allowed.",
    "I": "Software update is required, but program download failed.",
    "J": "Configuration download failed.",
    "K": "Heartbeat event during start error control service. No heartbeat message received "
         "from CANopen device during start error control service.",
    "L": "CANopen device is initially in NMT state OPERATIONAL.",
    "M": "Value of object 1018 sub-index 02 from CANopen device is different to value in "
         "object 1F86 (Product code).",
    "N": "Value of object 1018 sub-index 03 from CANopen device is different to value in "
         "object 1F87 (Revision number).",
    "O": "Value of object 1018 sub-index 04 from CANopen device is different to value in "
         "object 1F88 (Serial number).",
}

IDENTITY_STEPS = {1: ("vendor_id", "D", 0x1F85), 2: ("product_code", "M", 0x1F86),
                  3: ("revision_number", "N", 0x1F87), 4: ("serial_number", "O", 0x1F88)}
RESTORE_VALUE = 0x64616F6C  # "load"
CS_START, CS_RESET_NODE, CS_RESET_COMM = 0x01, 0x81, 0x82
MAX_STEPS = 64
KEEP_PROCESSES = 64  # per node, besides those with a finding and the last one


@dataclass
class BootParams:
    probe_window_s: float = 1.0
    sdo_timeout_s: float = 1.0
    restore_timeout_s: float = 1.0
    rtr_timeout_s: float = 0.1
    reset_timeout_s: float = 1.0
    stall_s: float = 10.0


@dataclass(slots=True)
class Where:
    time: float
    frame_index: int
    line: int


@dataclass(slots=True)
class Step:
    step: str
    time: float
    frame_index: int
    line: int
    attempt: int = 0
    row: int = -1  # the transfer's row, for transfer steps
    index: int | None = None
    sub: int | None = None
    result: str | None = None
    value: int | None = None
    expected: int | None = None
    expected_source: str | None = None
    abort_code: int | None = None
    end: Where | None = None
    direction: int = -1

    def as_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"step": self.step, "time": round(self.time, 6),
                             "frame_index": self.frame_index, "line": self.line or None}
        if self.row >= 0:
            d.update({"index": f"{self.index:04X}h", "sub": self.sub,
                      "end_time": None if self.end is None else round(self.end.time, 6),
                      "end_frame_index": None if self.end is None else self.end.frame_index,
                      "end_line": None if self.end is None else (self.end.line or None),
                      "result": self.result, "value": _hex(self.value),
                      "expected": _hex(self.expected), "expected_source": self.expected_source,
                      "abort_code": None if self.abort_code is None
                      else f"{self.abort_code:08X}h"})
        return d


def _hex(v: int | None) -> str | None:
    return None if v is None else f"0x{v:08X}"


@dataclass(slots=True)
class Failure:
    code: str  # P001 ... P004
    letter: str
    at: Where  # the proving frame (for K/E/F: the wait's expiry moment, frame -1)
    message: str
    evidence: Where | None = None
    moment: bool = False  # the finding is a moment (P004): its frame is found later


@dataclass(slots=True)
class Process:
    node: int
    start: float
    start_idx: int
    start_line: int
    anchor: str  # bootup | reset | master-bootup
    probes: list[int] = field(default_factory=list)  # transfer rows
    answered: bool = False
    end: float | None = None
    end_idx: int | None = None
    end_how: str = "trace-end"  # start | operational | superseded | trace-end
    started_at: Where | None = None
    operational_at: Where | None = None
    keep_alive: bool = False
    probed_before_bootup: bool = False
    steps: list[Step] = field(default_factory=list)
    attempts: int = 1
    failure: Failure | None = None  # the first failure of the last attempt
    failures: int = 0
    status: str = "incomplete"
    letter: str | None = None
    letter_source: str | None = None
    reason: str | None = None
    evidence: Where | None = None
    findings: list[str] = field(default_factory=list)
    last_frame: Where | None = None
    transfers: int = 0
    last_step: str = "none"  # kept when the steps of an old, healthy process are dropped

    def as_dict(self) -> dict[str, Any]:
        steps = [s.as_dict() for s in self.steps]
        if len(steps) > MAX_STEPS:
            cfg = [s for s in self.steps if s.step == "config"]
            rest = [s.as_dict() for s in self.steps if s.step != "config"]
            summary = {"step": "config", "count": len(cfg),
                       "failed": sum(1 for s in cfg if s.result not in ("ok", "open")),
                       "time": round(cfg[0].time, 6) if cfg else None,
                       "end_time": round(max((s.end.time if s.end else s.time) for s in cfg), 6)
                       if cfg else None}
            steps = sorted([*rest, summary], key=lambda d: d["time"] or 0.0)[:MAX_STEPS]
        return {"start": round(self.start, 6),
                "end": None if self.end is None else round(self.end, 6),
                "anchor": self.anchor, "attempts": self.attempts, "keep_alive": self.keep_alive,
                "probed_before_bootup": self.probed_before_bootup,
                "started_at": None if self.started_at is None else round(self.started_at.time, 6),
                "steps": steps,
                "evidence": None if self.evidence is None else {
                    "time": round(self.evidence.time, 6),
                    "frame_index": self.evidence.frame_index,
                    "line": self.evidence.line or None},
                "findings": list(self.findings)}


@dataclass
class BootFinding:
    code: str
    channel: str
    node: int
    time: float
    frame_index: int | None
    line: int | None
    message: str
    letter: str | None
    evidence: Where | None


STATUSES = ("ok", "failed", "incomplete")


@dataclass
class Spans:
    """Every process of a node in brief, as columns (whole processes are kept only where a
    finding or the report needs them: a log may boot a node a million times)."""

    start: np.ndarray
    end: np.ndarray  # inf: open at the trace end
    status: np.ndarray  # index into STATUSES
    letter: np.ndarray  # "" when none
    last_step: list[str]  # distinct names, for `step`
    step: np.ndarray  # index into last_step
    ev_time: np.ndarray  # the evidence frame (NaN: none)
    ev_idx: np.ndarray
    ev_line: np.ndarray

    @classmethod
    def of(cls, procs: list[Process]) -> Spans:
        names = sorted({x.last_step for x in procs})
        ev = [x.evidence for x in procs]
        return cls(np.asarray([x.start for x in procs], np.float64),
                   np.asarray([np.inf if x.end is None else x.end for x in procs], np.float64),
                   np.asarray([STATUSES.index(x.status) for x in procs], np.int8),
                   np.asarray([x.letter or "" for x in procs], "U1"), names,
                   np.asarray([names.index(x.last_step) for x in procs], np.int16),
                   np.asarray([np.nan if w is None else w.time for w in ev], np.float64),
                   np.asarray([-1 if w is None else w.frame_index for w in ev], np.int64),
                   np.asarray([0 if w is None else w.line for w in ev], np.int64))

    @classmethod
    def empty(cls) -> Spans:
        spans = blank(cls, lambda: cls.of([]))  # one per node: its columns made once
        spans.last_step = []  # appended to in place
        return spans

    def __len__(self) -> int:
        return len(self.start)

    def compact_names(self) -> None:
        """`last_step` as `of` makes it: the names in use, sorted."""
        used = sorted({self.last_step[k] for k in np.unique(self.step).tolist()})
        remap = np.zeros(max(len(self.last_step), 1), np.int16)
        for k, name in enumerate(self.last_step):
            if name in used:
                remap[k] = used.index(name)
        self.step = remap[self.step]
        self.last_step = used


@dataclass
class NodeBootReport:
    channel: str
    node: int
    status: str  # ok | failed | incomplete | not-managed
    letter: str | None = None
    letter_source: str | None = None
    reason: str | None = None
    assignment: dict[str, Any] | None = None
    processes: int = 0
    process: Process | None = None
    candidates: str = ""
    spans: Spans = field(default_factory=lambda: Spans.empty())  # every process, compact

    def as_dict(self) -> dict[str, Any]:
        return {"status": self.status, "letter": self.letter,
                "letter_source": self.letter_source, "reason": self.reason,
                "assignment": self.assignment, "processes": self.processes,
                "process": None if self.process is None else self.process.as_dict()}


@dataclass
class ChannelBoot:
    name: str
    manager: str  # network | master-dcf | inferred | none | off
    starts_slaves: tuple[bool, str] = (False, "inferred")
    start_all: tuple[bool, str] = (False, "inferred")
    sdo_timeout_inferred_ms: float | None = None
    manager_sdo_timeout_ms: float | None = None
    network_boots: list[dict[str, Any]] = field(default_factory=list)
    note: str = ""

    @property
    def ran(self) -> bool:
        return self.manager in ("network", "master-dcf", "inferred")

    def as_dict(self) -> dict[str, Any]:
        return {"manager": self.manager,
                "starts_slaves": {"value": self.starts_slaves[0], "source": self.starts_slaves[1]},
                "start_all": {"value": self.start_all[0], "source": self.start_all[1]},
                "sdo_timeout_inferred_ms": self.sdo_timeout_inferred_ms,
                "network_boots": self.network_boots}

    def heading(self) -> str:
        if not self.ran:
            return (f"manager {self.manager}: no CiA 302 boot-slave process seen"
                    if self.manager == "none" else "manager off: the P group is turned off")
        how = "all at once" if self.start_all[0] else "individually"
        starts = (f"starts slaves {how} ({self.starts_slaves[1]})" if self.starts_slaves[0]
                  else f"starts no slave ({self.starts_slaves[1]})")
        return f"manager {self.manager}; {starts}"


@dataclass
class BootAnalysis:
    """What the boot stage found. A log may fail a million boot processes: past `cap`
    findings of a code (the engine's per-rule cap, 0: none) a finding is only counted in
    `omitted`, since the engine would only count it too; `findings` holds the others, in
    the order the P rules hand them on (channel, node, process)."""

    channels: dict[str, ChannelBoot] = field(default_factory=dict)
    nodes: dict[tuple[str, int], NodeBootReport] = field(default_factory=dict)
    findings: list[BootFinding] = field(default_factory=list)
    cap: int = 0
    counts: dict[str, int] = field(default_factory=dict)  # per code: made and omitted
    omitted: dict[tuple[str, str], int] = field(default_factory=dict)  # (code, channel)

    def for_rule(self, code: str) -> Iterator[BootFinding]:
        return (f for f in self.findings if f.code == code)

    def make(self, code: str, channel: str) -> bool:
        """Count a finding of `code`; whether it is made (under the cap)."""
        seen = self.counts.get(code, 0)
        if self.cap and seen >= self.cap:
            self.omit(code, channel, 1)
            return False
        self.counts[code] = seen + 1
        return True

    def omit(self, code: str, channel: str, k: int) -> None:
        """Count k findings of `code` past the cap."""
        self.counts[code] = self.counts.get(code, 0) + k
        self.omitted[(code, channel)] = self.omitted.get((code, channel), 0) + k

    def batches(self, code: str) -> Iterator[tuple[str, list[BootFinding], int]]:
        """Per channel (in order): the findings of `code` made, then how many follow them
        uncounted past the cap."""
        made: dict[str, list[BootFinding]] = {}
        for f in self.for_rule(code):
            made.setdefault(f.channel, []).append(f)
        for ch in self.channels:
            rows, left = made.get(ch, []), self.omitted.get((code, ch), 0)
            if rows or left:
                yield ch, rows, left


_SLOT: Attached[BootAnalysis] = Attached("boot")
attach = _SLOT.attach  # the engine keeps the analysis with the model
of = _SLOT.of  # the rules and reports read it
