"""Helpers of the binary readers (MCAP, MF4, pcap): numpy instead of a Python step per frame.

Binary logs are long runs of records of one size (every classic CAN frame of a
topic or capture looks alike), so records are found by checking whole runs of
equal-size records at once, fields are gathered from the byte buffer as
columns, and decoded frames are collected as column arrays that become
`FrameBatch` objects, never one Python object per frame.
"""

from __future__ import annotations

import numpy as np

from nmtcheck.readers.frames import BATCH_SIZE, FrameBatch
from nmtcheck.readers.stats import InputStats, account

_FIRST_WINDOW = 16


def field(rows: np.ndarray, start: int, size: int, kind: str = "u", big_endian: bool = False,
          ) -> np.ndarray:
    """An integer column taken from bytes `start:start+size` of every row of a uint8 matrix."""
    raw = np.ascontiguousarray(rows[:, start : start + size])
    return raw.view(f"{'>' if big_endian else '<'}{kind}{size}").reshape(-1)


def equal_records(arr: np.ndarray, pos: int, stride: int, end: int, key_off: int, key: bytes,
                  known: int = 1) -> int:
    """How many consecutive records of `stride` bytes start at `pos` (the first `known` are).

    A record belongs to the run while its bytes at `key_off` (its type and
    size fields) equal `key`; the run is checked in windows that grow fourfold.
    """
    limit = (end - pos) // stride
    if limit <= known:
        return known
    keys = np.lib.stride_tricks.as_strided(arr[pos + key_off :], shape=(limit, len(key)),
                                           strides=(stride, 1), writeable=False)
    key_arr = np.frombuffer(key, np.uint8)
    done = known
    window = _FIRST_WINDOW
    while done < limit:
        m = min(window, limit - done)
        ok = (keys[done : done + m] == key_arr).all(axis=1)
        if ok.all():
            done += m
            window *= 4
            continue
        return done + int(np.argmin(ok))
    return done


class RecordRuns:
    """Where the records of one buffer are: grouped by size, each with its row in file order.

    Records are compared in Python until `PROBE` equal ones in a row show a
    run, which is then followed with numpy (`equal_records`); shorter runs
    cost a list append per record, so buffers that interleave sizes (two
    topics, trimmed packets) stay cheap.
    """

    PROBE = 8

    def __init__(self) -> None:
        self.total = 0
        self._runs: dict[int, list[tuple[int, int, int]]] = {}  # size -> (first row, pos, count)
        self._lone: dict[int, tuple[list[int], list[int]]] = {}  # size -> (positions, rows)

    def add(self, buf: bytes, arr: np.ndarray, pos: int, stride: int, end: int, key_off: int,
            key_len: int) -> int:
        """Note the complete record at `pos` and the equal records after it; the next pos."""
        key = buf[pos + key_off : pos + key_off + key_len]
        count = 1
        nxt = pos + stride
        while (count < self.PROBE and nxt + stride <= end
               and buf[nxt + key_off : nxt + key_off + key_len] == key):
            count += 1
            nxt += stride
        if count == self.PROBE:
            run = equal_records(arr, pos, stride, end, key_off, key, count)
            self._runs.setdefault(stride, []).append((self.total, pos, run))
            self.total += run
            return pos + stride * run
        lone = self._lone.get(stride)
        if lone is None:
            lone = self._lone[stride] = ([], [])
        for k in range(count):
            lone[0].append(pos + k * stride)
            lone[1].append(self.total + k)
        self.total += count
        return nxt

    def claim(self) -> int:
        """A row for a record decoded outside the runs (the caller keeps its position)."""
        self.total += 1
        return self.total - 1

    def groups(self) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """(record size, record positions, rows) per size."""
        out = []
        for stride in {**self._runs, **self._lone}:
            starts = [p + stride * np.arange(k, dtype=np.int64)
                      for _r, p, k in self._runs.get(stride, [])]
            rows = [np.arange(r, r + k, dtype=np.int64) for r, _p, k in self._runs.get(stride, [])]
            if stride in self._lone:
                starts.append(np.array(self._lone[stride][0], np.int64))
                rows.append(np.array(self._lone[stride][1], np.int64))
            out.append((stride, np.concatenate(starts), np.concatenate(rows)))
        return out


def strided_rows(arr: np.ndarray, starts: np.ndarray, width: int) -> np.ndarray:
    """The `width` bytes at each start as a (n, width) uint8 matrix.

    Evenly spaced starts (one record size in a run) become a view on the
    buffer; otherwise the bytes are gathered.
    """
    n = len(starts)
    if n > 1:
        step = int(starts[1] - starts[0])
        if step >= width and int(starts[-1] - starts[0]) == step * (n - 1) and bool(
            (np.diff(starts) == step).all()
        ):
            base = arr[int(starts[0]) :]
            return np.lib.stride_tricks.as_strided(base, shape=(n, width), strides=(step, 1),
                                                   writeable=False)
    out: np.ndarray = arr[np.asarray(starts, np.int64)[:, None] + np.arange(width)]
    return out


def split_seconds(value: np.ndarray, per_second: int) -> np.ndarray:
    """Integer ticks (ns, µs…) as float seconds without losing precision on epoch times."""
    value = value.astype(np.uint64)
    whole = (value // np.uint64(per_second)).astype(np.float64)
    frac = (value % np.uint64(per_second)).astype(np.float64) / per_second
    out: np.ndarray = whole + frac
    return out


_KEEP_BYTES = np.where(np.arange(8)[None, :] < np.arange(65)[:, None], 0xFF, 0).astype(np.uint8)


def zero_beyond(data: np.ndarray, length: np.ndarray) -> None:
    """Clear the bytes of each row of an (n, 8) matrix at and after its length (in place)."""
    data &= _KEEP_BYTES[np.clip(length, 0, 64)]


class Frames:
    """Decoded frames of one capacity-bounded chunk, filled column by column, in file order.

    `keep` marks the rows that became frames; rows left out are records the
    reader skipped or ignored.
    """

    def __init__(self, n: int) -> None:
        self.ts = np.zeros(n, np.float64)
        self.chan = np.zeros(n, np.int32)
        self.can_id = np.zeros(n, np.uint32)
        self.ext = np.zeros(n, bool)
        self.rtr = np.zeros(n, bool)
        self.err = np.zeros(n, bool)
        self.fd = np.zeros(n, bool)
        self.dlc = np.zeros(n, np.int16)
        self.data = np.zeros((n, 8), np.uint8)
        self.keep = np.zeros(n, bool)

    COLUMNS = ("ts", "chan", "can_id", "ext", "rtr", "err", "fd", "dlc", "data", "keep")

    def subset(self, sel: np.ndarray | slice) -> Frames:
        """The rows `sel` (a mask, indices or a slice) as a new `Frames`."""
        part = Frames(0)
        for name in self.COLUMNS:
            setattr(part, name, getattr(self, name)[sel])
        return part

    @classmethod
    def concatenate(cls, parts: list[Frames]) -> Frames:
        whole = cls(0)
        for name in cls.COLUMNS:
            setattr(whole, name, np.concatenate([getattr(p, name) for p in parts]))
        return whole

    def put(self, i: int, ts: float, chan: int, can_id: int, ext: bool, rtr: bool, err: bool,
            fd: bool, dlc: int, data: bytes) -> None:
        """One row (the per-message path of decoders that return objects)."""
        self.ts[i] = ts
        self.chan[i] = chan
        self.can_id[i] = can_id
        self.ext[i] = ext
        self.rtr[i] = rtr
        self.err[i] = err
        self.fd[i] = fd
        self.dlc[i] = dlc
        head = data[:8]
        self.data[i, : len(head)] = np.frombuffer(head, np.uint8)
        self.keep[i] = True


class ChannelNames:
    """Channel names of one input, entered in `InputStats.channels` in the order in which
    their first frame comes (decoders fill a chunk group by group, not in file order)."""

    def __init__(self, stats: InputStats) -> None:
        self.stats = stats
        self._ids: dict[str, int] = {}
        self._names: list[str] = []
        self._codes = np.zeros(0, np.int32)  # provisional id -> stats code (-1: not yet)

    def provisional(self, name: str) -> int:
        """An id for `name` to put in `Frames.chan` until `finish`."""
        pid = self._ids.get(name)
        if pid is None:
            pid = self._ids[name] = len(self._names)
            self._names.append(name)
            self._codes = np.append(self._codes, np.int32(-1))
        return pid

    def finish(self, frames: Frames) -> None:
        """Turn the provisional ids of the kept rows into channel codes."""
        kept = frames.chan[frames.keep]
        if not len(kept):
            return
        pids, first = np.unique(kept, return_index=True)
        for pid in pids[np.argsort(first)].tolist():
            if self._codes[pid] < 0:
                self._codes[pid] = self.stats.channel_code(self._names[pid])
        frames.chan[frames.keep] = self._codes[kept]


class BatchCollector:
    """Collects `Frames` chunks and hands out `FrameBatch` objects of about BATCH_SIZE frames."""

    def __init__(self, stats: InputStats) -> None:
        self.stats = stats
        self._parts: list[Frames] = []
        self._n = 0
        self.next_index = 0

    @property
    def ready(self) -> bool:
        return self._n >= BATCH_SIZE

    def add(self, frames: Frames) -> None:
        kept = int(np.count_nonzero(frames.keep))
        if kept == 0:
            return
        if kept < len(frames.keep):
            frames = frames.subset(frames.keep)
        self._parts.append(frames)
        self._n += kept

    def take(self) -> FrameBatch | None:
        """The collected frames as one accounted batch (None when there are none)."""
        if self._n == 0:
            return None
        parts = self._parts

        def cat(name: str) -> np.ndarray:
            return np.concatenate([getattr(p, name) for p in parts])

        n = self._n
        batch = FrameBatch(
            ts=cat("ts"), chan=cat("chan"), can_id=cat("can_id"), ext=cat("ext"),
            rtr=cat("rtr"), err=cat("err"), fd=cat("fd"), dlc=cat("dlc"), data=cat("data"),
            index=np.arange(self.next_index, self.next_index + n, dtype=np.int64),
            line=np.zeros(n, np.int64),
        )
        self.next_index += n
        self._parts = []
        self._n = 0
        return account(self.stats, batch)
