"""A candump log of one SDO segmented download that never ends (issue 39).

    python bench/sdo_endless.py 3M /tmp/sdo-endless-3M.log [--probe]

Node 5 boots, node 1 (the client) initiates a segmented download of 2000h:01 and then
sends `segments` segments of 7 bytes, never the last one (c = 0), each answered by the
server (toggle bit alternating): 2 x segments + 2 frames, 1 ms apart. `--probe` first
reads 1000h:00 (the boot signature of SPEC_BOOT §8.2.4): the transfers of node 5 are then
rebuilt as a boot process's. `bench/PATHOLOGICAL.md` has its figures.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run import parse_size


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("segments")
    ap.add_argument("out", type=Path)
    ap.add_argument("--probe", action="store_true")
    args = ap.parse_args()
    n = parse_size(args.segments)
    t = 1_000_000  # µs
    with args.out.open("w") as f:
        def put(can_id: str, data: str) -> None:
            nonlocal t
            f.write(f"({t // 1_000_000}.{t % 1_000_000:06d}) can0 {can_id}#{data}\n")
            t += 1000
        put("705", "00")
        if args.probe:
            put("605", "4000100000000000")
            put("585", "4300100092010000")
        put("605", "2100200100000000")  # segmented download, size not indicated
        put("585", "6000200100000000")
        chunk = []
        for k in range(n):
            toggle = (k & 1) << 4
            chunk.append(f"({t // 1_000_000}.{t % 1_000_000:06d}) can0 605#"
                         f"{toggle:02X}{k & 0xFFFFFFFFFFFFFF:014X}\n")
            t += 1000
            chunk.append(f"({t // 1_000_000}.{t % 1_000_000:06d}) can0 585#"
                         f"{0x20 | toggle:02X}00000000000000\n")
            t += 1000
            if len(chunk) >= 100_000:
                f.write("".join(chunk))
                chunk.clear()
        f.write("".join(chunk))


if __name__ == "__main__":
    main()
