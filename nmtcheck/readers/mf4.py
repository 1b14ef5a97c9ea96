"""ASAM MDF 4 bus logging (CAN_DataFrame, CAN_RemoteFrame, CAN_ErrorFrame groups),
as written by CSS Electronics CANedge, Vector and python-can's MF4Writer.

Needs the optional `asammdf` package (the `mf4` extra). Each
group is read through asammdf's array access in large slices, so a frame is
never a Python object (python-can's MF4Reader builds one per frame and is
about 20 times slower). Frames of all groups are merged by time, like
python-can does; the time is the file's start time plus the group's time
channel. The channel is the `BusChannel` number as written (CANedge: 1 =
CAN1). Records of other bus-event groups (LIN, CAN overload frames…) are
counted as ignored.
"""

from __future__ import annotations

import gc
import os
import shutil
import sys
import tempfile
from collections.abc import Iterator
from typing import Any

import numpy as np

from nmtcheck.errors import InputError
from nmtcheck.readers.binary import BatchCollector, ChannelNames, Frames, zero_beyond
from nmtcheck.readers.frames import BATCH_SIZE, FrameBatch
from nmtcheck.readers.records import MAX_TIMESTAMP_S
from nmtcheck.readers.source import Source
from nmtcheck.readers.stats import InputStats

INSTALL_HINT = "pip install '.[mf4]' in the nmtcheck checkout"
FRAME_GROUPS = ("CAN_DataFrame", "CAN_RemoteFrame", "CAN_ErrorFrame")
RECORDS_PER_READ = 1 << 20
BUS_TYPE_CAN = 2  # acquisition source bus type (MDF 4 SI block)
FLAG_CG_BUS_EVENT = 0x2
CAN_EFF_MASK = 0x1FFFFFFF
CAN_EFF_BIT = 0x80000000  # some writers keep the IDE bit in the ID
FD_LENGTHS = np.array([0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64], np.int16)


def sniff(head: bytes) -> bool:
    return head.startswith((b"MDF     ", b"UnFinMF "))


def _column(samples: np.ndarray, group: str, name: str) -> np.ndarray | None:
    key = f"{group}.{name}"
    names = samples.dtype.names or ()
    return samples[key] if key in names else None


def _payload(raw: np.ndarray, n: int) -> np.ndarray:
    """The first 8 data bytes of each record as an (n, 8) matrix."""
    data = np.zeros((n, 8), np.uint8)
    if raw.dtype == object:  # variable-length data (VLSD): one bytes object per record
        for i, value in enumerate(raw.tolist()):
            head = bytes(value)[:8]
            data[i, : len(head)] = np.frombuffer(head, np.uint8)
        return data
    flat = raw.reshape(n, -1).astype(np.uint8, copy=False)
    width = min(8, flat.shape[1])
    data[:, :width] = flat[:, :width]
    return data


def _frames(group: str, samples: np.ndarray, times: np.ndarray, start: float) -> Frames:
    """Columns of one slice of a bus-logging group; `chan` holds the BusChannel number."""
    n = len(times)
    frames = Frames(n)
    frames.keep[:] = True
    frames.ts[:] = times.astype(np.float64) + start
    bus = _column(samples, group, "BusChannel")
    frames.chan[:] = 1  # no BusChannel: one bus
    if bus is not None:
        frames.chan[:] = bus.astype(np.int32)
    ident = _column(samples, group, "ID")
    raw_id = np.zeros(n, np.uint32) if ident is None else ident.astype(np.uint32)
    ide = _column(samples, group, "IDE")
    ext = (raw_id & CAN_EFF_BIT) != 0 if ide is None else ide.astype(bool)
    frames.can_id[:] = raw_id & CAN_EFF_MASK
    edl = _column(samples, group, "EDL")
    if edl is not None:
        frames.fd[:] = edl.astype(bool)
    length = _column(samples, group, "DataLength")
    dlc_field = _column(samples, group, "DLC")
    if group == "CAN_ErrorFrame":
        frames.err[:] = True
        ext[:] = False
        frames.rtr[:] = False
    if group == "CAN_RemoteFrame":
        frames.rtr[:] = True
        dlc = dlc_field if dlc_field is not None else length
        frames.dlc[:] = np.zeros(n) if dlc is None else np.minimum(dlc.astype(np.int16), 8)
    else:
        if length is None and dlc_field is not None:
            codes = np.minimum(dlc_field.astype(np.int64), 15)
            length = np.where(frames.fd, FD_LENGTHS[codes], np.minimum(codes, 8))
        frames.dlc[:] = 0 if length is None else length.astype(np.int16)
        raw = _column(samples, group, "DataBytes")
        if raw is not None:
            frames.data[:] = _payload(raw, n)
            zero_beyond(frames.data, np.minimum(frames.dlc, 8))
    frames.ext[:] = ext
    return frames


def _local_copy(source: Source, folder: str) -> str:
    """A seekable file for asammdf: the input itself, or the decompressed stream spooled
    into `folder`."""
    if source.file_path is not None:
        return source.file_path
    fd, name = tempfile.mkstemp(prefix="nmtcheck-", suffix=".mf4", dir=folder)
    try:
        with os.fdopen(fd, "wb") as out:
            shutil.copyfileobj(source.stream, out, 1 << 20)
    except source.errors as exc:
        os.unlink(name)
        raise InputError(source.path, f"read error (truncated or corrupt file?): {exc}") from None
    return name


def read(source: Source, stats: InputStats) -> Iterator[FrameBatch]:
    try:
        from asammdf import MDF
    except ImportError:
        raise InputError(source.path, "reading MF4 needs the optional asammdf package: "
                         + INSTALL_HINT) from None
    from nmtcheck.spool import removed_on_exit, spill_directory

    # asammdf's own temporary files go here too: it copies an unfinalized MF4 whole, and
    # left that copy in /tmp when the file turned out damaged
    with removed_on_exit(spill_directory("nmtcheck-mf4-")) as folder:
        path = _local_copy(source, folder)
        mdf = _open(MDF, path, source, folder)
        try:
            yield from _read_groups(mdf, source, stats)
        finally:
            mdf.close()


def _open(mdf_class: Any, path: str, source: Source, folder: str) -> Any:
    """asammdf's MDF of the file, its temporary files in `folder`; a damaged or cut-off
    file is an InputError naming the input, not a temporary copy of it.

    When asammdf's constructor fails, the half-built object's __del__ fails too and Python
    prints that traceback on stderr ("Exception ignored in MDF4.__del__"): silenced, so the
    one-line message stays the only one.
    """
    hook = sys.unraisablehook
    sys.unraisablehook = lambda _unraisable: None
    try:
        try:
            # asammdf's own per-ID signal tables are not needed (and cost time)
            options: dict[str, Any] = {"process_bus_logging": False,
                                       "temporary_folder": folder}
            return mdf_class(path, **options)
        except Exception as exc:  # asammdf raises many kinds for a damaged file
            why = str(exc).replace(path, source.path)
            message = f"cannot read MF4 file (cut off or damaged?): {why}"
        gc.collect()  # the half-built object goes now, while its complaint is silenced
    finally:
        sys.unraisablehook = hook
    raise InputError(source.path, message)


def _read_groups(mdf: Any, source: Source, stats: InputStats) -> Iterator[FrameBatch]:
    try:
        start = mdf.header.start_time.timestamp()
    except (AttributeError, OverflowError, ValueError):
        start = 0.0
    parts: list[Frames] = []
    found = False
    for index, group in enumerate(mdf.groups):
        cg = group.channel_group
        channel_names = {ch.name for ch in group.channels}
        source_info = getattr(cg, "acq_source", None)
        bus_type = getattr(source_info, "bus_type", BUS_TYPE_CAN)
        kind = next((g for g in FRAME_GROUPS if g in channel_names), None)
        if kind is None or bus_type != BUS_TYPE_CAN:
            if getattr(cg, "flags", 0) & FLAG_CG_BUS_EVENT:
                stats.ignored += int(cg.cycles_nr)  # LIN, FlexRay, other CAN events
            continue
        found = True
        for offset in range(0, int(cg.cycles_nr), RECORDS_PER_READ):
            try:
                signal = mdf.get(kind, index, record_offset=offset,
                                 record_count=RECORDS_PER_READ, raw=True)
            except Exception as exc:  # asammdf raises many kinds for a damaged group
                raise InputError(source.path, f"cannot read group {index} ({kind}): "
                                 f"{exc}") from None
            samples = signal.samples
            if samples.dtype.names is None or not len(samples):
                continue
            parts.append(_frames(kind, samples, signal.timestamps, start))
    if not found:
        raise InputError(source.path, "no CAN bus-logging groups (CAN_DataFrame, "
                         "CAN_RemoteFrame, CAN_ErrorFrame) in this MDF file")
    if not parts:
        return
    merged = Frames.concatenate(parts)
    # a time no report can hold (inf, nan, beyond MAX_TIMESTAMP_S): a skipped record
    plausible = np.abs(merged.ts) < MAX_TIMESTAMP_S
    if not bool(plausible.all()):
        why = f"timestamp not finite or out of range (±{MAX_TIMESTAMP_S:.0e} s)"
        if stats.strict:
            raise InputError(source.path, f"cannot parse {stats.format} record: {why}")
        stats.skip_reason = stats.skip_reason or why
        stats.skipped += int(np.count_nonzero(~plausible))
        merged = merged.subset(np.flatnonzero(plausible))
    order = np.argsort(merged.ts, kind="stable")  # groups merged by time, as python-can does
    names = ChannelNames(stats)
    numbers = np.unique(merged.chan)
    pids = np.array([names.provisional(str(int(n))) for n in numbers.tolist()], np.int32)
    merged.chan = pids[np.searchsorted(numbers, merged.chan)]
    out = BatchCollector(stats)
    for begin in range(0, len(order), BATCH_SIZE):
        piece = merged.subset(order[begin : begin + BATCH_SIZE])
        names.finish(piece)
        out.add(piece)
        if (batch := out.take()) is not None:
            yield batch
