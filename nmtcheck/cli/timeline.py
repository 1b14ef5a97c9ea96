"""`nmtcheck timeline`: each log's per-node NMT state timeline, as text, CSV or JSON."""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Collection
from typing import Any

import click

from nmtcheck.cli.common import load_profile_network, write_stdout
from nmtcheck.cli.helptext import LOGS_HELP, DocumentedCommand, complete_paths
from nmtcheck.cli.inputs import expand_inputs, input_options, named_check_inputs, remote_logs
from nmtcheck.engine import select_rules
from nmtcheck.protocol.nmt import SOURCES, STATES
from nmtcheck.reporters import comm_lanes, lss_lane, lss_report
from nmtcheck.reporters.common import moment, reboot_note, reboots, spreadsheet_safe
from nmtcheck.results import InputResult
from nmtcheck.safe_text import escape_lines
from nmtcheck.settings.config import discover


@click.command(cls=DocumentedCommand, arguments={"LOGS": LOGS_HELP},
               short_help="Print each node's NMT state timeline, events in time order.")
@click.argument("logs", nargs=-1, required=True, shell_complete=complete_paths)
@input_options
@click.option("--format", "fmt", type=click.Choice(["text", "csv", "json"]), default="text",
              show_default=True)
@click.option("--storage-option", "storage_options", multiple=True, metavar="KEY=VALUE",
              help="For a LOG that is a URL (s3://...): an fsspec storage option "
                   "(endpoint_url=...); credentials come from the environment. Repeatable.")
def timeline(logs: tuple[str, ...], input_format: str | None, rules_profile: str | None,
             network_file: str | None, config_file: str | None, isolated: bool,
             dcf: tuple[str, ...], strict: bool, channel: str | None, topics: tuple[str, ...],
             fmt: str, storage_options: tuple[str, ...] = ()) -> None:
    """Print the per-node NMT state timeline of each LOG (quoted globs and directories are
    expanded as by `check`): the states and the node events in time order."""
    profile, network, _info = load_profile_network(rules_profile, network_file, dcf,
                                                   discover(config_file, isolated))
    with remote_logs(logs, storage_options) as (logs, names):
        paths = expand_inputs(logs).logs
        # the rules whose findings the timeline draws as gaps, and the L rules its LSS
        # rows name (SPEC §9.4.2), as the profile enables them; no other rule runs
        rules = [r for r in select_rules(profile, [], [])
                 if r.code in comm_lanes.GAP_RULES or r.code.startswith("L")]
        results = named_check_inputs(names, paths, 1, profile, rules, network=network,
                                     input_format=input_format, strict=strict,
                                     channel=channel,
                                     reader_options={"topics": list(topics)} if topics else {})
    write_stdout([render_timelines(results, fmt, {r.code for r in rules})])


def render_timelines(results: list[InputResult], fmt: str,
                     checked: Collection[str] = tuple(comm_lanes.GAP_RULES)) -> str:
    """The timelines of several logs: one after the other in text; in JSON and CSV one log
    alone as before, several with each row's `input` named. `checked`: the gap rules that
    ran (the profile may turn Y001 off)."""
    if len(results) == 1:
        return render_timeline(results[0], fmt, checked)
    if fmt == "json":
        return json.dumps([{"input": res.stats.path, **row} for res in results
                           for row in json.loads(render_timeline(res, fmt, checked))],
                          indent=2) + "\n"
    if fmt == "csv":
        out = io.StringIO()
        w = csv.writer(out, lineterminator="\n")
        for k, res in enumerate(results):
            rows = list(csv.reader(io.StringIO(render_timeline(res, fmt, checked))))
            w.writerows([["input", *row] for row in rows[:1]] if k == 0 else [])
            w.writerows([spreadsheet_safe(res.stats.path), *row] for row in rows[1:])
        return out.getvalue()
    return "\n".join(render_timeline(res, fmt, checked) for res in results)


# The rows of `--format csv|json`: a node's NMT states (`kind` state), and SPEC §9.4.2's
# SYNC and PDO gaps of the Y001, D001 and D004 findings, each node's EMCYs and each LSS
# exchange (`kind` lss: `code` its command specifier, `rule` the L findings at it)
COLUMNS = ("channel", "node", "state", "start", "end", "source", "kind", "rule", "cob_id",
           "code", "error_register", "line", "text", "canopennode")


def timeline_rows(res: InputResult) -> list[dict[str, Any]]:
    """Every row of a log's timeline in time order (states first at equal times), times
    as the trace has them."""
    blank = dict.fromkeys(COLUMNS)
    rows = [{**blank, "channel": m.channel, "node": m.node, "state": STATES[st],
             "start": round(a, 6), "end": round(b, 6), "source": SOURCES[so], "kind": "state"}
            for m in res.nodes() for a, b, st, so in zip(
                m.intervals.start.tolist(), m.intervals.end.tolist(),
                m.intervals.state.tolist(), m.intervals.source.tolist(), strict=True)]
    rows += [{**blank, "channel": g.finding.channel, "node": g.finding.node,
              "start": round(g.start, 6), "end": round(g.end, 6), "kind": g.kind,
              "rule": g.finding.rule, "cob_id": g.cob_id, "line": g.finding.line or None,
              "text": g.finding.message} for g in comm_lanes.finding_gaps(res)]
    rows += [{**blank, "channel": e.channel, "node": e.node, "start": round(e.time, 6),
              "end": round(e.time, 6), "kind": "emcy",
              "code": None if e.code is None else f"{e.code:04X}h",
              "error_register": None if e.register is None else f"{e.register:02X}h",
              "line": e.line or None, "text": e.text, "canopennode": e.canopennode}
             for m in res.nodes() for e in comm_lanes.emcy_rows(res, m.channel, m.node)]
    rows += lss_lane.timeline_rows(res, blank)
    order = {c: k for k, c in enumerate(res.stats.channels)}
    rows.sort(key=lambda r: (order.get(r["channel"], len(order)), r["node"] is not None,
                             r["node"] or 0, r["start"], r["kind"] != "state"))
    return rows


def render_timeline(res: InputResult, fmt: str,
                    checked: Collection[str] = tuple(comm_lanes.GAP_RULES)) -> str:
    start = res.stats.start or 0.0
    if fmt == "json":
        return json.dumps(timeline_rows(res), indent=2) + "\n"
    if fmt == "csv":
        out = io.StringIO()
        w = csv.writer(out, lineterminator="\n")
        w.writerow(COLUMNS)
        for r in timeline_rows(res):
            cn = r["canopennode"]
            w.writerow([spreadsheet_safe(r["channel"]), r["node"], r["state"],
                        f"{r['start']:.6f}", f"{r['end']:.6f}", spreadsheet_safe(r["source"]),
                        r["kind"],
                        r["rule"], r["cob_id"], r["code"], r["error_register"], r["line"],
                        spreadsheet_safe(r["text"]) if r["text"] else None,
                        None if cn is None else json.dumps(cn)])
        return out.getvalue()
    untimed = res.stats.order_only
    lines = [f"{res.stats.path}: no timestamps: order only, times are frame numbers "
             "(1 = the first frame)" if untimed else
             f"{res.stats.path}: times in seconds from the first frame ({start:.6f})"]

    def at(t: float) -> str:
        return f"{moment(res, t, unit=''):>12}"

    def gap_line(g: comm_lanes.GapInterval) -> str:
        f = g.finding
        what = f"{'SYNC' if g.kind == 'sync_gap' else 'PDO'} gap {g.cob_id or ''}".strip()
        to = "end" if g.open else at(g.end)
        return (f"  {at(g.start)} .. {to:>12}  {what:<16} {f.rule} {f.severity}"
                f"{f' (line {f.line})' if f.line else ''}: {f.message}")

    gaps = comm_lanes.finding_gaps(res)

    def sync_lines(channel: str) -> list[str]:
        """SPEC §9.4.2: the channel's SYNC line above its node rows, with Y001's gaps."""
        sync = comm_lanes.sync_summary(res, channel, "Y001" in checked)
        return [] if sync is None else [f"{channel} {sync}"] + [
            gap_line(g) for g in gaps if g.kind == "sync_gap" and g.finding.channel == channel]

    shown: set[str] = set()
    for m in res.nodes():
        if m.channel not in shown:
            shown.add(m.channel)
            lines += sync_lines(m.channel)
        lines.append(f"{m.channel} node {m.node}:")
        # EMCY, SDO aborts, configuration written: among the states, in time order (an
        # event at a state's start after that state's line); a node's boot-ups inside a
        # state (it rebooted without a state change, B002 or B003) under that state's line; the
        # node's PDO gaps (D001 of a producer, D004 of a consumer) as intervals
        detail = {e.frame_index: e.detail for e in comm_lanes.emcy_rows(res, m.channel, m.node)
                  if e.canopennode is not None}
        timed: list[tuple[float, float, str]] = [(iv.start, 0, f"  {at(iv.start)} .. {at(iv.end)}  "
                               f"{iv.state:<16} ({iv.source})") for iv in m.intervals]
        timed += [(float(m.intervals.start[r.interval]), 0.5,
                   f"  {'':>12}    {reboot_note(res, m, r)}") for r in reboots(m)]
        timed += [(e.ts, 1, f"  {at(e.ts)}     event: {e.text}"
                   + (f"; {detail[e.idx]}" if e.idx in detail else "")) for e in m.events]
        timed += [(g.start, 0.75, gap_line(g)) for g in gaps if g.kind == "pdo_gap"
                  and g.finding.channel == m.channel and g.finding.node == m.node]
        lines.extend(text for _t, _k, text in sorted(timed, key=lambda x: (x[0], x[1])))
    for channel in res.stats.channels:  # SYNC on a channel where no node was seen
        if channel not in shown:
            lines += sync_lines(channel)
    lines += lss_report.timeline_lines(res, at)  # SPEC §9.4.2: LSS as channel events
    return escape_lines(lines) + "\n"  # a name's newline never starts a line of its own
