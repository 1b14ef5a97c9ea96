"""A live session: every frame recorded, the tracker fed, a timer for the timeouts, and
at the end `engine.check_input` over the recording.

Offline = online by construction: the final findings and reports *are* `nmtcheck check`
on the recording. The live findings are what the tracker could be sure of early; each
is reconciled with the final result (confirmed, clock-only: after the last recorded
frame so no offline check can see it, or not confirmed). Memory is O(nodes): the frames
are on disk.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import threading
import time
import weakref
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from nmtcheck.checks.base import Rule
from nmtcheck.engine import check_input
from nmtcheck.errors import UsageError
from nmtcheck.live.comm import CommTracker
from nmtcheck.live.frames import LiveFrame, candump_line, to_message
from nmtcheck.live.tracker import LiveFinding, NodeState, Tracker
from nmtcheck.results import MAX_FINDINGS_PER_RULE, Finding, InputResult
from nmtcheck.settings.network import Network
from nmtcheck.settings.profiles import Profile

TICK_S = 0.005  # how often the timer looks at the deadlines
GRACE_S = 0.015  # a frame may reach us this late: a timeout fires only once it is this old
CONFIRM_TOLERANCE_S = 0.1  # live and offline times of one finding differ by at most this
GAP_RULES = ("H001", "G002", "G003", "B001")  # counted again from a recording gap's end
MAX_LIVE_FINDINGS = 10000  # kept in memory; more are counted (the recording has them all)
FLUSH_S = 0.5  # the recording reaches the disk at least this often
CLOCK_WINDOW_S = 10  # the bus clock's offset is learnt from this many recent seconds
QUEUE_FRAMES = 50_000  # frames received and not yet checked; more are dropped and counted
OVERLOAD_NOTE_S = 1.0  # the live note about dropped frames, at most this often

CANDUMP_SUFFIXES = ("", ".log")  # a recording written as candump -L by the session itself


def check_record(path: str) -> bool:
    """Whether a recording at `path` is written by python-can (True: a suffix its
    `can.Logger` knows: .asc, .blf, .csv, .db, .mf4, .trc, .txt, any of them .gz) or by
    the session itself as a candump log (False: .log or no suffix); another suffix is a
    usage error, before anything is received."""
    from can.io.logger import MESSAGE_WRITERS

    parts = [x.lower() for x in Path(path).suffixes]
    suffix = parts[-1] if parts else ""
    if suffix == ".gz":
        suffix = parts[-2] if len(parts) > 1 else ""
        if suffix in MESSAGE_WRITERS:
            return True
    elif suffix in CANDUMP_SUFFIXES:
        return False
    elif suffix in MESSAGE_WRITERS:
        return True
    known = ", ".join(sorted(MESSAGE_WRITERS))
    raise UsageError(f"--record {path}: no log writer for this suffix (known: {known}, "
                     "each also .gz)")


def record_writer(path: str) -> Any:
    """python-can's writer for a recording at `path`, chosen by its suffix as `can.Logger`
    chooses; None for a candump log, which the session writes itself (`check_record`)."""
    import can

    if not check_record(path):
        return None
    try:
        return can.Logger(path)
    except (OSError, ImportError, ValueError) as exc:
        raise UsageError(f"--record {path}: cannot write: {exc}") from None


class BusClock:
    """Bus time now, from the wall clock: the frames' timestamps are the bus's clock
    (kernel time for socketcan, a driver's for others, a log's for a replay), so the
    offset is learnt from them. The largest `ts - wall` is the frame that waited least;
    it is taken over the last CLOCK_WINDOW_S only, so that an adapter's clock drifting
    against the host's (tens of ppm: 0.1 s an hour) never makes timeouts fire early."""

    def __init__(self, wall: Callable[[], float] = time.time) -> None:
        self.wall = wall
        self.offset: float | None = None
        self._buckets: deque[tuple[int, float]] = deque()  # (wall second, max offset)

    def observe(self, ts: float) -> None:
        wall = self.wall()
        off = ts - wall
        second = int(wall)
        if self._buckets and self._buckets[-1][0] == second:
            if off > self._buckets[-1][1]:
                self._buckets[-1] = (second, off)
        else:
            self._buckets.append((second, off))
        while self._buckets and self._buckets[0][0] < second - CLOCK_WINDOW_S:
            self._buckets.popleft()
        self.offset = max(o for _s, o in self._buckets)

    def now(self) -> float | None:
        return None if self.offset is None else self.wall() + self.offset


@dataclass
class Outcome:
    """The end of a session: the offline result over the recording and the live findings
    with their reconciliation."""

    result: InputResult | None  # None: no frame was received
    live: list[LiveFinding]
    live_dropped: int = 0
    notes: list[str] = field(default_factory=list)
    dropped: int = 0  # frames received that the session could not keep up with (I004)

    def counts(self) -> dict[str, int]:
        out = {"confirmed": 0, "clock-only": 0, "not-confirmed": 0, "withdrawn": 0,
               "recording-gap": 0, "provisional": 0}
        for lf in self.live:
            out[lf.confirmed] = out.get(lf.confirmed, 0) + 1
            out["provisional"] += not lf.certain
        return out


def _remove_file(path: str) -> None:
    with contextlib.suppress(OSError):
        os.unlink(path)


class Session:
    """Thread-safe: frames may come from several reader threads, the timer runs beside."""

    def __init__(self, profile: Profile, rules: list[Rule], network: Network | None = None,
                 record: str | None = None, on_finding: Callable[[LiveFinding], Any] | None = None,
                 timer: bool = True, input_format: str | None = "candump",
                 channel: str | None = None, strict: bool = False,
                 max_findings: int = MAX_FINDINGS_PER_RULE,
                 clock: BusClock | None = None,
                 on_withdraw: Callable[[LiveFinding], Any] | None = None,
                 name: str | None = None,
                 on_overload: Callable[[int], Any] | None = None,
                 queue_frames: int = QUEUE_FRAMES) -> None:
        self.profile, self.rules, self.network = profile, rules, network
        self.input_format, self.channel, self.strict = input_format, channel, strict
        self.max_findings = max_findings
        self.on_finding = on_finding
        self.lock = threading.RLock()
        self.clock = clock or BusClock()
        self.on_withdraw = on_withdraw
        self.tracker = Tracker(profile, rules, network, self._emit, self._withdrawn)
        self.comm = CommTracker(profile, self.tracker, network, self._emit)
        self.live: list[LiveFinding] = []
        self.live_dropped = 0
        self.frames = 0
        self.records = 0  # frames, or lines of a followed log (which may hold none)
        self.last_ts: float | None = None
        # `record` in another format than candump (.blf, .asc, ...): python-can's writer
        # for its suffix keeps it, beside the candump recording the checks read
        self._writer = record_writer(record) if record is not None else None
        self.temporary = record is None or self._writer is not None
        path = record
        if path is None or self._writer is not None:
            fd, path = tempfile.mkstemp(prefix="nmtcheck-live-", suffix=".log")
            os.close(fd)
            # removed by close(), else when the session is collected or at exit: a session
            # never closed (a program that forgot to, an error in setting it up) left it
            self._remove_temporary = weakref.finalize(self, _remove_file, path)
        self.path = path
        # what the reports call the input: the recording kept, else `name`
        self.name = record if record is not None else name or "<live>"
        self._file: IO[bytes] | None = open(path, "wb")  # noqa: SIM115 - closed in close()
        self._last_flush = time.monotonic()
        self._stop = threading.Event()
        # the bounded intake of `submit` (bus threads): frames wait here for the checker
        self.queue_frames = queue_frames
        self.on_overload = on_overload
        self.dropped = 0  # frames `submit` had no room for, in all
        self._unrecorded_drops = 0  # of those, not yet written as a DROPCOUNT line
        self._drop_span: tuple[float, float] | None = None  # their first and last ts
        self._pending_lost = 0  # a followed log's DROPCOUNT: placed at the next frame
        self._queue: deque[LiveFrame] = deque()
        self._intake = threading.Condition(threading.Lock())
        self._submitted = 0
        self._taken = 0  # frames the checker took from the queue (fed or counted)
        self._worker: threading.Thread | None = None
        self._closing = False
        self._last_note = 0.0
        self._timer: threading.Thread | None = None
        if timer:
            self._timer = threading.Thread(target=self._run_timer, name="nmtcheck-live-timer",
                                           daemon=True)
            self._timer.start()

    # -- input -----------------------------------------------------------------------------

    def feed(self, frame: LiveFrame | None, raw: bytes | None = None) -> None:
        """One frame (recorded as a candump line), or one raw line of a followed log and
        the frame parsed from it (None for a line that holds none: still recorded)."""
        with self.lock:
            if self._file is None:
                return
            self._file.write(raw if raw is not None else candump_line(frame).encode()
                             if frame is not None else b"")
            self.records += 1
            if frame is None:
                return
            self.frames += 1
            if self._writer is not None:
                self._writer.on_message_received(to_message(frame))
            if self._pending_lost:  # lost between the previous frame and this one
                before = self.last_ts if self.last_ts is not None else frame.ts
                self.tracker.recent.frames_lost(before, frame.ts, self._pending_lost)
                self._pending_lost = 0
            self.last_ts = frame.ts
            self.clock.observe(frame.ts)
            if frame.ts > self.comm.next_due:  # its deadlines see the states before it
                self.comm.advance(frame.ts)
            self.tracker.feed(frame)
            self.comm.feed(frame)

    def frames_lost(self, count: int) -> None:
        """A followed log's logger lost `count` frames here (its DROPCOUNT line, which the
        recording keeps): a `frames_lost` cause for live findings around the next frame."""
        with self.lock:
            self._pending_lost += count

    def submit(self, frame: LiveFrame) -> None:
        """A frame from a bus thread, queued for the checker thread: the bus thread never
        waits for the checks, and the queue never holds more than `queue_frames` frames.
        A frame that finds it full is dropped and counted: the recording gets a candump
        `DROPCOUNT` line at that point, so every report has an I004 (frames lost) finding,
        and `on_overload` hears of it (at most every OVERLOAD_NOTE_S)."""
        note = 0
        with self._intake:
            if self._closing:
                return
            self._submitted += 1
            if len(self._queue) >= self.queue_frames:
                self.dropped += 1
                self._unrecorded_drops += 1
                span = self._drop_span
                self._drop_span = (frame.ts if span is None else span[0], frame.ts)
                self._taken += 1
                now = time.monotonic()
                if now - self._last_note >= OVERLOAD_NOTE_S:
                    self._last_note = now
                    note = self.dropped
            else:
                self._queue.append(frame)
                self._intake.notify()
            if self._worker is None:
                self._worker = threading.Thread(target=self._check_queued,
                                                name="nmtcheck-live-checker", daemon=True)
                self._worker.start()
        if note and self.on_overload is not None:
            self.on_overload(note)

    def _check_queued(self) -> None:
        while True:
            with self._intake:
                while not self._queue and not self._unrecorded_drops and not self._closing:
                    self._intake.wait()
                if not self._queue and not self._unrecorded_drops and self._closing:
                    return
                frames = list(self._queue)
                self._queue.clear()
                drops, self._unrecorded_drops = self._unrecorded_drops, 0
                span, self._drop_span = self._drop_span, None
            with self.lock:
                for frame in frames:
                    self.feed(frame)
                # the dropped frames came after those the queue held: the DROPCOUNT line
                # goes after them, where candump would write it (before the next frame)
                self._record_drops(drops)
                if drops and span is not None:
                    self.tracker.recent.frames_lost(span[0], span[1], drops)
            with self._intake:
                self._taken += len(frames)
                self._intake.notify_all()

    def _record_drops(self, count: int) -> None:
        """`count` frames dropped here: a DROPCOUNT line as candump writes one (I004)."""
        if count and self._file is not None:
            self._file.write(f"DROPCOUNT: dropped {count} CAN frame(s) on 'nmtcheck' queue "
                             f"(total drops {self.dropped})\n".encode())

    def drain(self) -> None:
        """Wait until every frame `submit` took before this call has been checked (or
        counted as dropped): what the session reports then covers them."""
        with self._intake:
            target = self._submitted
            while self._taken < target and self._worker is not None and (
                    self._worker.is_alive()):
                self._intake.wait(0.1)

    def _stop_intake(self) -> None:
        self.drain()
        with self._intake:
            self._closing = True
            self._intake.notify_all()
        if self._worker is not None and self._worker is not threading.current_thread():
            self._worker.join()

    def tick(self) -> None:
        """Fire the timeouts that have certainly expired by now (and flush the recording)."""
        with self.lock:
            now = self.clock.now()
            if now is not None and self.frames:
                self.tracker.advance(now - GRACE_S)
                self.comm.advance(now - GRACE_S)
            if self._file is not None and time.monotonic() - self._last_flush > FLUSH_S:
                self._file.flush()
                self._last_flush = time.monotonic()

    def _run_timer(self) -> None:
        while not self._stop.wait(TICK_S):
            self.tick()

    def _withdrawn(self, lf: LiveFinding) -> None:
        self.comm.tracker_withdrawn(lf)
        if self.on_withdraw is not None:
            self.on_withdraw(lf)

    def _emit(self, lf: LiveFinding) -> None:
        self.comm.tracker_finding(lf)
        if len(self.live) < MAX_LIVE_FINDINGS:
            self.live.append(lf)
        else:
            self.live_dropped += 1
        if self.on_finding is not None:
            self.on_finding(lf)

    # -- views -----------------------------------------------------------------------------

    def nodes(self) -> list[NodeState]:
        self.drain()
        with self.lock:
            return self.tracker.table()

    @property
    def start(self) -> float | None:
        return self.tracker.start

    def check(self) -> InputResult | None:
        """`nmtcheck check` over the recording so far (None before the first frame)."""
        self.drain()
        with self.lock:
            if self._file is not None:
                self._file.flush()
            if not self.records:
                return None
            result = check_input(self.path, 0, self.profile, self.rules, self.network,
                                 self.input_format, self.strict, self.channel,
                                 max_findings=self.max_findings)
            result.stats.path = self.name
            return result

    def close(self) -> Outcome:
        """Stop the timer, close the recording, check it, reconcile; a temporary recording
        is removed."""
        self._stop_intake()
        self._stop.set()
        if self._timer is not None and self._timer is not threading.current_thread():
            self._timer.join()
        with self.lock:
            self._record_drops(self._unrecorded_drops)
            self._unrecorded_drops = 0
            self.tick()
            self.tracker.finish()
            self.comm.finish()
            try:
                result = self.check()
            finally:
                if self._file is not None:
                    self._file.close()
                    self._file = None
                if self._writer is not None:
                    self._writer.stop()
                    self._writer = None
                if self.temporary:
                    self._remove_temporary()
            reconcile(self.live, result)
            return Outcome(result, list(self.live), self.live_dropped, dropped=self.dropped)

    def extra_findings(self, result: InputResult | None) -> list[Finding]:
        """Live findings no offline check can see (after the last recorded frame), as
        Findings: a test bench must not lose a timeout because the bus went quiet."""
        with self.lock:
            reconcile(self.live, result)
            out = []
            for lf in self.live:
                if lf.confirmed != "clock-only":
                    continue
                f = Finding(0, lf.rule, lf.name, lf.severity, lf.channel, lf.node, lf.time,
                            None, None, lf.message + " [live: after the last recorded frame"
                            + ("" if lf.certain else "; provisional") + "]")
                f.causes, f.causes_omitted = lf.causes, lf.causes_omitted
                f.reactions, f.reactions_omitted = lf.reactions, lf.reactions_omitted
                out.append(f)
            return out


def reconcile(live: list[LiveFinding], result: InputResult | None) -> None:
    """Mark each live finding: confirmed by the offline check (same rule, channel, node,
    time within CONFIRM_TOLERANCE_S), recording-gap (a timeout inside a silence the
    offline check reads as a recording gap, I007), clock-only (its moment is after the
    recording's last frame: the offline check cannot know it), or not-confirmed."""
    findings = result.findings if result is not None else []
    end = result.stats.end if result is not None and result.stats.end is not None else None
    by_key: dict[tuple[str, str | None, int | None], list[float]] = {}
    for f in findings:
        by_key.setdefault((f.rule, f.channel, f.node), []).append(f.time)
    # one offline H001 may stand for a run of timeouts (every interval over an assumed
    # limit, said once with its count): each timeout of the run confirms a live one
    for m in result.nodes() if result is not None else ():
        times = by_key.get(("H001", m.channel, m.node))
        if times is not None:
            times += [t.moment for t in m.timeouts if t.rule == "H001"]
    # SPEC §3 I007: offline, a silence of the whole channel may be the recorder's; the
    # timeouts live saw inside it are counted again from its end there
    gaps = {(cm.name, g.start, g.end) for cm in (result.model.channels if result else [])
            for g in cm.recording_gaps}
    for lf in live:
        times = by_key.get((lf.rule, lf.channel, lf.node), [])
        hi = lf.time + CONFIRM_TOLERANCE_S if lf.until is None else lf.until
        if any(lf.time - CONFIRM_TOLERANCE_S <= t <= hi for t in times):
            lf.confirmed = "confirmed"
        elif lf.rule in GAP_RULES and any(
                c == lf.channel and a < lf.time <= b for c, a, b in gaps):
            lf.confirmed = "recording-gap"
        elif lf.withdrawn:
            lf.confirmed = "withdrawn"
        elif end is None or lf.time > end:
            lf.confirmed = "clock-only"
        else:
            lf.confirmed = "not-confirmed"
