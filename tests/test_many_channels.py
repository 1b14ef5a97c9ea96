"""Logs of many channels and many small nodes (issue 24 item 2).

A node of a frame or two costs the same fixed work in every stage, so the timeline, the
rules and the boot stage take shortcuts for the common trivial node and match every
node at once where they can (S001-S003). These tests pin each shortcut to the full path
it stands for, on random logs of many channels, and the whole check of 40,000 channels
(bench/pathological.py `channels`) to its verdicts and to linear time.
"""

from __future__ import annotations

import gc
import random
import time
from dataclasses import astuple
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import Checker

from nmtcheck.checks import state
from nmtcheck.engine import check_input, select_rules
from nmtcheck.errors import UsageError
from nmtcheck.processes import boot_records
from nmtcheck.processes.sdo_transfers import SdoSpool
from nmtcheck.protocol.nmt import EPS, OFFLINE, OPERATIONAL, PRE_OPERATIONAL, STATE_INDEX, STOPPED
from nmtcheck.reporters import streamer
from nmtcheck.results import InputResult
from nmtcheck.settings.profiles import load_profile
from nmtcheck.timeline import build as timeline
from nmtcheck.timeline import error_control, intervals
from nmtcheck.timeline.decode import KIND_EMCY, KIND_RPDO, KIND_SDO_TX, KIND_TPDO
from nmtcheck.timeline.model import InputModel, NodeConfig, NodeModel
from nmtcheck.timeline.node_events import EmcyTable, SdoEventTable, WriteTable
from nmtcheck.timeline.tables import (
    CommandTable,
    EcTable,
    FewIntervals,
    IntervalTable,
    NmtTable,
    shared_empty,
)


def channels_log(channels: int) -> str:
    """bench/pathological.py's `channels` shape: on every channel a boot-up of node 5,
    then, 40 ms x channels later, a TPDO of node 5."""
    return "".join(f"({1_700_000_000 + i / 1000:.6f}) c{i % channels} "
                   f"{'705#00' if i < channels else '185#01'}\n" for i in range(2 * channels))


def random_log(rng: random.Random, channels: int = 30, frames: int = 1500) -> str:
    """Several channels of a few nodes each: boot-ups, heartbeats of every state (and
    silences long enough for a timeout), NMT commands direct and broadcast, TPDOs,
    RPDOs, SDO responses and EMCYs, sometimes with the time going back."""
    lines = []
    t = 1_700_000_000.0
    for _ in range(frames):
        t += rng.choice((0.001, 0.003, 0.05, 0.2, 0.5, 2.5)) if rng.random() > 0.02 else -0.3
        ch = f"c{rng.randrange(channels)}"
        n = rng.randint(1, 4)
        r = rng.random()
        if r < 0.12:
            frame = f"{0x700 + n:03X}#00"
        elif r < 0.45:
            frame = f"{0x700 + n:03X}#{rng.choice(('05', '7F', '04', '05', '85')):s}"
        elif r < 0.55:
            cs = rng.choice(("01", "02", "80", "81", "82"))
            frame = f"000#{cs}{rng.choice((0, n, n)):02X}"
        elif r < 0.75:
            frame = f"{0x180 + n:03X}#01"
        elif r < 0.85:
            frame = f"{0x200 + n:03X}#02"
        elif r < 0.93:
            frame = f"{0x580 + n:03X}#4B00100000000000"
        else:
            frame = f"{0x080 + n:03X}#0010010000000000"
        lines.append(f"({t:.6f}) {ch} {frame}\n")
    return "".join(lines)


def _reference_scan(model: InputModel, kinds: tuple[int, ...], states: tuple[str, ...],
                    grace_s: float, grace_from: str | None, unproven: bool = False
                    ) -> list[tuple[NodeModel, int, state._Run]]:
    """`state._scan` as it was, node by node (the seventh session's code)."""
    by_key = {m.key: m for cm in model.channels for m in cm.nodes.values()}
    offline = STATE_INDEX[OFFLINE]
    grace_code = STATE_INDEX[grace_from] if grace_from else -2
    wanted = np.asarray([STATE_INDEX[s] for s in states], np.int8)
    found: dict[tuple[int, int], state._Run] = {}
    cand = model.sent_while(states, kinds)  # the cached candidates of the rule run
    sel = np.flatnonzero(np.isin(cand.kind, kinds))
    keys = cand.key[sel]
    order = np.argsort(keys, kind="stable")
    uniq, first = np.unique(keys[order], return_index=True)
    bounds = np.append(first, len(order))
    for g, key in enumerate(uniq.tolist()):
        m = by_key.get(key)
        if m is None:
            continue
        starts = m.interval_starts()
        codes = m.intervals.state
        since = np.full(len(codes), -np.inf)
        for i in range(len(codes)):
            if grace_from is None:
                back = i >= 2 and codes[i - 1] == offline and codes[i - 2] == codes[i]
                since[i] = since[i - 2] if back else starts[i]
            elif i >= 1 and codes[i - 1] == grace_code:
                since[i] = starts[i]
            elif i >= 1 and codes[i - 1] != offline:
                since[i] = since[i - 1]
        rows = sel[order[bounds[g]:bounds[g + 1]]]
        ts = cand.ts[rows]
        iv = np.maximum(np.searchsorted(starts, ts, side="right") - 1, 0)
        bad = np.isin(codes[iv], wanted)
        bad &= ~((ts - since[iv]) <= grace_s + EPS)
        if unproven and m.unproven_spans:
            spans = np.asarray(m.unproven_spans, np.float64)
            span = np.searchsorted(spans[:, 0], ts, side="right") - 1
            bad &= ~((span >= 0) & (ts <= spans[np.maximum(span, 0), 1] + EPS))
        for j in np.flatnonzero(bad).tolist():
            row = rows[j]
            k = (key, int(iv[j]))
            run = found.get(k)
            if run is None:
                found[k] = state._Run(float(cand.ts[row]), int(cand.idx[row]),
                                      int(cand.line[row]), int(cand.can_id[row]),
                                      int(cand.kind[row]), 1)
            else:
                run.count += 1
    return [(by_key[key], iv, run) for (key, iv), run in sorted(
        found.items(), key=lambda kv: kv[1].idx)]


SCANS = [  # S001, S002, S003 as the rules call `_scan`, and with other grace periods
    ((KIND_TPDO,), (PRE_OPERATIONAL, STOPPED), 0.005, OPERATIONAL, True),
    ((KIND_TPDO,), (PRE_OPERATIONAL, STOPPED), 0.3, OPERATIONAL, False),
    ((KIND_RPDO,), (PRE_OPERATIONAL, STOPPED), 0.0, None, False),
    ((KIND_SDO_TX, KIND_EMCY), (STOPPED,), 0.005, None, False),
    ((KIND_SDO_TX, KIND_EMCY, KIND_TPDO), (STOPPED, PRE_OPERATIONAL), 0.6, None, True),
]


def _runs(found: list[tuple[NodeModel, int, state._Run]]) -> list[tuple[object, ...]]:
    return [(m.key, iv, astuple(run)) for m, iv, run in found]


def test_scan_matches_the_node_by_node_walk(checker: Checker) -> None:
    """S001-S003 match every node's intervals at once; on random logs of 30 channels the
    runs they find (node, interval, first frame, count, in file order) are the walk's,
    with some found and some nodes silent in each."""
    hits = silent = 0
    for seed in range(8):
        model = checker.run(random_log(random.Random(seed))).model
        for args in SCANS:
            got, want = _runs(state._scan(model, *args)), _runs(_reference_scan(model, *args))
            assert got == want, (seed, args)
            hits += len(got)
            silent += sum(1 for m in model.nodes()) - len({k for k, _, _ in got})
    assert hits > 100 and silent > 100, (hits, silent)


def test_grace_since_matches_the_walk_on_every_interval_pattern() -> None:
    """The grace periods' starts, found for all nodes at once, on random state sequences
    rich in OFFLINE returns (the walk's chains of two steps back)."""
    rng = random.Random(1)
    pool = [STATE_INDEX[s] for s in (OFFLINE, OPERATIONAL, PRE_OPERATIONAL, STOPPED)]
    starts, states = [], []
    for _ in range(300):
        n = rng.randint(1, 9)
        starts.append(np.cumsum(np.asarray([rng.random() for _ in range(n)])))
        states.append(np.asarray([rng.choice(pool) for _ in range(n)], np.int8))
    # tables of both kinds, as the timeline makes them: the join must not mix them up
    ivs = state._Intervals([
        FewIntervals((*st.tolist(), float(st[-1]) + 1.0), codes, codes) if k % 2 else
        IntervalTable(st, st, codes, codes)
        for k, (st, codes) in enumerate(zip(starts, states, strict=True))])
    for grace in (None, *pool):
        got = ivs.grace_since(grace)
        want = []
        for st, codes in zip(starts, states, strict=True):
            since = np.full(len(codes), -np.inf)
            for i in range(len(codes)):
                if grace is None:
                    back = i >= 2 and codes[i - 1] == pool[0] and codes[i - 2] == codes[i]
                    since[i] = since[i - 2] if back else st[i]
                elif i >= 1 and codes[i - 1] == grace:
                    since[i] = st[i]
                elif i >= 1 and codes[i - 1] != pool[0]:
                    since[i] = since[i - 1]
            want.append(since)
        assert np.array_equal(got, np.concatenate(want)), grace


def _trivial_nodes(res: InputResult) -> list[NodeModel]:
    return [m for m in res.model.nodes() if intervals.only_bootups(m)]


def test_trivial_node_shortcuts_match_the_full_paths(checker: Checker) -> None:
    """A node of boot-ups only: its intervals, unproven spans, measured period and
    heartbeat pairs are what the full paths give (the walk, the self-start search, the
    segment medians), on random logs and on the many-channels shape."""
    logs = [random_log(random.Random(seed), channels=60, frames=400) for seed in range(6)]
    trivial = 0
    for text in [*logs, channels_log(50)]:
        res = checker.run(text)
        start, end, obey = res.model.start, res.model.end, res.model.timeline.obey_s
        for m in _trivial_nodes(res):
            trivial += 1
            full = intervals.node_intervals(m, start, end, obey, {})
            for name in ("start", "end", "state", "source"):
                assert np.array_equal(getattr(m.intervals, name), getattr(full, name))
            spans = m.unproven_spans
            assert not error_control._self_start_queries(m, end) and m.unproven_spans == spans
            a, b = m.heartbeat_pairs()
            assert not len(a) and not len(b) and m.heartbeat_gaps().count == 0
            bounds, medians = error_control._segment_medians(m)
            assert np.array_equal(bounds, m.seg_bounds) and np.array_equal(
                medians, m.seg_median, equal_nan=True) and m.median_s is None
    assert trivial > 60, trivial


def test_a_tpdo_after_a_lone_boot_up_is_no_s001_but_after_pre_operational_it_is(
        checker: Checker) -> None:
    """Many channels: where a boot-up alone precedes the TPDO nothing shows the node did
    not start itself (silent); where a heartbeat says PRE-OPERATIONAL first, S001 fires,
    on exactly those channels."""
    lines = []
    for c in range(200):
        lines.append(f"(1700000000.{c:06d}) c{c} 705#00\n")
        if c % 3 == 0:
            lines.append(f"(1700000001.{c:06d}) c{c} 705#7F\n")
        lines.append(f"(1700000002.{c:06d}) c{c} 185#01\n")
    res = checker.run("".join(lines), select="S001")
    assert sorted(str(f.channel) for f in res.findings) == sorted(
        f"c{c}" for c in range(0, 200, 3))
    assert all(f.node == 5 and f.rule == "S001" for f in res.findings)


def test_forty_thousand_channels_are_checked_in_seconds(checker: Checker) -> None:
    """The bench's 40,000 channels: every node PRE-OPERATIONAL from its boot-up, nothing
    found, in linear time (2,000 channels for scale; 158 s at issue 24, 18 s before this
    change on a shared 2-core machine, about 4 s after)."""
    took = {}
    for channels in (2_000, 40_000):
        text = channels_log(channels)
        began = time.perf_counter()
        res = checker.run(text)
        took[channels] = time.perf_counter() - began
        nodes = list(res.model.nodes())
        assert len(nodes) == channels and not res.findings
        assert {(m.channel, m.node) for m in nodes} == {(f"c{c}", 5) for c in range(channels)}
        # c0's boot-up is the trace's first frame: no UNKNOWN before it
        assert [iv.state for iv in nodes[0].intervals] == ["PRE-OPERATIONAL"]
        for m in nodes[1:50]:
            assert [iv.state for iv in m.intervals] == ["UNKNOWN", "PRE-OPERATIONAL"]
            assert m.unproven_spans and m.period_source == "none"
    assert took[40_000] < 30 * max(took[2_000], 0.1) and took[40_000] < 60, took


def test_the_boot_stage_lists_the_sdo_servers_once(checker: Checker,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """Each channel's SDO servers are found in one pass, not one listing per channel
    (quadratic at 40,000 channels); each channel's node still gets its boot report."""
    calls = []
    listing = SdoSpool.servers

    def counted(self: SdoSpool) -> list[int]:
        calls.append(1)
        return listing(self)

    monkeypatch.setattr(SdoSpool, "servers", counted)
    text = "".join(f"(1700000000.{c:06d}) c{c} 705#00\n(1700000000.{c + 500:06d}) c{c} "
                   f"585#4300100000000000\n" for c in range(300))
    res = checker.run(text)
    assert len(calls) == 1
    assert res.boot is not None
    assert {key for key in res.boot.nodes} == {(f"c{c}", 5) for c in range(300)}


def test_the_collector_runs_again_after_a_check_and_a_report(checker: Checker,
                                                            tmp_path: Path) -> None:
    """The checks and the reports pause the cyclic garbage collector while they make the
    model's objects, and leave it as they found it, also when a check fails."""
    assert gc.isenabled()
    res = checker.run(channels_log(20))
    assert gc.isenabled()
    assert "".join(streamer("json")([res], {})).startswith("{")
    assert "c19/5" in "".join(streamer("text")([res], {}))
    assert gc.isenabled()
    gc.disable()
    try:
        checker.run(channels_log(20))
        "".join(streamer("json")([res], {}))
        assert not gc.isenabled()
    finally:
        gc.enable()
    log = tmp_path / "few.log"
    log.write_text(channels_log(5))
    profile = load_profile("default")
    with pytest.raises(UsageError, match="--channel nope"):
        check_input(str(log), 0, profile, select_rules(profile, [], []), channel="nope")
    assert gc.isenabled()


def test_shared_empty_tables_stay_empty(checker: Checker) -> None:
    """Nodes without a table of their own share one empty table per kind; after checks
    of random logs of many channels every shared one is still empty and unchanged."""
    for seed in range(3):
        checker.run(random_log(random.Random(seed), channels=40, frames=600))
    for cls in (EcTable, CommandTable, IntervalTable, NmtTable, WriteTable, EmcyTable,
                SdoEventTable):
        table: Any = shared_empty(cls)
        assert len(table) == 0
        for name, value in vars(table).items():
            if isinstance(value, np.ndarray):
                assert value.size == 0, (cls, name)
    assert shared_empty(EcTable).runs is None
    assert NodeConfig() == timeline._NO_CONFIG
    spans = boot_records.Spans
    assert spans.empty().last_step == [] and spans.empty() is not spans.empty()


def heartbeat_log(rng: random.Random, channels: int = 40) -> str:
    """Many channels of a node or three that boot and send a handful of heartbeats:
    steady, early, late (a timeout), of changing, unknown or reserved-bit states, a
    malformed frame, a request or a command now and then (those nodes take the numpy
    paths), sometimes boot-ups again and the time going back."""
    lines = []
    for c in range(channels):
        for n in rng.sample(range(1, 6), rng.randint(1, 3)):
            t = 1_700_000_000.0 + rng.random()
            frames = [(t, f"{0x700 + n:03X}#00")] if rng.random() < 0.8 else []
            for _ in range(rng.randint(1, 8)):
                t += rng.choice((0.1, 0.1, 0.1, 0.1, 0.03, 0.4, 0.0))
                r = rng.random()
                code = rng.choice(("05", "05", "05", "7F", "04", "85", "02"))
                frame = (f"{0x700 + n:03X}#00" if r < 0.08 else f"{0x700 + n:03X}#0500"
                         if r < 0.1 else f"{0x700 + n:03X}#R" if r < 0.12
                         else f"000#01{n:02X}" if r < 0.14 else f"{0x180 + n:03X}#01"
                         if r < 0.2 else f"{0x700 + n:03X}#{code}")
                frames.append((t - 0.3 if rng.random() < 0.02 else t, frame))
            lines += [f"({ts:.6f}) c{c} {f}\n" for ts, f in frames]
    lines.sort(key=lambda line: float(line[1:line.index(")")]))
    return "".join(lines)


def _node_state(m: NodeModel) -> tuple[object, ...]:
    iv = m.intervals
    return (m.key, m.median_s, m.period_s, m.period_source, m.seg_bounds.tolist(),
            [None if v != v else v for v in m.seg_median.tolist()],  # NaN: None
            [astuple(t) for t in m.timeouts], m.self_starts, m.unproven_spans,
            m.ec.stale.tolist(), iv.start.tolist(), iv.end.tolist(), iv.state.tolist(),
            iv.source.tolist())


def test_small_node_lists_match_the_numpy_paths(checker: Checker,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """A small plain node (a boot-up and a few heartbeats, `error_control.small_ec`): its period,
    segment medians, H001 timeouts, self-starts, unproven spans, intervals and every
    finding (H002, H003, C003, C004, S005 return early from the lists) are the numpy
    paths', on random logs of many channels, with findings fired and nodes silent."""
    network = "[nodes.2]\nheartbeat_ms = 100\n[nodes.3]\nheartbeat_ms = 250\n"
    small = fired = 0
    codes: set[str] = set()
    for seed in range(10):
        text = heartbeat_log(random.Random(seed))
        for net in (None, network):
            fast = checker.run(text, network=net)
            with monkeypatch.context() as mp:
                mp.setattr(error_control, "SMALL_NODE_FRAMES", 0)  # every node the numpy way
                full = checker.run(text, network=net)
            assert not any(m.small for m in full.model.nodes())
            small += sum(1 for m in fast.model.nodes() if m.small is not None)
            assert [_node_state(m) for m in fast.model.nodes()] == [
                _node_state(m) for m in full.model.nodes()], seed
            assert [astuple(f) for f in fast.findings] == [astuple(f) for f in full.findings]
            fired += len(fast.findings)
            codes |= {f.rule for f in fast.findings}
    assert small > 300 and fired > 100, (small, fired)
    assert {"H001", "H002", "H003", "C003", "C004", "S005", "S001"} <= codes, codes


def test_first_and_last_frames_of_far_channel_codes_are_found_in_small_tables() -> None:
    """Each node key's first and last transmitted frame of a batch: with keys of high
    channel codes (chan * 128 + N; 200,000 channels reach 25.6 M) the tables are the
    batch's distinct keys, not one slot per possible key (two int64 tables of 25.6 M:
    410 MB for a batch of 200,000 channels); the same frames are found either way."""
    import tracemalloc

    from nmtcheck.readers.frames import FrameBatch
    from nmtcheck.timeline.decode import FirstTx, _first_last

    rng = np.random.default_rng(7)
    for spread in (200, 200_000):  # dense tables, then the distinct keys
        n = 3000
        keys = (rng.integers(0, spread, n) * 128 + rng.integers(1, 128, n)).astype(np.int64)
        rows = np.sort(rng.choice(np.arange(2 * n), n, replace=False))
        kinds = rng.integers(1, 6, 2 * n)
        ts = np.sort(rng.random(2 * n)) * 100
        z = np.zeros(2 * n, bool)
        b = FrameBatch(ts, np.zeros(2 * n, np.int32), np.zeros(2 * n, np.uint32), z, z, z, z,
                       np.zeros(2 * n, np.int16), np.zeros((2 * n, 8), np.uint8),
                       np.arange(2 * n, dtype=np.int64) + 10, np.arange(2 * n, dtype=np.int64))
        first: dict[int, FirstTx] = {int(keys[0]): FirstTx(-1, -1.0, 0)}  # seen before
        last: dict[int, float] = {}
        tracemalloc.start()
        _first_last(keys, rows, kinds, b, first, last)
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert peak < 2_000_000, (spread, peak)
        want_first: dict[int, FirstTx] = {int(keys[0]): FirstTx(-1, -1.0, 0)}
        want_last: dict[int, float] = {}
        for k, row in zip(keys.tolist(), rows.tolist(), strict=True):
            want_first.setdefault(k, FirstTx(row + 10, float(ts[row]), int(kinds[row])))
            want_last[k] = float(ts[row])
        assert first == want_first and last == want_last
        assert list(first) == [int(keys[0]), *sorted(set(want_first) - {int(keys[0])})]
