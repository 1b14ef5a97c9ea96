"""Vector BLF (binary logging format) as written by CANoe/CANalyzer, python-can and TSMaster.

A `LOGG` file header, then objects (`LOBJ`), normally log containers whose
payload (zlib-compressed or plain) is a stream of objects that may straddle
container boundaries. Read: CAN_MESSAGE (1), CAN_MESSAGE2 (86), CAN_FD_MESSAGE
(100), CAN_FD_MESSAGE_64 (101) with their RTR/extended/direction flags and
1-based channel numbers, and the error objects CAN_ERROR (2), CAN_ERROR_EXT (73)
and CAN_FD_ERROR_64 (104), counted as error frames. DATA_LOST_END (126) adds its
count of lost events to the dropped frames, placed at its timestamp and the next frame
(the `frames_lost` cause); every other object is a non-frame
record (ignored). Object header versions 1 and 2 are read; a frame object with
any other version is reported as skipped, never silently dropped.

Speed: containers are decompressed in C (zlib) and a few MB of object stream are
parsed at once with numpy: a stretch of equal-sized objects (python-can's and most
loggers' files) is checked at its stride without a signature search, headers and
bodies are gathered as whole records through byte-strided views (one gather each,
not one per byte: 2 M frames read in half the time); Python touches single objects
only for the unusual ones (lost-data records, corrupt or unsupported objects).
Timestamps are the file header's start time (SYSTEMTIME, read as UTC, as python-can
does; 0 when the header has none) plus each object's offset, so they match python-can's
numbers.

Damage is reported, not fatal (unless --strict): an object with a size below its
header (size 0 hangs python-can's BLFReader forever), a bad signature, a damaged
container or a truncated file are counted as skipped and the reader resynchronises
at the next `LOBJ` signature. Skip locations are 1-based object numbers in the
object stream (a binary file has no lines).

Where python-can 4.6.1 differs: its channels are 0-based (`channel - 1`), nmtcheck
keeps the number in the file; a CAN_FD_MESSAGE(_64) without the EDL flag is a
classic frame whose DLC stays as written (python-can applies the FD length table:
DLC 13 becomes 32); an FD frame is never remote (python-can reports objects with
both EDL and RTR set as remote FD frames); error frames are never extended.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Generator, Iterator
from dataclasses import dataclass
from datetime import datetime, timezone

import numpy as np

from nmtcheck.errors import InputError
from nmtcheck.readers.frames import FrameBatch
from nmtcheck.readers.source import Source
from nmtcheck.readers.stats import InputStats, account

SIGNATURE = b"LOBJ"
FILE_SIGNATURE = b"LOGG"
FILE_HEADER_MIN = 72  # signature … start/stop SYSTEMTIME; the file says how long it really is
BASE_HEADER = struct.Struct("<4sHHLL")  # signature, header size, header version, object size, type
CONTAINER_HEADER = struct.Struct("<H6xL4x")  # compression method, uncompressed size

LOG_CONTAINER = 10
CAN_MESSAGE = 1
CAN_ERROR = 2
CAN_ERROR_EXT = 73
CAN_MESSAGE2 = 86
CAN_FD_MESSAGE = 100
CAN_FD_MESSAGE_64 = 101
CAN_FD_ERROR_64 = 104
DATA_LOST_END = 126

NO_COMPRESSION = 0
ZLIB_DEFLATE = 2

HEADER_SIZE_BY_VERSION = {1: 32, 2: 40}  # base header + ObjectHeader / ObjectHeader2
TIME_TEN_MICS = 1  # object header flag: timestamp in 10 µs units (else ns)

# Bytes an object needs after its header for the fields read here.
MIN_BODY = {CAN_MESSAGE: 16, CAN_MESSAGE2: 16, CAN_FD_MESSAGE: 20, CAN_FD_MESSAGE_64: 40,
            CAN_ERROR: 2, CAN_ERROR_EXT: 20, CAN_FD_ERROR_64: 16}
FRAME_TYPES = np.array(sorted(MIN_BODY), np.uint32)

CAN_MSG_EXT = 0x80000000
CAN_ID_MASK = 0x1FFFFFFF
MSG_FLAG_RTR = 0x80  # CAN_MESSAGE / CAN_FD_MESSAGE flags
FD_FLAG_EDL = 0x01  # CAN_FD_MESSAGE canFdFlags
FD64_FLAG_RTR = 0x0010  # CAN_FD_MESSAGE_64 flags
FD64_FLAG_EDL = 0x1000

# The padding after an object is `size % 4` bytes in python-can's and Vector's files;
# the next signature is looked for this far past the end of the previous object.
MAX_GAP = 8
# An object claiming more than this is taken as a corrupt size, not waited for.
MAX_OBJECT_SIZE = 64 << 20
PARSE_CHUNK = 4 << 20  # decompressed bytes parsed per numpy pass
RAW_READ = 1 << 20

_DLC_TO_LEN = np.array([0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64] + [64] * 240,
                       np.int16)
_BYTE8 = np.arange(8, dtype=np.int64)


def sniff(head: bytes) -> bool:
    """A BLF file starts with the `LOGG` signature."""
    return head.startswith(FILE_SIGNATURE)


def systemtime_to_epoch(fields: tuple[int, ...]) -> float:
    """A Windows SYSTEMTIME (year, month, weekday, day, h, m, s, ms) as UTC epoch seconds.

    Read as UTC like python-can, so both tools give the same timestamps; 0 when
    the header has no (valid) start time.
    """
    year, month, _weekday, day, hour, minute, second, ms = fields
    try:
        return datetime(year, month, day, hour, minute, second, ms * 1000,
                        tzinfo=timezone.utc).timestamp()
    except ValueError:
        return 0.0


class _RawObjects:
    """The top-level object stream of the file, with resynchronisation after damage."""

    def __init__(self, source: Source, offset: int) -> None:
        self._stream = source.stream
        self._source = source
        self._pending = b""
        self.offset = offset  # file offset of the next unread byte

    def read(self, n: int) -> bytes:
        """Up to n bytes (fewer only at the end of the file)."""
        parts = []
        if self._pending:
            parts.append(self._pending[:n])
            self._pending = self._pending[n:]
        got = sum(len(p) for p in parts)
        try:
            while got < n:
                chunk = self._stream.read(n - got)
                if not chunk:
                    break
                parts.append(chunk)
                got += len(chunk)
        except self._source.errors as exc:
            raise InputError(self._source.path,
                             f"read error (truncated or corrupt file?): {exc}") from None
        data = b"".join(parts)
        self.offset += len(data)
        return data

    def unread(self, data: bytes) -> None:
        self._pending = data + self._pending
        self.offset -= len(data)

    def next_header(self, resync: bool) -> bytes:
        """The next object's 16 header bytes, or b"" if there is none.

        Without `resync` at most MAX_GAP filler bytes may precede the signature;
        with it the rest of the file is searched.
        """
        window = self.read(BASE_HEADER.size + MAX_GAP)
        while True:
            at = window.find(SIGNATURE)
            if 0 <= at < (len(window) if resync else MAX_GAP):
                self.unread(window[at:])
                return self.read(BASE_HEADER.size)
            if not resync or len(window) < len(SIGNATURE):
                self.unread(window)
                return b""
            keep = len(SIGNATURE) - 1  # a signature may straddle two reads
            more = self.read(RAW_READ)
            if not more:
                return b""
            window = window[-keep:] + more


@dataclass
class _Parsed:
    """The frames found in one stretch of the object stream, as columns."""

    ts: np.ndarray
    chan: np.ndarray  # channel numbers as written
    can_id: np.ndarray
    ext: np.ndarray
    rtr: np.ndarray
    err: np.ndarray
    fd: np.ndarray
    dlc: np.ndarray
    data: np.ndarray


# Unaligned little-endian fields read by one gather each: a view of the buffer with a
# stride of one byte, so element p is the field that starts at byte p.
_HEADER = np.dtype({"names": ["size", "type", "hsize", "hver", "flags", "stamp"],
                    "formats": ["<u4", "<u4", "<u2", "<u2", "<u4", "<u8"],
                    "offsets": [8, 12, 4, 6, 16, 24], "itemsize": 32})
_CLASSIC = np.dtype({"names": ["chan", "flags", "dlc", "id"],
                     "formats": ["<u2", "u1", "u1", "<u4"], "offsets": [0, 2, 3, 4],
                     "itemsize": 8})
# Zeros after the parsed bytes: a gather near the end never reads past the buffer.
_PAD = bytes(64)
# KEEP[k]: native uint64 whose bytes are k × FF then zeros (the first k data bytes shown).
_KEEP = np.array([[0xFF] * k + [0] * (8 - k) for k in range(9)], np.uint8).view(np.uint64)[:, 0]
_SIG32 = int(np.frombuffer(SIGNATURE, "<u4")[0])
_TYPE_TABLE = 128  # every object type read here is below this
_IS_FRAME = np.zeros(_TYPE_TABLE, bool)
_IS_FRAME[FRAME_TYPES] = True
_MIN_BODY = np.zeros(_TYPE_TABLE, np.int64)
_MIN_BODY[list(MIN_BODY)] = list(MIN_BODY.values())


def _view(buf: bytes, dtype: np.dtype | str, n: int) -> np.ndarray:
    """Element p: the `dtype` field at byte p of buf (n bytes, zero padded by _PAD)."""
    dt = np.dtype(dtype)
    out: np.ndarray = np.ndarray((max(n + len(_PAD) - dt.itemsize + 1, 0),), dt, buf, 0, (1,))
    return out


def _records(buf: bytes, n: int, dtype: np.dtype, pos: np.ndarray) -> np.ndarray:
    """The `dtype` records at byte offsets pos: gathered as raw bytes (numpy copies a
    structured dtype field by field, ten times slower), then viewed."""
    out: np.ndarray = _view(buf, f"V{dtype.itemsize}", n)[pos].view(dtype)
    return out


class _ObjectParser:
    """Parses the object stream in chunks; keeps the unfinished last object for the next chunk."""

    def __init__(self, stats: InputStats, start_time: float) -> None:
        self.stats = stats
        self.start_time = start_time
        self.tail = b""
        self.tail_is_mid_object = False  # after damage: resynchronise silently at the next object
        self.objects_seen = 0  # for skip locations
        self.frames_seen = 0  # the index of the next frame: where a lost-data record sits

    def _skip(self, why: str, extra_objects: int = 0) -> None:
        self.stats.skip(self.objects_seen + extra_objects + 1, why)

    def drop_tail(self, why: str) -> None:
        """Give up on the object stream so far (a damaged container cut it)."""
        if self.tail.strip(b"\0"):
            self._skip(why)
        self.tail = b""
        self.tail_is_mid_object = True

    def finish(self) -> bool:
        """End of file: what is left is a truncated object. True if there was one."""
        cut = bool(self.tail.strip(b"\0"))
        if cut:
            self._skip("the file ends inside an object")
        self.tail = b""
        return cut

    def _lost(self, buf: bytes, starts: np.ndarray, head: np.ndarray, lost: np.ndarray,
              frames: np.ndarray) -> None:
        """Frames the logger says it lost: the counts of the DATA_LOST_END objects among
        `starts` (at `lost`), each placed for the `frames_lost` cause at the first frame
        object after it (`frames`: where the frames kept sit among `starts`) and at its
        own timestamp (None where its header has none: that frame's time)."""
        for i in lost:
            hsize, size = int(head["hsize"][i]), int(head["size"][i])
            body = int(starts[i]) + hsize
            if hsize >= BASE_HEADER.size and body + 16 <= int(starts[i]) + size:
                count: int = struct.unpack_from("<L", buf, body + 12)[0]
                frame = self.frames_seen + int(np.searchsorted(frames, i))
                ts = None
                if hsize == HEADER_SIZE_BY_VERSION.get(int(head["hver"][i])):
                    stamp = float(head["stamp"][i])
                    ts = self.start_time + (stamp / 1e5 if int(head["flags"][i]) == TIME_TEN_MICS
                                            else stamp / 1e9)
                self.stats.drop(0, count, frame, ts)

    def parse(self, chunks: list[bytes]) -> _Parsed | None:
        buf = b"".join([self.tail, *chunks, _PAD])
        n = len(buf) - len(_PAD)
        starts, rest = self._object_starts(buf, n)
        self.tail = buf[rest:n]
        return self._frames(buf, n, starts)

    def _object_starts(self, buf: bytes, n: int) -> tuple[np.ndarray, int]:
        """Start offsets of the complete objects in buf[:n], and where the unfinished rest
        begins."""
        if n < BASE_HEADER.size:
            return np.empty(0, np.int64), 0
        uniform = self._uniform(buf, n)
        if uniform is not None:
            return uniform
        a = np.frombuffer(buf, np.uint8, n)
        u32 = _view(buf, "<u4", n)
        first = np.flatnonzero(a[:-3] == SIGNATURE[0])  # one byte compare, then the word
        cand = first[u32[first] == _SIG32].astype(np.int64)
        whole = cand[cand + BASE_HEADER.size <= n]
        cut = cand[len(whole):]  # a signature whose header the buffer ends in
        if len(whole) and len(cut) <= 1 and not self.tail_is_mid_object:
            size = u32[whole + 8].astype(np.int64)
            ends = whole + size
            gaps = whole[1:] - ends[:-1]
            regular = (
                whole[0] < MAX_GAP
                and bool(np.all((gaps >= 0) & (gaps < MAX_GAP)))
                and bool(np.all(size >= BASE_HEADER.size))
                and bool(np.all(size <= MAX_OBJECT_SIZE))
            )
            if regular:  # the usual case: every signature found starts an object
                last_end = int(ends[-1])
                if last_end > n:  # the last object goes on in the next container
                    if not len(cut):
                        return whole[:-1], int(whole[-1])
                elif not len(cut):
                    return whole, last_end
                elif 0 <= int(cut[0]) - last_end < MAX_GAP:
                    return whole, int(cut[0])
        return self._walk(buf, cand, n)

    def _uniform(self, buf: bytes, n: int) -> tuple[np.ndarray, int] | None:
        """Objects of one size back to back from the first byte (what loggers write for one
        kind of frame): checked at their stride, no signature search. The same starts and
        rest as `_walk`; None for any other stretch."""
        if self.tail_is_mid_object or not buf.startswith(SIGNATURE):
            return None
        size: int = struct.unpack_from("<L", buf, 8)[0]
        if size < BASE_HEADER.size or size > MAX_OBJECT_SIZE:
            return None
        headers = (n - BASE_HEADER.size) // size + 1  # objects whose header is in buf
        words = np.ndarray((headers, 3), "<u4", buf, 0, (size, 4))  # signature, -, size
        if not (bool(np.all(words[:, 0] == _SIG32)) and bool(np.all(words[:, 2] == size))):
            return None
        whole = min(headers, n // size)
        rest = whole * size
        if whole == headers and buf.find(SIGNATURE, rest + 1, n) >= 0:
            return None  # bytes after the last object: left to the walk's judgement
        return np.arange(0, rest, size, dtype=np.int64), rest

    def _walk(self, buf: bytes, cand: np.ndarray, n: int) -> tuple[np.ndarray, int]:
        """Object by object, for stretches with damage or a signature inside an object's data."""
        found: list[int] = []
        pos = 0
        while True:
            j = int(np.searchsorted(cand, pos))
            if j == len(cand):
                if n - pos > MAX_OBJECT_SIZE:  # garbage that will never become an object
                    self._skip("bytes without an object signature", len(found))
                    pos = n
                return np.array(found, np.int64), pos
            c = int(cand[j])
            if c - pos >= MAX_GAP and not self.tail_is_mid_object:
                self._skip(f"{c - pos} bytes that are not an object", len(found))
            self.tail_is_mid_object = False
            if c + BASE_HEADER.size > n:
                return np.array(found, np.int64), c
            size: int = struct.unpack_from("<L", buf, c + 8)[0]
            if size < BASE_HEADER.size or size > MAX_OBJECT_SIZE:
                self._skip(f"object size {size} is impossible", len(found))
                pos = c + len(SIGNATURE)
                self.tail_is_mid_object = True  # what follows is the broken object's body
                continue
            if c + size > n:
                return np.array(found, np.int64), c
            found.append(c)
            pos = c + size

    def _frames(self, buf: bytes, n: int, starts: np.ndarray) -> _Parsed | None:
        """The frame objects among `starts` as columns: one gather per header or body layout."""
        stats = self.stats
        first_object = self.objects_seen
        self.objects_seen += len(starts)
        if len(starts) == 0:
            return None
        head = objects = _records(buf, n, _HEADER, starts)
        otype = head["type"]
        is_frame = _IS_FRAME[np.minimum(otype, _TYPE_TABLE - 1)]
        lost = None
        if not is_frame.all():
            others = np.flatnonzero(~is_frame)
            stats.ignored += len(others)
            lost = others[otype[others] == DATA_LOST_END]
            frames = np.flatnonzero(is_frame)
            if len(frames) == 0:
                self._lost(buf, starts, objects, lost, frames)
                return None
            s, head = starts[frames], head[frames]
        else:
            frames, s = np.arange(len(starts)), starts
        hs = head["hsize"].astype(np.int64)
        hv = head["hver"]
        sz = head["size"].astype(np.int64)
        ty = head["type"]
        expected_hs = np.where(hv == 1, 32, np.where(hv == 2, 40, -1))
        good = (hs == expected_hs) & (sz >= hs + _MIN_BODY[ty])
        if not good.all():
            for i in np.flatnonzero(~good):
                where = first_object + int(frames[i])
                stats.skip(where + 1, _why_bad(int(ty[i]), int(hv[i]), int(hs[i]),
                                               int(expected_hs[i]), int(sz[i])))
            s, hs, sz, ty, head = s[good], hs[good], sz[good], ty[good], head[good]
            frames = frames[good]
        if lost is not None:
            self._lost(buf, starts, objects, lost, frames)
        count = len(s)
        self.frames_seen += count
        if count == 0:
            return None

        flags = head["flags"]
        stamp = head["stamp"].astype(np.float64)
        ten = flags == TIME_TEN_MICS
        if ten.all():
            ts = stamp / 1e5 + self.start_time
        elif not ten.any():
            ts = stamp / 1e9 + self.start_time
        else:
            ts = np.where(ten, stamp / 1e5, stamp / 1e9) + self.start_time
        b = s + hs  # object bodies
        if bool(np.all((ty == CAN_MESSAGE) | (ty == CAN_MESSAGE2))):  # the usual file
            body = _records(buf, n, _CLASSIC, b)
            chan = body["chan"].astype(np.int64)
            dlc = body["dlc"].astype(np.int16)
            raw_id = body["id"]
            rtr = (body["flags"] & MSG_FLAG_RTR) != 0
            err = np.zeros(count, bool)
            fd = np.zeros(count, bool)
            data_at = b + 8
            data_len = np.minimum(dlc, 8)
        else:
            chan, raw_id, rtr, err, fd, dlc, data_at, data_len = _mixed(buf, n, ty, b, hs, sz)

        ext = ((raw_id & CAN_MSG_EXT) != 0) & ~err
        shown = np.where(rtr | err, 0, np.minimum(data_len, 8))
        words = _view(buf, "=u8", n)[data_at] & _KEEP[shown]
        data = words.view(np.uint8).reshape(count, 8)
        late = np.flatnonzero(data_at + shown > n)
        if len(late):  # shown bytes past the buffer: the last byte repeated, as always read
            a = np.frombuffer(buf, np.uint8, n)
            idx = np.minimum(data_at[late, None] + _BYTE8, n - 1)
            data[late] = np.where(shown[late, None] > _BYTE8, a[idx], 0)
        return _Parsed(ts=ts, chan=chan, can_id=raw_id & CAN_ID_MASK, ext=ext, rtr=rtr,
                       err=err, fd=fd, dlc=dlc, data=data)


def _mixed(buf: bytes, n: int, ty: np.ndarray, b: np.ndarray, hs: np.ndarray,
           sz: np.ndarray) -> tuple[np.ndarray, ...]:
    """The columns of a stretch with FD, error or several kinds of frame objects, per type."""
    a = np.frombuffer(buf, np.uint8)
    u16 = _view(buf, "<u2", n)
    u32 = _view(buf, "<u4", n)
    count = len(ty)
    chan = np.zeros(count, np.int64)
    raw_id = np.zeros(count, np.uint32)
    rtr = np.zeros(count, bool)
    err = np.zeros(count, bool)
    fd = np.zeros(count, bool)
    dlc = np.zeros(count, np.int16)
    data_at = np.zeros(count, np.int64)
    data_len = np.zeros(count, np.int64)

    classic = np.flatnonzero((ty == CAN_MESSAGE) | (ty == CAN_MESSAGE2))
    if len(classic):
        bb = b[classic]
        chan[classic] = u16[bb]
        classic_dlc = a[bb + 3].astype(np.int16)
        raw_id[classic] = u32[bb + 4]
        rtr[classic] = (a[bb + 2] & MSG_FLAG_RTR) != 0
        dlc[classic] = classic_dlc
        data_at[classic] = bb + 8
        data_len[classic] = np.minimum(classic_dlc, 8)

    fd100 = np.flatnonzero(ty == CAN_FD_MESSAGE)
    if len(fd100):
        bb = b[fd100]
        chan[fd100] = u16[bb]
        raw_dlc = a[bb + 3]
        edl = (a[bb + 13] & FD_FLAG_EDL) != 0
        raw_id[fd100] = u32[bb + 4]
        fd[fd100] = edl
        rtr[fd100] = ((a[bb + 2] & MSG_FLAG_RTR) != 0) & ~edl
        dlc[fd100] = np.where(edl, _DLC_TO_LEN[raw_dlc], raw_dlc)
        data_at[fd100] = bb + 20
        data_len[fd100] = np.minimum(a[bb + 14], 64)

    fd64 = np.flatnonzero(ty == CAN_FD_MESSAGE_64)
    if len(fd64):
        bb = b[fd64]
        chan[fd64] = a[bb]
        raw_dlc = a[bb + 1]
        valid = a[bb + 2].astype(np.int64)
        raw_id[fd64] = u32[bb + 4]
        fd_flags = u32[bb + 12]
        edl = (fd_flags & FD64_FLAG_EDL) != 0
        fd[fd64] = edl
        rtr[fd64] = ((fd_flags & FD64_FLAG_RTR) != 0) & ~edl
        dlc[fd64] = np.where(edl, _DLC_TO_LEN[raw_dlc], raw_dlc)
        ext_offset = a[bb + 35].astype(np.int64)
        # TSMaster writes valid_bytes larger than the data stored (python-can issue 1905):
        # the missing bytes are zeros, as in CANoe
        stored = np.where(ext_offset > 0, ext_offset, sz[fd64]) - hs[fd64] - 40
        data_at[fd64] = bb + 40
        data_len[fd64] = np.clip(np.minimum(valid, stored), 0, 64)

    errors = np.flatnonzero((ty == CAN_ERROR) | (ty == CAN_ERROR_EXT))
    if len(errors):
        chan[errors] = u16[b[errors]]
        err[errors] = True
        ext_err = errors[ty[errors] == CAN_ERROR_EXT]
        raw_id[ext_err] = u32[b[ext_err] + 16]
    fd_errors = np.flatnonzero(ty == CAN_FD_ERROR_64)
    if len(fd_errors):
        chan[fd_errors] = a[b[fd_errors]]
        err[fd_errors] = True
        fd[fd_errors] = True
        raw_id[fd_errors] = u32[b[fd_errors] + 12]
    return chan, raw_id, rtr, err, fd, dlc, data_at, data_len


def _why_bad(otype: int, hver: int, hsize: int, expected_hsize: int, size: int) -> str:
    """Why a frame object's header does not fit its version and type."""
    if expected_hsize < 0:
        return (f"object type {otype} with header version {hver} "
                "(only versions 1 and 2 are known)")
    if hsize != expected_hsize:
        return f"object header size {hsize} does not match header version {hver}"
    return f"object type {otype} of {size} bytes is too short"


class _BatchMaker:
    """Turns parsed columns into FrameBatches with input-wide frame indices and channel codes."""

    def __init__(self, stats: InputStats) -> None:
        self.stats = stats
        self.next_index = 0
        self._codes: dict[int, int] = {}

    def batch(self, p: _Parsed) -> FrameBatch | None:
        n = len(p.ts)
        first = int(p.chan[0]) if n else 0
        if bool(np.all(p.chan == first)):  # one channel: no sort to find the others
            chan = np.full(n, self._code(first), np.int32)
        else:
            numbers, inverse = np.unique(p.chan, return_inverse=True)
            codes = np.array([self._code(int(c)) for c in numbers], np.int32)
            chan = codes[inverse.reshape(-1)]
        out = FrameBatch(
            ts=p.ts, chan=chan, can_id=p.can_id.astype(np.uint32),
            ext=p.ext, rtr=p.rtr, err=p.err, fd=p.fd, dlc=p.dlc.astype(np.int16), data=p.data,
            index=np.arange(self.next_index, self.next_index + n, dtype=np.int64),
            line=np.zeros(n, np.int64),
        )
        self.next_index += n
        return account(self.stats, out)

    def _code(self, number: int) -> int:
        code = self._codes.get(number)
        if code is None:
            code = self._codes[number] = self.stats.channel_code(str(number))
        return code


def read(source: Source, stats: InputStats) -> Iterator[FrameBatch]:
    header_size, start = _file_header(source)
    yield from _Reader(source, stats, header_size, start).batches()


def _file_header(source: Source) -> tuple[int, float]:
    """Read past the file header: its size, and the start time it gives."""
    head = source.stream.read(FILE_HEADER_MIN)
    if not head.startswith(FILE_SIGNATURE):
        raise InputError(source.path, "not a BLF file (no LOGG signature)")
    if len(head) < FILE_HEADER_MIN:
        raise InputError(source.path, "BLF file header is truncated")
    header_size: int = struct.unpack_from("<L", head, 4)[0]
    start = systemtime_to_epoch(struct.unpack_from("<8H", head, 40))
    to_skip = header_size - FILE_HEADER_MIN
    while to_skip > 0:  # in pieces: a damaged header size must not allocate gigabytes
        piece = source.stream.read(min(to_skip, RAW_READ))
        if not piece:
            raise InputError(source.path, "BLF file header is truncated")
        to_skip -= len(piece)
    return header_size, start


class _Reader:
    """The log objects after the file header: containers are collected and parsed in chunks
    of PARSE_CHUNK bytes, objects outside a container one by one; damage is skipped over."""

    def __init__(self, source: Source, stats: InputStats, header_size: int,
                 start: float) -> None:
        self.stats = stats
        self.start = start
        self.raw = _RawObjects(source, max(header_size, FILE_HEADER_MIN))
        self.parser = _ObjectParser(stats, start)
        self.maker = _BatchMaker(stats)
        self.pending: list[bytes] = []
        self.pending_size = 0
        self.resync = False  # searching for the next object after damage
        self.cut_container = False

    def batches(self) -> Iterator[FrameBatch]:
        raw = self.raw
        while True:
            header = raw.next_header(self.resync)
            if not header:
                if self._at_end():
                    break
                continue
            self.resync = False
            if len(header) < BASE_HEADER.size:
                self.cut("the file ends inside an object header")
                break
            _sig, _hsize, _hver, size, otype = BASE_HEADER.unpack(header)
            if size < BASE_HEADER.size or size > MAX_OBJECT_SIZE:
                self.damaged(f"log object at byte {raw.offset - BASE_HEADER.size} has an "
                             f"impossible size ({size})")
                self.resync = True
                continue
            body = raw.read(size - BASE_HEADER.size)
            truncated = len(body) < size - BASE_HEADER.size
            if otype != LOG_CONTAINER:
                if truncated:
                    self.cut("the file ends inside an object")
                    break
                yield from self._single(header + body)
                continue
            if len(body) < CONTAINER_HEADER.size:
                self.cut("the file ends inside a log container header")
                break
            data = yield from self._container_data(body)
            if data is None:
                continue
            self.pending.append(data)
            self.pending_size += len(data)
            if truncated:
                self.cut_container = True
                break
            if self.pending_size >= PARSE_CHUNK:
                yield from self.flush()
        yield from self._finish()

    def _at_end(self) -> bool:
        """No object header where one should be: True at the end of the file (or of the
        search for the next object after damage), else the damage is skipped over."""
        if self.resync:
            return True  # searched to the end of the file; the damage is already reported
        raw = self.raw
        rest = raw.read(RAW_READ)
        if not rest.strip(b"\0"):
            return True  # the end of the file (zero padding after the last object)
        if len(rest) < BASE_HEADER.size:  # a few bytes at the end: a header cut short
            self.cut("the file ends inside an object header")
            return True
        self.damaged(f"bytes at {raw.offset - len(rest)} are not a log object")
        raw.unread(rest)
        self.resync = True
        return False

    def _single(self, obj: bytes) -> Iterator[FrameBatch]:
        """An object outside any container: parsed on its own, after what came before it."""
        yield from self.flush()
        single = _ObjectParser(self.stats, self.start)
        single.objects_seen = self.parser.objects_seen
        single.frames_seen = self.parser.frames_seen
        parsed = single.parse([obj])
        self.parser.objects_seen = single.objects_seen
        self.parser.frames_seen = single.frames_seen
        if parsed is not None and (batch := self.maker.batch(parsed)) is not None:
            yield batch

    def _container_data(self, body: bytes) -> Generator[FrameBatch, None, bytes | None]:
        """The objects' bytes a log container holds; None (after what came before it) if
        they cannot be read."""
        method, _usize = CONTAINER_HEADER.unpack_from(body)
        payload = body[CONTAINER_HEADER.size:]
        if method == NO_COMPRESSION:
            return payload
        if method == ZLIB_DEFLATE:
            try:
                data: bytes = zlib.decompressobj().decompress(payload)
                return data
            except zlib.error as exc:
                yield from self.flush()
                self.parser.drop_tail("an object cut short by a damaged log container")
                self.damaged(f"log container data is corrupt ({exc})")
                return None
        yield from self.flush()
        self.parser.drop_tail("an object cut short by an unreadable log container")
        self.damaged(f"log container with unknown compression method {method}")
        return None

    def _finish(self) -> Iterator[FrameBatch]:
        yield from self.flush()
        if self.parser.finish():
            self.stats.truncated = True
        elif self.cut_container:
            self.cut("the file ends inside a log container")

    def flush(self) -> Iterator[FrameBatch]:
        parsed = self.parser.parse(self.pending)
        self.pending, self.pending_size = [], 0
        if parsed is not None and (batch := self.maker.batch(parsed)) is not None:
            yield batch

    def damaged(self, why: str) -> None:
        self.stats.skip(self.parser.objects_seen + 1, why)

    def cut(self, why: str) -> None:
        """The file ends inside an object: read up to there, report the input truncated."""
        self.stats.truncated = True
        self.damaged(why)
