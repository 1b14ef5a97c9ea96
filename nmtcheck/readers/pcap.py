"""pcap and pcapng captures of SocketCAN traffic (tcpdump, Wireshark, scapy).

Link types: LINKTYPE_CAN_SOCKETCAN (227) and Linux cooked captures SLL (113)
and SLL2 (276) whose protocol is CAN (000Ch) or CAN FD (000Dh); CAN XL frames
and other protocols are counted as ignored.

The 4-byte CAN-ID field is big-endian by the link-type specification, but
some producers (scapy, older libpcap) store it little-endian, and cooked
captures store it in the capturing host's order. The order is chosen per
capture from its first packets: the one under which the IDs are plausible
(an 11-bit ID fits in 11 bits, an error frame has neither EFF nor RTR set).

Channels: a classic pcap file has one interface, named "0"; a pcapng
interface is named by its `if_name` option, else by its number; SLL2 packets
(captures on "any") are named `ifindex<N>` by the interface index they carry.
A frame sent by the capturing host can appear twice in a capture on a
virtual CAN interface (outgoing, then looped back); both copies are kept, as
in the file.
"""

from __future__ import annotations

import struct
from collections.abc import Generator, Iterator
from dataclasses import dataclass

import numpy as np

from nmtcheck.errors import InputError
from nmtcheck.readers.binary import (
    BatchCollector,
    ChannelNames,
    Frames,
    RecordRuns,
    split_seconds,
    strided_rows,
    zero_beyond,
)
from nmtcheck.readers.frames import FrameBatch
from nmtcheck.readers.source import Source
from nmtcheck.readers.stats import InputStats

LINKTYPE_CAN_SOCKETCAN = 227
LINKTYPE_LINUX_SLL = 113
LINKTYPE_LINUX_SLL2 = 276
CAN_LINKTYPES = (LINKTYPE_CAN_SOCKETCAN, LINKTYPE_LINUX_SLL, LINKTYPE_LINUX_SLL2)
ETH_P_CAN = 0x000C
ETH_P_CANFD = 0x000D
ETH_P_CANXL = 0x000E
CAN_EFF_FLAG = 0x80000000
CAN_RTR_FLAG = 0x40000000
CAN_ERR_FLAG = 0x20000000
CAN_EFF_MASK = 0x1FFFFFFF
CANFD_FDF = 0x04  # in the FD flags byte: set by newer kernels on every CAN FD frame
CANXL_XLF = 0x80  # where CAN CC/FD have the length byte: set on CAN XL frames
CANFD_MTU_PAYLOAD = 72  # a CAN FD frame as captured: 8-byte header + 64 data bytes

PCAP_MAGICS = {  # magic -> (byte order, ticks per second)
    b"\xd4\xc3\xb2\xa1": ("<", 10**6),
    b"\xa1\xb2\xc3\xd4": (">", 10**6),
    b"\x4d\x3c\xb2\xa1": ("<", 10**9),
    b"\xa1\xb2\x3c\x4d": (">", 10**9),
}
PCAPNG_SHB = b"\x0a\x0d\x0d\x0a"
PCAPNG_SHB_TYPE = 0x0A0D0D0A
PCAPNG_BOMS = {b"\x4d\x3c\x2b\x1a": "<", b"\x1a\x2b\x3c\x4d": ">"}
BLOCK_IDB = 1
BLOCK_PB = 2  # obsolete Packet Block
BLOCK_SPB = 3
BLOCK_EPB = 6
READ_BYTES = 4 << 20
MAX_PACKET = 1 << 18  # larger records mean a corrupt length field
COOKED_HEADER = {LINKTYPE_LINUX_SLL: 16, LINKTYPE_LINUX_SLL2: 20}


def sniff(head: bytes) -> bool:
    if head[:4] in PCAP_MAGICS:
        return True
    return head[:4] == PCAPNG_SHB and head[8:12] in PCAPNG_BOMS


def _plausible(raw_id: np.ndarray) -> np.ndarray:
    """CAN-ID fields (with SocketCAN flag bits) that make sense under one byte order."""
    eff = (raw_id & CAN_EFF_FLAG) != 0
    rtr = (raw_id & CAN_RTR_FLAG) != 0
    err = (raw_id & CAN_ERR_FLAG) != 0
    small = (raw_id & CAN_EFF_MASK) <= 0x7FF
    out: np.ndarray = (eff & ~err) | (~eff & small & ~(err & rtr))
    return out


DAMAGED_INTERFACE = -1  # the link type of an interface block that cannot be read
MAX_TICKS = 10**18  # if_tsresol finer than 1e-18 s: a damaged option (and beyond uint64 math)


@dataclass
class _Interface:
    linktype: int
    name: str
    ticks: int = 10**6  # timestamp units per second
    offset: int = 0  # if_tsoffset, seconds


class _Capture:
    """Decodes packets of one capture into frames; shared by pcap and pcapng."""

    def __init__(self, source: Source, stats: InputStats) -> None:
        self.source = source
        self.stats = stats
        self.out = BatchCollector(stats)
        self.big_endian_id: dict[bool, bool] = {}  # cooked? -> decided CAN-ID byte order
        self.names = ChannelNames(stats)

    def _id_order(self, cooked: bool, b: np.ndarray) -> bool:
        """Big-endian CAN-IDs? Decided once per encapsulation from the first CAN packets."""
        decided = self.big_endian_id.get(cooked)
        if decided is not None:
            return decided
        as_be = (b[:, 0].astype(np.uint32) << 24 | b[:, 1].astype(np.uint32) << 16
                 | b[:, 2].astype(np.uint32) << 8 | b[:, 3])
        as_le = (b[:, 3].astype(np.uint32) << 24 | b[:, 2].astype(np.uint32) << 16
                 | b[:, 1].astype(np.uint32) << 8 | b[:, 0])
        be_ok = int(np.count_nonzero(_plausible(as_be)))
        le_ok = int(np.count_nonzero(_plausible(as_le)))
        if be_ok == le_ok:  # no evidence yet: the link-type spec's network order, or the
            return not cooked  # capturing host's order for cooked captures (x86: little)
        self.big_endian_id[cooked] = be_ok > le_ok
        return be_ok > le_ok

    def decode(self, pkt: np.ndarray, caplen: np.ndarray, ts: np.ndarray, iface: _Interface,
               out: np.ndarray, frames: Frames) -> None:
        """Packets as rows of `pkt` (bytes past `caplen` are not theirs) -> frames at `out`."""
        n = len(out)
        link = iface.linktype
        hdr = COOKED_HEADER.get(link, 0)
        cooked = hdr > 0
        proto = np.full(n, ETH_P_CAN, np.int64)
        ifindex: np.ndarray | None = None
        if pkt.shape[1] < hdr + 16:  # short packets: zero columns, never read past caplen
            pkt = np.pad(pkt, ((0, 0), (0, hdr + 16 - pkt.shape[1])))
        if link == LINKTYPE_LINUX_SLL:
            proto = pkt[:, 14].astype(np.int64) << 8 | pkt[:, 15]
        elif link == LINKTYPE_LINUX_SLL2:
            proto = pkt[:, 0].astype(np.int64) << 8 | pkt[:, 1]
            ifindex = (pkt[:, 4].astype(np.int64) << 24 | pkt[:, 5].astype(np.int64) << 16
                       | pkt[:, 6].astype(np.int64) << 8 | pkt[:, 7])
        can = pkt[:, hdr:]
        length = can[:, 4].astype(np.int16)
        fd_flags = can[:, 5]
        is_can = (proto == ETH_P_CAN) | (proto == ETH_P_CANFD)
        xl = (proto == ETH_P_CANXL) | (is_can & ((can[:, 4] & CANXL_XLF) != 0))
        # other protocols of a cooked capture and CAN XL are not CAN CC/FD frames
        ignored = (caplen >= hdr) & (~is_can | xl)
        short = ~ignored & (caplen < hdr + 8)
        cand = ~ignored & ~short
        self.stats.ignored += int(np.count_nonzero(ignored))
        for _ in range(int(np.count_nonzero(short))):
            self.stats.skip(0, "packet shorter than a CAN frame header")
        if not cand.any():
            return
        b = can[:, :4].astype(np.uint32)
        if self._id_order(cooked, b[cand]):
            raw = b[:, 0] << 24 | b[:, 1] << 16 | b[:, 2] << 8 | b[:, 3]
        else:
            raw = b[:, 3] << 24 | b[:, 2] << 16 | b[:, 1] << 8 | b[:, 0]
        err = (raw & CAN_ERR_FLAG) != 0
        rtr = (raw & CAN_RTR_FLAG) != 0
        ext = ((raw & CAN_EFF_FLAG) != 0) & ~err
        can_id = raw & CAN_EFF_MASK
        fd = (proto == ETH_P_CANFD) | ((fd_flags & CANFD_FDF) != 0) | (length > 8) | (
            caplen - hdr == CANFD_MTU_PAYLOAD)
        available = caplen - hdr - 8
        reasons = (
            (length > 64, "CAN frame length above 64"),
            (~ext & ~err & (can_id > 0x7FF), "11-bit CAN-ID above 7FFh"),
            (~rtr & (available < length), "packet ends inside the CAN data"),
        )
        good = cand.copy()
        for bad, why in reasons:
            hit = good & bad
            for _ in range(int(np.count_nonzero(hit))):
                self.stats.skip(0, why)
            good &= ~hit
        rtr &= ~fd  # CAN FD has no remote frames; the flag bit means nothing there
        dlc = np.where(fd, length, np.minimum(length, 8)).astype(np.int16)
        data = np.array(can[:, 8:16])
        zero_beyond(data, np.where(rtr, 0, np.minimum(dlc, 8)))
        rows = out[good]
        if not len(rows):
            return
        if ifindex is None:
            frames.chan[rows] = self.names.provisional(iface.name)
        else:
            kept = ifindex[good]
            for value in np.unique(kept).tolist():
                frames.chan[rows[kept == value]] = self.names.provisional(f"ifindex{value}")
        frames.ts[rows] = ts[good]
        frames.can_id[rows] = can_id[good]
        frames.ext[rows] = ext[good]
        frames.rtr[rows] = rtr[good]
        frames.err[rows] = err[good]
        frames.fd[rows] = fd[good]
        frames.dlc[rows] = dlc[good]
        frames.data[rows] = data[good]
        frames.keep[rows] = True


def _read(stream: object, n: int) -> bytes:
    parts = []
    got = 0
    while got < n:
        chunk = stream.read(n - got)  # type: ignore[attr-defined]
        if not chunk:
            break
        parts.append(chunk)
        got += len(chunk)
    return b"".join(parts)


class _Pcap(_Capture):
    """Classic pcap: a 24-byte file header, then 16-byte record headers and packets."""

    def batches(self, magic: bytes) -> Iterator[FrameBatch]:
        order, ticks = PCAP_MAGICS[magic]
        header = _read(self.source.stream, 20)
        if len(header) < 20:
            raise InputError(self.source.path, "truncated pcap file header")
        network = struct.unpack(order + "HHiIII", header)[5]
        linktype = network & 0x0FFFFFFF
        if linktype not in CAN_LINKTYPES:
            raise InputError(self.source.path, f"pcap link type {linktype} does not carry "
                             "SocketCAN frames (supported: 227 CAN_SOCKETCAN, 113 LINUX_SLL, "
                             "276 LINUX_SLL2)")
        iface = _Interface(linktype, "0", ticks)
        carry = b""
        while True:
            more = _read(self.source.stream, READ_BYTES)
            buf = carry + more
            if not buf:
                break
            used = yield from self._records(buf, order, iface)
            carry = buf[used:]
            if not more:
                if carry:
                    self.stats.truncated = True
                    self.stats.skip(0, "truncated record at the end of the file")
                break
            if used < 0:
                break
        if (batch := self.out.take()) is not None:
            yield batch

    def _records(self, buf: bytes, order: str, iface: _Interface,
                 ) -> Generator[FrameBatch, None, int]:
        """Decode the complete records of `buf`; returns how many bytes they took (-1: stop)."""
        arr = np.frombuffer(buf, np.uint8)
        end = len(buf)
        found = RecordRuns()
        pos = 0
        stop = False
        while end - pos >= 16:
            incl = int.from_bytes(buf[pos + 8 : pos + 12], "little" if order == "<" else "big")
            if incl > MAX_PACKET:
                self.stats.truncated = True
                self.stats.skip(0, f"record length {incl} is not plausible: corrupt file, "
                                   "rest not read")
                stop = True
                break
            stride = 16 + incl
            if stride > end - pos:
                break  # the rest of this record is in the next read
            pos = found.add(buf, arr, pos, stride, end, 8, 4)  # key: the captured length
        if found.total:
            frames = Frames(found.total)
            big = order == ">"
            for stride, starts, out in found.groups():
                rows = strided_rows(arr, starts, stride)
                sec = _column(rows, 0, big)
                frac = _column(rows, 4, big)
                ts = sec.astype(np.float64) + frac.astype(np.float64) / iface.ticks
                caplen = np.full(len(out), stride - 16, np.int64)
                self.decode(rows[:, 16:], caplen, ts, iface, out, frames)
            self.names.finish(frames)
            self.out.add(frames)
            if self.out.ready and (batch := self.out.take()) is not None:
                yield batch
        return -1 if stop else pos


def _column(rows: np.ndarray, start: int, big: bool) -> np.ndarray:
    raw = np.ascontiguousarray(rows[:, start : start + 4])
    return raw.view(">u4" if big else "<u4").reshape(-1)


class _PcapNg(_Capture):
    """pcapng: blocks; interfaces (IDB) give link type, name and time resolution."""

    def batches(self, magic: bytes) -> Iterator[FrameBatch]:
        self.order = "<"
        self.interfaces: list[_Interface] = []
        carry = magic
        while True:
            more = _read(self.source.stream, READ_BYTES)
            buf = carry + more
            if not buf:
                break
            used = yield from self._blocks(buf)
            carry = buf[used:] if used >= 0 else b""
            if not more or used < 0:
                if carry:
                    self.stats.truncated = True
                    self.stats.skip(0, "truncated block at the end of the file")
                break
        if (batch := self.out.take()) is not None:
            yield batch

    def _blocks(self, buf: bytes) -> Generator[FrameBatch, None, int]:
        """Decode the complete blocks of `buf`; returns how many bytes they took (-1: stop)."""
        arr = np.frombuffer(buf, np.uint8)
        end = len(buf)
        found = RecordRuns()  # Enhanced Packet Blocks
        loose: list[tuple[int, int, int, int, int]] = []  # row, pos, iface, ts ticks, caplen
        pos = 0
        while end - pos >= 12:
            if buf[pos : pos + 4] == PCAPNG_SHB:
                bom = buf[pos + 8 : pos + 12]
                if bom not in PCAPNG_BOMS:
                    raise InputError(self.source.path, "pcapng section header with an unknown "
                                     "byte-order mark")
                order = PCAPNG_BOMS[bom]
            else:
                order = self.order
            btype, blen = struct.unpack_from(order + "II", buf, pos)
            if blen < 12 or blen % 4 or blen > MAX_PACKET + 64:
                self.stats.truncated = True
                self.stats.skip(0, f"block length {blen} is not plausible: corrupt file, "
                                   "rest not read")
                yield from self._flush(buf, arr, found, loose)
                return -1
            if blen > end - pos:
                break
            if btype == BLOCK_EPB and blen >= 32:
                pos = found.add(buf, arr, pos, blen, end, 0, 8)  # key: block type and length
                continue
            body = buf[pos + 8 : pos + blen - 4]
            if btype == PCAPNG_SHB_TYPE:
                yield from self._flush(buf, arr, found, loose)
                found, loose = RecordRuns(), []
                self.order = order
                self.interfaces = []
            elif btype == BLOCK_IDB:
                self.interfaces.append(self._interface(body))
            elif btype == BLOCK_PB and len(body) >= 20:
                iface, _drops, hi, lo, caplen = struct.unpack_from(order + "HHIII", body, 0)
                loose.append((found.claim(), pos + 28, iface, hi << 32 | lo,
                              min(caplen, blen - 32)))
            elif btype == BLOCK_SPB:
                self.stats.skip(0, "simple packet block: no timestamp")
            pos += blen
        yield from self._flush(buf, arr, found, loose)
        return pos

    def _interface(self, body: bytes) -> _Interface:
        """An interface description; a damaged one keeps its number (packets name
        interfaces by number) and its packets are skipped."""
        order = self.order
        iface = _Interface(DAMAGED_INTERFACE, str(len(self.interfaces)))
        if len(body) < 8:
            self.stats.skip(0, "interface description block too short")
            return iface
        iface.linktype = struct.unpack_from(order + "H", body, 0)[0]
        pos = 8
        while pos + 4 <= len(body):
            code, size = struct.unpack_from(order + "HH", body, pos)
            value = body[pos + 4 : pos + 4 + size]
            if code == 0:
                break
            if len(value) < size:
                break  # an option that runs past its block: the options end here
            if code == 2 and value:  # if_name
                iface.name = value.rstrip(b"\0").decode("utf-8", "replace")
            elif code == 9 and size >= 1:  # if_tsresol
                res = value[0]
                iface.ticks = 2 ** (res & 0x7F) if res & 0x80 else 10**res
            elif code == 14 and size >= 8:  # if_tsoffset
                iface.offset = struct.unpack_from(order + "q", value, 0)[0]
            pos += 4 + size + (-size % 4)
        if iface.ticks > MAX_TICKS:
            self.stats.skip(0, f"interface time resolution of 1/{iface.ticks} s is not "
                               "plausible")
            iface.linktype = DAMAGED_INTERFACE
        return iface

    def _flush(self, buf: bytes, arr: np.ndarray, found: RecordRuns,
               loose: list[tuple[int, int, int, int, int]]) -> Iterator[FrameBatch]:
        """Decode the packets found so far (before the interfaces change with a new section)."""
        if found.total == 0:
            return
        frames = Frames(found.total)
        big = self.order == ">"
        parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        for stride, starts, out in found.groups():
            rows = strided_rows(arr, starts, stride - 4)
            iface = _column(rows, 8, big).astype(np.int64)
            ticks = _column(rows, 12, big).astype(np.uint64) << np.uint64(32) | _column(
                rows, 16, big).astype(np.uint64)
            caplen = _column(rows, 20, big).astype(np.int64)
            parts.append((rows[:, 28:], iface, ticks, np.minimum(caplen, stride - 32), out))
        if loose:  # obsolete Packet Blocks, one by one
            width = max(8, max(c for *_x, c in loose))
            padded = np.concatenate([arr, np.zeros(width, np.uint8)])
            starts = np.array([p for _r, p, *_y in loose], np.int64)
            parts.append((padded[starts[:, None] + np.arange(width)],
                          np.array([i for _r, _p, i, _t, _c in loose], np.int64),
                          np.array([t for _r, _p, _i, t, _c in loose], np.uint64),
                          np.array([c for *_x, c in loose], np.int64),
                          np.array([r for r, *_y in loose], np.int64)))
        for pkt, iface_ids, ticks, caplen, out in parts:
            for idx in np.unique(iface_ids).tolist():
                sel = np.flatnonzero(iface_ids == idx)
                if idx >= len(self.interfaces):
                    for _ in range(len(sel)):
                        self.stats.skip(0, f"packet on interface {idx}, which was never "
                                           "described")
                    continue
                iface = self.interfaces[idx]
                if iface.linktype == DAMAGED_INTERFACE:
                    for _ in range(len(sel)):
                        self.stats.skip(0, f"packet on interface {idx}, whose description "
                                           "is damaged")
                    continue
                if iface.linktype not in CAN_LINKTYPES:
                    self.stats.ignored += len(sel)
                    continue
                ts = split_seconds(ticks[sel], iface.ticks) + iface.offset
                self.decode(pkt[sel], caplen[sel], ts, iface, out[sel], frames)
        self.names.finish(frames)
        self.out.add(frames)
        if self.out.ready and (batch := self.out.take()) is not None:
            yield batch


def read(source: Source, stats: InputStats) -> Iterator[FrameBatch]:
    try:
        magic = _read(source.stream, 4)
        if magic in PCAP_MAGICS:
            yield from _Pcap(source, stats).batches(magic)
        elif magic == PCAPNG_SHB:
            yield from _PcapNg(source, stats).batches(magic)
        else:
            raise InputError(source.path, "not a pcap or pcapng file (bad magic)")
    except source.errors as exc:
        raise InputError(source.path, f"read error (truncated or corrupt file?): {exc}") from None
