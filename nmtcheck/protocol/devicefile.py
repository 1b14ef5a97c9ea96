"""EDS/DCF files: the few objects nmtcheck uses, read from the INI text.

Read: 1017h producer heartbeat time, 1016h consumer entries, 100Ch guard time,
100Dh life time factor, the PDO communication parameters (1400h-1403h RPDO,
1800h-1803h TPDO COB-IDs with their valid bit), 1F80h NMT startup (bit 0: the
device is the NMT master), 1F81h (CiA 302 slave assignment), and the SYNC and EMCY
objects of SPEC §9.1.1 (1005h COB-ID SYNC, 1006h period, 1007h window, 1019h counter
overflow, 1014h COB-ID EMCY, 1015h EMCY inhibit time, 1029h:01 error behaviour). A DCF's
ParameterValue wins over the DefaultValue; `$NODEID` is the node-ID the file is
used as (else its [DeviceComissioning] NodeID).

Only the sections of those objects (USED_OBJECTS, with the boot objects of SPEC §8.1.1)
and the file's non-object sections are parsed: a device file of 100,000 objects costs
the time to scan its lines, not an object dictionary of all of them. The canopen
library is not used: its import pulls in python-can and, where installed, asammdf with
pandas and sympy (about 200 MB before the first line of the file is read), and on every
EDS/DCF of samples/ and the shared corpus it read the same values as the INI text
(tests/test_devicefile.py compares them).

CiA 306 compact storage (`CompactSubObj=N` with a `[xxxxValue]` section, how
Lely's dcfgen and CANopen editors store 1016h and 1F81h) is read as CiA 306 says: the
`[xxxxValue]` entries, the object's own value the default of the others.

What cannot be read is a note naming the object and the reason, never fatal and never
silently dropped.
"""

from __future__ import annotations

import configparser
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from nmtcheck.errors import UsageError

COB_ID_INVALID = 0x80000000  # bit 31: the PDO does not exist / is not valid
_NODEID = re.compile(r"\$NODEID", re.I)
_OCTAL = re.compile(r"0[0-7]+")
_VALUE_KEYS = ("ParameterValue", "DefaultValue")  # a DCF's ParameterValue wins
# the objects nmtcheck reads from a device file: this module's, and the boot objects of
# SPEC §8.1.1 and §8.2.2 (processes/boot_config.py); only PDOs 1..4 are read
USED_OBJECTS = frozenset([
    0x1000, 0x1005, 0x1006, 0x1007, 0x100C, 0x100D, 0x1014, 0x1015, 0x1016, 0x1017,
    0x1018, 0x1019, 0x1029, *range(0x1400, 0x1404), *range(0x1600, 0x1604),
    *range(0x1800, 0x1804), *range(0x1A00, 0x1A04), 0x1F80, 0x1F81, *range(0x1F84, 0x1F8A)])
_HEADER = re.compile(r"\[(?P<header>.+)\]")  # configparser's section header
_OBJECT_SECTION = re.compile(r"([0-9A-F]{4})(SUB[0-9A-F]+|VALUE|NAME|DENOTATION)?", re.I)


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
    tpdo_types: dict[int, int] = field(default_factory=dict)  # PDO 1..4 -> sub 2
    rpdo_types: dict[int, int] = field(default_factory=dict)
    # PDO 1..4 -> {"inhibit_100us": sub 3, "event_timer_ms": sub 5, "sync_start": sub 6,
    # "mapping": [1600h/1A00h sub 1..n]} as far as the file gives them (SPEC §9.1.1)
    tpdo_params: dict[int, dict[str, Any]] = field(default_factory=dict)
    rpdo_params: dict[int, dict[str, Any]] = field(default_factory=dict)
    slaves: list[int] | None = None  # 1F81h: node-IDs assigned as slaves
    nmt_master: bool = False  # 1F80h read and its bit 0 set (CiA 302: the device is NMT master)
    # SPEC §9.1.1, as the file gives them (None: not given)
    sync_cob_id: int | None = None  # 1005h: bits 0-10 CAN-ID, bit 30 produces SYNC
    sync_period_us: int | None = None  # 1006h
    sync_window_us: int | None = None  # 1007h
    sync_counter_overflow: int | None = None  # 1019h
    emcy_cob_id: int | None = None  # 1014h: bits 0-10 CAN-ID, bit 31 no EMCY
    emcy_inhibit_100us: int | None = None  # 1015h
    error_behaviour: int | None = None  # 1029h:01
    notes: list[str] = field(default_factory=list)  # what could not be read, and why


def _int(text: str | None, node_id: int | None) -> int | None:
    """A CiA 306 number: decimal, 0x hex, 0-prefixed octal, terms joined by `+`, one of
    which may be `$NODEID`. None if empty; ValueError saying why if unreadable (the
    caller names the key)."""
    if text is None or not text.strip():
        return None
    total = 0
    for term in text.replace(" ", "").replace("\t", "").split("+"):
        if _NODEID.fullmatch(term):
            if node_id is None:
                raise ValueError("uses $NODEID but the node-ID is not known")
            total += node_id
        elif _OCTAL.fullmatch(term):
            total += int(term, 8)
        else:
            try:
                total += int(term, 0)
            except ValueError:
                raise ValueError("not a number") from None
    return total


def _read(key: str, text: str | None, node_id: int | None) -> int | None:
    """_int, with an error that names the key and the text."""
    try:
        return _int(text, node_id)
    except ValueError as exc:
        raise ValueError(f"cannot read {key}={(text or '').strip()} ({exc})") from None


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def _used_text(path: Path) -> str:
    """The file's lines less the sections of objects outside USED_OBJECTS (a header at
    the start of a line begins a section, as configparser reads it)."""
    keep = True
    lines: list[str] = []
    with path.open(encoding="latin-1") as file:
        for line in file:
            if line[:1] == "[" and (header := _HEADER.match(line.strip())) is not None:
                obj = _OBJECT_SECTION.fullmatch(header["header"])
                keep = obj is None or int(obj[1], 16) in USED_OBJECTS
            if keep:
                lines.append(line)
    return "".join(lines)


class _Ini:
    """The sections of an EDS/DCF that nmtcheck uses: the objects of USED_OBJECTS and the
    non-object sections ([DeviceInfo], [DeviceComissioning], ...). Notes on what it cannot
    read go to `notes`."""

    def __init__(self, path: Path) -> None:
        # keys are case-insensitive; values may end in a `; comment`
        self.cp = configparser.ConfigParser(strict=False, interpolation=None,
                                            inline_comment_prefixes=(";",))
        self.cp.read_string(_used_text(path))
        self.sections = {s.upper(): s for s in self.cp.sections()}
        self.notes: list[str] = []
        self._compact: dict[int, tuple[int, dict[int, str]] | None] = {}

    def section(self, name: str) -> configparser.SectionProxy | None:
        sec = self.sections.get(name.upper())
        return None if sec is None else self.cp[sec]

    def node_id(self) -> int | None:
        """[DeviceComissioning] NodeID (CiA 306 spells it so; the correct spelling is
        accepted too); None with a note when it is not a node-ID."""
        for name in ("DeviceComissioning", "DeviceCommissioning"):
            sec = self.section(name)
            if sec is None or not sec.get("NodeID", "").strip():
                continue
            text = sec["NodeID"].strip()
            try:
                nid = _int(text, None)
            except ValueError as exc:
                self.notes.append(f"[{name}] NodeID={text}: {exc}; ignored")
                return None
            if nid is None or not 1 <= nid <= 127:
                self.notes.append(f"[{name}] NodeID={text} is not a node-ID 1..127; ignored")
                return None
            return nid
        return None

    def compact(self, index: int) -> tuple[int, dict[int, str]] | None:
        """(N, {sub-index: value text}) of an object stored as `CompactSubObj=N` with its
        `[xxxxValue]` section (keys are decimal sub-indices, CiA 306); None if not compact."""
        if index not in self._compact:
            self._compact[index] = self._read_compact(index)
        return self._compact[index]

    def _read_compact(self, index: int) -> tuple[int, dict[int, str]] | None:
        obj = self.section(f"{index:04X}")
        values = self.section(f"{index:04X}Value")
        text = obj.get("CompactSubObj", "").strip() if obj is not None else ""
        try:
            n = _int(text, None) or 0
        except ValueError:
            self.notes.append(f"{index:04X}h: CompactSubObj={text} is not a number; "
                              f"its sub-objects are ignored")
            return (0, {})
        if not n:
            if values is not None:
                self.notes.append(f"{index:04X}h: [{index:04X}Value] ignored: the object has "
                                  f"no CompactSubObj")
            return None
        if any(s.startswith(f"{index:04X}SUB") for s in self.sections):
            self.notes.append(f"{index:04X}h: CompactSubObj={n} and [{index:04X}subN] sections; "
                              f"the sub-index sections are ignored")
        entries: dict[int, str] = {}
        if values is None:
            return (n, entries)
        listed = {k: v for k, v in values.items() if k.upper() != "NROFENTRIES"}
        declared = next((v.strip() for k, v in values.items() if k.upper() == "NROFENTRIES"), "")
        if declared != str(len(listed)):
            self.notes.append(f"{index:04X}h [{index:04X}Value]: NrOfEntries={declared or '?'} "
                              f"but {len(listed)} entries")
        for key, value in listed.items():
            if not key.isdigit():
                self.notes.append(f"{index:04X}h [{index:04X}Value] {key}={value}: {key!r} is "
                                  f"not a decimal sub-index; ignored")
            elif not 1 <= int(key) <= n:
                self.notes.append(f"{index:04X}h [{index:04X}Value] {key}={value}: sub-index "
                                  f"{key} outside 1..{n} (CompactSubObj); ignored")
            else:
                entries[int(key)] = value
        return (n, entries)

    def value(self, index: int, sub: int | None, node_id: int | None) -> int | None:
        if index not in USED_OBJECTS:  # its sections were not read: a caller's mistake
            raise KeyError(f"{index:04X}h is not in devicefile.USED_OBJECTS")
        compact = self.compact(index)
        if compact is not None:
            n, entries = compact
            if sub is None or not 1 <= sub <= n:
                return None
            if sub in entries:
                return _read(f"[{index:04X}Value] {sub}", entries[sub], node_id)
            sec = self.section(f"{index:04X}")  # the object's own value is every entry's default
        else:
            sec = self.section(f"{index:04X}" if sub is None else f"{index:04X}sub{sub:X}")
        if sec is None:
            return None
        for key in _VALUE_KEYS:
            v = _read(key, sec.get(key), node_id)
            if v is not None:
                return v
        return None


_Get = Callable[[int, int], int | None]  # the value of an object's sub-index, if any


def _read_consumers(get: _Get, out: DeviceValues) -> None:
    """1016h: the consumer heartbeat time of each producer (the shortest, noted if twice)."""
    consumer_sub: dict[int, int] = {}
    for sub in range(1, 128):
        entry = get(0x1016, sub)
        if entry is None:
            continue
        producer, time_ms = (entry >> 16) & 0xFF, entry & 0xFFFF
        if time_ms and 1 <= producer <= 127:  # else the entry is unused (CiA 301)
            prev = out.consumers.get(producer)
            if prev is not None:
                out.notes.append(f"1016h sub {sub}: node {producer} is also in sub "
                                 f"{consumer_sub[producer]}; the shorter time is taken")
            else:
                consumer_sub[producer] = sub
            out.consumers[producer] = min(prev, time_ms) if prev else float(time_ms)


def _read_pdo_cob_ids(get: _Get, out: DeviceValues) -> None:
    """1800h..1803h and 1400h..1403h sub 1: the COB-IDs of TPDO 1..4 and RPDO 1..4; sub 2:
    their transmission types (SPEC §9.1.1; a type CiA 301 refuses is noted, not used)."""
    for n in range(4):
        for base, table in ((0x1800, out.tpdo_cob_ids), (0x1400, out.rpdo_cob_ids)):
            cob = get(base + n, 1)
            if cob is not None:
                table[n + 1] = None if cob & COB_ID_INVALID else cob & 0x7FF
        for base, types, refused in ((0x1800, out.tpdo_types, range(241, 252)),
                                     (0x1400, out.rpdo_types, range(241, 254))):
            tt = get(base + n, 2)
            if tt is not None and tt in refused:
                out.notes.append(f"{base + n:04X}h sub 2 = {tt}: a reserved transmission "
                                 "type; taken as unknown")
            elif tt is not None:
                types[n + 1] = tt
        for base, mapping, params in ((0x1800, 0x1A00, out.tpdo_params),
                                      (0x1400, 0x1600, out.rpdo_params)):
            found: dict[str, Any] = {}
            for name, sub in (("inhibit_100us", 3), ("event_timer_ms", 5), ("sync_start", 6)):
                if base == 0x1400 and name != "event_timer_ms":
                    continue
                v = get(base + n, sub)
                if v is not None:
                    found[name] = v
            count = get(mapping + n, 0)
            if count is not None and 0 < count <= 64:
                entries = [get(mapping + n, sub) for sub in range(1, count + 1)]
                if all(e is not None for e in entries):
                    found["mapping"] = entries
            elif count is not None:
                found["mapping"] = []  # 0 entries, or an MPDO (FEh/FFh): not judged
            if found:
                params[n + 1] = found


def _read_sync_emcy(get: Callable[..., int | None], out: DeviceValues) -> None:
    """The SYNC and EMCY objects of SPEC §9.1.1. A 1019h that CiA 301 refuses (1 or above
    240) is noted and taken as unknown, never used (SPEC §9.1.2)."""
    out.sync_cob_id = get(0x1005)
    out.sync_period_us = get(0x1006)
    out.sync_window_us = get(0x1007)
    overflow = get(0x1019)
    if overflow is not None and (overflow == 1 or overflow > 240):
        out.notes.append(f"1019h = {overflow}: not a counter overflow value (0, 2..240); "
                         "taken as unknown")
        overflow = None
    out.sync_counter_overflow = overflow
    out.emcy_cob_id = get(0x1014)
    out.emcy_inhibit_100us = get(0x1015)
    out.error_behaviour = get(0x1029, 1)


def load_device_file(path: str, node_id: int | None = None) -> DeviceValues:
    """Read the NMT-relevant objects of an EDS/DCF; never fails on a messy file."""
    p = Path(path)
    if not p.is_file():
        raise UsageError(f"{path}: no such EDS/DCF file")
    out = DeviceValues(path=path)
    try:
        ini = _Ini(p)
    except (configparser.Error, UnicodeDecodeError, OSError) as exc:
        raise UsageError(f"{path}: not a readable EDS/DCF file: {_one_line(str(exc))}") from None
    file_nid = ini.node_id()
    if node_id is not None and file_nid is not None and file_nid != node_id:
        out.notes.append(f"[DeviceComissioning] NodeID={file_nid}, but the file is used for "
                         f"node {node_id}: $NODEID is {node_id}")
    nid = node_id or file_nid
    out.node_id = nid

    def get(index: int, sub: int | None = None) -> int | None:
        try:
            return ini.value(index, sub, nid)
        except ValueError as exc:
            where = f"{index:04X}h" + (f" sub {sub}" if sub is not None else "")
            out.notes.append(f"{where}: {exc}; ignored")
            return None

    hb = get(0x1017)
    out.heartbeat_ms = float(hb) if hb else None  # 0 in a file: not configured (SPEC §6)
    _read_consumers(get, out)
    gt = get(0x100C)
    out.guard_time_ms = float(gt) if gt else None
    ltf = get(0x100D)
    out.life_time_factor = ltf or None
    _read_pdo_cob_ids(get, out)
    startup = get(0x1F80)
    out.nmt_master = bool(startup is not None and startup & 1)
    slaves = [n for n in range(1, 128) if (get(0x1F81, n) or 0) & 1]
    out.slaves = slaves or None
    _read_sync_emcy(get, out)
    # the file's structure, then the values; one line each (a value in an INI file may
    # go on over several lines)
    out.notes = [_one_line(note) for note in ini.notes + out.notes]
    return out
