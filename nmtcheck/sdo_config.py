"""SDO requests paired with the server's confirmations: the configuration written in
the trace (1017h, 1016h, 100Ch/100Dh, PDO COB-IDs), and how long each write holds."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import NamedTuple

from nmtcheck import sdo
from nmtcheck.model import ConfigWrite, NodeEvent, NodeModel
from nmtcheck.nmt import BOOTUP


class SdoFrame(NamedTuple):
    """An SDO request (600h+N) or response (580h+N) as the timeline keeps it."""

    ts: float
    idx: int
    line: int
    can_id: int
    dlc: int
    data: list[int]  # plain ints: numpy uint8 would overflow on shifts


class _Request(NamedTuple):
    """An expedited download to a configuration object, waiting for its confirmation."""

    obj: int  # object index (a field named `index` would hide tuple.index)
    sub: int
    value: int | None  # None: a segmented download (its value is not known)
    ts: float
    idx: int


def pair_sdo_writes(rows: Iterable[SdoFrame], nodes: dict[int, NodeModel],
                    node_model: Callable[[int], NodeModel]) -> None:
    """Pair SDO requests with the server's answer: confirmed writes, aborts, segmented ones."""
    pending: dict[int, _Request] = {}  # by node
    for ts, idx, line, can_id, dlc, data in rows:
        if dlc < 4:
            continue
        cmd, index, sub = data[0], data[1] | data[2] << 8, data[3]
        if can_id >= 0x601:  # request to server N
            n = can_id - 0x600
            if cmd & 0xE0 == 0x20 and sdo.is_config_index(index, sub):
                pending[n] = _Request(index, sub, sdo.expedited_value(data), ts, idx)
            else:
                pending.pop(n, None)
            continue
        n = can_id - 0x580
        m = node_model(n)
        req = pending.get(n)
        matches = req is not None and (req.obj, req.sub) == (index, sub)
        if cmd == 0x80:
            code = int.from_bytes(bytes(data[4:8]), "little")
            what = f" to {sdo.object_name(index, sub)}" if matches else f" ({index:04X}h sub {sub})"
            m.events.append(NodeEvent(ts, idx, line, "sdo-abort",
                                      f"SDO abort{what}: {code:08X}h {sdo.abort_text(code)}",
                                      code))
            if matches:
                pending.pop(n, None)
        elif cmd == 0x60 and req is not None and matches:
            pending.pop(n, None)
            value = req.value
            if value is None:
                m.events.append(NodeEvent(ts, idx, line, "sdo-segmented",
                                          f"segmented download to {sdo.object_name(index, sub)}"
                                          f" confirmed; its value is not applied"))
                continue
            m.writes.append(ConfigWrite(ts, idx, line, n, index, sub, value,
                                        request_ts=req.ts, request_idx=req.idx))
            m.events.append(NodeEvent(ts, idx, line, "sdo-write",
                                      f"{sdo.object_name(index, sub)} = {value} "
                                      f"({value:X}h) written by SDO"))


def write_validity(nodes: dict[int, NodeModel]) -> None:
    """A written value holds until the node's next boot-up or reset; 1016h entries also
    count for the producer they name."""
    for m in nodes.values():
        ends = sorted(m.ec.ts[m.ec.kind == BOOTUP].tolist() + m.commands.reset_ts.tolist())
        for w in m.writes:
            w.until = next((t for t in ends if t > w.ts), float("inf"))
            if w.index == 0x1016:
                producer = nodes.get((w.value >> 16) & 0xFF)
                if producer is not None and producer is not m:
                    producer.consumer_writes.append(w)
