"""The columnar frame batch every reader yields, and CANopen COB-ID classification.

Frames never become one Python object each: a reader fills a `BatchBuilder`
(preallocated numpy columns) and hands out `FrameBatch` objects of up to a
few hundred thousand frames. Everything downstream works on whole columns.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import overload

import numpy as np

BATCH_SIZE = 262_144

# Pre-defined connection set (CiA 301 Tables 38/39), 11-bit IDs.
NMT_ID = 0x000
EMCY_BASE = 0x080
TPDO_BASES = (0x180, 0x280, 0x380, 0x480)
RPDO_BASES = (0x200, 0x300, 0x400, 0x500)
SDO_TX_BASE = 0x580  # server -> client (the node's response)
SDO_RX_BASE = 0x600  # client -> server (request to the node)
EC_BASE = 0x700  # boot-up, heartbeat, node guarding
MAX_NODE_ID = 0x7F  # node-IDs 1..127: a function's IDs are its base + 1 .. base + 7Fh
STD_ID_MASK = 0x7FF  # the 11 bits of a standard CAN-ID
STD_IDS = 0x800  # how many 11-bit CAN-IDs there are

# A node key: one integer per (channel code, node-ID), channel * NODE_KEYS_PER_CHANNEL +
# node-ID. Node keys sort by channel, then node; a channel's keys are one range.
NODE_KEYS_PER_CHANNEL = 128


@overload
def node_key(chan: int, node: int) -> int: ...
@overload
def node_key(chan: np.ndarray, node: np.ndarray | int) -> np.ndarray: ...
@overload
def node_key(chan: int, node: np.ndarray) -> np.ndarray: ...
def node_key(chan: np.ndarray | int, node: np.ndarray | int) -> np.ndarray | int:
    """The node key of (channel code, node-ID): channel * 128 + node."""
    return chan * NODE_KEYS_PER_CHANNEL + node


def key_channel(key: int) -> int:
    """The channel code of a node key."""
    return key // NODE_KEYS_PER_CHANNEL


def key_node(key: int) -> int:
    """The node-ID of a node key."""
    return key % NODE_KEYS_PER_CHANNEL


def channel_keys(chan: int) -> tuple[int, int]:
    """The first and the last node key of a channel (node-IDs 0 and 127)."""
    first = chan * NODE_KEYS_PER_CHANNEL
    return first, first + NODE_KEYS_PER_CHANNEL - 1


@dataclass
class FrameBatch:
    """A run of consecutive frames of one input, as parallel numpy columns."""

    ts: np.ndarray  # float64 seconds, trace time base
    chan: np.ndarray  # int32 code into InputStats.channels
    can_id: np.ndarray  # uint32, without flag bits
    ext: np.ndarray  # bool: 29-bit identifier
    rtr: np.ndarray  # bool: remote frame
    err: np.ndarray  # bool: error frame
    fd: np.ndarray  # bool: CAN FD frame
    dlc: np.ndarray  # int16: data length in bytes (the DLC field for remote frames)
    data: np.ndarray  # uint8 [n, 8]: the first 8 data bytes, zero padded
    index: np.ndarray  # int64: 0-based frame index within the input
    line: np.ndarray  # int64: 1-based line number (0 for binary formats)

    def __len__(self) -> int:
        return int(self.ts.shape[0])


class BatchBuilder:
    """Collects parsed rows of a line-oriented reader and hands them out as column batches.

    Rows are appended to plain lists (far cheaper per row than numpy item
    assignment) and turned into numpy columns once per batch. A vectorised
    reader appends whole columns instead (`add_columns`) and cuts batches of
    exactly `capacity` frames from them, so both paths yield the same batches.
    """

    def __init__(self, capacity: int = BATCH_SIZE) -> None:
        self.capacity = capacity
        self.next_index = 0
        self._parts: list[tuple[np.ndarray, ...]] = []  # column chunks from add_columns
        self._pending = 0
        self._reset()

    def _reset(self) -> None:
        self._ts: list[float] = []
        self._chan: list[int] = []
        self._id: list[int] = []
        self._flags: list[int] = []  # bit 0 ext, 1 rtr, 2 err, 3 fd
        self._dlc: list[int] = []
        self._data = bytearray()
        self._line: list[int] = []

    @property
    def n(self) -> int:
        return len(self._ts)

    @property
    def full(self) -> bool:
        return len(self._ts) >= self.capacity

    def add(
        self,
        ts: float,
        chan: int,
        can_id: int,
        *,
        ext: bool = False,
        rtr: bool = False,
        err: bool = False,
        fd: bool = False,
        dlc: int = 0,
        data: bytes = b"",
        line: int = 0,
    ) -> None:
        self._ts.append(ts)
        self._chan.append(chan)
        self._id.append(can_id)
        self._flags.append(ext | rtr << 1 | err << 2 | fd << 3)
        self._dlc.append(dlc)
        self._data += data[:8].ljust(8, b"\0")
        self._line.append(line)

    def add_columns(self, ts: np.ndarray, chan: np.ndarray, can_id: np.ndarray,
                    flags: np.ndarray, dlc: np.ndarray, data: np.ndarray,
                    line: np.ndarray) -> Iterator[FrameBatch]:
        """Append frames as columns (flags: bit 0 ext, 1 rtr, 2 err, 3 fd); yield every batch
        of `capacity` frames that is complete."""
        if ts.shape[0]:
            self._parts.append((ts, chan, can_id, flags, dlc, data, line))
            self._pending += int(ts.shape[0])
        while self._pending >= self.capacity:
            yield self._cut(self.capacity)

    def _cut(self, n: int) -> FrameBatch:
        """The first n frames of the column chunks as one batch: each column is copied once
        (a view would keep a whole chunk alive in the decoder's store), the rest of the
        chunk the cut falls in stays for the next batch."""
        taken, used = [], 0
        while used < n:
            part = self._parts.pop(0)
            k = min(n - used, part[0].shape[0])
            taken.append(part if k == part[0].shape[0] else tuple(c[:k] for c in part))
            if k < part[0].shape[0]:
                self._parts.insert(0, tuple(c[k:] for c in part))
            used += k
        head = [_owned(c) for c in zip(*taken, strict=True)]
        self._pending -= n
        ts, chan, can_id, flags, dlc, data, line = head
        batch = FrameBatch(
            ts=ts, chan=chan, can_id=can_id, ext=(flags & 1).astype(bool),
            rtr=(flags & 2).astype(bool), err=(flags & 4).astype(bool),
            fd=(flags & 8).astype(bool), dlc=dlc, data=data,
            index=np.arange(self.next_index, self.next_index + n, dtype=np.int64), line=line)
        self.next_index += n
        return batch

    def take(self) -> FrameBatch | None:
        """Hand out the collected rows as a batch and start a fresh one."""
        if self._pending:
            return self._cut(self._pending)
        n = len(self._ts)
        if n == 0:
            return None
        flags = np.asarray(self._flags, np.uint8)
        batch = FrameBatch(
            ts=np.asarray(self._ts, np.float64),
            chan=np.asarray(self._chan, np.int32),
            can_id=np.asarray(self._id, np.uint32),
            ext=(flags & 1).astype(bool),
            rtr=(flags & 2).astype(bool),
            err=(flags & 4).astype(bool),
            fd=(flags & 8).astype(bool),
            dlc=np.asarray(self._dlc, np.int16),
            data=np.frombuffer(bytes(self._data), np.uint8).reshape(n, 8).copy(),
            index=np.arange(self.next_index, self.next_index + n, dtype=np.int64),
            line=np.asarray(self._line, np.int64),
        )
        self.next_index += n
        self._reset()
        return batch


def _owned(parts: tuple[np.ndarray, ...]) -> np.ndarray:
    """The parts as one array that owns its memory (one copy at most)."""
    if len(parts) > 1:
        return np.concatenate(parts)
    return parts[0] if parts[0].base is None else parts[0].copy()


def canopen_mask(batch: FrameBatch) -> np.ndarray:
    """Frames that take part in CANopen decoding: 11-bit data and remote frames."""
    mask: np.ndarray = ~batch.ext & ~batch.err
    return mask


def is_restricted_id(can_id: np.ndarray) -> np.ndarray:
    """CiA 301 Table 40 reserved ranges (780h = 1920, not 2020 as one source says).

    Only the ranges no device may use are here; NMT (000h), the default SDO and
    error-control IDs are in Table 40 too but are used as intended by CANopen
    itself, so frames on them are checked by their own rules instead.
    """
    cid = can_id.astype(np.int64)
    return (
        ((cid >= 0x001) & (cid <= 0x07F))
        | ((cid >= 0x101) & (cid <= 0x180))
        | ((cid >= 0x6E0) & (cid <= 0x6FF))
        | ((cid >= 0x780) & (cid <= 0x7FF))
    )
