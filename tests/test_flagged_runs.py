"""`flagged_runs` (checks/base.py) looks only at the flagged items where no join links a
flagged item to an unflagged one (every rule's joins): the same runs as `run_starts`
filtered, for every kind of join the rules make and for joins that break that rule."""

from __future__ import annotations

import numpy as np

from nmtcheck.checks.base import flagged_runs, run_starts


def _filtered(join: np.ndarray, flagged: np.ndarray) -> list[tuple[int, int]]:
    first, length = run_starts(join)
    keep = flagged[first] if len(first) else np.zeros(0, bool)
    return list(zip(first[keep].tolist(), length[keep].tolist(), strict=True))


def test_flagged_runs_are_the_filtered_runs() -> None:
    rng = np.random.default_rng(7)
    for trial in range(6000):
        n = int(rng.integers(0, 30))
        values = rng.integers(0, 3, n)
        flagged = values != 0
        join = np.zeros(n, bool)
        if n > 1:
            if trial % 3 == 0:  # D002, Y004: both items flagged
                join[1:] = flagged[1:] & flagged[:-1]
            elif trial % 3 == 1:  # Y002, E rules: the same defect
                join[1:] = values[1:] == values[:-1]
            else:  # any join at all (join[0] set too): the general path
                join = rng.random(n) < 0.5
        assert flagged_runs(join, flagged) == _filtered(join, flagged), (join, flagged)


def test_a_clean_stream_makes_no_run_arrays() -> None:
    """Nothing flagged among 5 M items: no run is kept, and none is made."""
    join = np.zeros(5_000_000, bool)
    assert flagged_runs(join, join) == []
    flagged = np.zeros(5_000_000, bool)
    flagged[[10, 11, 4_000_000]] = True
    join[11] = True
    assert flagged_runs(join, flagged) == [(10, 2), (4_000_000, 1)]
