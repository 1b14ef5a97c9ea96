"""Live SYNC, PDO and EMCY rules (SPEC_COMM §9.2): the ones a live view can decide as the
frames arrive, judged by the values the offline check takes (the network file's §9.1.2
keys, the device files, confirmed SDO writes in the session, reset rule of §9.1.3).

Decided live: Y001 (when the SYNC deadline passes), Y002, Y003, Y004, D001 and D004 (when
the event timer or the RPDO deadline passes; withdrawn when the party's next report or
its going OFFLINE proves the gap was no fault of the stream, SPEC_COMM §9.1.6, D001),
D002, D005, D006 (expedited downloads, at the request), E001, E002. Left to the check of
the recording at the end, as every rule that needs the whole trace: Y005 (a median over
the segment), D003 (counts over SYNC cycles), E003 (the state at the trace end).

A finding that rests on something only the whole trace settles (a SYNC period measured
so far, a node state that a heartbeat timeout from a measured period decides, a frame's
wait for the bus) is provisional.
State is O(nodes + streams): nothing grows with the traffic.
"""

from __future__ import annotations

import bisect
import statistics
from collections.abc import Callable
from typing import Any

from nmtcheck.live.comm_state import (
    CommChannel,
    CommNode,
    Deadline,
    PdoStream,
    source_text,
    type_in,
)
from nmtcheck.live.tracker import LiveFinding, NodeState, Tracker
from nmtcheck.processes import pdo as pdo_stage
from nmtcheck.processes import sync as sync_stage
from nmtcheck.processes.comm_values import UNKNOWN, Value
from nmtcheck.protocol.nmt import (
    OPERATIONAL,
    PRE_OPERATIONAL,
    RESETS,
    STATE_OF_CODE,
)
from nmtcheck.protocol.nmt import (
    UNKNOWN as STATE_UNKNOWN,
)
from nmtcheck.settings.network import Network
from nmtcheck.settings.profiles import Profile

EPS = 1e-9
TEXT_RESOLUTION_S = 1e-6  # the session's recording is candump text (microseconds)
D8_KEPT = 16  # the smallest intervals before an 8-byte frame, for d8
SYNC_MEDIAN_EVERY = 64  # a measured SYNC period is recomputed every this many SYNCs
_WRITTEN = (0x1005, 0x1006, 0x1007, 0x1015, 0x1019)  # the sub-0 objects the rules read
# Live takes a node's PDO parameters from the files: where SDO wrote one of them
# (1400h-1BFFh) in the session, its findings of these rules are provisional (the
# session's check applies the write, processes/pdo_params.py).
_PDO_JUDGED = frozenset(("D001", "D002", "D004", "D005", "Y004"))
_CONSUMING = (PRE_OPERATIONAL, OPERATIONAL)


class CommTracker:
    """Fed every frame after the NMT tracker (whose node states it reads); `advance(now)`
    fires the SYNC and RPDO deadlines that expired by `now`."""

    def __init__(self, profile: Profile, tracker: Tracker, network: Network | None,
                 emit: Callable[[LiveFinding], object]) -> None:
        self.tracker, self.network, self.emit = tracker, network, emit
        p: dict[str, dict[str, Any]] = {code: s.params for code, s in profile.items()}
        self.factor = float(p["Y001"]["timeout_factor"])
        self.min_intervals = int(p["Y001"]["min_intervals"])
        self.generic_bit = bool(p["E002"]["require_generic_bit"])
        self.d001_tolerance = float(p["D001"]["tolerance"])
        self.d001_margin = float(p["D001"]["margin_ms"]) / 1000
        given = profile.timeline.get("timestamp_resolution_us")
        self.r = float(given) / 1e6 if given else TEXT_RESOLUTION_S
        self.on = {c for c in ("Y001", "Y002", "Y003", "Y004", "D001", "D002", "D004", "D005",
                               "D006", "E001", "E002") if c in tracker.active}
        self.channels: dict[str, CommChannel] = {}
        self.nodes: dict[tuple[str, int], CommNode] = {}
        self.next_due = float("inf")

    # -- helpers ---------------------------------------------------------------------------

    def _channel(self, name: str) -> CommChannel:
        ch = self.channels.get(name)
        if ch is None:
            ch = self.channels[name] = CommChannel(name)
            ch.needs_q = "E001" in self.on  # an EMCY may have waited for the bus too
            net = self.network
            if net is not None:
                keys = net.sync_keys(name)
                devices = {n: d for n, d in net.devices.items()
                           if net.node_channel(n) in (None, name)}
                ch.sync_cob = sync_stage._cob_id(keys, devices, [])[0]
                prod = sync_stage._producer(keys, devices, [])
                ch.producer = int(prod.value) if prod.known and prod.value else None
                for cob, producer, consumers, w in pdo_stage.channel_parties(net, name):
                    st = ch.streams[cob] = PdoStream(cob, producer, consumers, w)
                    ch.needs_q = ch.needs_q or bool(st.inhibit_s)
                    for d in st.deadlines:
                        ch.watched.setdefault(d.party.node, []).append(d)
                        ch.ec_watch.add(d.party.node)
                    if producer is not None and type_in(producer, pdo_stage.EVENT_DRIVEN) \
                            and producer.event_timer_ms.value:
                        st.event_limit_s = (float(producer.event_timer_ms.value) / 1000
                                            * (1 + self.d001_tolerance) + self.d001_margin)
                        ch.ec_watch.add(producer.node)
        return ch

    def _node(self, channel: str, n: int) -> CommNode:
        key = (channel, n)
        got = self.nodes.get(key)
        if got is None:
            got = self.nodes[key] = CommNode()
        return got

    def _in_force(self, channel: str, n: int, index: int, files: int | None,
                  source: str) -> Value:
        """§9.1.1/§9.1.3 for a sub-0 object: a confirmed write, unknown after a reset
        that voided one, else the files' value."""
        w = self.nodes.get((channel, n))
        if w is not None and index in w.written:
            got = w.written[index]
            return UNKNOWN if got is None else Value(got[0], "sdo", n, got[1])
        return UNKNOWN if files is None else Value(files, source, n)

    def _dev(self, n: int) -> Any:
        return self.network.devices.get(n) if self.network is not None else None

    def _find(self, code: str, channel: str, node: int | None, ts: float, message: str,
              certain: bool = True) -> LiveFinding | None:
        if code not in self.on:
            return None
        t = self.tracker
        if code in _PDO_JUDGED and node is not None and certain:
            w = self.nodes.get((channel, node))
            certain = w is None or not w.pdo_written
        lf = LiveFinding(code, t.active[code].name, t.severity[code], channel, node, ts,
                         message, certain=certain)
        st = t.nodes.get((channel, node)) if node is not None else None
        if st is not None:
            st.findings += 1
        self.emit(lf)
        return lf

    def _sure(self, st: NodeState | None) -> bool:
        """Whether the tracker's state of the node is the offline timeline's: its timeouts
        rest on configured times (as S001 asks)."""
        return st is None or ((st.timeout_configured() or not st.producer())
                              and not st.ambiguous)

    @staticmethod
    def _operational(st: NodeState | None, since: float | None = None) -> int:
        """2: the node is OPERATIONAL; 1: it may be (after its boot-up at or before `since`,
        before any report or command: it may have started itself, SPEC §2, which only
        the offline timeline settles); 0: it is not."""
        if st is None:
            return 0
        if st.state == OPERATIONAL:
            return 2
        return int(st.self_start_open and st.state == PRE_OPERATIONAL and (
            since is None or (st.last_boot is not None and st.last_boot <= since + EPS)))

    def _op_through(self, channel: str, n: int, t0: float) -> int:
        """The node is OPERATIONAL now and has been since `t0` (no change out of it, no
        heartbeat or guarding timeout live saw): 2 yes, 1 maybe (`_operational`), 0 no."""
        st = self.tracker.nodes.get((channel, n))
        level = self._operational(st, t0)
        if not level or st is None:
            return 0
        if st.left_operational is not None and st.left_operational > t0 + EPS:
            return 0
        w = self.nodes.get((channel, n))
        return 0 if w is not None and w.offline_at > t0 + EPS else level

    def tracker_finding(self, lf: LiveFinding) -> None:
        """The NMT tracker's H001/G002: the node is OFFLINE from then on."""
        if lf.rule in ("H001", "G002") and lf.node is not None:
            w = self._node(lf.channel, lf.node)
            w.offline_at = lf.time
            # D001: the producer sent nothing at all until it went OFFLINE: it fell
            # silent, not its TPDO (H001/G002 say so)
            for found, t_l, _st in w.silent_watch:
                if t_l < lf.time:
                    self._withdraw(found)
            w.silent_watch.clear()

    def tracker_withdrawn(self, lf: LiveFinding) -> None:
        """A heartbeat timeout taken back (a late frame): the node was not OFFLINE."""
        if lf.rule in ("H001", "G002") and lf.node is not None:
            w = self.nodes.get((lf.channel, lf.node))
            if w is not None and w.offline_at == lf.time:
                w.offline_at = float("-inf")

    # -- time ------------------------------------------------------------------------------

    def advance(self, now: float) -> None:
        """Fire the SYNC and RPDO deadlines that expired by `now` (bus time)."""
        if now <= self.next_due + EPS:
            return
        nxt = float("inf")
        for ch in self.channels.values():
            if ch.sync_due is not None:
                if now > ch.sync_due + EPS:
                    self._y001(ch)
                else:
                    nxt = min(nxt, ch.sync_due)
            for st in ch.streams.values():
                if st.d001_armed is not None:
                    if now > st.d001_due + EPS:
                        self._d001(ch, st)
                    else:
                        nxt = min(nxt, st.d001_due)
                for d in st.deadlines:
                    if d.armed is None or d.fired is not None:
                        continue
                    if now > d.due + self.r + EPS:
                        self._d004(ch, st, d)
                    else:
                        nxt = min(nxt, d.due + self.r)
        self.next_due = nxt

    def _y001(self, ch: CommChannel) -> None:
        due, last, limit = ch.sync_due, ch.last_sync, ch.sync_limit
        ch.sync_due = None
        assert due is not None and last is not None and limit is not None
        self.tracker.advance(due)  # the node states at the deadline
        others = [st for (c, n), st in self.tracker.nodes.items()
                  if c == ch.name and n != ch.producer and (st.seen or st.state != STATE_UNKNOWN)]
        expected = self.network is not None and any(
            n != ch.producer and c in (None, ch.name) for n, c in self.network.expected())
        if (others or expected) and not any(st.state in _CONSUMING for st in others):
            return
        t_limit, how, configured = limit
        start = self.tracker.start or 0.0
        ch.y001_fired = self._find("Y001", ch.name, ch.producer, due,
                   f"no SYNC for at least {(due - last) * 1000:.3f} ms after "
                   f"{last - start:.6f} s; timeout {t_limit * 1000:.3f} ms = {self.factor:g} "
                   f"x {how}", certain=configured and all(self._sure(st) for st in others))

    def _d001(self, ch: CommChannel, st: PdoStream) -> None:
        t_l, due = st.d001_armed, st.d001_due
        st.d001_armed = None
        p = st.producer
        assert t_l is not None and p is not None
        self.tracker.advance(due)
        level = self._op_through(ch.name, p.node, t_l)
        if not level:
            return
        node = self.tracker.nodes.get((ch.name, p.node))
        w = self._node(ch.name, p.node)
        # certain once the producer reported since t_l: its state in the gap is supervised
        # and it did not fall silent (else its next report or OFFLINE may void it)
        reported = w.last_report > t_l + EPS
        e = float(p.event_timer_ms.value or 0)
        found = st.d001_fired = self._find("D001", ch.name, p.node, due,
                           f"no TPDO {st.cob_id:03X}h from node {p.node} for at least "
                           f"{(due - t_l) * 1000:.3f} ms while OPERATIONAL; event timer "
                           f"{p.base_index:04X}h:05 = {e:g} ms ({source_text(p.event_timer_ms)}),"
                           f" limit {st.event_limit_s * 1000:.3f} ms",
                           certain=reported and level == 2 and self._sure(node))
        if found is None or reported:
            return
        w.report_watch.append((found, t_l, float("inf")))
        if w.last_ec <= t_l + EPS:  # nor any frame on 700h + N
            w.silent_watch.append((found, t_l, st))

    def _d004(self, ch: CommChannel, st: PdoStream, d: Deadline) -> None:
        assert d.armed is not None
        c = d.party
        self.tracker.advance(d.due)
        level = self._op_through(ch.name, c.node, d.armed)
        if d.voidable or not level:
            d.armed = None
            return
        producer = f"node {st.producer.node}" if st.producer else "unknown"
        e = float(c.event_timer_ms.value or 0)
        d.fired = self._find(
            "D004", ch.name, c.node, d.due,
            f"no RPDO {st.cob_id:03X}h for node {c.node} for at least "
            f"{(d.due - d.armed) * 1000:.3f} ms; deadline {c.base_index:04X}h:05 = {e:g} ms "
            f"({source_text(c.event_timer_ms)}); producer {producer}",
            # certain once the consumer reported since t_l (its state is supervised)
            certain=not d.watch and level == 2 and self._sure(
                self.tracker.nodes.get((ch.name, c.node))))
        if d.fired is None:
            d.armed = None

    def finish(self) -> None:
        """The end of the input: a deadline finding whose consumer reported another state
        with no EMCY 8250h after it stands voided (no stream frame follows)."""
        for ch in self.channels.values():
            for st in ch.streams.values():
                for d in st.deadlines:
                    if d.fired is not None and d.voidable:
                        self._withdraw(d.fired)
                        d.fired = None

    # -- frames ----------------------------------------------------------------------------

    def feed(self, f: Any) -> None:
        """One frame, after the NMT tracker took it (and `advance` to its time, before)."""
        ch = self.channels.get(f.channel) or self._channel(f.channel)
        if ch.needs_q:
            recent = ch.recent
            if recent and f.dlc == 8:
                gap = f.ts - recent[-1]
                if gap > 0 and (len(ch.d8) < D8_KEPT or gap < ch.d8[-1]):
                    bisect.insort(ch.d8, gap)
                    del ch.d8[D8_KEPT:]
                    vals = ch.d8
                    ch.d8_value = vals[0] if len(vals) >= 3 and vals[0] > 0 and sum(
                        v <= vals[0] * 1.05 for v in vals) >= 3 else None
            recent.append(f.ts)
        if f.ext or f.err:
            return
        cid = f.can_id
        st = ch.streams.get(cid)
        if st is not None:
            if not f.rtr:
                self._pdo(ch, st, f)
        elif cid == ch.sync_cob:
            self._sync(ch, f)
        elif 0x701 <= cid <= 0x77F:
            if cid - 0x700 in ch.ec_watch or f.data[:1] == b"\x00":
                self._report(ch, f, cid - 0x700)
        elif cid == 0:
            self._nmt(ch, f)
        elif 0x081 <= cid <= 0x0FF:
            self._emcy(ch, f, cid - 0x80)
        elif 0x581 <= cid <= 0x5FF or 0x601 <= cid <= 0x67F:
            self._sdo(ch, f, cid & 0x7F)

    # segment ends, resets, boot-ups, writes -------------------------------------------------

    def _end_segment(self, ch: CommChannel) -> None:
        ch.segment += 1
        ch.sync_due = None

    def _clear(self, ch: CommChannel, n: int, ts: float) -> None:
        """A boot-up of N or a reset command that reaches it at `ts`: what SDO wrote is
        void, and a new run of D005 and of E001's pairs begins."""
        w = self._node(ch.name, n)
        w.epoch += 1
        self._d005_new_run(ch, n, ts, w.epoch)
        if w.emcy_ts is not None and w.cleared_at is None and ts > w.emcy_ts + EPS:
            w.cleared_at = ts
        for index in list(w.written):
            w.written[index] = None

    def _nmt(self, ch: CommChannel, f: Any) -> None:
        if f.rtr or f.dlc != 2 or len(f.data) < 2 or f.data[0] not in RESETS:
            return
        target = f.data[1]
        if target > 127:
            return
        if not target or target == ch.producer:
            self._end_segment(ch)
        if target:
            self._clear(ch, target, f.ts)
        else:
            master = self.tracker.master(ch.name)
            for (c, n) in list(self.tracker.nodes):
                if c == ch.name and n != master:
                    self._clear(ch, n, f.ts)

    def _report(self, ch: CommChannel, f: Any, n: int) -> None:
        w = self._node(ch.name, n)
        w.last_ec = f.ts
        w.silent_watch.clear()  # N did not fall silent
        if f.rtr or f.dlc != 1 or not f.data:
            return
        if f.data[0] == 0:  # boot-up
            self._clear(ch, n, f.ts)
            if n == ch.producer:
                self._end_segment(ch)
            return
        # D004: the consumer's first report after the deadline was armed (§9.1.6)
        st = self.tracker.nodes.get((ch.name, n))
        reported = STATE_OF_CODE.get(f.data[0] & 0x7F)
        cmd = st.last_cmd if st is not None else None
        stale = (cmd is not None and f.ts - cmd[0] <= self.tracker.obey_s + EPS
                 and reported == cmd[1])
        if stale:
            return
        w.last_report = f.ts
        for found, t_l, nxt in w.report_watch:  # gaps of streams that went on since
            commanded = cmd is not None and cmd[0] > t_l + EPS
            if reported != OPERATIONAL and not commanded and not (
                    found.rule == "D004" and found.time - EPS <= w.last_8250 < nxt):
                self._withdraw(found)
        w.report_watch.clear()
        for d in ch.watched.get(n, ()):
            if d.watch and d.armed is not None:
                d.watch = False
                commanded = cmd is not None and cmd[0] > d.armed + EPS
                if reported == OPERATIONAL or commanded:
                    continue
                # it left OPERATIONAL because of this timeout: an 8250h says so
                d.voidable = d.fired is None or w.last_8250 < d.due - EPS

    def _late(self, lf: LiveFinding | None, ts: float) -> None:
        """The gap's next frame, stamped at or before the moment the clock fired `lf` at:
        it reached the session late (a driver queue), and the gap was no gap."""
        if lf is not None and ts <= lf.time + EPS:
            self._withdraw(lf)

    def _withdraw(self, lf: LiveFinding) -> None:
        if not lf.withdrawn:
            lf.withdrawn = True
            if self.tracker.withdraw is not None:
                self.tracker.withdraw(lf)

    def _sdo(self, ch: CommChannel, f: Any, n: int) -> None:
        """Confirmed expedited downloads of the objects the rules read (§9.1.1)."""
        if f.dlc < 4 or len(f.data) < 4:
            return
        w = self._node(ch.name, n)
        cmd, index, sub = f.data[0], f.data[1] | f.data[2] << 8, f.data[3]
        if f.can_id >= 0x601:
            w.request = None
            if cmd & 0xE3 != 0x23 or len(f.data) < 8:
                return  # an expedited download with its size
            size = 4 - ((cmd >> 2) & 0x3)
            value = int.from_bytes(bytes(f.data[4:4 + size]), "little")
            if (sub == 0 and index in _WRITTEN) or 0x1400 <= index <= 0x1BFF:
                w.request = (index, sub, value)
            if sub == 2 and ((0x1800 <= index <= 0x19FF and 241 <= value <= 251)
                             or (0x1400 <= index <= 0x15FF and 241 <= value <= 253)):
                kind = "241–251 (TPDO)" if index >= 0x1800 else "241–253 (RPDO)"
                self._find("D006", ch.name, n, f.ts,
                           f"download {index:04X}h:02 = {value} to node {n}: transmission "
                           f"types {kind} are reserved")
            return
        req, w.request = w.request, None
        if cmd != 0x60 or req is None or req[:2] != (index, sub):
            return
        if 0x1400 <= index <= 0x1BFF:  # the check of the session applies it (§9.1.3)
            w.pdo_written = True
            return
        w.written[index] = (req[2], f.ts)
        if index == 0x1019:
            ch.c_written = True
        if index == 0x1015:
            w.writes_1015 += 1
        if index in (0x1005, 0x1006) and (ch.producer is None or ch.producer == n):
            self._end_segment(ch)

    # SYNC ----------------------------------------------------------------------------------

    def _segment_values(self, ch: CommChannel) -> tuple[Value, Value]:
        """P (Y001) and C (1019h) in force at a segment's first SYNC (§9.1.1)."""
        net = self.network
        keys = net.sync_keys(ch.name) if net is not None else None
        prod = ch.producer

        def of_producer(index: int, net_value: int | None, attr: str) -> Value:
            if net_value is not None:
                return Value(net_value, "network")
            if prod is None:
                return UNKNOWN
            dev = self._dev(prod)
            return self._in_force(ch.name, prod, index,
                                  getattr(dev, attr) if dev is not None else None,
                                  "device-file")

        nodes = sorted({n for c, n in self.nodes if c == ch.name}
                       | {n for c, n in self.tracker.nodes if c == ch.name}
                       | ({n for n in net.devices if net.node_channel(n) in (None, ch.name)}
                          if net is not None else set()))
        period = of_producer(0x1006, keys.period_us if keys else None, "sync_period_us")
        if not period.known:  # the first consumer to time out
            periods = [v for n in nodes for dev in (self._dev(n),)
                       for v in (self._in_force(ch.name, n, 0x1006, dev.sync_period_us
                                                if dev is not None else None, "device-file"),)
                       if v.known and v.value]
            if periods:
                period = min(periods, key=lambda v: float(v.value or 0))
        overflow = of_producer(0x1019, keys.counter_overflow if keys else None,
                               "sync_counter_overflow")
        if not overflow.known:
            found = set()
            first = UNKNOWN
            for n in nodes:
                dev = self._dev(n)
                v = self._in_force(ch.name, n, 0x1019,
                                   dev.sync_counter_overflow if dev is not None else None,
                                   "device-file")
                if v.known:
                    found.add(v.value)
                    first = first if first.known else v
            overflow = first if len(found) == 1 else UNKNOWN
        return period, overflow

    def _sync(self, ch: CommChannel, f: Any) -> None:
        ts = f.ts
        self._late(ch.y001_fired, ts)
        ch.y001_fired = None
        if ch.sync_segment != ch.segment:  # a new segment begins at this SYNC
            ch.sync_segment = ch.segment
            ch.seg_values = self._segment_values(ch)
            ch.seg_first_dlc, ch.seg_broken = None, False
            ch.intervals.clear()
            ch.syncs, ch.measured, ch.last_counter = 0, None, None
        else:
            ch.intervals.append(ts - (ch.last_sync if ch.last_sync is not None else ts))
        ch.last_sync = ts
        ch.syncs += 1
        period, overflow = ch.seg_values
        c = int(overflow.value or 0) if overflow.known else None
        defect = self._y002(ch, f, c)
        if not defect and f.dlc == 1 and f.data:
            self._y003(ch, f, int(f.data[0]), c)
        # Y001's deadline from this SYNC
        ch.sync_due = None
        if period.known:
            if not period.value:
                return
            p = float(period.value) / 1e6
            # a period written by SDO holds until a reset reaches its node: which ones do
            # only the offline timeline settles
            ch.sync_limit = (self.factor * p, f"1006h {p * 1000:.3f} ms ({source_text(period)})",
                             period.source != "sdo")
        else:
            if ch.syncs <= self.min_intervals:
                return
            if ch.measured is None or ch.syncs % SYNC_MEDIAN_EVERY == 0:
                ch.measured = statistics.median(ch.intervals)
            p = ch.measured
            ch.sync_limit = (self.factor * p, f"median SYNC interval {p * 1000:.3f} ms "
                             "[limit measured so far]", False)
        ch.sync_due = round(ts + ch.sync_limit[0], 9)
        self.next_due = min(self.next_due, ch.sync_due)

    def _y002(self, ch: CommChannel, f: Any, c: int | None) -> int:
        """The SYNC frame's defect (checks/sync._defects), one finding per run."""
        dlc = f.dlc
        if f.rtr:
            defect = 1
        else:
            first = ch.seg_first_dlc
            if first is None:
                ch.seg_first_dlc = first = dlc
            defect = 0
            if c is not None:
                if dlc != (0 if c == 0 else 1):
                    defect = 2
            elif dlc > 1 or dlc != first:
                defect = 3
            if not defect and dlc == 1 and f.data and (
                    f.data[0] == 0 or f.data[0] > (c if c else 240)):
                defect = 4
        prev = ch.y002_run
        ch.y002_run = (defect, ch.segment)
        if not defect or prev == (defect, ch.segment):
            return defect
        if defect == 1:
            text = f"remote frame on the SYNC COB-ID {ch.sync_cob:03X}h"
        elif defect == 2:
            text = (f"SYNC with {dlc} data byte(s); 1019h = {c} "
                    f"({source_text(ch.seg_values[1])}) requires {0 if c == 0 else 1}: "
                    "CANopenNode consumers drop it, CANopenNode and Lely consumers raise "
                    "EMCY 8240h")
        elif defect == 3:
            text = f"SYNC DLC {dlc} after DLC {ch.seg_first_dlc} in the same segment"
        else:
            text = f"SYNC counter {f.data[0]} outside 1..{c or 240}"
        self._find("Y002", ch.name, None, f.ts, text, certain=defect == 1 or not ch.c_written)
        return defect

    def _y003(self, ch: CommChannel, f: Any, v: int, c: int | None) -> None:
        prev, ch.last_counter = ch.last_counter, v
        if prev is None or ch.seg_broken:
            return
        top = c if c else 240
        expected = 1 if prev >= top else prev + 1
        if v in (expected, 1):
            return
        ch.seg_broken = True
        if v == prev:
            what = "repeated"
        elif c or v > expected:
            what = f"{(v - expected) % c if c else v - expected} SYNC(s) missing"
        else:
            what = "went back"
        self._find("Y003", ch.name, ch.producer, f.ts,
                   f"SYNC counter {v} after {prev} (expected {expected}): {what}",
                   certain=not ch.c_written)

    # EMCY ----------------------------------------------------------------------------------

    def _emcy(self, ch: CommChannel, f: Any, n: int) -> None:
        w = self._node(ch.name, n)
        if f.rtr:
            self._find("E002", ch.name, n, f.ts,
                       f"remote frame on the EMCY COB-ID {f.can_id:03X}h of node {n}")
            return
        code = f.data[0] | f.data[1] << 8 if len(f.data) >= 2 else -1
        if code == 0x8250:
            w.last_8250 = f.ts
            for st in ch.streams.values():
                for d in st.deadlines:
                    if d.party.node == n and d.fired is not None and f.ts >= d.due - EPS:
                        d.voidable = False
        # E002: one finding per run of EMCYs of one defect (a DLC other than 8, or with
        # `require_generic_bit` an error code without error-register bit 0)
        flag = 100 + f.dlc if f.dlc != 8 else 2 if (
            self.generic_bit and code >= 0x100 and len(f.data) > 2 and not f.data[2] & 1) else 0
        if flag and flag != w.e002_run:
            self._find("E002", ch.name, n, f.ts,
                       f"EMCY {code:04X}h with error register {f.data[2]:02X}h: bit 0 "
                       "(generic) clear" if flag == 2 else
                       f"EMCY of node {n} with DLC {f.dlc}, 8 expected (CanFestival "
                       "consumers drop it)")
        w.e002_run = flag
        # E001: consecutive EMCYs closer than 1015h, no reset or write of 1015h between
        keys = self.network.comm_nodes.get(n) if self.network is not None else None
        dev = self._dev(n)
        net_inh = keys.emcy_inhibit_100us if keys is not None else None
        inhibit = self._in_force(ch.name, n, 0x1015, net_inh if net_inh is not None else (
            dev.emcy_inhibit_100us if dev is not None else None),
            "network" if net_inh is not None else "device-file")
        cleared = w.cleared_at is not None and w.cleared_at < f.ts - EPS
        bad = False
        if w.emcy_ts is not None and not cleared and w.writes_1015 == w.emcy_writes and (
                inhibit.known and inhibit.value):
            limit = float(inhibit.value) * 1e-4
            dt = f.ts - w.emcy_ts
            bad = dt < limit - self.r - EPS
            q, q_sure = (self._q(ch, w.emcy_ts) if bad else (0.0, True))
            bad = bad and dt < limit - self.r - q - EPS
            if bad and not w.e001_run:
                i = float(inhibit.value)
                self._find("E001", ch.name, n, f.ts,
                           f"EMCY {max(code, 0):04X}h of node {n} {dt * 1000:.3f} ms after "
                           f"the previous one; inhibit time 1015h = {i:g} x 100 us = "
                           f"{i / 10:g} ms ({source_text(inhibit)})",
                           certain=inhibit.source != "sdo" and q_sure)
        w.e001_run = bad
        w.emcy_ts, w.emcy_writes, w.cleared_at = f.ts, w.writes_1015, None

    # PDO -----------------------------------------------------------------------------------

    def _q(self, ch: CommChannel, t1: float) -> tuple[float, bool]:
        """q(F1) of §9.1.6 for the channel's frame at `t1` among the recent ones
        (checks/bus_wait.bus_wait), with the d8 known so far, and whether it is surely that
        (d8 only shrinks as frames come). Looked up only for a spacing under the
        inhibit time."""
        times = ch.recent
        k = len(times) - 1
        while k >= 0 and times[k] > t1 + EPS:
            k -= 1
        if k < 1:  # the channel's first frame, or older than the frames kept
            return 0.0, k == 0 and len(times) < (times.maxlen or 0)
        vals = ch.d8
        if vals and times[k] - times[k - 1] > 1.25 * vals[0] + EPS:
            return 0.0, True  # not back to back, whatever d8 proves to be
        d8 = ch.d8_value
        if d8 is None:
            return 0.0, False
        j = k
        while j > 0 and times[j] - times[j - 1] <= 1.25 * d8 + EPS:
            j -= 1
        return (0.0 if j == k else float(times[k] - times[j]) + d8), False

    def _pdo(self, ch: CommChannel, st: PdoStream, f: Any) -> None:
        p = st.producer
        if st.inhibit_s and p is not None:
            self._d002(ch, st, p, f.ts)
        if st.window_s and ch.last_sync is not None:
            self._y004(ch, st, f)
        # D005: the DLC against the producer's (a) and each consumer's (b) mapping
        for producing, party, want in st.mapped:
            if f.dlc != want:
                self._d005(ch, st, f, producing, party, want)
        if st.event_limit_s and p is not None:
            self._d001_arm(ch, st, p, f.ts)
        if st.deadlines:
            self._d004_arm(ch, st, f.ts)

    def _d002(self, ch: CommChannel, st: PdoStream, p: pdo_stage.Party, ts: float) -> None:
        """An event-driven TPDO closer to the previous one than its inhibit time, the
        producer OPERATIONAL through both; one finding per run of such pairs."""
        bad = False
        level = 0
        if st.last is not None and ts - st.last < st.inhibit_s:
            level = self._op_through(ch.name, p.node, st.last)
        if level and st.last is not None:
            inhibit = st.inhibit_s
            dt = ts - st.last
            q, q_sure = self._q(ch, st.last)
            bad = dt < inhibit - self.r - q - EPS
            if bad and not st.d002_run:
                self._find("D002", ch.name, p.node, ts,
                           f"TPDO {st.cob_id:03X}h of node {p.node} {dt * 1000:.3f} ms "
                           f"after the previous one; inhibit time {p.base_index:04X}h:03 "
                           f"= {p.inhibit_100us.value} x 100 us = {inhibit * 1000:g} ms "
                           f"({source_text(p.inhibit_100us)}), allowance "
                           f"{(self.r + q) * 1000:.3f} ms",
                           certain=q_sure and level == 2 and self._sure(
                               self.tracker.nodes.get((ch.name, p.node))))
        st.d002_run = bad
        st.last = ts

    def _d001_arm(self, ch: CommChannel, st: PdoStream, p: pdo_stage.Party,
                  ts: float) -> None:
        """The producer's event timer runs from a frame sent while OPERATIONAL; the frame
        ends the previous gap (a D001 the clock fired for it is withdrawn if the frame
        is stamped before its moment)."""
        w = self.nodes.get((ch.name, p.node))
        if w is not None and w.silent_watch:  # the stream went on: not silent
            w.silent_watch = [x for x in w.silent_watch if x[2] is not st]
        node = self.tracker.nodes.get((ch.name, p.node))
        st.d001_armed = ts if self._operational(node) else None
        st.d001_due = round(ts + st.event_limit_s, 9)
        if st.d001_armed is not None:
            self.next_due = min(self.next_due, st.d001_due)
        self._late(st.d001_fired, ts)
        st.d001_fired = None

    def _d004_arm(self, ch: CommChannel, st: PdoStream, ts: float) -> None:
        """Each consumer's RPDO deadline, armed by a frame received while OPERATIONAL;
        the frame settles the previous gap's finding where it can."""
        for d in st.deadlines:
            if d.fired is not None and ts <= d.due + self.r + EPS:
                self._withdraw(d.fired)  # the clock fired it; this frame came late
            elif d.fired is not None and d.voidable:
                self._withdraw(d.fired)  # no EMCY 8250h before this frame
            elif d.fired is not None and d.watch:  # its first report is still to come
                assert d.armed is not None
                self._node(ch.name, d.party.node).report_watch.append((d.fired, d.armed, ts))
            d.fired, d.voidable = None, False
            node = self.tracker.nodes.get((ch.name, d.party.node))
            if not self._operational(node):
                d.armed, d.watch = None, False
                continue
            d.armed, d.watch = ts, True
            d.due = round(ts + float(d.party.event_timer_ms.value or 0) / 1000, 9)
            self.next_due = min(self.next_due, d.due + self.r)

    def _y004(self, ch: CommChannel, st: PdoStream, f: Any) -> None:
        """A frame of a synchronous stream more than W + r after the latest SYNC, while
        its producer (when known) is OPERATIONAL; one finding per run of late frames in
        one OPERATIONAL interval of the producer."""
        last = ch.last_sync
        assert last is not None
        p = st.producer
        node = self.tracker.nodes.get((ch.name, p.node)) if p is not None else None
        level = 2
        late = f.ts - last > st.window_s + self.r + EPS
        interval: tuple[float | None, float] = (None, 0.0)
        if p is not None:
            w = self.nodes.get((ch.name, p.node))
            level = self._operational(node)
            late = late and level > 0
            interval = (node.left_operational if node is not None else None,
                        w.offline_at if w is not None else float("-inf"))
        prev, st.y004_run = st.y004_run, interval if late else None
        if not late or prev == interval:
            return
        what, party = ("TPDO", f"node {p.node}") if p is not None else (
            "RPDO", f"consumer node {st.consumers[0].node}")
        start = self.tracker.start or 0.0
        self._find("Y004", ch.name, p.node if p is not None else None, f.ts,
                   f"{what} {st.cob_id:03X}h ({party}, type {st.tt}) "
                   f"{(f.ts - last) * 1000:.3f} ms after SYNC at {last - start:.6f} s; "
                   f"synchronous window 1007h = {st.window_s * 1000:.3f} ms "
                   f"({source_text(st.window)})", certain=level == 2 and self._sure(node))

    def _d005(self, ch: CommChannel, st: PdoStream, f: Any, producing: bool,
              party: pdo_stage.Party, want: int) -> None:
        """One finding per stream, party and DLC between the party's boot-ups and resets;
        a consumer judges what it receives while PRE-OPERATIONAL or OPERATIONAL."""
        node = self.tracker.nodes.get((ch.name, party.node))
        if not producing and (node is None or node.state not in _CONSUMING):
            return
        w = self._node(ch.name, party.node)
        seen = st.d005.get((producing, party.node))
        if seen is None or seen[0] != w.epoch:
            seen = st.d005[(producing, party.node)] = (w.epoch, {})
        got = seen[1].get(f.dlc)
        seen[1][f.dlc] = (got[0] if got is not None else f.ts, f.ts)
        if got is None:
            self._d005_find(ch, st, party, producing, want, f.dlc, f.ts, node)

    def _d005_find(self, ch: CommChannel, st: PdoStream, party: pdo_stage.Party, producing: bool,
                   want: int, dlc: int, ts: float, node: NodeState | None) -> None:
        if producing:
            text = (f"TPDO {st.cob_id:03X}h of node {party.node} has DLC {dlc}; its "
                    f"mapping {party.map_index:04X}h has {want} bytes "
                    f"({source_text(party.mapping)})")
        else:
            what = "discards it and raises EMCY 8210h" if dlc < want else "raises EMCY 8220h"
            text = (f"RPDO {st.cob_id:03X}h has DLC {dlc}; node {party.node} maps {want} "
                    f"bytes ({party.map_index:04X}h, {source_text(party.mapping)}): node "
                    f"{party.node} {what}")
        self._find("D005", ch.name, party.node, ts, text,
                   certain=producing or self._sure(node))

    def _d005_new_run(self, ch: CommChannel, n: int, ts: float, epoch: int) -> None:
        """N's boot-up or reset at `ts`: D005's runs of N begin anew. An offending frame on
        the same instant came before it in the log, yet the offline check counts it in the
        new run: it opens that run (and is reported now if its DLC was known already)."""
        node = self.tracker.nodes.get((ch.name, n))
        for st in ch.streams.values():
            for producing, party, want in st.mapped:
                seen = st.d005.get((producing, n)) if party.node == n else None
                if seen is None:
                    continue
                kept = {}
                for dlc, (first, last) in seen[1].items():
                    if abs(last - ts) <= EPS:
                        kept[dlc] = (last, last)
                        if abs(first - ts) > EPS:
                            self._d005_find(ch, st, party, producing, want, dlc, last, node)
                st.d005[(producing, n)] = (epoch, kept)
