"""SocketCAN candump log format (`candump -l` / `-L`): `(ts) iface ID#DATA [R|T]`.

Covers remote frames (`ID#R`, `ID#R<len>`, `ID#R<len>_<dlc>`), 8-digit extended
IDs, error frames (CAN_ERR_FLAG 0x20000000 in the ID), CAN FD
(`ID##<flags><data>`), the raw-DLC suffix of `candump -8` (`ID#<8 bytes>_<dlc>`),
the optional direction flag, nanosecond timestamps and `DROPCOUNT:` lines. CAN XL
lines (`ID###…` of older can-utils, `<vcid><prio>#<flags>:<sdt>:<af>#<data>` of
newer ones) are well-formed records that are not CAN CC/FD frames: ignored.
"""

from __future__ import annotations

import re
from binascii import unhexlify
from collections.abc import Iterator

from nmtcheck.frames import BatchBuilder, FrameBatch
from nmtcheck.readers import InputStats, Source, account, is_text

CAN_ERR_FLAG = 0x20000000
CAN_EFF_MASK = 0x1FFFFFFF
_HEX_DIGITS = b"0123456789abcdefABCDEF"
_FAST = re.compile(  # a classic 11-bit data frame; everything else takes the general path
    rb"\(([0-9]{1,12}\.[0-9]{1,9})\) (\S+) ([0-9A-Fa-f]{3})#((?:[0-9A-Fa-f]{2}){0,8})"
    rb"(?: [RT])?\r?\n?")
_DROP = re.compile(rb"DROPCOUNT:\s*dropped\s+(\d+)")
_CANXL = re.compile(rb"[0-9A-Fa-f]{5}#[0-9A-Fa-f]{2}:[0-9A-Fa-f]{2}:[0-9A-Fa-f]{8}#[0-9A-Fa-f.]*$")


def _is_hex(b: bytes) -> bool:
    return bool(b) and not b.translate(None, _HEX_DIGITS)  # nothing left once hex is deleted


def _bad_raw_dlc(sep: bytes, raw_dlc: bytes) -> bool:
    """A `_<dlc>` suffix (len8_dlc, `candump -8`) must be one hex digit."""
    return bool(sep) and (len(raw_dlc) != 1 or not _is_hex(raw_dlc))


_SNIFF = re.compile(rb"^\s*\(\s*-?\d+(\.\d+)?\)\s+\S+\s+[0-9A-Fa-f]+##?")


def sniff(head: bytes) -> bool:
    """A candump log starts (within its first 50 lines) with a `(ts) iface ID#` line."""
    if not is_text(head):
        return False
    for raw in head.splitlines()[:50]:
        line = raw.strip()
        if line:
            return _SNIFF.match(line) is not None
    return False


def read(source: Source, stats: InputStats) -> Iterator[FrameBatch]:
    builder = BatchBuilder()
    add = builder.add
    chan_of: dict[bytes, int] = {}
    for lineno, raw in enumerate(source.lines(), 1):
        fast = _FAST.fullmatch(raw)
        if fast is not None:  # the common case: a classic 11-bit data frame
            iface = fast[2]
            chan = chan_of.get(iface)
            if chan is None:
                chan = chan_of[iface] = stats.channel_code(iface.decode("latin-1"))
            data = unhexlify(fast[4])
            add(float(fast[1]), chan, int(fast[3], 16), dlc=len(data), data=data, line=lineno)
            if builder.full and (batch := account(stats, builder.take())) is not None:
                yield batch
            continue
        parts = raw.split()
        if not parts:
            continue
        if parts[0].startswith(b"DROPCOUNT"):
            m = _DROP.search(raw)
            if m is None:
                stats.skip(lineno, "DROPCOUNT line without a count")
                continue
            stats.dropped += int(m.group(1))
            stats.ignored += 1
            continue
        if len(parts) < 3 or len(parts) > 4:
            stats.skip(lineno, "expected '(timestamp) interface ID#DATA'")
            continue
        tok_ts, iface, frame = parts[0], parts[1], parts[2]
        if len(parts) == 4 and parts[3] not in (b"R", b"T"):
            stats.skip(lineno, "unexpected text after the frame")
            continue
        if not (tok_ts.startswith(b"(") and tok_ts.endswith(b")")):
            stats.skip(lineno, "timestamp is not in parentheses")
            continue
        try:
            ts = float(tok_ts[1:-1])
        except ValueError:
            stats.skip(lineno, "timestamp is not a number")
            continue
        if ts != ts or ts in (float("inf"), float("-inf")):
            stats.skip(lineno, "timestamp is not a finite number")
            continue
        hash_pos = frame.find(b"#")
        if hash_pos == 5 and _CANXL.match(frame):
            stats.ignored += 1  # CAN XL frame: not CAN CC/FD traffic
            continue
        id_text = frame[:hash_pos]
        if hash_pos < 0 or len(id_text) not in (3, 8) or not _is_hex(id_text):
            stats.skip(lineno, "CAN-ID must be 3 or 8 hex digits followed by '#'")
            continue
        can_id = int(id_text, 16)
        ext = len(id_text) == 8
        rest = frame[hash_pos + 1 :]
        fd = rtr = err = False
        dlc = 0
        data = b""
        if rest.startswith(b"#"):  # CAN FD: ##<flags nibble><data>
            if rest.startswith(b"##"):
                stats.ignored += 1  # CAN XL frame: not CAN CC/FD traffic
                continue
            body = rest[2:]
            if len(rest) < 2 or not _is_hex(rest[1:2]) or len(body) % 2 or len(body) > 128 or (
                body and not _is_hex(body)
            ):
                stats.skip(lineno, "malformed CAN FD data")
                continue
            fd = True
            data = bytes.fromhex(body.decode())
            dlc = len(data)
        elif rest[:1] in (b"R", b"r"):
            rtr = True
            tail, sep, raw_dlc = rest[1:].partition(b"_")
            if (tail and not (len(tail) == 1 and b"0" <= tail <= b"8")) or _bad_raw_dlc(
                sep, raw_dlc
            ):
                stats.skip(lineno, "malformed remote frame length")
                continue
            dlc = int(tail) if tail else 0
        else:
            body, sep, raw_dlc = rest.partition(b"_")  # a len8_dlc suffix (`_9`): DLC > 8
            if len(body) % 2 or (body and not _is_hex(body)) or len(body) > 16 or _bad_raw_dlc(
                sep, raw_dlc
            ):
                stats.skip(lineno, "data must be 0..8 bytes of hex")
                continue
            data = bytes.fromhex(body.decode())
            dlc = len(data)
        if ext and can_id & CAN_ERR_FLAG:
            err = True
            ext = False
        can_id &= CAN_EFF_MASK
        if err:
            can_id &= ~CAN_ERR_FLAG & CAN_EFF_MASK
        chan = stats.channel_code(iface.decode("latin-1"))
        builder.add(ts, chan, can_id, ext=ext, rtr=rtr, err=err, fd=fd, dlc=dlc, data=data,
                    line=lineno)
        if builder.full and (batch := account(stats, builder.take())) is not None:
            yield batch
    if (batch := account(stats, builder.take())) is not None:
        yield batch
