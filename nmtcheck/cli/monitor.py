"""`nmtcheck monitor`: check a live python-can bus; findings as they happen, then the
reports of `nmtcheck check` over the session's recording.

The session ends on Ctrl-C (or SIGTERM/SIGHUP), `--duration`, or a bus error; each way
the summary and every `-o` report are written. The exit code is `check`'s on the
recording (0/1 by --fail-on), or 2 after a bus error or when nothing was received.
"""

from __future__ import annotations

import sys
import threading
import time
from pathlib import Path
from typing import Any

import click

from nmtcheck.cli.common import (
    EXIT_ERROR,
    EXIT_FINDINGS,
    EXIT_OK,
    load_profile_network,
    resolve_settings,
    write_reports,
    write_stdout,
)
from nmtcheck.engine import select_rules
from nmtcheck.errors import NmtcheckError, UsageError
from nmtcheck.live.display import Display, live_summary
from nmtcheck.live.session import Outcome, Session, check_record
from nmtcheck.live.tracker import LiveFinding
from nmtcheck.reporters import FORMATS, auto_format, format_for_path, streamer
from nmtcheck.results import MAX_FINDINGS_PER_RULE, summary
from nmtcheck.safe_text import escape_controls

REFRESH_S = 0.25  # node table redraws
HUMAN_FORMATS = ("text", "concise", "markdown")


@click.command(short_help="Check a live CAN bus: findings as they happen.")
@click.option("-i", "--interface", default=None,
              help="python-can interface: socketcan, pcan, kvaser, vector, ixxat, slcan, "
                   "gs_usb, virtual, ... [default: python-can's configuration].")
@click.option("-c", "--channel", "channels", multiple=True,
              help="Channel (can0, PCAN_USBBUS1, ...). Repeatable: each channel is its own "
                   "CANopen network.")
@click.option("-b", "--bitrate", type=int, default=None, help="Bit rate (interfaces that set it).")
@click.option("--fd", is_flag=True, help="CAN FD.")
@click.option("--data-bitrate", type=int, default=None, help="CAN FD data-phase bit rate.")
@click.option("--bus-option", "bus_options", multiple=True, metavar="KEY=VALUE",
              help="Any other python-can bus argument (e.g. receive_own_messages=true, "
                   "serial=12345). Repeatable.")
@click.option("--record", default=None, metavar="FILE",
              help="Keep the session's frames in FILE, written as python-can's can.Logger "
                   "writes its suffix (.blf, .asc, .trc, .csv, .mf4, .db, .txt, any .gz); "
                   ".log or no suffix: a candump -L log (`nmtcheck check FILE` gives the "
                   "same findings).")
@click.option("--duration", type=click.FloatRange(min=0, min_open=True), default=None,
              help="End the session after this many seconds [default: until Ctrl-C].")
@click.option("--rules", "rules_profile", default=None,
              help="Rule profile: a name in rules/ or a TOML file.")
@click.option("--network", "network_file", default=None,
              help="Network description (TOML): expected nodes and their timing.")
@click.option("--dcf", multiple=True, metavar="NODE=PATH",
              help="EDS/DCF file of a node (adds it to the network). Repeatable.")
@click.option("--config", "config_file", default=None, metavar="FILE",
              help="Configuration file [default: found upward from the current directory].")
@click.option("--isolated", is_flag=True, help="Ignore every configuration file.")
@click.option("--select", multiple=True, help="Only these rules (codes, prefixes, names).")
@click.option("--ignore", multiple=True, help="Skip these rules (codes, prefixes, names).")
@click.option("--fail-on", type=click.Choice(["error", "warning", "info", "never"]),
              default=None, help="Exit 1 when a finding of this severity or higher exists "
                                 "[default: error].")
@click.option("--format", "fmt", default=None,
              help="Format of the final report on stdout (as `check --format`) [default: text].")
@click.option("-o", "--output", "outputs", multiple=True,
              help="Write a report of the session to PATH (format from the suffix). "
                   "Repeatable.")
@click.option("-q", "--quiet", is_flag=True, help="Only the findings and the verdict.")
def monitor(interface: str | None, channels: tuple[str, ...], bitrate: int | None, fd: bool,
            data_bitrate: int | None, bus_options: tuple[str, ...], record: str | None,
            duration: float | None, rules_profile: str | None, network_file: str | None,
            dcf: tuple[str, ...], config_file: str | None, isolated: bool,
            select: tuple[str, ...], ignore: tuple[str, ...], fail_on: str | None,
            fmt: str | None, outputs: tuple[str, ...], quiet: bool) -> None:
    """Check a live CAN bus (any python-can interface): findings the moment they happen,
    a node table on a terminal, the reports of `nmtcheck check` at the end."""
    from nmtcheck.live.bus import BusReader, close_buses, open_buses, parse_option

    config, fmt, fail_on, selected, ignored = resolve_settings(
        config_file, isolated, fmt, fail_on, select, ignore)
    if fmt not in FORMATS:
        raise UsageError(f"--format {fmt}: unknown format (available: {', '.join(FORMATS)})")
    profile, network, config_info = load_profile_network(rules_profile, network_file, dcf,
                                                         config)
    rules = select_rules(profile, selected, ignored)
    stdout_render = streamer(fmt)
    files = [(path, streamer(format_for_path(path))) for path in outputs]
    for option, path in [*(("--output", p) for p in outputs),
                         *([("--record", record)] if record else [])]:
        if not Path(path).parent.is_dir():  # fail before the session, not after an hour
            raise UsageError(f"{option} {path}: the directory does not exist")
    if record:
        check_record(record)  # a suffix no writer knows: before the session too
    options = dict(parse_option(item) for item in bus_options)
    buses = open_buses(interface, list(channels), bitrate, fd, data_bitrate, options)
    # the live lines share stdout with a report meant for people; next to a machine
    # format (json, csv, sarif, ...) they go to stderr and stdout stays parseable
    human = fmt in HUMAN_FORMATS or (fmt == "auto" and auto_format() == "text")
    display = Display(sys.stdout if human else sys.stderr)
    session: Session | None = None
    try:
        session = Session(profile, rules, network, record, _shown(display, lambda: session),
                          on_withdraw=display.withdrawn,
                          name=f"<live: {', '.join(name for name, _b in buses)}>",
                          on_overload=lambda n: display.note(
                              f"nmtcheck: falling behind: {n} frame(s) dropped so far (the "
                              "bus delivers faster than the checks run); every report "
                              "counts them (I004)"))
        outcome, error, ended = _run(session, buses, display, duration, BusReader)
    finally:
        close_buses(buses)
    report_options: dict[str, object] = {
        "fail_on": fail_on, "quiet": quiet,
        "rules": {r.code: profile[r.code].severity for r in rules},
        "network_notes": list(network.notes) if network else [],
        "max_findings": MAX_FINDINGS_PER_RULE, "config": config_info}
    code = finish(outcome, files, stdout_render, report_options, fail_on, ended,
                  f"no frame received on {', '.join(name for name, _b in buses)}")
    if error is not None:
        raise NmtcheckError(error)  # after the reports: what was seen is never lost
    raise SystemExit(code)


def _shown(display: Display, session: Any) -> Any:
    def show(lf: LiveFinding) -> None:
        s = session()
        display.start = s.start if s is not None else None
        display.finding(lf)
    return show


def _run(session: Session, buses: list[tuple[str, Any]], display: Display,
         duration: float | None, reader_class: Any) -> tuple[Outcome, str | None, str]:
    """Read until Ctrl-C, --duration or a bus error; then close the session."""
    from nmtcheck.live.signals import ended_by, ending_on_signals

    stop = threading.Event()
    readers = [reader_class(name, bus, session.submit, stop) for name, bus in buses]
    with ending_on_signals(stop) as signals:
        for r in readers:
            r.start()
        click.echo(escape_controls(
            f"nmtcheck: monitoring {', '.join(name for name, _b in buses)}; "
            f"{'--duration ' + format(duration, 'g') + ' s or ' if duration else ''}"
            f"Ctrl-C ends the session"), err=True)
        began = time.monotonic()
        timed_out = False
        while not stop.wait(REFRESH_S):
            display.refresh(session.nodes(), session.clock.now())
            if duration is not None and time.monotonic() - began >= duration:
                timed_out = True
                break
        stop.set()
        for r in readers:
            r.join(1.0)
        display.refresh(session.nodes(), session.clock.now())
        display.close()
        error = next((r.error for r in readers if r.error), None)
        ended = ended_by(signals, "duration" if timed_out else "bus error" if error else "end")
        return session.close(), error, ended


def finish(outcome: Outcome, files: list[tuple[str, Any]], stdout_render: Any,
           options: dict[str, object], fail_on: str, ended: str, nothing: str) -> int:
    """Write every report, print the final one and the live summary; the exit code is
    `check`'s on the recording."""
    from nmtcheck.checks.base import fails

    if outcome.result is None:
        click.echo(escape_controls(f"nmtcheck: {nothing} ({ended})"), err=True)
        return EXIT_ERROR
    results = [outcome.result]
    # stdout first: a report that cannot be written must not cost the session's verdict
    try:
        write_stdout(stdout_render(results, options))
    except UsageError as exc:  # e.g. a full disk: still write the reports, then exit 2
        click.echo(live_summary(outcome, ended), err=True)
        write_reports(results, files, options)
        raise exc
    click.echo(live_summary(outcome, ended), err=True)
    write_reports(results, files, options)
    return EXIT_FINDINGS if fails(summary(results), fail_on) else EXIT_OK
