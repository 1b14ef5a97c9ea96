"""The one frame shape the live code passes around, and its candump -L line.

The live session records every frame as a candump log so that its final verdict is
`nmtcheck check` on that recording (offline = online by construction).
"""

from __future__ import annotations

from typing import Any, NamedTuple

CAN_ERR_FLAG = 0x20000000


class LiveFrame(NamedTuple):
    ts: float  # seconds, the bus's own time base (python-can's Message.timestamp)
    channel: str
    can_id: int
    ext: bool = False
    rtr: bool = False
    err: bool = False
    fd: bool = False
    dlc: int = 0
    data: bytes = b""


def candump_line(f: LiveFrame) -> str:
    """`(ts) iface ID#DATA` exactly as `candump -L` writes it (what readers/candump reads)."""
    if f.err:
        ident = f"{(f.can_id | CAN_ERR_FLAG) & 0x3FFFFFFF:08X}"
    elif f.ext:
        ident = f"{f.can_id:08X}"
    else:
        ident = f"{f.can_id & 0x7FF:03X}"
    if f.fd:
        body = f"##0{f.data.hex().upper()}"
    elif f.rtr:
        body = f"#R{f.dlc}" if f.dlc else "#R"
    else:
        body = "#" + f.data[:8].hex().upper()
    channel = "".join(c if c.isprintable() and not c.isspace() else "_" for c in f.channel)
    return f"({f.ts:.6f}) {channel or 'can0'} {ident}{body}\n"


def from_message(msg: object, default_channel: str) -> LiveFrame:
    """A python-can `Message` as a LiveFrame; a message without a channel gets `default_channel`."""
    channel = getattr(msg, "channel", None)
    data = bytes(getattr(msg, "data", b"") or b"")
    return LiveFrame(float(getattr(msg, "timestamp", 0.0)),
                     default_channel if channel is None or channel == "" else str(channel),
                     int(getattr(msg, "arbitration_id", 0)),
                     bool(getattr(msg, "is_extended_id", False)),
                     bool(getattr(msg, "is_remote_frame", False)),
                     bool(getattr(msg, "is_error_frame", False)),
                     bool(getattr(msg, "is_fd", False)),
                     int(getattr(msg, "dlc", len(data))), data)


def to_message(f: LiveFrame) -> Any:
    """A LiveFrame as a python-can `Message` (for python-can's log writers)."""
    import can

    return can.Message(timestamp=f.ts, arbitration_id=f.can_id, is_extended_id=f.ext,
                       is_remote_frame=f.rtr, is_error_frame=f.err, is_fd=f.fd,
                       dlc=f.dlc, data=f.data, channel=f.channel, check=False)
