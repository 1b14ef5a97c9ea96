#!/usr/bin/env python3
"""Live checking: H001 latency on python-can's virtual bus, feed throughput, memory.

    python bench/live.py [--trials 20]

Latency: a node heartbeats every 100 ms on a virtual bus, then stops; the time from the
timeout's expiry (last heartbeat + 1.5 x 100 ms, in the bus's time = wall time on a
virtual bus) to the Monitor's on_finding call. Throughput: frames per second through
`Session.feed` (tracker + recording). Memory: what the session holds after 10 and 60
simulated minutes (tracemalloc).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import threading
import time
import tracemalloc
from pathlib import Path

import can

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

import nmtcheck
from nmtcheck.engine import select_rules
from nmtcheck.live.session import Session
from nmtcheck.settings.profiles import load_profile


def latency_trial(k: int) -> float:
    channel = f"bench-{k}"
    tx = can.Bus(interface="virtual", channel=channel)
    rx = can.Bus(interface="virtual", channel=channel)
    got: list[tuple[float, float]] = []
    done = threading.Event()

    def on_finding(lf: object) -> None:
        got.append((time.time(), lf.time))  # type: ignore[attr-defined]
        done.set()

    monitor = nmtcheck.Monitor(on_finding=on_finding)
    notifier = can.Notifier(rx, [monitor], timeout=0.05)
    try:
        tx.send(can.Message(arbitration_id=0x705, data=[0], is_extended_id=False))
        for _ in range(10):
            tx.send(can.Message(arbitration_id=0x705, data=[5], is_extended_id=False))
            time.sleep(0.1)
        done.wait(2.0)
    finally:
        notifier.stop()
        monitor.stop()
        tx.shutdown()
        rx.shutdown()
    return got[0][0] - got[0][1]


def throughput(frames: int = 200_000) -> float:
    from test_live_memory import hour_of_traffic

    profile = load_profile("default")
    with tempfile.TemporaryDirectory() as tmp:
        s = Session(profile, select_rules(profile, [], []), None, f"{tmp}/t.log", timer=True)
        began = time.perf_counter()
        n = 0
        for f in hour_of_traffic(1_700_000_000.0):
            s.feed(f)
            n += 1
            if n >= frames:
                break
        rate = n / (time.perf_counter() - began)
        s.close()
    return rate


def memory() -> tuple[int, int, int]:
    from test_live_memory import hour_of_traffic

    profile = load_profile("default")
    with tempfile.TemporaryDirectory() as tmp:
        s = Session(profile, select_rules(profile, [], []), None, f"{tmp}/m.log", timer=False)
        tracemalloc.start()
        at10 = 0
        n = 0
        for f in hour_of_traffic(1_700_000_000.0):
            s.feed(f)
            n += 1
            if not at10 and f.ts - 1_700_000_000.0 > 600:
                at10 = tracemalloc.get_traced_memory()[0]
        at60 = tracemalloc.get_traced_memory()[0]
        tracemalloc.stop()
        s.close()
    return n, at10, at60


def _rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return 0.0


def overload(rate: int = 64_000, seconds: float = 30.0) -> None:
    """Issue 24 item 8: a Monitor on a python-can Notifier, a sender thread flooding the
    virtual bus at `rate` frames/s (heartbeats of 16 nodes) for `seconds`: frames sent,
    checked and dropped, and the RSS before and after (sampled every second)."""
    tx = can.Bus(interface="virtual", channel="flood")
    rx = can.Bus(interface="virtual", channel="flood")
    monitor = nmtcheck.Monitor()
    notifier = can.Notifier(rx, [monitor], timeout=0.05)
    start_rss = _rss_mb()
    peak = start_rss
    sent = 0
    began = time.perf_counter()
    next_sample = began + 1
    while (now := time.perf_counter()) - began < seconds:
        due = int((now - began) * rate)
        while sent < due:
            tx.send(can.Message(arbitration_id=0x701 + sent % 16, data=[5],
                                is_extended_id=False, timestamp=time.time()))
            sent += 1
        if now >= next_sample:
            peak = max(peak, _rss_mb())
            next_sample += 1
        time.sleep(0.001)
    notifier.stop()
    monitor.stop()
    res = monitor.result()
    checked = res.stats.frames if res is not None else 0
    i004 = [f.message for f in (res.findings if res else []) if f.rule == "I004"]
    print(f"overload at {rate:,} frames/s for {seconds:g} s: {sent:,} sent, {checked:,} "
          f"checked, {getattr(monitor, 'dropped', 0):,} dropped (counted), "
          f"{sent - checked - getattr(monitor, 'dropped', 0):,} unaccounted; RSS "
          f"{start_rss:.0f} MB -> peak {peak:.0f} MB; I004: {i004[:1]}")
    tx.shutdown()
    rx.shutdown()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--trials", type=int, default=20)
    ap.add_argument("--overload", type=float, default=0,
                    help="only the overload case, for this many seconds (issue 24 item 8)")
    ap.add_argument("--rate", type=int, default=64_000)
    args = ap.parse_args()
    if args.overload:
        overload(args.rate, args.overload)
        return
    lat = sorted(latency_trial(k) * 1000 for k in range(args.trials))
    print(f"H001 latency after expiry, {len(lat)} trials: median {statistics.median(lat):.1f} ms,"
          f" max {lat[-1]:.1f} ms, min {lat[0]:.1f} ms")
    print(f"Session.feed throughput: {throughput():,.0f} frames/s")
    n, at10, at60 = memory()
    print(f"memory held by the session over one simulated hour ({n:,} frames): "
          f"{at10 / 1024:.1f} KiB at 10 min, {at60 / 1024:.1f} KiB at 60 min")


if __name__ == "__main__":
    main()
