"""`nmtcheck timeline`: each log's per-node NMT state timeline, as text, CSV or JSON."""

from __future__ import annotations

import csv
import io
import json

import click

from nmtcheck.cli.common import load_profile_network, write_stdout
from nmtcheck.cli.helptext import LOGS_HELP, DocumentedCommand, complete_paths
from nmtcheck.cli.inputs import expand_inputs, input_options, named_check_inputs, remote_logs
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
        results = named_check_inputs(names, paths, 1, profile, [], network=network,
                                     input_format=input_format, strict=strict,
                                     channel=channel,
                                     reader_options={"topics": list(topics)} if topics else {})
    write_stdout([render_timelines(results, fmt)])


def render_timelines(results: list[InputResult], fmt: str) -> str:
    """The timelines of several logs: one after the other in text; in JSON and CSV one log
    alone as before, several with each row's `input` named."""
    if len(results) == 1:
        return render_timeline(results[0], fmt)
    if fmt == "json":
        return json.dumps([{"input": res.stats.path, **row} for res in results
                           for row in json.loads(render_timeline(res, fmt))], indent=2) + "\n"
    if fmt == "csv":
        out = io.StringIO()
        w = csv.writer(out, lineterminator="\n")
        for k, res in enumerate(results):
            rows = list(csv.reader(io.StringIO(render_timeline(res, fmt))))
            w.writerows([["input", *row] for row in rows[:1]] if k == 0 else [])
            w.writerows([spreadsheet_safe(res.stats.path), *row] for row in rows[1:])
        return out.getvalue()
    return "\n".join(render_timeline(res, fmt) for res in results)


def render_timeline(res: InputResult, fmt: str) -> str:
    start = res.stats.start or 0.0
    rows = [(m.channel, m.node, iv.state, iv.start, iv.end, iv.source)
            for m in res.nodes() for iv in m.intervals]
    if fmt == "json":
        return json.dumps([{"channel": c, "node": n, "state": s, "start": round(a, 6),
                            "end": round(b, 6), "source": src}
                           for c, n, s, a, b, src in rows], indent=2) + "\n"
    if fmt == "csv":
        out = io.StringIO()
        w = csv.writer(out, lineterminator="\n")
        w.writerow(["channel", "node", "state", "start", "end", "source"])
        for c, n, s, a, b, src in rows:
            w.writerow([spreadsheet_safe(c), n, s, f"{a:.6f}", f"{b:.6f}", spreadsheet_safe(src)])
        return out.getvalue()
    untimed = res.stats.order_only
    lines = [f"{res.stats.path}: no timestamps: order only, times are frame numbers "
             "(1 = the first frame)" if untimed else
             f"{res.stats.path}: times in seconds from the first frame ({start:.6f})"]

    def at(t: float) -> str:
        return f"{moment(res, t, unit=''):>12}"

    for m in res.nodes():
        lines.append(f"{m.channel} node {m.node}:")
        # EMCY, SDO aborts, configuration written: among the states, in time order (an
        # event at a state's start after that state's line); a node's boot-ups inside a
        # state (it rebooted without a state change, B003) under that state's line
        timed: list[tuple[float, float, str]] = [(iv.start, 0, f"  {at(iv.start)} .. {at(iv.end)}  "
                               f"{iv.state:<16} ({iv.source})") for iv in m.intervals]
        timed += [(float(m.intervals.start[r.interval]), 0.5,
                   f"  {'':>12}    {reboot_note(res, m, r)}") for r in reboots(m)]
        timed += [(e.ts, 1, f"  {at(e.ts)}     event: {e.text}") for e in m.events]
        lines.extend(text for _t, _k, text in sorted(timed, key=lambda x: (x[0], x[1])))
    return escape_lines(lines) + "\n"  # a name's newline never starts a line of its own
