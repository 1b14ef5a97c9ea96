"""SDO transfer reconstruction on the default channels (SPEC §8.3.1)."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from nmtcheck.processes import sdo_transfers as st
from nmtcheck.readers.frames import FrameBatch


def frames(*rows: tuple[float, str, str]) -> np.ndarray:
    """(time, 'req'|'resp', hex data) -> one server's SDO rows."""
    out = np.zeros(len(rows), st.SDO_DTYPE)
    for i, (t, who, data) in enumerate(rows):
        b = bytes.fromhex(data)
        out[i]["ts"], out[i]["idx"], out[i]["line"] = t, i, i + 1
        out[i]["req"], out[i]["dlc"] = who == "req", len(b)
        out[i]["data"][:len(b)] = list(b)
    return out


def results(t: st.TransferTable) -> list[tuple[str, int, int, str]]:
    return [(("dl", "up")[int(t.direction[k])], int(t.index[k]), int(t.sub[k]),
             st.RESULTS[int(t.result[k])]) for k in range(len(t))]


def test_expedited_upload_download_refused_aborted() -> None:
    t = st.transfers(frames(
        (0.0, "req", "4000100000000000"), (0.001, "resp", "4300100092010200"),
        (0.002, "req", "2F60600001000000"), (0.003, "resp", "6060600000000000"),
        (0.004, "req", "2300140102020080"), (0.005, "resp", "8000140111000906"),
        (0.006, "req", "4018100100000000"), (0.106, "req", "8000000000000405"),
    ), 10.0, 1.0)
    assert results(t) == [("up", 0x1000, 0, "ok"), ("dl", 0x6060, 0, "ok"),
                          ("dl", 0x1400, 1, "refused"), ("up", 0x1018, 1, "aborted")]
    assert int(t.value[0]) == 0x00020192 and int(t.value[1]) == 1
    assert int(t.abort_code[2]) == 0x06090011 and int(t.abort_code[3]) == st.TIMEOUT_ABORT
    assert t.is_probe().tolist() == [True, False, False, False]


def test_unanswered_and_open() -> None:
    rows = frames((0.0, "req", "4000100000000000"), (0.5, "req", "4000100000000000"))
    assert results(st.transfers(rows, 0.6, 1.0))[:] == [("up", 0x1000, 0, "unanswered"),
                                                      ("up", 0x1000, 0, "open")]
    assert results(st.transfers(rows, 2.0, 1.0))[1][3] == "unanswered"


def test_segmented_upload_and_download() -> None:
    t = st.transfers(frames(
        # upload 1008h: 9 bytes "ABCDEFGHI"
        (0.0, "req", "4008100000000000"), (0.001, "resp", "4108100009000000"),
        (0.002, "req", "6000000000000000"), (0.003, "resp", "00414243444546 47".replace(" ", "")),
        (0.004, "req", "7000000000000000"), (0.005, "resp", "1B48490000000000"),
        # segmented download of 1F50h:01, two segments
        (0.006, "req", "21501F010A000000"), (0.007, "resp", "60501F0100000000"),
        (0.008, "req", "0001020304050607"), (0.009, "resp", "2000000000000000"),
        (0.010, "req", "17080910000000 00".replace(" ", "")),
        (0.011, "resp", "3000000000000000"),
    ), 10.0, 1.0)
    assert results(t) == [("up", 0x1008, 0, "ok"), ("dl", 0x1F50, 1, "ok")]
    assert int(t.value[0]) == int.from_bytes(b"ABCDEFGH", "little")
    assert t.end_idx.tolist() == [5, 11]


def test_block_download_segment_40h_is_no_upload_request() -> None:
    t = st.transfers(frames(
        (0.0, "req", "C6501F0114000000"),  # block download initiate, 1F50h:01
        (0.001, "resp", "A0501F0140000000"),  # blksize 64
        *((0.002 + k / 1000, "req", f"{k:02X}00000000000000") for k in range(1, 64)),
        (0.07, "req", "4000000000000000"),  # segment 64: looks like an upload initiate
        (0.071, "resp", "A240400000000000"),  # ack 64
        (0.072, "req", "8100000000000000"),  # last segment (c = 1, seq 1)
        (0.073, "resp", "A201400000000000"),
        (0.074, "req", "C900000000000000"),  # end request
        (0.075, "resp", "A100000000000000"),  # end response
        (0.1, "req", "4000100000000000"), (0.101, "resp", "4300100092010200"),
    ), 10.0, 1.0)
    assert results(t) == [("dl", 0x1F50, 1, "ok"), ("up", 0x1000, 0, "ok")]
    assert int(t.mode[0]) == st.BLOCK


def test_spool_spills_per_server_and_reads_back_in_file_order() -> None:
    from nmtcheck.readers.frames import FrameBatch

    n = 1000
    can_id = np.where(np.arange(n) % 2 == 0, 0x602, 0x582).astype(np.uint32)
    can_id[::10] = 0x603
    data = np.zeros((n, 8), np.uint8)
    data[:, 0] = np.where(can_id == 0x582, 0x43, 0x40)
    data[:, 2] = 0x10
    batch = FrameBatch(np.arange(n) / 1000.0, np.zeros(n, np.int32), can_id,
                       np.zeros(n, bool), np.zeros(n, bool), np.zeros(n, bool), np.zeros(n, bool),
                       np.full(n, 8, np.int16), data, np.arange(n, dtype=np.int64),
                       np.arange(1, n + 1, dtype=np.int64))
    spool = st.SdoSpool(budget=1000)
    try:
        for part in range(0, n, 100):
            sel = slice(part, part + 100)
            spool.add(FrameBatch(*(getattr(batch, f)[sel] for f in
                                   FrameBatch.__dataclass_fields__)))
        assert spool.servers() == [2, 3]
        rows = spool.frames(2)
        assert len(rows) == int(np.count_nonzero((can_id & 0x7F) == 2))
        assert (np.diff(rows["idx"]) > 0).all()
    finally:
        spool.close()


def _endless_download(segments: int, server: int = 5) -> Iterator[FrameBatch]:
    """Batches of 4,096 frames: a segmented download initiate, then `segments` segments
    (c = 0) each confirmed, never the last one."""
    from nmtcheck.readers.frames import FrameBatch

    n = 2 + 2 * segments
    req = np.arange(n) % 2 == 0
    can_id = np.where(req, 0x600 + server, 0x580 + server).astype(np.uint32)
    data = np.zeros((n, 8), np.uint8)
    toggle = ((np.arange(n) // 2 - 1) % 2).astype(np.uint8) << 4
    data[:, 0] = np.where(req, toggle, 0x20 | toggle)
    data[2::2, 1:8] = np.random.default_rng(1).integers(0, 256, (segments, 7), np.uint8)
    data[0, :4], data[1, :4] = (0x21, 0x00, 0x20, 0x01), (0x60, 0x00, 0x20, 0x01)
    for lo in range(0, n, 4096):
        sel = slice(lo, min(n, lo + 4096))
        k = sel.stop - lo
        yield FrameBatch(np.arange(lo, sel.stop) / 1000.0, np.zeros(k, np.int32), can_id[sel],
                         np.zeros(k, bool), np.zeros(k, bool), np.zeros(k, bool),
                         np.zeros(k, bool), np.full(k, 8, np.int16), data[sel],
                         np.arange(lo, sel.stop, dtype=np.int64),
                         np.arange(lo + 1, sel.stop + 1, dtype=np.int64))


def test_a_transfer_that_never_ends_keeps_a_few_rows_a_batch() -> None:
    """200,000 segments of a download that never ends (issue 39: 3 M took 519 MB): the
    spool keeps the initiate and the frames at each batch's edges, and the transfer reads
    as from every frame (unanswered: its last client frame is the last segment)."""
    spool = st.SdoSpool()
    every = []
    try:
        for b in _endless_download(200_000):
            spool.add(b)
            every.append(b)
        rows = spool.frames(5)
        batches = len(every)
        assert len(rows) <= 2 + 8 * batches < 1000 and spool.steady_dropped == 400_002 - len(
            rows)
        whole = np.concatenate([_rows(b) for b in every])
        assert len(whole) == 400_002
        _same(st.transfers(rows, 500.0, 1.0), st.transfers(whole, 500.0, 1.0))
        t = st.transfers(rows, 500.0, 1.0)
        assert results(t) == [("dl", 0x2000, 1, "unanswered")]
        assert float(t.last_req_ts[0]) == float(whole["ts"][-2])
    finally:
        spool.close()


def _rows(b: FrameBatch) -> np.ndarray:
    """A batch of one server's SDO frames as SDO_DTYPE rows, none dropped."""
    rows = np.zeros(len(b.ts), st.SDO_DTYPE)
    rows["ts"], rows["idx"], rows["line"] = b.ts, b.index, b.line
    rows["req"], rows["dlc"], rows["data"] = b.can_id >= 0x600, b.dlc, b.data
    return rows


def _same(a: st.TransferTable, b: st.TransferTable) -> None:
    for name in st.TransferTable.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


# frames that start, end, abort or continue transfers, and the steady cycles' frames
_ODD_FRAMES = [("req", "4000100000000000"), ("resp", "4300100092010200"),
               ("req", "2B17100064000000"), ("resp", "6017100000000000"),
               ("req", "2100200108000000"), ("resp", "6000200100000000"),
               ("req", "4008100000000000"), ("resp", "4108100009000000"),
               ("req", "0101020304050607"), ("req", "1B08090000000000"),
               ("resp", "1B48490000000000"), ("resp", "0141424344454647"),
               ("req", "8000200100000405"), ("resp", "8000200111000906"),
               ("req", "0301020304050607"), ("resp", "2100000000000000")]
_CYCLES = [[("req", "00"), ("resp", "20"), ("req", "10"), ("resp", "30")],
           [("req", "60"), ("resp", "00"), ("req", "70"), ("resp", "10")]]


def test_dropping_steady_segments_changes_no_transfer() -> None:
    """Random mixtures of steady runs (either cycle, any phase, any length) and frames that
    start, end or abort transfers, cut into random batches: `transfers` gives the same
    table from the kept frames as from all of them, open or timed out at the end."""
    rng = np.random.default_rng(39)
    dropped = 0
    for _ in range(400):
        spec: list[tuple[float, str, str]] = []
        while len(spec) < 120:
            if rng.random() < 0.5:
                cycle, phase = _CYCLES[int(rng.integers(2))], int(rng.integers(4))
                for k in range(int(rng.integers(1, 30))):
                    who, cmd = cycle[(phase + k) % 4]
                    body = bytes(rng.integers(0, 256, 7, np.uint8)).hex()
                    spec.append((len(spec) * 0.01, who, cmd + body))
            else:
                who, data = _ODD_FRAMES[int(rng.integers(len(_ODD_FRAMES)))]
                spec.append((len(spec) * 0.01, who, data))
        rows = frames(*spec)
        cuts = np.sort(rng.choice(np.arange(1, len(rows)), 3, replace=False))
        kept = np.concatenate([p[~st.steady_segments(p)] for p in np.split(rows, cuts)])
        dropped += len(rows) - len(kept)
        for end, timeout in ((rows["ts"][-1] + 0.5, 1.0), (rows["ts"][-1] + 5.0, 1.0)):
            _same(st.transfers(kept, end, timeout), st.transfers(rows, end, timeout))
    assert dropped > 10_000  # the runs were long enough to drop frames from
