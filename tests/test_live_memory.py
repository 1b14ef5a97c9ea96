"""One hour of bus traffic through a live session on an accelerated clock: the memory the
session holds stays flat (the frames go to the recording on disk, the tracker keeps
O(nodes) state), and the hour's live findings are confirmed by the offline check."""

from __future__ import annotations

import tracemalloc
from collections.abc import Iterator
from pathlib import Path

from nmtcheck.engine import select_rules
from nmtcheck.live.frames import LiveFrame
from nmtcheck.live.session import Session
from nmtcheck.settings.profiles import load_profile

NODES = range(2, 7)
PERIOD = 0.5  # s, every node's heartbeat
HOUR = 3600.0


def hour_of_traffic(t0: float) -> Iterator[LiveFrame]:
    """5 nodes: boot-up, then a heartbeat and a TPDO each every 500 ms for an hour; every
    ten minutes one node falls silent for two seconds (an H001 each time)."""
    for n in NODES:
        yield LiveFrame(t0, "can0", 0x700 + n, dlc=1, data=b"\x00")
    yield LiveFrame(t0 + 0.01, "can0", 0x000, dlc=2, data=b"\x01\x00")
    k = 1
    while k * PERIOD < HOUR:
        t = t0 + k * PERIOD
        silent = int(t - t0) % 600 in (300, 301)  # one node, two seconds every ten minutes
        quiet_node = NODES[int((t - t0) // 600) % len(NODES)]
        for n in NODES:
            if silent and n == quiet_node:
                continue
            ts = t + n * 0.001
            yield LiveFrame(ts, "can0", 0x700 + n, dlc=1, data=b"\x05")
            yield LiveFrame(ts + 0.0005, "can0", 0x180 + n, dlc=8, data=bytes(8))
        k += 1


def test_one_hour_flat_memory(tmp_path: Path) -> None:
    profile = load_profile("default")
    rules = select_rules(profile, [], [])
    record = tmp_path / "hour.log"
    session = Session(profile, rules, None, str(record), timer=False)
    tracemalloc.start()
    samples = []
    frames = 0
    for f in hour_of_traffic(1_700_000_000.0):
        session.feed(f)
        frames += 1
        if frames % 5_000 == 0:
            samples.append(tracemalloc.get_traced_memory()[0])
    tracemalloc.stop()
    assert frames > 70_000
    # after the first minutes nothing grows: the last sample within 64 KiB of the second
    assert samples[-1] - samples[1] < 64 * 1024, samples
    outcome = session.close()
    assert outcome.result is not None and outcome.result.stats.frames == frames
    live = [(lf.rule, lf.node) for lf in outcome.live]
    assert live == [("H001", NODES[i % len(NODES)]) for i in range(6)], live
    assert all(lf.confirmed == "confirmed" for lf in outcome.live)
    assert [(f.rule, f.node) for f in outcome.result.findings
            if f.rule in ("H001", "B002", "B003")] == live
