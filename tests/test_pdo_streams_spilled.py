"""The PDO streams' frames past a few MB go to a temporary file and come back one stream at
a time (processes/pdo.py load_frames, spool.KeyedColumns): the findings and every report
must be the same as with all of them in memory, and what the store holds stays within its
budgets whatever the number of frames. The benchmark's log of 20 M frames with its SYNC +
PDO network file (15 M PDO frames in 32 streams) took 854 MB with every stream held, 266 MB
so (2-core VM, 2026-12-08, docs/status.md)."""

from __future__ import annotations

import gc
import os
import pickle
import sys
from pathlib import Path

import numpy as np
import pytest
from test_many_inputs import GROUPS, _check, _reports

from nmtcheck.checks import base as rules_base
from nmtcheck.processes import pdo as pdo_stage
from nmtcheck.results import PackedResult
from nmtcheck.settings.network import load_network
from nmtcheck.spool import SCRATCH, KeyedColumns

COLUMNS = {"ts": np.float64, "idx": np.int64, "dlc": np.uint8}


def _parts(seed: int) -> list[tuple[int, dict[str, np.ndarray]]]:
    """Parts of 12 keys in a random interleaving, of random sizes (some empty)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(200):
        n = int(rng.integers(0, 300))
        cols: dict[str, np.ndarray] = {"ts": rng.random(n), "idx": rng.integers(0, 1 << 40, n),
                                       "dlc": rng.integers(0, 9, n).astype(np.uint8)}
        out.append((int(rng.integers(0, 12)), cols))
    return out


def _joined(parts: list[tuple[int, dict[str, np.ndarray]]], key: int) -> list[np.ndarray]:
    mine = [cols for k, cols in parts if k == key]
    return [np.concatenate([c[name] for c in mine]) if mine else np.empty(0, dtype)
            for name, dtype in COLUMNS.items()]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/fd")
@pytest.mark.parametrize("budget", [1 << 30, 1, 5000])
def test_every_key_reads_back_what_was_appended(budget: int, tmp_path: Path) -> None:
    """In memory, spilled at every append, or now and then: the same rows per key, in
    order, as often as asked, and the same after a pickle; a key never appended reads
    empty. A spilled store has one directory in the scratch directory, with no file left
    open, removed with the store."""
    parts = _parts(budget)
    token = SCRATCH.set(str(tmp_path))
    try:
        store = KeyedColumns(COLUMNS, budget=budget, cache_budget=3000)
        for key, cols in parts:
            store.append(key, **cols)
        store.finish()
        assert store.spilled == (budget < 1 << 30)
        assert len(os.listdir(tmp_path)) == (1 if store.spilled else 0)
        assert not [fd for fd in os.listdir("/proc/self/fd")
                    if str(tmp_path) in _link(f"/proc/self/fd/{fd}")]
        for _round in range(2):
            for key in [*range(12), 99]:
                got = store.get(key)
                want = _joined(parts, key)
                assert [a.dtype for a in got] == [np.dtype(t) for t in COLUMNS.values()]
                assert all(np.array_equal(a, b) for a, b in zip(got, want, strict=True))
                if store.spilled:  # the cache keeps to its budget, or the last key's rows
                    assert store.held_bytes <= max(3000, sum(a.nbytes for a in got))
        again = pickle.loads(pickle.dumps(store))
        for key in range(12):
            assert all(np.array_equal(a, b) for a, b in zip(
                again.get(key), _joined(parts, key), strict=True))
        del store, again
        gc.collect()
        assert os.listdir(tmp_path) == []
    finally:
        SCRATCH.reset(token)


def _link(path: str) -> str:
    try:
        return os.readlink(path)
    except OSError:  # the listing's own descriptor, closed since
        return ""


def _log_of_many_streams(path: Path, nodes: int = 8, frames: int = 20_000) -> Path:
    """Nodes 1..`nodes` boot, are started, send heartbeats every 100 ms and TPDO1 every
    10 ms for `frames` frames each; node 3 misses five TPDOs at 100 s (a D001, and a D004
    of node 4, which consumes them), node 5 sends one 1 ms after another at 50 s (a
    D002)."""
    lines = [(0.0, f"{0x700 + n:03X}#00") for n in range(1, nodes + 1)]
    lines.append((0.01, "000#0100"))
    for k in range(frames // 10 + 1):
        t = 0.05 + k * 0.1
        lines += [(t, f"{0x700 + n:03X}#05") for n in range(1, nodes + 1)]
    for k in range(frames):
        t = 0.02 + k * 0.01
        lines += [(t + n * 1e-4, f"{0x180 + n:03X}#{k % 256:02X}{n:02X}")
                  for n in range(1, nodes + 1) if not (n == 3 and 10_000 <= k < 10_005)]
    lines.append((0.02 + 5000 * 0.01 + 5e-4 + 1e-3, f"{0x185:03X}#FF05"))
    lines.sort()
    path.write_text("".join(f"({t:.6f}) can0 {frame}\n" for t, frame in lines))
    return path


def _network(path: Path, nodes: int = 8) -> Path:
    text = []
    for n in range(1, nodes + 1):
        text += [f"[nodes.{n}]", "heartbeat_ms = 100", f"[nodes.{n}.tpdo.1]",
                 f"cob_id = 0x{0x180 + n:X}", "transmission_type = 255", "event_timer_ms = 10",
                 "inhibit_100us = 50", ""]
    text += ["[nodes.4.rpdo.1]", "cob_id = 0x183", "transmission_type = 255",
             "event_timer_ms = 20", ""]
    path.write_text("\n".join(text))
    return path


def test_a_spilled_check_holds_its_budgets_and_finds_the_same(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """160,000 TPDOs in 8 streams (4 MB of stream frames) against budgets of 256 KB in
    memory and 1 MB cached: the store went to its file and holds at most the cache and one
    stream after the check; the findings (D001 among them) and every report are those of
    the check that held every stream in memory."""
    log = _log_of_many_streams(tmp_path / "pdo.log")
    network = load_network(str(_network(tmp_path / "network.toml")))
    whole = _check([log], network)
    found = {(f.rule, f.node) for f in whole[0].findings}
    assert {("D001", 3), ("D004", 4), ("D002", 5)} <= found, found
    for window in (7, 5000, 10_000):  # windows that end at the findings' frames too
        monkeypatch.setattr(rules_base, "WINDOW", window)
        assert _reports(_check([log], network)) == _reports(whole)
    monkeypatch.setattr(rules_base, "WINDOW", 1 << 18)
    monkeypatch.setattr(pdo_stage, "STREAMS_IN_MEMORY", 256 << 10)
    monkeypatch.setattr(pdo_stage, "STREAMS_CACHED", 1 << 20)
    spilled = _check([log], network)
    analysis = pdo_stage.of(spilled[0].model)
    assert analysis is not None and len(analysis.streams) == 8
    store = analysis.streams[0].store
    assert store is not None and store.spilled
    one_stream = max(sum(a.nbytes for a in store.get(s.chan * 4096 + s.cob_id))
                     for s in analysis.streams)
    assert 20_000 * 25 <= one_stream < 1 << 20
    assert store.held_bytes <= (1 << 20) + one_stream
    assert [(f.rule, f.node, f.time, f.line) for f in spilled[0].findings] == [
        (f.rule, f.node, f.time, f.line) for f in whole[0].findings]
    assert _reports(spilled) == _reports(whole)
    assert _reports([PackedResult.of(r).unpack() for r in _check([log], network)]) == (
        _reports(whole))


WITH_STREAMS = sorted(g for g, (_logs, net) in GROUPS.items()
                      if net is not None and "pdo" in net.read_text().lower())


def test_sample_groups_with_pdo_streams_are_compared() -> None:
    assert len(WITH_STREAMS) >= 3, WITH_STREAMS


@pytest.mark.parametrize("group", WITH_STREAMS)
def test_the_real_stacks_recordings_report_the_same_spilled(
        group: str, monkeypatch: pytest.MonkeyPatch) -> None:
    """Every sample recording whose network file describes PDOs, with every append going
    to the file and a cache of one stream: reports as with the streams in memory, also as
    a worker sends its results back."""
    logs, net_path = GROUPS[group]
    assert net_path is not None
    network = load_network(str(net_path))
    whole = _reports(_check(logs, network))
    monkeypatch.setattr(pdo_stage, "STREAMS_IN_MEMORY", 1)
    monkeypatch.setattr(pdo_stage, "STREAMS_CACHED", 1)
    assert _reports(_check(logs, network)) == whole
    assert _reports([PackedResult.of(r).unpack() for r in _check(logs, network)]) == whole
    monkeypatch.setattr(rules_base, "WINDOW", 2)  # and the D rules in windows of 2 frames
    assert _reports(_check(logs, network)) == whole
