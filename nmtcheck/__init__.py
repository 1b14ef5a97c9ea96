"""nmtcheck: offline CANopen NMT trace analysis and CiA 301 compliance checking.

The Python API is imported lazily, so that `nmtcheck check` on one log never pays for
pandas, pyarrow or python-can:

- `nmtcheck.check(paths, ...)` -> `Report` (findings, timeline and node statistics as
  pandas DataFrames), `nmtcheck.read_results(dir_or_url)` (the fleet's Parquet dataset);
- `nmtcheck.Monitor`: a python-can `Listener` that checks live traffic.
"""

from __future__ import annotations

from typing import Any

__version__ = "0.1.0"

_LAZY = {
    "check": "nmtcheck.api",
    "Report": "nmtcheck.api",
    "read_results": "nmtcheck.api",
    "Monitor": "nmtcheck.live",
}

__all__ = ["Monitor", "Report", "__version__", "check", "read_results"]


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'nmtcheck' has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(module), name)
