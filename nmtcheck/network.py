"""The network description (`--network FILE`, SPEC §6): expected nodes and their configuration."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from nmtcheck.errors import UsageError
from nmtcheck.profiles import tomllib
from nmtcheck.timeline import NodeConfig

_KEYS = {"heartbeat_ms": float, "consumer_timeout_ms": float, "guard_time_ms": float,
         "life_time_factor": int, "channel": str, "dcf": str, "eds": str}


@dataclass
class Network:
    nodes: dict[int, tuple[NodeConfig, str | None]] = field(default_factory=dict)

    def configs(self) -> dict[tuple[str | None, int], NodeConfig]:
        return {(channel, n): cfg for n, (cfg, channel) in self.nodes.items()}

    def expected(self) -> list[tuple[int, str | None]]:
        return [(n, channel) for n, (_cfg, channel) in sorted(self.nodes.items())]


def _value(where: str, value: Any, want: type) -> Any:
    if want is float and isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    if isinstance(value, want) and not isinstance(value, bool):
        return value
    raise UsageError(f"{where}: expected {want.__name__}, got {value!r}")


def load_network(path: str) -> Network:
    """Read and validate a network file; errors name the file and key."""
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise UsageError(f"{path}: no such network file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise UsageError(f"{path}: cannot read network file: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise UsageError(f"{path}: invalid TOML: {exc}") from None
    for key in data:
        if key != "nodes":
            raise UsageError(f"{path}: unknown key {key!r} (expected [nodes.N] tables)")
    net = Network()
    for name, table in data.get("nodes", {}).items():
        where = f"{path}: [nodes.{name}]"
        if not name.isdigit() or not 1 <= int(name) <= 127:
            raise UsageError(f"{where}: node-ID must be 1..127")
        if not isinstance(table, dict):
            raise UsageError(f"{where}: expected a table")
        values: dict[str, Any] = {}
        for key, value in table.items():
            if key not in _KEYS:
                raise UsageError(f"{where} {key}: unknown key (known: {', '.join(_KEYS)})")
            values[key] = _value(f"{where} {key}", value, _KEYS[key])
        if "dcf" in values or "eds" in values:
            raise UsageError(f"{where} dcf: EDS/DCF files are not supported yet; give "
                             f"heartbeat_ms, consumer_timeout_ms, guard_time_ms and "
                             f"life_time_factor directly")
        hb = values.get("heartbeat_ms")
        cfg = NodeConfig(
            heartbeat_ms=hb if hb else None,  # 0 read from a file means "not configured"
            consumer_timeout_ms=values.get("consumer_timeout_ms") or None,
            guard_time_ms=values.get("guard_time_ms") or None,
            life_time_factor=values.get("life_time_factor") or None,
            expected=True,
        )
        net.nodes[int(name)] = (cfg, values.get("channel"))
    return net
