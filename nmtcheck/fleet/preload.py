"""Everything a fleet worker needs, imported once before its first task (issue 25): the
checker, every reader's module, pyarrow and its Parquet writer (and fsspec where a run
reads or writes anything but local files: prestart.local_context). The local pool's
fork server imports this module (its workers are forked from it, ready); `dask-local` has
its workers import it at start (`distributed.worker.preload`), and so can a cluster of
your own: `dask worker --preload nmtcheck.fleet.preload ...`. Without it each worker
imports all this at its first task, in the middle of the run.

pandas is not imported: a fleet task never needs it (see dataset.arrow_without_pandas).
"""

from __future__ import annotations

from nmtcheck.fleet.trace import mark

mark("preload_start")

import importlib  # noqa: E402

import numpy.ma  # noqa: E402,F401 - numpy.unique imports it at a check's first call
import pyarrow  # noqa: E402
import pyarrow.parquet  # noqa: E402,F401

import nmtcheck.checks  # noqa: E402
import nmtcheck.engine  # noqa: E402
import nmtcheck.fleet.comm_rows  # noqa: E402
import nmtcheck.fleet.dataset  # noqa: E402
import nmtcheck.fleet.tasks  # noqa: E402,F401
from nmtcheck.readers import FORMAT_MODULES  # noqa: E402

for _module in FORMAT_MODULES.values():  # light by design: their libraries load when used
    importlib.import_module(_module)

mark("preload")
