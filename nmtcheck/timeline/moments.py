"""A moment as a message states it: seconds from the trace's first frame, or, in a log
without timestamps, the frame it stands for (its time is the frame index, SPEC §1): a
message never quotes a time computed from frame numbers."""

from __future__ import annotations


def at(ts: float, start: float, order_only: bool, digits: int = 6) -> str:
    """`1.460000 s` (from `start`), or `frame 75` (1-based) without timestamps."""
    if order_only:
        return f"frame {round(ts) + 1}"
    return f"{ts - start:.{digits}f} s"


def span(seconds: float, order_only: bool, digits: int = 3) -> str:
    """A duration: `1.900 s`, or `19 frames` without timestamps."""
    if order_only:
        n = round(seconds)
        return f"{n} frame{'' if n == 1 else 's'}"
    return f"{seconds:.{digits}f} s"
