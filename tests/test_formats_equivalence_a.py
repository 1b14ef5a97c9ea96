"""The recorded samples, converted to BLF, TRC, CSV (and candump screen / SavvyCAN CSV), give the
findings and timelines of the candump original.

The conversions use python-can's own writers (`can.BLFWriter`, `can.TRCWriter`,
`can.CSVWriter`) on the frames python-can reads from the candump log. python-can's
TRCWriter drops remote frames ("not implemented"), which would lose the node-guarding
requests of `guard_toggle`; the writer below adds them as TRC 2.1 `RR` lines in the same
layout. candump's screen output and SavvyCAN's CSV have no python-can writer: they are
formatted here the way candump.c and SavvyCAN print them.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import can
import pytest
from conftest import SAMPLES

from nmtcheck.engine import check_input, select_rules
from nmtcheck.results import InputResult
from nmtcheck.settings.profiles import load_profile

SAMPLE_NAMES = sorted(p.stem for p in SAMPLES.glob("*.log"))


class TRCWriterWithRemoteFrames(can.TRCWriter):
    """python-can's TRCWriter, plus remote frames as `RR` lines of its own 2.1 layout."""

    def on_message_received(self, msg: can.Message) -> None:
        if not msg.is_remote_frame:
            super().on_message_received(msg)
            return
        if self.first_timestamp is None:
            self.first_timestamp = msg.timestamp
        line = self._format_message(msg, 1)  # the samples have one channel
        self.msgnr += 1
        self.log_event(line.replace(" DT ", " RR ", 1).rstrip(), msg.timestamp)


def messages(sample: str) -> list[can.Message]:
    return list(can.CanutilsLogReader(str(SAMPLES / f"{sample}.log")))


def to_blf(msgs: list[can.Message], path: Path) -> None:
    with can.BLFWriter(str(path)) as writer:
        for m in msgs:
            writer.on_message_received(m)


def to_trc(msgs: list[can.Message], path: Path) -> None:
    with TRCWriterWithRemoteFrames(str(path)) as writer:
        for m in msgs:
            writer.on_message_received(m)


def to_csv(msgs: list[can.Message], path: Path) -> None:
    with can.CSVWriter(str(path)) as writer:
        for m in msgs:
            writer.on_message_received(m)


def to_screen(msgs: list[can.Message], path: Path) -> None:
    """`candump -ta -x can0` output."""
    lines = []
    for m in msgs:
        sec, usec = divmod(round(m.timestamp * 1e6), 1_000_000)
        ident = f"{m.arbitration_id:08X}" if m.is_extended_id else f"{m.arbitration_id:03X}"
        body = (f" [{m.dlc}]  remote request" if m.is_remote_frame
                else f" [{m.dlc}] " + "".join(f" {b:02X}" for b in m.data))
        lines.append(f" ({sec:010d}.{usec:06d})  {m.channel}  {'RX' if m.is_rx else 'TX'} - -"
                     f"  {ident}  {body}\n")
    path.write_text("".join(lines))


def to_savvycan(msgs: list[can.Message], path: Path) -> None:
    """SavvyCAN's native CSV (it has no remote frames: the samples with RTRs are left out)."""
    lines = ["Time Stamp,ID,Extended,Dir,Bus,LEN,D1,D2,D3,D4,D5,D6,D7,D8\n"]
    for m in msgs:
        assert not m.is_remote_frame
        cells = [f"{b:02X}" for b in m.data] + ["00"] * (8 - len(m.data))
        lines.append(f"{round(m.timestamp * 1e6)},{m.arbitration_id:08X},"
                     f"{'true' if m.is_extended_id else 'false'},{'Rx' if m.is_rx else 'Tx'},0,"
                     f"{len(m.data)},{','.join(cells)},\n")
    path.write_text("".join(lines))


CONVERTERS: dict[str, tuple[str, Callable[[list[can.Message], Path], None]]] = {
    "blf": (".blf", to_blf),
    "trc": (".trc", to_trc),
    "csv": (".csv", to_csv),
    "candump-screen": (".txt", to_screen),
    "savvycan-csv": (".csv", to_savvycan),
}


def check(path: Path) -> InputResult:
    profile = load_profile("default")
    return check_input(str(path), 0, profile, select_rules(profile, [], []))


def findings(res: InputResult) -> list[tuple[str, int | None, float]]:
    start = res.stats.start or 0.0
    return [(f.rule, f.node, round(f.time - start, 3)) for f in res.findings]


def timeline(res: InputResult) -> list[tuple[int, str, float, float, str]]:
    start = res.stats.start or 0.0
    return [(m.node, iv.state, round(iv.start - start, 3), round(iv.end - start, 3), iv.source)
            for m in res.nodes() for iv in m.intervals]


@pytest.mark.parametrize("fmt", sorted(CONVERTERS))
@pytest.mark.parametrize("sample", SAMPLE_NAMES)
def test_converted_sample_gives_the_same_findings_and_timeline(tmp_path: Path, sample: str,
                                                               fmt: str) -> None:
    msgs = messages(sample)
    if fmt == "savvycan-csv" and any(m.is_remote_frame for m in msgs):
        pytest.skip("SavvyCAN's CSV has no remote frames")
    suffix, convert = CONVERTERS[fmt]
    path = tmp_path / f"{sample}{suffix}"
    convert(msgs, path)
    original, converted = check(SAMPLES / f"{sample}.log"), check(path)
    assert converted.stats.format == fmt.removesuffix("-csv").replace("savvycan", "csv")
    assert converted.stats.skipped == 0
    assert (converted.stats.frames, converted.stats.remote_frames) == (
        original.stats.frames, original.stats.remote_frames)
    assert findings(converted) == findings(original)
    assert timeline(converted) == timeline(original)
    assert [f.frame_index for f in converted.findings] == [
        f.frame_index for f in original.findings]


def test_every_fault_sample_has_findings() -> None:
    # the comparison above would pass vacuously on empty results; the samples are not empty
    results = {s: check(SAMPLES / f"{s}.log") for s in SAMPLE_NAMES}
    assert {res.findings[0].rule for res in results.values() if res.findings} >= {
        "G001", "H001", "S001", "S004", "B003"}
    assert all(timeline(res) for res in results.values())
    assert results["guard_toggle"].stats.remote_frames > 0
