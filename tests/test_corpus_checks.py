"""Third-party logs (not CANopen) through the whole pipeline: no crash, and CANopen-looking
frames are judged as the SPEC says, without inventing node states from them."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import CORPUS, shared_file

from nmtcheck.engine import check_input, select_rules
from nmtcheck.settings.profiles import load_profile

THIRD = CORPUS / "third_party"
# Paths under ../shared/corpus/third_party/; without ../shared, the ones copied into
# tests/data/corpus are checked and the others skip.
TEXT_LOGS = sorted([*(p.relative_to(THIRD).as_posix() for p in THIRD.glob("python-can/*.asc")),
                    *(p.relative_to(THIRD).as_posix() for p in THIRD.glob("python-can/*.asc.gz")),
                    "savvycan/candump.log", "css-electronics/multiGeneratorCAN.log",
                    "scapy/candump.gz", "scapy/gmlan_trace.candump.gz"])


def _run(path: Path):  # type: ignore[no-untyped-def]
    profile = load_profile("default")
    return check_input(str(path), 0, profile, select_rules(profile, [], []))


@pytest.mark.parametrize("rel", TEXT_LOGS, ids=lambda rel: rel.rsplit("/", 1)[-1])
def test_every_text_log_checks_cleanly(rel: str) -> None:
    res = _run(shared_file(f"corpus/third_party/{rel}"))
    assert res.stats.frames > 0 and res.stats.skipped == 0
    for f in res.findings:
        assert f.frame_index is not None and f.frame_index < res.stats.frames
        assert f.line and f.line >= 1


def test_savvycan_dlc8_frames_on_700h_range_are_not_heartbeats() -> None:
    """0x708..0x754 frames with DLC 8 in an automotive log: C003, never heartbeats or states."""
    res = _run(shared_file("corpus/third_party/savvycan/candump.log"))
    c003 = sorted(f.node for f in res.findings if f.rule == "C003")
    # 708h, 718h, 71Ch, 728h, 738h, 748h, 74Ah, 754h: every 700h+N ID the log uses
    assert c003 == [8, 24, 28, 40, 56, 72, 74, 84]
    for m in res.nodes():
        assert not m.heartbeats and not m.bootups
        assert {iv.state for iv in m.intervals} == {"UNKNOWN"}
    assert {f.rule for f in res.findings} == {"C001", "C003"}


def test_fd_and_extended_frames_counted_and_reserved_id_reported_per_channel() -> None:
    res = _run(shared_file("corpus/third_party/css-electronics/multiGeneratorCAN.log"))
    assert (res.stats.frames, res.stats.fd_frames, res.stats.extended) == (164, 128, 82)
    assert [(f.rule, f.channel) for f in res.findings] == [("C001", "can0"), ("C001", "can1")]
    assert all("123h" in f.message and "(41 frames)" in f.message for f in res.findings)
