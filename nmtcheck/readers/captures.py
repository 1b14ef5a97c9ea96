"""Several captures in one input: where time starts again, a new recording begins.

`cat run1.asc run2.asc`, candump logs joined in the wrong order, a logger that appends a
new session whose stamps start from zero: the file holds two recordings whose times
overlap. Checked as one trace, every node of the first seems to fall silent "for the rest
of the trace" and the second's PDOs are judged against the first's states. Where a
channel's time goes back to the recording's start (or to frames the input already had,
or after a note that frames were left out), the frames are a capture of their own; where
it goes back less, the logger's clock stepped back and later times are made continuous.
A channel that an earlier capture had is then a
channel of its own (`can0 (capture 2)`), with the capture's start and end as its trace
span, so that every rule sees each recording as the trace it is; the files' network and
device configuration still apply to it under its logged name (`InputStats.log_channel`).
Frames stay in file order; I005 still reports the jump.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from nmtcheck.readers.frames import FrameBatch
from nmtcheck.readers.stats import InputStats


class CaptureSpan(NamedTuple):
    """A channel of a later capture in the input (this module): the name it has
    in the log, its capture's span and where that capture begins."""

    log_name: str
    start: float
    end: float
    first_index: int
    first_line: int


# A channel's time going back by more than this starts a new capture, where it goes back
# to the start of the capture or before (within RESTART_S of it). Frames of a merged log
# (a buffered USB adapter) go back by milliseconds; a new recording goes back to its own
# start, seconds to days earlier. A clock step in the middle of a recording (NTP) goes
# back less than the recording's length: no new recording, I005 warns of it.
RESTART_S = 1.0
# A channel's time that goes back by more than this (and less than to a recording's
# start) and stays back is the logger's clock stepped back; a merged log's frames go
# back by milliseconds.
STEP_S = 0.05
# ... and stays back: the channel's CONFIRM frames after the first one are earlier too.
# One frame written late (a stamp seconds off, then time goes on as before) starts no
# capture.
CONFIRM = 3
# Never more captures or clock steps than this in one input: past it, time going back is
# I005's alone.
MAX_CAPTURES = 1000
# A channel's time that goes back within the recording and stays back is the logger's
# clock stepped back (NTP): the frames after it are timed as if it had not, continuing
# from the latest frame before it. Unless the frame it goes back to is one the input
# already had (its time written before, to the microsecond: a log pasted in overlapping
# pieces): then the rest is another capture. Looked for among the last HISTORY frames.
HISTORY = 1 << 16
MAX_REPEAT_LOOKS = 64  # frames going back looked at for a repeat, per search
# Where a batch goes back, the next step back is looked for among the next 2 x WINDOW
# frames first and taken where it lies in the first WINDOW of them (its confirming frames
# among the rest): a search costs the frames up to it, not the rest of the batch, so that
# a logger that resets its clock every second costs no more per reset than per frame.
WINDOW = 8192


@dataclass
class Capture:
    """One recording in the input: its first frame and the span of its times."""

    number: int  # 1, 2, …
    first_index: int  # the frame index of its first frame
    first_line: int
    start: float  # its first frame's time
    end: float  # its latest frame time


class Captures:
    """Splits the batches into captures as they pass, renaming the channels of later ones
    (`channel_spans` then tells the timeline each channel's span).

    Each channel's time is its own: two channels whose loggers' clocks differ, merged
    into one file, go back and forth against each other but never against themselves."""

    def __init__(self, stats: InputStats) -> None:
        self.stats = stats
        self.list: list[Capture] = []
        self.of_channel: dict[int, int] = {}  # channel code -> its capture's number
        self._codes: dict[int, int] = {}  # in the current capture: the reader's code -> ours
        self._latest = -np.inf  # the latest time of the current capture
        # per reader's channel code, its latest time in the current capture
        self._own = np.full(0, -np.inf)
        self._offset = 0.0  # added to every time since the clock stepped back
        self._recent = np.full(0, np.nan)  # the times of the last HISTORY frames
        self._recent_ids = np.zeros(0, np.uint32)  # and their CAN-IDs
        self._left = 0  # the notes of left-out frames (`InputStats.left_out`) taken so far

    def split(self, batches: Iterator[FrameBatch]) -> Iterator[FrameBatch]:
        """The batches with the channel codes of their captures. A batch in which time goes
        back is held until the next one's first frames can confirm a capture that begins
        near its end (rare: the others go on at once)."""
        held: FrameBatch | None = None
        for batch in batches:
            if not len(batch):
                continue
            if held is not None:
                yield self._batch(held, batch)
                held = None
            if self._in_order(batch):
                yield self._batch(batch, None, in_order=True)
            else:
                held = batch
        if held is not None:
            yield self._batch(held, None)
        if self.stats.clock_steps:  # the input's last time as the frames are timed
            self.stats.end = self._latest

    def _in_order(self, batch: FrameBatch) -> bool:
        """In order, the usual case: no frame goes back by STEP_S against any before."""
        ts = batch.ts
        return (ts[0] + self._offset >= self._latest - STEP_S
                and bool((ts[1:] >= ts[:-1]).all()))

    def _batch(self, batch: FrameBatch, after: FrameBatch | None,
               in_order: bool = False) -> FrameBatch:
        """`batch` split into captures and its times past clock steps made continuous
        (`after`: the next batch, None at the input's end)."""
        chan = batch.chan
        ts = batch.ts + self._offset if self._offset else batch.ts
        cuts = self._left_out_rows(batch)
        if not self.list:
            self._begin(batch, 0, ts)
            cuts = [r for r in cuts if r > 0]
        pos, starts = 0, [0]
        if cuts and cuts[0] == 0:  # frames left out between the last batch and this one
            ts = self._another(batch, 0, ts)
            starts.append(0)
            cuts = cuts[1:]
        if in_order and not cuts:
            self._note(ts, chan, batch.can_id)
            pos = len(ts)
        while pos < len(ts):
            cut = next((r for r in cuts if r > pos), len(ts))
            back, new = self._search(ts, chan, batch.can_id, pos, cut,
                                     after if cut == len(ts) else None)
            if back < 0:  # no step back in the next WINDOW frames: take them, look on
                self._note(ts[pos:pos + WINDOW], chan[pos:pos + WINDOW],
                           batch.can_id[pos:pos + WINDOW])
                pos += WINDOW
                continue
            stop = pos + back
            self._note(ts[pos:stop], chan[pos:stop], batch.can_id[pos:stop])
            if stop < len(ts):
                if new or stop == cut:  # another recording, or a piece after left-out ones
                    ts = self._another(batch, stop, ts)
                    starts.append(stop)
                else:  # the clock stepped back: go on from the latest time
                    if ts is batch.ts:
                        ts = ts.copy()
                    step = self._latest - float(ts[stop])
                    ts[stop:] += step
                    self._offset += step
                    self.stats.clock_steps.append(
                        (int(batch.index[stop]), int(batch.line[stop]), step))
            pos = stop
        if ts is not batch.ts:
            batch = replace(batch, ts=ts)
        if len(self.list) == 1:
            self._own_codes(chan, 1)
            return batch
        out = chan.copy()
        first = self.list[-1].number - len(starts) + 1  # the capture of the batch's row 0
        for k, lo in enumerate(starts):
            hi = starts[k + 1] if k + 1 < len(starts) else len(ts)
            if k:
                self._codes = {}
            if hi > lo:  # (a capture that begins at the batch's first row: none before it)
                out[lo:hi] = self._own_codes(chan[lo:hi], first + k)
        return replace(batch, chan=out)

    def _left_out_rows(self, batch: FrameBatch) -> list[int]:
        """The rows of `batch` that come first after a note that frames were left out
        (`[snip]`, `...`: `InputStats.left_out`): each begins a capture, as a log pasted
        in pieces is (a timeout across the left-out frames would be none)."""
        pending = self.stats.left_out[self._left:]
        if not pending or not batch.line[-1]:
            return []
        rows = np.searchsorted(batch.line, pending, side="right")
        taken = int(np.count_nonzero(rows < len(batch)))  # the others: the next batch's
        self._left += taken
        out: list[int] = []
        for row, line in zip(rows[:taken].tolist(), pending[:taken], strict=True):
            if row == 0 and not self.list:  # before the input's first frame: nothing left out
                continue
            if (not out or row != out[-1]) and len(self.list) + len(out) < MAX_CAPTURES:
                out.append(row)
                self.stats.left_out_restarts.append((line, int(batch.line[row])))
        return out

    def _note(self, ts: np.ndarray, chan: np.ndarray, can_id: np.ndarray) -> None:
        """Take frames of the current capture into its latest times, overall and per
        channel."""
        if not len(ts):
            return
        top = int(chan.max())
        if top >= len(self._own):
            self._own = np.concatenate([self._own, np.full(top + 1 - len(self._own), -np.inf)])
        if int(chan.min()) == top:  # one channel, the usual case
            self._own[top] = max(self._own[top], float(ts.max()))
        else:
            np.maximum.at(self._own, chan, ts)
        self._latest = max(self._latest, float(ts.max()))
        self.list[-1].end = self._latest
        if len(ts) >= HISTORY:
            self._recent, self._recent_ids = ts[-HISTORY:], can_id[-HISTORY:]
        else:
            self._recent = np.concatenate([self._recent, ts])[-HISTORY:]
            self._recent_ids = np.concatenate([self._recent_ids, can_id])[-HISTORY:]

    def _search(self, ts: np.ndarray, chan: np.ndarray, can_id: np.ndarray, pos: int,
                cut: int, after: FrameBatch | None) -> tuple[int, bool]:
        """`_back` of rows [pos, cut), relative to pos; (-1, False) where the first WINDOW
        rows hold no step back. Looked for among 2 x WINDOW rows first; where a frame in
        the first WINDOW could go back and its channel's confirming frames lie beyond
        them, among all the rows."""
        if cut - pos > 2 * WINDOW and not self._capped():
            hi = pos + 2 * WINDOW
            back, new, sure = self._back(ts[pos:hi], chan[pos:hi], can_id[pos:hi], None,
                                         trust=WINDOW)
            if sure:
                return (back, new) if back < WINDOW else (-1, False)
        back, new, _sure = self._back(ts[pos:cut], chan[pos:cut], can_id[pos:cut], after)
        return back, new

    def _capped(self) -> bool:
        return len(self.list) + len(self.stats.clock_steps) >= MAX_CAPTURES

    def _back(self, ts: np.ndarray, chan: np.ndarray, can_id: np.ndarray,
              after: FrameBatch | None, trust: int | None = None) -> tuple[int, bool, bool]:
        """The row of `ts` where a channel's time goes back (len(ts): nowhere), and
        whether another recording begins there: the first frame more than STEP_S
        before its channel's latest so far whose channel's next CONFIRM frames (this
        batch's, then `after`'s) are too. Another recording where it goes back by more
        than RESTART_S, to within RESTART_S of the capture's start or before it, or to a
        time the input already had; else the clock stepped back.

        With `trust` (the rows go on after `ts`), also whether the answer holds for the
        rows below `trust` as it would with every row after them: no frame there that
        goes back waited for confirming frames past the end of `ts`."""
        if self._capped():
            return len(ts), False, True
        latest = np.maximum.accumulate(ts)  # a channel's latest is never above the input's
        np.maximum(latest, self._latest, out=latest)
        rows = np.flatnonzero(ts < latest - STEP_S)
        found, drop, sure = len(ts), 0.0, True
        for code in np.unique(chan[rows]).tolist():
            mine = np.flatnonzero(chan == code)
            t = ts[mine]
            own = float(self._own[code]) if code < len(self._own) else -np.inf
            before = np.maximum.accumulate(np.concatenate([[own], t[:-1]]))
            ahead = [t, np.full(CONFIRM, np.inf)]  # inf: the input ends
            if after is not None:
                ahead.insert(1, after.ts[after.chan == code][:CONFIRM] + self._offset)
            t_ahead = np.concatenate(ahead)
            for k in np.flatnonzero(t < before - STEP_S).tolist():
                if int(mine[k]) >= found:
                    break
                if bool((t_ahead[k + 1:k + 1 + CONFIRM] < before[k] - STEP_S).all()):
                    found, drop = int(mine[k]), float(before[k] - t[k])
                    break
                if trust is not None and int(mine[k]) < trust and k + CONFIRM >= len(t):
                    sure = False  # its confirming frames lie past `ts`
        repeat = self._repeat(ts, can_id, latest, found)
        if repeat < found:  # a piece pasted again, by however little time it goes back
            return repeat, True, sure
        if found == len(ts):
            return found, False, sure
        to_start = drop > RESTART_S and float(ts[found]) <= self.list[-1].start + RESTART_S
        return found, to_start or self._seen(ts, can_id, found), sure

    def _repeat(self, ts: np.ndarray, can_id: np.ndarray, latest: np.ndarray,
                upto: int) -> int:
        """The first row before `upto` where time goes back (by any amount) to frames the
        input already had (`_seen`); `upto` if none. Only rows whose time some frame
        before had are looked at, the first MAX_REPEAT_LOOKS of them."""
        before = np.concatenate([[self._latest], latest[:-1]])
        back = np.flatnonzero(ts[:upto] < before[:upto])
        if not len(back):
            return upto
        back = back[np.isin(ts[back], np.concatenate([self._recent, ts]))][:MAX_REPEAT_LOOKS]
        return next((r for r in back.tolist() if self._seen(ts, can_id, r)), upto)

    def _seen(self, ts: np.ndarray, can_id: np.ndarray, row: int) -> bool:
        """Whether the frame at `row` and the CONFIRM after it (in the batch) each have a
        time and CAN-ID of a frame before `row`."""
        if row + CONFIRM >= len(ts):
            return False
        seen_ts = np.concatenate([self._recent, ts[:row]])[-HISTORY:]
        seen_id = np.concatenate([self._recent_ids, can_id[:row]])[-HISTORY:]
        return all(bool(((seen_ts == t) & (seen_id == i)).any()) for t, i in zip(
            ts[row:row + CONFIRM + 1].tolist(), can_id[row:row + CONFIRM + 1].tolist(),
            strict=True))

    def _another(self, batch: FrameBatch, row: int, ts: np.ndarray) -> np.ndarray:
        """Begin a capture at `row`; `ts` with the frames from there on at their own
        times (another recording: no earlier clock step applies to it)."""
        if ts is batch.ts:
            ts = ts.copy()
        ts[row:] -= self._offset
        self._offset = 0.0
        self._begin(batch, row, ts)
        return ts

    def _begin(self, batch: FrameBatch, row: int, ts: np.ndarray) -> None:
        self.list.append(Capture(len(self.list) + 1, int(batch.index[row]),
                                 int(batch.line[row]), float(ts[row]), float(ts[row])))
        self._latest = float(ts[row])
        self._own[:] = -np.inf
        self._recent, self._recent_ids = self._recent[:0], self._recent_ids[:0]

    def _own_codes(self, chan: np.ndarray, number: int) -> np.ndarray:
        """`chan` with each channel code as capture `number` has it: a channel that an
        earlier capture had gets a code (and name) of its own."""
        first = int(chan[0])
        one = first == int(chan.min()) == int(chan.max())  # the common case, found at once
        for code in [first] if one else np.flatnonzero(np.bincount(chan)).tolist():
            if code in self._codes:
                continue
            if code not in self.of_channel:
                self._codes[code] = code
                self.of_channel[code] = number
                continue
            name = self.stats.log_channel(self.stats.channels[code])
            own = self.stats.capture_channel(name, number)
            self._codes[code] = own
            self.of_channel[own] = number
        if all(k == v for k, v in self._codes.items()):
            return chan
        table = np.arange(max(self._codes) + 1, dtype=chan.dtype)
        for k, v in self._codes.items():
            table[k] = v
        out: np.ndarray = table[chan]
        return out


def channel_spans(captures: Captures) -> dict[int, CaptureSpan]:
    """What the timeline needs of an input of several captures (empty for one): each
    channel code's logged name, capture span and the frame its capture begins at."""
    if len(captures.list) < 2:
        return {}
    stats = captures.stats
    stats.restarts = [(c.first_index, c.first_line, c.start) for c in captures.list[1:]]
    stats.capture_spans = [(c.start, c.end, c.first_index, c.first_line)
                           for c in captures.list]
    out = {}
    for code, n in captures.of_channel.items():
        c = captures.list[n - 1]
        out[code] = CaptureSpan(stats.log_channel(stats.channels[code]), c.start, c.end,
                                c.first_index if n > 1 else 0, c.first_line)
    return out
