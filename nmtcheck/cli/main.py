"""Command line: `nmtcheck check`, `nmtcheck timeline`, `nmtcheck rules`, and the group
that `nmtcheck monitor` (live/command.py) and `nmtcheck fleet` (fleet/commands.py) are
registered on; what they share with these commands is in cli_common.py, so that neither
imports this module.

Exit codes: 0 no finding at or above --fail-on, 1 at least one, 2 usage or
input error (one line on stderr, never a traceback unless --debug).
"""

from __future__ import annotations

# First of all: `check --results` starts the fleet's fork server here, so that its imports
# run beside this module's (issue 25; does nothing for any other command). It also asks
# numpy's BLAS for one thread, which only works before numpy is imported.
import nmtcheck.fleet.prestart  # noqa: F401

# isort: split
import contextlib
import csv
import glob
import io
import json
import logging
import os
import signal
import sys
import tempfile
import traceback
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import click

from nmtcheck import __version__
from nmtcheck.checks import BY_CODE, RULES
from nmtcheck.checks.base import Rule, fails
from nmtcheck.cli.common import (
    EXIT_ERROR,
    EXIT_FINDINGS,
    EXIT_OK,
    check_outputs,
    load_profile_network,
    resolve_settings,
    write_atomically,
    write_reports,
    write_stdout,
)
from nmtcheck.settings.config import discover
from nmtcheck.engine import (
    MAX_FINDINGS_PER_RULE,
    InputResult,
    check_inputs,
    select_rules,
    summary,
)
from nmtcheck.errors import InputError, NmtcheckError, UsageError
from nmtcheck.fleet.commands import (
    FLEET_OPTION_NAMES,
    fleet,
    fleet_options,
    fleet_requested,
)
from nmtcheck.live.command import monitor as live_monitor
from nmtcheck.settings.profiles import DEFAULT_PROFILE, Profile, load_profile
from nmtcheck.readers import FORMATS as INPUT_FORMATS
from nmtcheck.readers import open_input
from nmtcheck.reporters import (
    auto_format,
    colour,
    format_for_path,
    statistics_renderer,
    streamer,
)
from nmtcheck.reporters.common import plural, spreadsheet_safe
from nmtcheck.safe_text import escape_controls

# The helpers that moved to cli_common.py (so that the monitor and fleet commands need not
# import this module) stay importable from here: `from nmtcheck.cli.main import write_reports`.
__all__ = [
    "EXIT_ERROR",
    "EXIT_FINDINGS",
    "EXIT_OK",
    "FleetGroupedCommand",
    "ProgressBar",
    "Terminated",
    "check",
    "check_outputs",
    "cli",
    "expand_inputs",
    "expand_logs",
    "is_log",
    "load_profile_network",
    "main",
    "render_timeline",
    "render_timelines",
    "resolve_settings",
    "rule_doc",
    "rule_table",
    "rules_cmd",
    "timeline",
    "write_atomically",
    "write_reports",
    "write_stdout",
]


def _common(f: Callable[..., Any]) -> Callable[..., Any]:
    """Options shared by `check` and `timeline`."""
    for opt in reversed([
        click.option("--input-format", type=click.Choice(INPUT_FORMATS), default=None,
                     help="Log format (default: detected from the content)."),
        click.option("--rules", "rules_profile", default=None,
                     help="Rule profile: a name in rules/ or a TOML file "
                          "[default: the configuration's, else 'default']."),
        click.option("--network", "network_file", default=None,
                     help="Network description (TOML): expected nodes and their timing."),
        click.option("--config", "config_file", default=None, metavar="FILE",
                     help="Configuration file (nmtcheck.toml or a pyproject.toml with "
                          "[tool.nmtcheck]) [default: found upward from the current "
                          "directory, up to the repository root]."),
        click.option("--isolated", is_flag=True,
                     help="Ignore every configuration file."),
        click.option("--dcf", multiple=True, metavar="NODE=PATH",
                     help="EDS/DCF file of a node (adds it to the network). Repeatable."),
        click.option("--strict", is_flag=True, help="The first unparseable record is fatal."),
        click.option("--channel", default=None, help="Only this channel (e.g. can0, 1)."),
        click.option("--topic", "topics", multiple=True,
                     help="MCAP: only these topics (each topic is a channel). Repeatable."),
    ]):
        f = opt(f)
    return f


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="nmtcheck")
@click.option("--debug", is_flag=True, hidden=True, help="Show tracebacks.")
@click.pass_context
def cli(ctx: click.Context, debug: bool) -> None:
    """Check recorded CAN logs against CANopen NMT (CiA 301)."""
    ctx.obj = {"debug": debug}


class FleetGroupedCommand(click.Command):
    """`check --help`: the fleet options (nmtcheck/fleet/) in a section of their own, after
    the options of an ordinary check."""

    def format_options(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        rows: list[tuple[str, str]] = []
        fleet_rows: list[tuple[str, str]] = []
        for param in self.get_params(ctx):
            record = param.get_help_record(ctx)
            if record is not None:
                (fleet_rows if param.name in FLEET_OPTION_NAMES else rows).append(record)
        if rows:
            with formatter.section("Options"):
                formatter.write_dl(rows)
        if fleet_rows:
            with formatter.section("Fleet options (with --results: many logs into a Parquet "
                                   "dataset; then nmtcheck fleet summary DIR)"):
                formatter.write_dl(fleet_rows)


@cli.command(cls=FleetGroupedCommand)
@click.argument("logs", nargs=-1, required=False)
@_common
@fleet_options
@click.option("--format", "fmt", default=None,
              help="text, concise, json, csv, html, junit, sarif, github, markdown, or auto "
                   "(github under GitHub Actions, else text) [default: text].")
@click.option("-o", "--output", "outputs", multiple=True,
              help="Also write a report to PATH; the format follows the suffix. Repeatable.")
@click.option("--select", multiple=True,
              help="Only these rules: codes, prefixes (H, I) or names (heartbeat-timeout).")
@click.option("--ignore", multiple=True,
              help="Skip these rules: codes, prefixes or names. The more specific of "
                   "--select/--ignore wins.")
@click.option("--fail-on", type=click.Choice(["error", "warning", "info", "never"]),
              default=None,
              help="Exit 1 when a finding of this severity or higher exists [default: error].")
@click.option("--statistics", is_flag=True,
              help="One line per rule with its count instead of every finding.")
@click.option("-q", "--quiet", is_flag=True, help="Only the findings and the verdict.")
@click.option("-j", "--jobs", type=click.IntRange(min=0), default=1, show_default=True,
              help="Check this many logs at once, in separate processes (0: one per core).")
@click.option("--follow", is_flag=True,
              help="Read LOG as it arrives: `-` is standard input to its end (candump -L "
                   "can0 | nmtcheck check --follow -), a file is followed as it grows, as "
                   "tail -F does, until Ctrl-C; live findings on stderr, the full check at "
                   "the end.")
@click.option("--color", "color", type=click.Choice(["auto", "always", "never"]),
              default="auto", show_default=True,
              help="Colour the text and concise reports: auto on a terminal, unless the "
                   "NO_COLOR environment variable is set.")
@click.option("--max-findings", type=click.IntRange(min=0), default=MAX_FINDINGS_PER_RULE,
              show_default=True,
              help="Keep at most this many findings per rule and input (0: all); every report "
                   "states how many more were left out, and they still count for the verdict.")
def check(logs: tuple[str, ...], input_format: str | None, rules_profile: str | None,
          network_file: str | None, config_file: str | None, isolated: bool,
          dcf: tuple[str, ...], strict: bool, channel: str | None, topics: tuple[str, ...],
          fmt: str | None, outputs: tuple[str, ...], select: tuple[str, ...],
          ignore: tuple[str, ...], fail_on: str | None, statistics: bool, quiet: bool,
          jobs: int, max_findings: int, follow: bool = False, color: str = "auto",
          **fleet_args: Any) -> None:
    """Analyse each LOG (`-`: standard input; quoted globs are expanded), print the findings
    and set the exit code."""
    config, fmt, fail_on, selected, ignored = resolve_settings(
        config_file, isolated, fmt, fail_on, select, ignore)
    check_outputs(outputs)  # before any log is read: not after a long analysis (SPEC §4)
    if fleet_requested(fleet_args):  # --results: a fleet run (nmtcheck/fleet/)
        from nmtcheck.fleet.commands import run_fleet_check

        profile, network, _info = load_profile_network(rules_profile, network_file, dcf, config)
        sys.exit(run_fleet_check(
            logs, fleet_args, profile, select_rules(profile, selected, ignored), network,
            fail_on, input_format=input_format, strict=strict, channel=channel,
            reader_options={"topics": list(topics)} if topics else {},
            max_findings=max_findings, quiet=quiet, outputs=outputs, statistics=statistics))
    if not logs:
        raise click.UsageError("Missing argument 'LOGS...'.")
    profile, network, config_info = load_profile_network(rules_profile, network_file, dcf, config)
    rules = select_rules(profile, selected, ignored)
    stdout_render = streamer(fmt) if not statistics else statistics_renderer(fmt)
    files = [(path, streamer(format_for_path(path))) for path in outputs]
    with remote_logs(logs, fleet_args.get("storage_options") or (), follow) as (logs, names):
        _check_logs(logs, names, profile, rules, network, config_info, stdout_render, files,
                    fmt=fmt, fail_on=fail_on, quiet=quiet, follow=follow, jobs=jobs,
                    color=color, statistics=statistics, max_findings=max_findings,
                    input_format=input_format, strict=strict, channel=channel,
                    topics=topics)


def named_check_inputs(names: dict[str, str], logs: tuple[str, ...], *args: Any, **kw: Any
                       ) -> list[InputResult]:
    """check_inputs, with each fetched copy (`names`: copy -> URL) named by its URL in
    the results and in any error, never by its temporary path."""
    try:
        results = check_inputs(logs, *args, **kw)
    except InputError as exc:
        raise InputError(names.get(exc.path, exc.path), by_url(exc.message, names),
                         exc.line) from None
    except UsageError as exc:  # --channel not in the log names the log
        raise UsageError(by_url(str(exc), names)) from None
    for res in results:
        res.stats.path = names.get(res.stats.path, res.stats.path)
        if res.error is not None:
            res.error = by_url(res.error, names)
    return results


def by_url(text: str, names: dict[str, str]) -> str:
    """`text` with each fetched copy's path replaced by its URL."""
    for copy, url in names.items():
        text = text.replace(copy, url)
    return text


@contextlib.contextmanager
def remote_logs(logs: tuple[str, ...], storage_options: tuple[str, ...], follow: bool = False
                ) -> Iterator[tuple[tuple[str, ...], dict[str, str]]]:
    """LOG arguments with each URL (s3://..., gs://...) fetched into a temporary local copy
    for the time of the check (fleet.storage.local_copies), and {copy: URL} to name the
    copies in the reports. Without a URL, nothing is imported and `--storage-option` is a
    usage error (it would be ignored)."""
    from nmtcheck.fleet.prestart import is_remote

    if not any(is_remote(a) for a in logs):
        if storage_options:
            raise UsageError("--storage-option is for URLs: a LOG such as s3://bucket/log.mf4, "
                             "or --results")
        yield logs, {}
        return
    if follow:
        raise UsageError("--follow reads a local file as it grows, not a URL")
    from nmtcheck.fleet.storage import local_copies, parse_storage_options

    with local_copies(logs, parse_storage_options(storage_options)) as (copies, names):
        yield tuple(copies), names


def _check_logs(logs: tuple[str, ...], names: dict[str, str], profile: Any, rules: list[Any],
                network: Any, config_info: Any, stdout_render: Any, files: list[Any], *,
                fmt: str, fail_on: str, quiet: bool, follow: bool, jobs: int, color: str,
                statistics: bool, max_findings: int, input_format: str | None, strict: bool,
                channel: str | None, topics: tuple[str, ...]) -> None:
    """The rest of `check` without --results: check the logs, write the reports, exit."""
    logs, not_logs = expand_inputs(logs)
    if "-" in logs:
        jobs = 1  # worker processes do not share this process's standard input
    reader_options: dict[str, object] = {"topics": list(topics)} if topics else {}
    progress = (ProgressBar(len(logs)) if sys.stderr.isatty() and not quiet and not follow
                else None)
    try:
        if follow:  # nmtcheck/live/follow.py: live findings, then this same check
            from nmtcheck.live.follow import follow_logs

            results = follow_logs(logs, profile, rules, network=network,
                                  input_format=input_format, strict=strict, channel=channel,
                                  max_findings=max_findings)
        else:
            # one unreadable input among several hides none of the others (SPEC §4)
            results = named_check_inputs(names, logs, jobs or os.cpu_count() or 1, profile,
                                         rules, progress=progress, keep_going=len(logs) > 1,
                                         network=network, input_format=input_format,
                                         strict=strict, channel=channel,
                                         reader_options=reader_options,
                                         max_findings=max_findings)
    finally:
        if progress:
            progress.close()
    options: dict[str, object] = {"fail_on": fail_on, "quiet": quiet,
                                  "rules": {r.code: profile[r.code].severity for r in rules},
                                  "network_notes": list(network.notes) if network else [],
                                  "max_findings": max_findings,
                                  "config": config_info, "not_logs": not_logs}
    write_reports(results, files, options)
    report = stdout_render(results, options)
    painting = not statistics and colour.wanted(color, sys.stdout)
    if painting:
        report = colour.painted(report, auto_format() if fmt == "auto" else fmt)
    write_stdout(report, color=True if painting else None)
    unreadable = [res for res in results if res.error is not None]
    for res in unreadable:  # named in every report, and here, one line each
        click.echo(escape_controls(f"nmtcheck: {res.stats.path}: {res.error}"), err=True)
    if unreadable:
        sys.exit(EXIT_ERROR)
    if fails(summary(results), fail_on):
        sys.exit(EXIT_FINDINGS)


@cli.command()
@click.argument("logs", nargs=-1, required=True)
@_common
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
        paths, _not_logs = expand_inputs(logs)
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


def expand_inputs(args: tuple[str, ...]) -> tuple[tuple[str, ...], list[str]]:
    """The LOG arguments as files (`expand_logs`), a directory standing for every log below
    it, recursively, in name order (as ruff takes a directory); and the files below those
    directories whose content is no log format (or empty): skipped and counted, not errors.
    Hidden files and directories (`.git`) are not looked at."""
    out: list[str] = []
    not_logs: list[str] = []
    for arg in expand_logs(args):
        if arg == "-" or not os.path.isdir(arg):
            out.append(arg)
            continue
        found = []
        for root, dirs, names in os.walk(arg):
            dirs[:] = sorted(d for d in dirs if not d.startswith("."))
            found += [os.path.join(root, n) for n in sorted(names) if not n.startswith(".")]
        logs = [p for p in found if is_log(p)]
        not_logs += [p for p in found if p not in set(logs)]
        if not logs:
            raise UsageError(f"{arg}: no log file below this directory"
                             + (f" ({plural(len(found), 'file')} whose content is no log "
                                "format)" if found else ""))
        out += logs
    return tuple(out), not_logs


# Suffixes that only logs have: a file below a directory named so whose content is no
# log format is a damaged or empty recording (a cut-off .blf, a 0-byte .mf4), not some
# other file, and checking it fails the gate; `.log`, `.txt` and `.csv` are left to the
# content (build.log, README.txt).
LOG_SUFFIXES = tuple(suffix + packed
                     for suffix in (".asc", ".blf", ".mf4", ".trc", ".mcap", ".pcap", ".pcapng")
                     for packed in ("", ".gz", ".bz2", ".xz", ".zst"))


def is_log(path: str) -> bool:
    """Whether the content of `path` is a log format nmtcheck reads (detected from the
    first bytes, as `check` does). A file that cannot be opened counts as a log: checking
    it names the reason; so does one whose suffix only logs have (LOG_SUFFIXES)."""
    try:
        opened = open_input(path)
    except InputError as exc:
        if path.lower().endswith(LOG_SUFFIXES):
            return True
        return not exc.message.startswith(("unknown log format", "empty file"))
    opened.batches.close()
    return True


def expand_logs(logs: tuple[str, ...]) -> tuple[str, ...]:
    """LOG arguments with the glob patterns the shell left alone (quoted, or from a CI
    config) expanded, sorted; a pattern's matches are the files it names, not directories.
    `-` (standard input) may come once."""
    out: list[str] = []
    for arg in logs:
        if arg == "-" or os.path.lexists(arg) or not glob.has_magic(arg):
            out.append(arg)
            continue
        matches = sorted(m for m in glob.glob(arg, recursive=True) if not os.path.isdir(m))
        if not matches:
            raise UsageError(f"{arg}: no log file matches this pattern")
        out.extend(matches)
    if out.count("-") > 1:
        raise UsageError("-: standard input can be read only once")
    return tuple(out)


class ProgressBar:
    """Frames checked so far, on stderr (tqdm), shown only once a run takes over a second."""

    def __init__(self, inputs: int) -> None:
        from tqdm import tqdm

        self._bar = tqdm(unit=" frames", unit_scale=True, file=sys.stderr, leave=False,
                         delay=1.0, mininterval=0.5, dynamic_ncols=True,
                         bar_format="{desc}{n_fmt} frames [{elapsed}, {rate_fmt}]")
        self._inputs = inputs
        self._started = 0

    def start_input(self, path: str) -> None:
        self._started += 1
        self._bar.set_description(f"[{self._started}/{self._inputs}] {Path(path).name}",
                                  refresh=False)

    def frames(self, n: int) -> None:
        self._bar.update(n)

    def close(self) -> None:
        self._bar.close()


class Terminated(BaseException):
    """SIGTERM, SIGHUP or SIGINT as an exception, so that `finally` blocks and the temporary
    directories' finalizers run (CI cancellation sends SIGTERM)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


def _raise_terminated(signum: int, _frame: object) -> None:
    raise Terminated(signum)


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
            w.writerow([spreadsheet_safe(c), n, s, f"{a:.6f}", f"{b:.6f}", src])
        return out.getvalue()
    lines = [f"{res.stats.path}: no timestamps: order only, times are frame numbers"
             if res.stats.order_only else
             f"{res.stats.path}: times in seconds from the first frame ({start:.6f})"]
    for m in res.nodes():
        lines.append(f"{m.channel} node {m.node}:")
        # EMCY, SDO aborts, configuration written: among the states, in time order (an
        # event at a state's start after that state's line)
        timed = [(iv.start, 0, f"  {iv.start - start:12.6f} .. {iv.end - start:12.6f}  "
                               f"{iv.state:<16} ({iv.source})") for iv in m.intervals]
        timed += [(e.ts, 1, f"  {e.ts - start:12.6f}     event: {e.text}") for e in m.events]
        lines.extend(text for _t, _k, text in sorted(timed, key=lambda x: (x[0], x[1])))
    return "\n".join(lines) + "\n"


@cli.command(name="rules")
@click.argument("code", required=False)
@click.option("--format", "fmt", type=click.Choice(["text", "markdown"]), default="text",
              show_default=True)
def rules_cmd(code: str | None, fmt: str) -> None:
    """List the rule catalogue, or document one rule (CODE)."""
    defaults = load_profile(DEFAULT_PROFILE)
    if code is None:
        click.echo(rule_table(defaults) if fmt == "markdown" else "\n".join(
            f"{r.code}  {r.name:<28} {defaults[r.code].severity:<8} {r.summary}" for r in RULES))
        return
    r = BY_CODE.get(code.upper()) or next((x for x in RULES if x.name == code.lower()), None)
    if r is None:
        raise UsageError(f"rules: unknown rule code {code!r} (known: {', '.join(BY_CODE)})")
    click.echo(f"{r.code} {r.name} (default severity: {defaults[r.code].severity})\n\n"
               + rule_doc(r, defaults))


def rule_doc(r: Rule, defaults: Profile) -> str:
    """A rule's documentation as `nmtcheck rules CODE` prints it after its title line (and
    the docs site's rule page shows it): the docstring, the parameters with their defaults."""
    lines = [r.doc]
    if r.params:
        lines += ["", "**Parameters** (rule profile `[rules." + r.code + "]`):"]
        for p in r.params:
            lines.append(f"- `{p.name}` = {defaults[r.code].params[p.name]!r}: {p.doc}")
    lines += ["", "Also: `enabled = false` turns it off; "
              "`severity = \"warning\"` changes its level."]
    return "\n".join(lines)


def rule_table(defaults: Profile) -> str:
    """The rule table of docs/reference/rules/index.md, generated from the registry."""
    rows = ["| code | name | severity | what it flags |", "|---|---|---|---|"]
    rows += [f"| {r.code} | {r.name} | {defaults[r.code].severity} | {r.summary} |"
             for r in RULES]
    return "\n".join(rows)


cli.add_command(fleet)  # nmtcheck fleet summary (nmtcheck/fleet/commands.py)
cli.add_command(live_monitor)  # nmtcheck monitor (nmtcheck/live/command.py)


def main() -> None:
    """Entry point: one-line errors with exit code 2, never a traceback."""
    debug = "--debug" in sys.argv[1:]
    if not debug:  # third-party logging (asammdf, canopen, can) never reaches stderr: every
        logging.getLogger().addHandler(logging.NullHandler())  # error is nmtcheck's one line
    # Python finds the temporary directory by writing and removing a probe file there; a
    # signal between the two would leave it behind, so that happens before the handlers
    # (without a usable one, the first spill says so later).
    with contextlib.suppress(OSError):
        tempfile.gettempdir()
    for name in ("SIGTERM", "SIGHUP", "SIGINT"):
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), _raise_terminated)
    try:
        cli.main(standalone_mode=False)
    except Terminated as exc:  # shells expect 128 + the signal's number (130 for Ctrl-C)
        click.echo(f"nmtcheck: interrupted ({signal.Signals(exc.signum).name})", err=True)
        sys.exit(128 + exc.signum)
    except click.exceptions.Exit as exc:
        sys.exit(exc.exit_code)
    except click.exceptions.Abort:
        click.echo("nmtcheck: aborted", err=True)
        sys.exit(EXIT_ERROR)
    except click.ClickException as exc:
        click.echo(escape_controls(f"nmtcheck: {exc.format_message()}"), err=True)
        sys.exit(EXIT_ERROR)
    except NmtcheckError as exc:
        click.echo(escape_controls(f"nmtcheck: {exc}"), err=True)
        sys.exit(EXIT_ERROR)
    except BrokenPipeError:
        sys.exit(EXIT_OK)
    except Exception as exc:  # noqa: BLE001 - a CI gate must fail cleanly
        if debug:
            traceback.print_exc()
        click.echo(escape_controls(f"nmtcheck: internal error: {type(exc).__name__}: {exc} "
                                   f"(please report; --debug shows the traceback)"), err=True)
        sys.exit(EXIT_ERROR)


def command() -> None:
    """The `nmtcheck` command (its console script, `python -m nmtcheck`): main(), then the
    process ends without tearing the interpreter down module by module, which took 20 ms
    of a small log's 0.19 s check here (numpy's, pyarrow's and the checker's modules
    freed one by one, for nothing). Threads still running, and the atexit handlers
    (multiprocessing's finalizers, temporary directories), are waited for as Python
    would; a program or test that calls main() gets its SystemExit as before."""
    try:
        main()
        code: str | int | None = None
    except SystemExit as exc:
        code = exc.code
    _end(code)


def _end(code: str | int | None) -> None:
    """Exit with `code` as sys.exit does, skipping only the interpreter's teardown."""
    import atexit
    import threading

    run_exitfuncs = getattr(atexit, "_run_exitfuncs", None)
    running = [t for t in threading.enumerate()
               if t is not threading.main_thread() and t.is_alive() and not t.daemon]
    if run_exitfuncs is None or running:  # let Python join them, as it would
        sys.exit(code)
    if code is None:
        status = 0
    elif isinstance(code, int):
        status = code
    else:  # sys.exit("message"): printed, status 1
        print(code, file=sys.stderr)
        status = 1
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):  # a closed pipe (| head): no output
            stream.flush()
    run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):  # what the handlers printed
        with contextlib.suppress(OSError, ValueError):
            stream.flush()
    os._exit(status)
