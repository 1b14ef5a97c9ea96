"""SDO frames that configure error control and PDOs, and SDO abort codes (CiA 301 §7.2.4).

Only the expedited downloads (client command specifier 1, `e` bit set:
23h/27h/2Bh/2Fh, and 22h without size) to 1016h, 1017h, 100Ch, 100Dh, the PDO
communication parameters, and the SYNC and EMCY objects of SPEC §9.1.1 (1005h, 1006h,
1007h, 1019h, 1014h, 1015h, 1029h:01) are applied; the server's 60h confirms one, 80h
aborts it. Segmented downloads to these objects are reported, not applied.
"""

from __future__ import annotations

PDO_COMM_OBJECTS = (0x1400, 0x1401, 0x1402, 0x1403, 0x1800, 0x1801, 0x1802, 0x1803)
# SPEC §9.1.1: one value at sub-index 0 (1029h: its sub 1, communication error)
COMM_OBJECTS = {0x1005: "COB-ID SYNC", 0x1006: "communication cycle period",
                0x1007: "synchronous window length", 0x1019: "synchronous counter overflow",
                0x1014: "COB-ID EMCY", 0x1015: "inhibit time EMCY"}
ERROR_BEHAVIOUR = 0x1029
CONFIG_OBJECTS = {0x1016: "consumer heartbeat time", 0x1017: "producer heartbeat time",
                  0x100C: "guard time", 0x100D: "life time factor",
                  **{0x1400 + n: f"RPDO{n + 1} communication parameter" for n in range(4)},
                  **{0x1800 + n: f"TPDO{n + 1} communication parameter" for n in range(4)},
                  **COMM_OBJECTS, ERROR_BEHAVIOUR: "error behaviour"}

ABORT_CODES = {
    0x05030000: "toggle bit not alternated",
    0x05040000: "SDO protocol timed out",
    0x05040001: "client/server command specifier not valid or unknown",
    0x05040002: "invalid block size",
    0x05040003: "invalid sequence number",
    0x05040004: "CRC error",
    0x05040005: "out of memory",
    0x06010000: "unsupported access to an object",
    0x06010001: "attempt to read a write only object",
    0x06010002: "attempt to write a read only object",
    0x06020000: "object does not exist in the object dictionary",
    0x06040041: "object cannot be mapped to the PDO",
    0x06040042: "the number and length of the objects to be mapped would exceed PDO length",
    0x06040043: "general parameter incompatibility reason",
    0x06040047: "general internal incompatibility in the device",
    0x06060000: "access failed due to a hardware error",
    0x06070010: "data type does not match, length of service parameter does not match",
    0x06070012: "data type does not match, length of service parameter too high",
    0x06070013: "data type does not match, length of service parameter too low",
    0x06090011: "sub-index does not exist",
    0x06090030: "invalid value for parameter (download only)",
    0x06090031: "value of parameter written too high (download only)",
    0x06090032: "value of parameter written too low (download only)",
    0x06090036: "maximum value is less than minimum value",
    0x060A0023: "resource not available: SDO connection",
    0x08000000: "general error",
    0x08000020: "data cannot be transferred or stored to the application",
    0x08000021: "data cannot be transferred or stored to the application because of local control",
    0x08000022: "data cannot be transferred or stored to the application because of the "
                "present device state",
    0x08000023: "object dictionary dynamic generation fails or no object dictionary is present",
    0x08000024: "no data available",
}


def abort_text(code: int) -> str:
    return ABORT_CODES.get(code, "unknown abort code")


def is_config_index(index: int, sub: int) -> bool:
    if index in (0x1017, 0x100C, 0x100D) or index in COMM_OBJECTS:
        return sub == 0
    if index == 0x1016:
        return 1 <= sub <= 127
    return (index in PDO_COMM_OBJECTS or index == ERROR_BEHAVIOUR) and sub == 1


def is_pdo_param(index: int, sub: int) -> bool:
    """A PDO parameter of SPEC §9.1.1 other than the COB-ID of PDOs 1-4 (which
    `is_config_index` covers): sub 1 (COB-ID), 2 (type), 3 (inhibit time) and 5 (event
    timer) of 1400h-15FFh and 1800h-19FFh, sub 0..40h of the mappings 1600h-17FFh and
    1A00h-1BFFh. Written by SDO in the trace, they are applied to the PDO streams."""
    if 0x1400 <= index <= 0x15FF or 0x1800 <= index <= 0x19FF:
        return sub in (1, 2, 3, 5) and not is_config_index(index, sub)
    return (0x1600 <= index <= 0x17FF or 0x1A00 <= index <= 0x1BFF) and sub <= 0x40


def expedited_value(data: bytes | list[int]) -> int | None:
    """The value of an expedited download request (bytes 4..7, length from byte 0)."""
    cmd = data[0]
    if cmd & 0xE0 != 0x20 or not cmd & 0x02:  # not a download initiate, or not expedited
        return None
    size = 4 - ((cmd >> 2) & 0x3) if cmd & 0x01 else 4
    return int.from_bytes(bytes(data[4 : 4 + size]), "little")


def object_name(index: int, sub: int) -> str:
    name = CONFIG_OBJECTS.get(index, "object")
    return f"{index:04X}h sub {sub} ({name})"
