"""SDO requests paired with the server's confirmations: the configuration written in
the trace (1017h, 1016h, 100Ch/100Dh, PDO COB-IDs), and how long each write holds."""

from __future__ import annotations

from collections.abc import Callable

from nmtcheck import sdo
from nmtcheck.model import ConfigWrite, NodeEvent, NodeModel
from nmtcheck.nmt import BOOTUP


def pair_sdo_writes(rows: list[tuple[float, int, int, int, int, list[int]]],
                    nodes: dict[int, NodeModel], node_model: Callable[[int], NodeModel]
                    ) -> None:
    """Pair SDO requests with the server's answer: confirmed writes, aborts, segmented ones."""
    # node -> index, sub, value, ts, idx of the request
    pending: dict[int, tuple[int, int, int | None, float, int]] = {}
    for ts, idx, line, can_id, dlc, data in rows:
        if dlc < 4:
            continue
        cmd, index, sub = data[0], data[1] | data[2] << 8, data[3]
        if can_id >= 0x601:  # request to server N
            n = can_id - 0x600
            if cmd & 0xE0 == 0x20 and sdo.is_config_index(index, sub):
                pending[n] = (index, sub, sdo.expedited_value(data), ts, idx)
            else:
                pending.pop(n, None)
            continue
        n = can_id - 0x580
        m = node_model(n)
        req = pending.get(n)
        matches = req is not None and req[:2] == (index, sub)
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
            value = req[2]
            if value is None:
                m.events.append(NodeEvent(ts, idx, line, "sdo-segmented",
                                          f"segmented download to {sdo.object_name(index, sub)}"
                                          f" confirmed; its value is not applied"))
                continue
            m.writes.append(ConfigWrite(ts, idx, line, n, index, sub, value,
                                        request_ts=req[3], request_idx=req[4]))
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
