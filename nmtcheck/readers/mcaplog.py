"""MCAP recordings of CAN traffic: ROS 2 / ROS 1 bags, protobuf and JSON messages.

Each topic is a channel (one CANopen network); `--topic` picks topics.
Understood topics: ROS 2 `can_msgs/msg/Frame` (ros2_socketcan, CDR),
`ros2_socketcan_msgs/msg/FdFrame`, ROS 1 `can_msgs/Frame`, protobuf messages
with an id and a data field, and JSON messages (`id`/`can_id`/`arbitration_id`,
`data` as a list or hex string, `is_rtr`/`is_remote_frame`,
`is_extended`/`is_extended_id`, `is_error`/`is_error_frame`, `is_fd`, `dlc`,
optional `channel`, which makes `topic:channel` the channel). Messages of
every other topic are counted as ignored.

The time of a frame is the message's `header.stamp` when it has a non-zero
one (the MCAP log time adds the recorder's latency), else the log time.

Speed: ROS 2 `can_msgs/msg/Frame` has a fixed CDR layout, so when a topic's
schema is exactly that message, its frames are decoded from each chunk with
numpy (tens of thousands at a time); other schemas and byte orders go through
the mcap support libraries one message at a time. The file is read as a
stream, record by record, so compressed inputs work too.
"""

from __future__ import annotations

import contextlib
import io
import json
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import IO, Any

import numpy as np

from nmtcheck.errors import InputError
from nmtcheck.readers.binary import (
    BatchCollector,
    ChannelNames,
    Frames,
    RecordRuns,
    field,
    split_seconds,
    strided_rows,
    zero_beyond,
)
from nmtcheck.readers.frames import FrameBatch
from nmtcheck.readers.source import Source
from nmtcheck.readers.stats import InputStats

MAGIC = b"\x89MCAP0\r\n"
OP_FOOTER = 0x02
OP_SCHEMA = 0x03
OP_CHANNEL = 0x04
OP_MESSAGE = 0x05
OP_CHUNK = 0x06
MESSAGE_FIXED = 22  # channel id, sequence, log time, publish time
MESSAGE_DATA = 9 + MESSAGE_FIXED  # offset of the payload in a message record
MAX_RECORD = 4 << 30
LOOSE_FLUSH_BYTES = 8 << 20  # messages outside chunks are decoded in pieces this large
CAN_EFF_FLAG = 0x80000000
CAN_RTR_FLAG = 0x40000000
CAN_ERR_FLAG = 0x20000000
CAN_EFF_MASK = 0x1FFFFFFF

ROS2_FRAME = "can_msgs/msg/Frame"
ROS2_FD_FRAME = "ros2_socketcan_msgs/msg/FdFrame"
ROS1_FRAME = "can_msgs/Frame"
_ROS2_FRAME_FIELDS = [
    ("std_msgs/Header", "header"), ("uint32", "id"), ("bool", "is_rtr"),
    ("bool", "is_extended"), ("bool", "is_error"), ("uint8", "dlc"), ("uint8[8]", "data"),
]
_ROS2_DEPENDENCIES = {
    "std_msgs/Header": [("builtin_interfaces/Time", "stamp"), ("string", "frame_id")],
    "builtin_interfaces/Time": [("int32", "sec"), ("uint32", "nanosec")],
}
_ID_FIELDS = ("id", "can_id", "arbitration_id")

IGNORED = "ignored"  # not a CAN topic, or not selected by --topic
ROS2_FAST = "ros2-frame"  # the fixed CDR layout, decoded with numpy
OBJECTS = "objects"  # decoded message by message by a library (or json)
UNDECIDED_JSON = "json?"  # JSON without a usable schema: the first message decides


def sniff(head: bytes) -> bool:
    return head.startswith(MAGIC)


class _Bad(Exception):
    """A CAN message that cannot be turned into a frame."""


@dataclass
class _Topic:
    topic: str
    kind: str
    schema_name: str
    decode: Callable[[bytes], Any] | None = None
    fd: bool = False  # every message is a CAN FD frame (FdFrame)
    cdr_decoder: Callable[[bytes], Any] | None = None  # ROS2_FAST: for messages not CDR_LE


def _norm_type(name: str) -> str:
    """`std_msgs/msg/Header` and `Header` are the same type as `std_msgs/Header`."""
    if name == "Header":
        return "std_msgs/Header"
    return name.replace("/msg/", "/")


def ros2_fields(text: str) -> dict[str, list[tuple[str, str]]]:
    """The fields of a ros2msg schema: "" the message itself, then each `MSG:` dependency."""
    sections: dict[str, list[tuple[str, str]]] = {}
    name = ""
    fields: list[tuple[str, str]] = []
    for raw in text.splitlines():
        if raw.startswith("==="):
            sections[name] = fields
            name, fields = "", []
            continue
        line = raw.split("#", 1)[0].strip()
        if line.startswith("MSG:"):
            name = _norm_type(line[4:].strip())
            continue
        parts = line.split()
        if len(parts) < 2 or "=" in parts[1] or (len(parts) > 2 and parts[2].startswith("=")):
            continue  # blank, or a constant: no bytes in the message
        fields.append((_norm_type(parts[0]), parts[1]))
    sections[name] = fields
    return sections


def is_known_ros2_frame(text: str) -> bool:
    """The schema is ros2_socketcan's can_msgs/msg/Frame, whose CDR layout the fast path knows."""
    sections = ros2_fields(text)
    if sections.get("") != _ROS2_FRAME_FIELDS:
        return False
    return all(sections.get(dep, fields) == fields for dep, fields in _ROS2_DEPENDENCIES.items())


def _get(msg: Any, name: str) -> Any:
    if isinstance(msg, dict):
        return msg.get(name)
    return getattr(msg, name, None)


def _first(msg: Any, names: tuple[str, ...]) -> Any:
    for name in names:
        value = _get(msg, name)
        if value is not None:
            return value
    return None


def _integer(value: Any, what: str) -> int:
    if isinstance(value, bool) or value is None:
        raise _Bad(f"{what} is not an integer")
    if isinstance(value, int):
        return value
    if isinstance(value, str):
        try:
            return int(value.strip(), 0)
        except ValueError:
            raise _Bad(f"{what} {value!r} is not an integer") from None
    try:
        return int(value)  # numpy integers
    except (TypeError, ValueError, OverflowError):  # OverflowError: a JSON `Infinity`
        raise _Bad(f"{what} is not an integer") from None


def _payload(value: Any) -> bytes:
    """`data` as bytes: bytes, a list of byte values, or a hex string ("0102", "01 02", "01:02")."""
    if value is None:
        return b""
    if isinstance(value, (bytes, bytearray, memoryview)):
        return bytes(value)
    if isinstance(value, str):
        text = value.strip()
        if text[:2].lower() == "0x":
            text = text[2:]
        for sep in (" ", ":", "-", ","):
            text = text.replace(sep, "")
        try:
            return bytes.fromhex(text)
        except ValueError:
            raise _Bad("data is not a hex string") from None
    try:
        values = [_integer(v, "data byte") for v in value]
    except TypeError:
        raise _Bad("data is neither bytes, a list nor a hex string") from None
    if any(v < 0 or v > 0xFF for v in values):
        raise _Bad("data byte out of range 0..255")
    return bytes(values)


def _stamp(msg: Any) -> float | None:
    """`header.stamp` in seconds (ROS 2 sec/nanosec, ROS 1 secs/nsecs, protobuf seconds/nanos);
    None when absent or zero (not filled in by the producer)."""
    header = _get(msg, "header")
    stamp = _get(header, "stamp") if header is not None else None
    if stamp is None:
        return None
    sec = _first(stamp, ("sec", "secs", "seconds"))
    nsec = _first(stamp, ("nanosec", "nsecs", "nanos"))
    if sec is None and nsec is None:
        return None
    sec = _integer(sec or 0, "header.stamp seconds")
    nsec = _integer(nsec or 0, "header.stamp nanoseconds")
    if abs(sec) >= 1 << 63 or abs(nsec) >= 1 << 63:  # JSON integers have no limit
        raise _Bad("header.stamp out of range")
    if sec == 0 and nsec == 0:
        return None
    return sec + nsec * 1e-9


def frame_from_message(msg: Any, fd_type: bool
                       ) -> tuple[float | None, Any, int, bool, bool, bool, bool, int, bytes]:
    """(stamp, channel, id, ext, rtr, err, fd, dlc, data) of one decoded CAN message."""
    raw_id = _first(msg, _ID_FIELDS)
    if raw_id is None:
        raise _Bad("no id/can_id/arbitration_id field")
    can_id = _integer(raw_id, "CAN-ID")
    if can_id < 0 or can_id > 0xFFFFFFFF:
        raise _Bad("CAN-ID out of range")
    flags = can_id & ~CAN_EFF_MASK  # SocketCAN flag bits, if the producer left them in the ID
    can_id &= CAN_EFF_MASK
    rtr = bool(_first(msg, ("is_rtr", "is_remote_frame")) or flags & CAN_RTR_FLAG)
    err = bool(_first(msg, ("is_error", "is_error_frame")) or flags & CAN_ERR_FLAG)
    ext_field = _first(msg, ("is_extended", "is_extended_id"))
    if ext_field is None:  # no flag given: a value above 7FFh can only be a 29-bit ID
        ext = bool(flags & CAN_EFF_FLAG) or can_id > 0x7FF
    else:
        ext = bool(ext_field) or bool(flags & CAN_EFF_FLAG)
    if err:
        ext = False
    elif not ext and can_id > 0x7FF:
        raise _Bad("11-bit CAN-ID above 7FFh")
    fd = fd_type or bool(_get(msg, "is_fd"))
    data = b"" if rtr else _payload(_get(msg, "data"))
    raw_dlc = _first(msg, ("dlc", "len"))
    dlc = len(data) if raw_dlc is None else _integer(raw_dlc, "dlc")
    if dlc < 0 or dlc > 64:
        raise _Bad(f"dlc {dlc} out of range")
    if not rtr:
        if not fd and dlc > 8 and len(data) == 8 and dlc <= 15:
            dlc = 8  # classic DLC codes 9..15 mean 8 bytes
        if dlc > len(data):
            raise _Bad(f"dlc {dlc} but {len(data)} data bytes")
        data = data[:dlc]
        if dlc > 8:
            fd = True  # more than 8 bytes can only be CAN FD
    elif dlc > 15 and not fd:
        raise _Bad(f"remote frame dlc {dlc} above 15")
    elif dlc > 8 and not fd:
        dlc = 8
    return _stamp(msg), _get(msg, "channel"), can_id, ext, rtr, err, fd, dlc, data


def _json_is_can(value: Any) -> bool:
    return isinstance(value, dict) and any(k in value for k in _ID_FIELDS) and "data" in value


READ_PIECE = 16 << 20  # a damaged length field must not make one read allocate gigabytes


def _read_exact(stream: Any, n: int) -> bytes:
    """n bytes, or fewer at the end of the input; read in pieces, so memory follows the
    bytes that are really there, not the length a damaged record claims."""
    parts = []
    got = 0
    while got < n:
        chunk = stream.read(min(n - got, READ_PIECE))
        if not chunk:
            break
        parts.append(chunk)
        got += len(chunk)
    return b"".join(parts)


class _McapFrames:
    """One MCAP input read as a stream of records."""

    def __init__(self, source: Source, stats: InputStats) -> None:
        from mcap.records import Channel, Schema

        self._schema_cls = Schema
        self._channel_cls = Channel
        self.source = source
        self.stats = stats
        wanted = source.options.get("topics") or []
        self.selected: set[str] | None = set(wanted) if wanted else None
        self.schemas: dict[int, Any] = {}
        self.topics: dict[int, _Topic] = {}
        self.seen_topics: dict[str, _Topic] = {}
        self.names = ChannelNames(stats)
        self.out = BatchCollector(stats)
        self._ros2_factory: Any = None
        self._ros1_factory: Any = None
        self._protobuf_factory: Any = None

    # --- records -------------------------------------------------------------------------

    def batches(self) -> Iterator[FrameBatch]:
        stream = self.source.stream
        loose = bytearray()
        try:
            if _read_exact(stream, len(MAGIC)) != MAGIC:
                raise InputError(self.source.path, "not an MCAP file (bad magic)")
            while (record := self._next_record(stream)) is not None:
                opcode, head, body = record
                if opcode == OP_MESSAGE:
                    loose += head
                    loose += body
                    if len(loose) >= LOOSE_FLUSH_BYTES:
                        yield from self._records(bytes(loose))
                        loose.clear()
                    continue
                if loose:
                    yield from self._records(bytes(loose))
                    loose.clear()
                if opcode == OP_FOOTER:
                    break
                yield from self._record(opcode, body)
        except self.source.errors as exc:
            raise InputError(self.source.path,
                             f"read error (truncated or corrupt file?): {exc}") from None
        if loose:
            yield from self._records(bytes(loose))
        if (batch := self.out.take()) is not None:
            yield batch
        self._check_selected_topics()

    def _next_record(self, stream: IO[bytes]) -> tuple[int, bytes, bytes] | None:
        """(opcode, header, body) of the next record; None where the file ends without a
        footer or with a record cut short (the input is then truncated)."""
        head = _read_exact(stream, 9)
        if not head:
            # no footer: a recording that was not closed; what is there counts
            self.stats.truncated = True
            return None
        if len(head) < 9:
            self.stats.truncated = True
            self.stats.skip(0, "truncated record at the end of the file")
            return None
        opcode, length = struct.unpack("<BQ", head)
        if length > MAX_RECORD:
            self.stats.truncated = True
            self.stats.skip(0, f"record length {length} is beyond 4 GiB: corrupt file, "
                               "rest not read")
            return None
        body = _read_exact(stream, length)
        if len(body) < length:
            self.stats.truncated = True
            self.stats.skip(0, "truncated record at the end of the file")
            return None
        return opcode, head, body

    def _record(self, opcode: int, body: bytes) -> Iterator[FrameBatch]:
        """A record other than a message or the footer: a chunk's messages, a schema, a
        channel; the others say nothing about CAN frames."""
        if opcode == OP_CHUNK:
            records = self._chunk_records(body)
            if records is not None:
                yield from self._records(records)
        elif opcode == OP_SCHEMA:
            self._schema(body)
        elif opcode == OP_CHANNEL:
            self._channel(body)

    def _check_selected_topics(self) -> None:
        if self.selected is None:
            return
        for topic in sorted(self.selected):
            seen = self.seen_topics.get(topic)
            if seen is None:
                names = ", ".join(sorted(self.seen_topics)) or "none"
                raise InputError(self.source.path, f"--topic {topic}: no such topic "
                                 f"(topics: {names})")
            if seen.kind == IGNORED:
                raise InputError(self.source.path, f"--topic {topic}: not a CAN topic "
                                 f"(schema {seen.schema_name or 'none'})")

    def _chunk_records(self, body: bytes) -> bytes | None:
        """The records of a chunk, decompressed; None (and a skipped record) if damaged."""
        try:
            usize = struct.unpack_from("<Q", body, 16)[0]
            clen = struct.unpack_from("<I", body, 28)[0]
            compression = body[32 : 32 + clen].decode()
            rlen = struct.unpack_from("<Q", body, 32 + clen)[0]
            start = 40 + clen
            data = body[start : start + rlen]
            if len(data) != rlen:
                raise ValueError("records length beyond the chunk")
        except (struct.error, UnicodeDecodeError, ValueError) as exc:
            self.stats.skip(0, f"malformed chunk: {exc}")
            return None
        if compression == "":
            return data
        if compression not in ("zstd", "lz4"):
            raise InputError(self.source.path, f"chunk compression {compression!r} is not "
                             "supported (zstd, lz4 or none)")
        try:
            if compression == "zstd":
                import zstandard

                out = zstandard.ZstdDecompressor().decompress(data, max_output_size=usize)
            else:
                import lz4.frame

                out = lz4.frame.decompress(data)
        except Exception as exc:  # each codec raises its own error types
            self.stats.skip(0, f"corrupt {compression} chunk: {exc}")
            return None
        if len(out) != usize:
            self.stats.skip(0, "chunk decompresses to the wrong size")
            return None
        return out

    def _schema(self, body: bytes) -> None:
        from mcap.data_stream import ReadDataStream
        from mcap.exceptions import McapError

        try:
            schema = self._schema_cls.read(ReadDataStream(io.BytesIO(body)))
        except (struct.error, UnicodeDecodeError, McapError) as exc:
            self.stats.skip(0, f"malformed schema record: {exc}")
            return
        self.schemas[schema.id] = schema

    def _channel(self, body: bytes) -> None:
        from mcap.data_stream import ReadDataStream
        from mcap.exceptions import McapError

        try:
            channel = self._channel_cls.read(ReadDataStream(io.BytesIO(body)))
        except (struct.error, UnicodeDecodeError, McapError) as exc:
            self.stats.skip(0, f"malformed channel record: {exc}")
            return
        if channel.id in self.topics:
            return  # the summary section repeats the channels
        topic = self._classify(channel)
        self.topics[channel.id] = topic
        self.seen_topics.setdefault(topic.topic, topic)

    def _classify(self, channel: Any) -> _Topic:
        """How the messages of a channel become frames (or why they are ignored)."""
        schema = self.schemas.get(channel.schema_id)
        topic = _Topic(channel.topic, IGNORED, schema.name if schema is not None else "")
        if self.selected is not None and channel.topic not in self.selected:
            return topic
        # mcap_ros2's schema parser prints its complaints about a damaged schema to stderr;
        # the damage is reported as skipped messages, and stderr is for exit-2 messages only
        with contextlib.redirect_stderr(io.StringIO()):
            self._decoders(topic, channel, schema)
        return topic

    def _decoders(self, topic: _Topic, channel: Any, schema: Any) -> None:
        """Set how the topic's messages are decoded, from its encoding and schema."""
        name = topic.schema_name
        enc = channel.message_encoding
        senc = schema.encoding if schema is not None else ""
        try:
            if enc == "json":
                self._classify_json(topic, schema)
            elif schema is None:
                pass  # the other encodings cannot be decoded without their schema
            elif enc == "cdr" and senc == "ros2msg" and name in (ROS2_FRAME, ROS2_FD_FRAME):
                decoder = self._ros2_decoder(schema)
                if name == ROS2_FRAME and is_known_ros2_frame(schema.data.decode()):
                    topic.kind, topic.cdr_decoder = ROS2_FAST, decoder
                else:
                    topic.kind, topic.decode, topic.fd = OBJECTS, decoder, name == ROS2_FD_FRAME
            elif enc == "ros1" and senc == "ros1msg" and name == ROS1_FRAME:
                if self._ros1_factory is None:
                    from mcap_ros1.decoder import DecoderFactory as Ros1Factory

                    self._ros1_factory = Ros1Factory()
                topic.kind = OBJECTS
                topic.decode = self._ros1_factory.decoder_for(enc, schema)
            elif enc == "protobuf" and senc == "protobuf":
                self._classify_protobuf(topic, schema)
        except Exception as exc:  # a schema the library cannot parse: every message is skipped
            why = f"{channel.topic}: schema {name!r} cannot be used: {exc}"

            def broken(_data: bytes) -> Any:
                raise _Bad(why)

            topic.kind, topic.decode = OBJECTS, broken

    def _ros2_decoder(self, schema: Any) -> Callable[[bytes], Any]:
        if self._ros2_factory is None:
            from mcap_ros2.decoder import DecoderFactory as Ros2Factory

            self._ros2_factory = Ros2Factory()
        decoder: Callable[[bytes], Any] | None = self._ros2_factory.decoder_for("cdr", schema)
        assert decoder is not None
        return decoder

    def _classify_protobuf(self, topic: _Topic, schema: Any) -> None:
        if self._protobuf_factory is None:
            from mcap_protobuf.decoder import DecoderFactory as ProtobufFactory

            self._protobuf_factory = ProtobufFactory()
        decode = self._protobuf_factory.decoder_for("protobuf", schema)
        if decode is None:
            return
        fields = _protobuf_fields(schema)
        if fields is not None and "data" in fields and any(f in fields for f in _ID_FIELDS):
            topic.kind, topic.decode = OBJECTS, decode

    def _classify_json(self, topic: _Topic, schema: Any) -> None:
        topic.decode = json.loads
        properties = None
        if schema is not None and schema.encoding == "jsonschema":
            try:
                properties = json.loads(schema.data).get("properties")
            except (ValueError, AttributeError):
                properties = None
        if isinstance(properties, dict):
            topic.kind = OBJECTS if _json_is_can(properties) else IGNORED
        else:
            topic.kind = UNDECIDED_JSON

    # --- messages ------------------------------------------------------------------------

    def _records(self, buf: bytes) -> Iterator[FrameBatch]:
        """Decode one run of records (a chunk's, or messages outside chunks)."""
        arr = np.frombuffer(buf, np.uint8)
        end = len(buf)
        found = RecordRuns()
        pos = 0
        while pos < end:
            if end - pos < 9:
                self.stats.skip(0, "truncated record in a chunk")
                break
            opcode = buf[pos]
            length = int.from_bytes(buf[pos + 1 : pos + 9], "little")
            stride = 9 + length
            if stride > end - pos:
                self.stats.skip(0, "truncated record in a chunk")
                break
            if opcode == OP_MESSAGE:
                pos = found.add(buf, arr, pos, stride, end, 0, 9)  # key: opcode and length
                continue
            if opcode == OP_SCHEMA:
                self._schema(buf[pos + 9 : pos + stride])
            elif opcode == OP_CHANNEL:
                self._channel(buf[pos + 9 : pos + stride])
            pos += stride
        if found.total == 0:
            return
        frames = Frames(found.total)
        for stride, starts, out in found.groups():
            if stride - 9 < MESSAGE_FIXED:
                for _ in range(len(starts)):
                    self.stats.skip(0, "message record shorter than its fixed fields")
                continue
            self._messages(buf, strided_rows(arr, starts, stride), starts, out, frames)
        self.names.finish(frames)
        self.out.add(frames)
        if self.out.ready and (batch := self.out.take()) is not None:
            yield batch

    def _messages(self, buf: bytes, rows: np.ndarray, starts: np.ndarray, out: np.ndarray,
                  frames: Frames) -> None:
        """Message records of one size, one per row of `rows`, go to their channel's decoder."""
        chan_ids = field(rows, 9, 2)
        log_ns = field(rows, 15, 8)
        first = int(chan_ids[0])
        groups = ([first] if bool((chan_ids == first).all())
                  else np.unique(chan_ids).tolist())
        for cid in groups:
            if len(groups) == 1:
                sel: slice | np.ndarray = slice(None)
            else:
                sel = np.flatnonzero(chan_ids == cid)
            n = len(out[sel])
            topic = self.topics.get(cid)
            if topic is None:
                for _ in range(n):
                    self.stats.skip(0, f"message on channel {cid}, which was never defined")
            elif topic.kind == IGNORED:
                self.stats.ignored += n
            elif topic.kind == ROS2_FAST:
                self._ros2_frames(topic, buf, rows[sel, MESSAGE_DATA:], starts[sel],
                                  log_ns[sel], out[sel], frames)
            else:
                self._object_frames(topic, buf, starts[sel], rows.shape[1] - 9, log_ns[sel],
                                    out[sel], frames)

    def _ros2_frames(self, topic: _Topic, buf: bytes, payload: np.ndarray, starts: np.ndarray,
                     log_ns: np.ndarray, out: np.ndarray, frames: Frames) -> None:
        """ros2_socketcan can_msgs/msg/Frame messages of one size, decoded with numpy.

        CDR_LE after the 4-byte encapsulation header: stamp (int32 sec, uint32
        nanosec), frame_id (uint32 length incl. NUL, chars), padding to 4,
        uint32 id, bool is_rtr, bool is_extended, bool is_error, uint8 dlc,
        uint8[8] data.
        """
        size = payload.shape[1]
        fast = np.zeros(len(out), bool)
        id_at = np.zeros(len(out), np.int64)
        if size >= 36:  # header, a 1-byte frame_id, the frame fields
            fast = (payload[:, 0] == 0) & (payload[:, 1] == 1)
            id_at = 4 + ((12 + field(payload, 12, 4).astype(np.int64) + 3) & ~3)
            fast &= id_at + 16 <= size
        if not fast.all():  # other byte orders and odd sizes: the library decides
            slow = np.flatnonzero(~fast)
            fallback = _Topic(topic.topic, OBJECTS, topic.schema_name, topic.cdr_decoder)
            self._object_frames(fallback, buf, starts[slow], size + MESSAGE_FIXED, log_ns[slow],
                                out[slow], frames)
            if not fast.any():
                return
        code = self.names.provisional(topic.topic)
        layouts = [int(id_at[0])] if bool((id_at == id_at[0]).all()) else np.unique(
            id_at[fast]).tolist()
        for at in layouts:
            if len(layouts) == 1 and fast.all():
                sel: slice | np.ndarray = slice(None)
            else:
                sel = np.flatnonzero(fast & (id_at == at))
            rows = payload[sel]
            # three 8-byte words per message: fewer passes over the strided rows
            stamp = field(rows, 4, 8)
            sec = (stamp & 0xFFFFFFFF).astype(np.uint32).view(np.int32).astype(np.int64)
            nsec = (stamp >> np.uint64(32)).astype(np.int64)
            word = field(rows, at, 8)
            can_id = (word & 0xFFFFFFFF).astype(np.uint32)
            flags = (word >> np.uint64(32)).astype(np.uint32)
            rtr = (flags & 0xFF) != 0
            err = (flags & 0xFF0000) != 0
            ext = ((flags & 0xFF00) != 0) & ~err
            dlc = (flags >> 24).astype(np.int16)
            data = field(rows, at + 8, 8).view(np.uint8).reshape(-1, 8)
            stamped = stamp != 0
            ts = np.where(stamped, sec + nsec * 1e-9, split_seconds(log_ns[sel], 10**9))
            rows_out = out[sel]
            bad_id = ~ext & ~err & (can_id > 0x7FF)
            bad_dlc = dlc > 15
            if bad_id.any() or bad_dlc.any():
                for _ in range(int(np.count_nonzero(bad_id))):
                    self.stats.skip(0, f"{topic.topic}: 11-bit CAN-ID above 7FFh")
                for _ in range(int(np.count_nonzero(bad_dlc & ~bad_id))):
                    self.stats.skip(0, f"{topic.topic}: dlc above 15")
                good = ~bad_id & ~bad_dlc
                rows_out, ts, can_id, ext, rtr, err, dlc, data = (
                    a[good] for a in (rows_out, ts, can_id, ext, rtr, err, dlc, data))
            dlc = np.minimum(dlc, 8)
            zero_beyond(data, np.where(rtr, 0, dlc))
            frames.ts[rows_out] = ts
            frames.chan[rows_out] = code
            frames.can_id[rows_out] = can_id & np.where(ext | err, CAN_EFF_MASK, 0x7FF)
            frames.ext[rows_out] = ext
            frames.rtr[rows_out] = rtr
            frames.err[rows_out] = err
            frames.dlc[rows_out] = dlc
            frames.data[rows_out] = data
            frames.keep[rows_out] = True

    def _object_frames(self, topic: _Topic, buf: bytes, starts: np.ndarray, length: int,
                       log_ns: np.ndarray, rows_out: np.ndarray, frames: Frames) -> None:
        """Messages (records of `length` bytes) decoded one at a time by a library or as JSON;
        only their frames are kept."""
        stats = self.stats
        for start, t_ns, row in zip(starts.tolist(), log_ns.tolist(), rows_out.tolist(),
                                    strict=True):
            payload = buf[start + MESSAGE_DATA : start + 9 + length]
            if topic.kind == IGNORED:
                stats.ignored += 1
                continue
            try:
                assert topic.decode is not None
                msg = topic.decode(payload)
            except Exception as exc:  # each library raises its own decode errors
                stats.skip(0, f"{topic.topic}: cannot decode message: {exc}")
                continue
            if topic.kind == UNDECIDED_JSON:
                topic.kind = OBJECTS if _json_is_can(msg) else IGNORED
                if topic.kind == IGNORED:
                    stats.ignored += 1
                    continue
            try:
                stamp, channel, can_id, ext, rtr, err, fd, dlc, data = frame_from_message(
                    msg, topic.fd)
            except _Bad as exc:
                stats.skip(0, f"{topic.topic}: {exc}")
                continue
            name = topic.topic if channel in (None, "") else f"{topic.topic}:{channel}"
            ts = stamp if stamp is not None else t_ns // 10**9 + (t_ns % 10**9) * 1e-9
            frames.put(row, ts, self.names.provisional(name), can_id, ext, rtr, err, fd, dlc,
                       data)


def _protobuf_fields(schema: Any) -> set[str] | None:
    """Field names of the protobuf message type a schema names (None if it is not found)."""
    from google.protobuf.descriptor_pb2 import FileDescriptorSet

    fds = FileDescriptorSet.FromString(schema.data)
    for fd in fds.file:
        prefix = f"{fd.package}." if fd.package else ""
        stack = [(prefix + m.name, m) for m in fd.message_type]
        while stack:
            full, message = stack.pop()
            if full == schema.name:
                return {f.name for f in message.field}
            stack.extend((full + "." + n.name, n) for n in message.nested_type)
    return None


def read(source: Source, stats: InputStats) -> Iterator[FrameBatch]:
    yield from _McapFrames(source, stats).batches()
