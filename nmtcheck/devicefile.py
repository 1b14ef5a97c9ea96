"""EDS/DCF files: the few objects NMT checking needs, read with the canopen library.

Read: 1017h producer heartbeat time, 1016h consumer entries, 100Ch guard time,
100Dh life time factor, the PDO communication parameters (1400h-1403h RPDO,
1800h-1803h TPDO COB-IDs with their valid bit) and 1F81h (CiA 302 slave
assignment). A DCF's ParameterValue wins over the DefaultValue.

Real files are messy and canopen's import raises on some (an empty numeric
value, a DummyUsage section without all entries). Then the same objects are
read from the INI text directly, and what still cannot be read is reported,
never fatal.
"""

from __future__ import annotations

import configparser
import logging
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from nmtcheck.errors import UsageError

COB_ID_INVALID = 0x80000000  # bit 31: the PDO does not exist / is not valid
_NODEID = re.compile(r"\$NODEID", re.I)


@dataclass
class DeviceValues:
    """Configuration of one device as its EDS/DCF gives it (None: not given)."""

    path: str
    node_id: int | None = None
    heartbeat_ms: float | None = None
    consumers: dict[int, float] = field(default_factory=dict)  # producer node -> time (ms)
    guard_time_ms: float | None = None
    life_time_factor: int | None = None
    tpdo_cob_ids: dict[int, int | None] = field(default_factory=dict)  # PDO 1..4 -> COB-ID
    rpdo_cob_ids: dict[int, int | None] = field(default_factory=dict)
    slaves: list[int] | None = None  # 1F81h: node-IDs assigned as slaves
    reader: str = "canopen"  # canopen | ini (fallback)
    notes: list[str] = field(default_factory=list)  # what could not be read, and why


def _int(text: str | None, node_id: int | None) -> int | None:
    """An EDS number: decimal, 0x-hex, octal, or `$NODEID+...`; None if empty."""
    if text is None:
        return None
    t = text.strip()
    if not t:
        return None
    if _NODEID.search(t):
        if node_id is None:
            return None
        t = _NODEID.sub(str(node_id), t)
    total = 0
    for term in t.replace(" ", "").split("+"):
        total += int(term, 0)
    return total


class _Ini:
    """Direct INI access to an EDS/DCF (the fallback when canopen's import fails)."""

    def __init__(self, path: Path) -> None:
        self.cp = configparser.ConfigParser(strict=False, interpolation=None)
        self.cp.optionxform = str  # type: ignore[assignment,method-assign]
        self.cp.read_string(path.read_text(encoding="latin-1"))
        self.sections = {s.upper(): s for s in self.cp.sections()}

    def node_id(self) -> int | None:
        sec = self.sections.get("DEVICECOMISSIONING")
        if sec is None:
            return None
        try:
            return _int(self.cp[sec].get("NodeID"), None)
        except ValueError:
            return None

    def value(self, index: int, sub: int | None, node_id: int | None) -> int | None:
        name = f"{index:04X}" if sub is None else f"{index:04X}SUB{sub:X}"
        sec = self.sections.get(name)
        if sec is None:
            return None
        s = self.cp[sec]
        for key in ("ParameterValue", "DefaultValue"):
            v = _int(s.get(key), node_id)
            if v is not None:
                return v
        return None


class _CanopenOD:
    """Values through canopen's object dictionary import."""

    def __init__(self, path: Path, node_id: int | None) -> None:
        import canopen

        logging.getLogger("canopen").setLevel(logging.ERROR)
        self.od = canopen.import_od(str(path), node_id)

    def node_id(self) -> int | None:
        nid = self.od.node_id
        return int(nid) if nid else None

    def value(self, index: int, sub: int | None, node_id: int | None) -> int | None:
        try:
            entry: Any = self.od[index]
            obj: Any = entry if sub is None else entry[sub]
        except (KeyError, IndexError, TypeError):
            return None
        for v in (getattr(obj, "value", None), getattr(obj, "default", None)):
            if isinstance(v, bool):
                continue
            if isinstance(v, int):
                return v
        return None


def load_device_file(path: str, node_id: int | None = None) -> DeviceValues:
    """Read the NMT-relevant objects of an EDS/DCF; never fails on a messy file."""
    p = Path(path)
    if not p.is_file():
        raise UsageError(f"{path}: no such EDS/DCF file")
    out = DeviceValues(path=path)
    try:
        source: _CanopenOD | _Ini = _CanopenOD(p, node_id)
    except Exception as exc:  # noqa: BLE001 - canopen raises many kinds on messy files
        out.reader = "ini"
        out.notes.append(f"canopen could not import it ({type(exc).__name__}: {exc}); "
                         f"read the needed objects from the INI text instead")
        try:
            source = _Ini(p)
        except (configparser.Error, UnicodeDecodeError) as exc2:
            raise UsageError(f"{path}: not a readable EDS/DCF file: {exc2}") from None
    nid = node_id or source.node_id()
    out.node_id = nid

    def get(index: int, sub: int | None = None) -> int | None:
        try:
            return source.value(index, sub, nid)
        except ValueError as exc:
            where = f"{index:04X}h" + (f" sub {sub}" if sub is not None else "")
            out.notes.append(f"{where}: unreadable value ({exc})")
            return None

    hb = get(0x1017)
    out.heartbeat_ms = float(hb) if hb else None  # 0 in a file: not configured (SPEC §6)
    for sub in range(1, 128):
        entry = get(0x1016, sub)
        if entry is None:
            continue
        producer, time_ms = (entry >> 16) & 0xFF, entry & 0xFFFF
        if time_ms and 1 <= producer <= 127:
            prev = out.consumers.get(producer)
            out.consumers[producer] = min(prev, time_ms) if prev else float(time_ms)
    gt = get(0x100C)
    out.guard_time_ms = float(gt) if gt else None
    ltf = get(0x100D)
    out.life_time_factor = ltf or None
    for n in range(4):
        for base, table in ((0x1800, out.tpdo_cob_ids), (0x1400, out.rpdo_cob_ids)):
            cob = get(base + n, 1)
            if cob is not None:
                table[n + 1] = None if cob & COB_ID_INVALID else cob & 0x7FF
    slaves = [n for n in range(1, 128) if (get(0x1F81, n) or 0) & 1]
    out.slaves = slaves or None
    return out
