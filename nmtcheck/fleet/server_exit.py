"""Imported last by the local pool's fork server, and only there (prestart.local_context):
when the run's driver ends, the server ends at once instead of tearing down numpy, pyarrow
and the checker module by module (40 ms). Until it has gone, a caller that captures the
command's output (CI, `subprocess.run(capture_output=True)`) waits for the end of the
server's copy of stderr. The server has nothing to flush or clean up; the workers it
forks end through os._exit and never run this."""

from __future__ import annotations

import atexit
import os

atexit.register(os._exit, 0)
