"""The cost of the SYNC, PDO and EMCY rules (SPEC §9) on the benchmark's traffic.

Checks the benchmark's candump log (bench/generate.py: a 10 ms SYNC, each of 16 nodes'
TPDO1 and RPDO1, TPDO2 of half of them, heartbeats, SDO, EMCY) twice in one run, rounds
interleaved: without a network file (the Y rules judge the SYNC by its measured period,
no PDO stream is known) and with one that gives the SYNC period and window and every
node's TPDO1/RPDO1 as synchronous (type 1), so Y001-Y005, D003 and Y004 judge every
frame. Prints the median wall time and peak RSS of each and their ratio.

    python bench/comm.py 5000000 /tmp/nmtcheck-bench --rounds 3
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


def network_file(path: Path) -> Path:
    """SYNC every 10 ms, window 5 ms; TPDO1 (180h+N) and RPDO1 (200h+N) of type 1."""
    lines = ["[sync]", "period_us = 10000", "window_us = 5000", ""]
    for n in range(1, 17):
        lines += [f"[nodes.{n}.tpdo.1]", f"cob_id = 0x{0x180 + n:X}", "transmission_type = 1",
                  "", f"[nodes.{n}.rpdo.1]", f"cob_id = 0x{0x200 + n:X}",
                  "transmission_type = 1", ""]
    path.write_text("\n".join(lines))
    return path


def run(log: Path, network: Path | None) -> tuple[float, int]:
    """(wall seconds, peak RSS in kB) of one `nmtcheck check -q`, from GNU time."""
    cmd = ["/usr/bin/time", "-f", "%e %M", sys.executable, "-m", "nmtcheck", "check", "-q",
           str(log), "--fail-on", "never"]
    if network is not None:
        cmd += ["--network", str(network)]
    res = subprocess.run(cmd, capture_output=True, text=True, check=True)
    wall, rss = res.stderr.strip().splitlines()[-1].split()
    return float(wall), int(rss)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("frames", type=int)
    ap.add_argument("out_dir", type=Path)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()
    args.out_dir.mkdir(parents=True, exist_ok=True)
    label = f"{args.frames // 1_000_000}M" if args.frames >= 1_000_000 else str(args.frames)
    log = args.out_dir / f"bench-{label}.log"
    if not log.exists():
        subprocess.run([sys.executable, str(HERE / "generate.py"), str(args.frames),
                        str(args.out_dir), "--formats", "candump"], check=True)
    net = network_file(args.out_dir / "bench-comm-network.toml")
    times: dict[str, list[tuple[float, int]]] = {"no network file": [], "SYNC + PDO file": []}
    for _ in range(args.rounds):
        times["no network file"].append(run(log, None))
        times["SYNC + PDO file"].append(run(log, net))
    base = statistics.median(t for t, _ in times["no network file"])
    for name, got in times.items():
        wall = statistics.median(t for t, _ in got)
        rss = max(r for _, r in got) / 1024
        print(f"{name:<16} {wall:6.2f} s  {rss:6.0f} MB  {wall / base:4.2f}x")


if __name__ == "__main__":
    main()
