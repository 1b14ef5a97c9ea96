"""The fleet's command line: the options `nmtcheck check` takes for a fleet run, and the
`nmtcheck fleet` group. Light to import (click only): `nmtcheck check` on local files without
`--results` never loads fsspec, pyarrow or pandas.
"""

from __future__ import annotations

import shlex
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from nmtcheck.cli.helptext import DocumentedCommand
from nmtcheck.errors import UsageError
from nmtcheck.safe_text import escape_controls

FLEET_OPTION_NAMES = ("results", "executor", "manifest", "storage_options", "path_pattern",
                      "force", "on_input_error")


def fleet_options(f: Callable[..., Any]) -> Callable[..., Any]:
    """The fleet options of `nmtcheck check`."""
    for opt in reversed([
        click.option("--results", default=None, metavar="DIR_OR_URL",
                     help="Fleet run: write every log's results to this Parquet dataset "
                          "(a directory or an fsspec URL such as s3://bucket/nmtcheck/); "
                          "LOG arguments may then be URLs and globs (s3://b/2026/**/*.MF4)."),
        click.option("--executor", default=None, metavar="SPEC",
                     help="With --results: local[:N] (default, a process pool), "
                          "dask-local[:N] (a Dask LocalCluster) or dask://HOST:PORT."),
        click.option("--manifest", default=None, metavar="FILE",
                     help="With --results: also check the logs listed in FILE, one URL per "
                          "line (or an S3 Inventory CSV), for listings too big to glob."),
        click.option("--storage-option", "storage_options", multiple=True, metavar="KEY=VALUE",
                     help="For URLs (LOG arguments such as s3://bucket/log.mf4, and "
                          "--results): an fsspec storage option (endpoint_url=..., "
                          "anon=true); credentials come from the environment. Repeatable."),
        click.option("--path-pattern", default=None, metavar="PATTERN",
                     help="With --results: read {device}, {session}, {split} from the end of "
                          "each log's path, e.g. '{device}/{session}/{split}.MF4'."),
        click.option("--force", is_flag=True,
                     help="With --results: check again the logs the dataset already has "
                          "(same content, nmtcheck version and profile)."),
        click.option("--on-input-error", type=click.Choice(["fail", "continue"]), default=None,
                     help="With --results: a log that cannot be read is an input_error row "
                          "and the run goes on; at the end 'fail' exits 2 naming it (an "
                          "unreadable log never passes), 'continue' lets --fail-on decide "
                          "over the logs that were read [default: fail]."),
    ]):
        f = opt(f)
    return f


def fleet_requested(options: dict[str, Any]) -> bool:
    """Any fleet option given (then --results is required); --storage-option alone is no
    fleet run: it may be for a LOG that is a URL."""
    given = [n for n in FLEET_OPTION_NAMES if options.get(n) and n != "storage_options"]
    if given and not options.get("results"):
        flag = "--" + given[0].replace("_", "-").removesuffix("s")
        raise UsageError(f"{flag} needs --results DIR_OR_URL (where the fleet's results go)")
    return bool(given)


def run_fleet_check(logs: tuple[str, ...], options: dict[str, Any], profile: Any,
                    rules: list[Any], network: Any, fail_on: str, *,
                    input_format: str | None, strict: bool, channel: str | None,
                    reader_options: dict[str, Any], max_findings: int, quiet: bool,
                    outputs: tuple[str, ...], statistics: bool) -> int:
    """`nmtcheck check --results ...`: the run, a summary on stdout, the exit code."""
    from nmtcheck.fleet.trace import mark

    mark("cli")  # the command line parsed, its imports and the profile done
    from nmtcheck.fleet.dataset import arrow_without_pandas
    from nmtcheck.fleet.run import FleetOptions, run_fleet
    from nmtcheck.fleet.storage import parse_storage_options

    ctx = click.get_current_context()
    fmt_given = ctx.params.get("fmt")
    executor = options.get("executor")
    if ctx.get_parameter_source("jobs") == click.core.ParameterSource.COMMANDLINE:
        if executor:
            raise UsageError("-j/--jobs does not go with --executor (use --executor local:N)")
        executor = f"local:{ctx.params['jobs']}" if ctx.params.get("jobs") else "local"
    conflicting = [name for name, given in (("--output", outputs), ("--format", fmt_given),
                                            ("--statistics", statistics)) if given]
    if conflicting:
        raise UsageError(f"{conflicting[0]} does not go with --results: a fleet run writes a "
                         "dataset; report on it with 'nmtcheck fleet summary RESULTS'")
    if not logs and not options.get("manifest"):
        raise UsageError("nothing to check: give LOG arguments (paths, URLs, globs) or "
                         "--manifest FILE")
    if "-" in logs:
        raise UsageError("-: standard input cannot be part of a fleet run")
    opts = FleetOptions(
        sources=list(logs), results=options["results"], manifest=options.get("manifest"),
        executor=executor or "local",
        storage_options=parse_storage_options(options.get("storage_options") or ()),
        path_pattern=options.get("path_pattern"), force=bool(options.get("force")),
        progress=sys.stderr.isatty() and not quiet)
    import logging
    import warnings

    # Dask's client logs each worker it loses; the run's own summary names the logs concerned.
    logging.getLogger("distributed").setLevel(logging.ERROR)
    arrow_without_pandas()  # this process hands pyarrow no DataFrame: 0.3-0.5 s less start-up
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = run_fleet(opts, profile, [r.code for r in rules], network, input_format,
                        strict, channel, reader_options, max_findings)
    for w in caught:
        # nmtcheck's own, and Dask's client/scheduler/worker version check ("Mismatched
        # versions found"); Dask's other chatter (a dashboard port in use) is left out
        if issubclass(w.category, UserWarning) and (
                "nmtcheck" in str(w.filename) or "ismatched versions" in str(w.message)):
            click.echo(escape_controls(f"nmtcheck: warning: {w.message}"), err=True)
    click.echo(render_outcome(out, opts.results, quiet))
    mark("reported")
    from nmtcheck.fleet.prestart import is_command

    if is_command(sys.argv[0]):  # the process ends next (not a program that called this)
        import gc

        gc.freeze()  # its last collections need not walk numpy's and pyarrow's objects: 30 ms
    failed = [(u, e) for u, e in out.errors]
    bad = sum(out.status.get(s, 0) + out.skipped_status.get(s, 0)
              for s in ("input_error", "crashed"))
    if options.get("on_input_error") != "continue" and bad:
        url, err = failed[0] if failed else ("", "")
        more = f" (and {bad - 1} more)" if bad > 1 else ""
        click.echo(escape_controls(
            f"nmtcheck: {err if err.startswith(url) else f'{url}: {err}'}{more}"), err=True)
        return 2
    from nmtcheck.checks.base import fails

    return 1 if fails(out.severity, fail_on) else 0


def render_outcome(out: Any, results: str, quiet: bool) -> str:
    from nmtcheck.fleet.run import _size

    status = ", ".join(f"{k} {v}" for k, v in out.status.items())
    lines = [f"{out.files} logs: {out.checked} checked ({_size(out.bytes)}, {status}), "
             f"{out.skipped} already in the results"]
    if not quiet:
        for url, err in out.errors:
            lines.append(f"  {err if err.startswith(url) else f'{url}: {err}'}")
        if out.checked:
            lines.append(f"results: {results} (run {out.run_id}, {out.executor}, "
                         f"{out.seconds:.1f} s)")
        else:
            lines.append(f"results: {results} (nothing new to check: no run recorded)")
    sev = out.severity
    lines.append(f"fleet: {sev['error']} errors, {sev['warning']} warnings, {sev['info']} info")
    if not quiet:  # what to run next: the report over the whole dataset
        lines.append(f"next: nmtcheck fleet summary {shlex.quote(results)}")
    return "\n".join(lines)


@click.group(name="fleet", short_help="Report on a fleet's results dataset.")
def fleet() -> None:
    """Report on a fleet's results dataset (written by `nmtcheck check --results`)."""


@fleet.command(name="summary", cls=DocumentedCommand,
               arguments={"RESULTS": "The results dataset `nmtcheck check --results` wrote: "
                                     "a folder or a URL (s3://bucket/results)."},
               short_help="The fleet at a glance: worst devices and nodes per rule.")
@click.argument("results")
@click.option("-o", "--output", "outputs", multiple=True,
              help="Also write the summary to PATH (.html, .csv, .txt). Repeatable.")
@click.option("--format", "fmt", type=click.Choice(["text", "csv", "html"]), default="text",
              show_default=True, help="What goes to stdout.")
@click.option("--rule", "rules", multiple=True, help="Only these rule codes. Repeatable.")
@click.option("--top", type=click.IntRange(min=1), default=10, show_default=True,
              help="Devices and nodes listed per rule.")
@click.option("--all-checks", is_flag=True,
              help="Every check of every log, not only each log's latest.")
@click.option("--storage-option", "storage_options", multiple=True, metavar="KEY=VALUE",
              help="An fsspec storage option for RESULTS. Repeatable.")
def summary_cmd(results: str, outputs: tuple[str, ...], fmt: str, rules: tuple[str, ...],
                top: int, all_checks: bool, storage_options: tuple[str, ...]) -> None:
    """The fleet at a glance: worst devices and nodes per rule, findings over time and by
    nmtcheck version, logs that could not be checked."""
    from nmtcheck.fleet.storage import parse_storage_options
    from nmtcheck.fleet.summary import RENDERERS, summarise

    writers = []
    for path in outputs:
        suffix = Path(path).suffix.lower().lstrip(".")
        kind = {"htm": "html", "txt": "text"}.get(suffix, suffix)
        if kind not in RENDERERS:
            raise UsageError(f"--output {path}: unknown report type (use .html, .csv or .txt)")
        if not Path(path).parent.is_dir():
            raise UsageError(f"--output {path}: no such directory")
        writers.append((path, kind))
    s = summarise(results, parse_storage_options(storage_options),
                  [r.upper() for r in rules], top, latest_only=not all_checks)
    from nmtcheck.cli.common import write_atomically

    for path, kind in writers:
        try:
            write_atomically(Path(path), RENDERERS[kind](s))
        except OSError as exc:
            raise UsageError(f"--output {path}: cannot write: {exc.strerror}") from None
    click.echo(RENDERERS[fmt](s), nl=False)
