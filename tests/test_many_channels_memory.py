"""Memory of a log of many channels (issue 39 item 4: 200,000 channels took 1.5 GB).

A node of a frame or two used to hold some 40 numpy arrays (about 100 bytes each before
their data): 8 views of the error-control columns, 4 interval columns, and more. Now such
a node holds no array of its own: its error-control rows are read from the channel-wide
columns when looked at (`_FewEcRows`), its boot-ups-only intervals are bounds
(`FewIntervals`), and the empty things every node starts with are shared. These tests
bound the footprint per channel of a whole check, count each node's own arrays, and pin
the compact forms to what the full ones give.
"""

from __future__ import annotations

import gc
import pickle
import random
import subprocess
import sys
import tracemalloc
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import Checker
from test_many_channels import channels_log, random_log

from nmtcheck.engine import check_input, select_rules
from nmtcheck.processes import boot
from nmtcheck.protocol.nmt import BOOTUP, EC_KIND_NAMES, HEARTBEAT, REQUEST
from nmtcheck.settings.profiles import load_profile
from nmtcheck.timeline import intervals
from nmtcheck.timeline.model import NodeConfig, NodeModel
from nmtcheck.timeline.node_events import NO_EVENTS, NodeEvents
from nmtcheck.timeline.tables import (
    FEW_ROWS,
    EcTable,
    FewIntervals,
    IntervalTable,
    interval_columns,
    kind_stamp,
)


def _arrays(obj: Any, depth: int = 2) -> list[np.ndarray]:
    """The numpy arrays an object holds in its attributes, and those of the objects it
    holds (to `depth`)."""
    found: list[np.ndarray] = []
    values = list(vars(obj).values()) if hasattr(obj, "__dict__") else []
    for value in values:
        if isinstance(value, np.ndarray):
            found.append(value)
        elif depth and hasattr(value, "__dict__") and not isinstance(value, type):
            found.extend(_arrays(value, depth - 1))
    return found


def test_a_node_of_two_frames_holds_no_array_of_its_own(checker: Checker) -> None:
    """On the bench's many-channels shape (a boot-up then a TPDO per channel), no node
    holds an array that no other node holds too (before: 12 each, 8 of them views of
    the error-control columns and 4 interval columns)."""
    res = checker.run(channels_log(500))
    nodes = list(res.model.nodes())
    assert len(nodes) == 500
    holders: dict[int, int] = {}
    for m in nodes:
        for a in {id(a): a for a in _arrays(m)}.values():
            holders[id(a)] = holders.get(id(a), 0) + 1
    # (a read-only array is one of the shared constants, even where one node uses it)
    own = [sum(1 for k, a in {id(a): a for a in _arrays(m)}.items()
               if holders[k] == 1 and a.flags.writeable) for m in nodes]
    assert max(own) == 0, own[:10]
    # what they hold still reads as before
    m = nodes[1]
    assert type(m.ec).__name__ == "_FewEcRows" and isinstance(m.intervals, FewIntervals)
    assert m.ec.kind.tolist() == [BOOTUP] and len(m.ec) == 1 and m.ec[0].kind == "bootup"
    assert [iv.state for iv in m.intervals] == ["UNKNOWN", "PRE-OPERATIONAL"]


def _kept_per_channel(log: Path, channels: int) -> tuple[float, float]:
    profile = load_profile("default")
    rules = select_rules(profile, [], [])
    check_input(str(log), 0, profile, rules)  # imports and one-time caches out of the way
    gc.collect()
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        res = check_input(str(log), 0, profile, rules)
        gc.collect()
        kept, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert len(list(res.model.nodes())) == channels and not res.findings
    return (kept - before) / channels, (peak - before) / channels


def test_the_footprint_of_a_channel_of_two_frames_is_bounded(tmp_path: Path) -> None:
    """What a whole check (model, boot processes, findings) keeps of 10,000 channels of
    two frames, and its peak, by tracemalloc per channel: 4.6 KB kept and 5.5 KB at the
    peak before (2026-12-08, Python 3.11, numpy 2.4), 2.5 and 3.2 KB after."""
    log = tmp_path / "channels.log"
    log.write_text(channels_log(10_000))
    # in a fresh interpreter: what other tests did in this one (objects unpickled in
    # another attribute order give the model classes' instances unshared dicts) counts
    # nothing here
    code = ("import sys; sys.path[:0] = sys.argv[2:]; from pathlib import Path; "
            "from test_many_channels_memory import _kept_per_channel; "
            "print(*_kept_per_channel(Path(sys.argv[1]), 10_000))")
    here = str(Path(__file__).resolve().parent)
    out = subprocess.run([sys.executable, "-c", code, str(log), here], capture_output=True,
                         text=True, check=True).stdout.split()
    kept, peak = float(out[0]), float(out[1])
    assert kept < 3_000 and peak < 4_000, (kept, peak)


def _columns(n: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    return {"ts": np.sort(rng.random(n)) * 100, "idx": np.arange(n, dtype=np.int64) * 3,
            "line": np.arange(n, dtype=np.int64) * 3 + 1, "rtr": rng.random(n) < 0.2,
            "dlc": rng.integers(0, 3, n).astype(np.int16),
            "value": rng.integers(0, 256, n).astype(np.uint8),
            "kind": rng.integers(0, len(EC_KIND_NAMES), n).astype(np.int8),
            "stale": np.zeros(n, bool)}


def test_few_rows_read_and_write_as_views_do() -> None:
    """A node's few rows (`_FewEcRows`) give the columns, frames, positions and counts
    the kept views give, writes reach the channel-wide columns as through a view, an
    assigned kind column is kept, and it pickles."""
    rng = np.random.default_rng(7)
    cols = _columns(200, rng)
    shared = {k: v.copy() for k, v in cols.items()}  # the full views' own copy
    names = ("ts", "idx", "line", "rtr", "dlc", "value", "kind", "stale")
    checked = 0
    for lo in range(0, 190, 3):
        rows = slice(lo, lo + int(rng.integers(0, FEW_ROWS + 1)))
        few = EcTable.view(cols, rows, cols["kind"], cols["stale"])
        full = EcTable.view(shared, rows, shared["kind"], shared["stale"])
        assert type(few).__name__ == "_FewEcRows" and type(full).__name__ == "_FewEcRows"
        full = EcTable(*(shared[k][rows] for k in names[:6]))
        full.kind, full.stale = shared["kind"][rows], shared["stale"][rows]
        assert len(few) == len(full)
        for name in names:
            assert np.array_equal(getattr(few, name), getattr(full, name)), name
        assert list(few) == list(full) and few.runs is None and few.guard_runs is None
        if len(few):  # frames read from the channel-wide columns stay within the rows
            assert few[-1] == full[-1] and few[-len(few)] == full[-len(full)]
        for outside in (len(few), -len(few) - 1):
            with pytest.raises(IndexError):
                few[outside]
        for kind in (BOOTUP, HEARTBEAT, REQUEST):
            assert np.array_equal(few.where(kind), full.where(kind))
            assert few.count(kind) == full.count(kind)
        assert np.array_equal(few.code, full.code)
        if len(few):
            mid = int(few.idx[len(few) // 2])
            assert few.after(mid) == full.after(mid)
            few.stale[0] = True  # as `mark_power_on_bootups` does through a view
            assert cols["stale"][rows.start]
        checked += 1
    assert checked > 50
    few = EcTable.view(cols, slice(10, 12), cols["kind"], cols["stale"])
    stamp = kind_stamp(few)
    assert few.kind is not few.kind and kind_stamp(few) is stamp  # a view made per read
    new = np.full(2, HEARTBEAT, np.int8)
    few.kind = new  # `classify` replaces the kinds
    assert few.kind is new and kind_stamp(few) is new
    assert [f.kind for f in few] == ["heartbeat"] * 2
    back = pickle.loads(pickle.dumps(few))
    assert np.array_equal(back.ts, few.ts) and np.array_equal(back.kind, new)
    # a table of more rows keeps its views as before
    big = EcTable.view(cols, slice(0, FEW_ROWS + 1), cols["kind"], cols["stale"])
    assert type(big) is EcTable and "ts" in vars(big)


def test_kind_counts_follow_a_new_classification() -> None:
    """`kind_counts` and `heartbeat_pairs` are cached per classification, for a table of
    few rows and one of views alike: reading a column again does not count again,
    assigning new kinds does."""
    cols = _columns(20, np.random.default_rng(3))
    cols["kind"][:] = HEARTBEAT
    for size in (FEW_ROWS, FEW_ROWS + 3):
        m = NodeModel(0, "c0", 5, NodeConfig())
        m.ec = EcTable.view(cols, slice(2, 2 + size), cols["kind"], cols["stale"])
        first = m.kind_counts()
        assert first[HEARTBEAT] == size and m.kind_counts() is first
        a, _b = m.heartbeat_pairs()
        assert a.tolist() == list(range(size - 1)) and m.heartbeat_pairs()[0] is a
        new = np.full(size, HEARTBEAT, np.int8)
        new[0], new[-1] = BOOTUP, REQUEST
        m.ec.kind = new
        assert m.kind_counts()[HEARTBEAT] == size - 2 and m.kind_counts()[BOOTUP] == 1
        assert m.heartbeat_pairs()[0].tolist() == list(range(1, size - 2))


def test_few_intervals_are_the_walks_and_join_in_order(checker: Checker) -> None:
    """Boot-ups-only intervals as bounds read as the full walk's columns, and
    `interval_columns` joins compact and full tables node after node in order."""
    res = checker.run(random_log(random.Random(4), channels=60, frames=500))
    tables = [m.intervals for m in res.model.nodes()]
    assert any(isinstance(t, FewIntervals) for t in tables)
    assert any(not isinstance(t, FewIntervals) and len(t) for t in tables)
    for m in res.model.nodes():
        if isinstance(m.intervals, FewIntervals):
            full = intervals.node_intervals(m, res.model.start, res.model.end,
                                            res.model.timeline.obey_s, {})
            assert list(m.intervals) == list(full) and len(m.intervals) == len(full)
            assert not m.intervals.state.flags.writeable  # shared by nodes
    tables.append(IntervalTable.empty())
    lengths, start, end, state = interval_columns(tables)
    assert lengths.tolist() == [len(t) for t in tables]
    assert np.array_equal(start, np.concatenate([t.start for t in tables]))
    assert np.array_equal(end, np.concatenate([t.end for t in tables]))
    assert np.array_equal(state, np.concatenate([t.state for t in tables]))
    lengths2, start2, end2, state2 = interval_columns(tables, with_end=False)
    assert np.array_equal(lengths2, lengths) and np.array_equal(start2, start)
    assert np.array_equal(state2, state) and not len(end2)
    start2[:] = -1.0  # the caller's own: no table changes
    assert np.array_equal(start, np.concatenate([t.start for t in tables]))


def test_the_shared_empty_events_and_spans_are_never_written(checker: Checker) -> None:
    """Nodes without EMCY, SDO write or boot process share one empty `NodeEvents` and
    one empty `Spans`; after random checks both are still empty, and the shared events
    refuse a write."""
    for seed in range(3):
        res = checker.run(random_log(random.Random(seed), channels=40, frames=600))
        shared = [m for m in res.model.nodes() if m.events is NO_EVENTS]
        own = [m for m in res.model.nodes() if m.events is not NO_EVENTS]
        assert shared and own and all(m.events for m in own if len(m.events.emcy))
    assert not NO_EVENTS and not len(NO_EVENTS.emcy) and not list(NO_EVENTS)
    with pytest.raises(AttributeError):
        NO_EVENTS.emcy = NodeEvents().emcy
    assert len(boot._NO_SPANS) == 0 and boot._NO_SPANS.last_step == []
    m = NodeModel(0, "c0", 5, NodeConfig())
    assert m.events is NO_EVENTS and m.own_events() is m.events is not NO_EVENTS
