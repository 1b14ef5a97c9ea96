"""Vector ASC (ASCII) logs as written by CANoe/CANalyzer and python-can's ASCWriter.

Handles `base hex|dec`, `timestamps absolute|relative` (relative: each stamp
is the delta from the previous event), trigger blocks present, absent or
repeated, classic `d`/`r` lines, `ErrorFrame`, `CANFD` lines (the flags field
says whether a frame is FD and whether it is remote), channels above 9,
cp1252 text and CRLF. Timestamps stay as written: seconds since the start of
measurement, as CANoe shows them.

Where python-can's ASCReader differs, this reader follows the file: `TxRq`
lines are transmit requests, not bus frames; relative timestamps are
accumulated; channels keep their 1-based number; a CANFD line with data
length 0 is remote only if its flags say so.
"""

from __future__ import annotations

import re
from collections.abc import Iterator

from nmtcheck.frames import BatchBuilder, FrameBatch
from nmtcheck.readers import InputStats, Source, account, is_text

FLAG_REMOTE = 0x10  # <MessageFlags> bit 4
FLAG_EDL = 0x1000  # bit 12: an FD frame
_NON_FRAME_AFTER_CHANNEL = {b"statistic:", b"j1939tp", b"status:", b"overloadframe"}


class _Bad(Exception):
    """A frame-like line that does not parse."""


def _num(tok: bytes, base: int) -> int:
    try:
        return int(tok, base)
    except ValueError:
        raise _Bad(f"{tok.decode('latin-1')!r} is not a number") from None


def _data(tokens: list[bytes], n: int, base: int) -> bytes:
    if len(tokens) < n:
        raise _Bad(f"expected {n} data bytes, found {len(tokens)}")
    values = [_num(t, base) for t in tokens[:n]]
    if any(v > 0xFF for v in values):
        raise _Bad("data byte above FFh")
    return bytes(values)


def _can_id(tok: bytes, base: int) -> tuple[int, bool]:
    ext = tok[-1:] in (b"x", b"X")
    value = _num(tok[:-1] if ext else tok, base)
    if value > (0x1FFFFFFF if ext else 0x7FF):
        raise _Bad("CAN-ID out of range")
    return value, ext


_HEADER = re.compile(rb"^\s*(date\s|base\s+(hex|dec)|Begin Triggerblock|// version)", re.I)
_EVENT = re.compile(rb"^\s*\d+\.\d+\s+(\d+|CANFD)\s+")


def sniff(head: bytes) -> bool:
    """An ASC log starts with its `date`/`base`/trigger-block header or with event lines."""
    if not is_text(head):
        return False
    for raw in head.splitlines()[:50]:
        line = raw.strip()
        if line:
            return _HEADER.match(line) is not None or _EVENT.match(line) is not None
    return False


def read(source: Source, stats: InputStats) -> Iterator[FrameBatch]:
    builder = BatchBuilder()
    base = 16
    relative = False
    clock = 0.0  # running sum of deltas in relative mode
    for lineno, raw in enumerate(source.lines(), 1):
        tokens = raw.split()
        if not tokens:
            continue
        first = tokens[0].lower()
        if first in (b"date", b"//") or first.startswith(b"//"):
            continue
        if first == b"base":
            base = 10 if len(tokens) > 1 and tokens[1].lower() == b"dec" else 16
            relative = b"relative" in raw.lower()
            continue
        if first in (b"internal", b"no") and b"events" in raw.lower():
            continue
        if first in (b"begin", b"end") and len(tokens) > 1 and tokens[1].lower() == b"triggerblock":
            clock = 0.0
            continue
        try:
            stamp = float(tokens[0])
        except ValueError:
            stats.skip(lineno, "line does not start with a timestamp")
            continue
        if stamp != stamp or stamp in (float("inf"), float("-inf")):
            stats.skip(lineno, "timestamp is not a finite number")
            continue
        if relative:
            clock += stamp
            ts = clock
        else:
            ts = stamp
        if len(tokens) < 3:
            stats.skip(lineno, "event without content")
            continue
        kind = tokens[1]
        try:
            if kind == b"CANFD":
                frame = _fd_frame(tokens, base)
            elif kind.isdigit():
                if tokens[2].lower() in _NON_FRAME_AFTER_CHANNEL:
                    stats.ignored += 1
                    continue
                frame = _classic_frame(tokens, base)
            else:  # chip status, start of measurement, other buses, system variables…
                stats.ignored += 1
                continue
        except _Bad as exc:
            stats.skip(lineno, str(exc))
            continue
        if frame is None:  # TxRq: a transmit request, never on the bus
            stats.ignored += 1
            continue
        chan_name, can_id, ext, rtr, err, fd, dlc, data = frame
        builder.add(ts, stats.channel_code(chan_name), can_id, ext=ext, rtr=rtr, err=err, fd=fd,
                    dlc=dlc, data=data, line=lineno)
        if builder.full and (batch := account(stats, builder.take())) is not None:
            yield batch
    if (batch := account(stats, builder.take())) is not None:
        yield batch


_Frame = tuple[str, int, bool, bool, bool, bool, int, bytes]


def _classic_frame(tokens: list[bytes], base: int) -> _Frame | None:
    """`<ts> <ch> <id>[x] Rx|Tx d <dlc> <bytes…>` / `… r [dlc]` / `<ts> <ch> ErrorFrame …`."""
    chan = str(int(tokens[1]))
    if tokens[2].lower() == b"errorframe":
        return chan, 0, False, False, True, False, 0, b""
    if len(tokens) < 5:
        raise _Bad("truncated frame line")
    can_id, ext = _can_id(tokens[2], base)
    direction = tokens[3]
    if direction == b"TxRq":
        return None
    if direction not in (b"Rx", b"Tx"):
        raise _Bad(f"unknown direction {direction.decode('latin-1')!r}")
    dtype = tokens[4].lower()
    if dtype == b"r":
        dlc = 0
        if len(tokens) > 5 and tokens[5].isalnum() and len(tokens[5]) == 1:
            dlc = _num(tokens[5], base)
        return chan, can_id, ext, True, False, False, dlc, b""
    if dtype != b"d" or len(tokens) < 6:
        raise _Bad("expected 'd <dlc>' or 'r'")
    dlc = _num(tokens[5], base)
    if dlc > 64:
        raise _Bad("DLC above 64")
    if dlc > 15:  # an FD frame written as a classic line: the field is its data length
        return chan, can_id, ext, False, False, True, dlc, _data(tokens[6:], dlc, base)[:8]
    data = _data(tokens[6:], min(dlc, 8), base)
    return chan, can_id, ext, False, False, False, dlc, data


def _fd_frame(tokens: list[bytes], base: int) -> _Frame | None:
    """`<ts> CANFD <ch> <dir> <id>[x] [name] <brs> <esi> <dlc> <len> <data…> <dur> <bits> <flags>`…

    None for a `TxRq` line (a transmit request, never on the bus).
    """
    if len(tokens) < 5:
        raise _Bad("truncated CANFD line")
    chan = str(_num(tokens[2], 10))
    if tokens[3] == b"TxRq":
        return None
    if tokens[4].lower() == b"errorframe":
        return chan, 0, False, False, True, True, 0, b""
    can_id, ext = _can_id(tokens[4], base)
    rest = tokens[5:]
    if len(rest) >= 2 and not (rest[0].isdigit() and rest[1].isdigit()):
        rest = rest[1:]  # symbolic message name
    if len(rest) < 4:
        raise _Bad("truncated CANFD line")
    data_length = _num(rest[3], 10)
    if data_length > 64:
        raise _Bad("CAN FD data length above 64")
    data = _data(rest[4:], data_length, base)
    trailer = rest[4 + data_length :]
    fd, rtr = True, False
    if len(trailer) >= 3:
        flags = _num(trailer[2], 16)
        fd = bool(flags & FLAG_EDL) or data_length > 8
        rtr = bool(flags & FLAG_REMOTE) and not fd and data_length == 0
    dlc = _num(rest[2], 16) if rtr else data_length
    return chan, can_id, ext, rtr, False, fd, dlc, data[:8]
