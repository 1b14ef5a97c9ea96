"""Write the benchmark's CANopen traffic (bench/traffic.py) as candump, ASC, BLF and MCAP.

Text formats are formatted vectorised (20 M lines in seconds); BLF goes through
python-can's BLFWriter and MCAP through mcap_ros2's writer (`can_msgs/msg/Frame`
on topic `/can0`), so those files are what the real libraries produce.

    python bench/generate.py 1000000 /tmp/nmtcheck-bench   # writes bench-1M.{log,asc,blf,mcap}
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from traffic import T0_US, Frames, traffic

HEX = np.frombuffer(b"0123456789ABCDEF", np.uint8)
FORMATS = ("candump", "asc", "blf", "mcap")
SUFFIX = {"candump": "log", "asc": "asc", "blf": "blf", "mcap": "mcap"}


def _digits(x: np.ndarray, width: int) -> np.ndarray:
    """ASCII decimal digits of non-negative ints, zero padded to `width`: uint8 [n, width]."""
    powers = 10 ** np.arange(width - 1, -1, -1, dtype=np.int64)
    return ((x[:, None] // powers) % 10 + 48).astype(np.uint8)


def _hex_bytes(data: np.ndarray) -> np.ndarray:
    """Upper-case hex of each byte: uint8 [n, 8, 2]."""
    return np.stack([HEX[data >> 4], HEX[data & 15]], axis=-1)


def _join(cols: list[tuple[np.ndarray, np.ndarray | None]]) -> bytes:
    """Concatenate per-row fields; each field is (uint8 [n, w], keep mask [n, w] or None)."""
    mat = np.concatenate([c for c, _ in cols], axis=1)
    keep = np.concatenate([np.ones(c.shape, bool) if k is None else k for c, k in cols], axis=1)
    out: bytes = mat[keep].tobytes()
    return out


def _const(n: int, text: bytes) -> tuple[np.ndarray, None]:
    return np.broadcast_to(np.frombuffer(text, np.uint8), (n, len(text))), None


def candump_lines(f: Frames) -> bytes:
    """`(1700000000.123456) can0 181#0102030405060708` as `candump -l` writes it (a remote
    request: `705#R`)."""
    n = len(f)
    sec, us = np.divmod(f.us, 10**6)
    hexd = _hex_bytes(f.data).reshape(n, 16)
    data_keep = np.arange(16)[None, :] < 2 * f.dlc[:, None].astype(np.int64)
    rtr = np.zeros((n, 1), bool) if f.rtr is None else f.rtr.reshape(n, 1).astype(bool)
    data_keep &= ~rtr
    ids = f.can_id.astype(np.int64)
    return _join([
        _const(n, b"("), (_digits(sec, 10), None), _const(n, b"."), (_digits(us, 6), None),
        _const(n, b") can0 "),
        (np.stack([HEX[(ids >> 8) & 15], HEX[(ids >> 4) & 15], HEX[ids & 15]], 1), None),
        _const(n, b"#"), (hexd, data_keep), (np.full((n, 1), ord("R"), np.uint8), rtr),
        _const(n, b"\n"),
    ])


def asc_lines(f: Frames) -> bytes:
    """CANoe's classic line: `   0.010123 1  181             Rx   d 8 01 … 08  Length = …`."""
    n = len(f)
    rel = f.us - T0_US
    sec, us = np.divmod(rel, 10**6)
    width = max(4, len(str(int(sec.max(initial=0)))))
    sec_digits = _digits(sec, width)
    used = np.ones_like(sec)
    for k in range(1, width):
        used += sec >= 10**k
    sec_digits[np.arange(width)[None, :] < (width - used)[:, None]] = 32  # like %11.6f
    ids = f.can_id.astype(np.int64)
    id_hex = np.stack([HEX[(ids >> 8) & 15], HEX[(ids >> 4) & 15], HEX[ids & 15]], 1)
    dlc = f.dlc.astype(np.int64)
    hexd = _hex_bytes(f.data)  # [n, 8, 2]
    data = np.concatenate([hexd, np.full((n, 8, 1), 32, np.uint8)], axis=2).reshape(n, 24)
    data_keep = np.arange(24)[None, :] < 3 * dlc[:, None]
    dec_width = np.where(ids >= 1000, 4, np.where(ids >= 100, 3, np.where(ids >= 10, 2, 1)))
    dec = _digits(ids, 4)
    dec_keep = np.arange(4)[None, :] >= (4 - dec_width)[:, None]
    bits = 100 + 10 * dlc  # a plausible bit count for the Length/BitCount fields
    return _join([
        (sec_digits, None),
        _const(n, b"."), (_digits(us, 6), None), _const(n, b" 1  "), (id_hex, None),
        _const(n, b"             Rx   d "), ((dlc + 48).astype(np.uint8)[:, None], None),
        _const(n, b" "), (data, data_keep), _const(n, b" Length = "),
        (_digits(bits * 2000, 6), None), _const(n, b" BitCount = "), (_digits(bits, 3), None),
        _const(n, b" ID = "), (dec, dec_keep), _const(n, b"\n"),
    ])


ASC_HEADER = (b"date Tue Nov 14 22:13:20.000 2023\nbase hex  timestamps absolute\n"
              b"internal events logged\n// version 13.0.0\n"
              b"Begin Triggerblock Tue Nov 14 22:13:20.000 2023\n"
              b"   0.000000 Start of measurement\n")


def write_text(path: Path, chunks: Iterable[Frames], fmt: Callable[[Frames], bytes],
               header: bytes = b"", footer: bytes = b"") -> None:
    with open(path, "wb") as out:
        out.write(header)
        for f in chunks:
            out.write(fmt(f))
        out.write(footer)


def write_blf(path: Path, chunks: Iterable[Frames]) -> None:
    import can

    with can.BLFWriter(str(path)) as writer:
        for f in chunks:
            ts = (f.us / 1e6).tolist()
            for t, cid, dlc, row in zip(ts, f.can_id.tolist(), f.dlc.tolist(), f.data,
                                        strict=True):
                writer.on_message_received(can.Message(
                    timestamp=t, arbitration_id=cid, is_extended_id=False, dlc=dlc,
                    data=bytes(row[:dlc]), channel=0))


CAN_FRAME_MSGDEF = """std_msgs/Header header
uint32 id
bool is_rtr
bool is_extended
bool is_error
uint8 dlc
uint8[8] data
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""


def write_mcap(path: Path, chunks: Iterable[Frames]) -> None:
    from mcap_ros2.writer import Writer

    with open(path, "wb") as out:
        writer = Writer(out)
        schema = writer.register_msgdef("can_msgs/msg/Frame", CAN_FRAME_MSGDEF)
        for f in chunks:
            sec, us = np.divmod(f.us, 10**6)
            for s, u, cid, dlc, row in zip(sec.tolist(), us.tolist(), f.can_id.tolist(),
                                           f.dlc.tolist(), f.data.tolist(), strict=True):
                ns = s * 10**9 + u * 1000
                writer.write_message("/can0", schema, {
                    "header": {"stamp": {"sec": s, "nanosec": u * 1000}, "frame_id": "can0"},
                    "id": cid, "is_rtr": False, "is_extended": False, "is_error": False,
                    "dlc": dlc, "data": row}, log_time=ns, publish_time=ns)
        writer.finish()


def path_for(out_dir: Path, n_frames: int, fmt: str) -> Path:
    label = f"{n_frames // 10**6}M" if n_frames % 10**6 == 0 else str(n_frames)
    return out_dir / f"bench-{label}.{SUFFIX[fmt]}"


def generate(n_frames: int, out_dir: Path, fmt: str) -> Path:
    """Write one file (if not there yet) and return its path."""
    path = path_for(out_dir, n_frames, fmt)
    if path.exists():
        return path
    out_dir.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".part")
    chunks = traffic(n_frames)
    if fmt == "candump":
        write_text(tmp, chunks, candump_lines)
    elif fmt == "asc":
        write_text(tmp, chunks, asc_lines, ASC_HEADER, b"End TriggerBlock\n")
    elif fmt == "blf":
        write_blf(tmp, chunks)
    elif fmt == "mcap":
        write_mcap(tmp, chunks)
    else:
        raise ValueError(fmt)
    os.replace(tmp, path)
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("frames", type=int)
    ap.add_argument("out_dir", type=Path)
    ap.add_argument("--formats", default=",".join(FORMATS))
    args = ap.parse_args()
    for fmt in args.formats.split(","):
        print(generate(args.frames, args.out_dir, fmt))


if __name__ == "__main__":
    main()
