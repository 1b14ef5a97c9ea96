"""What a reader tells of its input (`InputStats`: every record accounted for, drops,
notes, channels) and the batches a line reader hands out, counted into it."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from nmtcheck.errors import InputError
from nmtcheck.readers.frames import BatchBuilder, FrameBatch
from nmtcheck.readers.records import MAX_LEFT_OUT, is_left_out_line

MAX_SKIPPED_LINES_KEPT = 10
MAX_DROPS = 10000  # drop records placed (InputStats.drops); all of them are counted


class Drop(NamedTuple):
    """One drop record of the logger (`InputStats.drop`); `line` 0: a binary format's."""

    line: int
    lost: int  # frames lost (`count` is a tuple's method)
    frame: int | None = None  # the first frame after the loss; None: after `line`
    ts: float | None = None  # when the logger reported it; None: that frame's time


@dataclass
class InputStats:
    """What a reader saw in one input; every record is accounted for here."""

    path: str
    format: str = ""
    frames: int = 0
    skipped: int = 0  # records that could not be parsed
    skipped_lines: list[int] = field(default_factory=list)
    skip_reason: str = ""  # why the first skipped record could not be parsed
    ignored: int = 0  # well-formed records that are not bus frames (status, statistics, TxRq…)
    notes: int = 0  # of `ignored`: lines that are only a note or a comment (`# …`, a prompt)
    extended: int = 0
    error_frames: int = 0
    remote_frames: int = 0
    fd_frames: int = 0
    dropped: int = 0  # frames the logger says it lost (DROPCOUNT, BLF data lost, CLX000 Lost)
    # the first MAX_DROPS drop records: where a loss sits (SPEC §8.6)
    drops: list[Drop] = field(default_factory=list)
    backwards_timestamps: int = 0
    first_backwards: tuple[int, int, float] | None = None  # frame index, line, time
    truncated: bool = False  # the input ends early (cut off, or a damaged compressed stream)
    start: float | None = None
    end: float | None = None
    channels: list[str] = field(default_factory=list)
    # False when the input has no timestamps written (candump screen output without `-t`,
    # bare `ID#DATA` lines): every frame is at 0 s and only their order counts (SPEC §1)
    timestamped: bool = True
    # the frame index stands for the time: no usable timestamps (set by the engine, SPEC §1)
    order_only: bool = False
    strict: bool = False
    # where a later capture begins in the input (nmtcheck/readers/captures.py): frame index, line,
    # time; and each of its channels' name in the log
    restarts: list[tuple[int, int, float]] = field(default_factory=list)
    capture_channels: dict[str, str] = field(default_factory=dict)
    # each capture's first and latest time, first frame index and line, when the input
    # holds several (the reports give each one's span: times of two never subtract)
    capture_spans: list[tuple[float, float, int, int]] = field(default_factory=list)
    # where the logger's clock stepped back within a recording: frame index, line, and
    # the seconds the frames after it are timed later than their stamps (captures.py)
    clock_steps: list[tuple[int, int, float]] = field(default_factory=list)
    # the lines of notes that frames were left out (`[snip]`, `...`), in file order; and
    # those of them after which a capture begins, with its first frame's line (captures.py)
    left_out: list[int] = field(default_factory=list)
    left_out_restarts: list[tuple[int, int]] = field(default_factory=list)
    _chan_codes: dict[str, int] = field(default_factory=dict, repr=False)

    def channel_code(self, name: str) -> int:
        code = self._chan_codes.get(name)
        if code is None:
            code = len(self.channels)
            self._chan_codes[name] = code
            self.channels.append(name)
        return code

    def capture_channel(self, name: str, number: int) -> int:
        """The code of channel `name` (as logged) in the input's capture `number` (> 1):
        `can0 (capture 2)`, a channel of its own (nmtcheck/readers/captures.py)."""
        own = f"{name} (capture {number})"
        self.capture_channels[own] = name
        return self.channel_code(own)

    def log_channel(self, name: str) -> str:
        """A channel's name in the log (that of a later capture's channel without it)."""
        return self.capture_channels.get(name, name)

    def drop(self, line: int, count: int, frame: int | None = None,
             ts: float | None = None) -> None:
        """A logger's drop record: counted, and placed for the `frames_lost` cause of the
        findings around it. A text record (`DROPCOUNT`) gives only its `line`: the cause
        places it at the first frame after that line. A reader that knows more gives the
        index of the first frame after the loss (`frame`) and the moment the logger
        reported it (`ts`; None: that frame's time)."""
        self.dropped += count
        if len(self.drops) < MAX_DROPS:
            self.drops.append(Drop(line, count, frame, ts))

    @property
    def drop_record(self) -> str:
        """What this format calls its records of lost frames (reports name them)."""
        return {"blf": "BLF data-lost", "cl2000": "CL2000 Lost"}.get(self.format, "DROPCOUNT")

    def skip(self, line: int, why: str) -> None:
        """Count an unparseable record; fatal under --strict."""
        if self.strict:
            raise InputError(self.path, f"cannot parse {self.format} record: {why}", line)
        if not self.skipped:
            self.skip_reason = why
        self.skipped += 1
        if len(self.skipped_lines) < MAX_SKIPPED_LINES_KEPT:
            self.skipped_lines.append(line)

    def left_out_text(self) -> str | None:
        """What the reports say of the notes that frames were left out (`[... snip ...]`,
        `...`) after which a capture begins: information on an edit the user made on
        purpose, no finding (I005 is for timestamps that go backwards); None if none."""
        lines = [note for note, _first in self.left_out_restarts]
        if not lines:
            return None
        at = ", ".join(str(n) for n in lines[:3]) + (", …" if len(lines) > 3 else "")
        return (f"frames were left out at line{'s' if len(lines) > 1 else ''} {at} (a note "
                f"such as `[snip]` or `...`): {len(self.restarts) + 1} captures, each "
                "checked as a trace of its own (a later capture's channels are named "
                "'NAME (capture K)')")

    def note(self, count: int = 1, raw: bytes | None = None, line: int = 0) -> None:
        """Count lines that are only a note or a comment: non-frame records, not skips. A
        note `raw` at `line` that frames were left out there is kept (`left_out`)."""
        self.ignored += count
        self.notes += count
        if (raw is not None and line and len(self.left_out) < MAX_LEFT_OUT
                and is_left_out_line(raw)):
            self.left_out.append(line)


def account(stats: InputStats, batch: FrameBatch | None) -> FrameBatch | None:
    """Count a finished batch into the input's stats (vectorised, once per batch)."""
    if batch is None or len(batch) == 0:
        return None
    ts = batch.ts
    # each frame against the one before it (the previous batch's last for the first)
    prev = np.concatenate([[stats.end if stats.end is not None else ts[0]], ts[:-1]])
    backwards = np.flatnonzero(ts < prev)
    back = len(backwards)
    if back and stats.first_backwards is None:
        k = int(backwards[0])
        stats.first_backwards = (int(batch.index[k]), int(batch.line[k]), float(ts[k]))
    if stats.start is None:
        stats.start = float(ts[0])
    stats.end = float(ts[-1])
    stats.backwards_timestamps += back
    stats.frames += len(batch)
    stats.extended += int(np.count_nonzero(batch.ext))
    stats.error_frames += int(np.count_nonzero(batch.err))
    stats.remote_frames += int(np.count_nonzero(batch.rtr))
    stats.fd_frames += int(np.count_nonzero(batch.fd))
    return batch


class Row(NamedTuple):
    """One frame parsed by a line reader's per-line parser (the slow path: one per line)."""

    ts: float
    channel: str  # the channel's name as the log writes it
    can_id: int
    ext: bool
    rtr: bool
    err: bool
    fd: bool
    dlc: int
    data: bytes


def batches_of(stats: InputStats, rows: Iterable[tuple[int, Row]]) -> Iterator[FrameBatch]:
    """What every line-oriented reader does with its (line number, row) pairs: code the
    channel names, collect the frames, and hand out accounted batches as they fill."""
    builder = BatchBuilder()
    for line, (ts, channel, can_id, ext, rtr, err, fd, dlc, data) in rows:
        builder.add(ts, stats.channel_code(channel), can_id, ext=ext, rtr=rtr, err=err, fd=fd,
                    dlc=dlc, data=data, line=line)
        if builder.full and (batch := account(stats, builder.take())) is not None:
            yield batch
    if (batch := account(stats, builder.take())) is not None:
        yield batch
