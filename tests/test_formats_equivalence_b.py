"""The same traffic in MCAP (ROS 2 and JSON), pcap and pcapng gives the same verdicts as candump.

Every sample (samples/*.log, candump recordings of a real CANopen stack) is
converted here: into MCAP with mcap_ros2's writer (can_msgs/msg/Frame, the
header stamp carrying the time and the log time lagging by a varying
latency) and with the plain mcap writer (JSON messages, log time only), and
into pcap / pcapng (SocketCAN link type) with the writers of
test_readers_pcap. Findings (rule, node, time from the input's start, frame)
and every node's timeline must equal those of the candump original. The
scapy GMLAN trace, published both as candump and as pcap, must give
identical frames.
"""

from __future__ import annotations

import dataclasses
import json
import random
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import CORPUS, SAMPLES, needs_corpus
from hostile_logs import ROS2_FRAME_MSG
from mcap.writer import Writer as McapWriter
from test_readers_pcap import (
    Frame,
    pcap_file,
    pcapng_interface,
    pcapng_packet,
    pcapng_section,
    socketcan,
)

from nmtcheck.engine import check_input, select_rules
from nmtcheck.readers import open_input
from nmtcheck.readers.frames import FrameBatch
from nmtcheck.results import InputResult
from nmtcheck.settings.profiles import load_profile

THIRD = CORPUS / "third_party"
SAMPLE_LOGS = sorted(SAMPLES.glob("*.log"))
Columns = dict[str, np.ndarray]


def columns(path: Path) -> Columns:
    opened = open_input(str(path))
    batches = list(opened.batches)
    return {f.name: np.concatenate([getattr(b, f.name) for b in batches])
            for f in dataclasses.fields(FrameBatch)}


def _ns(ts: float) -> int:
    return round(ts * 1e6) * 1000  # candump stamps have microseconds


def _frames(c: Columns) -> list[tuple[int, int, bool, bool, bool, int, bytes]]:
    out = []
    for i in range(len(c["ts"])):
        dlc = int(c["dlc"][i])
        rtr = bool(c["rtr"][i])
        out.append((_ns(float(c["ts"][i])), int(c["can_id"][i]), bool(c["ext"][i]), rtr,
                    bool(c["err"][i]), dlc, b"" if rtr else bytes(c["data"][i, :dlc])))
    return out


def to_mcap_ros2(c: Columns, path: Path) -> None:
    from mcap_ros2.writer import Writer

    rnd = random.Random(7)
    with path.open("wb") as fh:
        writer = Writer(fh)
        schema = writer.register_msgdef("can_msgs/msg/Frame", ROS2_FRAME_MSG)
        for t, can_id, ext, rtr, err, dlc, data in _frames(c):
            sec, nsec = divmod(t, 10**9)
            writer.write_message("/from_can_bus", schema, {
                "header": {"stamp": {"sec": sec, "nanosec": nsec}, "frame_id": "can0"},
                "id": can_id, "is_rtr": rtr, "is_extended": ext, "is_error": err, "dlc": dlc,
                "data": data.ljust(8, b"\0")}, log_time=t + rnd.randrange(1_000_000, 40_000_000))
        writer.finish()


def to_mcap_json(c: Columns, path: Path) -> None:
    with path.open("wb") as fh:
        writer = McapWriter(fh)
        writer.start(profile="", library="nmtcheck tests")
        channel = writer.register_channel("/can/json", "json", 0)
        for seq, (t, can_id, ext, rtr, err, dlc, data) in enumerate(_frames(c)):
            msg: dict[str, Any] = {"can_id": can_id, "is_extended_id": ext,
                                   "is_remote_frame": rtr, "is_error_frame": err,
                                   "dlc": dlc, "data": data.hex()}
            writer.add_message(channel, log_time=t, publish_time=t, sequence=seq,
                               data=json.dumps(msg).encode())
        writer.finish()


def _socketcan_frames(c: Columns) -> list[Frame]:
    return [Frame(t // 1000, can_id, data, ext, rtr, err, dlc=dlc)
            for t, can_id, ext, rtr, err, dlc, data in _frames(c)]


def to_pcap(c: Columns, path: Path) -> None:
    path.write_bytes(pcap_file((f.t_us, socketcan(f)) for f in _socketcan_frames(c)))


def to_pcapng(c: Columns, path: Path) -> None:
    blocks = [pcapng_section(), pcapng_interface(227, "can0", 9)]
    blocks += [pcapng_packet(0, f.t_us * 1000, socketcan(f, "<", trim=True))
               for f in _socketcan_frames(c)]
    path.write_bytes(b"".join(blocks))


CONVERTERS = {"mcap-ros2": (to_mcap_ros2, ".mcap"), "mcap-json": (to_mcap_json, ".mcap"),
              "pcap": (to_pcap, ".pcap"), "pcapng": (to_pcapng, ".pcapng")}


def _check(path: Path) -> InputResult:
    profile = load_profile("default")
    return check_input(str(path), 0, profile, select_rules(profile, [], []))


def findings(r: InputResult) -> list[tuple[str, str, int | None, float, int | None]]:
    start = r.stats.start or 0.0
    return [(f.rule, f.severity, f.node, f.time - start, f.frame_index) for f in r.findings]


def timeline(r: InputResult) -> list[tuple[int, str, str, float, float]]:
    start = r.stats.start or 0.0
    return [(m.node, iv.state, iv.source, iv.start - start, iv.end - start)
            for m in r.nodes() for iv in m.intervals]


def same_within_1ms(ours: list[tuple[Any, ...]], theirs: list[tuple[Any, ...]]) -> None:
    assert len(ours) == len(theirs), (ours, theirs)
    for a, b in zip(ours, theirs, strict=True):
        assert [x for x in a if not isinstance(x, float)] == [
            x for x in b if not isinstance(x, float)], (a, b)
        assert [x for x in a if isinstance(x, float)] == pytest.approx(
            [x for x in b if isinstance(x, float)], abs=1e-3), (a, b)


def test_samples_present() -> None:
    assert len(SAMPLE_LOGS) >= 6


@pytest.mark.parametrize("kind", sorted(CONVERTERS))
@pytest.mark.parametrize("log", SAMPLE_LOGS, ids=[p.stem for p in SAMPLE_LOGS])
def test_sample_gives_the_same_verdict(log: Path, kind: str, tmp_path: Path) -> None:
    convert, suffix = CONVERTERS[kind]
    original = columns(log)
    converted = tmp_path / f"{log.stem}{suffix}"
    convert(original, converted)
    a, b = _check(log), _check(converted)
    assert b.stats.format == ("mcap" if kind.startswith("mcap") else "pcap")
    assert (b.stats.frames, b.stats.skipped, b.stats.remote_frames) == (
        a.stats.frames, 0, a.stats.remote_frames)
    assert len(b.stats.channels) == 1
    same_within_1ms(findings(b), findings(a))
    same_within_1ms(timeline(b), timeline(a))
    assert [iv[:3] for iv in timeline(a)], "a sample without any node timeline"


@needs_corpus
def test_gmlan_trace_candump_and_pcap_give_identical_frames() -> None:
    a = columns(THIRD / "scapy/gmlan_trace.candump.gz")
    b = columns(THIRD / "scapy/gmlan_trace.pcap.gz")
    assert len(a["ts"]) == len(b["ts"]) == 1087
    for name in a:
        if name not in ("chan", "line"):  # the pcap has no interface name, and no lines
            np.testing.assert_array_equal(a[name], b[name], err_msg=name)
