"""Ctrl-C, SIGTERM and SIGHUP end a live session by setting an event, not by raising.

cli.main turns those signals into a `Terminated` exception, which may land anywhere,
also inside the tracker while it holds the session's lock. A session instead waits on
an event in the main thread; the handler here only sets it, so the session always ends
through its one orderly path (reports written, exit code as `check`'s).
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def ending_on_signals(stop: threading.Event) -> Iterator[list[int]]:
    """While inside, those signals set `stop`; yields the list of the signals received."""
    got: list[int] = []

    def handler(signum: int, _frame: object) -> None:
        got.append(signum)
        stop.set()

    old = {}
    if threading.current_thread() is threading.main_thread():
        for name in ("SIGINT", "SIGTERM", "SIGHUP"):
            if hasattr(signal, name):
                sig = getattr(signal, name)
                old[sig] = signal.signal(sig, handler)
    try:
        yield got
    finally:
        for sig, previous in old.items():
            signal.signal(sig, previous)


def ended_by(signals: list[int], otherwise: str) -> str:
    return f"interrupted ({signal.Signals(signals[0]).name})" if signals else otherwise
