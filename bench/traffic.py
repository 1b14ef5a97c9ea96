"""Realistic CANopen traffic for the benchmark, generated as numpy columns.

One 1 Mbit/s bus (`can0`) with 16 nodes at about 45 % load: a 10 ms SYNC cycle
with each node's TPDO1 and RPDO1, TPDO2 of half the nodes, 100 ms heartbeats,
an SDO exchange every 0.5 s and an EMCY now and then. The recording starts
with the master's reset-communication broadcast, the boot-ups and a start
command; halfway through, node 7 reboots on its own (B002) and node 12 stops
sending heartbeats for 1.5 s (H001), so the checker has a few findings to
report on an otherwise healthy log.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

NODES = np.arange(1, 17)
CYCLE_S = 0.010
T0_US = 1_700_000_000 * 10**6
CHUNK_FRAMES = 500_000


@dataclass
class Frames:
    """A run of generated frames (11-bit frames, like most CANopen buses)."""

    us: np.ndarray  # int64 epoch microseconds
    can_id: np.ndarray  # uint16
    dlc: np.ndarray  # uint8
    data: np.ndarray  # uint8 [n, 8], zero past dlc
    rtr: np.ndarray | None = None  # bool: remote requests (no data); None: all data frames

    def __len__(self) -> int:
        return int(self.us.shape[0])


def _cycle_template() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(offset within a 100 ms super-cycle, CAN-ID, DLC) of the periodic frames."""
    offs, ids, dlcs = [], [], []
    for cycle in range(10):
        base = cycle * CYCLE_S
        offs.append(base)
        ids.append(0x080)  # SYNC
        dlcs.append(0)
        for i, n in enumerate(NODES):
            offs.append(base + 0.00012 + i * 0.00013)
            ids.append(0x180 + n)
            dlcs.append(8)
            if n % 2 == 0:
                offs.append(base + 0.0023 + i * 0.00012)
                ids.append(0x280 + n)
                dlcs.append(4)
            offs.append(base + 0.0045 + i * 0.00011)
            ids.append(0x200 + n)
            dlcs.append(8)
        for n in NODES[cycle == NODES % 10]:
            offs.append(base + 0.0068 + n * 0.0001)
            ids.append(0x700 + n)
            dlcs.append(1)
    offs += [0.0081, 0.0083, 0.0091]  # an SDO upload of 1017h (to a node chosen per
    ids += [0x600, 0x580, 0x083]  # super-cycle) and a slot for node 3's occasional EMCY
    dlcs += [8, 8, 8]
    order = np.argsort(offs, kind="stable")
    return (np.asarray(offs)[order], np.asarray(ids, np.uint16)[order],
            np.asarray(dlcs, np.uint8)[order])


def _startup() -> Frames:
    """Reset communication (broadcast), boot-ups, a few pre-operational heartbeats, start."""
    ts: list[int] = []
    ids: list[int] = []
    dlcs: list[int] = []
    data: list[bytes] = []

    def add(t: float, cid: int, payload: bytes) -> None:
        ts.append(T0_US + round(t * 1e6))
        ids.append(cid)
        dlcs.append(len(payload))
        data.append(payload.ljust(8, b"\0"))

    add(0.0, 0x000, bytes([0x82, 0]))
    for n in NODES:
        add(0.050 + n * 0.001, 0x700 + n, b"\x00")
    for k in range(1, 4):
        for n in NODES:
            add(0.050 + k * 0.1 + n * 0.0001, 0x700 + n, b"\x7f")
    add(0.39, 0x000, bytes([0x01, 0]))
    return Frames(np.asarray(ts, np.int64), np.asarray(ids, np.uint16), np.asarray(dlcs, np.uint8),
                  np.frombuffer(b"".join(data), np.uint8).reshape(-1, 8).copy())


def traffic(n_frames: int, seed: int = 1) -> Iterator[Frames]:
    """Exactly `n_frames` frames in time order, in chunks of about CHUNK_FRAMES."""
    rng = np.random.default_rng(seed)
    offs, ids, dlcs = _cycle_template()
    per_super = len(offs)
    startup = _startup()
    yield startup
    left = n_frames - len(startup)
    total_supers = -(-left // per_super) + 2
    mid = total_supers // 2  # where the faults are injected
    sup = 0
    t_start = 0.4
    while left > 0:
        k = max(1, min(CHUNK_FRAMES // per_super, total_supers - sup))
        s = np.arange(sup, sup + k)
        t = (t_start + s[:, None] * 0.1 + offs[None, :]).ravel()
        cid = np.tile(ids, k).astype(np.int64)
        dlc = np.tile(dlcs, k)
        jitter = rng.integers(0, 40, t.shape[0]) * 1e-6
        t = t + jitter
        # SDO pairs go to a different node each time
        sdo = (cid == 0x600) | (cid == 0x580)
        node_of_super = (np.repeat(s, per_super) % 16) + 1
        cid[sdo] += node_of_super[sdo]
        data = rng.integers(0, 256, (t.shape[0], 8), dtype=np.uint8)
        data[np.arange(8)[None, :] >= dlc[:, None]] = 0
        hb = (cid >= 0x701) & (cid <= 0x77F)
        data[hb, 0] = 0x05
        sdo_req = cid >= 0x601
        data[sdo_req & (cid <= 0x67F), :4] = [0x40, 0x17, 0x10, 0x00]
        data[(cid >= 0x581) & (cid <= 0x5FF), :4] = [0x4B, 0x17, 0x10, 0x00]
        sup_of = np.repeat(s, per_super)
        keep = (cid != 0x083) | (sup_of % 200 == 100)  # EMCY every 20 s
        # node 12 falls silent (heartbeats only) for 1.5 s in the middle
        window = (s[0] <= mid + 15) & (s[-1] >= mid)
        if window:
            keep &= ~((cid == 0x70C) & (sup_of >= mid) & (sup_of < mid + 15))
        t, cid, dlc, data = t[keep], cid[keep], dlc[keep], data[keep]
        if s[0] <= mid + 40 <= s[-1]:  # node 7 reboots on its own: boot-up, then start-up
            at = t_start + (mid + 40) * 0.1 + 0.0095
            extra_t = np.asarray([at])
            t = np.concatenate([t, extra_t])
            cid = np.concatenate([cid, [0x707]])
            dlc = np.concatenate([dlc, [1]]).astype(np.uint8)
            data = np.concatenate([data, np.zeros((1, 8), np.uint8)])
            order = np.argsort(t, kind="stable")
            t, cid, dlc, data = t[order], cid[order], dlc[order], data[order]
        t_us = T0_US + np.round(t * 1e6).astype(np.int64)
        take = min(left, t.shape[0])
        yield Frames(t_us[:take], cid[:take].astype(np.uint16), dlc[:take].astype(np.uint8),
                     data[:take])
        left -= take
        sup += k
