"""What `nmtcheck timeline --format csv|json` and the HTML timeline draw of LSS (SPEC
§9.4.2): each LSS exchange with the L finding at it, the LSS sessions, and where a node
that boots under an LSS-assigned node-ID got it (the configure exchange).

An exchange's findings: L003, L004, L005 and L007 name one of its frames; L001 and L002
end its wait for an answer (their frame is the next request, which is another exchange,
so they are matched by the request the rule judged); L006 belongs to the
configure-node-ID exchange whose node-ID was not adopted."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from nmtcheck.processes import lss as lss_stage
from nmtcheck.processes.lss import Exchange, LssChannel
from nmtcheck.results import Finding, InputResult

FAILURES = ("L001", "L002", "L003", "L004", "L005", "L006")  # red on the timeline
# LSS marks a page draws, shared among the channels with LSS (each at least
# MIN_LSS_MARKS_PER_CHANNEL); the first ones in file order, the rest counted
MAX_LSS_MARKS = 5000
MIN_LSS_MARKS_PER_CHANNEL = 200
EPS = 1e-9


def _key(t: float) -> float:
    return round(t, 9)


def exchange_findings(res: InputResult, lc: LssChannel) -> dict[int, list[Finding]]:
    """The L findings at each exchange of the channel (by its index), in finding order."""
    analysis = lss_stage.of(res.model)
    by_frame: dict[int, int] = {}
    by_request: dict[float, int] = {}
    for j, ex in enumerate(lc.exchanges):
        by_frame.setdefault(ex.request.idx, j)
        for r in ex.responses:
            by_frame.setdefault(r.idx, j)
        by_request.setdefault(_key(ex.request.ts), j)
    out: dict[int, list[Finding]] = {}
    for f in res.findings:
        if not f.rule.startswith("L") or f.channel != lc.channel:
            continue
        k: int | None = None
        if f.rule in ("L001", "L006") and analysis is not None:
            found = analysis.effects.get((lc.channel, f.rule, _key(f.time)))
            k = None if found is None else by_request.get(_key(found[0]))
        elif f.rule == "L002":
            k = next((j for j, ex in enumerate(lc.exchanges) if ex.cs == lss_stage.SELECTIVE_SERIAL
                      and not ex.responses and abs(ex.deadline(lc.timeout_s) - f.time) <= EPS),
                     None)
        elif f.frame_index is not None:
            k = by_frame.get(f.frame_index)
        if k is not None:
            out.setdefault(k, []).append(f)
    return out


def exchange_node(lc: LssChannel, ex: Exchange) -> int | None:
    """The slave's node-ID when known: a configure node-ID's (1-127), an inquire
    node-ID's answer, else the active node-ID of the slave its session selected."""
    if ex.node is not None:
        return ex.node
    if ex.cs == lss_stage.INQUIRE_NODE_ID and len(ex.responses) == 1:
        n = ex.responses[0].data[1]
        return n if 1 <= n <= 127 else None
    if ex.session is None:
        return None
    slave = lc.sessions[ex.session].slave
    active = None if slave is None else lc.slaves[slave].active_node_id
    return active if active is not None and 1 <= active <= 127 else None


def exchange_text(ex: Exchange) -> str:
    """`LSS configure node-ID 5 -> ok` (the answers when they say more than ok)."""
    answers = ", ".join(t for t in (ex.response_text(r)[1] for r in ex.responses) if t != "ok")
    return (f"LSS {ex.service}{ex.argument_text()} -> {ex.result}"
            + (f" ({answers})" if answers else ""))


def _end(ex: Exchange) -> float:
    """An exchange ends at its last answer (its request when none came)."""
    return ex.responses[-1].ts if ex.responses else ex.request.ts


def timeline_rows(res: InputResult, blank: dict[str, Any]) -> list[dict[str, Any]]:
    """`kind: lss` rows of `nmtcheck timeline --format csv|json`: one per exchange."""
    analysis = lss_stage.of(res.model)
    if analysis is None:
        return []
    rows = []
    for lc in analysis.channels.values():
        at = exchange_findings(res, lc)
        for k, ex in enumerate(lc.exchanges):
            found = at.get(k, [])
            rows.append({**blank, "channel": lc.channel, "node": exchange_node(lc, ex),
                         "start": round(ex.request.ts, 6), "end": round(_end(ex), 6),
                         "kind": "lss", "rule": ",".join(f.rule for f in found) or None,
                         "cob_id": "7E5h", "code": f"{ex.cs:02X}h",
                         "line": ex.request.line or None,
                         "text": "; ".join([exchange_text(ex)]
                                           + [f"{f.rule}: {f.message}" for f in found])})
    return rows


def marks_per_channel(results: list[InputResult]) -> int:
    channels = 0
    for res in results:
        analysis = lss_stage.of(res.model)
        channels += 0 if analysis is None else len(analysis.channels)
    return max(MAX_LSS_MARKS // max(channels, 1), MIN_LSS_MARKS_PER_CHANNEL)


def lss_lane(res: InputResult, channel: str, begin: float,
             group_of: dict[int, tuple[str, int]], limit: int, texts: dict[str, int]
             ) -> dict[str, Any] | None:
    """The HTML LSS row of a channel (times from `begin`): `exchanges` as `[start, end,
    failed, text, line, group, occurrence]` with the text (service, result, findings) an
    index into `texts` (added there when new: a flood of one request costs one text), the
    first `limit` of them (`omitted` the rest); `sessions` as `[start, end, title]`; None
    for a channel without LSS frames."""
    analysis = lss_stage.of(res.model)
    lc = analysis.channels.get(channel) if analysis is not None else None
    if lc is None:
        return None
    at = exchange_findings(res, lc)
    exchanges = []
    for k, ex in enumerate(lc.exchanges[:limit]):
        found = at.get(k, [])
        failed = [f for f in found if f.rule in FAILURES]
        first = (failed or found)[:1]
        group: tuple[str | None, int | None] = (
            group_of.get(id(first[0]), (None, None)) if first else (None, None))
        text = exchange_text(ex) + "".join(f"\n{f.rule} {f.name}: {f.message}" for f in found)
        exchanges.append([round(ex.request.ts - begin, 6), round(_end(ex) - begin, 6),
                          bool(failed), texts.setdefault(text, len(texts)),
                          ex.request.line or None, *group])
    sessions = []
    for se in lc.sessions:
        end = se.end if se.end is not None else lc.end
        who = ("every slave (switch state global)" if se.slave is None
               else f"slave {lss_stage.identity_text(tuple(lc.slaves[se.slave].identity))}")
        sessions.append([round(se.start - begin, 6), round(end - begin, 6),
                         f"LSS session ({se.how}): {who}, {len(se.exchanges)} requests"])
    return {"exchanges": exchanges, "sessions": sessions,
            "omitted": max(len(lc.exchanges) - limit, 0)}


def left_out(lane: object) -> int:
    """How many of a channel's LSS requests its row leaves out (0 without a row)."""
    return int(lane["omitted"]) if isinstance(lane, dict) else 0


def adoptions(res: InputResult, channel: str, node: int, begin: float,
              when: Callable[[float], str]) -> list[list[Any]]:
    """Where node `node` got its node-ID (SPEC §9.4.2): `[boot-up time, configure
    request time, title]` for each LSS configure node-ID the node adopted at a boot-up."""
    analysis = lss_stage.of(res.model)
    lc = analysis.channels.get(channel) if analysis is not None else None
    if lc is None:
        return []
    out = []
    for s in lc.slaves:
        for c in s.configured:
            if c.node_id != node or c.bootup is None:
                continue
            ex = lc.exchanges[c.exchange]
            who = (lss_stage.identity_text(tuple(s.identity)) if s.key is not None
                   else "a slave of partly known identity")
            out.append([round(c.bootup[0] - begin, 6), round(ex.request.ts - begin, 6),
                        f"node-ID {node} assigned by LSS: configure node-ID {node} at "
                        f"{when(ex.request.ts)} (line {ex.request.line}) to {who}, "
                        + ("stored" if c.stored else "not stored")
                        + f"; boot-up as node {node} at line {c.bootup[2]}"])
    return out
