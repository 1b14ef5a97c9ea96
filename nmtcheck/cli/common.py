"""What every command of the command line shares: the exit codes, the settings in force
(command line over configuration file: format, --fail-on, --select/--ignore, the rule
profile and the network) and the way reports are written (`-o` checked before the run,
written atomically; standard output errors as one line).

Its own module so that `nmtcheck check`/`timeline`/`rules` (cli.py), `nmtcheck monitor`
(cli/monitor.py) and `nmtcheck fleet` (cli/fleet.py) share them without importing
one another: cli.py registers the other two on its group, and they never import cli.py.
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING, NamedTuple

import click

from nmtcheck.engine import check_patterns
from nmtcheck.errors import UsageError
from nmtcheck.reporters import FORMATS
from nmtcheck.settings.config import Config, discover
from nmtcheck.settings.network import Network, load_network
from nmtcheck.settings.profiles import DEFAULT_PROFILE, Profile, derived_profile, load_profile
from nmtcheck.settings.values import quoted

if TYPE_CHECKING:
    from nmtcheck.reporters import Streamer
    from nmtcheck.results import InputResult

EXIT_OK, EXIT_FINDINGS, EXIT_ERROR = 0, 1, 2


def _split(values: tuple[str, ...]) -> list[str]:
    return [v.strip() for item in values for v in item.split(",") if v.strip()]


def load_profile_network(rules_profile: str | None, network_file: str | None,
                         dcf: tuple[str, ...] = (), config: Config | None = None
                         ) -> tuple[Profile, Network | None, dict[str, object]]:
    """The profile and network in force (the command line wins over the configuration
    file), and what the reports say about where they came from."""
    overrides: list[str] = []
    if rules_profile is not None or config is None:
        name = rules_profile or DEFAULT_PROFILE
        profile = load_profile(name)
    else:
        # The file's `rules` is resolved against its directory; its [rules.CODE] and
        # [timeline] tables form a profile that extends the one it names.
        name = config.profile or DEFAULT_PROFILE
        profile = derived_profile(config.label, name, config.directory, config.rule_tables,
                                  config.timeline)
        overrides = [*sorted(config.rule_tables), *(["timeline"] if config.timeline else [])]
    dcf_args: dict[int, str] = {}
    for item in dcf:
        node, sep, path = item.partition("=")
        if not sep or not node.strip().isdigit() or not path:
            raise UsageError(f"--dcf {item}: expected NODE=PATH, e.g. --dcf 3=node3.dcf")
        dcf_args[int(node)] = path
    if network_file is None and config is not None:
        network_file = config.network
    network = load_network(network_file, dcf_args) if network_file or dcf_args else None
    info: dict[str, object] = {"file": config.display() if config else None, "profile": name,
                               "overrides": overrides}
    return profile, network, info


class Settings(NamedTuple):
    """What `check` and `monitor` take from the command line, else the configuration."""

    config: Config | None
    fmt: str
    fail_on: str
    select: list[str]
    ignore: list[str]


def resolve_settings(config_file: str | None, isolated: bool, fmt: str | None,
                     fail_on: str | None, select: tuple[str, ...], ignore: tuple[str, ...]
                     ) -> Settings:
    """The command line wins over the configuration file; a bad value in the file is
    named with the file."""
    config = discover(config_file, isolated)
    if config is not None and config.format is not None and config.format not in FORMATS:
        raise UsageError(f"{config.label}: format: unknown format {quoted(config.format)} "
                         f"(available: {', '.join(FORMATS)})")
    if config is not None:
        check_patterns([] if select else config.select or [], f"{config.label}: select")
        check_patterns([] if ignore else config.ignore or [], f"{config.label}: ignore")
    return Settings(config, fmt or (config.format if config else None) or "text",
                    fail_on or (config.fail_on if config else None) or "error",
                    _split(select) if select else (config.select or [] if config else []),
                    _split(ignore) if ignore else (config.ignore or [] if config else []))


def check_outputs(outputs: Iterable[str]) -> None:
    """Every `-o` path can be written: its directory exists, and it is no directory."""
    for path in outputs:
        target = Path(path)
        parent = target.parent
        if not parent.is_dir():
            raise UsageError(f"--output {path}: the directory {str(parent)!r} does not exist")
        if target.is_dir():
            raise UsageError(f"--output {path}: is a directory")
        if not os.access(parent, os.W_OK | os.X_OK):
            raise UsageError(f"--output {path}: cannot write in {str(parent)!r}: "
                             "permission denied")


def write_atomically(path: Path, text: str | Iterable[str]) -> None:
    """Write a report beside its target and rename it into place: a full disk or a killed
    run never leaves a truncated report or destroys the previous one, and `-o link.json`
    replaces the link instead of writing through it into the file it points to."""
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent or ".")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            if isinstance(text, str):
                f.write(text)
            else:  # a report in pieces: it is never whole in memory
                f.writelines(text)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def write_reports(results: list[InputResult], files: list[tuple[str, Streamer]],
                  options: dict[str, object]) -> None:
    """Every `-o` report, each atomically; when one fails, the error says which were
    written before it."""
    written: list[str] = []
    for path, render in files:
        try:
            write_atomically(Path(path), render(results, options))
        except OSError as exc:
            done = f" (written: {', '.join(written)})" if written else " (none written)"
            raise UsageError(f"--output {path}: cannot write: {exc.strerror}{done}") from None
        written.append(path)


def write_stdout(chunks: Iterable[str], color: bool | None = None) -> None:
    """The report on standard output; a full disk or a closed device is an ordinary write
    error (one line, exit 2), not an internal one. `color`: keep the colour codes also
    when standard output is no terminal (`--color always`)."""
    try:
        for chunk in chunks:
            click.echo(chunk, nl=False, color=color)
    except BrokenPipeError:
        raise
    except OSError as exc:
        with contextlib.suppress(OSError):  # nothing more reaches it, not even at exit
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        raise UsageError(f"cannot write to standard output: {exc.strerror}") from None


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
