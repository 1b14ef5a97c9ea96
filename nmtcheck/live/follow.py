"""`nmtcheck check --follow -`: standard input read as it arrives (`candump -L can0 |
nmtcheck check --follow -`), live findings on stderr the moment they happen, and at the
end of the stream (or Ctrl-C) exactly `nmtcheck check` over the bytes received.

`nmtcheck check --follow FILE` follows a growing file as `tail -F` does: from its first
byte, then what is appended, until Ctrl-C (or SIGTERM); a file truncated is read again
from its start, a file replaced (log rotation) is reopened by its name, and one removed
is waited for.

stdout stays `check`'s report (so `--format json` stays JSON); the live lines and the
node table go to stderr. Every byte read is recorded to a temporary file, which the final
check reads with the same format detection as `check -`.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
from collections.abc import Iterator
from typing import IO, Any

from nmtcheck.errors import InputError
from nmtcheck.live.display import Display
from nmtcheck.live.frames import LiveFrame
from nmtcheck.live.session import Session
from nmtcheck.live.tracker import LiveFinding
from nmtcheck.readers import READ_PIECE, InputStats, split_lines
from nmtcheck.readers.candump import _parse_line, sniff
from nmtcheck.results import InputResult
from nmtcheck.settings.profiles import Profile

FOLLOW_POLL_S = 0.1  # a followed file is looked at this often once its end is reached


def follow(stream: IO[bytes] | None, profile: Profile, rules: list[Any], network: Any = None,
           input_format: str | None = None, strict: bool = False, channel: str | None = None,
           max_findings: int = 0, display: Display | None = None,
           path: str | None = None) -> list[InputResult]:
    """Follow `stream` (standard input when None) to its end or Ctrl-C, or the file `path`
    as it grows (`tail -F`) until Ctrl-C; the results of `check` over everything read, as
    `check_inputs` returns them."""
    from nmtcheck.live.display import live_summary
    from nmtcheck.live.signals import ended_by, ending_on_signals

    name = path if path is not None else "<stdin>"
    done = threading.Event()
    lines = _input_lines(stream) if path is None else split_lines(_file_pieces(path, done))
    display = display or Display(sys.stderr)
    session: Session | None = None

    def shown(lf: LiveFinding) -> None:
        display.start = session.start if session is not None else None
        display.finding(lf)

    session = Session(profile, rules, network, None, shown, input_format=input_format,
                      channel=channel, strict=strict, max_findings=max_findings,
                      on_withdraw=display.withdrawn, name=name)
    stats = InputStats(name)
    live: list[bool | None] = [None if input_format in (None, "candump") else False]
    failure: list[BaseException] = []

    def read() -> None:
        """Standard input (or the followed file), line by line as it arrives, into the
        session."""
        try:
            for lineno, raw in enumerate(lines, 1):
                if done.is_set():
                    return
                lost = stats.dropped
                frame = _live_frame(raw, lineno, stats, live, display)
                if stats.dropped > lost:  # a DROPCOUNT line: a cause of what follows
                    session.frames_lost(stats.dropped - lost)
                session.feed(frame, raw)
        except Exception as exc:  # noqa: BLE001 - reported by the main thread
            failure.append(exc)
        finally:
            done.set()

    with ending_on_signals(done) as signals:
        reader = threading.Thread(target=read, name="nmtcheck-follow", daemon=True)
        reader.start()
        while not done.wait(0.25):
            pass
    ended = ended_by(signals, "end of the stream")
    if failure:
        if isinstance(failure[0], InputError):
            raise failure[0]
        raise InputError(name, f"cannot read: {failure[0]}")
    display.close()
    try:
        outcome = session.close()
    except InputError as exc:  # the same message as `check -` on these bytes
        raise InputError(name, exc.message, exc.line) from None
    if outcome.result is None:
        raise InputError(name, f"no frame received ({ended})")
    for line in live_summary(outcome, ended).split("\n"):  # each line escaped already
        display.note(line)
    return [outcome.result]


def _input_lines(stream: IO[bytes] | None) -> Iterator[bytes]:
    """The stream's lines (standard input's when None) as they arrive."""
    if stream is None:
        if sys.stdin is None:
            raise InputError("<stdin>", "no standard input to read")
        return _fd_lines(sys.stdin.fileno())
    read = getattr(stream, "read1", stream.read)  # what has arrived, not a full buffer
    return split_lines(iter(lambda: read(READ_PIECE), b""))


def _live_frame(raw: bytes, lineno: int, stats: InputStats, live: list[bool | None],
                display: Display) -> LiveFrame | None:
    """The frame of one line, if it is a candump -L frame; `live[0]`: whether the lines are
    candump -L lines (None until the first line that is not blank tells)."""
    if live[0] is None and raw.strip():
        live[0] = sniff(raw)
        if not live[0]:
            display.note("nmtcheck: live findings need candump -L lines; the "
                         "whole check runs at the end of the stream")
    row = _parse_line(raw, lineno, stats) if live[0] else None
    if row is None:
        return None
    ts, iface, cid, ext, rtr, err, fd, dlc, data = row
    return LiveFrame(ts, iface.decode("utf-8", "replace"), cid, ext, rtr, err, fd, dlc, data)


def _fd_lines(fd: int) -> Iterator[bytes]:
    """Lines of a file descriptor as they arrive (readers.split_lines: linear in a line's
    length, a line of MAX_LINE_BYTES or more one skipped record, never held whole).
    os.read, not sys.stdin.buffer: the reading thread may still wait in it when the
    process exits, and a buffered reader's lock held then is a fatal error at interpreter
    shutdown."""
    def pieces() -> Iterator[bytes]:
        while True:
            try:
                chunk = os.read(fd, READ_PIECE)
            except OSError as exc:
                raise InputError("<stdin>", f"cannot read: {exc.strerror or exc}") from None
            if not chunk:
                return
            yield chunk

    return split_lines(pieces())


def _file_pieces(path: str, done: threading.Event, poll: float = FOLLOW_POLL_S
                 ) -> Iterator[bytes]:
    """The bytes of the file `path` as it grows, until `done` is set, as `tail -F` follows
    a file: by its name. At its end it waits `poll` seconds and looks again: a file
    shorter than what was read (truncated) is read again from its start, another file
    under the name (rotated) is opened, a missing one is waited for. A line cut short by
    that is ended there, never joined with the next file's first line."""
    try:
        f: IO[bytes] | None = open(path, "rb")  # noqa: SIM115 - closed below
    except OSError as exc:
        raise InputError(path, f"cannot read: {exc.strerror or exc}") from None
    last = b"\n"
    try:
        while not done.is_set():
            if f is not None:
                chunk = f.read(READ_PIECE)
                if chunk:
                    last = chunk[-1:]
                    yield chunk
                    continue
            try:
                now = os.stat(path)
            except OSError:
                now = None
            if f is not None and now is not None and not os.path.samestat(
                    now, os.fstat(f.fileno())):
                f.close()  # rotated: everything the old file held has been read
                f = None
            if f is None and now is not None:
                with contextlib.suppress(OSError):
                    f = open(path, "rb")  # noqa: SIM115 - closed below
                if f is not None:
                    if last != b"\n":
                        last = b"\n"
                        yield b"\n"
                    continue
            elif f is not None and now is not None and now.st_size < f.tell():
                f.seek(0)  # truncated in place (`> file`, copytruncate)
                if last != b"\n":
                    last = b"\n"
                    yield b"\n"
                continue
            done.wait(poll)
    finally:
        if f is not None:
            f.close()


def follow_logs(logs: tuple[str, ...], profile: Profile, rules: list[Any], **options: Any
                ) -> list[InputResult]:
    """`check --follow LOG`: LOG is `-` (standard input to its end) or one file, followed
    as it grows (`tail -F`) until Ctrl-C."""
    from nmtcheck.errors import UsageError

    if len(logs) != 1:
        raise UsageError("--follow reads one log as it grows: a file (as tail -F follows "
                         "it) or - (standard input)")
    if logs[0] == "-":
        return follow(None, profile, rules, **options)
    if os.path.isdir(logs[0]):
        raise UsageError(f"--follow {logs[0]}: is a directory")
    return follow(None, profile, rules, path=logs[0], **options)
