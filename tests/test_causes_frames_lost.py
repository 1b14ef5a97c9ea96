"""The `frames_lost` cause (SPEC §8.6.3, kind 5): a logger drop or a controller overflow
inside a finding's window. Recorded traffic (samples/heartbeat_loss.log: node 3 stops its
heartbeats at 1795299775.666 s, H001 at 775.816 s) with the lines a logger writes
inserted: candump's `DROPCOUNT` line and a SocketCAN controller error frame."""

from __future__ import annotations

from typing import Any

from conftest import SAMPLES, Checker

from nmtcheck.reporters import text

LOG = (SAMPLES / "heartbeat_loss.log").read_text().splitlines(keepends=True)
DROP = "DROPCOUNT: dropped 17 CAN frames on 'can0' socket (total drops 17)\n"
# SocketCAN: CAN_ERR_FLAG | CAN_ERR_CRTL, byte 1 = CAN_ERR_CRTL_RX_OVERFLOW (01h) or
# CAN_ERR_CRTL_RX_WARNING (04h, no frame lost)
OVERFLOW = "(1795299775.700000) can0 20000004#0001000000000000\n"
WARNING = "(1795299775.700000) can0 20000004#0004000000000000\n"


def with_lines(at: int, *extra: str) -> str:
    """The sample with `extra` inserted after its line `at` (1-based)."""
    return "".join(LOG[:at] + list(extra) + LOG[at:])


def h001(checker: Checker, log: str) -> Any:
    res = checker.run(log)
    found = [f for f in res.findings if f.rule == "H001" and f.node == 3]
    assert len(found) == 1, [(f.rule, f.node) for f in res.findings]
    return res, found[0]


def lost(f: Any) -> list[dict[str, Any]]:
    return [c for c in f.causes or [] if c["kind"] == "frames_lost"]


def test_dropcount_inside_the_gap_is_a_cause(checker: Checker) -> None:
    # after line 75 (775.756512 s): the DROPCOUNT is line 76; its moment is the frame after
    # it (index 75, line 77, 775.790898 s): the lost frames were due before that one
    res, f = h001(checker, with_lines(75, DROP))
    [c] = lost(f)
    assert (c["time"], c["frame_index"], c["line"], c["count"], c["end"], c["node"]) == (
        1795299775.790898, 75, 76, 17, None, None)
    assert c["text"].startswith("the logger reported 17 frame(s) lost (1 DROPCOUNT record(s))")
    assert res.stats.dropped == 17 and res.stats.drops == [(76, 17)]
    assert any(r.rule == "I004" for r in res.findings)  # the input finding stays as it was
    # text: an indented cause line under the finding
    out = text.render([res], {})
    start = res.stats.start or 0.0
    assert f"        cause: {1795299775.790898 - start:.6f} s the logger reported 17 frame(s) " \
        "lost" in out


def test_dropcount_outside_the_window_is_no_cause(checker: Checker) -> None:
    # after the last line: 778.19 s, past the window's end (775.816 + 0.5 s)
    res, f = h001(checker, with_lines(len(LOG), DROP))
    assert res.stats.dropped == 17
    assert lost(f) == []
    _res, clean = h001(checker, "".join(LOG))
    assert lost(clean) == []


def test_controller_overflow_error_frame_is_a_cause(checker: Checker) -> None:
    _res, f = h001(checker, with_lines(75, OVERFLOW))
    [c] = lost(f)
    assert (c["time"], c["count"], c["line"]) == (1795299775.7, 1, 76)
    assert "controller overflow" in c["text"]
    # an error frame is also an error frame
    assert [c["count"] for c in f.causes if c["kind"] == "error_frames"] == [1]


def test_error_frame_without_overflow_is_no_lost_frame(checker: Checker) -> None:
    _res, f = h001(checker, with_lines(75, WARNING))
    assert lost(f) == []
    assert [c["count"] for c in f.causes if c["kind"] == "error_frames"] == [1]
