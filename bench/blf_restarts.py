"""A BLF whose recordings restart their times (issue 39), written by python-can's BLFWriter.

    python bench/blf_restarts.py 22.4M 64 /tmp/blf64-22.4M.blf [--jitter-ms 0.5]

`blocks` recordings one after the other, each of 8 nodes' heartbeats (05h) every 10 ms
(+-jitter, uniform), each starting again at the file's start time: a logger that appends
sessions, or containers whose stamps restart. nmtcheck checks each as a capture of its own
(I005); `bench/PATHOLOGICAL.md` has its figures. Writing 22.4 M frames takes ~5 min.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run import parse_size


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("frames")
    ap.add_argument("blocks", type=int)
    ap.add_argument("out", type=Path)
    ap.add_argument("--jitter-ms", type=float, default=0.5)
    args = ap.parse_args()
    import can

    rng = np.random.default_rng(3)
    rounds = parse_size(args.frames) // args.blocks // 8
    jit = args.jitter_ms / 1000.0
    with can.BLFWriter(str(args.out)) as w:
        for _ in range(args.blocks):
            t = (np.arange(rounds)[:, None] * 0.010 + 0.001 * np.arange(1, 9)[None, :]
                 + rng.uniform(-jit, jit, (rounds, 8))).ravel()
            ids = np.tile(0x701 + np.arange(8), rounds)
            order = np.argsort(t, kind="stable")
            for stamp, cid in zip((1_700_000_000 + t[order]).tolist(), ids[order].tolist(),
                                  strict=True):
                w.on_message_received(can.Message(timestamp=stamp, arbitration_id=cid,
                                                  is_extended_id=False, dlc=1, data=b"\x05",
                                                  channel=0))


if __name__ == "__main__":
    main()
