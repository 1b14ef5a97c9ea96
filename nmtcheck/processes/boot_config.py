"""What the network file and the manager's files say about the CiA 302-2 boot-slave process
(SPEC §8.2): the `[boot]` table (top level or `[channels.NAME.boot]`), the per-node keys
spelled as ros2_canopen's `bus.yml`, the master DCF and dcfgen's concise `master.bin`,
and the node's own EDS for the expected identity."""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from nmtcheck.errors import UsageError

BOOT_KEYS: dict[str, type] = {"manager": bool, "master_dcf": str, "master_bin": str,
                              "startup": int, "boot_time_ms": float,
                              "manager_sdo_timeout_ms": float}

# per-node keys: name -> (type, object it stands for)
NODE_KEYS: dict[str, type] = {
    "assignment": int, "boot": bool, "mandatory": bool, "reset_communication": bool,
    "device_type": int, "vendor_id": int, "product_code": int, "revision_number": int,
    "serial_number": int, "configuration_date": int, "configuration_time": int,
    "software_version": int, "manager_consumer_ms": float}

IDENTITY = {"device_type": 0x1F84, "vendor_id": 0x1F85, "product_code": 0x1F86,
            "revision_number": 0x1F87, "serial_number": 0x1F88}


@dataclass
class BootTable:
    """One `[boot]` table (the keys given; None: absent)."""

    manager: bool | None = None
    master_dcf: str | None = None
    master_bin: str | None = None
    startup: int | None = None
    boot_time_ms: float | None = None
    manager_sdo_timeout_ms: float | None = None


@dataclass
class Expected:
    value: int | None  # None: unknown (not checked); 0: not checked
    source: str | None  # network | master-dcf | master-bin | node-dcf | None


@dataclass
class NodeBoot:
    """What the configuration says of one slave (None: unknown)."""

    assignment: int | None = None
    assignment_source: str | None = None
    manager_consumer_ms: float | None = None
    identity: dict[str, Expected] = field(default_factory=dict)

    def bit(self, n: int) -> bool | None:
        return None if self.assignment is None else bool(self.assignment >> n & 1)

    @property
    def mandatory(self) -> bool:
        return bool(self.bit(0) and self.bit(3))

    @property
    def keep_alive(self) -> bool | None:
        return self.bit(4)


@dataclass
class BootConfig:
    """The boot configuration of one channel."""

    table: BootTable = field(default_factory=BootTable)
    startup: int | None = None  # 1F80h
    boot_time_ms: float = 0.0  # 1F89h
    master_dcf_known: bool = False  # a master DCF with 1F80h bit 0
    nodes: dict[int, NodeBoot] = field(default_factory=dict)


def _typed(where: str, value: Any, want: type) -> Any:
    if want is bool:
        if isinstance(value, bool):
            return value
    elif want is int:
        if isinstance(value, int) and not isinstance(value, bool) and value >= 0:
            return value
    elif want is float:
        # a time: finite and at most 1e9 ms (nan, inf and 1e308 are no time)
        if isinstance(value, (int, float)) and not isinstance(value, bool) and 0 <= value <= 1e9:
            return float(value)
    elif isinstance(value, want):
        return value
    raise UsageError(f"{where}: expected {want.__name__}, got {value!r}")


def read_boot_table(where: str, table: Any, base: Path) -> BootTable:
    """A `[boot]` table, validated; file paths made relative to the network file."""
    if not isinstance(table, dict):
        raise UsageError(f"{where}: expected a table [boot]")
    out = BootTable()
    for key, value in table.items():
        if key not in BOOT_KEYS:
            raise UsageError(f"{where} {key}: unknown key (known: {', '.join(BOOT_KEYS)})")
        v = _typed(f"{where} {key}", value, BOOT_KEYS[key])
        if key in ("master_dcf", "master_bin"):
            v = str(base / v)
        setattr(out, key, v)
    return out


def read_node_key(where: str, key: str, value: Any) -> Any:
    return _typed(where, value, NODE_KEYS[key])


def read_master_bin(path: str) -> dict[tuple[int, int], int]:
    """dcfgen's concise DCF: UNSIGNED32 count, then per entry index (U16), sub (U8), size
    (U32) and the data, little-endian (values of up to 8 bytes kept)."""
    try:
        raw = Path(path).read_bytes()
    except OSError as exc:
        raise UsageError(f"{path}: cannot read master_bin: {exc.strerror}") from None
    out: dict[tuple[int, int], int] = {}
    try:
        (count,) = struct.unpack_from("<L", raw, 0)
        pos = 4
        for _ in range(count):
            index, sub, size = struct.unpack_from("<HBL", raw, pos)
            pos += 7
            data = raw[pos:pos + size]
            if len(data) < size:
                raise struct.error("truncated")
            pos += size
            out[(index, sub)] = int.from_bytes(data[:8], "little")
    except struct.error:
        raise UsageError(f"{path}: master_bin: not a concise DCF (entry count, then "
                         f"index, sub-index, size, data)") from None
    return out


class MasterDcf:
    """The manager's DCF: the objects of SPEC §8.1.1, compact storage included."""

    def __init__(self, path: str) -> None:
        from nmtcheck.protocol.devicefile import _Ini

        try:
            self._ini = _Ini(Path(path))
        except (OSError, UnicodeDecodeError) as exc:
            raise UsageError(f"{path}: cannot read master_dcf: {exc}") from None
        except Exception as exc:  # configparser errors
            raise UsageError(f"{path}: master_dcf: {exc}") from None
        self.path = path
        self.node_id = self._ini.node_id()

    def get(self, index: int, sub: int | None) -> int | None:
        try:
            return self._ini.value(index, sub, self.node_id)
        except ValueError:
            return None


def node_dcf_identity(path: str, node: int) -> dict[str, int]:
    """The identity a node's own EDS/DCF gives (SPEC §8.2.2 item 3; 0 / missing: none)."""
    from nmtcheck.protocol.devicefile import _Ini

    try:
        ini = _Ini(Path(path))
    except Exception:
        return {}

    def get(index: int, sub: int | None) -> int | None:
        try:
            return ini.value(index, sub, node)
        except ValueError:
            return None

    def info(key: str) -> int | None:
        sec = ini.section("DeviceInfo")
        text = sec.get(key) if sec is not None else None
        try:
            return int(text.strip(), 0) if text and text.strip() else None
        except ValueError:
            return None

    found = (("device_type", get(0x1000, None) or get(0x1000, 0)),
             ("vendor_id", get(0x1018, 1) or info("VendorNumber")),
             ("product_code", get(0x1018, 2) or info("ProductNumber")),
             ("revision_number", get(0x1018, 3) or info("RevisionNumber")),
             ("serial_number", get(0x1018, 4)))
    return {name: value for name, value in found if value}


def channel_config(table: BootTable, node_keys: dict[int, dict[str, Any]],
                   node_dcfs: dict[int, str], master_file: str | None) -> BootConfig:
    """The channel's boot configuration: explicit keys over master_bin over master_dcf;
    the node's own EDS for the identity only when no master file is known."""
    cfg = BootConfig(table=table)
    dcf_path = table.master_dcf or master_file
    dcf = MasterDcf(dcf_path) if dcf_path else None
    bin_path = table.master_bin
    if bin_path is None and dcf_path is not None:
        guess = Path(dcf_path).with_name("master.bin")
        bin_path = str(guess) if guess.is_file() else None
    concise = read_master_bin(bin_path) if bin_path else {}

    def master(index: int, sub: int | None) -> tuple[int | None, str | None]:
        key = (index, sub or 0)
        if key in concise:
            return concise[key], "master-bin"
        if dcf is not None:
            v = dcf.get(index, sub)
            return (v, "master-dcf") if v is not None else (None, None)
        return None, None

    startup, _src = master(0x1F80, None)
    cfg.startup = table.startup if table.startup is not None else startup
    cfg.master_dcf_known = dcf is not None and bool((startup or 0) & 1)
    boot_time, _src = master(0x1F89, None)
    cfg.boot_time_ms = (table.boot_time_ms if table.boot_time_ms is not None
                        else float(boot_time or 0))
    nodes = set(node_keys)
    if dcf is not None or concise:
        nodes |= {n for n in range(1, 128) if (master(0x1F81, n)[0] or 0) & 1}
    nodes |= set(node_dcfs)
    for n in sorted(nodes):
        own = node_dcf_identity(node_dcfs[n], n) if (
            n in node_dcfs and dcf is None and not concise) else {}
        cfg.nodes[n] = _node_boot(n, node_keys.get(n, {}), master, dcf,
                                  dcf is not None or bool(concise), own)
    return cfg


def _node_boot(n: int, keys: dict[str, Any],
               master: Callable[[int, int | None], tuple[int | None, str | None]],
               dcf: MasterDcf | None, master_known: bool, own: dict[str, int]) -> NodeBoot:
    """One slave's boot configuration (SPEC §8.2.2)."""
    nb = NodeBoot()
    value, src = master(0x1F81, n)
    if "assignment" in keys:
        value, src = keys["assignment"], "network"
    for key, bitno, invert in (("boot", 2, False), ("mandatory", 3, False),
                               ("reset_communication", 4, True)):
        if key in keys:
            bit = bool(keys[key]) != invert
            base = value if value is not None else 0x5  # listed, booted by the manager
            value = (base & ~(1 << bitno)) | (bit << bitno)
            src = "network"
    nb.assignment, nb.assignment_source = value, src
    nb.manager_consumer_ms = keys.get("manager_consumer_ms")
    if nb.manager_consumer_ms is None and dcf is not None:
        for sub in range(1, 128):
            entry = dcf.get(0x1016, sub)
            if entry is None:
                break
            if (entry >> 16) & 0x7F == n and entry & 0xFFFF:
                nb.manager_consumer_ms = float(entry & 0xFFFF)
    for name, index in IDENTITY.items():
        if name in keys:
            nb.identity[name] = Expected(keys[name], "network")
            continue
        v, s = master(index, n)
        if master_known:
            nb.identity[name] = Expected(v or 0, s or "master-dcf")
        elif name in own:
            nb.identity[name] = Expected(own[name], "node-dcf")
    return nb
