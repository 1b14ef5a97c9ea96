#!/usr/bin/env python3
"""The candump reader alone: time and peak RSS to read a log into frame batches (issue 24:
many channels, 29-bit and error frames, a long line through `check --follow -`).

    python bench/readers.py --sizes 80000,5M --kinds channels,extended,errorframes,canids
    python bench/readers.py --pythonpath /tmp/base     # another checkout's reader (baseline)
    python bench/readers.py --follow-line-mb 80         # `check --follow -` of one 80 MB line

The logs are bench/pathological.py's (same kinds and --data). Each read runs in a fresh
process (`open_input`, every batch taken, nothing kept), so ru_maxrss is the reader's.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from pathological import KINDS, generate, label  # noqa: E402
from run import parse_size  # noqa: E402

READ = r"""
import json, resource, sys, time
from nmtcheck.readers import open_input
began = time.perf_counter()
opened = open_input(sys.argv[1])
frames = sum(len(b) for b in opened.batches)
s = opened.stats
print(json.dumps({"frames": frames, "skipped": s.skipped, "extended": s.extended,
                  "error_frames": s.error_frames, "channels": len(s.channels),
                  "seconds": time.perf_counter() - began,
                  "max_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def read_one(log: Path, pythonpath: str) -> dict[str, float]:
    env = {**os.environ, "PYTHONPATH": pythonpath}
    # -P: not the working directory's nmtcheck (a checkout) but PYTHONPATH's
    out = subprocess.run([sys.executable, "-P", "-c", READ, str(log)], env=env, check=True,
                         capture_output=True, text=True, timeout=900)
    result: dict[str, float] = json.loads(out.stdout)
    return result


def follow_line(mb: int, nmtcheck: str) -> tuple[float, str]:
    """`nmtcheck check --follow -` of a healthy log with one line of `mb` MB in the middle."""
    head = (HERE.parent / "samples" / "healthy.log").read_bytes()
    data = head + b"(" + b"7" * (mb << 20) + b"\n" + head
    began = time.perf_counter()
    res = subprocess.run([nmtcheck, "check", "--follow", "-", "--format", "json"], input=data,
                         capture_output=True, timeout=900)
    took = time.perf_counter() - began
    inputs = json.loads(res.stdout)["inputs"][0]
    return took, f"frames {inputs['frames']}, skipped {inputs['skipped']}"


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", default="80000")
    ap.add_argument("--kinds", default="channels,extended,errorframes,canids")
    ap.add_argument("--data", default="/tmp/nmtcheck-patho", type=Path)
    ap.add_argument("--pythonpath", default=str(HERE.parent),
                    help="the checkout whose nmtcheck package is measured")
    ap.add_argument("--follow-line-mb", type=int, default=0)
    ap.add_argument("--nmtcheck", default=str(Path(sys.executable).parent / "nmtcheck"))
    args = ap.parse_args()
    if args.follow_line_mb:
        took, what = follow_line(args.follow_line_mb, args.nmtcheck)
        print(f"check --follow - with one {args.follow_line_mb} MB line: {took:.2f} s ({what})")
        return
    print("| kind | frames | channels | extended | error frames | read s | max RSS MB |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    for kind in args.kinds.split(","):
        if kind not in KINDS:
            ap.error(f"unknown kind {kind}")
        for n in (parse_size(x) for x in args.sizes.split(",")):
            log = generate(kind, n, args.data)
            r = read_one(log, args.pythonpath)
            print(f"| {kind}-{label(n)} | {r['frames']:,.0f} | {r['channels']:,.0f} | "
                  f"{r['extended']:,.0f} | {r['error_frames']:,.0f} | {r['seconds']:.2f} | "
                  f"{r['max_rss_mb']:.0f} |", flush=True)


if __name__ == "__main__":
    main()
