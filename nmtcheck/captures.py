"""Several captures in one input: where time starts again, a new recording begins.

`cat run1.asc run2.asc`, candump logs joined in the wrong order, a logger that appends a
new session whose stamps start from zero: the file holds two recordings whose times
overlap. Checked as one trace, every node of the first seems to fall silent "for the rest
of the trace" and the second's PDOs are judged against the first's states. A jump back
of more than RESTART_S in the frame times is no jitter of a merged log: from there on
the frames are a capture of their own. A channel that an earlier capture had is then a
channel of its own (`can0 (capture 2)`), with the capture's start and end as its trace
span, so that every rule sees each recording as the trace it is; the files' network and
device configuration still apply to it under its logged name (`InputStats.log_channel`).
Frames stay in file order and keep their stamps; I005 still reports the jump.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np

from nmtcheck.frames import FrameBatch
from nmtcheck.model import CaptureSpan
from nmtcheck.readers import InputStats

# Time going back by more than this starts a new capture. Frames of a merged log (two
# channels, a buffered USB adapter) go back by milliseconds; a new recording goes back to
# its own start, seconds to days earlier.
RESTART_S = 1.0
# ... and stays back: the CONFIRM frames after the first one are earlier too. One frame
# written late (a stamp seconds off, then time goes on as before) starts no capture.
CONFIRM = 3


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
    (`channel_spans` then tells the timeline each channel's span)."""

    def __init__(self, stats: InputStats) -> None:
        self.stats = stats
        self.list: list[Capture] = []
        self.of_channel: dict[int, int] = {}  # channel code -> its capture's number
        self._codes: dict[int, int] = {}  # in the current capture: the reader's code -> ours
        self._latest = -np.inf  # the latest time of the current capture

    def split(self, batches: Iterator[FrameBatch]) -> Iterator[FrameBatch]:
        """The batches with the channel codes of their captures. A batch whose last frames
        may begin a capture is held until the next one's first frames confirm it or not
        (rare: the others go on at once)."""
        held: FrameBatch | None = None
        for batch in batches:
            if not len(batch):
                continue
            if held is not None:
                yield self._batch(held, batch.ts[:CONFIRM])
                held = None
            tail = batch.ts[-CONFIRM:]
            if float(tail.min()) < max(self._latest, float(batch.ts.max())) - RESTART_S:
                held = batch  # (the batch's maximum is at least the running one there)
            else:
                yield self._batch(batch, tail[:0])
        if held is not None:
            yield self._batch(held, held.ts[:0])

    def _batch(self, batch: FrameBatch, after: np.ndarray) -> FrameBatch:
        """`batch` split into captures (`after`: the next frames' times, up to CONFIRM)."""
        ts = batch.ts
        if not self.list:
            self._begin(batch, 0)
        pos, starts = 0, [0]
        if ts[0] >= self._latest - RESTART_S and bool((ts[1:] >= ts[:-1]).all()):
            pos = len(ts)  # in order, the usual case: the running maximum is not needed
            self._latest = max(self._latest, float(ts[-1]))
            self.list[-1].end = self._latest
        ahead = np.concatenate([ts, after, np.full(CONFIRM, np.inf)])  # inf: the input ends
        while pos < len(ts):
            # a frame more than RESTART_S before the latest one so far (itself included:
            # it is never below itself), and the CONFIRM frames after it too, starts a
            # capture
            latest = np.maximum.accumulate(ts[pos:])
            np.maximum(latest, self._latest, out=latest)
            limit = latest - RESTART_S
            back = np.flatnonzero(ts[pos:] < limit)
            for k in range(1, CONFIRM + 1):
                back = back[ahead[pos + back + k] < limit[back]]
            stop = pos + int(back[0]) if len(back) else len(ts)
            if stop > pos:
                self._latest = float(latest[stop - pos - 1])
                self.list[-1].end = self._latest
            if stop < len(ts):
                self._begin(batch, stop)
                starts.append(stop)
            pos = stop
        if len(self.list) == 1:
            self._own(batch.chan, 1)
            return batch
        chan = batch.chan.copy()
        first = self.list[-1].number - len(starts) + 1  # the capture of the batch's row 0
        for k, lo in enumerate(starts):
            hi = starts[k + 1] if k + 1 < len(starts) else len(ts)
            if k:
                self._codes = {}
            if hi > lo:  # (a capture that begins at the batch's first row: none before it)
                chan[lo:hi] = self._own(chan[lo:hi], first + k)
        return replace(batch, chan=chan)

    def _begin(self, batch: FrameBatch, row: int) -> None:
        self.list.append(Capture(len(self.list) + 1, int(batch.index[row]),
                                 int(batch.line[row]), float(batch.ts[row]),
                                 float(batch.ts[row])))
        self._latest = float(batch.ts[row])

    def _own(self, chan: np.ndarray, number: int) -> np.ndarray:
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
    out = {}
    for code, n in captures.of_channel.items():
        c = captures.list[n - 1]
        out[code] = CaptureSpan(stats.log_channel(stats.channels[code]), c.start, c.end,
                                c.first_index if n > 1 else 0, c.first_line)
    return out
