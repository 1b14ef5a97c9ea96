"""Everything a fleet worker needs, imported once before its first task (issue 25): the
checker, every reader's module, fsspec, pyarrow and its Parquet writer. The local pool's
fork server imports this module (its workers are forked from it, ready); `dask-local` has
its workers import it at start (`distributed.worker.preload`), and so can a cluster of
your own: `dask worker --preload nmtcheck.fleet.preload ...`. Without it each worker
imports all this at its first task, in the middle of the run.

pandas is not imported: a fleet task never needs it (see dataset.arrow_without_pandas).
"""

from __future__ import annotations

import importlib

import fsspec.implementations.local  # noqa: F401
import numpy.ma  # noqa: F401 - numpy.unique imports it at a check's first call
import pyarrow
import pyarrow.parquet  # noqa: F401

import nmtcheck.checks
import nmtcheck.engine
import nmtcheck.fleet.dataset
import nmtcheck.fleet.tasks  # noqa: F401
from nmtcheck.readers import FORMAT_MODULES

for _module in FORMAT_MODULES.values():  # light by design: their libraries load when used
    importlib.import_module(_module)
