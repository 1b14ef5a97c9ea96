"""How far a check's verdict reaches, read from the model after the rules ran (SPEC §7):
which selected rules could not be evaluated (`not_evaluated`, with the reason) and where
a finding's limit came from (`basis`: `configured` or `measured`).

A rule that had nothing to judge is not a rule that passed: without a network file N001
has no node to expect, H003 compares a period with a producer time that nothing gives,
G003 needs guard time and life time factor, H004 a consumer entry (1016h). And a
heartbeat timeout of 1.5 x a median the trace itself measured is a guess, not the
configured limit. The rules themselves (checks/) do not change: this reads the model.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING

import numpy as np

from nmtcheck.protocol.nmt import BOOTUP, HEARTBEAT
from nmtcheck.timeline.model import InputModel, NodeConfig, NodeModel

if TYPE_CHECKING:
    from nmtcheck.results import Finding

CONFIGURED, MEASURED = "configured", "measured"

NO_NETWORK = "no network file (--network): no node is expected"
NO_PRODUCER_TIME = "no producer time configured or written"
NO_GUARDING = "no guard time/life time factor configured or written"
NO_CONSUMER = "no heartbeat consumer time (1016h) configured or written"
NODE_REASONS = {"H003": NO_PRODUCER_TIME, "G003": NO_GUARDING, "H004": NO_CONSUMER}


def _written(m: NodeModel, index: int) -> bool:
    return bool((m.writes.index == index).any()) if len(m.writes) else False


def node_reason(code: str, m: NodeModel) -> str | None:
    """Why rule `code` could not be evaluated for node `m`, or None when it could."""
    cfg = m.config
    if code == "H003":
        if not (cfg.heartbeat_ms or 0) > 0 and not _written(m, 0x1017):
            return NO_PRODUCER_TIME
    elif code == "G003":
        guard = bool(cfg.guard_time_ms) or _written(m, 0x100C)
        factor = bool(cfg.life_time_factor) or _written(m, 0x100D)
        if not (guard and factor):
            return NO_GUARDING
    elif code == "H004" and not _written(m, 0x1016) and not any(
            t for p, t in cfg.consumes.items() if p != m.node):
        return NO_CONSUMER
    return None


def not_evaluated(model: InputModel, codes: Iterable[str], network_given: bool
                  ) -> dict[str, str]:
    """The selected rules (`codes`) that could not be evaluated on this input at all,
    each with its reason: N001 without a network file; H003, G003, H004 when no node
    of the input has what they need (from a file or written by SDO in the trace)."""
    nodes = list(model.nodes())
    out: dict[str, str] = {}
    for code in codes:
        if code == "N001" and not network_given:
            out[code] = NO_NETWORK
        elif code in NODE_REASONS and all(node_reason(code, m) for m in nodes):
            out[code] = NODE_REASONS[code]
    return out


def finding_bases(model: InputModel, findings: Iterable[Finding]) -> None:
    """Set `basis` on each finding whose limit is a time: H001 and H002 `configured` when
    the timeout or period in force came from a file or an SDO write, else `measured`
    (a factor x the period measured from the trace); H003, H004 and G003 only ever
    compare with configured values."""
    nodes: dict[tuple[str | None, int | None], NodeModel] = {
        (cm.name, m.node): m for cm in model.channels for m in cm.nodes.values()}
    by_node: dict[tuple[str | None, int | None, str], list[Finding]] = {}
    for f in findings:
        if f.rule in ("H003", "H004", "G003"):
            f.basis = CONFIGURED
        elif f.rule in ("H001", "H002"):
            by_node.setdefault((f.channel, f.node, f.rule), []).append(f)
    for (channel, node, rule), group in by_node.items():
        m = nodes.get((channel, node))
        if m is None:
            continue
        at = _h001_starts(m, group) if rule == "H001" else _h002_starts(m, group)
        configured = m.config_series(np.asarray(at, np.float64), _limit_configured)
        for f, t, c in zip(group, at, configured.tolist(), strict=True):
            if not np.isnan(t):
                f.basis = CONFIGURED if c > 0 else MEASURED


def _limit_configured(cfg: NodeConfig) -> float:
    """1 when the configuration gives the heartbeat limit (a consumer time or a non-zero
    producer time), else 0."""
    return 1.0 if cfg.consumer_timeout_ms or (cfg.heartbeat_ms or 0) > 0 else 0.0


def _h001_starts(m: NodeModel, group: list[Finding]) -> list[float]:
    """The start of each H001 finding's gap (its timeout was fixed there), NaN if unknown."""
    starts = {round(t.moment, 9): t.after_ts for t in m.timeouts if t.rule == "H001"}
    return [starts.get(round(f.time, 9), np.nan) for f in group]


def _h002_starts(m: NodeModel, group: list[Finding]) -> list[float]:
    """The first heartbeat of each H002 finding's pair (the period in force there)."""
    pos = m.ec.where(HEARTBEAT, BOOTUP)
    idx = m.ec.idx[pos]
    out = []
    for f in group:
        at = -1 if f.frame_index is None else f.frame_index
        k = int(np.searchsorted(idx, at))
        ok = 0 < k < len(pos) and int(idx[k]) == at
        out.append(float(m.ec.ts[pos[k - 1]]) if ok else np.nan)
    return out
