"""How much freed memory a fleet worker keeps for its next log (glibc's malloc): used by
the local pool's workers (executors) and by the Dask workers a run uses (dask_workers)."""

from __future__ import annotations

import os

# glibc's mallopt parameters (malloc.h)
M_TRIM_THRESHOLD, M_TOP_PAD, M_MMAP_THRESHOLD = -1, -2, -3
WORKER_HEAP_BYTES = 64 << 20  # about what a check of one 1 M-frame log allocates at once
MMAP_THRESHOLD_MAX = 32 << 20  # the most a 64-bit glibc takes (HEAP_MAX_SIZE / 2)


def keep_freed_memory() -> None:
    """Have glibc keep what a pool worker frees for its next log instead of handing it
    back to the system: numpy's column arrays are large enough to be mapped and unmapped
    one by one, so each check faulted its memory in again (5,000 page faults per 1 M-frame
    log after the first), 4 % of its time here. The worker's peak memory is what it was;
    it is just not returned between logs. In nmtcheck's pool workers and in the Dask workers
    a run uses (dask_workers.WorkerSettings, where it also undoes Dask's
    MALLOC_TRIM_THRESHOLD_), only where the C library is glibc."""
    import ctypes

    try:
        if not os.confstr("CS_GNU_LIBC_VERSION"):
            return
        libc = ctypes.CDLL(None)
        # A fixed trim threshold also fixes the mmap threshold at its 128 kB default (it
        # stops adapting): every column array would then be mapped and unmapped, 4x
        # slower. So the rest only where the mmap threshold was taken.
        if libc.mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_MAX):
            libc.mallopt(M_TRIM_THRESHOLD, 4 * WORKER_HEAP_BYTES)
            libc.mallopt(M_TOP_PAD, WORKER_HEAP_BYTES)
    except (OSError, ValueError, AttributeError):  # not glibc: its defaults stay
        return
