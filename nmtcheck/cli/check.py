"""`nmtcheck check`: check each log, write the reports, and set the exit code (0: no
finding at or above --fail-on, 1: at least one, 2: a usage error or an unreadable input).
With --results it is a fleet run (cli/fleet.py); with --follow, a live one (live/follow.py)."""

from __future__ import annotations

import os
import sys
import threading
from collections.abc import Mapping
from pathlib import Path
from typing import IO, Any

import click

from nmtcheck.checks.base import fails
from nmtcheck.cli.common import (
    EXIT_ERROR,
    EXIT_FINDINGS,
    check_outputs,
    load_profile_network,
    resolve_settings,
    write_reports,
    write_stdout,
)
from nmtcheck.cli.fleet import FLEET_OPTION_NAMES, fleet_options, fleet_requested
from nmtcheck.cli.helptext import LOGS_HELP, DocumentedCommand, complete_paths
from nmtcheck.cli.inputs import expand_inputs, input_options, named_check_inputs, remote_logs
from nmtcheck.engine import select_rules
from nmtcheck.readers.forked import PAUSED_AT_FORK as PROGRESS_THREAD
from nmtcheck.reporters import (
    auto_format,
    colour,
    format_for_path,
    statistics_renderer,
    streamer,
)
from nmtcheck.results import MAX_FINDINGS_PER_RULE, summary
from nmtcheck.safe_text import escape_controls


class FleetGroupedCommand(DocumentedCommand):
    """`check --help`: the fleet options (nmtcheck/fleet/) in a section of their own, after
    the options of an ordinary check; LOGS in the Arguments section, not among them."""

    def format_options(self, ctx: click.Context, formatter: click.HelpFormatter) -> None:
        rows: list[tuple[str, str]] = []
        fleet_rows: list[tuple[str, str]] = []
        for param in self.get_params(ctx):
            if isinstance(param, click.Argument):
                continue
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


@click.command(cls=FleetGroupedCommand, arguments={"LOGS": LOGS_HELP},
               short_help="Check logs: findings, reports and the gate's exit code.")
@click.argument("logs", nargs=-1, required=False, shell_complete=complete_paths)
@input_options
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
        from nmtcheck.cli.fleet import run_fleet_check

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


def _check_logs(logs: tuple[str, ...], names: dict[str, str], profile: Any, rules: list[Any],
                network: Any, config_info: Any, stdout_render: Any, files: list[Any], *,
                fmt: str, fail_on: str, quiet: bool, follow: bool, jobs: int, color: str,
                statistics: bool, max_findings: int, input_format: str | None, strict: bool,
                channel: str | None, topics: tuple[str, ...]) -> None:
    """The rest of `check` without --results: check the logs, write the reports, exit."""
    logs, not_logs, not_regular = expand_inputs(logs)
    if "-" in logs:
        jobs = 1  # worker processes do not share this process's standard input
    reader_options: dict[str, object] = {"topics": list(topics)} if topics else {}
    progress = (ProgressBar(len(logs)) if progress_wanted(sys.stderr, quiet, follow)
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
                                         reports_only=True,
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
                                  "config": config_info, "not_logs": not_logs,
                                  "not_regular": not_regular}
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



def progress_wanted(stream: Any, quiet: bool, follow: bool,
                    environ: Mapping[str, str] = os.environ) -> bool:
    """Whether `check` shows a progress bar on `stream` (stderr): on a terminal only,
    never in a CI log (`CI` set, as CI services set it, also where they give the job a
    terminal) nor on a dumb one, never with -q or --follow."""
    if quiet or follow or environ.get("CI") or environ.get("TERM") == "dumb":
        return False
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError):  # no stream, or a closed one
        return False


_AT_FORK: list[threading.Lock] = []  # the running bar's lock, held across a fork


def _pause_at_fork(lock: threading.Lock) -> None:
    """The reader forks a parse worker (readers/forked.py) while the bar's ticker runs:
    the fork waits until the ticker is outside the bar and stderr (it only touches them
    holding `lock`), so the worker inherits no lock held mid-write."""
    if not _AT_FORK:
        os.register_at_fork(before=lambda: _AT_FORK[-1].acquire(),
                            after_in_parent=lambda: _AT_FORK[-1].release(),
                            after_in_child=lambda: _AT_FORK[-1].release())
    _AT_FORK[:] = [lock]


class ProgressBar:
    """Frames checked so far, on stderr (tqdm): shown once a run takes over `delay`
    seconds, then redrawn every TICK_S, also while no frame arrives (a slow
    decompression, the rules after the read): its clock runs, so a long check never
    looks hung. Cleared when the run ends."""

    TICK_S = 0.5

    def __init__(self, inputs: int, file: IO[str] | None = None, delay: float = 1.0) -> None:
        from tqdm import tqdm

        class Bar(tqdm):  # type: ignore[misc]
            monitor_interval = 0  # no tqdm monitor thread: the ticker below redraws

        # miniters=0: every update may redraw (no more often than TICK_S), update(0) too
        self._bar = Bar(unit=" frames", unit_scale=True, file=file or sys.stderr,
                         leave=False, delay=delay, mininterval=self.TICK_S, miniters=0,
                         dynamic_ncols=True,
                         bar_format="{desc}{n_fmt} frames [{elapsed}, {rate_fmt}]")
        self._inputs = inputs
        self._started = 0
        self._lock = threading.Lock()  # the bar's count is not thread-safe
        self._stop = threading.Event()
        self._ticker = threading.Thread(target=self._tick, name=PROGRESS_THREAD,
                                        daemon=True)
        _pause_at_fork(self._lock)
        self._ticker.start()

    def _tick(self) -> None:
        while not self._stop.wait(self.TICK_S):
            with self._lock:
                self._bar.update(0)

    def start_input(self, path: str) -> None:
        with self._lock:
            self._started += 1
            self._bar.set_description(f"[{self._started}/{self._inputs}] {Path(path).name}",
                                      refresh=False)

    def frames(self, n: int) -> None:
        with self._lock:
            self._bar.update(n)

    def close(self) -> None:
        self._stop.set()
        self._ticker.join()
        with self._lock:
            self._bar.close()
