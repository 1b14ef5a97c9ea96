"""How far a check's verdict reaches, read from the model after the rules ran (SPEC §7):
which selected rules could not be evaluated (`not_evaluated`, with the reason) and where
a finding's limit came from (`basis`: `configured`, `assumed` or `measured`).

A rule that had nothing to judge is not a rule that passed: without a network file N001
has no node to expect, H003 compares a period with a producer time that nothing gives,
G003 needs guard time and life time factor, H004 a consumer entry (1016h). And a
heartbeat timeout of 1.5 x a median the trace itself measured is a guess, not the
configured limit. The rules themselves (checks/) do not change: this reads the model.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

import numpy as np

from nmtcheck.processes import emcy as emcy_stage
from nmtcheck.processes import lss as lss_stage
from nmtcheck.processes import pdo as pdo_stage
from nmtcheck.processes import sync as sync_stage
from nmtcheck.protocol.nmt import BOOTUP, HEARTBEAT
from nmtcheck.timeline.model import InputModel, NodeConfig, NodeModel

if TYPE_CHECKING:
    from nmtcheck.results import Finding

CONFIGURED, ASSUMED, MEASURED = "configured", "assumed", "measured"

NO_NETWORK = "no network file (--network): no node is expected"
NO_PRODUCER_TIME = "no producer time configured or written"
NO_GUARDING = "no guard time/life time factor configured or written"
NO_CONSUMER = "no heartbeat consumer time (1016h) configured or written"
NODE_REASONS = {"H003": NO_PRODUCER_TIME, "G003": NO_GUARDING, "H004": NO_CONSUMER}
# SPEC §9.1.9, where the input has SYNC frames or EMCYs to judge
NO_SYNC_PERIOD = ("SYNC period unknown: no 1006h configured or written, fewer than "
                  "min_intervals SYNC intervals")
NO_PRODUCER_PERIOD = "the SYNC producer's 1006h is unknown"
NO_EMCY_INHIBIT = "no EMCY inhibit time (1015h) known"
NO_SYNC_PDO = "no synchronous PDO with a known transmission type"
NO_WINDOW = "1007h unknown or 0"
NO_OVERFLOW = "1019h unknown: only DLC > 1, remote frames and DLC changes were checked"
# SPEC §9.1.9: the D rules lacking what they compare with, on an input with PDO frames
PDO_REASONS = {
    "D001": "no TPDO of type 254/255 with a known non-zero event timer",
    "D002": "no TPDO of type 254/255 with a known non-zero inhibit time",
    "D003": "no TPDO with a known synchronous transmission type",
    "D004": "no RPDO with a known non-zero event timer (deadline)",
    "D005": "no PDO mapping known",
}
# SPEC §9.1.9: L001/L002 without timestamps judge only "before the next request"
NO_LSS_TIMEOUT = ("no timestamps: lss_response_timeout_ms was not judged, only the next "
                  "request ends the wait for an answer")
MAX_SCOPE = 20  # what a partly evaluated rule skipped, named (then counted)


def partly_evaluated(model: InputModel, codes: Iterable[str]) -> dict[str, str]:
    """Rules that judged part of the input and skipped the rest for want of a value
    (SPEC §9.1.3: `partial`), each with its reason and what it skipped: E001 for the
    nodes whose 1015h is unknown, Y002 for the channels whose 1019h is (its other parts
    ran)."""
    out: dict[str, str] = {}
    codes = list(codes)
    emcy = emcy_stage.of(model)
    senders = [e for e in (emcy.nodes.values() if emcy is not None else ()) if len(e) > 1]
    unknown = [e for e in senders if not bool(np.nan_to_num(e.inhibit).any())]
    if "E001" in codes and unknown and len(unknown) < len(senders):
        out["E001"] = _scoped(NO_EMCY_INHIBIT, [f"{e.channel} node {e.node}" for e in unknown])
    if "D005" in codes:
        skipped = _d005_skipped(model)
        if skipped:
            out["D005"] = _scoped(PDO_REASONS["D005"], skipped)
    sync = sync_stage.of(model)
    if "Y002" in codes and sync is not None:
        skipped = [sc.channel for sc in sync.channels.values() if len(sc)
                   and any(not v.overflow.known for v in sc.by_segment)]
        if skipped:
            out["Y002"] = _scoped(NO_OVERFLOW, [f"{c} SYNC" for c in skipped])
    lss = lss_stage.of(model)
    if model.timeline.order_only and lss is not None and lss.channels:
        out.update({code: NO_LSS_TIMEOUT for code in ("L001", "L002") if code in codes})
    cut = [lc for lc in (lss.channels.values() if lss is not None else ()) if lc.left_out]
    if cut:
        why = _scoped(f"more than {lss_stage.MAX_REQUESTS} LSS requests on a channel: the "
                      "LSS frames after that were not judged",
                      [f"{lc.channel} from line {lc.left_out_line}" for lc in cut])
        out.update({code: why for code in ("L001", "L002", "L003", "L004", "L005", "L006",
                                           "L007") if code in codes and code not in out})
    return out


def _d005_skipped(model: InputModel) -> list[str]:
    """What D005 skipped on an input where it judged some party's mapping: the parties
    whose mapping is unknown for some of their frames, and the PDO CAN-IDs that carried
    frames but are no stream's (SPEC §9.1.3 `partial`). Empty where it judged nothing."""
    found = pdo_stage.of(model)
    streams = found.streams if found is not None else []
    parties = [(st, p) for st in streams for p in [st.producer, *st.consumers] if p is not None]
    if not any(p.pieces is not None and p.pieces.known for _, p in parties):
        return []
    out = []
    for st, p in parties:
        ts = st.frames()[0]
        if p.pieces is None or not len(ts):
            continue
        if (p.pieces.length[p.pieces.at(ts)] < 0).any():
            out.append(f"{st.channel} {p.kind.upper()} {st.cob_id:03X}h (node {p.node})")
    covered = {(st.chan, st.cob_id) for st in streams}
    names = {cm.chan: cm.network_name for cm in model.channels}
    for chan, cob in pdo_stage.pdo_ids(model):
        if (chan, cob) not in covered and chan in names:
            out.append(f"{names[chan]} PDO {cob:03X}h")
    return out


def _pdo_reasons(model: InputModel, codes: list[str]) -> dict[str, str]:
    """D001-D005 with nothing to judge for want of a parameter, on an input whose frames
    include PDOs (SPEC §9.1.9)."""
    wanted = [c for c in codes if c in PDO_REASONS]
    if not wanted or not model.decoded.pdo_frames:
        return {}
    found = pdo_stage.of(model)
    streams = found.streams if found is not None else []
    producers = [st.producer for st in streams if st.producer is not None]
    consumers = [c for st in streams for c in st.consumers]

    def known(v: Any, allowed: range | tuple[int, ...] | None = None) -> bool:
        return bool(v.known and v.value) and (allowed is None or int(v.value) in allowed)

    event = (254, 255)
    judged = {
        "D001": any(known(p.transmission_type, event) and known(p.event_timer_ms)
                    for p in producers),
        "D002": any(known(p.transmission_type, event) and known(p.inhibit_100us)
                    for p in producers),
        "D003": any(p.transmission_type.known and int(p.transmission_type.value or 0) <= 240
                    for p in producers),
        "D004": any(known(c.event_timer_ms) for c in consumers),
        "D005": any(p.pieces is not None and p.pieces.known for p in [*producers, *consumers]),
    }
    return {c: PDO_REASONS[c] for c in wanted if not judged[c]}


def _scoped(reason: str, scope: list[str]) -> str:
    more = f" and {len(scope) - MAX_SCOPE} more" if len(scope) > MAX_SCOPE else ""
    return f"{reason} ({', '.join(scope[:MAX_SCOPE])}{more})"


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
    out.update(_comm_reasons(model, [c for c in codes if c not in out]))
    return out


def _comm_reasons(model: InputModel, codes: list[str]) -> dict[str, str]:
    """Y001, Y005 and E001 lacking the value they need (SPEC §9.1.9), on an input that has
    SYNC frames (Y) or a node with two EMCYs (E001) to judge."""
    out: dict[str, str] = {}
    sync = sync_stage.of(model)
    channels = [sc for sc in (sync.channels.values() if sync is not None else ()) if len(sc)]
    if channels and "Y001" in codes and not any(
            sc.period.known or any(len(pos) > 5 for pos in sc.segments()) for sc in channels):
        out["Y001"] = NO_SYNC_PERIOD
    if channels and "Y004" in codes:
        found = pdo_stage.of(model)
        pdos = [st for st in found.streams if st.synchronous] if found is not None else []
        if not pdos:
            out["Y004"] = NO_SYNC_PDO
        elif not any(st.window_known for st in pdos):
            out["Y004"] = NO_WINDOW
    if channels and "Y005" in codes and not any(
            sc.producer_period.known and sc.producer_period.value for sc in channels):
        out["Y005"] = NO_PRODUCER_PERIOD
    out.update(_pdo_reasons(model, codes))
    emcy = emcy_stage.of(model)
    senders = [e for e in (emcy.nodes.values() if emcy is not None else ()) if len(e) > 1]
    if senders and "E001" in codes and not any(
            bool(np.nan_to_num(e.inhibit).any()) for e in senders):
        out["E001"] = NO_EMCY_INHIBIT
    return out


def finding_bases(model: InputModel, findings: Iterable[Finding]) -> None:
    """Set `basis` on each finding whose limit is a time: H001 and H002 `configured` when
    the timeout or period in force came from a file or an SDO write, else `measured`
    (a factor x the period measured from the trace); H003, H004 and G003 only ever
    compare with configured values. An H001 timeout made of a configured producer time x
    `timeout_factor` where no consumer time is known is `assumed` (SPEC §7): the consumer
    time is what a consumer times out on, and the log does not show it."""
    nodes: dict[tuple[str | None, int | None], NodeModel] = {
        (cm.name, m.node): m for cm in model.channels for m in cm.nodes.values()}
    by_node: dict[tuple[str | None, int | None, str], list[Finding]] = {}
    sync = sync_stage.of(model)
    for f in findings:
        if f.rule in ("H003", "H004", "G003", "Y004", "Y005", "D001", "D002", "D004", "E001"):
            f.basis = CONFIGURED
        elif f.rule == "Y001" and sync is not None:
            gap = sync.gaps.get((str(f.channel), round(f.time, 9)))
            f.basis = gap.basis if gap is not None else None
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
                f.basis = (CONFIGURED if c >= 2 or (c > 0 and rule == "H002")
                           else ASSUMED if c > 0 else MEASURED)


def _limit_configured(cfg: NodeConfig) -> float:
    """2 when the configuration gives the heartbeat timeout (a consumer time), 1 when it
    gives only a non-zero producer time (H001's timeout is then nmtcheck's factor x it),
    else 0."""
    if cfg.consumer_timeout_ms:
        return 2.0
    return 1.0 if (cfg.heartbeat_ms or 0) > 0 else 0.0


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
