"""Live checking: nmtcheck monitor, check --follow and the python-can Listener.

`Monitor` is imported lazily: `nmtcheck check` never pays for python-can.
"""

from __future__ import annotations

from typing import Any

__all__ = ["Monitor"]


def __getattr__(name: str) -> Any:
    if name == "Monitor":
        from nmtcheck.live.monitor import Monitor

        return Monitor
    raise AttributeError(f"module 'nmtcheck.live' has no attribute {name!r}")
