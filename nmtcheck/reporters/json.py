"""The JSON report of SPEC §7 (plus a few extra input counters)."""

from __future__ import annotations

import json
import math
from collections.abc import Iterator
from typing import Any

from nmtcheck import __version__
from nmtcheck.protocol.nmt import SOURCES, STATES
from nmtcheck.reporters import boot_report, comm_report, lss_report
from nmtcheck.reporters.common import (
    captures,
    configured_vs_measured,
    duration,
    fail_on,
    latest,
    network_notes,
    order_only,
    utc_start,
    verdict,
)
from nmtcheck.results import InputResult, summary
from nmtcheck.safe_text import dumps_finite
from nmtcheck.timeline.model import NodeModel

REPORT_VERSION = 2  # 2: SPEC §9.4.1 (sync, pdo_streams, emcy, reactions, cob_id)


def _r(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else round(float(x), 6)


def _num(x: float) -> str:
    """A JSON number of `x` as `json.dumps` writes it, `null` where it is not finite."""
    return repr(round(x, 6)) if math.isfinite(x) else "null"


def _period_ms(m: NodeModel, end: float) -> float | None:
    period, _source = m.reported_period(end)
    return _r(period * 1000.0) if period else None


def _configured_vs_measured(m: NodeModel, end: float) -> dict[str, Any]:
    c = configured_vs_measured(m, end)
    return {"configured": {"heartbeat_ms": c.producer_ms, "consumer_timeout_ms": c.consumer_ms,
                           "consumer_node": c.consumer_node, "guard_time_ms": c.guard_time_ms,
                           "life_time_factor": c.life_time_factor},
            "measured": {"heartbeat_median_ms": c.median_ms, "heartbeat_jitter_ms": c.jitter_ms,
                         "worst_heartbeat_gap_ms": c.worst_gap_ms}}


def report_dict(results: list[InputResult], options: dict[str, object] | None = None
                ) -> dict[str, Any]:
    """The whole report as one dict (the HTML report and the Python API read it)."""
    return {key: list(value) if isinstance(value, Iterator) else value
            for key, value in report_sections(results, options).items()}


def report_sections(results: list[InputResult], options: dict[str, object] | None = None
                    ) -> dict[str, Any]:
    """The report's top-level entries; the long lists (inputs, nodes, channels, timeline,
    events, findings) as generators, so that they are written entry by entry, not held: a
    node with a million state intervals, or 200,000 channels (their node and channel
    entries took about 230 MB)."""
    return {"tool": {"name": "nmtcheck", "version": __version__},
            "report_version": REPORT_VERSION, "inputs": _inputs(results),
            "nodes": _nodes(results), "timeline": _timeline(results),
            "findings": _findings(results), "events": _events(results),
            "channels": _channels(results),
            "pdo_streams": [st for res in results for st in comm_report.pdo_streams(res)],
            "lss": [row for res in results for row in lss_report.channel_rows(res)],
            "network": {"notes": list(network_notes(options))},
            "config": _config(options),
            "omitted": [{"input": res.index, "rule": o.rule, "name": o.name,
                         "severity": o.severity, "count": o.count}
                        for res in results for o in res.omitted],
            "not_logs": list(_not_logs(options)),
            "summary": {**summary(results),
                        "verdict": verdict(results, fail_on(options or {})),
                        # inputs checked in order only: a pass there did not check timing
                        "order_only": order_only(results)}}


def _channels(results: list[InputResult]) -> Iterator[dict[str, Any]]:
    for res in results:
        for cm in res.model.channels:
            master = cm.master
            yield {"input": res.index, "name": cm.name, "master": None if master is None
                   else {"node": master.node, "source": master.source,
                         "detail": master.detail},
                   "master_note": None if master is not None else cm.master_note,
                   "boot": boot_report.channel_boot(res, cm.name),
                   "sync": comm_report.channel_sync(res, cm.name)}


def _inputs(results: list[InputResult]) -> Iterator[dict[str, Any]]:
    for res in results:
        s = res.stats
        end = latest(res)
        yield {
            "path": s.path, "format": s.format, "frames": s.frames, "skipped": s.skipped,
            "extended": s.extended, "error_frames": s.error_frames,
            "start": _r(s.start if s.start is not None else 0.0),
            # the latest time (with several captures, the latest of theirs: never < start)
            "end": _r(end if end is not None else 0.0),
            "remote_frames": s.remote_frames, "fd_frames": s.fd_frames, "ignored": s.ignored,
            "dropped": s.dropped, "backwards": s.backwards_timestamps,
            "backwards_timestamps": s.backwards_timestamps, "truncated": s.truncated,
            "skipped_lines": s.skipped_lines, "channels": s.channels,
            # where time starts again: a later capture in the input (nmtcheck/readers/captures.py)
            "restarts": [{"frame_index": i, "line": line or None, "time": _r(t)}
                         for i, line, t in s.restarts],
            # where the logger's clock stepped back: later frames are timed `seconds` later
            "clock_steps": [{"frame_index": i, "line": line or None, "seconds": _r(step)}
                            for i, line, step in s.clock_steps],
            # seconds recorded (the sum of the captures' spans; null: no timestamps)
            "duration": None if s.order_only else _r(duration(res)),
            "captures": [{"start": _r(c.start), "end": _r(c.end), "frames": c.frames,
                          "line": c.line or None} for c in captures(res)],
            "error": res.error, "start_utc": utc_start(res),
            "timestamp_resolution_us": comm_report.resolution_us(res),
            "not_evaluated": [{"rule": code, "reason": why}
                              for code, why in res.not_evaluated.items()]
            + [{"rule": code, "reason": why, "partial": True}
               for code, why in res.partly_evaluated.items()],
        }


def _nodes(results: list[InputResult]) -> Iterator[dict[str, Any]]:
    for res in results:
        yield from ({
            "input": res.index, "channel": m.channel, "node": m.node,
            "first_seen": _r(m.first_show_ts), "last_seen": _r(m.last_seen),
            "final_state": m.intervals[-1].state if m.intervals else "UNKNOWN",
            "bootups": m.bootup_count, "error_control": m.error_control,
            "heartbeat_period_ms": _period_ms(m, res.model.end_of(m.channel)),
            **_configured_vs_measured(m, res.model.end_of(m.channel)),
            "boot": boot_report.node_boot(res, m.channel, m.node),
            "emcy": comm_report.node_emcy(res, m.channel, m.node),
        } for m in res.nodes())


def _findings(results: list[InputResult]) -> Iterator[dict[str, Any]]:
    for res in results:
        yield from ({"input": f.input, "rule": f.rule, "name": f.name,
                     "severity": f.severity, "channel": f.channel, "node": f.node,
                     "time": _r(f.time), "frame_index": f.frame_index,
                     "line": f.line or None, "message": f.message, "basis": f.basis,
                     "cob_id": comm_report.finding_cob_id(res, f),
                     **boot_report.finding_fields(f)}
                    for f in res.findings)


def _timeline(results: list[InputResult]) -> Iterator[dict[str, Any]]:
    for res in results:
        for m in res.nodes():
            for iv in m.intervals:
                row = {"input": res.index, "channel": m.channel, "node": m.node,
                       "state": iv.state, "start": _r(iv.start), "end": _r(iv.end),
                       "source": iv.source}
                causes = res.interval_causes.get((m.channel, m.node, round(iv.start, 9)))
                if causes is not None:  # SPEC §9.3.6: a change no command explains
                    row["causes"] = causes
                yield row


def _timeline_lines(results: list[InputResult]) -> Iterator[str]:
    """`json.dumps` of each `_timeline` entry, made from the interval columns without
    a dict per interval (the same text: keys in order, floats as `repr`)."""
    for res in results:
        for m in res.nodes():
            ivs = m.intervals
            head = json.dumps({"input": res.index, "channel": m.channel, "node": m.node})[:-1]
            for a, b, st, so in zip(ivs.start.tolist(), ivs.end.tolist(), ivs.state.tolist(),
                                    ivs.source.tolist(), strict=True):
                causes = res.interval_causes.get((m.channel, m.node, round(a, 9)))
                tail = "" if causes is None else f', "causes": {json.dumps(causes)}'
                yield (f'{head}, "state": "{STATES[st]}", "start": {_num(a)}, '
                       f'"end": {_num(b)}, "source": "{SOURCES[so]}"{tail}}}')


def _events(results: list[InputResult]) -> Iterator[dict[str, Any]]:
    for res in results:  # by input, then in file order
        for m, e in res.model.events():
            row = {"input": res.index, "channel": m.channel, "node": m.node,
                   "kind": e.kind, "time": _r(e.ts), "frame_index": e.idx,
                   "line": e.line or None, "code": e.code, "message": e.text}
            if e.kind == "emcy":  # SPEC §9.3.6: its chain, and CANopenNode's detail
                row["causes"] = res.event_causes.get((m.channel, m.node, e.idx), [])
                row["canopennode"] = comm_report.emcy_detail(res, m.channel, m.node, e.idx)
            yield row


def _not_logs(options: dict[str, object] | None) -> list[str]:
    """Files below a directory argument whose content is no log format (skipped)."""
    skipped = (options or {}).get("not_logs") or []
    assert isinstance(skipped, list)
    return [str(p) for p in skipped]


def _config(options: dict[str, object] | None) -> dict[str, Any]:
    """Which configuration file was used (null: none) and the rule profile in force
    (null when the caller did not say: a library call without the CLI's options)."""
    cfg = (options or {}).get("config")
    if not isinstance(cfg, dict):
        return {"file": None, "profile": None, "overrides": []}
    return {"file": cfg.get("file"), "profile": cfg.get("profile"),
            "overrides": list(cfg.get("overrides") or [])}


PIECE_CHARS = 1 << 16  # what `stream` joins into one piece


def stream(results: list[InputResult], options: dict[str, object]) -> Iterator[str]:
    """The report in pieces of about `PIECE_CHARS` characters, one list entry per line:
    `json.dumps` with an indent runs in pure Python (40 s for 200 k findings and
    intervals); entry by entry it runs in C. Entries are joined before they are written:
    a write per entry costs more than the entry (40,000 nodes, 80,000 intervals)."""
    held: list[str] = []
    size = 0
    for piece in _entries(results, options):
        held.append(piece)
        size += len(piece)
        if size >= PIECE_CHARS:
            yield "".join(held)
            held, size = [], 0
    if held:
        yield "".join(held)


def _entries(results: list[InputResult], options: dict[str, object]) -> Iterator[str]:
    """The report's text entry by entry (see `stream`)."""
    yield "{\n"
    first = True
    for key, value in report_sections(results, options).items():
        if not first:
            yield ",\n"
        first = False
        if key == "timeline":
            value = _timeline_lines(results)
        elif isinstance(value, Iterator) or (
                isinstance(value, list) and value and all(isinstance(v, dict) for v in value)):
            value = (dumps_finite(v) for v in value)
        else:
            yield f"  {json.dumps(key)}: " + dumps_finite(value, indent=2).replace("\n", "\n  ")
            continue
        yield f"  {json.dumps(key)}: ["
        empty = True
        for entry in value:
            yield ("\n    " if empty else ",\n    ") + entry
            empty = False
        yield "]" if empty else "\n  ]"
    yield "\n}\n"


def render(results: list[InputResult], options: dict[str, object]) -> str:
    return "".join(stream(results, options))
