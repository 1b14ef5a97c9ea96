"""What `nmtcheck monitor` and `check --follow` print while the session runs.

A finding is printed the moment it is reported, as one line. On a terminal a node
table (state, time since the last heartbeat, findings) stays below the lines and is
redrawn a few times a second; when stdout is not a terminal only the lines are
printed (a pipe, a CI log, `tee`).
"""

from __future__ import annotations

import sys
import threading
from typing import TextIO

from nmtcheck.live.session import Outcome
from nmtcheck.live.tracker import LiveFinding, NodeState
from nmtcheck.safe_text import escape_controls, escape_lines

_UP_CLEAR = "\x1b[{n}F\x1b[J"  # cursor up n lines to column 0, clear to the end


def finding_line(lf: LiveFinding, start: float | None) -> str:
    node = f"node {lf.node}" if lf.node is not None else "-"
    base = start if start is not None else lf.time
    return (f"{lf.time - base:9.3f} s  {lf.channel} {node}  {lf.rule} {lf.name}"
            f"  {lf.message}" + ("" if lf.certain else "  [provisional]"))


def cause_lines(lf: LiveFinding, start: float | None) -> list[str]:
    """SPEC §8.6: one indented line per cause under the live line, times as the live
    line shows them (seconds from the session's first frame)."""
    base = start if start is not None else lf.time
    out = []
    for c in lf.causes or ():
        span = f"{c['time'] - base:.3f}" + (
            f"-{c['end'] - base:.3f}" if c.get("end") is not None else "")
        node = f" (node {c['node']})" if c.get("node") is not None else ""
        out.append(f"    cause: {span} s {c['text']}{node}")
    if lf.causes_omitted:
        out.append(f"    cause: ... {lf.causes_omitted} more")
    for c in lf.reactions or ():
        span = f"{c['time'] - base:.3f}" + (
            f"-{c['end'] - base:.3f}" if c.get("end") is not None else "")
        node = f" (node {c['node']})" if c.get("node") is not None else ""
        out.append(f"    after: {span} s {c['text']}{node}  [{c['role']}]")
    if lf.reactions_omitted:
        out.append(f"    after: ... {lf.reactions_omitted} more")
    return out


def node_table(nodes: list[NodeState], now: float | None) -> list[str]:
    rows = [f"{'channel':<10} {'node':>4}  {'state':<16} {'heartbeat age':>13}  findings"]
    for st in nodes:
        age = ("-" if st.last_heartbeat is None or now is None
               else f"{max(now - st.last_heartbeat, 0.0):.3f} s")
        rows.append(f"{escape_controls(st.channel):<10} {st.node:>4}  {st.state:<16} "
                    f"{age:>13}  {st.findings}")
    return rows


class Display:
    """Thread-safe: findings come from reader and timer threads, redraws from the main one."""

    def __init__(self, out: TextIO | None = None, table: bool | None = None) -> None:
        self.out = out or sys.stdout
        self.table = self.out.isatty() if table is None else table
        self.lock = threading.Lock()
        self._drawn = 0  # lines of the table on screen
        self._rows: list[str] = []
        self.start: float | None = None

    def finding(self, lf: LiveFinding) -> None:
        with self.lock:
            self._clear()
            self.out.write(escape_controls(finding_line(lf, self.start)) + "\n")
            for line in cause_lines(lf, self.start):
                self.out.write(escape_controls(line) + "\n")
            self._draw()
            self.out.flush()

    def withdrawn(self, lf: LiveFinding) -> None:
        self.note(f"withdrawn: {finding_line(lf, self.start).strip()} ({why_withdrawn(lf)})")

    def note(self, text: str) -> None:
        with self.lock:
            self._clear()
            self.out.write(escape_controls(text) + "\n")  # a name's ESC is shown, not sent
            self._draw()
            self.out.flush()

    def refresh(self, nodes: list[NodeState], now: float | None) -> None:
        if not self.table:
            return
        with self.lock:
            self._clear()
            self._rows = node_table(nodes, now)
            self._draw()
            self.out.flush()

    def close(self) -> None:
        """Leave the last table on screen (it is the session's final state)."""
        with self.lock:
            self._drawn = 0

    def _clear(self) -> None:
        if self._drawn:
            self.out.write(_UP_CLEAR.format(n=self._drawn))
            self._drawn = 0

    def _draw(self) -> None:
        if self.table and self._rows:
            self.out.write("\n".join(self._rows) + "\n")
            self._drawn = len(self._rows)


def why_withdrawn(lf: LiveFinding) -> str:
    """What took a live finding back: a late frame (the NMT timeouts), or the party's
    report or silence after a PDO gap (D001, D004: SPEC_COMM §9.1.6)."""
    if lf.rule in ("D001", "D004"):
        return ("a frame stamped before that moment arrived late, or the node's next report "
                "showed another state with no command to it, or it went OFFLINE without a "
                "frame: the gap was not the stream's")
    return "a frame stamped before that moment arrived late"


def live_summary(outcome: Outcome, ended: str) -> str:
    """How the live findings compare with the offline check of the recording; the ones
    after the last recorded frame are stated in full (no report can hold them)."""
    res = outcome.result
    start = res.stats.start if res is not None else None
    c = outcome.counts()
    lines = [f"nmtcheck: session ended: {ended}; {res.stats.frames if res else 0} frames; "
             f"{len(outcome.live)} live finding(s): {c['confirmed']} confirmed by the "
             f"offline check of the recording, {c['clock-only']} after its last frame "
             f"(seen by the clock only), {c['not-confirmed']} not confirmed"
             + (f", {c['withdrawn']} withdrawn" if c["withdrawn"] else "")
             + (f", {c['recording-gap']} inside a recording gap (I007)"
                if c["recording-gap"] else "")
             + (f" ({c['provisional']} of them provisional: resting on what only the "
                f"whole trace settles)" if c["provisional"] else "")]
    if outcome.live_dropped:
        lines.append(f"nmtcheck: {outcome.live_dropped} more live findings were not kept")
    if outcome.dropped:
        lines.append(f"nmtcheck: {outcome.dropped} frame(s) dropped: received faster than the "
                     "checks ran (I004 in every report; the findings around them may be the "
                     "monitor's loss, not the network's)")
    for lf in outcome.live:
        if lf.confirmed != "confirmed":
            what = {"clock-only": "after the last recorded frame",
                    "withdrawn": f"withdrawn ({why_withdrawn(lf)})",
                    "recording-gap": "inside a silence the offline check reads as a "
                                     "recording gap (I007)"}.get(
                lf.confirmed, "not confirmed by the offline check")
            lines.append(f"  {what}: {finding_line(lf, start)}")
    return escape_lines(lines)  # a channel's newline or ESC is shown, never sent
