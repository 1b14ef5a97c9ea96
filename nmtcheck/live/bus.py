"""python-can buses for `nmtcheck monitor`: opened from the command line's options, read
by one thread each; a driver that is missing or a bus that fails is one line, never a
traceback."""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable
from typing import Any

from nmtcheck.errors import NmtcheckError
from nmtcheck.live.frames import LiveFrame, from_message

RECV_TIMEOUT_S = 0.1


class BusError(NmtcheckError):
    """A bus that cannot be opened or fails while it is read (exit 2)."""


def parse_option(item: str) -> tuple[str, Any]:
    """`--bus-option KEY=VALUE`: the value as int, float or bool when it reads as one."""
    key, sep, text = item.partition("=")
    if not sep or not key.strip():
        raise BusError(f"--bus-option {item}: expected KEY=VALUE, e.g. --bus-option "
                       f"receive_own_messages=true")
    value: Any = text
    if text.lower() in ("true", "false"):
        value = text.lower() == "true"
    else:
        for kind in (int, float):
            try:
                value = kind(text, 0) if kind is int else kind(text)
                break
            except ValueError:
                continue
    return key.strip(), value


def open_buses(interface: str | None, channels: list[str], bitrate: int | None, fd: bool,
               data_bitrate: int | None, options: dict[str, Any]) -> list[tuple[str, Any]]:
    """One python-can bus per channel (python-can's own configuration when no
    interface or channel is given), each with the name its frames are recorded under."""
    import logging

    import can

    # python-can's backends log warnings of their own on import and open (a missing
    # optional module, a clock note): the contract is one line on stderr, ours
    logging.getLogger("can").setLevel(logging.ERROR)
    kwargs: dict[str, Any] = dict(options)
    if interface is not None:
        kwargs["interface"] = interface
    if bitrate is not None:
        kwargs["bitrate"] = bitrate
    if fd:
        kwargs["fd"] = True
    if data_bitrate is not None:
        kwargs["data_bitrate"] = data_bitrate
    opened: list[tuple[str, Any]] = []
    wanted: list[str | None] = list(channels) or [None]
    for channel in wanted:
        where = f"--interface {interface or '(python-can configuration)'}" + (
            f" --channel {channel}" if channel is not None else "")
        try:
            bus = can.Bus(channel=channel, **kwargs) if channel is not None else can.Bus(**kwargs)
        except can.CanInterfaceNotImplementedError as exc:
            close_buses(opened)
            if interface is None:
                raise BusError("no --interface given, and no python-can configuration "
                               "names one (~/.canrc, can.ini or $CAN_INTERFACE)") from None
            raise BusError(f"{where}: interface not available (driver or python-can "
                           f"backend not installed?): {_one_line(exc)}") from None
        except Exception as exc:  # noqa: BLE001 - every backend raises its own kind
            close_buses(opened)
            raise BusError(f"{where}: cannot open the bus: {_one_line(exc)}") from None
        name = str(channel if channel is not None else getattr(bus, "channel_info", "") or "can0")
        opened.append((name, bus))
    return opened


def close_buses(buses: list[tuple[str, Any]]) -> None:
    for _name, bus in buses:
        with contextlib.suppress(Exception):
            bus.shutdown()


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if len(text) < 300 else text[:297] + "..."


class BusReader(threading.Thread):
    """Reads one bus until `stop` is set; a failure is kept in `error` and sets `stop`
    (the session then ends cleanly with what was seen)."""

    def __init__(self, name: str, bus: Any, feed: Callable[[LiveFrame], object],
                 stop: threading.Event) -> None:
        super().__init__(name=f"nmtcheck-bus-{name}", daemon=True)
        self.channel, self.bus, self.feed, self.stop = name, bus, feed, stop
        self.error: str | None = None

    def run(self) -> None:
        while not self.stop.is_set():
            try:
                msg = self.bus.recv(RECV_TIMEOUT_S)
            except Exception as exc:  # noqa: BLE001 - USB unplugged, driver error, ...
                if not self.stop.is_set():
                    self.error = f"{self.channel}: bus error: {_one_line(exc)}"
                    self.stop.set()
                return
            if msg is not None:
                self.feed(from_message(msg, self.channel)._replace(channel=self.channel))
