"""A self-contained HTML report for people who never run the tool.

One file with inline CSS, JavaScript and SVG (a Content-Security-Policy forbids
any network access, so it opens the same on an offline field laptop). It
carries the state intervals and findings, never frames, so it stays small for
huge logs: repeated findings of one rule on one node are one table row with a
count, and at most `MAX_OCCURRENCES` of them become timeline markers.
Rendered from the Jinja2 template `templates/report.html.j2` (package data).
"""

from __future__ import annotations

import html
import re
from datetime import datetime, timezone
from functools import cache
from importlib import resources
from typing import Any

import jinja2
import numpy as np
from markupsafe import Markup

from nmtcheck import __version__
from nmtcheck.processes.boot_records import LETTERS
from nmtcheck.protocol.nmt import HEARTBEAT, STATES
from nmtcheck.protocol.nmt import SOURCES as TIMELINE_SOURCES
from nmtcheck.reporters import boot_report, comm_lanes, comm_report, lss_lane, lss_report
from nmtcheck.reporters.common import (
    SEVERITY_ORDER,
    FindingGroup,
    captures_note,
    checked_rules,
    config_line,
    duration,
    error_line,
    fail_on,
    group_findings,
    heartbeat_stats,
    is_failing,
    master_line,
    measured_mark,
    moment,
    network_notes,
    node_label,
    nodes_by_channel,
    not_logs_line,
    offset,
    omitted_lines,
    reboots,
    resets,
    unreadable,
    verdict_class,
    verdict_word,
    where_label,
)
from nmtcheck.reporters.json import report_sections
from nmtcheck.results import Finding, InputResult
from nmtcheck.safe_text import dumps_finite
from nmtcheck.timeline.gaps import Gaps
from nmtcheck.timeline.model import NodeModel

# Colours of the NMT states on the timeline and in the legend (colour-blind safe-ish:
# the fault states are the dark/saturated ones, and wide intervals carry their name).
STATE_COLORS = {
    "UNKNOWN": "#d9d9d9",
    "INITIALISING": "#f1c232",
    "PRE-OPERATIONAL": "#6fa8dc",
    "OPERATIONAL": "#6aa84f",
    "STOPPED": "#8e7cc3",
    "OFFLINE": "#cc4125",
}
SEVERITY_COLORS = {"error": "#b3261e", "warning": "#e69138", "info": "#3d85c6"}
# EMCY markers by code class (SPEC §9.4.2): 81xxh/82xxh communication, error resets, others
EMCY_COLORS = {"communication": "#d9480f", "reset": "#2b8a3e", "other": "#7048e8"}
SOURCES = ("start", "bootup", "heartbeat", "guarding", "command", "timeout", "self-start")
_SOURCE_OF = [SOURCES.index(s) for s in TIMELINE_SOURCES]  # timeline's index -> the page's
# A browser cannot draw millions of intervals; a page holds at most this many, shared
# among the nodes (each gets at least MIN_DRAWN_PER_NODE): a node that changes state on
# every heartbeat gets its first ones drawn and the timeline says how many are not.
MAX_DRAWN_INTERVALS = 200_000
MIN_DRAWN_PER_NODE = 1000


def drawn_per_node(nodes: int) -> int:
    return max(MAX_DRAWN_INTERVALS // max(nodes, 1), MIN_DRAWN_PER_NODE)
MAX_OCCURRENCES = 200  # per finding group: markers and listed messages; the count says the rest
HISTOGRAM_BINS = 24
TEMPLATE = "report.html.j2"


@cache
def _environment() -> jinja2.Environment:
    return jinja2.Environment(loader=jinja2.PackageLoader("nmtcheck.reporters", "templates"),
                              autoescape=True, trim_blocks=True, lstrip_blocks=True,
                              undefined=jinja2.StrictUndefined)


def _asset(name: str) -> str:
    return (resources.files("nmtcheck.reporters") / "templates" / name).read_text("utf-8")


def script_json(data: object) -> Markup:
    """JSON safe inside <script>: no `</script>`, `<!--` or `&` can end or confuse it."""
    text = dumps_finite(data, separators=(",", ":"), ensure_ascii=False)
    return Markup(text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026"))


_INLINE = [(re.compile(r"\*\*(.+?)\*\*"), r"<strong>\1</strong>"),
           (re.compile(r"`([^`]+)`"), r"<code>\1</code>")]


def doc_html(doc: str) -> Markup:
    """The rule docs' small Markdown subset (paragraphs, `- ` lists, **bold**, `code`)."""
    parts = []
    for block in re.split(r"\n\s*\n", doc.strip()):
        lines = block.splitlines()
        if all(line.lstrip().startswith("- ") for line in lines):
            items = [_inline(line.lstrip()[2:]) for line in lines]
            parts.append("<ul>" + "".join(f"<li>{i}</li>" for i in items) + "</ul>")
        else:
            parts.append(f"<p>{_inline(' '.join(line.strip() for line in lines))}</p>")
    return Markup("\n".join(parts))


def _inline(text: str) -> str:
    text = html.escape(text, quote=False)
    for pattern, repl in _INLINE:
        text = pattern.sub(repl, text)
    return text


def _r(x: float) -> float:
    return round(float(x), 6)


def timeline_id(res: InputResult, channel: str) -> str:
    """An HTML id safe for any channel name (MCAP topics have slashes): numbers only."""
    channels = res.stats.channels
    return f"tl-{res.index}-{channels.index(channel) if channel in channels else channel}"


def _group_view(res: InputResult, g: FindingGroup, gid: str) -> dict[str, Any]:
    shown = g.findings[:MAX_OCCURRENCES]
    f = g.first
    return {
        "id": gid, "input": g.input, "path": res.stats.path, "rule": g.rule, "name": g.name,
        "severity": g.severity, "severity_rank": SEVERITY_ORDER.index(g.severity),
        "channel": g.channel, "node": g.node,
        "where": "input" if g.channel is None else node_label(g.node),
        "place": where_label(g.channel, g.node),
        "node_key": (f"{g.input}/input" if g.channel is None
                     else f"{g.input}/{g.channel}/{'' if g.node is None else g.node}"),
        "sort_node": ("" if g.channel is None else f"{g.channel}/"
                      + ("zzz" if g.node is None else f"{g.node:03d}")),
        "count": g.count, "time": _r(offset(res, f.time)), "line": f.line or None,
        "when": moment(res, f.time, unit="", f=f),  # `frame N` in a log without timestamps
        # I-rule findings belong to no channel: no timeline to jump to
        "message": f.message,
        # a limit measured from the trace, not configured: said beside the message
        "measured": measured_mark(f).strip(" []"),
        "timeline": None if g.channel is None else timeline_id(res, g.channel),
        "occurrences": [{"time": _r(offset(res, o.time)), "when": moment(res, o.time, f=o),
                         "line": o.line or None,
                         "message": o.message, **_causes_view(res, o)} for o in shown],
        "hidden": g.count - len(shown),
    }


def _comm_views(results: list[InputResult], report: dict[str, Any]) -> dict[str, Any]:
    """SPEC §9.4.2: each channel's SYNC, each PDO stream and each node's EMCYs as table
    rows (times in seconds from the first frame)."""
    paths = {res.index: res.stats.path for res in results}
    sync = [{"input": c["input"], "path": paths.get(c["input"]), "channel": c["name"],
             **c["sync"]} for c in report["channels"] if c.get("sync")]
    intervals = {res.index: comm_report.pdo_stream_intervals(res) for res in results}
    seen: dict[int, int] = {}  # streams of each input so far: `pdo_streams` is in their order
    pdo = []
    for st in report["pdo_streams"]:
        k = seen[st["input"]] = seen.get(st["input"], -1) + 1
        iv = intervals.get(st["input"], [])
        pdo.append({**st, "path": paths.get(st["input"]), "intervals": len(iv[k]) if k < len(iv)
                    else 0, "histogram": _histogram(Gaps(iv[k])) if k < len(iv) else None})
    emcy = [{"input": n["input"], "path": paths.get(n["input"]), "channel": n["channel"],
             "node": n["node"], **n["emcy"]} for n in report["nodes"] if n.get("emcy")]
    return {"sync_rows": sync, "pdo_rows": pdo, "emcy_rows": emcy}


def _causes_view(res: InputResult, f: Finding) -> dict[str, Any]:
    """SPEC §8.6, §9.3: the events that may explain a finding and those that came after its
    effect began (folded), times from the first frame; no keys at all for a finding of a
    rule that has no causes."""
    if f.causes is None:
        return {}

    def view(c: dict[str, Any]) -> dict[str, Any]:
        return {"kind": c["kind"], "time": _r(offset(res, c["time"])),
                "end": None if c.get("end") is None else _r(offset(res, c["end"])),
                "line": c.get("line") or None, "node": c.get("node"),
                "count": c.get("count"), "code": c.get("code"), "text": c["text"],
                "role": c.get("role"), "link": c.get("link"), "depth": c.get("depth") or 1}

    causes = [view(c) for c in f.causes]
    return {"causes": causes, "cause_tree": cause_tree(causes),
            "causes_omitted": f.causes_omitted or 0,
            "reactions": [view(c) for c in f.reactions or ()],
            "reactions_omitted": f.reactions_omitted or 0}


def cause_tree(causes: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """A chain's entries (pre-order, each with its depth) as a tree for the nested list of
    SPEC §9.3.6: each entry with its `children`."""
    roots: list[dict[str, Any]] = []
    path: list[dict[str, Any]] = []  # the open entries, one per depth
    for c in causes:
        node = {**c, "children": []}
        depth = max(1, min(int(c.get("depth") or 1), len(path) + 1))
        del path[depth - 1:]
        (path[-1]["children"] if path else roots).append(node)
        path.append(node)
    return roots


def _sub_index(step: dict[str, Any]) -> str:
    if step.get("index") is None:
        return ""
    sub = step.get("sub")
    index = str(step["index"]).removesuffix("h")
    return index if sub is None else f"{index}:{int(sub):02X}"


def _step_view(res: InputResult, step: dict[str, Any]) -> dict[str, Any]:
    """One row of a node's steps (SPEC §8.5.3): time, step, index:sub, value / expected,
    result, line; a summary of many configuration steps says how many and how many failed."""
    if "count" in step:
        end = step.get("end_time")
        return {"time": _r(offset(res, step["time"])), "step": step["step"], "object": "",
                "value": f"{step['count']} downloads, {step.get('failed', 0)} failed",
                "expected": None, "result": "",
                "line": None, "end": None if end is None else _r(offset(res, end))}
    result = step.get("result") or ""
    if step.get("abort_code") and result not in ("ok", ""):
        result = f"{result} ({step['abort_code']})"
    return {"time": _r(offset(res, step["time"])), "step": step["step"],
            "object": _sub_index(step), "value": step.get("value"),
            "expected": step.get("expected"), "expected_source": step.get("expected_source"),
            "result": result, "line": step.get("line") or None,
            "end": None}


def _boot_row(res: InputResult, entry: dict[str, Any]) -> dict[str, Any]:
    """A node's row in its channel's boot table, from the JSON report's `nodes[].boot`."""
    boot = entry["boot"]
    x = boot.get("process")
    rep = res.boot.nodes.get((entry["channel"], entry["node"])) if res.boot else None
    letter = boot.get("letter")
    when: float | None = None
    line = None
    if boot["status"] == "incomplete":
        when = res.model.end_of(entry["channel"])
    elif x is not None:
        evidence = x.get("evidence") or {}
        when = evidence.get("time", x.get("end"))
        line = evidence.get("line") or None
    failed = (boot_report.failure_finding(rep, res.findings)
              if rep is not None and boot["status"] == "failed" else None)
    if failed is not None:  # when its finding says it failed, as the text table shows it
        when, line = failed.time, failed.line or None
    return {
        "node": entry["node"], "status": boot["status"], "letter": letter,
        "letter_text": LETTERS.get(letter or "", boot.get("reason") or ""),
        "letter_source": boot.get("letter_source"),
        "time": None if when is None else _r(offset(res, when)), "line": line,
        "attempts": None if x is None else x.get("attempts"), "processes": boot["processes"],
        "anchor": None if x is None else x.get("anchor"),
        "detail": "" if rep is None else boot_report._detail(rep, res.findings),
        "mandatory": bool((boot.get("assignment") or {}).get("mandatory")),
        "steps": [] if x is None else [_step_view(res, s) for s in x.get("steps", ())],
    }


def _boot_views(res: InputResult, nodes: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One "Boot (CiA 302-2)" table per channel of an input where the boot group ran (SPEC
    §8.5.3), with its manager line; nothing when it ran on no channel."""
    b = res.boot
    if b is None or not any(cb.ran for cb in b.channels.values()):
        return []
    return [{"input": res.index, "path": res.stats.path, "channel": name,
             "heading": cb.heading(),
             "rows": [_boot_row(res, n) for n in nodes if n["input"] == res.index
                      and n["channel"] == name and n.get("boot") is not None]
             if cb.ran else []}
            for name, cb in b.channels.items()]


def _histogram(intervals: Gaps) -> dict[str, Any] | None:
    """Bin heartbeat intervals for a small inline SVG bar chart (ms on the x axis).

    Gaps longer than twice the median (a lost heartbeat) would squash every normal
    interval into one bar: they are counted in a separate overflow bar instead.
    """
    if not intervals.count:
        return None
    values = intervals.values
    counts = (np.ones(len(values), np.int64) if intervals.counts is None
              else intervals.counts)
    lo = intervals.minimum()
    limit = 2 * intervals.median()
    hi = min(intervals.maximum(), limit)
    sel = values <= hi
    normal, weight = values[sel], counts[sel]
    overflow = intervals.count - int(weight.sum())
    span = hi - lo
    nbins = HISTOGRAM_BINS if span > 1e-9 else 1
    where = (np.zeros(len(normal), np.int64) if span <= 1e-9
             else np.minimum(((normal - lo) / span * nbins).astype(np.int64), nbins - 1))
    bins = np.bincount(where, weights=weight, minlength=nbins).astype(np.int64).tolist()
    peak = max(*bins, overflow)
    return {"lo_ms": lo * 1000, "hi_ms": hi * 1000, "bins": bins, "peak": peak,
            "heights": [b / peak for b in bins], "overflow": overflow,
            "overflow_height": overflow / peak, "max_ms": intervals.maximum() * 1000}


def _timeline_begins(res: InputResult, start: float) -> dict[str, float]:
    """Where each channel's timeline begins in an input of several captures (each at its
    capture's first frame: nmtcheck/readers/captures.py); empty for one capture, whose
    timelines all begin at the input's first frame, `start`."""
    if not res.stats.restarts:
        return {}
    return {cm.name: _r(cm.start) if cm.first_index else start for cm in res.model.channels}


def _node_view(entry: dict[str, Any], m: NodeModel, end: float) -> dict[str, Any]:
    """The JSON report's node entry plus what a person wants to see of its heartbeats
    (`end`: the trace's, where the period in force is reported)."""
    hb = heartbeat_stats(m)

    def ms(seconds: float | None) -> float | None:
        return None if seconds is None else seconds * 1000

    return {
        **entry, "period_ms": entry["heartbeat_period_ms"],
        "period_source": m.reported_period(end)[1],
        "heartbeats": m.ec.count(HEARTBEAT), "intervals": hb.count, "min_ms": ms(hb.minimum),
        "median_ms": ms(hb.median), "max_ms": ms(hb.maximum), "jitter_ms": ms(hb.jitter),
        "resets": resets(m), "histogram": _histogram(hb.intervals),
        "reboots": sum(r.count for r in reboots(m)),  # boot-ups without a state change
    }


def report_context(results: list[InputResult], options: dict[str, object]) -> dict[str, Any]:
    """Everything the template shows; the timeline part also goes to the page as JSON.

    Inputs, nodes and state intervals come from the JSON report (`report_dict`), so the
    page and `--format json` can never disagree.
    """
    threshold = fail_on(options)
    report = report_sections(results, options)
    for section in ("inputs", "nodes", "channels", "findings"):  # read more than once here
        report[section] = list(report[section])
    inputs = [{**entry, "index": i, "duration": duration(res), "findings": len(res.findings),
               "order_only": res.stats.order_only, "captures_note": captures_note(res)}
              for i, (entry, res) in enumerate(zip(report["inputs"], results, strict=True))]
    intervals: dict[tuple[int, str, int], list[list[float | int]]] = {}
    boots: dict[tuple[int, str, int], list[float]] = {}  # boot-ups inside a state
    left_out: dict[tuple[int, str], int] = {}  # intervals not drawn, by input and channel
    per_node = drawn_per_node(sum(len(res.nodes()) for res in results))
    for res in results:
        begins = _timeline_begins(res, inputs[res.index]["start"])
        for m in res.nodes():
            begin = begins.get(m.channel, inputs[res.index]["start"])
            ivs = m.intervals
            shown = min(len(ivs), per_node)
            if shown < len(ivs):
                key = (res.index, m.channel)
                left_out[key] = left_out.get(key, 0) + len(ivs) - shown
            drawn = intervals[(res.index, m.channel, m.node)] = [
                [_r(round(a, 6) - begin), _r(round(b, 6) - begin), st, _SOURCE_OF[so]]
                for a, b, st, so in zip(ivs.start[:shown].tolist(), ivs.end[:shown].tolist(),
                                        ivs.state[:shown].tolist(), ivs.source[:shown].tolist(),
                                        strict=True)]
            # a node that keeps booting without a state change: its interval is drawn
            # apart (a 5th entry: how many boot-ups) and each boot-up gets a marker
            for r in reboots(m):
                if r.interval < shown:
                    drawn[r.interval].append(r.count)
                    boots.setdefault((res.index, m.channel, m.node), []).extend(
                        _r(round(t, 6) - begin) for t in r.ts[:MAX_OCCURRENCES].tolist())
    models = {(res.index, m.channel, m.node): (m, res.model.end_of(m.channel))
              for res in results for m in res.nodes()}
    nodes = [_node_view(entry, *models[(entry["input"], entry["channel"], entry["node"])])
             for entry in report["nodes"]]
    groups: list[dict[str, Any]] = []
    timelines = []
    emcy_per_node = comm_lanes.emcy_marks_per_node(results)
    sync_ticks = comm_lanes.sync_ticks_per_channel(results)
    lss_marks = lss_lane.marks_per_channel(results)
    emcy_texts: dict[str, int] = {}  # each distinct EMCY text once on the page
    lss_texts: dict[str, int] = {}  # and each distinct LSS exchange text
    for res in results:
        found = group_findings(res.findings)
        res_groups = [_group_view(res, g, f"g{len(groups) + i}") for i, g in enumerate(found)]
        group_of = {id(f): (view["id"], k) for g, view in zip(found, res_groups, strict=True)
                    for k, f in enumerate(g.findings[:MAX_OCCURRENCES])}
        groups += res_groups
        begins = _timeline_begins(res, inputs[res.index]["start"])
        gaps = comm_lanes.finding_gaps(res)
        for channel, channel_nodes in nodes_by_channel(res).items():
            rows = []
            # a later capture's timeline counts from its own first frame
            begin = begins.get(channel, inputs[res.index]["start"])
            shift = begin - inputs[res.index]["start"]

            def when(t: float, begin: float = begin, order_only: bool = res.stats.order_only
                     ) -> str:
                return f"frame {int(t) + 1}" if order_only else f"{t - begin:.6f} s"
            emcy_left_out = 0
            for node in channel_nodes:
                mine = [g for g in res_groups if g["channel"] == channel and g["node"] == node]
                marks = [[_r(o["time"] - shift), g["id"], k] for g in mine
                         for k, o in enumerate(g["occurrences"])]
                # the events that may explain a finding, on the finding's row (SPEC §8.6)
                causes = [[_r(c["time"] - shift), g["id"], k, j] for g in mine
                          for k, o in enumerate(g["occurrences"])
                          for j, c in enumerate(o.get("causes", ()))]
                emcy, emcy_left = ([], 0) if node is None else comm_lanes.emcy_marks(
                    res, channel, node, begin, emcy_per_node, emcy_texts)
                emcy_left_out += emcy_left
                rows.append({"node": node, "label": node_label(node), "marks": sorted(marks),
                             "causes": sorted(causes), "emcy": emcy,
                             "iv": [] if node is None
                             else intervals.get((res.index, channel, node), []),
                             "boots": [] if node is None
                             else boots.get((res.index, channel, node), []),
                             # SPEC §9.4.2: where an LSS-assigned node-ID came from
                             "lss": [] if node is None
                             else lss_lane.adoptions(res, channel, node, begin, when)})
            cm = next((c for c in res.model.channels if c.name == channel), None)
            master = ("no NMT master known" if cm is None or cm.master is None
                      else f"NMT master node {cm.master.node} ({cm.master.source})")
            timelines.append({"master": master,
                              "master_title": "" if cm is None else master_line(cm),
                              "id": timeline_id(res, channel), "input": res.index,
                              "path": res.stats.path, "channel": channel,
                              "duration": _r(cm.end - cm.start if cm is not None
                                             and res.stats.restarts else duration(res)),
                              "shift": _r(shift), "rows": rows,
                              # SPEC §9.4.2: the SYNC row above the node rows
                              "sync": comm_lanes.sync_lane(res, channel, begin, gaps, group_of,
                                                           sync_ticks),
                              # and the LSS row: its exchanges and sessions
                              "lss": lss_lane.lss_lane(res, channel, begin, group_of,
                                                       lss_marks, lss_texts),
                              # no timestamps: the axis counts frames, not seconds
                              "frames": res.stats.order_only})
            hidden = left_out.get((res.index, channel), 0)
            notes = [f"{hidden} state intervals not drawn (at most {per_node} per node; the "
                     "JSON report has all)"] if hidden else []
            notes += [f"{emcy_left_out} EMCYs not drawn (at most {emcy_per_node} per node; "
                      "the JSON report has all)"] if emcy_left_out else []
            lss_row = lss_lane.left_out(timelines[-1]["lss"])
            notes += [f"{lss_row} LSS requests not drawn (at most {lss_marks} per "
                      "channel)"] if lss_row else []
            if notes:
                timelines[-1]["left_out"] = "; ".join(notes)
    rules = [{"code": r.code, "name": r.name, "severity": sev, "summary": r.summary,
              "doc": doc_html(r.doc), "findings": sum(1 for res in results
                                                      for f in res.findings if f.rule == r.code),
              "not_evaluated": _not_evaluated_on(results, r.code),
              "skipped": _skipped_everywhere(results, r.code)}
             for r, sev in checked_rules(options)]
    page_data = {
        "states": list(STATES), "sources": list(SOURCES), "stateColors": STATE_COLORS,
        "severityColors": SEVERITY_COLORS, "timelines": timelines,
        "groups": {g["id"]: {**{k: g[k] for k in ("rule", "name", "severity", "where",
                                                  "channel", "count", "timeline")},
                             "occurrences": [{k: v for k, v in o.items() if k != "cause_tree"}
                                             for o in g["occurrences"]]}
                   for g in groups},
        "emcyClasses": list(comm_lanes.EMCY_CLASSES), "emcyColors": EMCY_COLORS,
        "emcyTexts": list(emcy_texts), "lssTexts": list(lss_texts),
    }
    return {
        "version": __version__,
        "generated": datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC"),
        "fail_on": threshold, "failing": is_failing(results, threshold),
        "verdict": verdict_word(results, options),
        "verdict_class": verdict_class(results, options),
        "order_only": any(res.stats.order_only for res in results if res.error is None),
        "rebooting": bool(boots),
        "sync_lanes": any(tl["sync"] for tl in timelines),
        "lss_lanes": any(tl["lss"] for tl in timelines),
        "emcy_marks": bool(emcy_texts), "emcy_colors": EMCY_COLORS,
        "unreadable": [error_line(res) for res in unreadable(results)],
        "not_logs": not_logs_line(options),
        "counts": report["summary"],
        "inputs": inputs, "timelines": timelines, "groups": groups, "nodes": nodes,
        "boot": [view for res in results for view in _boot_views(res, report["nodes"])],
        **_comm_views(results, report),
        **lss_report.html_rows(results, report),
        "rules": rules, "state_colors": STATE_COLORS, "severity_colors": SEVERITY_COLORS,
        "several_inputs": len(results) > 1, "network_notes": network_notes(options),
        "omitted": omitted_lines(results, options),
        "rule_options": sorted({g["rule"] for g in groups}),
        "node_options": [(i, place, key) for i, _c, _n, key, place in sorted(
            {(g["input"], g["channel"] or "", -2 if g["channel"] is None else
              -1 if g["node"] is None else g["node"], g["node_key"], g["place"])
             for g in groups})],
        "config": config_line(options),
        "page_data": script_json(page_data),
        "css": Markup(_asset("report.css")), "js": Markup(_asset("report.js")),
    }


def _not_evaluated_on(results: list[InputResult], code: str) -> list[str]:
    """Why a rule could not be evaluated, per readable input where it could not be (with
    the input's path when there are several); empty when it ran on every one."""
    readable = [res for res in results if res.error is None]
    reasons = [(res.stats.path, res.not_evaluated[code]) for res in readable
               if code in res.not_evaluated]
    if len(readable) <= 1 or len({why for _p, why in reasons}) == 1 == len(readable):
        return [why for _p, why in reasons[:1]]
    return [f"{path}: {why}" for path, why in reasons]


def _skipped_everywhere(results: list[InputResult], code: str) -> bool:
    """Whether a rule could not be evaluated on any readable input: it is listed apart
    from the rules that were checked, never as one that passed."""
    readable = [res for res in results if res.error is None]
    return bool(readable) and all(code in res.not_evaluated for res in readable)


def render(results: list[InputResult], options: dict[str, object]) -> str:
    return _environment().get_template(TEMPLATE).render(report_context(results, options))
