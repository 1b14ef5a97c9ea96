"""What the reports show of the LSS reconstruction (SPEC §9.4.1 `lss[]`): per channel its
exchanges, the slaves with their identity and node-IDs, the LSS sessions and the
fastscans, made in one place for the JSON report, the text report and the Python API."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from nmtcheck.processes import lss as lss_stage
from nmtcheck.processes.lss import Exchange, Fastscan, LssChannel, Slave
from nmtcheck.results import InputResult
from nmtcheck.timeline.moments import at

MAX_EXCHANGES = 1000  # per channel in the JSON report, then `exchanges_omitted`
MAX_TEXT_SESSIONS = 20  # per channel in the text report
MAX_TIMELINE_EXCHANGES = 200  # per channel in `nmtcheck timeline`


def _r(x: float | None) -> float | None:
    return None if x is None else round(float(x), 6)


def _identity(parts: tuple[int | None, ...] | list[int | None]) -> dict[str, str | None] | None:
    if all(v is None for v in parts):
        return None
    return {name: None if v is None else f"0x{v:08X}"
            for name, v in zip(lss_stage.PARTS, parts, strict=True)}


def _exchange(ex: Exchange) -> dict[str, Any]:
    q = ex.request
    responses = []
    for r in ex.responses:
        status, text = ex.response_text(r)
        responses.append({"time": _r(r.ts), "frame_index": r.idx, "line": r.line or None,
                          "status": status, "text": text})
    return {"time": _r(q.ts), "frame_index": q.idx, "line": q.line or None,
            "cs": f"{ex.cs:02X}h", "service": ex.service_id, "argument": ex.argument,
            "cfg": ex.cfg, "dlc": q.dlc, "result": ex.result, "responses": responses}


def exchange_rows(res: InputResult) -> list[dict[str, Any]]:
    """One row per LSS request of every channel (the Python API's `Report.lss` and the
    fleet's `lss` table, SPEC §9.4.2): the fields of `lss[].exchanges[]` with the channel,
    the request's index among the channel's and its LSS session's (`lss_session`, None:
    in none; `session` is a fleet path field)."""
    analysis = lss_stage.of(res.model)
    if analysis is None:
        return []
    return [{"input": res.index, "channel": lc.channel, "exchange": k,
             "lss_session": ex.session, **_exchange(ex)}
            for lc in analysis.channels.values() for k, ex in enumerate(lc.exchanges)]


def _slave(lc: LssChannel, s: Slave) -> dict[str, Any]:
    last = s.configured[-1] if s.configured else None
    bootup = None
    if last is not None and last.bootup is not None:
        bootup = {"node": last.node_id, "time": _r(last.bootup[0]),
                  "line": last.bootup[2] or None}
    return {"identity": _identity(s.identity), "identity_source": s.identity_source,
            "unconfigured": s.unconfigured, "active_node_id": s.active_node_id,
            "pending_node_id": None if last is None else last.node_id,
            "stored": None if last is None else last.stored, "bootup": bootup,
            "network_node": s.network_node}


def _fastscan(fs: Fastscan) -> dict[str, Any]:
    last = fs.last or fs.start
    return {"start": _r(fs.start.ts), "end": _r(last.ts), "result": fs.result,
            "requests": fs.requests, "ended_by": fs.ended_by,
            "identity": _identity(fs.identity)}


def channel_rows(res: InputResult) -> list[dict[str, Any]]:
    """`lss[]`: one row per channel of the input with LSS frames."""
    analysis = lss_stage.of(res.model)
    if analysis is None:
        return []
    out = []
    for lc in analysis.channels.values():
        row: dict[str, Any] = {
            "input": res.index, "channel": lc.channel, "requests": len(lc.exchanges),
            "unsolicited": lc.unsolicited,
            "exchanges": [_exchange(ex) for ex in lc.exchanges[:MAX_EXCHANGES]],
            "slaves": [_slave(lc, s) for s in lc.slaves],
            "sessions": [{"start": _r(se.start), "end": _r(se.end), "cfg": se.cfg,
                          "how": se.how,
                          "identity": None if se.slave is None
                          else _identity(lc.slaves[se.slave].identity),
                          "slave": se.slave, "exchanges": se.exchanges}
                         for se in lc.sessions],
            "fastscans": [_fastscan(fs) for fs in lc.fastscans]}
        if len(lc.exchanges) > MAX_EXCHANGES:
            row["exchanges_omitted"] = len(lc.exchanges) - MAX_EXCHANGES
        if lc.left_out:  # past lss.MAX_REQUESTS: counted, never silently dropped
            row["frames_not_reconstructed"] = lc.left_out
            row["not_reconstructed_from_line"] = lc.left_out_line
        out.append(row)
    return out


def slave_text(s: Slave) -> str:
    """One slave as the text report and the timeline name it."""
    who = (lss_stage.identity_text(tuple(s.identity)) if s.key is not None
           else "slave " + "/".join(lss_stage.hex32(v) for v in s.identity if v is not None)
           if any(v is not None for v in s.identity) else "a slave of unknown identity")
    parts = [who]
    if s.unconfigured:
        parts.append("non-configured")
    elif s.active_node_id is not None and s.active_node_id != 0xFF:
        parts.append(f"node-ID {s.active_node_id}")
    if s.network_node is not None:
        parts.append(f"network node {s.network_node}")
    for c in s.configured:
        adopted = (f", booted as node {c.node_id} at line {c.bootup[2]}" if c.bootup
                   else f", pending node-ID {c.node_id}")
        parts.append(f"configured node-ID {c.node_id}"
                     + (", stored" if c.stored else ", not stored") + adopted)
    return "; ".join(parts)


def text_lines(res: InputResult) -> list[str]:
    """The LSS section of the text report: per channel its sessions (who was selected,
    what was asked, what each slave answered), its fastscans and its slaves."""
    analysis = lss_stage.of(res.model)
    if analysis is None or not analysis.channels:
        return []
    order_only = res.model.timeline.order_only
    out = ["  LSS (CiA 305):"]
    for lc in analysis.channels.values():
        start = next((cm.start for cm in res.model.channels if cm.name == lc.channel),
                     res.model.start)

        def when(t: float, start: float = start) -> str:
            return at(t, start, order_only)

        out.append(f"    {lc.channel}: {len(lc.exchanges)} requests, {len(lc.sessions)} "
                   f"sessions, {len(lc.fastscans)} fastscans, {lc.unsolicited} unsolicited "
                   "responses")
        if lc.left_out:
            out.append(f"      {lc.left_out} LSS frames from line {lc.left_out_line} not "
                       f"reconstructed (more than {lss_stage.MAX_REQUESTS} requests)")
        for k, se in enumerate(lc.sessions[:MAX_TEXT_SESSIONS]):
            who = ("every slave (switch state global)" if se.slave is None and se.how == "global"
                   else slave_text(lc.slaves[se.slave]) if se.slave is not None else "?")
            out.append(f"      session {k + 1} at {when(se.start)} ({se.how}): {who}")
            for i in se.exchanges:
                ex = lc.exchanges[i]
                answers = ", ".join(ex.response_text(r)[1] for r in ex.responses)
                out.append(f"        line {ex.request.line}: {ex.service}"
                           f"{ex.argument_text()} -> {ex.result}"
                           + (f" ({answers})" if answers else ""))
        if len(lc.sessions) > MAX_TEXT_SESSIONS:
            out.append(f"      … {len(lc.sessions) - MAX_TEXT_SESSIONS} more sessions "
                       "(see --format json)")
        for fs in lc.fastscans:
            found = (lss_stage.identity_text(fs.identity) if fs.complete else fs.result)
            out.append(f"      fastscan at {when(fs.start.ts)}: {found} ({fs.requests} "
                       "requests)")
        out.extend(f"      slave: {slave_text(s)}" for s in lc.slaves)
    return out


def html_rows(results: list[InputResult], report: dict[str, Any]) -> dict[str, Any]:
    """The HTML report's LSS table (SPEC §9.4.2, `templates/lss.html.j2`): the JSON rows
    with the input's path and the moment times count from (the input's first frame)."""
    paths = {res.index: res.stats.path for res in results}
    starts = {k: entry["start"] for k, entry in enumerate(report["inputs"])}
    return {"lss_rows": [{**row, "path": paths.get(row["input"]),
                          "start": starts.get(row["input"], 0.0)} for row in report["lss"]]}


def timeline_lines(res: InputResult, at: Callable[[float], str]) -> list[str]:
    """`nmtcheck timeline` (text): each channel's LSS exchanges and fastscans as channel
    events in time order (SPEC §9.4.2), `at` giving a moment as the timeline's column."""
    analysis = lss_stage.of(res.model)
    if analysis is None:
        return []
    out: list[str] = []
    for lc in analysis.channels.values():
        out.append(f"{lc.channel} LSS (CiA 305):")
        timed: list[tuple[float, str]] = []
        for ex in lc.exchanges[:MAX_TIMELINE_EXCHANGES]:
            answers = ", ".join(t for t in (ex.response_text(r)[1] for r in ex.responses)
                                if t != "ok")
            timed.append((ex.request.ts, f"  {at(ex.request.ts)}     LSS {ex.service}"
                          f"{ex.argument_text()} -> {ex.result}"
                          + (f" ({answers})" if answers else "")
                          + f" (line {ex.request.line})"))
        for fs in lc.fastscans:
            last = fs.last or fs.start
            found = (f"found {lss_stage.identity_text(fs.identity)}" if fs.complete
                     else fs.result)
            timed.append((last.ts, f"  {at(fs.start.ts)} .. {at(last.ts)}  fastscan: {found} "
                          f"({fs.requests} requests)"))
        out += [text for _t, text in sorted(timed, key=lambda x: x[0])]
        if len(lc.exchanges) > MAX_TIMELINE_EXCHANGES:
            out.append(f"  … {len(lc.exchanges) - MAX_TIMELINE_EXCHANGES} more LSS requests "
                       "(see check --format json)")
    return out
