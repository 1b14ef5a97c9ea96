"""The network description (`--network FILE`, SPEC §6): expected nodes and their configuration.

Per node: explicit keys, else the values of the node's EDS/DCF (`dcf`/`eds`,
paths relative to the network file, or `--dcf NODE=PATH`). A consumer entry
(1016h) in any node's device file sets the consumer time of the producer it
names; a 1F81h slave assignment (CiA 302, in the master's DCF) adds the nodes
it lists to the expected ones.

The NMT master of a channel (SPEC §2): `master = M` under `[channels.NAME]`,
else at top level, else the node whose device file has 1F80h bit 0 set (the
lowest node-ID if several do).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from nmtcheck.errors import UsageError
from nmtcheck.processes import boot_config
from nmtcheck.protocol.devicefile import DeviceValues, load_device_file
from nmtcheck.settings import comm_keys
from nmtcheck.settings.comm_keys import NodeCommKeys, SyncKeys
from nmtcheck.settings.values import loads, number, quoted, shortened
from nmtcheck.timeline.model import NodeConfig

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

_KEYS = {"heartbeat_ms": float, "consumer_timeout_ms": float, "guard_time_ms": float,
         "life_time_factor": int, "channel": str, "dcf": str, "eds": str}


@dataclass
class Network:
    nodes: dict[int, tuple[NodeConfig, str | None]] = field(default_factory=dict)
    devices: dict[int, DeviceValues] = field(default_factory=dict)
    # One line each, naming node, file and object: what could not be read from device files.
    notes: list[str] = field(default_factory=list)
    path: str | None = None  # the network file, if any
    master: int | None = None  # top-level `master = M`
    channel_masters: dict[str, int] = field(default_factory=dict)  # [channels.NAME] master
    # SPEC §8.2.1: the [boot] tables (top level, per channel) and the per-node boot keys
    boot: boot_config.BootTable | None = None
    channel_boot: dict[str, boot_config.BootTable] = field(default_factory=dict)
    boot_nodes: dict[int, dict[str, Any]] = field(default_factory=dict)
    # SPEC §9.1.2: [sync] (top level, per channel) and the nodes' EMCY and PDO keys
    sync: SyncKeys | None = None
    channel_sync: dict[str, SyncKeys] = field(default_factory=dict)
    comm_nodes: dict[int, NodeCommKeys] = field(default_factory=dict)

    def sync_keys(self, channel: str) -> SyncKeys | None:
        """The `[sync]` table in force on a channel: its own, else the top level's."""
        return self.channel_sync.get(channel, self.sync)

    def node_channel(self, node: int) -> str | None:
        """The channel a node of the file is restricted to (None: any)."""
        found = self.nodes.get(node)
        return found[1] if found is not None else None

    def boot_config(self, channel: str) -> boot_config.BootConfig:
        """The boot configuration of a channel (SPEC §8.2.2)."""
        table = self.channel_boot.get(channel, self.boot) or boot_config.BootTable()
        found = self.master_for(channel)
        dev = self.devices.get(found[0]) if found else None
        mine = [n for n, (_cfg, ch) in self.nodes.items() if ch in (None, channel)]
        return boot_config.channel_config(
            table, {n: v for n, v in self.boot_nodes.items() if n in mine},
            {n: d.path for n, d in self.devices.items() if n in mine},
            dev.path if dev is not None and dev.nmt_master else None)

    def master_for(self, channel: str) -> tuple[int, str, str] | None:
        """(node, source, detail) of the channel's NMT master as the files name it: source
        "network" (the channel's table wins over the top level) or "device-file" (1F80h
        bit 0; a device file of a node restricted to another channel does not count)."""
        claims = sorted(n for n, dev in self.devices.items()
                        if dev.nmt_master and self.nodes[n][1] in (None, channel))
        m = self.channel_masters.get(channel, self.master)
        if m is not None:
            where = f"[channels.{channel}] master" if channel in self.channel_masters else "master"
            detail = f"{self.path}: {where} = {m}"
            others = [n for n in claims if n != m]
            if others:
                verb = "has" if len(others) == 1 else "have"
                detail += f" ({_and(others)} also {verb} 1F80h bit 0)"
            return m, "network", detail
        if not claims:
            return None
        if len(claims) == 1:
            dev = self.devices[claims[0]]
            return claims[0], "device-file", f"node {claims[0]} {dev.path}: 1F80h bit 0 set"
        return claims[0], "device-file", f"{_and(claims)} have 1F80h bit 0; lowest taken"

    def configs(self) -> dict[tuple[str | None, int], NodeConfig]:
        return {(channel, n): cfg for n, (cfg, channel) in self.nodes.items()}

    def expected(self) -> list[tuple[int, str | None]]:
        return [(n, channel) for n, (cfg, channel) in sorted(self.nodes.items())
                if cfg.expected]


def _and(nodes: list[int]) -> str:
    """"node 5", "nodes 1 and 5", "nodes 1, 5 and 7"."""
    if len(nodes) == 1:
        return f"node {nodes[0]}"
    return f"nodes {', '.join(map(str, nodes[:-1]))} and {nodes[-1]}"


def _master(where: str, value: Any) -> int:
    if isinstance(value, int) and not isinstance(value, bool) and 1 <= value <= 127:
        return value
    raise UsageError(f"{where}: expected a node-ID 1..127, got {quoted(value)}")


def _value(where: str, value: Any, want: type) -> Any:
    if want in (float, int) and isinstance(value, (int, float)) and not isinstance(value, bool):
        number(where, value, integer=want is int)  # times, factors: finite, >= 0
    if want is float and isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    if isinstance(value, want) and not isinstance(value, bool):
        return value
    raise UsageError(f"{where}: expected {want.__name__}, got {quoted(value)}")


def _read_toml(path: str) -> dict[str, Any]:
    p = Path(path)
    try:
        doc: dict[str, Any] = loads(p.read_text(encoding="utf-8"))
        return doc
    except FileNotFoundError:
        raise UsageError(f"{path}: no such network file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise UsageError(f"{path}: cannot read network file: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise UsageError(f"{path}: invalid TOML: {exc}") from None


def load_network(path: str | None, dcf_args: dict[int, str] | None = None) -> Network:
    """Read and validate a network file (and --dcf NODE=PATH); errors name the file and key."""
    net = Network(path=path)
    tables = _read_network_file(path, net) if path is not None else {}
    for node, dcf in (dcf_args or {}).items():
        if not 1 <= node <= 127:
            raise UsageError(f"--dcf {node}={dcf}: node-ID must be 1..127")
        tables.setdefault(node, {})["dcf"] = dcf
    for node, values in sorted(tables.items()):
        net.nodes[node] = (_node_config(net, node, values), values.get("channel"))
    _consumer_times(net, tables)
    _expected_slaves(net)
    return net


def _read_network_file(path: str, net: Network) -> dict[int, dict[str, Any]]:
    """The masters of the network file (into `net`) and its [nodes.N] tables, validated."""
    data = _read_toml(path)
    for key in data:
        if key not in ("nodes", "channels", "master", "boot", "sync"):
            raise UsageError(f"{path}: unknown key {quoted(key)} (expected master, [boot], "
                             f"[sync], [nodes.N] and [channels.NAME] tables)")
    base = Path(path).resolve().parent
    if "boot" in data:
        net.boot = boot_config.read_boot_table(f"{path}: [boot]", data["boot"], base)
    if "master" in data:
        net.master = _master(f"{path}: master", data["master"])
    if "sync" in data:
        net.sync = comm_keys.read_sync_table(f"{path}: [sync]", data["sync"])
    _read_channels(path, data.get("channels", {}), net)
    tables = _read_nodes(path, data.get("nodes", {}), base)
    for n, values in tables.items():
        keys = {k: values.pop(k) for k in list(values) if k in boot_config.NODE_KEYS}
        if keys:
            net.boot_nodes[n] = keys
            if "manager_consumer_ms" in keys and "consumer_timeout_ms" not in values:
                values["consumer_timeout_ms"] = keys["manager_consumer_ms"]
        comm = {k: values.pop(k) for k in list(values) if k in comm_keys.NODE_KEYS}
        if comm:
            net.comm_nodes[n] = NodeCommKeys(**comm)
    return tables


def _read_channels(path: str, channels: Any, net: Network) -> None:
    """[channels.NAME] tables: each channel's `master`."""
    if not isinstance(channels, dict):
        raise UsageError(f"{path}: channels: expected [channels.NAME] tables")
    for name, table in channels.items():
        where = f"{path}: [channels.{shortened(name)}]"
        if not isinstance(table, dict):
            raise UsageError(f"{where}: expected a table")
        for key, value in table.items():
            if key == "boot":
                net.channel_boot[name] = boot_config.read_boot_table(
                    f"{where} boot", value, Path(path).resolve().parent)
                continue
            if key == "sync":
                net.channel_sync[name] = comm_keys.read_sync_table(f"{where} sync", value)
                continue
            if key != "master":
                raise UsageError(f"{where} {shortened(key)}: unknown key (known: master, boot, "
                                 "sync)")
            net.channel_masters[name] = _master(f"{where} master", value)


def _read_nodes(path: str, nodes: Any, base: Path) -> dict[int, dict[str, Any]]:
    """[nodes.N] tables, by node-ID: their values checked, device file paths made relative
    to the network file's folder."""
    if not isinstance(nodes, dict):
        raise UsageError(f"{path}: nodes: expected [nodes.N] tables")
    tables: dict[int, dict[str, Any]] = {}
    for name, table in nodes.items():
        where = f"{path}: [nodes.{shortened(name)}]"
        if not name.isdigit() or len(name) > 3 or not 1 <= int(name) <= 127:
            raise UsageError(f"{where}: node-ID must be 1..127")
        if not isinstance(table, dict):
            raise UsageError(f"{where}: expected a table")
        values: dict[str, Any] = {}
        for key, value in table.items():
            if key in boot_config.NODE_KEYS:
                values[key] = boot_config.read_node_key(f"{where} {key}", key, value)
                continue
            if key in comm_keys.NODE_KEYS:
                values[key] = comm_keys.read_node_key(where, key, value)
                continue
            if key not in _KEYS:
                known = ", ".join([*_KEYS, *boot_config.NODE_KEYS, *comm_keys.NODE_KEYS])
                raise UsageError(f"{where} {shortened(key)}: unknown key (known: {known})")
            values[key] = _value(f"{where} {key}", value, _KEYS[key])
        for key in ("dcf", "eds"):
            if key in values:
                values[key] = str(base / values[key])
        tables[int(name)] = values
    return tables


def _node_config(net: Network, node: int, values: dict[str, Any]) -> NodeConfig:
    """One node's configuration: the network file's values over its device file's (which is
    loaded into `net`)."""
    dev_path = values.get("dcf") or values.get("eds")
    dev = load_device_file(dev_path, node) if dev_path else None
    if dev is not None:
        net.devices[node] = dev
        net.notes += [f"node {node} {dev.path}: {note}" for note in dev.notes]

    def pick(key: str, from_dev: float | None) -> float | None:
        explicit: float | None = values.get(key)
        if explicit is not None:
            return explicit or None  # 0 read from a file means "not configured"
        return from_dev

    cfg = NodeConfig(
        heartbeat_ms=pick("heartbeat_ms", dev.heartbeat_ms if dev else None),
        consumer_timeout_ms=pick("consumer_timeout_ms", None),
        guard_time_ms=pick("guard_time_ms", dev.guard_time_ms if dev else None),
        expected=True,
    )
    ltf = pick("life_time_factor", dev.life_time_factor if dev else None)
    cfg.life_time_factor = int(ltf) if ltf else None
    if dev is not None:
        cfg.consumes = dict(dev.consumers)
        cfg.tpdo_cob_ids = dict(dev.tpdo_cob_ids)
        cfg.rpdo_cob_ids = dict(dev.rpdo_cob_ids)
    comm = net.comm_nodes.get(node)
    for ids, pdos in ((cfg.tpdo_cob_ids, comm.tpdo if comm else {}),
                      (cfg.rpdo_cob_ids, comm.rpdo if comm else {})):
        for k, pdo in pdos.items():  # explicit COB-IDs win (SPEC §9.1.1)
            if k <= 4 and pdo.cob_id is not None and not pdo.cob_id & 0x20000000:
                ids[k] = None if pdo.cob_id & 0x80000000 else pdo.cob_id & 0x7FF
    return cfg


def _consumer_times(net: Network, tables: dict[int, dict[str, Any]]) -> None:
    """1016h entries of every device file set their producers' consumer times."""
    for consumer, dev in net.devices.items():
        for producer, time_ms in dev.consumers.items():
            cfg, _channel = net.nodes.setdefault(producer, (NodeConfig(), None))
            if "consumer_timeout_ms" in tables.get(producer, {}):
                continue  # the explicit key wins
            if cfg.consumer_timeout_ms is None or time_ms < cfg.consumer_timeout_ms:
                cfg.consumer_timeout_ms, cfg.consumer_node = time_ms, consumer


def _expected_slaves(net: Network) -> None:
    """1F81h slave assignment: the master's list of expected slaves."""
    for dev in net.devices.values():
        for slave in dev.slaves or []:
            cfg, _channel = net.nodes.setdefault(slave, (NodeConfig(), None))
            cfg.expected = True
