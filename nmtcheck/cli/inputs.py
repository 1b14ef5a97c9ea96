"""What the LOG arguments of `check` and `timeline` stand for: quoted globs expanded,
directories walked for the logs below them, URLs fetched into local copies (and named by
their URL again in every result), and the options both commands take to read them."""

from __future__ import annotations

import contextlib
import fnmatch
import glob
import os
import stat
from collections.abc import Callable, Iterator
from typing import Any, NamedTuple

import click

from nmtcheck.engine import check_inputs
from nmtcheck.errors import InputError, UsageError
from nmtcheck.readers import FORMATS as INPUT_FORMATS
from nmtcheck.readers import open_input
from nmtcheck.readers.opening import FRAME_LIKE
from nmtcheck.reporters.common import plural
from nmtcheck.results import InputResult


def input_options(f: Callable[..., Any]) -> Callable[..., Any]:
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


class Expanded(NamedTuple):
    """The LOG arguments as `expand_inputs` found them."""

    logs: tuple[str, ...]  # the inputs to check, in order
    not_logs: list[str]  # files below a directory that are no log: skipped, counted
    not_regular: list[str]  # of those, the FIFOs, sockets and devices: never opened


def expand_inputs(args: tuple[str, ...]) -> Expanded:
    """The LOG arguments as files (`expand_logs`), a directory standing for every log below
    it, recursively, in name order (as ruff takes a directory); and the files below those
    directories that are no log: skipped and counted, not errors (SPEC §4). A file there
    whose name carries a log suffix (LOG_SUFFIXES) is an input whatever its content, so an
    empty or damaged recording is an unreadable input, never passed over. Only regular
    files are read (a FIFO, a socket or a device below a directory is named and skipped,
    never opened), each real file once however many links reach it. Hidden files and
    directories (`.git`) are not looked at."""
    out: list[str] = []
    not_logs: list[str] = []
    not_regular: list[str] = []
    seen: set[tuple[int, int]] = set()  # (device, inode) of every file taken
    matched_special: list[str] = []  # FIFOs, sockets, devices a pattern matched
    expanded = expand_logs(args, matched_special)
    not_logs += matched_special
    not_regular += matched_special
    for arg in expanded:
        if arg == "-" or not os.path.isdir(arg):
            out.append(arg)
            with contextlib.suppress(OSError):
                st = os.stat(arg)
                seen.add((st.st_dev, st.st_ino))
            continue
        found = []
        for root, dirs, names in os.walk(arg):
            dirs[:] = sorted(d for d in dirs if not d.startswith("."))
            found += [os.path.join(root, n) for n in sorted(names) if not n.startswith(".")]
        logs: list[str] = []
        for path in found:
            try:
                st = os.stat(path)
            except OSError:  # a link to nothing, a file gone since: checking it names why
                logs.append(path)
                continue
            if not stat.S_ISREG(st.st_mode):  # opening a FIFO would wait for a writer
                not_logs.append(path)
                not_regular.append(path)
            elif (st.st_dev, st.st_ino) in seen:  # a hard or symbolic link to a file taken
                continue
            elif is_log(path):
                seen.add((st.st_dev, st.st_ino))
                logs.append(path)
            else:
                not_logs.append(path)
        if not logs:
            raise UsageError(f"{arg}: no log file below this directory"
                             + (f" ({plural(len(found), 'file')} whose content is no log "
                                "format)" if found else ""))
        out += logs
    return Expanded(tuple(out), not_logs, not_regular)


# Suffixes of the files that candump and the other recorders nmtcheck reads write (SPEC
# §4): a file below a directory named so whose content is no log format is a damaged or
# empty recording (a cut-off .blf, a 0-byte .mf4, `candump -l`'s .log killed before its
# first frame), not some other file, and checking it fails the gate. `.txt` is left to the
# content: a log when a line of it looks like a CAN frame (README.txt is no log).
LOG_SUFFIXES = tuple(suffix + packed
                     for suffix in (".log", ".asc", ".blf", ".mf4", ".trc", ".mcap", ".pcap",
                                    ".pcapng", ".csv")
                     for packed in ("", ".gz", ".bz2", ".xz", ".zst"))
TEXT_SUFFIXES = tuple(".txt" + packed for packed in ("", ".gz", ".bz2", ".xz", ".zst"))


def is_log(path: str) -> bool:
    """Whether `path` is an input below a directory: its content is a log format nmtcheck
    reads (detected from the first bytes, as `check` does), or its name carries a log
    suffix (LOG_SUFFIXES), or it is a `.txt` with a line that looks like a CAN frame. A
    file that cannot be opened counts as a log: checking it names the reason."""
    name = path.lower()
    if name.endswith(LOG_SUFFIXES):
        return True
    try:
        opened = open_input(path)
    except InputError as exc:
        if name.endswith(TEXT_SUFFIXES) and FRAME_LIKE in exc.message:
            return True
        return not exc.message.startswith(("unknown log format", "empty file"))
    opened.batches.close()
    return True


def expand_logs(logs: tuple[str, ...], not_regular: list[str] | None = None
                ) -> tuple[str, ...]:
    """LOG arguments with the glob patterns the shell left alone (quoted, or from a CI
    config) expanded, sorted; a pattern's matches are the regular files it names (a FIFO,
    a socket or a device it matches is added to `not_regular`, never opened), each real
    file once. `**` walks each real directory once, so a symbolic link loop below it
    costs one visit, not an expansion that doubles with each loop. `-` (standard input)
    may come once."""
    out: list[str] = []
    for arg in logs:
        if arg == "-" or os.path.lexists(arg) or not glob.has_magic(arg):
            out.append(arg)
            continue
        seen: set[tuple[int, int]] = set()
        matches = []
        for path in sorted(_glob(arg)):
            try:
                st = os.stat(path)
            except OSError:  # gone since: checking it names why
                matches.append(path)
                continue
            if stat.S_ISDIR(st.st_mode) or (st.st_dev, st.st_ino) in seen:
                continue
            seen.add((st.st_dev, st.st_ino))
            if stat.S_ISREG(st.st_mode):
                matches.append(path)
            elif not_regular is not None:
                not_regular.append(path)
        if not matches:
            raise UsageError(f"{arg}: no log file matches this pattern" + (
                f" (it matches {plural(len(seen), 'file')}, none of them a regular file: a "
                "FIFO, a socket or a device)" if seen else ""))
        out.extend(matches)
    if out.count("-") > 1:
        raise UsageError("-: standard input can be read only once")
    return tuple(out)


def _glob(pattern: str) -> list[str]:
    """What `glob.glob(pattern, recursive=True)` matches, with `**` walked by `_walk`
    (each real directory once) instead of following every path through a loop."""
    if "**" not in pattern:
        return glob.glob(pattern)
    parts = pattern.split(os.sep)
    fixed = 0
    while fixed < len(parts) - 1 and not glob.has_magic(parts[fixed]):
        fixed += 1
    prefix = os.sep.join(parts[:fixed]) or (os.sep if fixed else "")  # '/**/x': from /
    rest: list[str] = []
    for part in parts[fixed:]:  # 'a//b' is 'a/b', '**/**' is '**'
        if part and not (part == "**" and rest[-1:] == ["**"]):
            rest.append(part)
    hidden = any(part.startswith(".") for part in rest)  # else no hidden name can match
    return [path for path, rel in _walk(prefix or os.curdir, prefix, hidden)
            if _matches(tuple(rel), tuple(rest))]


def _walk(root: str, shown: str, hidden: bool) -> Iterator[tuple[str, list[str]]]:
    """Every entry below `root` (its path as `shown` + the names, and those names), hidden
    ones only if `hidden`; each real directory entered once, however many links reach
    it."""
    visited: set[tuple[int, int]] = set()
    todo: list[tuple[str, str, list[str]]] = [(root, shown, [])]
    while todo:
        where, named, rel = todo.pop()
        try:
            st = os.stat(where)
            if (st.st_dev, st.st_ino) in visited:
                continue
            visited.add((st.st_dev, st.st_ino))
            entries = sorted(os.scandir(where), key=lambda e: e.name)
        except OSError:  # unreadable, gone: glob skips it too
            continue
        below = []
        for entry in entries:
            if entry.name.startswith(".") and not hidden:
                continue
            path = os.path.join(named, entry.name) if named else entry.name
            yield path, [*rel, entry.name]
            with contextlib.suppress(OSError):
                if entry.is_dir():  # a link to a directory too: entered once, as any
                    below.append((entry.path, path, [*rel, entry.name]))
        todo.extend(reversed(below))


def _matches(names: tuple[str, ...], parts: tuple[str, ...]) -> bool:
    """Whether the path `names` matches the pattern `parts`, `**` standing for any number
    of names (none included), each other part for one name (fnmatch); a hidden name is
    matched only by a part that starts with a dot, as glob has it."""
    if not parts:
        return not names
    if parts[0] == "**":
        return _matches(names, parts[1:]) or (
            bool(names) and not names[0].startswith(".") and _matches(names[1:], parts))
    return (bool(names) and (parts[0].startswith(".") or not names[0].startswith("."))
            and fnmatch.fnmatchcase(names[0], parts[0]) and _matches(names[1:], parts[1:]))
