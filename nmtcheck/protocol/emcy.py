"""EMCY messages (80h+N): error code meaning, error register bits, manufacturer bytes.

Decoded so a field engineer sees "EMCY 8130h heartbeat/life-guard error from node 1"
next to the timeout that caused it. Codes per CiA 301 Table 21 (the generic
classes) and the communication codes of §7.2.7.
"""

from __future__ import annotations

SPECIFIC = {
    0x0000: "error reset or no error",
    0x1000: "generic error",
    0x8100: "communication: generic",
    0x8110: "CAN overrun (objects lost)",
    0x8120: "CAN in error passive mode",
    0x8130: "life guard error or heartbeat error",
    0x8140: "recovered from bus off",
    0x8150: "CAN-ID collision",
    0x8200: "protocol error: generic",
    0x8210: "PDO not processed due to length error",
    0x8220: "PDO length exceeded",
    0x8230: "DAM MPDO not processed, destination object not available",
    0x8240: "unexpected SYNC data length",
    0x8250: "RPDO timeout",
    0x9000: "external error",
    0xF000: "additional functions",
    0xFF00: "device specific",
}
CLASSES = {
    0x1: "generic error", 0x2: "current", 0x3: "voltage", 0x4: "temperature",
    0x5: "device hardware", 0x6: "device software", 0x7: "additional modules",
    0x8: "monitoring", 0x9: "external error", 0xF: "additional functions",
}
REGISTER_BITS = ["generic", "current", "voltage", "temperature", "communication",
                 "device profile specific", "reserved", "manufacturer specific"]


def describe(data: bytes | list[int], dlc: int) -> tuple[int | None, str]:
    """(error code, one-line description) of an EMCY frame's data."""
    if dlc < 2:
        return None, f"malformed EMCY (DLC {dlc}, CiA 301 requires 8)"
    code = data[0] | data[1] << 8
    meaning = SPECIFIC.get(code) or SPECIFIC.get(code & 0xFF00) or CLASSES.get(code >> 12,
                                                                                "unknown")
    text = f"EMCY {code:04X}h {meaning}"
    if dlc >= 3:
        bits = [name for i, name in enumerate(REGISTER_BITS) if data[2] >> i & 1]
        text += f", error register {data[2]:02X}h" + (f" ({', '.join(bits)})" if bits else "")
    if dlc > 3:
        text += ", manufacturer data " + bytes(data[3:min(dlc, 8)]).hex(" ").upper()
    return code, text
