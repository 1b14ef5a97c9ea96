"""An EDS of many manufacturer objects (issue 39): 1017h, then RECORDs 2000h, 2001h, ...
of sub-indices 0..3 each (a sub-object count of 4 x records).

    python bench/big_eds.py 25000 /tmp/big.eds     # 100,000 sub-objects, 13 MB
    /usr/bin/time -v nmtcheck check samples/healthy.log --dcf 5=/tmp/big.eds

`bench/PATHOLOGICAL.md` has its figures.
"""

from __future__ import annotations

import argparse
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("records", type=int, help="at most 57,344 (2000h-FFFFh)")
    ap.add_argument("out", type=Path)
    args = ap.parse_args()
    if not 0 <= args.records <= 0x10000 - 0x2000:
        ap.error("records: 0..57344")
    with args.out.open("w") as f:
        f.write("[FileInfo]\nFileName=big.eds\n[DeviceInfo]\nVendorNumber=0x1234\n"
                "ProductNumber=0x1\n[DeviceComissioning]\nNodeID=5\n"
                "[1017]\nParameterName=Producer heartbeat time\nObjectType=0x7\n"
                "DataType=0x0006\nAccessType=rw\nDefaultValue=100\nPDOMapping=0\n")
        for i in range(args.records):
            index = 0x2000 + i
            f.write(f"[{index:04X}]\nParameterName=Object {i}\nObjectType=0x9\nSubNumber=4\n"
                    f"[{index:04X}sub0]\nParameterName=Highest sub-index\nObjectType=0x7\n"
                    "DataType=0x0005\nAccessType=ro\nDefaultValue=3\nPDOMapping=0\n")
            for sub in (1, 2, 3):
                f.write(f"[{index:04X}sub{sub}]\nParameterName=Value {sub}\nObjectType=0x7\n"
                        f"DataType=0x0007\nAccessType=rw\nDefaultValue=0x{sub:08X}\n"
                        "PDOMapping=1\n")


if __name__ == "__main__":
    main()
