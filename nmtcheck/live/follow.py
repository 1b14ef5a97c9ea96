"""`nmtcheck check --follow -`: standard input read as it arrives (`candump -L can0 |
nmtcheck check --follow -`), live findings on stderr the moment they happen, and at the
end of the stream (or Ctrl-C) exactly `nmtcheck check` over the bytes received.

stdout stays `check`'s report (so `--format json` stays JSON); the live lines and the
node table go to stderr. Every byte read is recorded to a temporary file, which the final
check reads with the same format detection as `check -`.
"""

from __future__ import annotations

import os
import sys
import threading
from collections.abc import Iterator
from typing import IO, Any

from nmtcheck.engine import InputResult
from nmtcheck.errors import InputError
from nmtcheck.live.display import Display
from nmtcheck.live.frames import LiveFrame
from nmtcheck.live.session import Session
from nmtcheck.live.tracker import LiveFinding
from nmtcheck.profiles import Profile
from nmtcheck.readers import READ_PIECE, InputStats, split_lines
from nmtcheck.readers.candump import _parse_line, sniff


def follow(stream: IO[bytes] | None, profile: Profile, rules: list[Any], network: Any = None,
           input_format: str | None = None, strict: bool = False, channel: str | None = None,
           max_findings: int = 0, display: Display | None = None) -> list[InputResult]:
    """Follow `stream` (standard input when None) to its end or Ctrl-C; the results of
    `check` over everything read, as `check_inputs` returns them."""
    from nmtcheck.live.command import live_summary
    from nmtcheck.live.signals import ended_by, ending_on_signals

    lines = _input_lines(stream)
    display = display or Display(sys.stderr)
    session: Session | None = None

    def shown(lf: LiveFinding) -> None:
        display.start = session.start if session is not None else None
        display.finding(lf)

    session = Session(profile, rules, network, None, shown, input_format=input_format,
                      channel=channel, strict=strict, max_findings=max_findings,
                      on_withdraw=display.withdrawn, name="<stdin>")
    stats = InputStats("<stdin>")
    live: list[bool | None] = [None if input_format in (None, "candump") else False]
    done = threading.Event()
    failure: list[BaseException] = []

    def read() -> None:
        """Standard input, line by line as it arrives, into the session."""
        try:
            for lineno, raw in enumerate(lines, 1):
                if done.is_set():
                    return
                session.feed(_live_frame(raw, lineno, stats, live, display), raw)
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
        raise InputError("<stdin>", f"cannot read: {failure[0]}")
    display.close()
    try:
        outcome = session.close()
    except InputError as exc:  # the same message as `check -` on these bytes
        raise InputError("<stdin>", exc.message, exc.line) from None
    if outcome.result is None:
        raise InputError("<stdin>", f"no frame received ({ended})")
    display.note(live_summary(outcome, ended))
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


def follow_logs(logs: tuple[str, ...], profile: Profile, rules: list[Any], **options: Any
                ) -> list[InputResult]:
    """`check --follow LOGS`: LOGS must be `-` alone (a file does not grow here)."""
    from nmtcheck.errors import UsageError

    if tuple(logs) != ("-",):
        raise UsageError("--follow reads standard input as it arrives: "
                         "nmtcheck check --follow -")
    return follow(None, profile, rules, **options)
