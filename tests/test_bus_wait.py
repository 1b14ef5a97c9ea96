"""q(F) of SPEC §9.1.6 (checks/bus_wait.py): the vectorised pass over the frame times
gives, for every frame asked about, what the rule's definition gives frame by frame."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from nmtcheck.checks import pdo as pdo_rules
from nmtcheck.checks.bus_wait import EPS, WINDOW, bus_waits
from nmtcheck.spool import ChunkStore


def _one_by_one(times: np.ndarray, i: int, d8: float) -> float:
    """§9.1.6 for frame i, walking back over at most WINDOW frames (F included)."""
    window = times[max(i - (WINDOW - 1), 0):i + 1]
    j = len(window) - 1
    while j > 0 and window[j] - window[j - 1] <= 1.25 * d8 + EPS:
        j -= 1
    return 0.0 if j == len(window) - 1 else float(window[-1] - window[j]) + d8


def _model(times: np.ndarray, cuts: list[int], d8: float | None, budget: int,
           chans: np.ndarray | None = None) -> tuple[SimpleNamespace, SimpleNamespace]:
    """A model of what bus_waits reads: the frame-time store (chunks cut at `cuts`, each
    with its channel codes as the decode stage stores them), d8 and channel 0."""
    from nmtcheck.timeline.decode import _chans

    chans = np.zeros(len(times), np.int32) if chans is None else chans
    store = ChunkStore(budget)
    for lo, hi in zip([0, *cuts], [*cuts, len(times)], strict=True):
        store.append(ts=times[lo:hi], base=np.asarray([lo], np.int64), **_chans(chans[lo:hi]))
    decoded = SimpleNamespace(frame_times=store, channels=int(chans.max()) + 1,
                              d8=lambda chan: d8)
    return SimpleNamespace(decoded=decoded), SimpleNamespace(chan=0)


@pytest.mark.parametrize("seed", range(6))
def test_every_frame_gets_the_definitions_q(seed: int) -> None:
    """Random back-to-back runs (some longer than the window) cut into random chunks,
    in memory and spilled to disk; the frames asked about in any order, some twice."""
    rng = np.random.default_rng(seed)
    d8 = 130e-6
    steps = np.where(rng.random(3000) < 0.7, d8 * rng.uniform(0.95, 1.3, 3000),
                     rng.uniform(1e-3, 5e-3, 3000))
    steps[1000:1400] = d8  # a run of 400 frames: q stops at the window
    times = 10.0 + np.cumsum(steps)
    cuts = sorted(rng.choice(np.arange(1, 3000), 7, replace=False).tolist())
    asked = rng.permutation(np.concatenate([rng.choice(3000, 500), [0, 1, 1399, 1399]]))
    want = [_one_by_one(times, int(i), d8) for i in asked]
    assert sum(w > 0 for w in want) > 100  # many frames did wait
    for budget in (1 << 30, 1000):
        model, cm = _model(times, cuts, d8, budget)
        got = bus_waits(model, cm, asked)  # type: ignore[arg-type]
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


@pytest.mark.parametrize("seed", range(4))
def test_the_other_channels_frames_are_left_out(seed: int) -> None:
    """Channel 0's frames interleaved with another channel's (whole chunks of it too):
    each channel-0 frame gets the q of channel 0's frames alone."""
    rng = np.random.default_rng(100 + seed)
    d8 = 130e-6
    steps = np.where(rng.random(2000) < 0.7, d8 * rng.uniform(0.95, 1.3, 2000),
                     rng.uniform(1e-3, 5e-3, 2000))
    mine = 10.0 + np.cumsum(steps)
    other = np.sort(rng.uniform(mine[0], mine[-1], 1500))
    other = np.concatenate([other, np.linspace(mine[-1] + 1, mine[-1] + 2, 400)])
    times = np.concatenate([mine, other])
    chans = np.concatenate([np.zeros(len(mine), np.int32), np.ones(len(other), np.int32)])
    by_time = np.argsort(times, kind="stable")
    times, chans = times[by_time], chans[by_time]
    cuts = sorted(rng.choice(np.arange(1, len(times)), 5, replace=False).tolist())
    asked_mine = rng.choice(len(mine), 400)  # the k-th frame of channel 0
    asked = np.flatnonzero(chans == 0)[asked_mine]
    want = [_one_by_one(mine, int(k), d8) for k in asked_mine]
    assert sum(w > 0 for w in want) > 50
    for budget in (1 << 30, 1000):
        model, cm = _model(times, cuts, d8, budget, chans)
        got = bus_waits(model, cm, asked)  # type: ignore[arg-type]
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)


def test_no_d8_no_allowance() -> None:
    times = 10.0 + np.arange(50) * 130e-6
    model, cm = _model(times, [20], None, 1 << 30)
    assert not bus_waits(model, cm, np.arange(50)).any()  # type: ignore[arg-type]


def test_a_stream_that_breaks_its_inhibit_time_reads_the_frame_times_once(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """D002 asks q for every pair closer than the inhibit time: 20,000 8-byte TPDOs 5 ms
    apart against 10 ms. It read the frame times anew for each (200,000 such frames took
    16 s); now one pass serves them all."""
    from nmtcheck.api import check

    log = tmp_path / "tpdo.log"
    t = 10.0 + np.arange(20_000) * 0.005
    log.write_text("(9.990000) can0 703#00\n(9.995000) can0 000#0103\n" + "".join(
        f"({x:.6f}) can0 183#0100000000000000\n" for x in t.tolist()))
    net = tmp_path / "net.toml"
    net.write_text("[nodes.3.tpdo.1]\ncob_id = 0x183\ntransmission_type = 255\n"
                   "inhibit_100us = 100\n")
    passes = 0
    reaching = ChunkStore.reaching

    def counted(self: ChunkStore, ts: float) -> Iterator[dict[str, np.ndarray]]:
        nonlocal passes
        passes += 1
        return reaching(self, ts)

    asked: list[float] = []

    def waits(model: Any, cm: Any, idxs: np.ndarray) -> np.ndarray:
        q = bus_waits(model, cm, idxs)
        asked.extend(q.tolist())
        return q

    monkeypatch.setattr(ChunkStore, "reaching", counted)
    monkeypatch.setattr(pdo_rules, "bus_waits", waits)
    check([str(log)], network=str(net))
    assert len(asked) == 19_999 and min(asked) > 0  # every pair, each one ends a run
    assert passes < 20
