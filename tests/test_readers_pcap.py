"""pcap / pcapng reader: SocketCAN link type 227, Linux cooked captures, CAN-ID byte order.

Captures are written by the small writers below (pcap and pcapng as
libpcap/Wireshark write them); the scapy captures of the shared corpus are
checked against a plain struct-by-struct reading written here.
"""

from __future__ import annotations

import dataclasses
import gzip
import struct
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import CORPUS, needs_corpus
from conftest import read_columns as read

from nmtcheck.errors import InputError
from nmtcheck.readers import InputStats, detect_format, open_input, pcap

THIRD = CORPUS / "third_party"
CAN_EFF_FLAG = 0x80000000
CAN_RTR_FLAG = 0x40000000
CAN_ERR_FLAG = 0x20000000


@dataclasses.dataclass
class Frame:
    t_us: int  # microseconds since the epoch
    can_id: int
    data: bytes = b""
    ext: bool = False
    rtr: bool = False
    err: bool = False
    fd: bool = False
    dlc: int | None = None  # remote frames: the requested length


def socketcan(f: Frame, id_order: str = ">", trim: bool = False, fdf: bool = True) -> bytes:
    """The SocketCAN frame as captured: can_id, length, FD flags, 2 reserved, data.

    `trim`: store only the used data bytes (as scapy does) instead of the full
    16/72-byte frame.
    """
    raw_id = f.can_id | (CAN_EFF_FLAG if f.ext else 0) | (CAN_RTR_FLAG if f.rtr else 0) | (
        CAN_ERR_FLAG if f.err else 0)
    length = f.dlc if f.rtr and f.dlc is not None else len(f.data)
    flags = 0x04 if f.fd and fdf else 0
    head = struct.pack(id_order + "I", raw_id) + bytes([length, flags, 0, 0])
    if trim:
        return head + f.data
    return head + f.data.ljust(64 if f.fd else 8, b"\0")


def sll(payload: bytes, proto: int = 0x000C, pkttype: int = 0) -> bytes:
    """Linux cooked capture v1 header (16 bytes, ARPHRD_CAN) + payload."""
    return struct.pack(">HHH8sH", pkttype, 280, 0, b"", proto) + payload


def sll2(payload: bytes, ifindex: int, proto: int = 0x000C) -> bytes:
    """Linux cooked capture v2 header (20 bytes) + payload."""
    return struct.pack(">HHIHBB8s", proto, 0, ifindex, 280, 0, 0, b"") + payload


def pcap_file(packets: Iterable[tuple[int, bytes]], linktype: int = 227, order: str = "<",
              nanos: bool = False) -> bytes:
    """A classic pcap file of (time in µs, packet) records."""
    magic = 0xA1B23C4D if nanos else 0xA1B2C3D4
    out = [struct.pack(order + "IHHiIII", magic, 2, 4, 0, 0, 262144, linktype)]
    for t_us, pkt in packets:
        sec, frac = divmod(t_us, 10**6)
        out.append(struct.pack(order + "IIII", sec, frac * 1000 if nanos else frac, len(pkt),
                               len(pkt)) + pkt)
    return b"".join(out)


def _block(btype: int, body: bytes, order: str = "<") -> bytes:
    body += b"\0" * (-len(body) % 4)
    n = len(body) + 12
    return struct.pack(order + "II", btype, n) + body + struct.pack(order + "I", n)


def _option(code: int, value: bytes, order: str = "<") -> bytes:
    return struct.pack(order + "HH", code, len(value)) + value + b"\0" * (-len(value) % 4)


def pcapng_section(order: str = "<") -> bytes:
    return _block(0x0A0D0D0A, struct.pack(order + "IHHq", 0x1A2B3C4D, 1, 0, -1), order)


def pcapng_interface(linktype: int, name: str | None = None, tsresol: int | None = None,
                     order: str = "<") -> bytes:
    opts = b""
    if name is not None:
        opts += _option(2, name.encode(), order)
    if tsresol is not None:
        opts += _option(9, bytes([tsresol]), order)
    if opts:
        opts += _option(0, b"", order)
    return _block(1, struct.pack(order + "HHI", linktype, 0, 262144) + opts, order)


def pcapng_packet(iface: int, ticks: int, pkt: bytes, order: str = "<",
                  flags: int | None = None) -> bytes:
    """An Enhanced Packet Block (optionally with an epb_flags option)."""
    body = struct.pack(order + "IIIII", iface, ticks >> 32, ticks & 0xFFFFFFFF, len(pkt),
                       len(pkt)) + pkt + b"\0" * (-len(pkt) % 4)
    if flags is not None:
        body += _option(2, struct.pack(order + "I", flags), order) + _option(0, b"", order)
    return _block(6, body, order)


def rows(stats: InputStats, cols: dict[str, np.ndarray]) -> list[tuple[Any, ...]]:
    """(µs, channel, id, ext, rtr, err, fd, dlc, first 8 data bytes) per frame."""
    return [(round(float(cols["ts"][i]) * 1e6), stats.channels[int(cols["chan"][i])],
             int(cols["can_id"][i]), bool(cols["ext"][i]), bool(cols["rtr"][i]),
             bool(cols["err"][i]), bool(cols["fd"][i]), int(cols["dlc"][i]),
             bytes(cols["data"][i]).rstrip(b"\0")) for i in range(len(cols["ts"]))]


def expect(frames: list[Frame], channel: str = "0") -> list[tuple[Any, ...]]:
    return [(f.t_us, channel, f.can_id, f.ext, f.rtr and not f.fd, f.err, f.fd,
             f.dlc if f.rtr and f.dlc is not None else len(f.data),
             b"" if f.rtr else f.data[:8].rstrip(b"\0")) for f in frames]


T0_US = 1_700_000_000_000_000
FRAMES = [
    Frame(T0_US, 0x701, b"\x00"),
    Frame(T0_US + 1000, 0x000, b"\x01\x00"),
    Frame(T0_US + 2000, 0x704, rtr=True, dlc=1),
    Frame(T0_US + 3000, 0x185, bytes(range(1, 9))),
    Frame(T0_US + 4000, 0x18DAF110, bytes([2, 0x10, 3]), ext=True),
    Frame(T0_US + 5000, 0x18DAF1F9, b"\x07", ext=True),
    Frame(T0_US + 6000, 0x004, bytes([0, 4, 0, 0, 0, 0, 0, 0x55]), err=True),
    Frame(T0_US + 7000, 0x123, bytes(range(1, 13)), fd=True),
    Frame(T0_US + 8000, 0x701, b"\x05"),
    Frame(T0_US + 9000, 0x7FF, b""),
]


# --- classic pcap -------------------------------------------------------------------------


@pytest.mark.parametrize("id_order", [">", "<"], ids=["network-order", "little-endian"])
@pytest.mark.parametrize("trim", [False, True], ids=["full-frame", "trimmed"])
def test_socketcan_linktype_both_id_byte_orders(tmp_path: Path, id_order: str,
                                                trim: bool) -> None:
    path = tmp_path / "cap.pcap"
    path.write_bytes(pcap_file((f.t_us, socketcan(f, id_order, trim)) for f in FRAMES))
    stats, cols = read(path)
    assert stats.format == "pcap"
    assert rows(stats, cols) == expect(FRAMES)
    assert (stats.frames, stats.extended, stats.remote_frames, stats.error_frames,
            stats.fd_frames, stats.skipped, stats.ignored) == (10, 2, 1, 1, 1, 0, 0)
    assert (cols["line"] == 0).all() and cols["index"].tolist() == list(range(10))


@pytest.mark.parametrize("order,nanos", [(">", False), ("<", True), (">", True)])
def test_file_header_byte_order_and_nanosecond_magic(tmp_path: Path, order: str,
                                                     nanos: bool) -> None:
    path = tmp_path / "cap.pcap"
    path.write_bytes(pcap_file(((f.t_us, socketcan(f)) for f in FRAMES), order=order,
                               nanos=nanos))
    stats, cols = read(path)
    assert rows(stats, cols) == expect(FRAMES)


def test_fd_frame_without_fdf_flag_is_recognised_by_its_size(tmp_path: Path) -> None:
    """Older kernels leave the FD flags zero: a 72-byte frame is CAN FD all the same."""
    fd8 = Frame(T0_US, 0x181, bytes(range(8)), fd=True)
    path = tmp_path / "oldfd.pcap"
    path.write_bytes(pcap_file([(fd8.t_us, socketcan(fd8, fdf=False))]))
    stats, cols = read(path)
    assert rows(stats, cols) == expect([fd8])


def test_cooked_captures(tmp_path: Path) -> None:
    """SLL: CAN and CAN FD by protocol, host-order (little-endian) IDs; other protocols and
    CAN XL are ignored, not skipped."""
    packets = [(f.t_us, sll(socketcan(f, "<"), 0x000D if f.fd else 0x000C, pkttype=4))
               for f in FRAMES]
    packets.insert(3, (T0_US + 2500, sll(b"\x45" + bytes(19), 0x0800)))  # IPv4
    packets.insert(4, (T0_US + 2600, sll(b"\x00\x01", 0x0806)))  # shorter than a CAN header
    xl = struct.pack("<IBBHI", 0x7FF, 0x80, 0, 4, 0) + b"\x01\x02\x03\x04"
    packets.insert(6, (T0_US + 3500, sll(xl, 0x000E)))
    path = tmp_path / "sll.pcap"
    path.write_bytes(pcap_file(packets, linktype=113))
    stats, cols = read(path)
    assert rows(stats, cols) == expect(FRAMES)
    assert (stats.ignored, stats.skipped) == (3, 0)


def test_sll2_channels_by_interface_index(tmp_path: Path) -> None:
    packets = [(f.t_us, sll2(socketcan(f, "<"), 3 + i % 2, 0x000D if f.fd else 0x000C))
               for i, f in enumerate(FRAMES)]
    path = tmp_path / "any.pcap"
    path.write_bytes(pcap_file(packets, linktype=276))
    stats, cols = read(path)
    assert stats.channels == ["ifindex3", "ifindex4"]
    assert rows(stats, cols) == [
        (r[0], f"ifindex{3 + i % 2}", *r[2:]) for i, r in enumerate(expect(FRAMES))]


def test_a_lone_ambiguous_id_follows_the_link_type_default(tmp_path: Path) -> None:
    """181h reads as a plausible 29-bit ID in the other byte order too; with no other
    evidence the link type's own order decides."""
    frame = Frame(T0_US, 0x181, b"\x01")
    for linktype, packet, order in ((227, socketcan(frame, ">"), ">"),
                                    (113, sll(socketcan(frame, "<")), "<")):
        path = tmp_path / f"one{linktype}.pcap"
        path.write_bytes(pcap_file([(T0_US, packet)], linktype=linktype))
        stats, cols = read(path)
        assert rows(stats, cols) == expect([frame]), order


def test_can_xl_flag_on_socketcan_linktype_is_ignored(tmp_path: Path) -> None:
    xl = struct.pack(">IBBHI", 0x123, 0x80, 0, 2, 0) + b"\x01\x02"
    path = tmp_path / "xl.pcap"
    path.write_bytes(pcap_file([(T0_US, xl), (T0_US + 1, socketcan(FRAMES[0]))]))
    stats, _cols = read(path)
    assert (stats.frames, stats.ignored) == (1, 1)


def test_damaged_records_are_skipped(tmp_path: Path) -> None:
    good = socketcan(FRAMES[3])
    packets = [(T0_US, good), (T0_US + 1, good[:6]),  # shorter than the CAN header
               (T0_US + 2, good[:12]),  # ends inside the 8 data bytes it announces
               (T0_US + 3, struct.pack(">I", 0x800) + bytes([1, 0, 0, 0, 9])),  # 11-bit > 7FFh
               (T0_US + 4, good)]
    data = pcap_file(packets)
    path = tmp_path / "bad.pcap"
    path.write_bytes(data + data[24:40])  # and a record cut at the end of the file
    stats, _cols = read(path)
    assert stats.frames == 2
    assert stats.skipped == 4 and stats.skipped_lines == [0, 0, 0, 0]
    with pytest.raises(InputError) as exc:
        list(open_input(str(path), strict=True).batches)
    assert "packet shorter than a CAN frame header" in str(exc.value)


def test_other_link_type_is_an_input_error(tmp_path: Path) -> None:
    path = tmp_path / "eth.pcap"
    path.write_bytes(pcap_file([(T0_US, bytes(60))], linktype=1))
    with pytest.raises(InputError) as exc:
        list(open_input(str(path)).batches)
    assert "pcap link type 1 does not carry SocketCAN frames" in str(exc.value)


def test_records_spanning_reads(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Many records of mixed sizes read in small pieces give the same frames as one read."""
    frames = [dataclasses.replace(FRAMES[i % len(FRAMES)], t_us=T0_US + i * 100)
              for i in range(5000)]
    path = tmp_path / "big.pcap"
    path.write_bytes(pcap_file((f.t_us, socketcan(f, trim=i % 3 == 0))
                               for i, f in enumerate(frames)))
    whole = read(path)
    monkeypatch.setattr(pcap, "READ_BYTES", 997)
    pieces = read(path)
    assert rows(*pieces) == rows(*whole) == expect(frames)


# --- pcapng -------------------------------------------------------------------------------


@pytest.mark.parametrize("order", ["<", ">"])
def test_pcapng_interfaces_resolutions_and_blocks(tmp_path: Path, order: str) -> None:
    blocks = [pcapng_section(order),
              pcapng_interface(227, "can0", None, order),  # µs
              pcapng_interface(227, "can1", 9, order),  # ns
              pcapng_interface(1, "eth0", None, order)]  # Ethernet: packets ignored
    expected = []
    for i, f in enumerate(FRAMES):
        iface = i % 2
        ticks = f.t_us if iface == 0 else f.t_us * 1000
        blocks.append(pcapng_packet(iface, ticks, socketcan(f, trim=i % 2 == 0), order,
                                    flags=1 if i % 4 == 0 else None))
        expected.append((*expect([f], f"can{iface}")[0],))
        if i == 4:
            blocks.append(pcapng_packet(2, f.t_us, bytes(60), order))
            blocks.append(_block(5, struct.pack(order + "III", 0, 0, 0), order))  # statistics
            blocks.append(_block(3, struct.pack(order + "I", 16) + bytes(16), order))  # SPB
    # an obsolete Packet Block on can0
    pb = socketcan(FRAMES[0])
    t = T0_US + 20_000
    blocks.append(_block(2, struct.pack(order + "HHIIII", 0, 0, t >> 32, t & 0xFFFFFFFF, len(pb),
                                        len(pb)) + pb, order))
    expected.append(expect([dataclasses.replace(FRAMES[0], t_us=t)], "can0")[0])
    path = tmp_path / "cap.pcapng"
    path.write_bytes(b"".join(blocks))
    stats, cols = read(path)
    assert stats.format == "pcap"
    assert stats.channels == ["can0", "can1"]
    assert rows(stats, cols) == expected
    assert stats.ignored == 1  # the Ethernet packet
    assert stats.skipped == 1  # the simple packet block has no time


def test_pcapng_new_section_resets_interfaces(tmp_path: Path) -> None:
    first, second = FRAMES[:3], FRAMES[3:6]
    data = pcapng_section() + pcapng_interface(227, "can0")
    data += b"".join(pcapng_packet(0, f.t_us, socketcan(f)) for f in first)
    data += pcapng_section(">") + pcapng_interface(113, None, order=">")
    data += b"".join(pcapng_packet(0, f.t_us, sll(socketcan(f, "<")), ">") for f in second)
    path = tmp_path / "two.pcapng"
    path.write_bytes(data)
    stats, cols = read(path)
    assert rows(stats, cols) == expect(first, "can0") + expect(second, "0")


def test_pcapng_without_interface_name_and_unknown_interface(tmp_path: Path) -> None:
    data = pcapng_section() + pcapng_interface(227)
    data += pcapng_packet(0, FRAMES[0].t_us, socketcan(FRAMES[0]))
    data += pcapng_packet(5, FRAMES[1].t_us, socketcan(FRAMES[1]))
    path = tmp_path / "anon.pcapng"
    path.write_bytes(data)
    stats, cols = read(path)
    assert rows(stats, cols) == expect(FRAMES[:1], "0")
    assert stats.skipped == 1


def test_sniff() -> None:
    assert detect_format(pcap_file([(T0_US, socketcan(FRAMES[0]))])) == "pcap"
    assert detect_format(pcapng_section() + pcapng_interface(227)) == "pcap"
    assert not pcap.sniff(b"\x0a\x0d\x0d\x0a" + bytes(8))  # no byte-order mark


# --- the scapy captures of the corpus -----------------------------------------------------


def _reference(rel: str) -> list[tuple[Any, ...]]:
    """The records of a scapy capture read one by one with struct (little-endian IDs)."""
    raw = gzip.decompress((THIRD / rel).read_bytes())
    linktype = struct.unpack_from("<I", raw, 20)[0]
    out = []
    pos = 24
    while pos < len(raw):
        sec, usec, incl, _orig = struct.unpack_from("<IIII", raw, pos)
        pkt = raw[pos + 16 : pos + 16 + incl]
        pos += 16 + incl
        proto = 0x000C
        if linktype == 113:
            proto = struct.unpack_from(">H", pkt, 14)[0]
            pkt = pkt[16:]
        raw_id, length, flags = struct.unpack_from("<IBB", pkt, 0)
        fd = proto == 0x000D or bool(flags & 0x04) or length > 8
        data = pkt[8 : 8 + length]
        assert len(data) == length
        out.append((sec * 10**6 + usec, "0", raw_id & 0x1FFFFFFF, bool(raw_id & CAN_EFF_FLAG),
                    bool(raw_id & CAN_RTR_FLAG), bool(raw_id & CAN_ERR_FLAG), fd, length,
                    data[:8].rstrip(b"\0")))
    return out


# (frames, extended, fd, distinct IDs, start, end): PROVENANCE record counts
SCAPY = {
    "scapy/candump_gmlan_scanner.pcap.gz": (3819, 0, 0, 1625906307.412579, 1625908919.473994),
    "scapy/candump_uds_scanner.pcap.gz": (9434, 0, 0, 1626788898.688202, 1626789869.755683),
    "scapy/gmlan_trace.pcap.gz": (1087, 0, 0, 0.297, 4951.645),
    "scapy/canfd.pcap.gz": (4, 0, 4, 1667650502.470855, 1667650504.872915),
}


@needs_corpus
@pytest.mark.parametrize("rel", sorted(SCAPY))
def test_scapy_captures(rel: str) -> None:
    stats, cols = read(THIRD / rel)
    frames, ext, fd, start, end = SCAPY[rel]
    assert (stats.format, stats.frames, stats.extended, stats.fd_frames, stats.skipped,
            stats.ignored, stats.channels) == ("pcap", frames, ext, fd, 0, 0, ["0"])
    assert stats.start == pytest.approx(start, abs=1e-9)
    assert stats.end == pytest.approx(end, abs=1e-9)
    assert rows(stats, cols) == _reference(rel)


@needs_corpus
def test_scapy_canfd_capture_content() -> None:
    """canfd.pcap: SLL, protocol CAN FD, ID 123h with 12 bytes, sent and looped back."""
    _stats, cols = read(THIRD / "scapy/canfd.pcap.gz")
    assert cols["can_id"].tolist() == [0x123] * 4
    assert cols["dlc"].tolist() == [12] * 4 and cols["fd"].all()
    assert bytes(cols["data"][0]) == bytes.fromhex("2233445566778899")  # of 22…99 33 00 00 00
