"""The network-file keys of SPEC §9.1.2: the channel's SYNC (`[sync]`,
`[channels.NAME.sync]`), a node's EMCY and error behaviour (`[nodes.N]` keys), and its
PDO communication and mapping parameters (`[nodes.N.tpdo.K]`, `[nodes.N.rpdo.K]`).

A value of the wrong type, a transmission type in a range CiA 301 refuses, or a mapping
longer than 64 entries is exit 2 naming file and key, as every other key of the network
file (SPEC §5).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from nmtcheck.errors import UsageError
from nmtcheck.settings.values import quoted

MAX_MAPPING = 64  # entries of a PDO mapping (1600h/1A00h sub 1..64)


@dataclass(frozen=True)
class SyncKeys:
    """A `[sync]` table; None: the key is absent."""

    cob_id: int | None = None
    producer: int | None = None
    period_us: int | None = None
    window_us: int | None = None
    counter_overflow: int | None = None


@dataclass
class PdoKeys:
    """One `[nodes.N.tpdo.K]` or `[nodes.N.rpdo.K]` table; None: the key is absent."""

    cob_id: int | None = None
    transmission_type: int | None = None
    inhibit_100us: int | None = None
    event_timer_ms: int | None = None
    sync_start: int | None = None
    mapping: list[int] | None = None


@dataclass
class NodeCommKeys:
    """A node's keys of §9.1.2 besides its PDO tables."""

    emcy_cob_id: int | None = None
    emcy_inhibit_100us: int | None = None
    error_behaviour: int | None = None
    error_register_mask: int | None = None
    tpdo: dict[int, PdoKeys] = field(default_factory=dict)
    rpdo: dict[int, PdoKeys] = field(default_factory=dict)


NODE_KEYS = ("emcy_cob_id", "emcy_inhibit_100us", "error_behaviour", "error_register_mask",
             "tpdo", "rpdo")
_SYNC_KEYS = {"cob_id": (0, 0xFFFFFFFF), "producer": (1, 127), "period_us": (0, 0xFFFFFFFF),
              "window_us": (0, 0xFFFFFFFF), "counter_overflow": (0, 240)}
_NODE_RANGES = {"emcy_cob_id": (0, 0xFFFFFFFF), "emcy_inhibit_100us": (0, 0xFFFF),
                "error_behaviour": (0, 255), "error_register_mask": (0, 255)}
_PDO_RANGES = {"cob_id": (0, 0xFFFFFFFF), "transmission_type": (0, 255),
               "inhibit_100us": (0, 0xFFFF), "event_timer_ms": (0, 0xFFFF),
               "sync_start": (0, 240)}


def _int(where: str, value: Any, lo: int, hi: int) -> int:
    if isinstance(value, int) and not isinstance(value, bool) and lo <= value <= hi:
        return value
    top = str(hi) if hi <= 0xFFFF else f"0x{hi:X}"
    raise UsageError(f"{where}: expected an integer {lo}..{top}, got {quoted(value)}")


def read_sync_table(where: str, table: Any) -> SyncKeys:
    """A `[sync]` table, validated. 1019h = 1 is refused by CiA 301 (CN `CO_SYNC.c` 149,
    LE `sync.c` 533): no counter overflow value."""
    if not isinstance(table, dict):
        raise UsageError(f"{where}: expected a table")
    values: dict[str, int] = {}
    for key, value in table.items():
        if key not in _SYNC_KEYS:
            raise UsageError(f"{where} {key}: unknown key (known: {', '.join(_SYNC_KEYS)})")
        values[key] = _int(f"{where} {key}", value, *_SYNC_KEYS[key])
    if values.get("counter_overflow") == 1:
        raise UsageError(f"{where} counter_overflow: 1 is not a counter overflow value "
                         "(0: no counter; 2..240)")
    return SyncKeys(**values)


def read_node_key(where: str, key: str, value: Any) -> Any:
    """One §9.1.2 key of `[nodes.N]` (`where`: "FILE: [nodes.N]"), validated; the PDO
    tables come whole."""
    if key in ("tpdo", "rpdo"):
        return read_pdo_tables(where, key, value)
    return _int(f"{where} {key}", value, *_NODE_RANGES[key])


def read_pdo_tables(where: str, kind: str, tables: Any) -> dict[int, PdoKeys]:
    """`[nodes.N.tpdo.K]` / `[nodes.N.rpdo.K]` tables by PDO number K (1..512); `where`:
    "FILE: [nodes.N]"."""
    if not isinstance(tables, dict):
        raise UsageError(f"{where} {kind}: expected [{kind}.K] tables")
    out: dict[int, PdoKeys] = {}
    for name, table in tables.items():
        here = f"{where.removesuffix(']')}.{kind}.{name}]"
        if not str(name).isdigit() or not 1 <= int(name) <= 512:
            raise UsageError(f"{here}: PDO number must be 1..512")
        if not isinstance(table, dict):
            raise UsageError(f"{here}: expected a table")
        keys = PdoKeys()
        for key, value in table.items():
            if key == "mapping":
                keys.mapping = _mapping(f"{here} mapping", value)
                continue
            if key not in _PDO_RANGES:
                raise UsageError(f"{here} {key}: unknown key (known: "
                                 f"{', '.join([*_PDO_RANGES, 'mapping'])})")
            setattr(keys, key, _int(f"{here} {key}", value, *_PDO_RANGES[key]))
        tt = keys.transmission_type
        refused = range(241, 252) if kind == "tpdo" else range(241, 254)
        if tt is not None and tt in refused:
            raise UsageError(f"{here} transmission_type: {tt} is reserved for "
                             f"{'TPDOs (241..251)' if kind == 'tpdo' else 'RPDOs (241..253)'}")
        out[int(name)] = keys
    return out


def _mapping(where: str, value: Any) -> list[int]:
    if not isinstance(value, list) or len(value) > MAX_MAPPING:
        raise UsageError(f"{where}: expected a list of at most {MAX_MAPPING} entries "
                         "(index << 16 | sub << 8 | bits)")
    return [_int(f"{where}[{k}]", v, 0, 0xFFFFFFFF) for k, v in enumerate(value)]
