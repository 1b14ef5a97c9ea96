"""Causes of live findings (SPEC §8.6): what happened lately on each channel, kept as a few
bounded deques, and the entries a live H001, G002, B001 or B002 gets the moment it fires.

A live finding can only look back: its window is [a0 - causes_before_ms, now], never the
frames after it (the `reboot` kind, the `boot_process` of the boot analysis and whatever
follows come with the offline check of the recording, whose reports carry the full
`causes`). Entries have the offline schema (`nmtcheck.explain.causes`), without frame index and
line (a live frame has neither). Memory: each deque holds at most the longest window
(`reset_window_ms` of B002, 10 s by default) and at most MAXLEN entries, so a flood of
EMCYs or error frames costs the same as a few.
"""

from __future__ import annotations

from collections import deque
from typing import Any

from nmtcheck.explain.causes import CAN_ERR_CRTL, CAN_ERR_CRTL_OVERFLOW, NMT_NAMES, SDO_WRITES
from nmtcheck.explain.entries import capped, cause_entry, cluster_entry, split
from nmtcheck.protocol import emcy
from nmtcheck.protocol.nmt import EPS

RULES = ("H001", "G002", "B001", "B002")  # the live rules of SPEC §8.6's list (no live S004)
MAXLEN = 1024  # entries per deque
MERGE_S = 0.01  # error frames closer than this are one bucket (their count is exact)


class Recent:
    """The recent events of every channel that can explain a finding."""

    def __init__(self, timeline: dict[str, Any], reset_window_s: float) -> None:
        self.before = float(timeline.get("causes_before_ms", 1000.0)) / 1000.0
        self.cap = int(timeline.get("causes_max", 5))
        self.silence_min = float(timeline.get("silence_min_ms", 100.0)) / 1000.0
        self.cluster = float(timeline.get("reboot_cluster_ms", 500.0)) / 1000.0
        self.reset_window = reset_window_s
        self.horizon = max(self.before, self.reset_window, self.cluster) + 1.0
        self.emcy: dict[str, deque[list[Any]]] = {}  # [ts, end, node, code, text, count, dlc]
        self.errors: dict[str, deque[list[Any]]] = {}  # [ts, end, count, overflows]
        self.nmt: dict[str, deque[tuple[float, int, int]]] = {}  # ts, cs, target
        self.sdo: dict[str, deque[list[Any]]] = {}  # [ts, node, index, sub, value, confirmed]
        self.silences: dict[str, deque[tuple[float, float]]] = {}
        self.last_frame: dict[str, float] = {}
        self.lost: deque[list[Any]] = deque(maxlen=MAXLEN)  # [ts, end, count, channel]

    def _q(self, table: dict[str, deque[Any]], channel: str) -> deque[Any]:
        q = table.get(channel)
        if q is None:
            q = table[channel] = deque(maxlen=MAXLEN)
        return q

    def _prune(self, q: deque[Any], ts: float) -> None:
        while q and q[0][0] < ts - self.horizon:
            q.popleft()

    # -- recording ---------------------------------------------------------------------------

    def frame(self, channel: str, ts: float) -> None:
        """Any frame: a stretch without frames before it is kept for `silence`."""
        last = self.last_frame.get(channel)
        if last is not None and ts - last >= self.silence_min - EPS:
            q = self._q(self.silences, channel)
            self._prune(q, ts)
            q.append((last, ts))
        self.last_frame[channel] = max(ts, last) if last is not None else ts

    def error_frame(self, channel: str, ts: float, can_id: int, data: bytes) -> None:
        overflow = bool(can_id & CAN_ERR_CRTL) and len(data) > 1 and bool(
            data[1] & CAN_ERR_CRTL_OVERFLOW)
        q = self._q(self.errors, channel)
        self._prune(q, ts)
        if q and ts - q[-1][1] <= MERGE_S and not overflow and not q[-1][3]:
            q[-1][1] = ts
            q[-1][2] += 1
        else:
            q.append([ts, ts, 1, overflow])

    def emcy_frame(self, channel: str, node: int, ts: float, dlc: int, data: bytes) -> None:
        if dlc < 2 or len(data) < 2:
            return
        code = data[0] | data[1] << 8
        q = self._q(self.emcy, channel)
        self._prune(q, ts)
        prev = next((e for e in reversed(q) if e[2] == node), None)
        if prev is not None and prev[3] == code:
            prev[1] = ts  # consecutive identical codes of one node merge
            prev[5] += 1
            return
        _c, text = emcy.describe(list(data[:8]), dlc)
        q.append([ts, ts, node, code, text, 1, dlc])

    def command(self, channel: str, ts: float, cs: int, target: int) -> None:
        q = self._q(self.nmt, channel)
        self._prune(q, ts)
        q.append((ts, cs, target))

    def sdo_request(self, channel: str, node: int, ts: float, cmd: int, index: int, sub: int,
                    data: bytes) -> None:
        """A download initiate to `node` (ccs 1), kept until confirmed or aged out."""
        if cmd & 0xE0 != 0x20:
            return
        value = None
        if cmd & 0x02 and len(data) >= 8:
            size = 4 - ((cmd >> 2) & 0x3) if cmd & 0x01 else 4
            value = int.from_bytes(data[4:4 + size], "little")
        q = self._q(self.sdo, channel)
        self._prune(q, ts)
        q.append([ts, node, index, sub, value, False])

    def sdo_response(self, channel: str, node: int, cmd: int, index: int, sub: int) -> None:
        if cmd != 0x60:
            return
        for e in reversed(self.sdo.get(channel, ())):
            if e[1] == node:
                if (e[2], e[3]) == (index, sub):
                    e[5] = True
                return

    def frames_lost(self, ts: float, end: float, count: int, channel: str | None = None
                    ) -> None:
        """A logger drop: the session's own queue, or a DROPCOUNT line of a followed log
        (None: every channel)."""
        self._prune(self.lost, ts)
        self.lost.append([ts, end, count, channel])

    # -- the causes of one finding -------------------------------------------------------------

    def causes(self, rule: str, channel: str, node: int, a0: float, now: float,
               master: int | None = None, periods: list[float] | None = None,
               bootups: list[tuple[float, int]] | None = None, te: float | None = None,
               tf: float | None = None
               ) -> tuple[list[dict[str, Any]], int, list[dict[str, Any]], int] | None:
        """The capped causes and reactions (and how many of each were left out) of a live
        finding of `rule` for `node`, whose interval starts at `a0` and whose effect began
        at `te` (§9.3.2; default: now), as the bus stands at `now`."""
        if rule not in RULES:
            return None
        lo, hi = a0 - self.before, now
        out = self._emcy(rule, channel, node, lo, hi)
        out += self._errors(channel, lo, hi)
        out += self._lost(channel, lo, hi)
        out += self._silence(channel, lo, hi, now, periods or [])
        # B002: commands and writes in the reset window before the boot-up (8.6.2)
        cmd = (a0 - self.reset_window, a0) if rule == "B002" else (lo, hi)
        out += self._nmt(rule, channel, node, a0, cmd, master)
        out += self._sdo(rule, channel, node, cmd)
        if rule == "B002" and bootups:
            out += self._cluster(node, a0, bootups)
        causes, reactions = split(out, now if te is None else te, now if tf is None else tf,
                                  node)
        return (*capped(causes, self.cap), *capped(reactions, self.cap))

    def _emcy(self, rule: str, channel: str, node: int, lo: float, hi: float
              ) -> list[dict[str, Any]]:
        out = []
        for ts, end, n, code, text, count, dlc in self.emcy.get(channel, ()):
            if not (lo - EPS <= ts <= hi + EPS) and not (lo - EPS <= end <= hi + EPS):
                continue
            if n == node and code and dlc >= 3:
                out.append(cause_entry("emcy", ts, None, None, text, n, count=count,
                                  code=f"{code:04X}h"))
            elif n != node and code >> 8 == 0x81 and rule != "B001":
                out.append(cause_entry("emcy_other", ts, None, None, text, n, count=count,
                                  code=f"{code:04X}h"))
        return out

    def _nmt(self, rule: str, channel: str, node: int, a0: float,
             window: tuple[float, float], master: int | None) -> list[dict[str, Any]]:
        out = []
        for ts, cs, target in self.nmt.get(channel, ()):
            if not (window[0] - EPS <= ts <= window[1] + EPS):
                continue
            if not (target == node or (target == 0 and node != master)):
                continue
            if rule == "B001" and (cs in (0x81, 0x82) or ts <= a0 + 1e-9):
                continue  # its own reset, and the resets: B001 (a) lists the others
            name = NMT_NAMES.get(cs, f"{cs:02X}h")
            text = f"NMT {name} to {'all nodes' if target == 0 else f'node {target}'}"
            if rule == "B001":
                text += ": likely lost while the node initialises"
            elif rule == "B002":
                text += ": this reset was already answered before the boot-up"
            out.append(cause_entry("nmt", ts, None, None, text, node))
        return out

    def _sdo(self, rule: str, channel: str, node: int, window: tuple[float, float]
             ) -> list[dict[str, Any]]:
        wanted = SDO_WRITES.get(rule, ())
        out = []
        for ts, n, index, sub, value, confirmed in self.sdo.get(channel, ()):
            if not (window[0] - EPS <= ts <= window[1] + EPS) or index not in wanted:
                continue
            if n != node and not (rule == "H001" and index == 0x1016 and value is not None
                                  and (value >> 16) & 0xFF == node):
                continue
            shown = "?" if value is None else f"0x{value:08X}"
            to = "" if n == node else f" to node {n}"
            out.append(cause_entry("sdo_write", ts, None, None,
                              f"SDO write {index:04X}h:{sub:02X} = {shown}{to} "
                              + ("confirmed" if confirmed else "not confirmed"), n))
        return out

    def _cluster(self, node: int, a0: float, bootups: list[tuple[float, int]]
                 ) -> list[dict[str, Any]]:
        """Boot-ups of other nodes within reboot_cluster_ms before this one (the ones after
        it come with the offline check)."""
        hits = sorted((ts, n, -1, 0) for ts, n in bootups
                      if n != node and abs(ts - a0) <= self.cluster + EPS)
        if not hits:
            return []
        nodes = ", ".join(str(n) for n in sorted({h[1] for h in hits}))
        return [cluster_entry(hits, (a0, node, -1, 0), nodes, self.cluster)]

    def _errors(self, channel: str, lo: float, hi: float) -> list[dict[str, Any]]:
        hit = [e for e in self.errors.get(channel, ()) if e[1] >= lo - EPS and e[0] <= hi + EPS]
        if not hit:
            return []
        count = sum(e[2] for e in hit)
        return [cause_entry("error_frames", hit[0][0], None, None,
                       f"{count} error frame(s) on the channel", end=hit[-1][1], count=count)]

    def _lost(self, channel: str, lo: float, hi: float) -> list[dict[str, Any]]:
        out = []
        drops = [e for e in self.lost if (e[3] is None or e[3] == channel)
                 and e[1] >= lo - EPS and e[0] <= hi + EPS]
        if drops:
            total = sum(e[2] for e in drops)
            out.append(cause_entry("frames_lost", drops[0][0], None, None,
                              f"{total} frame(s) lost before the checks saw them (the "
                              "logger's or the monitor's drop): a gap here may be theirs",
                              end=drops[-1][1] if drops[-1][1] != drops[0][0] else None,
                              count=total))
        over = [e for e in self.errors.get(channel, ()) if e[3] and lo - EPS <= e[0] <= hi + EPS]
        if over:
            out.append(cause_entry("frames_lost", over[0][0], None, None,
                              f"{len(over)} controller overflow error frame(s): the interface "
                              "lost received or queued frames",
                              end=over[-1][0] if len(over) > 1 else None, count=len(over)))
        return out

    def _silence(self, channel: str, lo: float, hi: float, now: float,
                 periods: list[float]) -> list[dict[str, Any]]:
        """Stretches with no frame on the channel of at least max(silence_min, 2 x the
        smallest period of the channel's other producers), the one still going on
        included."""
        if not periods:
            return []
        need = max(self.silence_min, 2 * min(periods))
        spans = [s for s in self.silences.get(channel, ()) if s[1] >= lo and s[0] <= hi]
        last = self.last_frame.get(channel)
        if last is not None and now - last >= need - EPS:
            spans.append((last, now))
        return [cause_entry("silence", a, None, None,
                       f"no frame on the channel for {(b - a) * 1000:.0f} ms"
                       + (" (so far)" if b == now and a == last else ""), end=b)
                for a, b in spans if b - a >= need - EPS][:3]
