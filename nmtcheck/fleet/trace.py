"""Phase timestamps of a fleet run, off unless NMTCHECK_FLEET_TRACE names a file (issue 25):
bench/fleet_scaling.py --phases reads them to say where a run's fixed cost goes, from
the driver's and each worker's side. Every process of the run (driver, fork server,
workers) appends one JSON line per mark; O_APPEND keeps lines of processes whole.
"""

from __future__ import annotations

import json
import os
import time
from typing import Any

TRACE_ENV = "NMTCHECK_FLEET_TRACE"


def mark(phase: str, **extra: Any) -> None:
    """`phase` reached now in this process: wall time, this process's CPU time, its pid."""
    path = os.environ.get(TRACE_ENV)
    if not path:
        return
    line = json.dumps({"phase": phase, "pid": os.getpid(), "t": time.time(),
                       "cpu": time.process_time(), **extra})
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, (line + "\n").encode())
    finally:
        os.close(fd)
