"""Each node's EMCY frames, reconstructed once per input (SPEC §9.1.7): its COB-ID, its
inhibit time (1015h) and error behaviour (1029h:01) in force with their sources, the
frames as columns with their error code and register, CANopenNode's detail where the
frame carries it, and whether the node is still in error. The E rules (`checks/emcy.py`)
and the reports read it; nothing here judges.

Only the pre-defined EMCY COB-ID (80h + N) is decoded; a node whose files configure
another (1014h) is named in the report with its frames on 80h + N.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from nmtcheck.processes.attached import Attached
from nmtcheck.processes.comm_values import Value, in_force
from nmtcheck.protocol import emcy
from nmtcheck.protocol.nmt import BOOTUP
from nmtcheck.readers.frames import EMCY_BASE
from nmtcheck.timeline.decode import key_rows
from nmtcheck.timeline.model import InputModel, NodeModel

# seconds: what a timestamp of each format can tell apart (SPEC §9.1.6); text formats
# write microseconds, the binary ones nanoseconds (BLF objects, MF4, MCAP)
RESOLUTION_S = {"blf": 1e-9, "mf4": 1e-9, "mcap": 1e-9}
TEXT_RESOLUTION_S = 1e-6


def resolution(stats: Any, timeline: dict[str, Any]) -> float:
    """r of §9.1.6: `[timeline] timestamp_resolution_us`, else the format's tick."""
    given = timeline.get("timestamp_resolution_us")
    if given:
        return float(given) / 1e6
    return RESOLUTION_S.get(str(getattr(stats, "format", "")), TEXT_RESOLUTION_S)


@dataclass
class EmcyNode:
    """One node's EMCYs as columns (file order) and its EMCY configuration."""

    channel: str
    node: int
    cob_id: int
    cob_id_source: str
    inhibit_file: Value  # 1015h of the files (network, else device file)
    inhibit: np.ndarray  # 1015h in force at each frame, 100 us units (NaN: unknown)
    inhibit_line: np.ndarray  # per frame: the line of the SDO write in force (-1: the files')
    behaviour: Value  # 1029h:01 at the trace end
    ts: np.ndarray
    idx: np.ndarray
    line: np.ndarray
    dlc: np.ndarray
    data: np.ndarray  # the 8 data bytes packed in one integer (little-endian)
    rtr_ts: np.ndarray  # remote frames on the EMCY COB-ID
    rtr_idx: np.ndarray
    rtr_line: np.ndarray
    clears: np.ndarray  # times of N's boot-ups and of reset commands that reach N
    register_mask: int | None = None  # [nodes.N] error_register_mask (SPEC §9.1.1)
    notes: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.ts)

    def inhibit_source(self, k: int) -> str:
        """Where frame k's 1015h came from, as a message names it."""
        line = int(self.inhibit_line[k])
        if line >= 0:
            return "written by SDO" + (f" at line {line}" if line else "")
        v = self.inhibit_file
        return "device file" if v.source == "device-file" else str(v.source)

    @property
    def code(self) -> np.ndarray:
        out: np.ndarray = (self.data & 0xFFFF).astype(np.int64)
        return out

    @property
    def register(self) -> np.ndarray:
        out: np.ndarray = ((self.data >> 16) & 0xFF).astype(np.int64)
        return out

    def data_bytes(self, k: int) -> list[int]:
        return list(int(self.data[k]).to_bytes(8, sys.byteorder))

    def describe(self, k: int) -> str:
        return emcy.describe(self.data_bytes(k), int(self.dlc[k]))[1]

    def since_clear(self, k: int) -> np.ndarray:
        """Positions of the EMCYs from N's last boot-up or reset before frame k to k."""
        before = self.clears[self.clears <= self.ts[k]]
        lo = float(before.max()) if len(before) else -np.inf
        return np.flatnonzero((self.ts > lo) & (np.arange(len(self)) <= k))

    def in_error_at_end(self) -> bool:
        """SPEC §9.1.7 at the trace end: the latest EMCY (of DLC >= 2) leaves N in error,
        and no boot-up or reset of N follows it."""
        pos = np.flatnonzero(self.dlc >= 2)
        if not len(pos):
            return False
        k = int(pos[-1])
        if (self.clears > self.ts[k]).any():
            return False
        register = int(self.register[k]) if self.dlc[k] >= 3 else 0
        return emcy.in_error(int(self.code[k]), register)

    def _inhibit_at_end(self) -> Value:
        if not len(self.ts):
            return self.inhibit_file
        v = float(self.inhibit[-1])
        if np.isnan(v):
            return Value(None)
        line = int(self.inhibit_line[-1])
        return Value(int(v), "sdo", line=line) if line >= 0 else self.inhibit_file

    def as_dict(self) -> dict[str, Any]:
        """`nodes[i].emcy` of the JSON report (SPEC §9.4.1)."""
        valid = np.flatnonzero(self.dlc >= 2)
        code = self.code[valid]
        uniq, first = np.unique(code, return_index=True)  # one row per code, vectorised:
        codes = []  # a node may flood the bus with EMCYs
        for c, f in sorted(zip(uniq.tolist(), first.tolist(), strict=True), key=lambda x: x[1]):
            mine = valid[code == c]
            regs = mine[self.dlc[mine] >= 3]
            codes.append({"code": f"{c:04X}h",
                          "meaning": self.describe(int(valid[f])).split(" ", 2)[-1].split(",")[0],
                          "count": len(mine), "first": round(float(self.ts[mine[0]]), 6),
                          "last": round(float(self.ts[mine[-1]]), 6),
                          "registers": [f"{int(r):02X}h" for r in dict.fromkeys(
                              self.register[regs].tolist())][:16]})
        errors = valid[code >= 0x100]
        # a hint, read from the first errors (a flood of one code says no more than ten)
        recognised = [emcy.canopennode_detail(self.data_bytes(k), int(self.dlc[k]))
                      for k in errors[:64].tolist()]
        last = int(valid[-1]) if len(valid) else None
        return {"cob_id": f"{self.cob_id:03X}h", "cob_id_source": self.cob_id_source,
                "inhibit_100us": self._inhibit_at_end().as_dict(),
                "error_behaviour": self.behaviour.as_dict(),
                "frames": len(self) + len(self.rtr_ts),
                "in_error_at_end": self.in_error_at_end(),
                "last_register": f"{int(self.register[last]):02X}h"
                if last is not None and self.dlc[last] >= 3 else None,
                "stack": "canopennode" if len(errors) and all(recognised) else None,
                "codes": codes, "notes": list(self.notes)}


@dataclass
class EmcyAnalysis:
    """Every node's EMCYs, by (channel, node); and the input's timestamp resolution."""

    nodes: dict[tuple[str, int], EmcyNode] = field(default_factory=dict)
    resolution_s: float = TEXT_RESOLUTION_S


_SLOT: Attached[EmcyAnalysis] = Attached("emcy")
attach = _SLOT.attach  # the engine keeps the analysis with the model
of = _SLOT.of  # the rules and reports read it


def analyse(model: InputModel, network: Any, resolution_s: float) -> EmcyAnalysis:
    """The EMCYs of every node that sent one, or whose EMCY the files configure."""
    out = EmcyAnalysis(resolution_s=resolution_s)
    cols, rtr = model.decoded.emcy, model.decoded.emcy_rtr
    for cm in model.channels:
        for n, m in cm.nodes.items():
            key = m.key
            rows = key_rows(cols["key"], key, key)
            remote = np.flatnonzero(rtr["key"] == key)
            keys = network.comm_nodes.get(n) if network is not None else None
            dev = network.devices.get(n) if network is not None else None
            configured = keys is not None and (keys.emcy_inhibit_100us is not None
                                               or keys.emcy_cob_id is not None)
            if rows.stop == rows.start and not len(remote) and not configured and not (
                    dev is not None and dev.emcy_inhibit_100us is not None):
                continue
            out.nodes[(cm.name, n)] = _node(cm.name, n, m, cm, cols, rows, rtr, remote, keys,
                                            dev)
    return out


def _node(channel: str, n: int, m: NodeModel, cm: Any, cols: dict[str, np.ndarray],
          rows: slice, rtr: dict[str, np.ndarray], remote: np.ndarray, keys: Any,
          dev: Any) -> EmcyNode:
    notes: list[str] = []
    net_cob = keys.emcy_cob_id if keys is not None else None
    dev_cob = dev.emcy_cob_id if dev is not None else None
    cob, source = EMCY_BASE + n, "default"
    for given, where in ((net_cob, "network"), (dev_cob, "device-file")):
        if given is not None:
            cob, source = given & 0x7FF, where
            if given & 0x80000000:
                notes.append(f"1014h bit 31 set ({where}): node {n} produces no EMCY")
            elif cob != EMCY_BASE + n:
                notes.append(f"1014h = {cob:03X}h ({where}): only frames on the pre-defined "
                             f"{EMCY_BASE + n:03X}h are read as node {n}'s EMCYs")
            break
    ts = cols["ts"][rows]
    net_inh = keys.emcy_inhibit_100us if keys is not None else None
    dev_inh = dev.emcy_inhibit_100us if dev is not None else None
    files = in_force(None, n, 0x1015, 0, 0.0, net_inh, dev_inh)
    inhibit, inhibit_line = _in_force_at(m, 0x1015, ts, files)
    end = cm.end
    behaviour = in_force(m, n, 0x1029, 1, end, keys.error_behaviour if keys else None,
                         dev.error_behaviour if dev is not None else None)
    clears = np.sort(np.concatenate([m.ec.ts[m.ec.kind == BOOTUP], m.commands.reset_ts]))
    return EmcyNode(channel, n, cob, source, files, inhibit, inhibit_line, behaviour, ts,
                    cols["idx"][rows],
                    cols["line"][rows], cols["dlc"][rows], cols["data"][rows],
                    rtr["ts"][remote], rtr["idx"][remote], rtr["line"][remote], clears,
                    keys.error_register_mask if keys is not None else None, notes)


def _in_force_at(m: NodeModel, index: int, ts: np.ndarray, files: Value
                 ) -> tuple[np.ndarray, np.ndarray]:
    """`comm_values.in_force` of a sub-index 0 object at many times at once: the values
    (NaN: unknown) and the line of the SDO write in force (-1: the files' value)."""
    value = np.full(len(ts), np.nan if files.value is None else float(files.value))
    line = np.full(len(ts), -1, np.int64)
    w = m.writes
    if not len(w):
        return value, line
    mine = np.flatnonzero((w.index == index) & (w.sub == 0))
    if not len(mine):
        return value, line
    mine = mine[np.argsort(w.ts[mine], kind="stable")]
    k = np.searchsorted(w.ts[mine], ts, side="right") - 1
    hit = k >= 0
    at = mine[np.maximum(k, 0)]
    holds = hit & (w.until[at] > ts)
    value[hit] = np.where(holds[hit], w.value[at][hit].astype(np.float64), np.nan)
    line[holds] = w.line[at][holds]
    return value, line
