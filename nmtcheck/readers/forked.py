"""Parsing text blocks in a forked worker process, next to the reading one.

Parse threads share the GIL, which every numpy call of a block's parse takes
back: two of them keep only about 1.3 of two cores busy (less for ASC, whose
short lines mean many small calls). A forked worker has a GIL of its own. It is
forked once the reader has learned the file's layout, so it parses exactly as
the reader would; blocks go to it, and its columns come back, through shared
memory. The reading process keeps the worker's queue full and parses a block
itself only when it would otherwise wait for the worker, so the work splits
itself between the two whatever the caller does with the frames. Results come
out strictly in file order.
"""

from __future__ import annotations

import contextlib
import mmap
import os
import pickle
import signal
import sys
import threading
import time
import warnings
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Generic, TypeVar

import numpy as np

if TYPE_CHECKING:  # multiprocessing is imported where a log is large enough to fork for
    from multiprocessing.connection import Connection

T = TypeVar("T")
Chunk = tuple[np.ndarray, int]  # a padded buffer and how many bytes of lines it holds
Layout = list[tuple[str, tuple[int, ...]]]  # dtype and shape of each array in a slot
SLOTS = 3  # blocks queued at the worker
LOOKAHEAD = 6  # blocks read ahead (queued at the worker or parsed here) at most
OUT_BYTES = 16 << 20  # room for one block's parsed columns; a block with more is parsed here


# a thread that holds its only lock across a fork (os.register_at_fork: the command
# line's progress ticker), so it cannot hold one mid-use in the worker
PAUSED_AT_FORK = "nmtcheck-progress"


def available() -> bool:
    """Forking is safe: Linux, no other thread (that could hold a lock across the fork)
    but one paused at fork, and not inside a daemonic multiprocessing worker."""
    mp = sys.modules.get("multiprocessing")  # a multiprocessing worker has imported it
    others = [t for t in threading.enumerate()
              if t is not threading.current_thread() and t.name != PAUSED_AT_FORK]
    return (sys.platform == "linux" and not others
            and not (mp is not None and mp.current_process().daemon))


def _put(arrays: list[np.ndarray], box: mmap.mmap) -> Layout | None:
    """Copy the arrays one after another into `box`; their dtypes and shapes, None if they
    do not fit."""
    if sum(a.nbytes for a in arrays) > len(box):
        return None
    at = 0
    for a in arrays:
        np.frombuffer(box, np.uint8, a.nbytes, at)[:] = np.ascontiguousarray(a).reshape(
            -1).view(np.uint8)
        at += a.nbytes
    return [(a.dtype.str, a.shape) for a in arrays]


def _take(box: mmap.mmap, layout: Layout) -> list[np.ndarray]:
    """Copies of the arrays `_put` wrote (the slot is reused)."""
    out, at = [], 0
    for dtype, shape in layout:
        dt = np.dtype(dtype)
        count = int(np.prod(shape, dtype=np.int64))
        out.append(np.frombuffer(box, dt, count, at).reshape(shape).copy())
        at += count * dt.itemsize
    return out


@dataclass
class _Ticket(Generic[T]):
    """One block, in file order: parsed here (`result`), or queued at the worker (`slot`)."""

    chunk: Chunk
    slot: int | None = None
    result: T | None = None


class ForkedParser(Generic[T]):
    """job(chunk) for chunks in file order, split between this process and a forked worker.

    `split` turns a job's result into arrays, `join` rebuilds the result from the chunk
    and those arrays (what comes back from the worker)."""

    def __init__(self, job: Callable[[Chunk], T], split: Callable[[T], list[np.ndarray]],
                 join: Callable[[Chunk, list[np.ndarray]], T], in_bytes: int) -> None:
        self._job, self._split, self._join = job, split, join
        self._inbox = [mmap.mmap(-1, in_bytes) for _ in range(SLOTS)]  # shared with the worker
        self._outbox = [mmap.mmap(-1, OUT_BYTES) for _ in range(SLOTS)]
        self._free = list(range(SLOTS))
        self._alive = True
        from multiprocessing import Pipe

        jobs_reader, self._jobs = Pipe(duplex=False)
        self._done, done_writer = Pipe(duplex=False)
        # Python 3.12+ warns of any OS thread, numpy's BLAS pool too (which handles fork);
        # Python threads were ruled out by available().
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", DeprecationWarning)
            self._pid = os.fork()
        if self._pid == 0:  # the worker: it leaves by os._exit, so nothing buffered is flushed
            try:
                signal.signal(signal.SIGINT, signal.SIG_IGN)  # the reading process stops it
                for name in ("SIGTERM", "SIGHUP"):  # not the reading process's handlers
                    signal.signal(getattr(signal, name), signal.SIG_DFL)
                self._jobs.close()
                self._done.close()
                self._serve(jobs_reader, done_writer)
            finally:
                os._exit(0)
        jobs_reader.close()
        done_writer.close()

    def _serve(self, jobs: Connection, done: Connection) -> None:
        """Parse each chunk sent, the result's arrays into the slot's outbox."""
        while True:
            try:
                slot, size, n = jobs.recv()
            except EOFError:
                return
            buf = np.frombuffer(self._inbox[slot], np.uint8, n)
            try:
                layout = _put(self._split(self._job((buf, size))), self._outbox[slot])
            except Exception:  # the reading process parses this block again and sees why
                layout = None
            done.send_bytes(pickle.dumps(layout))

    def map(self, chunks: Iterator[Chunk]) -> Iterator[T]:
        """job(chunk) for each chunk, in order: the worker's queue kept full, a block parsed
        here only where the oldest one is still at the worker (or the worker is gone)."""
        pending: deque[_Ticket[T]] = deque()
        more = True
        try:
            while True:
                while more and self._alive and self._free:
                    more = self._read(chunks, pending, here=False)
                if pending and (pending[0].slot is None or not self._alive
                                or self._done.poll()):
                    yield self._finish(pending.popleft())
                elif more and len(pending) < LOOKAHEAD:
                    more = self._read(chunks, pending, here=True)
                elif pending:
                    yield self._finish(pending.popleft())  # wait for the worker
                else:
                    return
        finally:
            self.close()

    def _read(self, chunks: Iterator[Chunk], pending: deque[_Ticket[T]], here: bool) -> bool:
        """The next chunk into `pending`, queued at the worker or parsed here; False at the
        end of the input."""
        if (chunk := next(chunks, None)) is None:
            return False
        pending.append(_Ticket(chunk, result=self._job(chunk)) if here else self._submit(chunk))
        return True

    def _submit(self, chunk: Chunk) -> _Ticket[T]:
        """Queue the chunk at the worker, or parse it here if it is larger than a slot (a
        block that ends in a carried-over line of up to 1 MiB)."""
        buf, size = chunk
        if buf.shape[0] > len(self._inbox[0]):
            return _Ticket(chunk, result=self._job(chunk))
        slot = self._free[-1]
        np.frombuffer(self._inbox[slot], np.uint8, buf.shape[0])[:] = buf
        try:
            self._jobs.send((slot, size, buf.shape[0]))
        except OSError:  # the worker is gone: this process parses on alone
            self._alive = False
            return _Ticket(chunk, result=self._job(chunk))
        self._free.pop()
        return _Ticket(chunk, slot)

    def _finish(self, ticket: _Ticket[T]) -> T:
        if ticket.slot is None:
            return ticket.result  # type: ignore[return-value]
        layout = None
        if self._alive:
            try:
                layout = pickle.loads(self._done.recv_bytes())
            except (EOFError, OSError):  # the worker is gone: this process parses on alone
                self._alive = False
        self._free.append(ticket.slot)
        if layout is None:  # no worker, no room for the columns, or an error: parse here
            return self._job(ticket.chunk)
        return self._join(ticket.chunk, _take(self._outbox[ticket.slot], layout))

    def close(self) -> None:
        """Stop the worker (it exits when its queue closes) and wait for it."""
        if self._pid <= 0:
            return
        self._jobs.close()
        self._done.close()
        deadline = time.monotonic() + 5
        with contextlib.suppress(ChildProcessError):  # already reaped (SIGCHLD ignored)
            while os.waitpid(self._pid, os.WNOHANG) == (0, 0):
                if time.monotonic() > deadline:
                    os.kill(self._pid, signal.SIGKILL)
                    os.waitpid(self._pid, 0)
                    break
                time.sleep(0.001)
        self._pid = 0
