"""The `nmtcheck` command: the group, one module per subcommand (check.py, timeline.py,
rules.py, monitor.py, fleet.py) registered on it, and the entry point that turns every
error into one line and exit code 2, never a traceback (unless --debug).

Exit codes: 0 no finding at or above --fail-on, 1 at least one, 2 usage or
input error (one line on stderr, never a traceback unless --debug).
"""

from __future__ import annotations

# First of all: `check --results` starts the fleet's fork server here, so that its imports
# run beside this module's (does nothing for any other command). It also asks numpy's BLAS
# for one thread, which only works before numpy is imported.
import nmtcheck.fleet.prestart  # noqa: F401

# isort: split
import contextlib
import logging
import os
import signal
import sys
import tempfile
import traceback

import click

from nmtcheck import __version__
from nmtcheck.cli.check import FleetGroupedCommand, ProgressBar, check
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
from nmtcheck.cli.fleet import fleet
from nmtcheck.cli.inputs import expand_inputs, expand_logs, is_log
from nmtcheck.cli.monitor import monitor
from nmtcheck.cli.rules import rule_doc, rule_table, rules_cmd
from nmtcheck.cli.timeline import render_timeline, render_timelines, timeline
from nmtcheck.errors import NmtcheckError
from nmtcheck.safe_text import error_line

# The names scripts and tests take from here (`from nmtcheck.cli.main import write_reports`)
# stay importable, wherever they are defined.
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
    "command",
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


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="nmtcheck")
@click.option("--debug", is_flag=True, hidden=True, help="Show tracebacks.")
@click.pass_context
def cli(ctx: click.Context, debug: bool) -> None:
    """Check recorded CAN logs against CANopen NMT (CiA 301)."""
    ctx.obj = {"debug": debug}


for _subcommand in (check, timeline, rules_cmd, fleet, monitor):
    cli.add_command(_subcommand)


class Terminated(BaseException):
    """SIGTERM, SIGHUP or SIGINT as an exception, so that `finally` blocks and the temporary
    directories' finalizers run (CI cancellation sends SIGTERM)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


def _raise_terminated(signum: int, _frame: object) -> None:
    raise Terminated(signum)


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
    except click.UsageError as exc:
        if _is_help(exc):  # bare `nmtcheck`, `nmtcheck fleet`:
            exc.show()  # the usage and help as click prints them (stderr, exit 2)
        else:  # one line: a name in it is the user's text, shown, never acted on
            click.echo(error_line(f"nmtcheck: {exc.format_message()}"), err=True)
        sys.exit(EXIT_ERROR)
    except click.ClickException as exc:
        click.echo(error_line(f"nmtcheck: {exc.format_message()}"), err=True)
        sys.exit(EXIT_ERROR)
    except NmtcheckError as exc:
        click.echo(error_line(f"nmtcheck: {exc}"), err=True)
        sys.exit(EXIT_ERROR)
    except BrokenPipeError:
        sys.exit(EXIT_OK)
    except Exception as exc:  # noqa: BLE001 - a CI gate must fail cleanly
        if debug:
            traceback.print_exc()
        click.echo(error_line(f"nmtcheck: internal error: {type(exc).__name__}: {exc} "
                                   f"(please report; --debug shows the traceback)"), err=True)
        sys.exit(EXIT_ERROR)


def _is_help(exc: click.UsageError) -> bool:
    """Whether `exc` is a group's help for a call without a subcommand (click 8.2's
    NoArgsIsHelpError, whose message is the help text: click's own words, no user's;
    older clicks print that help themselves and exit 0)."""
    no_args = getattr(click.exceptions, "NoArgsIsHelpError", None)
    return no_args is not None and isinstance(exc, no_args)


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
