"""The state the live SYNC, PDO and EMCY rules (live/comm.py) keep per node, PDO stream
and channel: a few numbers each, never the frames (O(nodes + streams))."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

from nmtcheck.live.tracker import LiveFinding
from nmtcheck.processes import pdo as pdo_stage
from nmtcheck.processes.comm_values import UNKNOWN, Value

RECENT_FRAMES = 256  # a channel's recent frame times: a frame's wait for the bus (q)
SYNC_INTERVALS = 1024  # the SYNC intervals of a segment kept for a measured period


@dataclass
class CommNode:
    """What the comm rules keep per (channel, node)."""

    written: dict[int, tuple[int, float] | None] = field(default_factory=dict)  # None: voided
    request: tuple[int, int, int] | None = None  # a pending expedited download: index,
    # sub-index, value
    pdo_written: bool = False  # a confirmed write of one of its PDO parameters
    epoch: int = 0  # boot-ups and resets so far (D005 runs)
    # the first boot-up or reset after its previous EMCY (E001: one strictly between two
    # EMCYs separates them; one on either's instant does not, as offline)
    cleared_at: float | None = None
    writes_1015: int = 0  # confirmed writes of 1015h (E001 pairs)
    offline_at: float = float("-inf")  # the latest H001/G002 live saw for it
    emcy_ts: float | None = None  # its previous EMCY
    emcy_writes: int = 0  # writes_1015 at it
    e001_run: bool = False
    e002_run: int = 0  # the defect (100 + DLC) of the run of malformed EMCYs, 0: none
    last_8250: float = float("-inf")  # its latest EMCY 8250h (D004)
    last_ec: float = float("-inf")  # its latest frame on 700h + N, a request too (D001)
    last_report: float = float("-inf")  # its latest heartbeat or guarding response
    # findings of gaps that began at t_l, waiting for the node's first report after t_l
    # (§9.1.6: another state with no command to it voids them): (finding, t_l, the
    # stream's next frame after the gap (D004: an EMCY 8250h before it keeps it))
    report_watch: list[tuple[LiveFinding, float, float]] = field(default_factory=list)
    # D001 findings whose producer sent nothing since t_l: void if it goes OFFLINE first
    silent_watch: list[tuple[LiveFinding, float, PdoStream]] = field(default_factory=list)


@dataclass
class Deadline:
    """An armed RPDO deadline of one consumer (D004)."""

    party: pdo_stage.Party
    armed: float | None = None  # t_l
    due: float = float("inf")
    fired: LiveFinding | None = None
    watch: bool = False  # the consumer's first report after t_l is still to come
    # that report showed another state with no command to it (§9.1.6): the finding goes
    # unless an EMCY 8250h of the consumer comes at or after the deadline, before the
    # stream's next frame
    voidable: bool = False


@dataclass
class PdoStream:
    """A PDO COB-ID on a channel with its parties (processes/pdo.channel_parties)."""

    cob_id: int
    producer: pdo_stage.Party | None
    consumers: list[pdo_stage.Party]
    window: Value = UNKNOWN  # W (1007h) of §9.1.1
    inhibit_s: float = 0.0  # D002: the producer's inhibit time (type 254/255), 0: not judged
    window_s: float = 0.0  # Y004: W of a synchronous stream, 0: not judged
    tt: int = -1  # the stream's transmission type (§9.1.5), -1: unknown
    y004_run: tuple[float | None, float] | None = None  # the OPERATIONAL interval of a run
    event_limit_s: float = 0.0  # D001: L of the producer's event timer, 0: not judged
    d001_armed: float | None = None  # t_l of the gap D001 watches
    d001_due: float = float("inf")
    d001_fired: LiveFinding | None = None  # the D001 of the latest gap
    # D005: (producer?, party, mapped length) of each party whose mapping is known
    mapped: list[tuple[bool, pdo_stage.Party, int]] = field(default_factory=list)
    last: float | None = None  # its previous frame (D002)
    d002_run: bool = False
    # D005: per (producer?, party) and run (its boot-ups and resets), each offending DLC's
    # first and latest frame
    d005: dict[tuple[bool, int], tuple[int, dict[int, tuple[float, float]]]] = field(
        default_factory=dict)
    deadlines: list[Deadline] = field(default_factory=list)  # D004, judged consumers only

    def __post_init__(self) -> None:
        p = self.producer
        if p is not None and p.inhibit_100us.value and type_in(p, pdo_stage.EVENT_DRIVEN):
            self.inhibit_s = float(p.inhibit_100us.value) * 1e-4
        tt = next((x.transmission_type for x in [p, *self.consumers]
                   if x is not None and x.transmission_type.known), UNKNOWN)
        self.tt = int(tt.value or 0) if tt.known else -1
        if self.tt in pdo_stage.SYNCHRONOUS and self.window.value:
            self.window_s = float(self.window.value) / 1e6
        self.mapped = [(which, party, int(party.mapping.value or 0)) for which, party in (
            [(True, p)] if p is not None else []) + [(False, c) for c in self.consumers]
            if party.mapping.value]
        # synchronous RPDOs are left alone (SPEC_COMM §9.2.2 D004)
        self.deadlines = [Deadline(c) for c in self.consumers if c.event_timer_ms.value
                          and not type_in(c, pdo_stage.SYNCHRONOUS)]


def type_in(party: pdo_stage.Party, types: range | tuple[int, ...]) -> bool:
    tt = party.transmission_type
    return tt.known and int(tt.value or 0) in types


@dataclass
class CommChannel:
    name: str
    recent: deque[float] = field(default_factory=lambda: deque(maxlen=RECENT_FRAMES))
    d8: list[float] = field(default_factory=list)  # the smallest intervals before DLC 8
    d8_value: float | None = None  # d8 of §9.1.6 from them (None: not established)
    streams: dict[int, PdoStream] = field(default_factory=dict)
    watched: dict[int, list[Deadline]] = field(default_factory=dict)  # consumer -> D004's
    ec_watch: set[int] = field(default_factory=set)  # nodes whose 700h + N frames matter
    needs_q: bool = False  # a D002 stream: the frame times are kept for q (§9.1.6)
    sync_cob: int = 0x80
    producer: int | None = None
    segment: int = 0  # segment ends so far
    sync_segment: int = -1  # the segment of the latest SYNC
    seg_first_dlc: int | None = None
    seg_values: tuple[Value, Value] = (UNKNOWN, UNKNOWN)  # P, C at the segment's start
    seg_broken: bool = False  # Y003 said in this segment
    intervals: deque[float] = field(default_factory=lambda: deque(maxlen=SYNC_INTERVALS))
    syncs: int = 0  # SYNC frames of the segment
    measured: float | None = None  # the median interval so far
    last_sync: float | None = None
    last_counter: int | None = None  # the latest valid counter (Y003)
    y002_run: tuple[int, int] = (0, -1)  # (defect, segment) of the previous SYNC
    sync_due: float | None = None
    sync_limit: tuple[float, str, bool] | None = None  # T, how, sure (configured by a file)
    # a confirmed write of 1019h was seen: whether C is known in a segment, and which,
    # rests on which resets reach which node, which only the offline timeline settles
    c_written: bool = False
    y001_fired: LiveFinding | None = None  # the Y001 of the latest gap


def source_text(v: Value) -> str:
    if v.source == "sdo":
        return "written by SDO"
    if v.source == "device-file" and v.node is not None:
        return f"node {v.node}'s device file"
    return str(v.source)
