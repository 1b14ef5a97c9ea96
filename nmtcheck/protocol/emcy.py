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


# CANopenNode's internal error bit (byte 3) with the info it writes in bytes 4-7, per error
# code (SPEC §9.1.7: CN `CO_Emergency.c`, `CO_SYNC.c`, `CO_HBconsumer.c`, `CO_PDO.c`). Bytes
# 3-7 of other stacks are arbitrary, so they are read as CN's only for these pairs.
CANOPENNODE = {
    (0x8100, 0x15): ("TPDO outside SYNC window", None),
    (0x8100, 0x18): ("SYNC timeout", "us since the last SYNC"),  # info: the elapsed time
    (0x8110, 0x13): ("CAN receive buffer overflow", None),
    (0x8110, 0x14): ("CAN transmit buffer overflow", None),
    (0x8120, 0x06): ("CAN receive error passive", None),
    (0x8120, 0x07): ("CAN transmit error passive", None),
    (0x8130, 0x1B): ("heartbeat consumer timeout", "1016h sub-index - 1"),
    (0x8130, 0x1C): ("monitored node sent a boot-up", "1016h sub-index - 1"),
    (0x8140, 0x12): ("bus-off, sent after recovery", None),
    (0x8210, 0x04): ("RPDO shorter than its mapping", "mapped length"),
    (0x8220, 0x04): ("RPDO longer than its mapping", "mapped length"),
    (0x8240, 0x19): ("SYNC length", "DLC | 40h or DLC | 80h"),
    (0x8250, 0x17): ("RPDO timeout", "us since the timer was armed"),
}
GENERIC_CRITICAL = range(0x28, 0x30)  # CN errors that set register bit 0 (application's)


def canopennode_detail(data: bytes | list[int], dlc: int) -> dict[str, object] | None:
    """`{"error_bit", "info", "meaning"}` when (code, byte 3) is a CANopenNode pair of
    SPEC §9.1.7 (an error reset carries the byte 3 of the error it clears), else None."""
    if dlc < 8:
        return None
    code, bit = data[0] | data[1] << 8, data[3]
    info = int.from_bytes(bytes(data[4:8]), "little")
    known = CANOPENNODE.get((code, bit))
    if known is not None:
        meaning = known[0] + (f" ({known[1]} = {info})" if known[1] else "")
    elif bit in GENERIC_CRITICAL and code >= 0x100 and data[2] & 1:
        meaning = "generic-critical error of the application"
    else:
        return None
    return {"error_bit": f"{bit:02X}h", "info": info, "meaning": meaning}


def in_error(code: int, register: int) -> bool:
    """SPEC §9.1.7: the latest EMCY leaves its node in error when its code is 0100h or
    more, or an error reset (below 0100h) still reports a register other than 00h."""
    return code >= 0x100 or register != 0
