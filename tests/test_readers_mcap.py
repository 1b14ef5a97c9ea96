"""MCAP reader: ROS 2 / ROS 1 CAN frames, FdFrame, protobuf and JSON messages.

Files are written with the mcap support libraries' own writers (mcap_ros2,
mcap_ros1, mcap_protobuf, mcap) and the frames are checked against what was
written and, for ROS 2, against the library decoder that the numpy fast path
replaces.
"""

from __future__ import annotations

import dataclasses
import gzip
import json
import os
import random
import struct
import subprocess
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import REPO
from conftest import read_columns as read
from hostile_logs import ROS2_FRAME_MSG
from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter

from nmtcheck.errors import InputError
from nmtcheck.readers import InputStats, detect_format, mcaplog, open_input

T0_NS = 1_700_000_000_000_000_000
LATENCY_NS = 7_000_000  # the recorder's log time lags the driver's header stamp

ROS2_FD_FRAME_MSG = """\
std_msgs/Header header
uint32 id
bool is_extended
bool is_error
uint8 len
uint8[<=64] data
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""
ROS2_STRING_MSG = "string data\n"
ROS1_FRAME_MSG = """\
Header header
uint32 id
bool is_rtr
bool is_extended
bool is_error
uint8 dlc
uint8[8] data
================================================================================
MSG: std_msgs/Header
uint32 seq
time stamp
string frame_id
"""


@dataclasses.dataclass
class Frame:
    """One frame as written: the expected reading (data: the valid bytes only)."""

    t_ns: int
    can_id: int
    ext: bool = False
    rtr: bool = False
    err: bool = False
    dlc: int = 0
    data: bytes = b""


def sample_frames(n: int = 300, seed: int = 5) -> list[Frame]:
    """A mix of CANopen-like 11-bit frames, extended, remote and error frames."""
    rnd = random.Random(seed)
    frames = []
    for i in range(n):
        t = T0_NS + i * 1_000_000 + rnd.randrange(1000)
        kind = rnd.random()
        if kind < 0.08:
            frames.append(Frame(t, 0x700 + rnd.randint(1, 127), rtr=True, dlc=rnd.choice([0, 1])))
        elif kind < 0.15:
            frames.append(Frame(t, rnd.randrange(1 << 29), ext=True, dlc=8,
                                data=rnd.randbytes(8)))
        elif kind < 0.18:
            frames.append(Frame(t, 0x004, err=True, dlc=8, data=rnd.randbytes(8)))
        else:
            dlc = rnd.randint(0, 8)
            frames.append(Frame(t, rnd.choice([0x000, 0x701, 0x185, 0x205, 0x585, 0x085]),
                                dlc=dlc, data=rnd.randbytes(dlc)))
    return frames


def ros2_message(f: Frame, frame_id: str = "can0", stamp: bool = True,
                 junk: bytes = b"") -> dict[str, Any]:
    """ros2_socketcan's message; bytes past dlc may hold junk (a reused buffer)."""
    sec, nsec = divmod(f.t_ns, 10**9) if stamp else (0, 0)
    return {"header": {"stamp": {"sec": sec, "nanosec": nsec}, "frame_id": frame_id},
            "id": f.can_id, "is_rtr": f.rtr, "is_extended": f.ext, "is_error": f.err,
            "dlc": f.dlc, "data": (f.data + junk).ljust(8, b"\0")[:8]}


def write_ros2(path: Path, topics: dict[str, list[Frame]], *, frame_ids: dict[str, str] | None
               = None, msgdef: str = ROS2_FRAME_MSG, stamp: bool = True,
               extra: Iterable[tuple[str, int, str]] = (), chunk_size: int = 1024 * 1024,
               ) -> None:
    """ROS 2 can_msgs/msg/Frame topics via mcap_ros2's writer, interleaved by time; `extra`
    adds std_msgs/msg/String messages (topic, time, text)."""
    from mcap_ros2.writer import Writer

    rows: list[tuple[int, str, Any]] = [(f.t_ns, t, f) for t, fs in topics.items() for f in fs]
    rows += [(t_ns, topic, text) for topic, t_ns, text in extra]
    rows.sort(key=lambda r: r[0])
    with path.open("wb") as fh:
        writer = Writer(fh, chunk_size=chunk_size)
        frame_schema = writer.register_msgdef("can_msgs/msg/Frame", msgdef)
        string_schema = writer.register_msgdef("std_msgs/msg/String", ROS2_STRING_MSG)
        for t_ns, topic, item in rows:
            if isinstance(item, Frame):
                fid = (frame_ids or {}).get(topic, "can0")
                writer.write_message(topic, frame_schema,
                                     ros2_message(item, fid, stamp, junk=b"\xee" * 8),
                                     log_time=t_ns + LATENCY_NS)
            else:
                writer.write_message(topic, string_schema, {"data": item}, log_time=t_ns)
        writer.finish()


def rows(stats: InputStats, cols: dict[str, np.ndarray]) -> list[tuple[Any, ...]]:
    """(ts in ns, channel, id, ext, rtr, err, fd, dlc, data) per frame, data cut to dlc."""
    out = []
    for i in range(len(cols["ts"])):
        dlc = int(cols["dlc"][i])
        out.append((round(float(cols["ts"][i]) * 1e9), stats.channels[int(cols["chan"][i])],
                    int(cols["can_id"][i]), bool(cols["ext"][i]), bool(cols["rtr"][i]),
                    bool(cols["err"][i]), bool(cols["fd"][i]), dlc,
                    bytes(cols["data"][i, : min(dlc, 8)]) if not cols["rtr"][i] else b""))
    return out


def expected(frames: list[Frame], channel: str, fd: bool = False) -> list[tuple[Any, ...]]:
    return [(f.t_ns, channel, f.can_id, f.ext, f.rtr, f.err, fd, f.dlc,
             b"" if f.rtr else f.data[:8]) for f in frames]


def close_ns(ours: list[tuple[Any, ...]], theirs: list[tuple[Any, ...]], tol_ns: int = 300,
             ) -> None:
    """Equal rows, timestamps within float precision of epoch seconds (~240 ns)."""
    assert len(ours) == len(theirs)
    for a, b in zip(ours, theirs, strict=True):
        assert abs(a[0] - b[0]) <= tol_ns, (a, b)
        assert a[1:] == b[1:], (a, b)


# --- ROS 2 can_msgs/msg/Frame: the numpy path ---------------------------------------------


def test_ros2_frames_use_header_stamp(tmp_path: Path) -> None:
    frames = sample_frames()
    path = tmp_path / "bag.mcap"
    write_ros2(path, {"/from_can_bus": frames})
    stats, cols = read(path)
    assert stats.format == "mcap"
    assert stats.channels == ["/from_can_bus"]
    close_ns(rows(stats, cols), expected(frames, "/from_can_bus"))
    assert (stats.frames, stats.skipped, stats.ignored) == (len(frames), 0, 0)
    assert stats.extended == sum(f.ext for f in frames)
    assert stats.remote_frames == sum(f.rtr for f in frames)
    assert stats.error_frames == sum(f.err for f in frames)
    assert cols["index"].tolist() == list(range(len(frames)))
    assert (cols["line"] == 0).all()
    # bytes past dlc were junk in the message: a batch is zero padded
    short = cols["dlc"] < 8
    assert not np.any(cols["data"][short][:, 7])


def test_ros2_zero_stamp_falls_back_to_log_time(tmp_path: Path) -> None:
    frames = sample_frames(50)
    path = tmp_path / "nostamp.mcap"
    write_ros2(path, {"/can": frames}, stamp=False)
    stats, cols = read(path)
    shifted = [dataclasses.replace(f, t_ns=f.t_ns + LATENCY_NS) for f in frames]
    close_ns(rows(stats, cols), expected(shifted, "/can"))


def test_fast_path_equals_library_decoder(tmp_path: Path) -> None:
    """The numpy decoding agrees field by field with mcap_ros2's decoder on the same file."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    frames = sample_frames(2000, seed=11)
    path = tmp_path / "cmp.mcap"
    write_ros2(path, {"/a": frames[::2], "/bb": frames[1::2]},
               frame_ids={"/a": "can0", "/bb": "a_much_longer_frame_id"}, chunk_size=4096)
    stats, cols = read(path)
    theirs = []
    with path.open("rb") as fh:
        for _schema, channel, message, msg in make_reader(
                fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
            stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            dlc = min(msg.dlc, 8)
            theirs.append((stamp, channel.topic, msg.id, msg.is_extended and not msg.is_error,
                           msg.is_rtr, msg.is_error, False, dlc,
                           b"" if msg.is_rtr else bytes(msg.data[:dlc])))
            assert message.log_time == stamp + LATENCY_NS
    close_ns(rows(stats, cols), theirs)
    assert stats.channels == ["/a", "/bb"]


def test_standard_schema_never_decodes_message_by_message(tmp_path: Path,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "fast.mcap"
    write_ros2(path, {"/can": sample_frames(500)})

    def refuse(*_a: Any, **_k: Any) -> None:
        raise AssertionError("per-message decoder used for the standard schema")

    monkeypatch.setattr(mcaplog._McapFrames, "_object_frames", refuse)
    stats, _ = read(path)
    assert stats.frames == 500


def test_schema_text_recognition() -> None:
    assert mcaplog.is_known_ros2_frame(ROS2_FRAME_MSG)
    # comments, blank lines, constants and the /msg/ spelling do not change the layout
    commented = ("# CAN frame\n\nuint8 MAX_DLC=8\nstd_msgs/msg/Header header # stamp\n"
                 + ROS2_FRAME_MSG.split("\n", 1)[1])
    assert mcaplog.is_known_ros2_frame(commented)
    assert mcaplog.is_known_ros2_frame(ROS2_FRAME_MSG.split("=====")[0])  # no dependencies
    reordered = ROS2_FRAME_MSG.replace("bool is_rtr\nbool is_extended",
                                       "bool is_extended\nbool is_rtr")
    assert not mcaplog.is_known_ros2_frame(reordered)
    assert not mcaplog.is_known_ros2_frame(ROS2_FRAME_MSG.replace("int32 sec", "int64 sec"))
    assert not mcaplog.is_known_ros2_frame(ROS2_FRAME_MSG.replace("uint8[8] data", "uint8[] data"))


def test_other_frame_layout_goes_through_the_library(tmp_path: Path) -> None:
    """A can_msgs/msg/Frame of another layout (fields reordered) is decoded by mcap_ros2."""
    frames = sample_frames(120)
    msgdef = ROS2_FRAME_MSG.replace("bool is_rtr\nbool is_extended",
                                    "bool is_extended\nbool is_rtr")
    path = tmp_path / "variant.mcap"
    write_ros2(path, {"/can": frames}, msgdef=msgdef)
    stats, cols = read(path)
    close_ns(rows(stats, cols), expected(frames, "/can"))


def _cdr_be_frame(f: Frame, frame_id: bytes = b"can0\0") -> bytes:
    sec, nsec = divmod(f.t_ns, 10**9)
    body = struct.pack(">iII", sec, nsec, len(frame_id)) + frame_id
    body += b"\0" * (-len(body) % 4)
    body += struct.pack(">I4B", f.can_id, f.rtr, f.ext, f.err, f.dlc) + f.data.ljust(8, b"\0")
    return b"\x00\x00\x00\x00" + body  # CDR_BE


def test_big_endian_cdr_and_short_messages(tmp_path: Path) -> None:
    """Messages the fixed layout does not fit go to the library: big-endian CDR is decoded,
    a truncated message is a skipped record."""
    frames = sample_frames(20)
    path = tmp_path / "be.mcap"
    with path.open("wb") as fh:
        w = McapWriter(fh)
        w.start(profile="ros2", library="test")
        sid = w.register_schema("can_msgs/msg/Frame", "ros2msg", ROS2_FRAME_MSG.encode())
        cid = w.register_channel("/can", "cdr", sid)
        for i, f in enumerate(frames):
            w.add_message(cid, log_time=f.t_ns, publish_time=f.t_ns, data=_cdr_be_frame(f),
                          sequence=i)
        w.add_message(cid, log_time=T0_NS, publish_time=T0_NS, data=b"\x00\x01\x00\x00\x01",
                      sequence=99)
        w.finish()
    stats, cols = read(path)
    close_ns(rows(stats, cols), expected(frames, "/can"))
    assert stats.skipped == 1 and stats.skipped_lines == [0]


# --- other topics, --topic -----------------------------------------------------------------


def test_non_can_topics_are_ignored_and_counted(tmp_path: Path) -> None:
    frames = sample_frames(200)
    chatter = [("/chatter", T0_NS + i * 3_333_333, "x" * (i % 7)) for i in range(60)]
    path = tmp_path / "mixed.mcap"
    write_ros2(path, {"/can0": frames[:100], "/can1": frames[100:]},
               frame_ids={"/can1": "can1_frame"}, extra=chatter)
    stats, cols = read(path)
    assert stats.ignored == 60
    assert stats.frames == 200
    # written interleaved by time: file order is time order
    close_ns(rows(stats, cols), sorted(expected(frames[:100], "/can0")
                                       + expected(frames[100:], "/can1")))
    # the same frames, one topic selected
    stats, cols = read(path, options={"topics": ["/can1"]})
    assert stats.channels == ["/can1"]
    close_ns(rows(stats, cols), expected(frames[100:], "/can1"))
    assert stats.ignored == 60 + 100


def test_topic_selection_errors(tmp_path: Path) -> None:
    path = tmp_path / "sel.mcap"
    write_ros2(path, {"/can": sample_frames(10)}, extra=[("/chatter", T0_NS, "hi")])
    opened = open_input(str(path), options={"topics": ["/nope"]})
    with pytest.raises(InputError) as exc:
        list(opened.batches)
    assert "--topic /nope: no such topic (topics: /can, /chatter)" in str(exc.value)
    opened = open_input(str(path), options={"topics": ["/chatter"]})
    with pytest.raises(InputError) as exc:
        list(opened.batches)
    assert "not a CAN topic (schema std_msgs/msg/String)" in str(exc.value)


def test_topic_option_on_the_command_line(tmp_path: Path) -> None:
    path = tmp_path / "two.mcap"
    write_ros2(path, {"/can0": sample_frames(50), "/can1": sample_frames(60, seed=3)})
    env = {**os.environ, "PYTHONPATH": str(REPO)}

    def run(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "nmtcheck", "check", str(path),
                               "--fail-on", "never", *args], capture_output=True, text=True,
                              cwd=tmp_path, env=env, timeout=120)

    res = run("--topic", "/can1")
    assert res.returncode == 0, res.stderr
    assert "60 frames" in res.stdout and "on 1 channel(s) /can1" in res.stdout
    res = run("--topic", "/can0", "--topic", "/can1")
    assert "110 frames" in res.stdout
    res = run("--topic", "/nope")
    assert res.returncode == 2
    assert res.stderr.strip().splitlines() == [
        f"nmtcheck: {path}: --topic /nope: no such topic (topics: /can0, /can1)"]


# --- FdFrame, ROS 1, protobuf ------------------------------------------------------------


def test_ros2_fd_frames(tmp_path: Path) -> None:
    from mcap_ros2.writer import Writer

    payloads = [bytes(range(12)), b"\x05", bytes(range(64))]
    path = tmp_path / "fd.mcap"
    with path.open("wb") as fh:
        writer = Writer(fh)
        schema = writer.register_msgdef("ros2_socketcan_msgs/msg/FdFrame", ROS2_FD_FRAME_MSG)
        for i, data in enumerate(payloads):
            t = T0_NS + i * 10**6
            writer.write_message("/from_can_bus_fd", schema, {
                "header": {"stamp": {"sec": t // 10**9, "nanosec": t % 10**9}, "frame_id": "can"},
                "id": 0x123 + i, "is_extended": i == 2, "is_error": False, "len": len(data),
                "data": data}, log_time=t + LATENCY_NS)
        writer.finish()
    stats, cols = read(path)
    close_ns(rows(stats, cols), [
        (T0_NS + i * 10**6, "/from_can_bus_fd", 0x123 + i, i == 2, False, False, True,
         len(d), d[:8]) for i, d in enumerate(payloads)])
    assert stats.fd_frames == 3


def test_ros1_frames(tmp_path: Path) -> None:
    from mcap_ros1._vendor.genpy import dynamic
    from mcap_ros1.writer import Writer

    frame_cls = dynamic.generate_dynamic("can_msgs/Frame", ROS1_FRAME_MSG)["can_msgs/Frame"]
    frames = sample_frames(80)
    path = tmp_path / "ros1.mcap"
    with path.open("wb") as fh:
        writer = Writer(fh)
        for f in frames:
            msg = frame_cls()
            msg.header.stamp.secs, msg.header.stamp.nsecs = divmod(f.t_ns, 10**9)
            msg.header.frame_id = "can0"
            msg.id, msg.is_rtr, msg.is_extended, msg.is_error = f.can_id, f.rtr, f.ext, f.err
            msg.dlc, msg.data = f.dlc, f.data.ljust(8, b"\0")
            writer.write_message("/received_messages", msg, log_time=f.t_ns + LATENCY_NS)
        writer.finish()
    stats, cols = read(path)
    close_ns(rows(stats, cols), expected(frames, "/received_messages"))


def _protobuf_frame_class() -> Any:
    """A protobuf CAN message built at run time: id, data bytes, flags, a header stamp."""
    from google.protobuf import descriptor_pb2, descriptor_pool
    from google.protobuf.message_factory import GetMessageClass

    fdp = descriptor_pb2.FileDescriptorProto(name="test_can.proto", package="testcan",
                                             syntax="proto3")
    stamp = fdp.message_type.add(name="Stamp")
    stamp.field.add(name="seconds", number=1, type=3, label=1)  # int64
    stamp.field.add(name="nanos", number=2, type=5, label=1)  # int32
    header = fdp.message_type.add(name="Header")
    header.field.add(name="stamp", number=1, type=11, label=1, type_name=".testcan.Stamp")
    frame = fdp.message_type.add(name="CanFrame")
    frame.field.add(name="header", number=1, type=11, label=1, type_name=".testcan.Header")
    frame.field.add(name="can_id", number=2, type=13, label=1)  # uint32
    frame.field.add(name="data", number=3, type=12, label=1)  # bytes
    frame.field.add(name="is_extended_id", number=4, type=8, label=1)
    frame.field.add(name="is_remote_frame", number=5, type=8, label=1)
    frame.field.add(name="is_error_frame", number=6, type=8, label=1)
    frame.field.add(name="dlc", number=7, type=13, label=1)
    other = fdp.message_type.add(name="Temperature")
    other.field.add(name="celsius", number=1, type=1, label=1)  # double
    pool = descriptor_pool.DescriptorPool()
    pool.Add(fdp)
    return (GetMessageClass(pool.FindMessageTypeByName("testcan.CanFrame")),
            GetMessageClass(pool.FindMessageTypeByName("testcan.Temperature")))


def test_protobuf_frames(tmp_path: Path) -> None:
    from mcap_protobuf.writer import Writer

    frame_cls, temperature_cls = _protobuf_frame_class()
    frames = sample_frames(90)
    path = tmp_path / "pb.mcap"
    with path.open("wb") as fh:
        writer = Writer(fh)
        for i, f in enumerate(frames):
            msg = frame_cls(can_id=f.can_id, data=f.data, is_extended_id=f.ext,
                            is_remote_frame=f.rtr, is_error_frame=f.err, dlc=f.dlc)
            msg.header.stamp.seconds, msg.header.stamp.nanos = divmod(f.t_ns, 10**9)
            writer.write_message("/can/pb", msg, log_time=f.t_ns + LATENCY_NS,
                                 publish_time=f.t_ns)
            if i % 10 == 0:
                writer.write_message("/temp", temperature_cls(celsius=21.5), log_time=f.t_ns,
                                     publish_time=f.t_ns)
        writer.finish()
    stats, cols = read(path)
    close_ns(rows(stats, cols), expected(frames, "/can/pb"))
    assert stats.ignored == 9


# --- JSON ----------------------------------------------------------------------------------


def write_json(path: Path, topics: dict[str, list[dict[str, Any] | str]], *,
               schema: dict[str, Any] | None = None, use_chunking: bool = True,
               compression: CompressionType = CompressionType.ZSTD) -> None:
    """JSON messages with the plain mcap writer; log time T0 + 1 ms per message."""
    with path.open("wb") as fh:
        w = McapWriter(fh, use_chunking=use_chunking, compression=compression)
        w.start(profile="", library="test")
        sid = 0
        if schema is not None:
            sid = w.register_schema("CanFrame", "jsonschema", json.dumps(schema).encode())
        channels = {t: w.register_channel(t, "json", sid) for t in topics}
        seq = 0
        for topic, msgs in topics.items():
            for i, msg in enumerate(msgs):
                t = T0_NS + i * 10**6
                raw = msg if isinstance(msg, str) else json.dumps(msg)
                w.add_message(channels[topic], log_time=t, publish_time=t, data=raw.encode(),
                              sequence=seq)
                seq += 1
        w.finish()


def test_json_field_spellings(tmp_path: Path) -> None:
    msgs: list[dict[str, Any] | str] = [
        {"id": 0x701, "data": [5]},
        {"can_id": 0x181, "data": "01 02 03", "is_extended": False},
        {"arbitration_id": 0x18DAF110, "is_extended_id": True, "data": "0102030405060708"},
        {"id": 0x705, "is_remote_frame": True, "dlc": 1, "data": []},
        {"id": 0x705, "is_rtr": True, "data": []},
        {"id": 0x80000123, "data": [1]},  # SocketCAN EFF flag left in the ID
        {"id": 0x1FFFFFF, "data": [1]},  # no flag: above 7FFh, so extended
        {"id": 0x123, "data": [1, 2, 3, 0, 0, 0, 0, 0], "dlc": 3},  # fixed array + dlc
        {"id": 0x124, "data": list(range(12)), "is_fd": True},
        {"id": 0x20000004, "data": [0, 0, 0, 0, 0, 0, 0, 0]},  # error frame by the flag bit
        {"id": 0x205, "data": "0x0a0b", "header": {"stamp": {"sec": 1_800_000_000,
                                                             "nanosec": 500_000_000}}},
    ]
    path = tmp_path / "json.mcap"
    write_json(path, {"/can_json": msgs})
    stats, cols = read(path)
    got = [r[2:] for r in rows(stats, cols)]
    assert got == [
        (0x701, False, False, False, False, 1, b"\x05"),
        (0x181, False, False, False, False, 3, b"\x01\x02\x03"),
        (0x18DAF110, True, False, False, False, 8, bytes(range(1, 9))),
        (0x705, False, True, False, False, 1, b""),
        (0x705, False, True, False, False, 0, b""),
        (0x123, True, False, False, False, 1, b"\x01"),
        (0x1FFFFFF, True, False, False, False, 1, b"\x01"),
        (0x123, False, False, False, False, 3, b"\x01\x02\x03"),
        (0x124, False, False, False, True, 12, bytes(range(8))),
        (0x004, False, False, True, False, 8, bytes(8)),
        (0x205, False, False, False, False, 2, b"\x0a\x0b"),
    ]
    ts = rows(stats, cols)
    assert ts[0][0] == T0_NS  # no header: the log time
    assert abs(ts[-1][0] - 1_800_000_000_500_000_000) < 300  # header.stamp wins
    assert stats.channels == ["/can_json"]


def test_json_channel_field_names_the_bus(tmp_path: Path) -> None:
    msgs: list[dict[str, Any] | str] = [
        {"id": 0x701, "data": [0], "channel": "can0"},
        {"id": 0x702, "data": [0], "channel": "can1"},
        {"id": 0x701, "data": [5], "channel": "can0"},
        {"id": 0x703, "data": [5]},
    ]
    path = tmp_path / "chan.mcap"
    write_json(path, {"/bus": msgs})
    stats, cols = read(path)
    assert stats.channels == ["/bus:can0", "/bus:can1", "/bus"]
    assert cols["chan"].tolist() == [0, 1, 0, 2]


def test_json_topics_without_schema_decided_by_first_message(tmp_path: Path) -> None:
    can_msgs: list[dict[str, Any] | str] = [{"id": 0x701, "data": [5]}] * 5
    can_msgs += ['{"id": 1793, "data": "zz"}', "not json",
                 {"id": 0x800, "is_extended": False, "data": [1]}, {"data": [1]}]
    weather: list[dict[str, Any] | str] = [{"temperature": 21.0, "data": [1]}] * 4
    path = tmp_path / "noschema.mcap"
    write_json(path, {"/can": can_msgs, "/weather": weather})
    stats, _cols = read(path)
    assert stats.frames == 5
    assert stats.ignored == 4
    assert stats.skipped == 4  # bad hex, not JSON, an 11-bit ID above 7FFh, no ID
    with pytest.raises(InputError) as exc:
        list(open_input(str(path), strict=True).batches)
    assert "/can: data is not a hex string" in str(exc.value)


def test_json_schema_properties_decide(tmp_path: Path) -> None:
    schema = {"type": "object", "properties": {"can_id": {"type": "integer"},
                                               "data": {"type": "array"}}}
    path = tmp_path / "schema.mcap"
    write_json(path, {"/can": [{"can_id": 0x181, "data": [1, 2]}]}, schema=schema)
    stats, cols = read(path)
    assert rows(stats, cols)[0][2:] == (0x181, False, False, False, False, 2, b"\x01\x02")
    other = {"type": "object", "properties": {"speed": {"type": "number"}}}
    path2 = tmp_path / "other.mcap"
    write_json(path2, {"/speed": [{"speed": 3.0}] * 3}, schema=other)
    stats2, _ = read(path2)
    assert (stats2.frames, stats2.ignored) == (0, 3)


# --- file structure: chunking, compression, damage ----------------------------------------


@pytest.mark.parametrize("use_chunking,compression", [
    (False, CompressionType.NONE), (True, CompressionType.LZ4), (True, CompressionType.NONE),
])
def test_chunking_and_compression_variants(tmp_path: Path, use_chunking: bool,
                                           compression: CompressionType) -> None:
    msgs: list[dict[str, Any] | str] = [{"id": 0x700 + i % 100, "data": [i % 256]}
                                        for i in range(3000)]
    ref = tmp_path / "ref.mcap"
    write_json(ref, {"/can": msgs})
    path = tmp_path / "variant.mcap"
    write_json(path, {"/can": msgs}, use_chunking=use_chunking, compression=compression)
    a, ca = read(ref)
    b, cb = read(path)
    assert a.frames == b.frames == 3000
    for name in ca:
        np.testing.assert_array_equal(ca[name], cb[name], err_msg=name)


def test_gzip_compressed_mcap_reads_as_a_stream(tmp_path: Path) -> None:
    frames = sample_frames(400)
    path = tmp_path / "bag.mcap"
    write_ros2(path, {"/can": frames}, chunk_size=2048)
    packed = tmp_path / "bag.mcap.gz"
    packed.write_bytes(gzip.compress(path.read_bytes()))
    _a, ca = read(path)
    b, cb = read(packed)
    assert b.format == "mcap" and b.frames == 400
    for name in ca:
        np.testing.assert_array_equal(ca[name], cb[name], err_msg=name)


def test_truncated_recording_keeps_complete_chunks(tmp_path: Path) -> None:
    frames = sample_frames(3000)
    path = tmp_path / "bag.mcap"
    write_ros2(path, {"/can": frames}, chunk_size=8192)
    raw = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(raw[: len(raw) // 2])
    stats, cols = read(cut)
    assert 0 < stats.frames < 3000
    assert stats.skipped == 1  # the chunk that was cut
    close_ns(rows(stats, cols), expected(frames[: stats.frames], "/can"))
    with pytest.raises(InputError) as exc:
        list(open_input(str(cut), strict=True).batches)
    assert "truncated record" in str(exc.value)


def test_sniff() -> None:
    assert detect_format(mcaplog.MAGIC + b"\x01" + bytes(20)) == "mcap"
    assert not mcaplog.sniff(b"(1.0) can0 123#00\n")
