"""PDO streams (SPEC §9.1.6, §9.1.4): one stream per PDO COB-ID and channel, its producer
(a TPDO's node) and consumers (RPDOs' nodes) with the parameters each gives it, and its
data frames from the node-frame store. Built once per input; the D rules and Y004 judge
them, the reports show them.

Where the parameters come from: the network file's `[nodes.N.tpdo.K]`/`[nodes.N.rpdo.K]`,
else the node's device file (1400h-1403h, 1800h-1803h, 1600h-1603h, 1A00h-1A03h). A PDO
1-4 without a configured COB-ID takes the pre-defined one (180h/200h + (k-1) x 100h + N);
a configured COB-ID wins over another node's default. Nothing else is assumed: no
transmission type, inhibit time, event timer or mapping. PDO parameters written by SDO in
the trace are applied as `pdo_params` says: a COB-ID written to a node's PDO puts it on
that stream, a mapping holds from its confirmation to the node's next reset.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from nmtcheck.processes import pdo_params
from nmtcheck.processes import sdo_transfers as st
from nmtcheck.processes.attached import Attached
from nmtcheck.processes.comm_values import UNKNOWN, Value
from nmtcheck.spool import KeyedColumns
from nmtcheck.timeline.decode import KIND_CONFIGURED, KIND_RPDO, KIND_TPDO, node_frame_lines
from nmtcheck.timeline.model import ChannelModel, InputModel

TPDO_BASES = (0x180, 0x280, 0x380, 0x480)
RPDO_BASES = (0x200, 0x300, 0x400, 0x500)
SYNCHRONOUS = range(0, 241)
EVENT_DRIVEN = (254, 255)
_PARAMS = ("transmission_type", "inhibit_100us", "event_timer_ms", "sync_start")
FRAME_COLUMNS = {"ts": np.float64, "idx": np.int64, "line": np.int64, "dlc": np.uint8}
STREAMS_IN_MEMORY = 16 << 20  # bytes of stream frames held before they go to a file
STREAMS_CACHED = 64 << 20  # bytes of streams read back from it kept for the next rule


@dataclass
class Party:
    """A node's TPDO (the producer) or RPDO (a consumer) on a stream, with its values."""

    node: int
    pdo: int  # k
    kind: str  # tpdo | rpdo
    transmission_type: Value = UNKNOWN
    inhibit_100us: Value = UNKNOWN
    event_timer_ms: Value = UNKNOWN
    mapping: Value = UNKNOWN  # the files' mapped length in bytes (None: unknown; 0: not judged)
    entries: list[int] = field(default_factory=list)
    # the mapped length over time, the trace's SDO writes applied (set by `analyse`)
    pieces: pdo_params.MappingPieces | None = field(default=None, repr=False)
    written_cob: bool = False  # the party's COB-ID is known only from an SDO write

    @property
    def base_index(self) -> int:
        return (0x1800 if self.kind == "tpdo" else 0x1400) + self.pdo - 1

    @property
    def map_index(self) -> int:
        return (0x1A00 if self.kind == "tpdo" else 0x1600) + self.pdo - 1


@dataclass
class Stream:
    """A PDO COB-ID on a channel: its producer (None: unknown), consumers and frames."""

    channel: str  # the channel's name in the files
    chan: int  # its channel code in the model
    cob_id: int
    producer: Party | None
    consumers: list[Party]
    window: Value  # 1007h: the network's, else the producer's, else a consumer's
    model: InputModel = field(repr=False)

    @property
    def kind(self) -> str:
        return "tpdo" if self.producer is not None else "rpdo" if self.consumers else "unknown"

    @property
    def party(self) -> int:
        """The producer, else the first consumer (whose type Y004 uses)."""
        if self.producer is not None:
            return self.producer.node
        return self.consumers[0].node if self.consumers else -1

    @property
    def transmission_type(self) -> Value:
        """The producer's type, else a consumer's (§9.1.5)."""
        for p in [self.producer, *self.consumers]:
            if p is not None and p.transmission_type.known:
                return p.transmission_type
        return UNKNOWN

    @property
    def synchronous(self) -> bool:
        tt = self.transmission_type
        return tt.known and int(tt.value or 0) in SYNCHRONOUS

    # the input's stream frames (load_frames), read back by (chan, COB-ID)
    store: KeyedColumns | None = field(default=None, repr=False)
    # W over time where a party's 1007h is written in the trace: (piece starts, values)
    window_pieces: tuple[np.ndarray, list[Value]] | None = field(default=None, repr=False)

    def windows_at(self, ts: np.ndarray) -> tuple[np.ndarray, list[Value]]:
        """Per frame time, the index of the W in force (into the list returned)."""
        if self.window_pieces is None:
            return np.zeros(len(ts), np.int64), [self.window]
        starts, values = self.window_pieces
        out: np.ndarray = np.searchsorted(starts, ts + 1e-9, side="right") - 1
        return out, values

    @property
    def window_known(self) -> bool:
        """Whether a non-zero W is known for some of the stream's frames."""
        values = [self.window] if self.window_pieces is None else self.window_pieces[1]
        return any(v.known and v.value for v in values)

    @property
    def _frames(self) -> tuple[np.ndarray, ...]:
        if self.store is None:
            load_frames([self], self.model)
        assert self.store is not None
        return self.store.get(self.chan * 4096 + self.cob_id)

    def frames(self, model: InputModel | None = None, cm: ChannelModel | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(ts, frame index, line) of the stream's data frames, in file order."""
        ts, idx, line, _dlc = self._frames
        return ts, idx, line

    @property
    def dlc(self) -> np.ndarray:
        return self._frames[3]


def load_frames(found: list[Stream], model: InputModel) -> None:
    """Every stream's data frames, read in one pass over the node-frame store (a log of
    1 M frames a minute holds mostly PDOs; one pass per stream would read it 32 times),
    into one store the streams share: past a few MB it is a temporary file read back
    stream by stream (KeyedColumns), so the rules, which judge one stream at a time, hold
    one stream's frames, not all."""
    if not found:
        return
    store = KeyedColumns(FRAME_COLUMNS, STREAMS_IN_MEMORY, STREAMS_CACHED)
    keys = np.asarray(sorted({s.chan * 4096 + s.cob_id for s in found}), np.int64)
    for chunk in model.decoded.node_frames:
        key = (chunk["key"].astype(np.int64) // 128) * 4096 + chunk["can_id"].astype(np.int64)
        sel = np.flatnonzero(np.isin(key, keys))
        if not sel.size:
            continue
        order = sel[np.argsort(key[sel], kind="stable")]
        k = key[order]
        bounds = np.flatnonzero(np.diff(k)) + 1
        lines = node_frame_lines(chunk, order)
        for a, z in zip([0, *bounds.tolist()], [*bounds.tolist(), len(order)], strict=True):
            rows = order[a:z]
            store.append(int(k[a]), ts=chunk["ts"][rows], idx=chunk["idx"][rows],
                         line=lines[a:z].copy(), dlc=chunk["dlc"][rows])
    store.finish()
    for s in found:
        s.store = store


def pdo_ids(model: InputModel) -> list[tuple[int, int]]:
    """(channel code, CAN-ID) of every PDO CAN-ID that carried a data frame, pre-defined
    or configured: one pass over the node-frame store, for the rules that say what they
    skipped."""
    found: set[int] = set()
    for chunk in model.decoded.node_frames:
        pdo = np.isin(chunk["kind"], (KIND_TPDO, KIND_RPDO, KIND_CONFIGURED))
        if pdo.any():
            key = (chunk["key"][pdo].astype(np.int64) // 128) * 4096 + chunk["can_id"][pdo]
            found.update(np.unique(key).tolist())
    return [(k // 4096, k % 4096) for k in sorted(found)]


def streams(model: InputModel, network: Any) -> list[Stream]:
    """Every stream the files describe on the model's channels, and those whose COB-ID
    the trace writes by SDO (§9.1.1 (3)): its producer and consumers with their
    parameters."""
    out: list[Stream] = []
    for cm in model.channels:
        name = cm.network_name
        for cob, producer, consumers, window in channel_parties(network, name, cm):
            out.append(Stream(name, cm.chan, cob, producer, consumers, window, model))
    return out


def _written_parties(cm: ChannelModel, parties: dict[int, list[Party]]) -> None:
    """The PDOs whose COB-ID the trace writes by SDO (valid, 11-bit) join the stream of
    that COB-ID where the files put no such PDO of the node there."""
    for n, m in sorted(cm.nodes.items()):
        if not len(m.writes) and not len(m.pdo_writes):
            continue
        for kind in ("tpdo", "rpdo"):
            for k, cobs in sorted(pdo_params.written_cob_ids(m, kind).items()):
                for cob in sorted(cobs):
                    there = parties.setdefault(cob, [])
                    if not any((p.node, p.kind, p.pdo) == (n, kind, k) for p in there):
                        there.append(Party(n, k, kind, written_cob=True))


def channel_parties(network: Any, name: str, cm: ChannelModel | None = None
                    ) -> list[tuple[int, Party | None, list[Party], Value]]:
    """(COB-ID, producer, consumers, W) of each stream the files describe on the channel
    `name`, by COB-ID: what `streams` builds on, and what live mode judges frames by.
    With the channel's model `cm`, also the PDOs whose COB-ID the trace writes by SDO."""
    nodes = [] if network is None else [
        n for n in sorted(set(network.nodes) | set(network.comm_nodes))
        if network.node_channel(n) in (None, name)]
    parties: dict[int, list[Party]] = {}
    defaults: dict[int, list[Party]] = {}
    for n in nodes:
        for kind in ("tpdo", "rpdo"):
            for party, cob, configured in _parties(network, n, kind):
                (parties if configured else defaults).setdefault(cob, []).append(party)
    for cob, found in defaults.items():  # a configured COB-ID wins over a default
        if cob not in parties:
            parties[cob] = found
    if cm is not None:
        _written_parties(cm, parties)
    out = []
    for cob in sorted(parties):
        found = parties[cob]
        producer = next((p for p in found if p.kind == "tpdo"), None)
        consumers = [p for p in found if p.kind == "rpdo"]
        window = (_window(network, name, [p.node for p in found]) if network is not None
                  else UNKNOWN)
        out.append((cob, producer, consumers, window))
    return out


def _parties(network: Any, n: int, kind: str) -> list[tuple[Party, int, bool]]:
    """Node n's TPDOs or RPDOs the files describe: (party, COB-ID, configured?)."""
    keys = network.comm_nodes.get(n)
    tables = (keys.tpdo if kind == "tpdo" else keys.rpdo) if keys is not None else {}
    dev = network.devices.get(n)
    dev_types = (dev.tpdo_types if kind == "tpdo" else dev.rpdo_types) if dev else {}
    dev_cobs = (dev.tpdo_cob_ids if kind == "tpdo" else dev.rpdo_cob_ids) if dev else {}
    dev_params = (dev.tpdo_params if kind == "tpdo" else dev.rpdo_params) if dev else {}
    bases = TPDO_BASES if kind == "tpdo" else RPDO_BASES
    out = []
    for k in sorted(set(tables) | set(dev_types) | set(dev_params) | set(dev_cobs)):
        pdo = tables.get(k)
        configured = True
        if pdo is not None and pdo.cob_id is not None:
            if pdo.cob_id & 0xA0000000:  # not valid, or a 29-bit ID: no part (§9.1.3)
                continue
            cob: int | None = pdo.cob_id & 0x7FF
        elif k in dev_cobs:
            cob = dev_cobs[k]
        else:
            cob, configured = (bases[k - 1] + n if k <= 4 else None), False
        if cob is None:
            continue
        party = Party(n, k, kind)
        from_dev = dict(dev_params.get(k, {}))
        if k in dev_types:
            from_dev["transmission_type"] = dev_types[k]
        for name in _PARAMS:
            given = getattr(pdo, name, None) if pdo is not None else None
            if given is not None:
                setattr(party, name, Value(given, "network", n))
            elif from_dev.get(name) is not None:
                setattr(party, name, Value(from_dev[name], "device-file", n))
        entries = pdo.mapping if pdo is not None and pdo.mapping is not None else (
            from_dev.get("mapping"))
        if entries is not None:
            source = "network" if pdo is not None and pdo.mapping is not None else "device-file"
            party.entries = list(entries)
            length = -(-sum(e & 0xFF for e in entries) // 8)  # bits to bytes, rounded up
            party.mapping = Value(length if entries else 0, source, n)
        out.append((party, cob, configured))
    return out


def _window(network: Any, channel: str, nodes: list[int]) -> Value:
    """W of §9.1.1: `[sync] window_us`, else a party's 1007h (the producer first)."""
    keys = network.sync_keys(channel)
    if keys is not None and keys.window_us is not None:
        return Value(keys.window_us, "network")
    for n in nodes:
        dev = network.devices.get(n)
        if dev is not None and dev.sync_window_us is not None:
            return Value(dev.sync_window_us, "device-file", n)
    return UNKNOWN


@dataclass(frozen=True)
class ReservedWrite:
    """An SDO download of a reserved transmission type (SPEC §9.2.2, D006)."""

    channel: str
    node: int  # the SDO server
    index: int
    value: int
    time: float  # the download request
    frame_index: int
    line: int
    result: str  # ok | refused | aborted | unanswered | open
    abort_code: int


@dataclass(frozen=True)
class PdoGap:
    """A gap D004 reported: the RPDO that armed the deadline, the next one (inf: none),
    the stream's producer (None: unknown) and its period (for the effect's start t_e)."""

    cob_id: int
    last_ts: float
    last_idx: int
    next_ts: float
    producer: int | None
    period: float


@dataclass
class PdoAnalysis:
    """The streams of the input, the downloads of reserved transmission types, and each
    gap D004 reported by (channel, consumer, finding time), for its causes and chains."""

    streams: list[Stream] = field(default_factory=list)
    reserved: list[ReservedWrite] = field(default_factory=list)
    gaps: dict[tuple[str, int, float], PdoGap] = field(default_factory=dict)


_SLOT: Attached[PdoAnalysis] = Attached("pdo")
attach = _SLOT.attach  # the engine keeps the analysis with the model
of = _SLOT.of  # the rules and reports read it


def analyse(model: InputModel, network: Any, spool: Any, sdo_timeout_s: float) -> PdoAnalysis:
    """The streams the files describe, and every SDO download of sub-index 2 of a PDO
    communication parameter (1400h-15FFh, 1800h-19FFh) with a reserved value."""
    found = streams(model, network)
    load_frames(found, model)
    _apply_writes(found)
    return PdoAnalysis(found, _reserved_writes(model, spool, sdo_timeout_s))


def _apply_writes(found: list[Stream]) -> None:
    """The trace's SDO writes of the parties' parameters: the mapping as pieces over time,
    the rest as the one value in force over the stream's frames (pdo_params)."""
    for s in found:
        cm = next((c for c in s.model.channels if c.chan == s.chan), None)
        if cm is None:
            continue
        ts = s.frames()[0]
        a, b = (float(ts.min()), float(ts.max())) if len(ts) else (-np.inf, np.inf)
        for p in [s.producer, *s.consumers]:  # W: the producer's 1007h, else a consumer's
            m = cm.nodes.get(p.node) if p is not None else None
            if p is not None and pdo_params.written(m, 0x1007, (0,)):
                own = s.window if s.window.node in (None, p.node) else UNKNOWN
                s.window_pieces = pdo_params.pieces(m, 0x1007, 0, own)
                s.window = pdo_params.constant_over(m, 0x1007, 0, own, a, b)
                break
        for p in [s.producer, *s.consumers]:
            if p is None:
                continue
            m = cm.nodes.get(p.node)
            p.pieces = pdo_params.mapping_pieces(
                m, p.map_index, p.entries if p.mapping.known else None, p.mapping)
            if m is None or (not len(m.pdo_writes) and not len(m.writes)):
                continue
            for name, sub in (("transmission_type", 2), ("inhibit_100us", 3),
                              ("event_timer_ms", 5)):
                setattr(p, name, pdo_params.constant_over(m, p.base_index, sub,
                                                          getattr(p, name), a, b))


def _reserved_writes(model: InputModel, spool: Any, sdo_timeout_s: float
                     ) -> list[ReservedWrite]:
    by_chan = {cm.chan: cm for cm in model.channels}
    out: list[ReservedWrite] = []
    for key in sorted(spool.pdo_type_servers):  # most logs: none
        cm = by_chan.get(key // 128)
        if cm is None:
            continue
        t = st.transfers(spool.frames(key), cm.end, sdo_timeout_s)
        tpdo = (t.index >= 0x1800) & (t.index <= 0x19FF)
        rpdo = (t.index >= 0x1400) & (t.index <= 0x15FF)
        v = t.value.astype(np.int64)
        bad = (t.direction == st.DOWNLOAD) & (t.sub == 2) & t.has_value & (
            (tpdo & (v >= 241) & (v <= 251)) | (rpdo & (v >= 241) & (v <= 253)))
        out += [ReservedWrite(cm.name, key % 128, int(t.index[k]), int(v[k]),
                              float(t.start_ts[k]), int(t.start_idx[k]), int(t.start_line[k]),
                              st.RESULTS[int(t.result[k])], int(t.abort_code[k]))
                for k in np.flatnonzero(bad).tolist()]
    return out
