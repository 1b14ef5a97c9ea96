"""SDO requests paired with the server's confirmations: the configuration written in
the trace (1017h, 1016h, 100Ch/100Dh, PDO COB-IDs), and how long each write holds."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from nmtcheck import sdo
from nmtcheck.model import NodeEvent, NodeModel, WriteTable
from nmtcheck.nmt import BOOTUP

_PDO_OBJECTS = np.asarray([i for i in sdo.CONFIG_OBJECTS if i not in (0x1016, 0x1017, 0x100C,
                                                                      0x100D)])


def _config_index(index: np.ndarray, sub: np.ndarray) -> np.ndarray:
    """`sdo.is_config_index` for columns."""
    found: np.ndarray = ((np.isin(index, (0x1017, 0x100C, 0x100D)) & (sub == 0))
                         | ((index == 0x1016) & (sub >= 1) & (sub <= 127))
                         | (np.isin(index, _PDO_OBJECTS) & (sub == 1)))
    return found


def _expedited_values(data: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`sdo.expedited_value` for columns: the values, and whether each has one."""
    cmd = data[:, 0].astype(np.int64)
    has = ((cmd & 0xE0) == 0x20) & ((cmd & 0x02) != 0)
    size = np.where(cmd & 0x01, 4 - ((cmd >> 2) & 0x3), 4)
    value = np.zeros(len(data), np.int64)
    for k in range(4):
        value |= np.where(k < size, data[:, 4 + k].astype(np.int64) << (8 * k), 0)
    return value, has


def pair_sdo_writes(rows: np.ndarray, node_model: Callable[[int], NodeModel]) -> None:
    """Pair SDO requests with the server's answer: confirmed writes, aborts, segmented ones.

    `rows`: the channel's SDO frames (EVENT_DTYPE, file order: config requests, their
    confirmations and aborts, DLC 4 or more). Per server, a response answers the latest
    request before it if that is a configuration write to the same object and no earlier
    response answered it (the request is pending until then). Vectorised: a log may
    write 1017h a million times.
    """
    if not len(rows):
        return
    cid = rows["can_id"].astype(np.int64)
    data = rows["data"]
    cmd = data[:, 0]
    index = data[:, 1].astype(np.int64) | (data[:, 2].astype(np.int64) << 8)
    sub = data[:, 3].astype(np.int64)
    request = cid >= 0x601
    server = np.where(request, cid - 0x600, cid - 0x580)
    config = request & ((cmd & 0xE0) == 0x20) & _config_index(index, sub)
    value, has_value = _expedited_values(data)
    # by server, file order within: the latest request at or before each row
    order = np.lexsort((np.arange(len(rows)), server))
    pos = np.arange(len(order))
    first_of_server = np.flatnonzero(np.concatenate([[True], server[order][1:]
                                                     != server[order][:-1]]))
    group = first_of_server[np.searchsorted(first_of_server, pos, side="right") - 1]
    latest = np.maximum.accumulate(np.where(request[order], pos, -1))
    latest = np.where(latest >= group, latest, -1)
    answers = np.flatnonzero(~request[order])  # positions in `order` of the responses
    resp = order[answers]
    req = np.where(latest[answers] >= 0, order[np.maximum(latest[answers], 0)], -1)
    matches = (req >= 0) & config[req] & (index[req] == index[resp]) & (sub[req] == sub[resp])
    # only the first matching response after a request answers it
    hit = np.flatnonzero(matches)
    _, first = np.unique(req[hit], return_index=True)
    answered = np.zeros(len(resp), bool)
    answered[hit[first]] = True
    for n in np.unique(server[resp]).tolist():
        node_model(n)  # every server that answers is a node
    _events(rows, resp, req, answered, index, sub, node_model)
    write = answered & (cmd[resp] == 0x60) & has_value[np.maximum(req, 0)]
    r, q = resp[write], req[write]
    if not len(r):
        return
    by_server = np.argsort(server[r], kind="stable")  # file order within a server
    r, q = r[by_server], q[by_server]
    bounds = np.flatnonzero(np.concatenate([[True], server[r][1:] != server[r][:-1], [True]]))
    for a, b in zip(bounds[:-1].tolist(), bounds[1:].tolist(), strict=True):
        rr, qq = r[a:b], q[a:b]
        m = node_model(int(server[rr[0]]))
        m.writes = WriteTable(rows["ts"][rr], rows["idx"][rr], rows["line"][rr], server[rr],
                              index[rr], sub[rr], value[qq], np.full(len(rr), np.inf),
                              rows["ts"][qq], rows["idx"][qq])
        m.events.writes = m.writes


def _events(rows: np.ndarray, resp: np.ndarray, req: np.ndarray, answered: np.ndarray,
            index: np.ndarray, sub: np.ndarray, node_model: Callable[[int], NodeModel]) -> None:
    """SDO aborts and confirmed segmented downloads become node events (objects: a log
    full of them is not yet bounded)."""
    data = rows["data"]
    cid = rows["can_id"].astype(np.int64)
    cmd = data[resp, 0]
    segmented = answered & (cmd == 0x60) & ~_expedited_values(data[np.maximum(req, 0)])[1]
    for k in np.flatnonzero((cmd == 0x80) | segmented).tolist():
        row = int(resp[k])
        ts, idx, line = float(rows["ts"][row]), int(rows["idx"][row]), int(rows["line"][row])
        i, s = int(index[row]), int(sub[row])
        m = node_model(int(cid[row]) - 0x580)
        if cmd[k] == 0x80:
            code = int.from_bytes(bytes(data[row, 4:8].tolist()), "little")
            what = f" to {sdo.object_name(i, s)}" if answered[k] else f" ({i:04X}h sub {s})"
            m.events.append(NodeEvent(ts, idx, line, "sdo-abort",
                                      f"SDO abort{what}: {code:08X}h {sdo.abort_text(code)}",
                                      code))
        else:
            m.events.append(NodeEvent(ts, idx, line, "sdo-segmented",
                                      f"segmented download to {sdo.object_name(i, s)}"
                                      f" confirmed; its value is not applied"))


def write_validity(nodes: dict[int, NodeModel]) -> None:
    """A written value holds until the node's next boot-up or reset; 1016h entries also
    count for the producer they name."""
    consumers: dict[int, list[WriteTable]] = {}
    for m in nodes.values():
        w = m.writes
        if not len(w):
            continue
        ends = np.sort(np.concatenate([m.ec.ts[m.ec.kind == BOOTUP], m.commands.reset_ts]))
        k = np.searchsorted(ends, w.ts, side="right")
        w.until = np.where(k < len(ends), ends[np.minimum(k, max(len(ends) - 1, 0))]
                           if len(ends) else np.inf, np.inf)
        entry = w.index == 0x1016
        producer = (w.value >> 16) & 0xFF
        for p in dict.fromkeys(producer[entry].tolist()):
            if p in nodes and nodes[p] is not m:
                consumers.setdefault(p, []).append(w.take(np.flatnonzero(entry & (producer == p))))
    for p, tables in consumers.items():
        nodes[p].consumer_writes = WriteTable.concat(tables)
