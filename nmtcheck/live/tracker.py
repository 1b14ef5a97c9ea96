"""The incremental part of a live session: per-node NMT state fed frame by frame, and the
findings that are certain the moment they happen (SPEC §2-3, the same parameters as the
offline engine).

Live findings: H001 (a heartbeat gap at the moment its timeout expires: `advance(now)`
is called by the session's timer, not only by the next frame), G001, G002, B001, B002,
B003, C001, C002, C003, C004, S001 (only where the node itself reported its state).
Every other rule needs the whole trace (medians, runs, the future) and
comes from the offline check of the recording at the end. State is O(nodes): nothing
grows with the traffic.
"""

from __future__ import annotations

import statistics
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

from nmtcheck.checks.base import Rule
from nmtcheck.explain.entries import effect_start
from nmtcheck.live.causes import Recent
from nmtcheck.live.frames import LiveFrame
from nmtcheck.protocol.nmt import (
    COMMAND_STATE,
    EPS,
    OFFLINE,
    OPERATIONAL,
    PRE_OPERATIONAL,
    RESETS,
    STATE_OF_CODE,
    STOPPED,
    UNKNOWN,
    state_name,
)
from nmtcheck.settings.network import Network
from nmtcheck.settings.profiles import Profile
from nmtcheck.timeline.error_control import MISSED
from nmtcheck.timeline.model import NodeConfig

SCAN_S = 0.001  # bus time between two looks at every node's deadlines while frames come
RECENT_INTERVALS = 32  # the period of a node with no configured producer time: their median
_RESERVED = ((0x001, 0x07F), (0x101, 0x180), (0x6E0, 0x6FF), (0x780, 0x7FF))


def _nmt_problem(f: LiveFrame, cs: int, target: int) -> str | None:
    """What makes an NMT command frame malformed, if anything."""
    if f.rtr:
        return "remote frame on CAN-ID 000h (NMT commands are data frames)"
    if f.dlc != 2:
        return f"DLC {f.dlc} (an NMT command has DLC 2)"
    if cs not in COMMAND_STATE:
        return f"unknown command specifier {cs:02X}h"
    if target > 127:
        return f"node-ID {target} above 127"
    return None


@dataclass
class LiveFinding:
    """A finding as the live tracker saw it, and what the final offline check said of it."""

    rule: str
    name: str
    severity: str
    channel: str
    node: int | None
    time: float  # the trace's time base, as Finding.time
    message: str
    # set at the end: confirmed | clock-only | not-confirmed | withdrawn | recording-gap
    confirmed: str = ""
    withdrawn: bool = False  # a frame stamped before the timeout's moment came in late
    # False: it rests on something only the whole trace settles (a heartbeat period
    # measured so far, a frame's class that depends on it): provisional
    certain: bool = True
    until: float | None = None  # the offline finding may come this late (B001's timeout)
    # SPEC §8.6: what may explain it, as far as the bus had shown when it fired (H001,
    # G002, B001, B002; None on the other rules)
    causes: list[dict[str, Any]] | None = None
    causes_omitted: int | None = None
    reactions: list[dict[str, Any]] | None = None  # SPEC §9.3: after the effect began
    reactions_omitted: int | None = None


@dataclass
class NodeState:
    """What the tracker keeps per (channel, node): a few numbers, never the frames."""

    channel: str
    node: int
    config: NodeConfig
    state: str = UNKNOWN
    saved: str | None = None  # the state to return to after OFFLINE
    pre_offline: str | None = None  # the state N had when it last went OFFLINE
    seen: bool = False  # N transmitted something (B002's "any frame earlier")
    last_frame: float | None = None
    last_heartbeat: float | None = None  # any 700h+N report, for the node table
    hb_since_boot: int = 0
    heartbeats: int = 0
    prev_hb: float | None = None  # the previous heartbeat since the last boot-up/reset
    intervals: deque[float] = field(default_factory=lambda: deque(maxlen=RECENT_INTERVALS))
    gap_start: float | None = None
    gap_limit: float | None = None
    gap_fired: bool = False
    gap_finding: LiveFinding | None = None  # the H001 of the current gap, if it fired
    written_hb_ms: float | None = None  # 1017h confirmed by SDO (0: heartbeat disabled)
    consumer_ms: dict[int, float] = field(default_factory=dict)  # consumer -> its 1016h entry
    sdo_request: tuple[int, int, int | None, float] | None = None  # index, sub, value, ts
    request: float | None = None  # the pending guarding request's ts
    requests: int = 0  # guarding requests since N's last 700h data frame
    polled: bool = False  # a guarding request to N was seen
    reported: bool = False  # N sent a report (700h data frame) since its boot-up
    reported_state: bool = False  # a heartbeat or guarding response since its boot-up
    start_frame: tuple[float, int] | None = None  # N's first report, at the session's start
    # the last response came after unanswered requests with toggle 0, or was N's first
    # report at the start (it may have been a heartbeat): the toggle expected before it,
    # and whether it was that first report
    doubt: tuple[int | None, bool] | None = None
    request_closed: bool = False
    guard_run: bool = False
    boots: int = 0
    last_boot: float | None = None
    last_boot_repeat: bool = False
    reset_since_boot: bool = False
    last_reset: float | None = None  # the latest direct reset command to N
    # N's first frame, a boot-up at most obey_ms after a reset command to N: stale if N's
    # next boot-up follows within obey_ms (SPEC §2, its power-on boot-up)
    power_on_boot: float | None = None
    unanswered_resets: deque[float] = field(default_factory=lambda: deque(maxlen=64))
    last_ec_bad: dict[str, bool] = field(default_factory=dict)
    # reset ts, its name, whether it surely applies to N (a broadcast does not apply to
    # the channel's master, which the offline check may infer)
    awaiting_boot: tuple[float, str, bool] | None = None
    # after a boot-up, until N's next report or a command to it: N may have started
    # itself (SPEC §2 Self-start), so its PDOs are left to the offline check
    self_start_open: bool = False
    boot_awaited: bool = True  # whether B001 waits out its timeout (the node sent before)
    last_cmd: tuple[float, str] | None = None  # the latest command: ts, the state before it
    observed_at: float | None = None  # the state was reported (not commanded) at this time
    left_operational: float | None = None
    s001_reported: bool = False  # in this state interval (one finding per run)
    custom_pdo: bool = False  # TPDO COB-IDs configured or written: S001 is left offline
    s001_pending: tuple[float, int] | None = None  # ts, COB-ID: decided once time moves on
    toggle_expected: int | None = None
    # the toggle N's responses alone expect (`toggle_expected` less the resets), and the
    # reset commands to N its responses have not shown processed yet: a stale response
    # (SPEC §2) left N before them (as offline `guarding._processed_resets`)
    toggle_seq: int | None = None
    resets_pending: deque[float] = field(default_factory=lambda: deque(maxlen=64))
    g001_run: bool = False
    class_last_hb: float | None = None  # the last heartbeat since the boot-up (SPEC §2)
    class_early: float | None = None  # early_factor x the period in force at it
    class_early_sure: bool = True  # that period was configured, not measured
    gap_certain: bool = True  # the gap's timeout is configured (not a measured period)
    config_doubt: bool = False  # a broadcast reset N may have sent itself cleared its values
    ambiguous: bool = False  # a 700h frame's class (heartbeat or guarding) depended on
    # a measured period: guarding findings of this node are provisional
    findings: int = 0

    def period(self) -> float | None:
        """The producer time in force (written, else configured), else the recent median."""
        hb = self.written_hb_ms if self.written_hb_ms is not None else self.config.heartbeat_ms
        if hb:
            return hb / 1000.0
        return statistics.median(self.intervals) if self.intervals else None

    def producer(self) -> bool:
        if self.written_hb_ms == 0:
            return False
        return bool(self.config.heartbeat_ms) or bool(self.written_hb_ms) or self.heartbeats >= 2

    def timeout_configured(self) -> bool:
        """Whether the H001 timeout rests on configured times, not a measured period. A
        file's producer time is in force only until SDO writes 1017h in the trace (SPEC
        §6), which a live view cannot foresee: a timeout resting on it is provisional."""
        return not self.config_doubt and bool(
            self.config.consumer_timeout_ms or any(self.consumer_ms.values())
            or self.written_hb_ms)

    def timeout(self, factor: float) -> float | None:
        """SPEC H001: the smallest non-zero consumer time, else factor x the period."""
        if self.written_hb_ms == 0:
            return None
        consumers = [v for v in self.consumer_ms.values() if v]
        if self.config.consumer_timeout_ms:
            consumers.append(self.config.consumer_timeout_ms)
        if consumers:
            return min(consumers) / 1000.0
        period = self.period()
        return factor * period if period else None


class Tracker:
    """Feeds frames in order; `advance(now)` fires the timeouts that expired by `now`."""

    def __init__(self, profile: Profile, rules: list[Rule], network: Network | None,
                 emit: Callable[[LiveFinding], object],
                 withdraw: Callable[[LiveFinding], object] | None = None) -> None:
        self.withdraw = withdraw
        self.active = {r.code: r for r in rules}
        self.severity = {r.code: profile[r.code].severity for r in rules}
        p: dict[str, dict[str, Any]] = {code: s.params for code, s in profile.items()}
        self.timeout_factor = float(p["H001"]["timeout_factor"])
        self.early_factor = float(p["H002"]["early_factor"])
        self.response_s = float(p["G002"]["response_timeout_ms"]) / 1000.0
        self.reset_window_s = float(p["B002"]["reset_window_ms"]) / 1000.0
        self.repeat_ms = float(p["B003"]["repeat_window_ms"])
        self.allow = {int(x) for x in p["C001"]["allow"]}
        self.bootup_timeout_s = float(p["B001"]["bootup_timeout_ms"]) / 1000.0
        self.bootup_grace_s = float(p["B001"]["grace_ms"]) / 1000.0
        # per channel: the latest broadcast reset, which the master may obey itself
        self.broadcast_reset_on: dict[str, float] = {}
        # per channel: the latest broadcast reset, kept (SPEC §2 stale boot-ups)
        self.last_broadcast_reset: dict[str, float] = {}
        self.obey_s = float(p["S004"]["obey_ms"]) / 1000.0
        self.grace_s = float(p["S001"]["grace_ms"]) / 1000.0
        self.master_window_s = float(profile.timeline["master_window_ms"]) / 1000.0
        # per channel: nodes that started like an NMT master (boot-up, then at once a
        # broadcast): a broadcast reset does not apply to its sender (SPEC §2)
        self.master_like: dict[str, set[int]] = {}
        self.boots_on: dict[str, deque[tuple[float, int]]] = {}
        self.last_command_on: dict[str, float] = {}
        self.configs = network.configs() if network else {}
        self.network = network
        self.masters: dict[str, int | None] = {}
        self.nodes: dict[tuple[str, int], NodeState] = {}
        self.c001_seen: set[tuple[str, int]] = set()
        self.emit = emit
        self.recent = Recent(profile.timeline, self.reset_window_s)  # for causes
        self.start: float | None = None
        self.now = float("-inf")
        self._scanned = float("-inf")  # the last `now` every node was looked at

    # -- helpers ---------------------------------------------------------------------------

    def node(self, channel: str, n: int) -> NodeState:
        key = (channel, n)
        st = self.nodes.get(key)
        if st is None:
            cfg = self.configs.get((channel, n)) or self.configs.get((None, n)) or NodeConfig()
            st = self.nodes[key] = NodeState(channel, n, cfg)
        return st

    def master(self, channel: str) -> int | None:
        if channel not in self.masters:
            found = self.network.master_for(channel) if self.network else None
            self.masters[channel] = found[0] if found else None
        return self.masters[channel]

    def _find(self, code: str, channel: str, node: NodeState | None, ts: float,
              message: str, unknown_ok: bool = False, certain: bool = True,
              until: float | None = None, cause_from: float | None = None
              ) -> LiveFinding | None:
        if code not in self.active:
            return None
        if node is not None and not unknown_ok and node.state == UNKNOWN:
            return None  # SPEC §3: never for a node whose state is UNKNOWN
        if node is not None:
            node.findings += 1
        lf = LiveFinding(code, self.active[code].name, self.severity[code], channel,
                         node.node if node else None, ts, message, certain=certain,
                         until=until)
        if cause_from is not None and node is not None:
            self._causes(lf, node, cause_from)
        self.emit(lf)
        return lf

    def _causes(self, lf: LiveFinding, st: NodeState, a0: float) -> None:
        """SPEC §8.6 causes of a live finding whose interval starts at `a0`: what the bus
        showed from `a0 - causes_before_ms` up to now (a live finding cannot look ahead)."""
        periods = [p for o in self.nodes.values()
                   if o.channel == st.channel and o is not st and o.producer()
                   for p in (o.period(),) if p]
        now = max(self.now, lf.time)
        found = self.recent.causes(lf.rule, st.channel, st.node, a0, now,
                                   master=self.master(st.channel), periods=periods,
                                   bootups=list(self.boots_on.get(st.channel, ())),
                                   te=effect_start(lf.rule, a0, lf.time, st.period()),
                                   tf=lf.time)
        if found is not None:
            lf.causes, lf.causes_omitted, lf.reactions, lf.reactions_omitted = found

    def _go_offline(self, st: NodeState) -> None:
        if st.state not in (UNKNOWN, OFFLINE):
            st.saved = st.pre_offline = st.state
            st.state = OFFLINE
            st.s001_reported = False

    def _back(self, st: NodeState) -> None:
        if st.state == OFFLINE:
            st.state = st.saved or UNKNOWN
            st.saved = None
            st.s001_reported = False

    def _set(self, st: NodeState, state: str, ts: float, observed: bool) -> None:
        """A new state, commanded or reported (`observed`: S001 trusts only those)."""
        if state != st.state:
            if st.state == OPERATIONAL:
                st.left_operational = ts
            st.s001_reported = False
            st.observed_at = ts if observed else None
        elif not observed:
            st.observed_at = None  # a command: the offline timeline may apply it or not
        elif st.observed_at is None:
            st.observed_at = ts  # a commanded state, now confirmed by the node
        if (st.s001_pending is not None and state != st.state
                and ts <= st.s001_pending[0] + EPS):
            st.s001_pending = None  # the state at the PDO's time is not what it saw
        st.state = state
        st.saved = None

    # -- time ------------------------------------------------------------------------------

    def advance(self, now: float) -> None:
        """Fire every heartbeat or guarding timeout that has expired by `now` (bus time)."""
        self.now = max(self.now, now)
        self._scanned = now
        for st in self.nodes.values():
            self._expire(st, now)

    def _expire(self, st: NodeState, now: float) -> None:
        """One node's deadlines that have passed by `now`."""
        pending = st.s001_pending
        if pending is not None and now > pending[0] + EPS:
            st.s001_pending = None
            self._s001(st, pending)
        self._expire_gap(st, now)
        if (st.request is not None and not st.request_closed
                and now > st.request + self.response_s + EPS):
            self._close_request(st, st.request + self.response_s)
        if st.awaiting_boot is not None and st.boot_awaited and now > (
                st.awaiting_boot[0] + self.bootup_timeout_s + EPS):
            reset_ts, name, sure = st.awaiting_boot
            st.awaiting_boot = None
            # a sign of life later (before a boot-up) is where the offline check
            # reports the same missing boot-up: any later B001 of N confirms this one
            self._find("B001", st.channel, st, reset_ts + self.bootup_timeout_s,
                       f"no boot-up from node {st.node} within "
                       f"{self.bootup_timeout_s:.3f} s after {name}", unknown_ok=True,
                       certain=sure, until=float("inf"), cause_from=reset_ts)

    def _expire_gap(self, st: NodeState, now: float) -> None:
        if (st.gap_start is None or st.gap_fired or st.gap_limit is None
                or not st.producer() or now <= st.gap_start + st.gap_limit + EPS):
            return
        st.gap_fired = True
        moment = st.gap_start + st.gap_limit
        limit = st.gap_limit
        whose = ""
        consumers = {c: v for c, v in st.consumer_ms.items() if v}
        if consumers or st.config.consumer_timeout_ms:
            node = st.config.consumer_node
            if consumers:
                node, _ms = min(consumers.items(), key=lambda kv: kv[1])
            whose = f"consumer time {limit:.3f} s" + (f" of node {node}" if node else "")
        else:
            whose = f"timeout {limit:.3f} s"
        st.gap_finding = self._find(
            "H001", st.channel, st, moment, cause_from=st.gap_start, message=
            f"no heartbeat from node {st.node} for {limit:.3f} s since "
            f"{st.gap_start - (self.start or 0.0):.3f} s ({whose}"
            + ("" if st.gap_certain else ", period measured so far") + ")",
            certain=st.gap_certain and not st.ambiguous)
        self._go_offline(st)

    def _end_gap(self, st: NodeState, ts: float) -> None:
        """A heartbeat, boot-up, reset or 1017h = 0 at `ts`: a timeout that expired before
        it still counts (SPEC H001). One the clock fired although this frame is stamped
        before its moment (the frame reached us late) is withdrawn."""
        lf = st.gap_finding
        if lf is not None and ts <= lf.time + EPS:
            self._withdraw_gap(st)
        self._expire_gap(st, ts)
        st.gap_start = st.gap_limit = None
        st.gap_fired = False
        st.gap_finding = None

    def _withdraw_gap(self, st: NodeState) -> None:
        """Take back the H001 the current gap fired (if it did): what it rested on proved
        otherwise."""
        lf = st.gap_finding
        if lf is not None and st.gap_fired and not lf.withdrawn:
            lf.withdrawn = True
            st.findings -= 1
            if self.withdraw is not None:
                self.withdraw(lf)
            self._back(st)

    def _open_gap(self, st: NodeState, ts: float) -> None:
        st.gap_start, st.gap_limit, st.gap_fired = ts, st.timeout(self.timeout_factor), False
        # from N's first report at the start, which a request may show was an answer
        at_start = st.start_frame is not None and st.start_frame[0] == ts and not st.polled
        st.gap_certain = st.timeout_configured() and not at_start

    def _close_request(self, st: NodeState, moment: float) -> None:
        st.request_closed = True
        if not st.guard_run:
            st.guard_run = True
            self._find("G002", st.channel, st, moment,
                       f"no node-guarding response from node {st.node} within "
                       f"{self.response_s:.3f} s",
                       # after an answer that may prove a heartbeat, the run may be one
                       # with the run before it
                       certain=not st.ambiguous and st.doubt is None,
                       cause_from=moment - self.response_s)
            self._go_offline(st)

    # -- frames ----------------------------------------------------------------------------

    def feed(self, f: LiveFrame) -> None:
        if self.start is None:
            self.start = f.ts
        cid = f.can_id
        # every node's deadlines at most once per SCAN_S of bus time (the moments are
        # computed, not the time of looking); the frame's own node and NMT commands,
        # which act on the deadlines, at once
        if cid == 0 or f.ts >= self._scanned + SCAN_S:
            self.advance(f.ts)
        else:
            self.now = max(self.now, f.ts)
            own = self.nodes.get((f.channel, cid & 0x7F)) if cid & 0x7F else None
            if own is not None:
                self._expire(own, f.ts)
        self.recent.frame(f.channel, f.ts)  # after the timeouts it may end: silence
        if f.err:
            self.recent.error_frame(f.channel, f.ts, cid, f.data)
        if f.ext or f.err:
            return
        if cid not in self.allow and any(lo <= cid <= hi for lo, hi in _RESERVED):
            key = (f.channel, cid)
            if key not in self.c001_seen and len(self.c001_seen) < 4096:
                self.c001_seen.add(key)
                self._find("C001", f.channel, None, f.ts,
                           f"CAN-ID {cid:03X}h is reserved by CiA 301 (first use)")
        if cid == 0:
            self._nmt(f)
            return
        if 0x701 <= cid <= 0x77F:
            self._error_control(f, self.node(f.channel, cid - 0x700))
            return
        n = cid & 0x7F
        if not n:
            return
        if 0x581 <= cid <= 0x5FF or 0x601 <= cid <= 0x67F:
            self._sdo(f, self.node(f.channel, n))
        if 0x081 <= cid <= 0x0FF:
            self.recent.emcy_frame(f.channel, n, f.ts, f.dlc, f.data)
            self._sign_of_life(self.node(f.channel, n), f.ts, what="EMCY")
        elif 0x581 <= cid <= 0x5FF:
            self._sign_of_life(self.node(f.channel, n), f.ts, what="SDO response")
        elif cid in (0x180 + n, 0x280 + n, 0x380 + n, 0x480 + n):
            st = self.node(f.channel, n)
            self._sign_of_life(st, f.ts, what="TPDO")
            self._tpdo(st, f)

    def _sign_of_life(self, st: NodeState, ts: float, reported: str | None = None,
                      what: str = "frame") -> None:
        """Any frame N sends; after a reset before its boot-up it is B001 (a), unless it is
        a state report queued before the reset (SPEC §2 stale reports)."""
        if st.awaiting_boot is not None and what != "boot-up" and (
                ts - st.awaiting_boot[0] > self.bootup_grace_s + EPS):  # else queued before
            reset_ts, name, sure = st.awaiting_boot
            cmd = st.last_cmd  # the latest command to N, the reset or a newer one
            in_window = (reported is not None and cmd is not None
                         and ts - cmd[0] <= self.obey_s + EPS)
            stale = in_window and cmd is not None and reported == cmd[1]
            if not stale:
                st.awaiting_boot = None
                # within the stale window the verdict hangs on the state before the
                # command, which a timeout from a measured period (OFFLINE or not) changes
                self._find("B001", st.channel, st, ts,
                           f"{what} from node {st.node} {ts - reset_ts:.3f} s after {name} "
                           f"without a boot-up", unknown_ok=True,
                           certain=sure and (not in_window or st.timeout_configured()),
                           cause_from=reset_ts)
        st.seen = True
        st.last_frame = ts
        self._back(st)

    def _nmt(self, f: LiveFrame) -> None:
        cs, target = (f.data[0], f.data[1]) if len(f.data) >= 2 else (-1, -1)
        problem = _nmt_problem(f, cs, target)
        if problem is not None:
            st = self.nodes.get((f.channel, target)) if f.dlc == 2 and cs not in COMMAND_STATE \
                else None
            self._find("C002", f.channel, st, f.ts, f"malformed NMT command: {problem}",
                       unknown_ok=st is None)
            return
        self.recent.command(f.channel, f.ts, cs, target)
        master = self.master(f.channel)
        like = self.master_like.setdefault(f.channel, set())
        if not target:
            like.update(self._booted_before(f))
        self.last_command_on[f.channel] = f.ts
        if not target and cs in RESETS:
            self.broadcast_reset_on[f.channel] = f.ts
            self.last_broadcast_reset[f.channel] = f.ts
        if not target and master is not None:
            # whether the master obeyed its own broadcast only its next report shows
            # (SPEC §2): its PDOs until then are left to the offline check
            own = self.nodes.get((f.channel, master))
            if own is not None:
                own.observed_at = None
        if target:
            targets = [self.node(f.channel, target)]
        else:
            targets = [st for (ch, n), st in self.nodes.items()
                       if ch == f.channel and n != master and (st.seen or st.state != UNKNOWN)]
        for st in targets:
            st.self_start_open = False
            if cs in RESETS:
                self._reset(st, f.ts, cs, target, master, like)
            new = COMMAND_STATE[cs]
            # what a stale report would still say: the state N had when it went OFFLINE
            st.last_cmd = (f.ts, st.pre_offline if st.state == OFFLINE and st.pre_offline
                           else st.state)
            if st.state == OFFLINE:
                st.saved = new
                st.observed_at = None
            else:
                self._set(st, new, f.ts, observed=False)
            if cs in RESETS:
                st.toggle_expected = 0  # CiA 301: reset communication resets the toggle
                st.resets_pending.append(f.ts)

    def _booted_before(self, f: LiveFrame) -> Iterator[int]:
        """The nodes that booted since the previous command on the channel and within the
        window before this broadcast: at a common power-on the slaves boot microseconds
        after the master (as timeline.infer_master)."""
        prev_cmd = self.last_command_on.get(f.channel, float("-inf"))
        for b_ts, b_node in self.boots_on.get(f.channel, ()):
            if b_ts > prev_cmd and f.ts - b_ts <= self.master_window_s + EPS:
                yield b_node

    def _reset(self, st: NodeState, ts: float, cs: int, target: int, master: int | None,
               like: set[int]) -> None:
        """A reset command for one node (`target` 0: a broadcast)."""
        if target or (master is None and st.node not in like) or master is not None:
            name = ("reset node" if cs == 0x81 else "reset communication") + (
                "" if target else " (broadcast)")
            st.awaiting_boot = (ts, name, bool(target) or master is not None)
            # a keep-alive manager resets every node-ID: only a node that sent before, or
            # one the network file expects, is awaited (SPEC §3 B001)
            st.boot_awaited = st.seen or st.config.expected
        self._end_gap(st, ts)
        st.reset_since_boot = True
        if target:
            st.last_reset = ts
        st.unanswered_resets.append(ts)
        st.prev_hb = None  # no heartbeat interval across a reset
        self._power_on_values(st)
        if not target and master is None and st.node in like:
            # the master does not obey its own broadcast: offline may not apply it
            st.config_doubt = True

    def _error_control(self, f: LiveFrame, st: NodeState) -> None:
        if f.rtr:
            if st.request is not None and not st.request_closed:
                self._close_request(st, f.ts)  # the next request before the answer
            st.request, st.request_closed = f.ts, False
            st.requests += 1
            if not st.polled:
                st.polled = True
                self._start_frame_answered(st)
            return
        requests, st.requests = st.requests, 0  # since N's previous 700h data frame
        first, st.reported = not st.reported, True  # N's first report since its boot-up
        was_seen = st.seen
        value = f.data[0] if f.data else 0
        if f.dlc == 1 and value == 0:
            self._sign_of_life(st, f.ts, what="boot-up")
        else:
            st.self_start_open = False
            self._sign_of_life(st, f.ts, STATE_OF_CODE.get(value & 0x7F) if f.dlc == 1 else None,
                               "heartbeat" if f.dlc == 1 else "malformed")
        st.last_heartbeat = f.ts
        if f.dlc != 1:
            self._ec_bad(st, "C003", f.ts, f"data frame on {f.can_id:03X}h with DLC {f.dlc} "
                         f"(error control has DLC 1)")
            return
        if value == 0:
            self._bootup(st, f.ts, was_seen)
            return
        st.reported_state = True  # its next boot-up repeats none (B003): N rebooted
        code = value & 0x7F
        toggle = value >> 7
        off = st.written_hb_ms == 0  # 1017h = 0 written: heartbeat disabled
        guard = self._answers(st, f.ts, value, requests, off)
        if guard:
            st.request = None
            st.guard_run = False
            doubtful = (requests > MISSED or first) and toggle == 0 and not off
            before = st.toggle_expected
            left = self._processed_resets(st, f.ts, code)
            self._toggle(st, f.ts, value)
            if left:  # resets it came before: the next response starts anew
                st.toggle_expected = 0
            st.doubt = (before, False) if doubtful else None
            if doubtful and requests > MISSED:  # offline may find it was a heartbeat
                st.ambiguous = True
        else:
            if value & 0x80:  # at the start maybe an answer, which a request may show
                self._ec_bad(st, "C003", f.ts, f"heartbeat {value:02X}h has bit 7 (reserved) set",
                             certain=not st.ambiguous and st.start_frame != (f.ts, value))
            else:
                st.last_ec_bad["C003"] = False
            self._heartbeat(st, f.ts)
        if code not in STATE_OF_CODE:
            self._ec_bad(st, "C004", f.ts, f"node {st.node} reports unknown NMT state "
                         f"{state_name(code)}")
        else:
            st.last_ec_bad["C004"] = False
            reported = STATE_OF_CODE[code]
            cmd = st.last_cmd
            stale = (cmd is not None and f.ts - cmd[0] <= self.obey_s + EPS
                     and reported == cmd[1])  # queued before the command (SPEC §2)
            if not stale:
                self._set(st, reported, f.ts, observed=True)

    def _processed_resets(self, st: NodeState, ts: float, code: int) -> bool:
        """Before N's guarding response at `ts` reporting `code` is judged: set the toggle
        it must have, and say whether reset commands to N remain that N processed after
        it (then the next response must have toggle 0).

        A stale response (SPEC §2: within `obey_ms` of the latest command to N, reporting
        the state from before it) left N before N processed the reset commands whose
        stale window holds it: it keeps the toggle sequence of before them, and they
        count for the next response (Lely, CANopenNode: `70N#85` 0.1 ms after
        `000#810N`). Any other response comes after every reset before it."""
        pending = st.resets_pending
        cmd = st.last_cmd
        stale = (cmd is not None and ts - cmd[0] <= self.obey_s + EPS
                 and STATE_OF_CODE.get(code) == cmd[1])
        if not pending or not stale:
            pending.clear()
            return False
        done = False
        while pending and ts - pending[0] > self.obey_s + EPS:
            pending.popleft()
            done = True
        if not done:
            st.toggle_expected = st.toggle_seq
        return bool(pending)

    def _answers(self, st: NodeState, ts: float, value: int, requests: int, off: bool
                 ) -> bool:
        """Whether N's report `value` at `ts` answers a guarding request (SPEC §2, and
        timeline._classify_guarding's additions); `requests`: those since N's last
        report; `off`: 1017h = 0 is written."""
        toggle = value >> 7
        if (st.start_frame is None and not st.polled and not st.heartbeats and not st.boots
                and self.start is not None and ts - self.start <= self.response_s + EPS):
            # N's first report: maybe the answer to a request sent before the session
            # began, if a request to N comes before its next report (_start_frame_answered)
            st.start_frame = (ts, value)
            return False
        if st.request is None or ts - st.request > self.response_s + EPS:
            return False
        if st.hb_since_boot >= 2 and not off:
            guard = bool(value & 0x80) or (
                st.class_early is not None and st.class_last_hb is not None
                and ts - st.class_last_hb < st.class_early)
            if not (value & 0x80) and not st.class_early_sure:
                st.ambiguous = True  # the class hangs on the whole trace's median
        else:  # the second of two frames with toggle 0 after unanswered requests, a
            # repeat as a response: heartbeats (timeline._classify_guarding_walk)
            guard = not (not off and requests > MISSED and toggle == 0
                         and st.toggle_expected == 1 and st.doubt is not None)
        if st.doubt is not None and (not guard or off or st.doubt[1]) \
                and toggle != st.toggle_expected and st.doubt[0] in (None, toggle):
            st.toggle_expected = st.doubt[0]  # that one was a heartbeat: this one fits
            st.toggle_seq = st.doubt[0]
            st.doubt = None
            st.ambiguous = True  # what live made of it stands: offline reads it again
        return guard

    def _start_frame_answered(self, st: NodeState) -> None:
        """N's first request: the heartbeat N sent right at the session's start, its only
        one, answered a request sent before the session began (monitoring that starts
        mid-stream, as the offline timeline reads it): its gap, and an H001 that gap
        fired, go; the next answer's toggle follows it."""
        if st.start_frame is None or st.heartbeats != 1 or st.prev_hb != st.start_frame[0]:
            return
        value = st.start_frame[1]
        self._withdraw_gap(st)
        st.gap_start = st.gap_limit = None
        st.gap_fired, st.gap_finding = False, None
        st.heartbeats -= 1
        st.hb_since_boot = max(st.hb_since_boot - 1, 0)
        st.prev_hb = st.class_last_hb = None
        st.toggle_expected = st.toggle_seq = 1 - (value >> 7)
        st.doubt = (None, True)  # the next answer's toggle decides, as offline
        st.ambiguous = True  # offline may still find it was a heartbeat, with what follows

    def _toggle(self, st: NodeState, ts: float, value: int) -> None:
        """G001: guarding responses alternate bit 7, starting with 0 after a boot-up or a
        reset; one finding per run of offending responses."""
        toggle = value >> 7
        expected = st.toggle_expected
        if expected is not None and toggle != expected:
            if not st.g001_run:
                why = ("first response after boot-up/reset has toggle 1"
                       if expected == 0 and toggle else
                       f"toggle bit {toggle} repeats the previous response's")
                self._find("G001", st.channel, st, ts,
                           f"guarding response {value:02X}h from node {st.node}: {why}",
                           certain=not st.ambiguous)
            st.g001_run = True
        else:
            st.g001_run = False
        st.toggle_expected = st.toggle_seq = 1 - toggle

    def _tpdo(self, st: NodeState, f: LiveFrame) -> None:
        """S001, when it is certain: the node itself reported PRE-OPERATIONAL or STOPPED
        (no command since, which the offline timeline might apply otherwise), left
        OPERATIONAL more than `grace_ms` ago, and uses the default TPDO COB-IDs."""
        if (st.custom_pdo or st.config.tpdo_cob_ids or st.s001_reported or st.self_start_open
                or st.state not in (PRE_OPERATIONAL, STOPPED) or st.observed_at is None):
            return
        if st.left_operational is not None and (
                f.ts - st.left_operational <= self.grace_s + EPS):
            return
        # the offline timeline takes every frame of the same timestamp as evidence for
        # that moment: decided once a later moment comes (the next frame, or the clock)
        if st.s001_pending is None:
            st.s001_pending = (f.ts, f.can_id)

    def _ec_bad(self, st: NodeState, code: str, ts: float, message: str,
                certain: bool = True) -> None:
        """One finding per run of offending frames (SPEC §3)."""
        if not st.last_ec_bad.get(code):
            self._find(code, st.channel, st, ts, message, unknown_ok=True, certain=certain)
        st.last_ec_bad[code] = True

    def _heartbeat(self, st: NodeState, ts: float) -> None:
        st.class_last_hb = ts
        hb = st.written_hb_ms if st.written_hb_ms is not None else st.config.heartbeat_ms
        period = hb / 1000.0 if hb else (
            statistics.median(st.intervals) if st.intervals else None)
        st.class_early = self.early_factor * period - EPS if period else None
        st.class_early_sure = bool(hb)
        self._end_gap(st, ts)
        if st.prev_hb is not None:
            st.intervals.append(ts - st.prev_hb)
        st.prev_hb = ts
        st.hb_since_boot += 1
        st.heartbeats += 1
        if st.written_hb_ms != 0:
            self._open_gap(st, ts)

    def _bootup(self, st: NodeState, ts: float, was_seen: bool) -> None:
        self._end_gap(st, ts)
        st.awaiting_boot = None
        self.boots_on.setdefault(st.channel, deque(maxlen=128)).append((ts, st.node))
        if st.request is not None and not st.request_closed and (
                ts - st.request > self.response_s + EPS):
            self._close_request(st, st.request + self.response_s)
        st.request, st.guard_run = None, False
        # through INITIALISING in no time: as on the offline timeline, a boot-up while
        # PRE-OPERATIONAL starts no new interval
        self._set(st, PRE_OPERATIONAL, ts, observed=True)
        st.last_cmd = None  # nothing after a boot-up was queued before a command
        st.self_start_open = True  # until a report or a command shows it did not start itself
        st.toggle_expected, st.g001_run = 0, False
        st.toggle_seq = 0
        st.resets_pending.clear()
        st.requests, st.doubt = 0, None
        st.reported = False
        # B003's window: 3 x the configured period, else x the whole trace's median
        # (the recent one here: then a verdict on a gap over 1 s is provisional)
        configured = st.config.heartbeat_ms
        period = configured / 1000.0 if configured else (
            statistics.median(st.intervals) if st.intervals else None)
        window = (self.repeat_ms / 1000.0 if self.repeat_ms
                  else max(3 * period if period else 0.0, 1.0))
        since = ts - st.last_boot if st.last_boot is not None else None
        sure = bool(self.repeat_ms or configured) or (since is not None and since <= 1.0)
        # SPEC §2: N's power-on boot-up, overtaken by a reset command, and this one
        # answering that reset: neither is B003 nor B002 (as checks/bootup._power_on)
        answer = (st.power_on_boot is not None
                  and -EPS <= ts - st.power_on_boot <= self.obey_s + EPS)
        st.power_on_boot = ts if not was_seen and self._reset_just_before(st, ts) else None
        repeat = (since is not None and since <= window + EPS and not st.reset_since_boot
                  and not answer and not st.reported_state)
        while st.unanswered_resets and ts - st.unanswered_resets[0] > self.reset_window_s + EPS:
            st.unanswered_resets.popleft()
        own = self.broadcast_reset_on.get(st.channel)
        if own is not None and ts - own <= self.bootup_timeout_s + EPS:
            # it obeyed a broadcast reset: it did not send it (SPEC §2 inference (2))
            self.master_like.get(st.channel, set()).discard(st.node)
        if st.unanswered_resets:
            st.unanswered_resets.popleft()  # each reset explains one boot-up
        elif st.node == self.master(st.channel) and (
                own is not None and ts - own <= self.bootup_timeout_s + EPS):
            self.broadcast_reset_on.pop(st.channel, None)  # the master obeyed its own reset
        elif answer:
            pass
        elif repeat:
            if not st.last_boot_repeat:
                self._find("B003", st.channel, st, ts,
                           f"node {st.node} sent boot-up (00h) again within {window:.3f} s "
                           f"without a reset command", certain=sure)
        elif was_seen:
            self._find("B002", st.channel, st, ts,
                       f"node {st.node} sent a boot-up with no reset command before it "
                       f"(spontaneous reboot?)", certain=sure or since is None, cause_from=ts)
        st.last_boot_repeat = repeat
        st.last_boot = ts
        st.boots += 1
        st.reset_since_boot = st.reported_state = False
        st.hb_since_boot = 0
        st.prev_hb = None
        st.class_last_hb = st.class_early = None
        st.class_early_sure = True
        self._power_on_values(st)
        st.config_doubt = False

    def _reset_just_before(self, st: NodeState, ts: float) -> bool:
        """Whether a reset command to N, direct or broadcast (whether or not N had been
        seen), came at most obey_ms before `ts` (SPEC §2 stale boot-ups)."""
        latest = max(st.last_reset if st.last_reset is not None else float("-inf"),
                     self.last_broadcast_reset.get(st.channel, float("-inf")))
        return -EPS <= ts - latest <= self.obey_s + EPS

    def _power_on_values(self, st: NodeState) -> None:
        """N's boot-up or a reset command to it: what SDO wrote to N's objects no longer
        holds (SPEC §6), its 1017h nor its 1016h entries for other producers."""
        st.written_hb_ms = None
        for other in self.nodes.values():
            if other.channel == st.channel:
                other.consumer_ms.pop(st.node, None)

    def _sdo(self, f: LiveFrame, st: NodeState) -> None:
        """Confirmed expedited writes of 1016h/1017h change the heartbeat timing (SPEC §6)."""
        if f.dlc < 4 or len(f.data) < 4:
            return
        cmd, index, sub = f.data[0], f.data[1] | f.data[2] << 8, f.data[3]
        if f.can_id >= 0x601:
            self.recent.sdo_request(f.channel, st.node, f.ts, cmd, index, sub, f.data)
        else:
            self.recent.sdo_response(f.channel, st.node, cmd, index, sub)
        if f.can_id >= 0x601:
            if 0x1800 <= index <= 0x1803:
                st.custom_pdo = True  # a TPDO COB-ID written: leave S001 to the offline check
            if cmd & 0xE0 == 0x20 and index in (0x1016, 0x1017):
                value = None
                if cmd & 0x02 and len(f.data) >= 8:
                    size = 4 - ((cmd >> 2) & 0x3) if cmd & 0x01 else 4
                    value = int.from_bytes(f.data[4:4 + size], "little")
                st.sdo_request = (index, sub, value, f.ts)
            else:
                st.sdo_request = None
            return
        req = st.sdo_request
        if cmd != 0x60 or req is None or req[:2] != (index, sub) or req[2] is None:
            if cmd == 0x80:
                st.sdo_request = None
            return
        st.sdo_request = None
        value = req[2]
        if index == 0x1017:
            if value == 0:
                self._end_gap(st, f.ts)
            elif st.gap_start is None:
                st.written_hb_ms = float(value)
                self._open_gap(st, f.ts)
                return
            st.written_hb_ms = float(value)
            if st.gap_start is not None and st.gap_start >= req[3] and not st.gap_fired:
                # a heartbeat sent while the write was being confirmed follows the new value
                st.gap_limit = st.timeout(self.timeout_factor)
        elif index == 0x1016:
            producer = (value >> 16) & 0xFF
            if producer and producer != st.node:
                self.node(st.channel, producer).consumer_ms[st.node] = float(value & 0xFFFF)

    def finish(self) -> None:
        """The end of the input: every frame of the last moment is in, so the PDOs waiting
        for it are decided."""
        for st in self.nodes.values():
            pending = st.s001_pending
            if pending is not None:
                st.s001_pending = None
                self._s001(st, pending)

    def _s001(self, st: NodeState, pending: tuple[float, int]) -> None:
        """One finding per run of offending PDOs in one state interval: the intervals
        OFFLINE cuts are certain only where the timeouts are (configured times)."""
        st.s001_reported = True
        self._find("S001", st.channel, st, pending[0],
                   f"TPDO {pending[1]:03X}h from node {st.node} while {st.state}",
                   certain=(st.timeout_configured() or not st.producer()) and not st.ambiguous)

    # -- what the node table shows ---------------------------------------------------------

    def table(self) -> list[NodeState]:
        return sorted((st for st in self.nodes.values() if st.seen or st.state != UNKNOWN),
                      key=lambda s: (s.channel, s.node))
