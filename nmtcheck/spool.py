"""Columns spilled to disk past a small memory budget: what keeps the decoder's memory
bounded however long the log is (the error-control spool, the node-frame chunk store), and
the scratch directory and signal handling that make sure the files go away."""

from __future__ import annotations

import contextlib
import contextvars
import os
import signal
import tempfile
import threading
from collections import OrderedDict
from collections.abc import Hashable, Iterator, Mapping
from typing import Any, BinaryIO

import numpy as np
from numpy.typing import DTypeLike

from nmtcheck.errors import NmtcheckError

STORE_BUDGET_BYTES = 8 << 20  # per store; past it chunks go to a temporary directory


_SIGNALS = {getattr(signal, name) for name in ("SIGTERM", "SIGINT", "SIGHUP")
            if hasattr(signal, name)}


# Where a check's temporary files go (spilled columns, a spooled MF4 stream, a fleet task's
# fetched logs); None: tempfile's default. A fleet task in a Dask worker sets the worker's
# own directory (fleet.tasks.worker_scratch), which Dask removes even after a crash.
SCRATCH: contextvars.ContextVar[str | None] = contextvars.ContextVar("nmtcheck_scratch",
                                                                    default=None)


def spill_directory(prefix: str = "nmtcheck-") -> tempfile.TemporaryDirectory[str]:
    """A temporary directory for spilled columns (or a worker pool's files), made with
    the terminating signals held back: one that came between making the directory and
    registering its clean-up would leave the directory behind (the CLI turns these
    signals into an exception)."""
    if not hasattr(signal, "pthread_sigmask"):
        return tempfile.TemporaryDirectory(prefix=prefix, dir=SCRATCH.get())
    held = signal.pthread_sigmask(signal.SIG_BLOCK, _SIGNALS)
    try:
        return tempfile.TemporaryDirectory(prefix=prefix, dir=SCRATCH.get())
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, held)


@contextlib.contextmanager
def removed_on_exit(tmp: tempfile.TemporaryDirectory[str]) -> Iterator[str]:
    """`with tmp` whose removal the terminating signals cannot cut short: a second Ctrl-C
    during the rmtree of a directory of fetched logs left most of them behind."""
    try:
        yield tmp.name
    finally:
        with signals_deferred():
            tmp.cleanup()


@contextlib.contextmanager
def signals_deferred() -> Iterator[None]:
    """The terminating signals that come during the block are handled after it, by their
    own handlers. Python runs handlers in the main thread whichever thread the signal
    reached (numpy's BLAS threads, a fetch pool), so a thread's signal mask is not
    enough; elsewhere than the main thread the block just runs."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    came: list[int] = []
    previous = {sig: signal.signal(sig, lambda signum, _frame: came.append(signum))
                for sig in _SIGNALS}
    try:
        yield
    finally:
        for sig, handler in previous.items():  # None: one set outside Python
            signal.signal(sig, signal.SIG_DFL if handler is None else handler)
        for sig in dict.fromkeys(came):
            signal.raise_signal(sig)


def write_spill(col: np.ndarray, f: BinaryIO | str, directory: str) -> None:
    """Append a column to a spill file; a full or unwritable temporary directory is the
    user's to fix (TMPDIR), so it ends the run with one line, not an internal error."""
    try:
        np.ascontiguousarray(col).tofile(f)
    except OSError as e:
        why = e.strerror or str(e)
        raise NmtcheckError(
            f"cannot write temporary data to {directory} ({why}; a full disk?): a long log "
            "spills about 40 bytes per frame there; set TMPDIR to a directory with more "
            "room") from None


class ColumnSpool:
    """Columns appended batch by batch and read back whole once: the error-control
    frames. Past a small budget they go to one file per column, so the decoder keeps
    no growing heap of small arrays (which glibc could not give back)."""

    def __init__(self, dtypes: Mapping[str, DTypeLike], budget: int = 4 << 20) -> None:
        self._dtypes = dtypes
        self._parts: dict[str, list[np.ndarray]] = {name: [] for name in dtypes}
        self._size = 0
        self._rows = 0
        self._budget = budget
        self._tmp: tempfile.TemporaryDirectory[str] | None = None

    @property
    def dtypes(self) -> Mapping[str, DTypeLike]:
        return self._dtypes

    def __len__(self) -> int:
        """Rows appended so far."""
        return self._rows

    def append(self, cols: dict[str, np.ndarray]) -> None:
        for name, col in cols.items():
            self._parts[name].append(col.astype(self._dtypes[name], copy=False))
            self._size += col.nbytes
        self._rows += len(next(iter(cols.values())))
        if self._size > self._budget:
            self._flush()

    def chunks(self, size: int) -> Iterator[dict[str, np.ndarray]]:
        """Every row so far, `size` rows at a time in order; the spool keeps them (it can
        be read again: `ec_compact.restore`)."""
        if self._tmp is not None:
            self._flush()
        else:  # small: one part per column, in memory
            self._parts = {name: [np.concatenate(parts) if parts else np.empty(
                0, self._dtypes[name])] for name, parts in self._parts.items()}
        for start in range(0, self._rows, size):
            count = min(size, self._rows - start)
            if self._tmp is None:
                yield {name: parts[0][start:start + count] for name, parts in self._parts.items()}
                continue
            yield {name: np.fromfile(os.path.join(self._tmp.name, name),
                                     np.dtype(self._dtypes[name]), count=count,
                                     offset=start * np.dtype(self._dtypes[name]).itemsize)
                   for name in self._dtypes}

    def _flush(self) -> None:
        if self._tmp is None:
            self._tmp = spill_directory()
        for name, parts in self._parts.items():
            with open(os.path.join(self._tmp.name, name), "ab") as f:
                for part in parts:
                    write_spill(part, f, self._tmp.name)
            parts.clear()
        self._size = 0

    def column(self, name: str) -> np.ndarray:
        """One whole column; the parts it was made of are released."""
        dtype = self._dtypes[name]
        parts = self._parts[name]
        if self._tmp is not None:  # the rest to the file too, then one read: no copy
            path = os.path.join(self._tmp.name, name)
            with open(path, "ab") as f:
                for part in parts:
                    write_spill(part, f, self._tmp.name)
            parts.clear()
            col = np.fromfile(path, dtype)
            os.remove(path)
            return col
        col = np.concatenate(parts) if parts else np.empty(0, dtype)
        parts.clear()
        return col

    def close(self) -> None:
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None


_Spilled = tuple[str, np.dtype, tuple[int, ...]]  # a column on disk: path, dtype, shape


class ChunkStore:
    """Append-only columnar chunks, kept in memory up to a budget, then on disk.

    A spilled chunk is one raw file per column (`ndarray.tofile`): no archive,
    no checksum, read back with `np.fromfile` at disk-cache speed.
    """

    def __init__(self, budget: int = STORE_BUDGET_BYTES) -> None:
        self._budget = budget
        self._in_memory = 0
        self._chunks: list[dict[str, np.ndarray] | dict[str, _Spilled]] = []
        self._ts_max: list[float] = []  # per chunk, to skip chunks that end before a moment
        self._tmp: tempfile.TemporaryDirectory[str] | None = None

    def __len__(self) -> int:
        """How many chunks it holds (0: nothing was stored)."""
        return len(self._chunks)

    @property
    def spilled(self) -> int:
        """How many chunks live on disk."""
        return sum(1 for c in self._chunks if isinstance(next(iter(c.values())), tuple))

    def append(self, **cols: np.ndarray) -> None:
        ts = cols.get("ts")
        self._ts_max.append(float(ts.max()) if ts is not None and ts.size else np.inf)
        size = sum(a.nbytes for a in cols.values())
        if self._in_memory + size <= self._budget:
            self._chunks.append(cols)
            self._in_memory += size
            return
        if self._tmp is None:
            self._tmp = spill_directory()
        spilled: dict[str, _Spilled] = {}
        for name, col in cols.items():
            path = os.path.join(self._tmp.name, f"chunk{len(self._chunks)}.{name}")
            write_spill(col, path, self._tmp.name)
            spilled[name] = (path, col.dtype, col.shape)
        self._chunks.append(spilled)

    def __iter__(self) -> Iterator[dict[str, np.ndarray]]:
        return self.reaching(-np.inf)

    def reaching(self, ts: float) -> Iterator[dict[str, np.ndarray]]:
        """The chunks holding a time >= ts (others are not even read back from disk)."""
        for chunk, ts_max in zip(self._chunks, self._ts_max, strict=True):
            if ts_max >= ts:
                yield {name: np.fromfile(col[0], col[1]).reshape(col[2])
                       if isinstance(col, tuple) else col for name, col in chunk.items()}

    def close(self) -> None:
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None
        self._chunks.clear()
        self._ts_max.clear()


class KeyedColumns:
    """Rows of columns grouped by key (each PDO stream's frames), appended in any order and
    read back whole, per key, as often as asked. Up to `budget` bytes stay in memory; past
    it every key's rows go to one file in a temporary directory (removed with the store, at
    exit or on a terminating signal) and come back through a cache of `cache_budget` bytes.
    So what is held is the budget, the cache and what a caller holds (one key's rows), not
    every key's: a log of 15 M PDO frames in 32 streams held 374 MB of them. The file is
    open only while it is written or read: `nmtcheck check` keeps every input's store until
    its reports are written, and a directory of many long logs would run out of file
    descriptors. Call `finish` after the last append. A pickle (a worker's result sent
    back) carries every key's rows."""

    def __init__(self, dtypes: Mapping[str, DTypeLike], budget: int = 2 * STORE_BUDGET_BYTES,
                 cache_budget: int = 64 << 20) -> None:
        self._dtypes = {name: np.dtype(t) for name, t in dtypes.items()}
        self._budget = budget
        self._cache_budget = cache_budget
        self._pending: dict[Hashable, list[tuple[np.ndarray, ...]]] = {}
        self._pending_bytes = 0
        self._blocks: dict[Hashable, list[tuple[int, int]]] = {}  # (offset, rows) on file
        self._tmp: tempfile.TemporaryDirectory[str] | None = None
        self._end = 0
        self._whole: dict[Hashable, tuple[np.ndarray, ...]] = {}  # all in memory
        self._cache: OrderedDict[Hashable, tuple[np.ndarray, ...]] = OrderedDict()
        self._cache_bytes = 0
        self._lock = threading.Lock()  # the cache is shared by whoever reads

    @property
    def spilled(self) -> bool:
        """Whether the rows went to the file."""
        return self._tmp is not None

    @property
    def held_bytes(self) -> int:
        """The bytes of rows the store itself holds now (in memory, cached or pending)."""
        return self._pending_bytes + self._cache_bytes + sum(
            a.nbytes for cols in self._whole.values() for a in cols)

    def append(self, key: Hashable, **cols: np.ndarray) -> None:
        part = tuple(np.asarray(cols[name], dtype) for name, dtype in self._dtypes.items())
        self._pending.setdefault(key, []).append(part)
        self._pending_bytes += sum(a.nbytes for a in part)
        if self._pending_bytes > self._budget:
            self._flush()

    def finish(self) -> None:
        """After the last append: everything to the file if any went there, else joined
        in memory."""
        if self._tmp is not None:
            self._flush()
            return
        for key, parts in self._pending.items():
            self._whole[key] = tuple(np.concatenate([p[i] for p in parts])
                                     for i in range(len(self._dtypes)))
        self._pending.clear()
        self._pending_bytes = 0

    @property
    def _path(self) -> str:
        assert self._tmp is not None
        return os.path.join(self._tmp.name, "rows")

    def _flush(self) -> None:
        if self._tmp is None:
            self._tmp = spill_directory()
        with open(self._path, "ab") as f:
            for key, parts in self._pending.items():
                rows = sum(len(p[0]) for p in parts)
                for i in range(len(self._dtypes)):
                    for p in parts:
                        write_spill(p[i], f, self._tmp.name)
                self._blocks.setdefault(key, []).append((self._end, rows))
                self._end += rows * sum(dt.itemsize for dt in self._dtypes.values())
        self._pending.clear()
        self._pending_bytes = 0

    def get(self, key: Hashable) -> tuple[np.ndarray, ...]:
        """Every row of `key` (none: empty columns), one array per column, in order."""
        found = self._whole.get(key)
        if found is not None:
            return found
        with self._lock:
            found = self._cache.get(key)
            if found is not None:
                self._cache.move_to_end(key)
                return found
            found = self._read(key)
            self._cache[key] = found
            self._cache_bytes += sum(a.nbytes for a in found)
            while self._cache_bytes > self._cache_budget and len(self._cache) > 1:
                _old, cols = self._cache.popitem(last=False)
                self._cache_bytes -= sum(a.nbytes for a in cols)
            return found

    def _read(self, key: Hashable) -> tuple[np.ndarray, ...]:
        blocks = self._blocks.get(key, [])
        out = tuple(np.empty(sum(n for _off, n in blocks), dt) for dt in self._dtypes.values())
        if not blocks:
            return out
        with open(self._path, "rb") as f:
            at = 0
            for offset, rows in blocks:
                f.seek(offset)
                for col in out:
                    buf = col[at:at + rows].data.cast("B")
                    got = 0
                    while got < len(buf):
                        n = f.readinto(buf[got:])
                        if not n:
                            raise NmtcheckError(f"{self._path}: temporary data ended early")
                        got += n
                at += rows
        return out

    def __getstate__(self) -> dict[str, Any]:
        keys = [*self._whole, *self._blocks]
        with self._lock:
            return {"dtypes": self._dtypes, "budget": self._budget,
                    "cache_budget": self._cache_budget,
                    "whole": {key: (self._whole[key] if key in self._whole
                                    else self._read(key)) for key in keys}}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(state["dtypes"], state["budget"], state["cache_budget"])  # type: ignore[misc]
        self._whole = state["whole"]
