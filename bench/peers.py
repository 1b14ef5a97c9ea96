"""The peers the benchmark measures nmtcheck against, run as their own processes.

    python bench/peers.py iterate LOG   # python-can LogReader, merely iterating
    python bench/peers.py track LOG     # python-can plus a naive per-frame NMT tracker

The tracker is what a short script written against python-can typically does:
per frame, apply NMT commands, note boot-ups and heartbeat states, flag
heartbeat gaps over 1.5x the last interval and PDOs of nodes that are not
OPERATIONAL. It prints its counts so the work cannot be optimised away.
"""

from __future__ import annotations

import sys

import can


def iterate(path: str) -> None:
    n = 0
    for _msg in can.LogReader(path):
        n += 1
    print(n)


def track(path: str) -> None:
    state: dict[int, int] = {}
    last_hb: dict[int, float] = {}
    interval: dict[int, float] = {}
    findings = frames = 0
    for msg in can.LogReader(path):
        frames += 1
        if msg.is_extended_id or msg.is_error_frame or msg.is_remote_frame:
            continue
        cid = msg.arbitration_id
        if cid == 0 and len(msg.data) == 2:
            cs, node = msg.data
            targets = list(state) if node == 0 else [node]
            for t in targets:
                state[t] = {1: 5, 2: 4, 0x80: 0x7F}.get(cs, 0)
        elif 0x701 <= cid <= 0x77F and len(msg.data) == 1:
            node = cid - 0x700
            value = msg.data[0] & 0x7F
            state[node] = 0x7F if value == 0 else value
            prev = last_hb.get(node)
            if prev is not None:
                gap = msg.timestamp - prev
                if node in interval and gap > 1.5 * interval[node]:
                    findings += 1
                interval[node] = gap if node not in interval else min(interval[node], gap) \
                    if gap > 0.01 else interval[node]
            last_hb[node] = msg.timestamp
        elif 0x181 <= cid <= 0x4FF and state.get(cid & 0x7F, 5) != 5:
            findings += 1
    print(frames, findings)


if __name__ == "__main__":
    {"iterate": iterate, "track": track}[sys.argv[1]](sys.argv[2])
