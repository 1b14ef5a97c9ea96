"""Causes in live monitoring (SPEC §8.6): recorded samples replayed through the live path
(`Session`, `check --follow`); a live finding gets the causes the bus had shown when it
fired, printed as indented lines under its live line, and the reports at the end (the
offline check of the recording) carry the full `causes`."""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import pytest
from conftest import SAMPLES

from nmtcheck.engine import check_input, select_rules
from nmtcheck.live.display import Display
from nmtcheck.live.follow import follow
from nmtcheck.live.frames import LiveFrame
from nmtcheck.live.session import Session
from nmtcheck.live.tracker import LiveFinding
from nmtcheck.readers import InputStats
from nmtcheck.readers.candump import _parse_line
from nmtcheck.settings.network import load_network
from nmtcheck.settings.profiles import load_profile

PROFILE = load_profile("default")
RULES = select_rules(PROFILE, [], [])
HB_LOSS = SAMPLES / "heartbeat_loss.log"  # node 3 silent after 775.666 s: H001 at 775.816 s
LINES = HB_LOSS.read_text().splitlines(keepends=True)
LIVE_KINDS = {"emcy", "emcy_other", "error_frames", "nmt", "sdo_write", "bootup_cluster"}


def frames(text: str) -> list[LiveFrame]:
    stats = InputStats("x")
    out = []
    for lineno, raw in enumerate(text.encode().splitlines(keepends=True), 1):
        row = _parse_line(raw, lineno, stats)
        if row is not None:
            ts, iface, cid, ext, rtr, err, fd, dlc, data = row
            out.append(LiveFrame(ts, iface.decode(), cid, ext, rtr, err, fd, dlc, data))
    return out


def replay(text: str, tmp_path: Path, network: Any = None
           ) -> tuple[list[LiveFinding], Any, str]:
    """`text` fed frame by frame (no timer: the next frame is the clock); the live
    findings, the offline result and what the display printed."""
    out = io.StringIO()
    display = Display(out, table=False)
    session = Session(PROFILE, RULES, network, str(tmp_path / "rec.log"), timer=False,
                      on_finding=display.finding)
    for f in frames(text):
        display.start = session.start
        session.feed(f)
    outcome = session.close()
    return outcome.live, outcome.result, out.getvalue()


def with_lines(at: int, *extra: str) -> str:
    return "".join(LINES[:at] + list(extra) + LINES[at:])


def test_live_h001_has_the_causes_before_it(tmp_path: Path) -> None:
    live, result, printed = replay("".join(LINES), tmp_path)
    [h] = [lf for lf in live if lf.rule == "H001" and lf.node == 3]
    assert [(c["kind"], c["time"], c["text"]) for c in h.causes or []] == [
        ("nmt", 1795299774.715903, "NMT start to all nodes")]
    assert h.causes_omitted == 0
    # the same entry as the offline finding's (the report written at the end)
    [off] = [f for f in result.findings if f.rule == "H001" and f.node == 3]
    assert [(c["kind"], c["time"]) for c in off.causes] == [("nmt", 1795299774.715903)]
    # printed under the live line, in the live line's time base
    lines = printed.splitlines()
    k = next(i for i, ln in enumerate(lines) if "H001" in ln)
    start = 1795299774.255886
    assert lines[k + 1] == f"    cause: {1795299774.715903 - start:.3f} s NMT start to all " \
                           "nodes (node 3)"
    # other live findings carry no causes field
    assert all(lf.causes is None for lf in live if lf.rule not in ("H001", "G002", "B001",
                                                                  "B002"))


def test_emcy_of_another_node_before_the_gap(tmp_path: Path) -> None:
    """Node 2 reports 8130h (it lost a node it monitors) 50 ms after node 3's last
    heartbeat: an `emcy_other` cause of node 3's H001, live and offline."""
    text = with_lines(73, "(1795299775.716000) can0 082#3081110000000000\n")
    live, result, printed = replay(text, tmp_path)
    [h] = [lf for lf in live if lf.rule == "H001" and lf.node == 3]
    other = [c for c in h.causes or [] if c["kind"] == "emcy_other"]
    assert [(c["node"], c["code"], c["time"]) for c in other] == [
        (2, "8130h", 1795299775.716)]
    assert "heartbeat error" in other[0]["text"]
    assert "EMCY 8130h" in printed
    [off] = [f for f in result.findings if f.rule == "H001" and f.node == 3]
    assert ("emcy_other", 2, "8130h") in {(c["kind"], c["node"], c["code"]) for c in off.causes}


def test_a_live_finding_cannot_look_ahead(tmp_path: Path) -> None:
    """SPEC_BOOT C1 (as §9.3.7 amends it): node 5's EMCY 8140h comes after its timeout.
    The offline H001 lists it as a reaction (the node's report); the live one, which fired
    before the EMCY was on the bus, cannot."""
    text = ("(10.000000) can0 705#05\n(10.100000) can0 705#05\n(10.200000) can0 705#05\n"
            "(10.300000) can0 705#05\n(11.000000) can0 085#4081110000000000\n"
            "(11.010000) can0 705#05\n")
    live, result, _printed = replay(text, tmp_path)
    [h] = [lf for lf in live if lf.rule == "H001"]
    assert h.causes == [] and h.reactions == []
    [off] = [f for f in result.findings if f.rule == "H001"]
    assert off.causes == []
    assert [(c["kind"], c["code"], c["role"]) for c in off.reactions or []] == [
        ("emcy", "8140h", "report")]


@pytest.mark.parametrize("path", [SAMPLES / "lely" / "mandatory" / "mandatory_lost.log",
                                  SAMPLES / "lely" / "unplugged_guarded.log",
                                  SAMPLES / "lely" / "reboot.log",
                                  SAMPLES / "lely" / "unplugged_heartbeat.log"],
                         ids=lambda p: p.stem)
def test_live_causes_are_among_the_offline_ones(path: Path, tmp_path: Path) -> None:
    """Real Lely recordings (H001, G002, B001, B002): every cause a live finding shows is
    one the offline finding has too, and every offline cause of a kind the live tracker
    knows, dated before the live finding fired, was shown live."""
    net = load_network(str(path.parent / "network.toml"))
    live, result, _printed = replay(path.read_text(), tmp_path, net)
    original = check_input(str(path), 0, PROFILE, RULES, net)
    checked = 0
    for lf in live:
        if lf.causes is None:
            continue
        match = [f for f in original.findings if (f.rule, f.node) == (lf.rule, lf.node)
                 and abs(f.time - lf.time) < 0.1]
        assert match, (lf.rule, lf.node, lf.time)
        off = match[0].causes or []
        key = {(c["kind"], c["time"], c["node"], c["code"]) for c in off}
        for c in lf.causes:
            if c["kind"] in LIVE_KINDS and c["kind"] != "error_frames":
                assert (c["kind"], c["time"], c["node"], c["code"]) in key, (lf.rule, c, off)
        if not match[0].causes_omitted and not lf.causes_omitted:
            seen = {(c["kind"], c["time"]) for c in lf.causes}
            for c in off:
                if c["kind"] in LIVE_KINDS and c["time"] <= lf.time and c["kind"] not in (
                        "bootup_cluster", "error_frames"):
                    assert (c["kind"], c["time"]) in seen, (lf.rule, lf.node, c)
        checked += 1
    assert checked  # each of these logs has a finding with causes
    # the session's reports are the offline check: the same causes
    assert [(f.rule, f.node, f.causes) for f in result.findings] == [
        (f.rule, f.node, f.causes) for f in original.findings]


def run_follow(text: str) -> tuple[str, Any]:
    out = io.StringIO()
    [res] = follow(io.BytesIO(text.encode()), PROFILE, RULES, display=Display(out, table=False))
    return out.getvalue(), res


def test_follow_dropcount_in_the_gap_is_a_frames_lost_cause() -> None:
    drop = "DROPCOUNT: dropped 9 CAN frames on 'can0' socket (total drops 9)\n"
    printed, res = run_follow(with_lines(70, drop))  # between 775.656 s and 775.666 s
    lines = printed.splitlines()
    k = next(i for i, ln in enumerate(lines) if "H001" in ln and "node 3" in ln)
    causes = [ln for ln in lines[k + 1:] if ln.startswith("    cause:")]
    assert any("9 frame(s) lost" in ln for ln in causes), printed
    # the report at the end (the offline check of the same bytes) has it too
    [off] = [f for f in res.findings if f.rule == "H001" and f.node == 3]
    assert [c["count"] for c in off.causes if c["kind"] == "frames_lost"] == [9]


def test_follow_dropcount_long_after_is_no_cause() -> None:
    drop = "DROPCOUNT: dropped 9 CAN frames on 'can0' socket (total drops 9)\n"
    printed, res = run_follow(with_lines(len(LINES) - 1, drop))  # at 778.19 s
    assert "frame(s) lost" not in printed
    assert res.stats.dropped == 9
    [off] = [f for f in res.findings if f.rule == "H001" and f.node == 3]
    assert [c for c in off.causes if c["kind"] == "frames_lost"] == []
