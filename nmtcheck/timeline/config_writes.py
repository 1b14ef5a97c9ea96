"""SDO requests paired with the server's confirmations: the configuration written in
the trace (1017h, 1016h, 100Ch/100Dh, PDO COB-IDs, and the SYNC and EMCY objects of SPEC
§9.1.1), and how long each write holds."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from nmtcheck.protocol import sdo
from nmtcheck.protocol.nmt import BOOTUP
from nmtcheck.timeline.model import NodeModel, SdoEventTable, WriteTable

_SUB0_OBJECTS = np.asarray([0x1017, 0x100C, 0x100D, *sdo.COMM_OBJECTS])
_SUB1_OBJECTS = np.asarray([*sdo.PDO_COMM_OBJECTS, sdo.ERROR_BEHAVIOUR])


def _config_index(index: np.ndarray, sub: np.ndarray) -> np.ndarray:
    """`sdo.is_config_index` for columns."""
    found: np.ndarray = ((np.isin(index, _SUB0_OBJECTS) & (sub == 0))
                         | ((index == 0x1016) & (sub >= 1) & (sub <= 127))
                         | (np.isin(index, _SUB1_OBJECTS) & (sub == 1)))
    return found


def _pdo_param_index(index: np.ndarray, sub: np.ndarray) -> np.ndarray:
    """`sdo.is_pdo_param` for columns: the PDO parameters beyond the COB-IDs of PDOs 1-4."""
    comm = ((index >= 0x1400) & (index <= 0x15FF)) | ((index >= 0x1800) & (index <= 0x19FF))
    mapping = ((index >= 0x1600) & (index <= 0x17FF)) | ((index >= 0x1A00) & (index <= 0x1BFF))
    found: np.ndarray = ((comm & np.isin(sub, (1, 2, 3, 5)) & ~_config_index(index, sub))
                         | (mapping & (sub <= 0x40)))
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
    request = rows["can_id"] >= 0x601
    server = np.where(request, rows["can_id"].astype(np.int32) - 0x600,
                      rows["can_id"].astype(np.int32) - 0x580)
    by_server = np.argsort(server, kind="stable")  # file order within a server
    bounds = np.flatnonzero(np.diff(server[by_server], prepend=-1, append=-1))
    for a, b in zip(bounds[:-1].tolist(), bounds[1:].tolist(), strict=True):
        if request[by_server[a:b]].all():
            continue  # requests no server answered pair nothing (and show no node)
        mine = rows[by_server[a:b]]  # one server at a time bounds the columns below
        _pair_server(mine, int(server[by_server[a]]), node_model(int(server[by_server[a]])))


def _pair_server(rows: np.ndarray, n: int, m: NodeModel) -> None:
    """`pair_sdo_writes` for the frames of one server N, in file order (every server that
    answers is a node of the model, made by the caller)."""
    data = rows["data"]
    cmd = data[:, 0]
    index = data[:, 1].astype(np.int32) | (data[:, 2].astype(np.int32) << 8)
    sub = data[:, 3]
    request = rows["can_id"] >= 0x601
    known = _config_index(index, sub)
    config = request & ((cmd & 0xE0) == 0x20) & (known | _pdo_param_index(index, sub))
    # each response and the latest request before it (-1: none)
    latest = np.maximum.accumulate(np.where(request, np.arange(len(rows)), -1))
    resp = np.flatnonzero(~request)
    req = latest[resp]
    at = np.maximum(req, 0)
    matches = (req >= 0) & config[at] & (index[at] == index[resp]) & (sub[at] == sub[resp])
    # only the first matching response after a request answers it
    hit = np.flatnonzero(matches)
    _, first = np.unique(req[hit], return_index=True)
    answered = np.zeros(len(resp), bool)
    answered[hit[first]] = True
    value, has_value = _expedited_values(data[at])
    confirmed = answered & (cmd[resp] == 0x60)
    _events(rows, resp, answered, confirmed & ~has_value & known[at], index, sub, m)
    write = confirmed & has_value
    m.writes = _table(rows, resp, req, write & known[at], index, sub, value, n)
    m.own_events().writes = m.writes
    pdo = write & ~known[at]
    if pdo.any():  # PDO parameters: read by the PDO streams only (SPEC §9.1.1)
        m.pdo_writes = _table(rows, resp, req, pdo, index, sub, value, n)


def _table(rows: np.ndarray, resp: np.ndarray, req: np.ndarray, sel: np.ndarray,
           index: np.ndarray, sub: np.ndarray, value: np.ndarray, n: int) -> WriteTable:
    """The confirmed writes `sel` (a mask over the responses) as a table."""
    r, q = resp[sel], req[sel]
    return WriteTable(rows["ts"][r], rows["idx"][r], rows["line"][r], np.full(len(r), n),
                      index[r], sub[r], value[sel], np.full(len(r), np.inf),
                      rows["ts"][q], rows["idx"][q])


def _events(rows: np.ndarray, resp: np.ndarray, answered: np.ndarray, segmented: np.ndarray,
            index: np.ndarray, sub: np.ndarray, m: NodeModel) -> None:
    """SDO aborts and confirmed segmented downloads become node events (as columns)."""
    data = rows["data"]
    abort = data[resp, 0] == 0x80
    k = np.flatnonzero(abort | segmented)
    r = resp[k]
    code = (data[r, 4].astype(np.int64) | (data[r, 5].astype(np.int64) << 8)
            | (data[r, 6].astype(np.int64) << 16) | (data[r, 7].astype(np.int64) << 24))
    m.own_events().sdo = SdoEventTable(rows["ts"][r], rows["idx"][r], rows["line"][r], abort[k],
                                       index[r], sub[r], code, answered[k])


def write_validity(nodes: dict[int, NodeModel]) -> None:
    """A written value holds until the node's next boot-up or reset; 1016h entries also
    count for the producer they name."""
    consumers: dict[int, list[WriteTable]] = {}
    for m in nodes.values():
        w = m.writes
        if not len(w) and not len(m.pdo_writes):
            continue
        ends = np.sort(np.concatenate([m.ec.ts[m.ec.kind == BOOTUP], m.commands.reset_ts]))
        for table in (w, m.pdo_writes):
            if len(table):
                k = np.searchsorted(ends, table.ts, side="right")
                table.until = np.where(k < len(ends), ends[np.minimum(k, max(len(ends) - 1, 0))]
                                       if len(ends) else np.inf, np.inf)
        if not len(w):
            continue
        entry = w.index == 0x1016
        producer = (w.value >> 16) & 0xFF
        for p in dict.fromkeys(producer[entry].tolist()):
            if p in nodes and nodes[p] is not m:
                consumers.setdefault(p, []).append(w.take(np.flatnonzero(entry & (producer == p))))
    for p, tables in consumers.items():
        nodes[p].consumer_writes = WriteTable.concat(tables)
