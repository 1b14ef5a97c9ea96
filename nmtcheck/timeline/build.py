"""Decoded events -> per (channel, node) NMT state timeline (SPEC §2).

Each node's error-control frames are numpy columns (`EcTable`): they are
classified (boot-up, heartbeat, guarding response), the heartbeat period is
found (configured, else the median interval), heartbeat and guarding timeouts
are computed, and finally the state intervals are built, with OFFLINE from each
timeout to the node's next frame of any kind. Everything is vectorised per node
but the interval walk, which sees only the frames that can change the state.
NMT commands and EMCYs are columns too; only the configuration SDOs are Python objects.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from nmtcheck.readers.captures import CaptureSpan
from nmtcheck.timeline.config_writes import pair_sdo_writes, write_validity
from nmtcheck.timeline.decode import Decoded, node_groups
from nmtcheck.timeline.error_control import (
    classify,
    ec_columns,
    find_period,
    guard_timeouts,
    heartbeat_timeouts,
    node_ec_tables,
    offline_ends,
    self_starts,
    small_ec,
)
from nmtcheck.timeline.intervals import (
    bootups_only,
    mark_power_on_bootups,
    node_intervals,
    only_bootups,
    reports_by_node,
)
from nmtcheck.timeline.masters import channel_master, master_obeyed
from nmtcheck.timeline.model import (
    ChannelModel,
    CommandTable,
    EmcyTable,
    InputModel,
    Master,
    NmtTable,
    NodeConfig,
    NodeModel,
    TimelineParams,
)
from nmtcheck.timeline.recording_gaps import find_recording_gaps
from nmtcheck.timeline.tables import shared_empty


def build(decoded: Decoded, channels: list[str], start: float, end: float,
          params: TimelineParams, configs: dict[tuple[str | None, int], NodeConfig],
          masters: dict[str, Master] | None = None,
          captures: dict[int, CaptureSpan] | None = None) -> InputModel:
    """Build every node's model and timeline from the decoded input.

    `masters`: the NMT master of a channel (by name) known from the network or device
    files; on other channels it is inferred from the start-up pattern (SPEC §2).
    `captures`: the channels of a later capture in the input, by code, with their span:
    each is the trace of its own recording (nmtcheck/readers/captures.py).
    """
    # each channel's rows, found once: a log may have tens of thousands of channels
    ev_rows, nmt_rows = _rows_by_channel(decoded.events["chan"]), _rows_by_channel(
        decoded.nmt["chan"])
    sent: dict[int, list[int]] = {}
    for key in decoded.first_tx:
        sent.setdefault(key // 128, []).append(key)
    ec_groups, emcy_groups = node_groups(decoded.ec), node_groups(decoded.emcy)
    ec_cols = ec_columns(decoded.ec)
    models = []
    for chan, name in enumerate(channels):
        span = (captures or {}).get(chan)
        cm = _channel(decoded, chan, name, span.start if span else start,
                      span.end if span else end, params, configs, masters or {},
                      ev_rows.get(chan), nmt_rows.get(chan), sent.get(chan, []),
                      ec_groups.get(chan, []), emcy_groups.get(chan, []), ec_cols)
        if span is not None:
            cm.log_name, cm.first_index, cm.first_line = (span.log_name, span.first_index,
                                                          span.first_line)
        models.append(cm)
    # the whole channel silent past every running limit: the recorder's gap, maybe (I007);
    # its time comes out of the timeouts before they make OFFLINE intervals
    find_recording_gaps(decoded, models, params,
                        sorted({s.first_index for s in (captures or {}).values()}))
    # OFFLINE lasts until the node's next frame of any kind: one pass for all channels
    offline_ends(decoded, [(m, t) for cm in models for m in cm.nodes.values()
                            for t in m.timeouts])
    self_starts(decoded, [(m, cm.end) for cm in models for m in cm.nodes.values()])
    for cm in models:
        reports = reports_by_node(cm) if params.order_only else {}
        for m in cm.nodes.values():
            m.intervals = (bootups_only(m.ec, cm.start, cm.end) if only_bootups(m)
                           else node_intervals(m, cm.start, cm.end, params.obey_s, reports))
    return InputModel(decoded, start, end, models, params)


_NO_CONFIG = NodeConfig()  # nothing from files: shared by such nodes, never changed


class _Nodes(dict[int, NodeModel]):
    """A channel's nodes, each made on first mention with its configuration from files."""

    def __init__(self, chan: int, name: str,
                 configs: dict[tuple[str | None, int], NodeConfig]) -> None:
        super().__init__()
        self.chan, self.name, self.configs = chan, name, configs

    def __call__(self, n: int) -> NodeModel:
        m = self.get(n)
        if m is None:
            cfg = self.configs.get((self.name, n)) or self.configs.get((None, n)) or _NO_CONFIG
            m = self[n] = NodeModel(self.chan, self.name, n, cfg)
        return m


def _rows_by_channel(chan: np.ndarray) -> dict[int, np.ndarray | None]:
    """Per channel code, the positions of its rows (None: every row is that channel's,
    the usual case, so no copy is made)."""
    if not len(chan):
        return {}
    first = int(chan[0])
    if bool((chan == first).all()):
        return {first: None}
    order = np.argsort(chan, kind="stable")
    codes, starts = np.unique(chan[order], return_index=True)
    bounds = np.append(starts, len(order))
    return {int(c): order[bounds[i]:bounds[i + 1]] for i, c in enumerate(codes.tolist())}


def _channel(decoded: Decoded, chan: int, name: str, start: float, end: float,
             params: TimelineParams, configs: dict[tuple[str | None, int], NodeConfig],
             masters: dict[str, Master], ev_rows: np.ndarray | None,
             nmt_rows: np.ndarray | None, sent: list[int],
             ec_groups: list[tuple[int, slice]],
             emcy_groups: list[tuple[int, slice]], ec_cols: dict[str, np.ndarray]
             ) -> ChannelModel:
    """One channel's nodes, commands and master, each node classified and timed (the
    state intervals come last, once every node's timeouts have their ends).

    `ev_rows`/`nmt_rows`: the channel's rows of the decoded events and NMT frames (None:
    all of them); `sent`: the node keys of the channel that transmitted; `ec_groups`,
    `emcy_groups`: each node's rows of the decoded error-control and EMCY columns;
    `ec_cols`: the error-control columns of `ec_columns`."""
    ev = decoded.events
    if ev_rows is None:
        rows = ev if not len(ev) or int(ev["chan"][0]) == chan else ev[:0]
    else:
        rows = ev[ev_rows]
    nmt = _nmt_table(decoded.nmt, chan, nmt_rows)
    nodes = _Nodes(chan, name, configs)
    _nodes_that_sent(decoded, sent, nodes)
    ec_tables = node_ec_tables(decoded, chan, ec_groups, ec_cols)
    for n, table in ec_tables.items():
        if not table.rtr.all():  # a node exists once it sends; requests alone do not
            nodes(n)
    _first_shown_by_commands(nmt, nodes)
    _emcy(decoded, emcy_groups, nodes)
    pair_sdo_writes(rows, nodes)  # SDO traffic: the configuration written in the trace
    for n, table in ec_tables.items():
        if n in nodes:  # requests to a node nothing else shows are not kept
            nodes[n].ec = table
    master, master_note = channel_master(name, nmt, ec_tables, params, masters, start)
    if len(nmt):  # else every node keeps its empty command table
        _apply_commands(nmt, nodes, master, params)
    requests = {n: classify(m, params, with_period=False, start=start)  # boot-ups bound the
                for n, m in nodes.items()}  # SDO-written values
    write_validity(nodes)
    if not params.order_only:  # "within obey_ms" needs time
        mark_power_on_bootups(nmt, nodes, params.obey_s)
    for n, m in nodes.items():
        m.small = small_ec(m, params)
        find_period(m)
        if requests[n]:  # without requests the second pass classifies alike
            classify(m, params, with_period=True, start=start)
            find_period(m)
        if params.order_only:  # frame numbers are no time: nothing was measured
            m.order_only = True
            m.median_s = m.period_s = None
            m.period_source = "none"
    for n, m in nodes.items():
        if not params.order_only:  # no timestamps: no timeouts either (SPEC §1)
            heartbeat_timeouts(m, params, end)
            if requests[n]:  # G002 needs a request
                guard_timeouts(m, params, end)
    return ChannelModel(chan, name, nmt, dict(sorted(nodes.items())), master, master_note,
                        start, end)


def _nodes_that_sent(decoded: Decoded, keys: list[int], nodes: _Nodes) -> None:
    """Nodes that transmitted anything (TPDO, SDO, EMCY, error control) exist from their
    first frame."""
    for key in keys:
        first = decoded.first_tx[key]
        if 1 <= key % 128 <= 127:
            m = nodes(key % 128)
            m.first_tx = first
            m.first_show_idx, m.first_show_ts = first.idx, first.ts
            m.last_seen = decoded.last_tx.get(key)


def _emcy(decoded: Decoded, groups: list[tuple[int, slice]], nodes: _Nodes) -> None:
    """Each node's EMCYs: views into the decoded columns (grouped by node)."""
    cols = decoded.emcy
    for n, r in groups:
        nodes(n).own_events().emcy = EmcyTable(cols["ts"][r], cols["idx"][r], cols["line"][r],
                                         cols["dlc"][r], cols["data"][r])


def _nmt_table(cols: dict[str, np.ndarray], chan: int, rows: np.ndarray | None) -> NmtTable:
    """The channel's frames on 000h (`rows`; None: all of them): views of the decoded
    columns when the input has one channel (a log of nothing but NMT frames must not be
    held twice)."""
    names = ("ts", "idx", "line", "rtr", "dlc", "cs", "target")
    if rows is None:
        if not len(cols["chan"]) or int(cols["chan"][0]) != chan:
            return shared_empty(NmtTable)  # most channels of a many-channel log
        return NmtTable(*(cols[name] for name in names))
    return NmtTable(*(cols[name][rows] for name in names))


def _first_shown_by_commands(nmt: NmtTable, node_model: Callable[[int], NodeModel]) -> None:
    """A valid direct command shows its target node exists, from that command on."""
    if not len(nmt):
        return
    direct = np.flatnonzero(nmt.valid & (nmt.target != 0))
    if not direct.size:
        return
    targets = nmt.target[direct]
    for n in np.unique(targets).tolist():
        first = direct[np.argmax(targets == n)]
        m = node_model(n)
        idx = int(nmt.idx[first])
        if m.first_show_idx is None or idx < m.first_show_idx:
            m.first_show_idx, m.first_show_ts = idx, float(nmt.ts[first])


def _apply_commands(nmt: NmtTable, nodes: dict[int, NodeModel],
                    master: Master | None, params: TimelineParams) -> None:
    """Each valid command to the nodes it applies to: a direct one to its target, a
    broadcast to every node seen before it; to the channel's master only where its own
    frames show that it obeyed (SPEC §2: a CAN controller does not receive its own
    frames, so Lely's master ignores its own `000#8200`, while CANopenNode applies its
    own commands to itself, and Lely's master obeys its own `000#8100`)."""
    broadcast = nmt.valid & (nmt.target == 0)
    for n, m in nodes.items():
        mine = nmt.valid & (nmt.target == n)
        if m.first_show_idx is not None:
            seen = broadcast & (m.first_show_idx < nmt.idx)
            if master is not None and n == master.node:
                own = np.flatnonzero(seen)
                obeyed = own[master_obeyed(m, nmt, own, mine, params)]
                m.own_command_idx = nmt.idx[obeyed]
                seen = np.zeros(len(nmt), bool)
                seen[obeyed] = True
            mine |= seen
        m.commands = CommandTable(nmt, np.flatnonzero(mine))
