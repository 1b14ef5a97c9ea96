"""Valid logs of one small CANopen network in every input format, for the hostile-input tests
and the fuzz targets (their seeds), and what each format counts as a record.

The network: an NMT start, three nodes booting and sending heartbeats every 100 ms, node 3
silent for 1.2 s (H001), node 1 sending a TPDO while pre-operational (S001), and filler
frames that no rule looks at (ID 6A0h, an extended ID) — corrupting those must change
nothing but the counts.
"""

from __future__ import annotations

import base64
import io
import struct
import zlib
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone

import can  # before asammdf: importing asammdf first leaves python-can without its MF4Writer

T0 = 1_700_000_000.0  # epoch of the first frame in the formats that write epoch times
FILLER_IDS = (0x6A0, 0x1ABCDE0)


@dataclass(frozen=True)
class Frame:
    t: float  # seconds from the first frame (whole milliseconds: every format can write it)
    can_id: int
    data: bytes = b""
    ext: bool = False

    @property
    def filler(self) -> bool:
        """No rule looks at this frame."""
        return self.can_id in FILLER_IDS


def network_frames() -> list[Frame]:
    """The trace every writer below writes: about 120 frames over 3 s."""
    frames = [Frame(0.0, 0x000, b"\x82\x00")]  # reset communication, all nodes
    frames += [Frame(0.010 + 0.001 * n, 0x700 + n, b"\x00") for n in (1, 2, 3)]  # boot-ups
    frames.append(Frame(0.020, 0x181, b"\x11\x22"))  # node 1 TPDO while pre-operational: S001
    frames.append(Frame(0.050, 0x000, b"\x01\x00"))  # start all
    for k in range(1, 30):
        t = 0.1 * k
        for n in (1, 2, 3):
            if n == 3 and 1.0 < t < 2.25:
                continue  # node 3 falls silent: H001
            frames.append(Frame(round(t + 0.002 * n, 3), 0x700 + n, b"\x05"))
        if k % 3 == 0:
            frames.append(Frame(round(t + 0.007, 3), 0x6A0, bytes([k, 0xAA])))
        if k % 4 == 0:
            frames.append(Frame(round(t + 0.008, 3), 0x1ABCDE0, bytes([k]) * 8, ext=True))
        if k % 5 == 0:
            frames.append(Frame(round(t + 0.009, 3), 0x182, bytes([k, 1, 2, 3])))
    frames.sort(key=lambda f: f.t)
    return frames


# --- text formats -------------------------------------------------------------------------


def _hex_id(f: Frame, width11: int = 3) -> str:
    return f"{f.can_id:08X}" if f.ext else f"{f.can_id:0{width11}X}"


def candump(frames: list[Frame]) -> bytes:
    return "".join(f"({T0 + f.t:.6f}) can0 {_hex_id(f)}#{f.data.hex().upper()}\n"
                   for f in frames).encode()


def asc(frames: list[Frame]) -> bytes:
    head = ("date Tue Nov 14 22:13:20.000 2023\nbase hex  timestamps absolute\n"
            "internal events logged\n// version 9.0.0\n"
            "Begin Triggerblock Tue Nov 14 22:13:20.000 2023\n   0.000000 Start of measurement\n")
    rows = []
    for f in frames:
        ident = f"{f.can_id:X}x" if f.ext else f"{f.can_id:X}"
        data = " ".join(f"{b:02X}" for b in f.data)
        rows.append(f"{f.t:11.6f} 1  {ident:<15} Rx   d {len(f.data)} {data}\n")
    return (head + "".join(rows) + "End TriggerBlock\n").encode()


def trc(frames: list[Frame]) -> bytes:
    """PEAK TRC 2.1 (PCAN-View 5)."""
    head = (";$FILEVERSION=2.1\n;$STARTTIME=45244.9259259259\n"
            ";$COLUMNS=N,O,T,B,I,d,R,L,D\n;\n;   Start time: 14.11.2023 22:13:20.000.0\n"
            ";---+-- ----+---- --+-- ---+ ---+---- -+ -+ -+ -- -- -- -- -- -- -- --\n")
    rows = []
    for i, f in enumerate(frames, 1):
        data = " ".join(f"{b:02X}" for b in f.data)
        rows.append(f"{i:>7} {f.t * 1000:13.3f} DT 1 {_hex_id(f, 4):>8} Rx - {len(f.data)}"
                    f"  {data}\n")
    return (head + "".join(rows)).encode()


def candump_screen(frames: list[Frame]) -> bytes:
    """`candump -ta can0` output."""
    return "".join(f"({T0 + f.t:.6f})  can0  {_hex_id(f):>3}   [{len(f.data)}]  "
                   + " ".join(f"{b:02X}" for b in f.data) + "\n" for f in frames).encode()


def csv_python_can(frames: list[Frame]) -> bytes:
    rows = ["timestamp,arbitration_id,extended,remote,error,dlc,data\n"]
    rows += [f"{T0 + f.t:.6f},0x{f.can_id:X},{int(f.ext)},0,0,{len(f.data)},"
             f"{base64.b64encode(f.data).decode()}\n" for f in frames]
    return "".join(rows).encode()


def csv_savvycan(frames: list[Frame]) -> bytes:
    rows = ["Time Stamp,ID,Extended,Dir,Bus,LEN,D1,D2,D3,D4,D5,D6,D7,D8\n"]
    for f in frames:
        cells = [f"{b:02X}" for b in f.data] + ["00"] * (8 - len(f.data))
        rows.append(f"{round((T0 + f.t) * 1e6)},{f.can_id:08X},{str(f.ext).lower()},Rx,0,"
                    f"{len(f.data)},{','.join(cells)},\n")
    return "".join(rows).encode()


CL2000_START = datetime(2017, 1, 1, 2, 22, 32, tzinfo=timezone.utc)


def cl2000(frames: list[Frame]) -> bytes:
    head = ("# Logger type: CL2000\n# HW rev: 6.xx\n# FW rev: 5.31\n# Logger ID: TEST\n"
            "# Session No.: 1\n# Split No.: 1\n# Time: 20170101T022232\n"
            '# Value separator: ";"\n# Time format: 4\n# Time separator: ""\n'
            '# Time separator ms: ""\n# Date separator: ""\n# Time and date separator: "T"\n'
            "Timestamp;Type;ID;Data\n")
    rows = []
    for f in frames:
        when = CL2000_START + timedelta(milliseconds=round(f.t * 1000))
        stamp = when.strftime("%dT%H%M%S") + f"{when.microsecond // 1000:03d}"
        rows.append(f"{stamp};{1 if f.ext else 0};{f.can_id:x};{f.data.hex()}\n")
    return (head + "".join(rows)).encode()


TEXT_WRITERS = {
    "candump": candump,
    "asc": asc,
    "trc": trc,
    "candump-screen": candump_screen,
    "csv": csv_python_can,
    "csv-savvycan": csv_savvycan,
    "cl2000": cl2000,
}


def format_of(writer: str) -> str:
    """The reader a writer's logs go to (`csv-savvycan` -> `csv`, `pcapng` -> `pcap`…)."""
    return {"csv-savvycan": "csv", "pcapng": "pcap", "blf-plain": "blf"}.get(writer, writer)


def record_lines(fmt: str, data: bytes) -> list[int]:
    """1-based numbers of the lines of a text log that are records (frames, non-frame records,
    or lines that should be but do not parse), by the format's own rules for what is not a
    record: blank lines, comments, headers."""
    lines = data.split(b"\n")
    if lines and lines[-1] == b"":
        lines.pop()
    if lines and lines[0].startswith(b"\xef\xbb\xbf"):
        lines[0] = lines[0][3:]
    out = []
    header_done = False
    explaining = False  # candump-screen: right below an error frame (`-e` explains it)
    for no, raw in enumerate(lines, 1):
        line = raw.strip()
        if not line:
            continue
        if fmt == "trc" and line.startswith(b";"):
            continue
        if fmt == "cl2000" and line.startswith(b"#"):
            continue
        if fmt == "candump-screen":
            # `-e` prints an error frame's explanation on tab-indented lines below it; any
            # other tab-indented line is a record (SPEC §1: leading white space is no part
            # of a record)
            if explaining and raw[:1] == b"\t" and b"[" not in raw:
                continue
            explaining = b"ERRORFRAME" in raw
        if fmt == "asc" and _asc_header(raw):
            continue
        if fmt in ("csv", "cl2000") and not header_done:
            header_done = True  # the column line
            continue
        out.append(no)
    return out


def _asc_header(raw: bytes) -> bool:
    tokens = raw.split()
    first = tokens[0].lower()
    return (first in (b"date", b"//", b"base") or first.startswith(b"//")
            or (first in (b"internal", b"no") and b"events" in raw.lower())
            or (first in (b"begin", b"end") and len(tokens) > 1
                and tokens[1].lower() == b"triggerblock"))


# --- binary formats -----------------------------------------------------------------------


def blf(frames: list[Frame], compressed: bool = True, per_container: int = 16) -> bytes:
    """Vector BLF: CAN_MESSAGE objects in log containers of `per_container` objects."""
    head = struct.pack("<4sLBBBBBBBBQQLL8H8H", b"LOGG", 144, 5, 0, 0, 0, 2, 6, 8, 1, 0, 0,
                       len(frames), len(frames), 2023, 11, 2, 14, 22, 13, 20, 0,
                       2023, 11, 2, 14, 22, 13, 23, 0).ljust(144, b"\0")
    objects = []
    for f in frames:
        body = struct.pack("<HBBL8s", 1, 0, len(f.data), f.can_id | (0x80000000 if f.ext else 0),
                           f.data)
        header = struct.pack("<LHHQ", 2, 0, 0, round(f.t * 1e9))
        objects.append(struct.pack("<4sHHLL", b"LOBJ", 32, 1, 32 + len(body), 1) + header + body)
    out = [head]
    for i in range(0, len(objects), per_container):
        payload = b"".join(objects[i:i + per_container])
        stored = zlib.compress(payload) if compressed else payload
        total = 32 + len(stored)
        out.append(struct.pack("<4sHHLL", b"LOBJ", 16, 1, total, 10)
                   + struct.pack("<H6xL4x", 2 if compressed else 0, len(payload)) + stored
                   + b"\0" * (total % 4))
    return b"".join(out)


PCAP_RECORD = 16 + 16  # record header + a 16-byte SocketCAN frame


def pcap(frames: list[Frame]) -> bytes:
    """Classic pcap, LINKTYPE_CAN_SOCKETCAN, big-endian CAN-IDs, one record per frame."""
    out = [struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 262144, 227)]
    for f in frames:
        sec, us = divmod(round((T0 + f.t) * 1e6), 10**6)
        raw_id = f.can_id | (0x80000000 if f.ext else 0)
        pkt = struct.pack(">I", raw_id) + bytes([len(f.data), 0, 0, 0]) + f.data.ljust(8, b"\0")
        out.append(struct.pack("<IIII", sec, us, len(pkt), len(pkt)) + pkt)
    return b"".join(out)


def _pcapng_block(btype: int, body: bytes) -> bytes:
    body += b"\0" * (-len(body) % 4)
    return struct.pack("<II", btype, len(body) + 12) + body + struct.pack("<I", len(body) + 12)


def pcapng(frames: list[Frame]) -> bytes:
    """pcapng: a section, an interface `can0` (µs), one Enhanced Packet Block per frame."""
    out = [_pcapng_block(0x0A0D0D0A, struct.pack("<IHHq", 0x1A2B3C4D, 1, 0, -1)),
           _pcapng_block(1, struct.pack("<HHI", 227, 0, 262144)
                         + struct.pack("<HH", 2, 4) + b"can0" + struct.pack("<HH", 0, 0))]
    for f in frames:
        ticks = round((T0 + f.t) * 1e6)
        raw_id = f.can_id | (0x80000000 if f.ext else 0)
        pkt = struct.pack(">I", raw_id) + bytes([len(f.data), 0, 0, 0]) + f.data.ljust(8, b"\0")
        out.append(_pcapng_block(6, struct.pack("<IIIII", 0, ticks >> 32, ticks & 0xFFFFFFFF,
                                                len(pkt), len(pkt)) + pkt))
    return b"".join(out)


ROS2_FRAME_MSG = """\
std_msgs/Header header
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


def mcap(frames: list[Frame], chunk_size: int = 2048) -> bytes:
    """ROS 2 can_msgs/msg/Frame messages on /can, in small chunks (many chunks to cut)."""
    from mcap_ros2.writer import Writer

    out = io.BytesIO()
    writer = Writer(out, chunk_size=chunk_size)
    schema = writer.register_msgdef("can_msgs/msg/Frame", ROS2_FRAME_MSG)
    for f in frames:
        ns = round((T0 + f.t) * 1e9)
        writer.write_message("/can", schema, {
            "header": {"stamp": {"sec": ns // 10**9, "nanosec": ns % 10**9}, "frame_id": "can0"},
            "id": f.can_id, "is_rtr": False, "is_extended": f.ext, "is_error": False,
            "dlc": len(f.data), "data": f.data.ljust(8, b"\0")}, log_time=ns)
    writer.finish()
    return out.getvalue()


def mcap_json(messages: list[bytes]) -> bytes:
    """Raw JSON message payloads on topic /can (schemaless JSON), one chunk."""
    from mcap.writer import Writer

    out = io.BytesIO()
    writer = Writer(out)
    writer.start()
    channel = writer.register_channel("/can", "json", 0)
    for i, payload in enumerate(messages):
        writer.add_message(channel, log_time=i, publish_time=i, data=payload)
    writer.finish()
    return out.getvalue()


def mf4(frames: list[Frame], path: str) -> None:
    """python-can's MF4Writer (needs asammdf)."""
    writer = can.MF4Writer(path)
    for f in frames:
        writer.on_message_received(can.Message(timestamp=T0 + f.t, arbitration_id=f.can_id,
                                               is_extended_id=f.ext, data=f.data, channel=0))
    writer.stop()


BINARY_WRITERS = {"blf": blf, "blf-plain": lambda frames: blf(frames, compressed=False),
                  "pcap": pcap, "pcapng": pcapng, "mcap": mcap}
