"""Each channel's LSS (CiA 305) traffic, reconstructed once per input (SPEC §9.1.8): the
requests on 7E5h paired with their responses on 7E4h, the configuration state of the
channel's LSS slaves before each request, the slaves seen (identity, node-IDs, store,
the boot-up that adopted a configured node-ID), the LSS sessions and the fastscan
sessions. The L rules (`checks/lss.py`), the `lss_bit_timing` link and the reports read
it; nothing here judges.

LSS traffic is sparse (a commissioning step, a drive swap), so the exchanges are kept as
objects; the frames themselves stay columns in `Decoded.lss`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from nmtcheck.processes.attached import Attached
from nmtcheck.protocol.nmt import BOOTUP
from nmtcheck.timeline.decode import LSS_REQUEST_ID
from nmtcheck.timeline.model import ChannelModel, InputModel

EPS = 1e-9
SWITCH_GLOBAL, CONFIGURE_NODE_ID, CONFIGURE_BIT_TIMING = 0x04, 0x11, 0x13
ACTIVATE_BIT_TIMING, STORE, SELECTIVE_SERIAL, SELECTIVE_ANSWER = 0x15, 0x17, 0x43, 0x44
FASTSCAN, IDENTIFY_ANSWER, NON_CONFIGURED_ANSWER, INQUIRE_NODE_ID = 0x51, 0x4F, 0x50, 0x5E
FASTSCAN_RESET = 0x80
PARTS = ("vendor_id", "product_code", "revision_number", "serial_number")
PART_NAMES = ("vendor-ID", "product code", "revision", "serial number")
RESETS = (0x81, 0x82)  # NMT reset node, reset communication

# cs -> (JSON name, the name a message uses)
SERVICES: dict[int, tuple[str, str]] = {
    0x04: ("switch-state-global", "switch state global"),
    0x40: ("switch-state-selective-vendor", "switch state selective vendor-ID"),
    0x41: ("switch-state-selective-product", "switch state selective product code"),
    0x42: ("switch-state-selective-revision", "switch state selective revision"),
    0x43: ("switch-state-selective-serial", "switch state selective serial number"),
    0x11: ("configure-node-id", "configure node-ID"),
    0x13: ("configure-bit-timing", "configure bit timing"),
    0x15: ("activate-bit-timing", "activate bit timing"),
    0x17: ("store-configuration", "store configuration"),
    0x46: ("identify-vendor", "identify remote slave vendor-ID"),
    0x47: ("identify-product", "identify remote slave product code"),
    0x48: ("identify-revision-low", "identify remote slave revision low"),
    0x49: ("identify-revision-high", "identify remote slave revision high"),
    0x4A: ("identify-serial-low", "identify remote slave serial low"),
    0x4B: ("identify-serial-high", "identify remote slave serial high"),
    0x4C: ("identify-non-configured", "identify non-configured remote slave"),
    0x51: ("fastscan", "fastscan"),
    0x5A: ("inquire-vendor-id", "inquire vendor-ID"),
    0x5B: ("inquire-product-code", "inquire product code"),
    0x5C: ("inquire-revision", "inquire revision"),
    0x5D: ("inquire-serial", "inquire serial number"),
    0x5E: ("inquire-node-id", "inquire node-ID"),
}
# request cs -> the cs of its response (SPEC §9.1.8's table); the others get none
RESPONSE_CS = {0x43: 0x44, 0x11: 0x11, 0x13: 0x13, 0x17: 0x17, 0x4B: 0x4F, 0x4C: 0x50,
               0x51: 0x4F, 0x5A: 0x5A, 0x5B: 0x5B, 0x5C: 0x5C, 0x5D: 0x5D, 0x5E: 0x5E}
# requests whose silence is their negative answer (CN CO_LSSmaster.h 145)
NEGATIVE_BY_SILENCE = (0x43, 0x4B, 0x4C, 0x51)
STATUS_TEXT = {
    0x11: {0: "ok", 1: "out of range", 0xFF: "manufacturer-specific error"},
    0x13: {0: "ok", 1: "not supported", 0xFF: "manufacturer-specific error"},
    0x17: {0: "ok", 1: "not supported", 2: "storage media access error",
           0xFF: "manufacturer-specific error"},
}
# requests reconstructed per channel: LSS traffic is a commissioning step, a flood of it is
# a fault in itself, and each exchange is an object (about 0.8 kB), so memory stays bounded
MAX_REQUESTS = 100_000
BIT_RATES_KBIT = {0: 1000, 1: 800, 2: 500, 3: 250, 4: 125, 6: 50, 7: 20, 8: 10}  # CN CO_LSS.h


def hex32(value: int | None) -> str:
    return "?" if value is None else f"{value:08X}h"


def identity_text(parts: tuple[int | None, ...]) -> str:
    return ":".join(hex32(v) for v in parts)


@dataclass
class Frame:
    """One LSS frame: where it is and its 8 data bytes."""

    ts: float
    idx: int
    line: int
    dlc: int
    data: bytes

    @property
    def cs(self) -> int:
        return self.data[0]

    def u32(self) -> int:
        """Bytes 1-4, little-endian (an identity part, an IDNumber, an inquired value)."""
        return int.from_bytes(self.data[1:5], "little")


@dataclass
class Exchange:
    """A request on 7E5h with the responses paired with it (SPEC §9.1.8 "Pairing")."""

    request: Frame
    cfg: str  # the configuration state before it: unknown | none | all | some
    responses: list[Frame] = field(default_factory=list)
    next_request: Frame | None = None  # the next 7E5h frame of the channel
    waiting_since: Frame | None = None  # the `04 00` that made `cfg` none
    sequence: tuple[int, ...] = ()  # 43h: the 40h-43h sent since the last 04h or 43h
    identity: tuple[int | None, ...] = ()  # 43h: the four values asked
    session: int | None = None

    @property
    def cs(self) -> int:
        return self.request.cs

    @property
    def service(self) -> str:
        return SERVICES.get(self.cs, (f"cs-{self.cs:02X}h", f"LSS request {self.cs:02X}h"))[1]

    @property
    def service_id(self) -> str:
        return SERVICES.get(self.cs, (f"cs-{self.cs:02X}h", ""))[0]

    @property
    def expects(self) -> int | None:
        return RESPONSE_CS.get(self.cs)

    @property
    def argument(self) -> int | None:
        d = self.request.data
        if self.cs in (SWITCH_GLOBAL, CONFIGURE_NODE_ID):
            return d[1]
        if self.cs == CONFIGURE_BIT_TIMING:
            return d[2]
        if self.cs == ACTIVATE_BIT_TIMING:
            return d[1] | d[2] << 8
        if 0x40 <= self.cs <= 0x4B or self.cs == FASTSCAN:
            return self.request.u32()
        return None

    def argument_text(self) -> str:
        d = self.request.data
        if self.cs == CONFIGURE_NODE_ID:
            return f" {d[1]}"
        if self.cs == CONFIGURE_BIT_TIMING:
            rate = BIT_RATES_KBIT.get(d[2]) if d[1] == 0 else None
            return f" table {d[1]} index {d[2]}" + (f" ({rate} kbit/s)" if rate else "")
        if self.cs == SWITCH_GLOBAL:
            return {0: " waiting", 1: " configuration"}.get(d[1], f" {d[1]:02X}h")
        if self.cs == ACTIVATE_BIT_TIMING:
            return f", switch delay {self.argument} ms"
        if 0x40 <= self.cs <= 0x4B:
            return f" {hex32(self.request.u32())}"
        return ""

    @property
    def node(self) -> int | None:
        """SPEC §9.2.0: byte 1 of a configure-node-ID request when it is 1-127."""
        n = self.request.data[1]
        return n if self.cs == CONFIGURE_NODE_ID and 1 <= n <= 127 else None

    @property
    def result(self) -> str:
        if self.expects is None:
            return "unconfirmed"
        if not self.responses:
            return "negative" if self.cs in NEGATIVE_BY_SILENCE else "no-response"
        if len(self.responses) > 1 and self.cs not in (0x4B, 0x4C, FASTSCAN):
            return "several"
        if self.cs in STATUS_TEXT and self.responses[0].data[1] != 0:
            return "error"
        return "ok"

    def response_text(self, r: Frame) -> tuple[int | None, str]:
        """(status, text) of one response, as the report gives it."""
        if self.cs in STATUS_TEXT:
            s = r.data[1]
            return s, STATUS_TEXT[self.cs].get(s, "unknown status")
        if 0x5A <= self.cs <= 0x5D:
            return None, f"{PART_NAMES[self.cs - 0x5A]} {hex32(r.u32())}"
        if self.cs == INQUIRE_NODE_ID:
            n = r.data[1]
            return None, "non-configured" if n == 0xFF else f"node-ID {n}"
        return None, {0x44: "selected", 0x4F: "identity matches",
                      0x50: "non-configured"}.get(r.cs, "")

    def deadline(self, timeout_s: float) -> float:
        """Where pairing ends: the next 7E5h frame or the request + the timeout, the earlier
        (with the frame index standing for the time: the next request only)."""
        t = self.request.ts + timeout_s
        if self.next_request is not None:
            t = min(t, self.next_request.ts)
        return t


@dataclass
class Configured:
    """A configure-node-ID request answered once with status 0: the pending node-ID."""

    exchange: int  # index into `LssChannel.exchanges`
    node_id: int
    stored: bool = False
    trigger: tuple[float, int, int, str] | None = None  # time, frame, line, what it was
    bootup: tuple[float, int, int] | None = None  # the first boot-up of 700h + N after it
    superseded: bool = False


@dataclass
class Slave:
    """An LSS slave of the channel, by identity when one was seen (SPEC §9.1.8 "Slaves")."""

    identity: list[int | None] = field(default_factory=lambda: [None] * 4)
    identity_source: str | None = None  # selective | fastscan | inquiry | None
    unconfigured: bool | None = None
    active_node_id: int | None = None
    configured: list[Configured] = field(default_factory=list)
    network_node: int | None = None

    @property
    def key(self) -> tuple[int | None, ...] | None:
        return tuple(self.identity) if all(v is not None for v in self.identity) else None


@dataclass
class Session:
    """From a switch to configuration to the next `04 00`, NMT reset or the trace end."""

    start: float
    start_idx: int
    how: str  # global | selective | fastscan
    cfg: str
    slave: int | None = None
    end: float | None = None
    exchanges: list[int] = field(default_factory=list)


@dataclass
class Fastscan:
    """From a fastscan reset (BitChecked 80h) to the next one, a `04 00`, an NMT reset or
    the trace end (SPEC §9.1.8)."""

    start: Frame
    requests: int = 0
    answered_reset: bool = False
    found: list[int | None] = field(default_factory=lambda: [None] * 4)
    complete: bool = False
    last: Frame | None = None  # the session's last frame (request or response)
    ended_by: str = "end"  # reset | waiting | nmt | end

    @property
    def identity(self) -> tuple[int | None, ...]:
        return tuple(self.found)

    @property
    def result(self) -> str:
        if self.complete:
            return "complete"
        return "abandoned" if self.answered_reset else "nobody"


@dataclass
class LssChannel:
    channel: str
    exchanges: list[Exchange] = field(default_factory=list)
    slaves: list[Slave] = field(default_factory=list)
    sessions: list[Session] = field(default_factory=list)
    fastscans: list[Fastscan] = field(default_factory=list)
    unsolicited: int = 0
    end: float = 0.0  # the channel's last frame
    timeout_s: float = 1.0  # lss_response_timeout_ms (inf: no timestamps)
    # LSS frames past MAX_REQUESTS requests: not reconstructed (count, first line)
    left_out: int = 0
    left_out_line: int | None = None


@dataclass
class LssAnalysis:
    channels: dict[str, LssChannel] = field(default_factory=dict)
    # (channel, rule, finding time rounded to 1 ns) -> (a0, t_e) of an L001 or L006
    # finding (SPEC §9.3.2-9.3.3: the request; the request or the trigger), for its causes
    effects: dict[tuple[str, str, float], tuple[float, float]] = field(default_factory=dict)

    def effect(self, channel: str, rule: str, t: float, a0: float, te: float) -> None:
        self.effects[(channel, rule, round(t, 9))] = (a0, te)


_SLOT: Attached[LssAnalysis] = Attached("lss")
attach = _SLOT.attach
of = _SLOT.of


def analyse(model: InputModel, network: Any, timeout_ms: float) -> LssAnalysis:
    """The LSS traffic of every channel that has LSS frames."""
    out = LssAnalysis()
    cols = model.decoded.lss
    if not len(cols["ts"]):
        return out
    timeout_s = float("inf") if model.timeline.order_only else timeout_ms / 1000.0
    for cm in model.channels:
        later = [c.first_index for c in model.channels
                 if c.chan == cm.chan and c.first_index > cm.first_index]
        hi = min(later) if later else np.iinfo(np.int64).max
        rows = np.flatnonzero((cols["chan"] == cm.chan) & (cols["idx"] >= cm.first_index)
                              & (cols["idx"] < hi))
        if len(rows):
            out.channels[cm.name] = _Walk(cm, cols, rows, timeout_s, network).run()
    return out


class _Walk:
    """One pass over a channel's LSS frames and NMT reset commands, in file order."""

    def __init__(self, cm: ChannelModel, cols: dict[str, np.ndarray], rows: np.ndarray,
                 timeout_s: float, network: Any) -> None:
        self.cm, self.cols, self.rows, self.network = cm, cols, rows, network
        self.out = LssChannel(cm.name, end=cm.end, timeout_s=timeout_s)
        self.cfg = "unknown"
        self.waiting: Frame | None = None
        self.session: Session | None = None
        self.slave: int | None = None  # the slave the current session selected
        self.fastscan: Fastscan | None = None
        self.selective: list[Frame] = []  # 40h-42h since the last 04h or 43h
        self.by_identity: dict[tuple[int | None, ...], int] = {}
        self.open: Exchange | None = None  # the last request, while it may be answered

    def run(self) -> LssChannel:
        nmt = self.cm.nmt
        resets = np.flatnonzero(nmt.valid & np.isin(nmt.cs, RESETS))
        r_idx = nmt.idx[resets]
        cols = self.cols
        data = cols["data"][self.rows]
        k = 0
        last_request: Exchange | None = None
        for j, row in enumerate(self.rows.tolist()):
            if len(self.out.exchanges) >= MAX_REQUESTS and int(
                    cols["can_id"][row]) == LSS_REQUEST_ID:
                self.out.left_out = len(self.rows) - j
                self.out.left_out_line = int(cols["line"][row])
                break
            idx = int(cols["idx"][row])
            while k < len(resets) and r_idx[k] < idx:
                self._nmt_reset(int(resets[k]))
                k += 1
            f = Frame(float(cols["ts"][row]), idx, int(cols["line"][row]),
                      int(cols["dlc"][row]), int(data[j]).to_bytes(8, "little"))
            if int(cols["can_id"][row]) == LSS_REQUEST_ID:
                if last_request is not None:
                    last_request.next_request = f
                last_request = self._request(f)
            else:
                self._response(f)
        cut = int(cols["idx"][self.rows[len(self.rows) - self.out.left_out]]) if (
            self.out.left_out) else None  # past the cut no state is followed
        while k < len(resets) and (cut is None or r_idx[k] < cut):
            self._nmt_reset(int(resets[k]))
            k += 1
        self._close_session(None)  # a session open at the trace end keeps `end` None
        if self.fastscan is not None:
            self._end_fastscan("end")
        self._adoptions()
        return self.out

    # -- state changes --------------------------------------------------------------

    def _nmt_reset(self, pos: int) -> None:
        nmt = self.cm.nmt
        t, idx, line = float(nmt.ts[pos]), int(nmt.idx[pos]), int(nmt.line[pos])
        target = int(nmt.target[pos])
        what = ("NMT reset node" if int(nmt.cs[pos]) == 0x81 else "NMT reset communication") + (
            " (broadcast)" if target == 0 else f" to node {target}")
        for s in self.out.slaves:
            if target == 0 or (s.active_node_id is not None and s.active_node_id == target):
                self._trigger(s, (t, idx, line, what))
        self.cfg = "unknown"
        self.open = None
        self._close_session(t)
        if self.fastscan is not None:
            self._end_fastscan("nmt")

    def _trigger(self, s: Slave, trigger: tuple[float, int, int, str]) -> None:
        for c in s.configured:
            if c.trigger is None and not c.superseded:
                c.trigger = trigger

    def _close_session(self, t: float | None) -> None:
        if self.session is not None:
            self.session.end = t
        self.session = None
        self.slave = None

    def _open_session(self, f: Frame, how: str, slave: int | None) -> None:
        self._close_session(f.ts)
        self.session = Session(f.ts, f.idx, how, self.cfg, slave)
        self.out.sessions.append(self.session)
        self.slave = slave

    def _end_fastscan(self, why: str) -> None:
        assert self.fastscan is not None
        self.fastscan.ended_by = why
        self.fastscan = None

    def _slave_by_identity(self, identity: tuple[int | None, ...], source: str) -> int:
        k = self.by_identity.get(identity)
        if k is None:
            k = len(self.out.slaves)
            self.out.slaves.append(Slave(list(identity), source,
                                         network_node=self._network_node(identity)))
            self.by_identity[identity] = k
        return k

    def _network_node(self, identity: tuple[int | None, ...]) -> int | None:
        nodes = getattr(self.network, "boot_nodes", None) or {}
        for n, keys in sorted(nodes.items()):
            if all(keys.get(p) is not None and keys.get(p) == v
                   for p, v in zip(PARTS, identity, strict=True)):
                return int(n)
        return None

    def _current_slave(self) -> Slave:
        """The slave the session selected, or one seen only by its answers."""
        if self.slave is None:
            self.slave = len(self.out.slaves)
            self.out.slaves.append(Slave())
            if self.session is not None:
                self.session.slave = self.slave
        return self.out.slaves[self.slave]

    # -- frames ---------------------------------------------------------------------

    def _request(self, f: Frame) -> Exchange:
        ex = Exchange(f, self.cfg, waiting_since=self.waiting if self.cfg == "none" else None)
        self.out.exchanges.append(ex)
        pos = len(self.out.exchanges) - 1
        cs, d = f.cs, f.data
        self.open = ex if ex.expects is not None else None
        if cs == SWITCH_GLOBAL and f.dlc < 2:
            pass  # no mode byte: the state it asks for is not known
        elif cs == SWITCH_GLOBAL:
            self.selective = []
            if d[1] == 0:
                self.cfg, self.waiting = "none", f
                self._close_session(f.ts)
                for s in self.out.slaves:
                    if s.unconfigured:
                        self._trigger(s, (f.ts, f.idx, f.line, "switch to waiting"))
                if self.fastscan is not None:
                    self._end_fastscan("waiting")
            elif d[1] == 1:
                self.cfg = "all"
                self._open_session(f, "global", None)
        elif 0x40 <= cs <= 0x42:
            self.selective.append(f)
        elif cs == SELECTIVE_SERIAL:
            asked = [*self.selective, f]
            ex.sequence = tuple(x.cs for x in asked)
            values: list[int | None] = [None, None, None, f.u32()]
            for x in self.selective:
                values[x.cs - 0x40] = x.u32()
            ex.identity = tuple(values)
            self.selective = []
        elif cs == FASTSCAN:
            self._fastscan_request(f)
        if self.session is not None:
            self.session.exchanges.append(pos)
            ex.session = len(self.out.sessions) - 1
        return ex

    def _fastscan_request(self, f: Frame) -> None:
        if f.data[5] == FASTSCAN_RESET:
            if self.fastscan is not None:
                self._end_fastscan("reset")
            self.fastscan = Fastscan(f)
            self.out.fastscans.append(self.fastscan)
        if self.fastscan is not None:
            self.fastscan.requests += 1
            self.fastscan.last = f

    def _response(self, f: Frame) -> None:
        ex = self.open
        timeout = self.out.timeout_s
        if ex is None or f.cs != ex.expects or f.ts - ex.request.ts > timeout + EPS:
            self.out.unsolicited += 1
            return
        ex.responses.append(f)
        first = len(ex.responses) == 1
        cs = ex.cs
        if cs == FASTSCAN:
            self._fastscan_response(ex, f)
        elif cs == SELECTIVE_SERIAL and first and all(v is not None for v in ex.identity):
            k = self._slave_by_identity(ex.identity, "selective")
            if self.cfg != "all":
                self.cfg = "some"
            pos = len(self.out.exchanges) - 1
            if self.session is not None and self.session.exchanges[-1:] == [pos]:
                self.session.exchanges.pop()  # the switch begins the new session
            self._open_session(ex.request, "selective", k)
            self.session.exchanges.append(len(self.out.exchanges) - 1)  # type: ignore[union-attr]
            ex.session = len(self.out.sessions) - 1
        elif len(ex.responses) == 1:
            self._single_answer(ex, f)
        else:
            self._several_answers(ex)

    def _single_answer(self, ex: Exchange, f: Frame) -> None:
        cs = ex.cs
        if cs == CONFIGURE_NODE_ID and f.data[1] == 0 and 1 <= ex.request.data[1] <= 127:
            s = self._current_slave()
            for c in s.configured:
                if c.trigger is None:
                    c.superseded = True
            s.configured.append(Configured(len(self.out.exchanges) - 1, ex.request.data[1]))
        elif cs == STORE and f.data[1] == 0:
            s = self._current_slave()
            if s.configured:
                s.configured[-1].stored = True
        elif cs == INQUIRE_NODE_ID:
            s = self._current_slave()
            n = f.data[1]
            s.unconfigured = n == 0xFF
            s.active_node_id = n if n == 0xFF or 1 <= n <= 127 else s.active_node_id
        elif 0x5A <= cs <= 0x5D:
            s = self._current_slave()
            if s.identity[cs - 0x5A] is None:
                s.identity[cs - 0x5A] = f.u32()
                s.identity_source = s.identity_source or "inquiry"
        elif cs == 0x4C and self.slave is not None:
            self.out.slaves[self.slave].unconfigured = True

    def _several_answers(self, ex: Exchange) -> None:
        """A second answer: what the first one set for one slave no longer holds."""
        if ex.cs == CONFIGURE_NODE_ID and self.slave is not None:
            s = self.out.slaves[self.slave]
            pos = len(self.out.exchanges) - 1
            s.configured = [c for c in s.configured if c.exchange != pos]

    def _fastscan_response(self, ex: Exchange, f: Frame) -> None:
        fs = self.fastscan
        if fs is None:
            return
        fs.last = f
        d = ex.request.data
        bit, sub, nxt = d[5], d[6], d[7]
        if bit == FASTSCAN_RESET:
            fs.answered_reset = True
        elif bit == 0 and sub <= 3 and len(ex.responses) == 1:
            fs.found[sub] = ex.request.u32()
            if nxt < sub and not fs.complete:
                fs.complete = True
                k = self._slave_by_identity(fs.identity, "fastscan")
                if self.cfg != "all":
                    self.cfg = "some"
                self._open_session(ex.request, "fastscan", k)
                assert self.session is not None
                self.session.exchanges.append(len(self.out.exchanges) - 1)
                ex.session = len(self.out.sessions) - 1

    # -- after the walk -------------------------------------------------------------

    def _adoptions(self) -> None:
        """Each configured node-ID's first boot-up on 700h + N after its confirmation."""
        for s in self.out.slaves:
            for c in s.configured:
                ex = self.out.exchanges[c.exchange]
                m = self.cm.nodes.get(c.node_id)
                if m is None or not ex.responses:
                    continue
                after = ex.responses[0].ts
                boot = np.flatnonzero((m.ec.kind == BOOTUP) & (m.ec.ts >= after - EPS))
                if c.trigger is not None:
                    boot = boot[m.ec.ts[boot] >= c.trigger[0] - EPS]
                if len(boot):
                    b = int(boot[0])
                    c.bootup = (float(m.ec.ts[b]), int(m.ec.idx[b]), int(m.ec.line[b]))
