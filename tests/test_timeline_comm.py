"""`nmtcheck timeline` and SPEC §9.4.2: the SYNC line above each channel's node rows, the
gaps of Y001, D001 and D004 as intervals, each node's EMCYs with CANopenNode's detail,
and the `kind` rows of `--format csv|json`.

The recordings are CANopenNode's (samples/canopennode/, README there): what is expected
comes from the log's frames and from the stack's own `.events` (the EMCYs it says it
sent, with their info), never from nmtcheck's other reports.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path

import stack_recording as recording
from conftest import SAMPLES, Checker
from conftest import run_cli as run

from nmtcheck.cli.timeline import COLUMNS, render_timeline

CN = SAMPLES / "canopennode"
SYNC_STOP = (CN / "sync_emcy" / "sync_producer_stopped.log",
             CN / "sync_emcy" / "network_sync_stopped.toml")
RPDO_STOP = (CN / "pdo" / "rpdo_producer_stopped.log",
             CN / "pdo" / "network_rpdo_producer_stopped.toml")
HEALTHY_SYNC = (CN / "pdo" / "sync_tpdo.log", CN / "pdo" / "network_sync_tpdo.toml")


def _timeline(pair: tuple[Path, Path], fmt: str, tmp_path: Path) -> str:
    log, net = pair
    res = run("timeline", str(log.resolve()), "--network", str(net.resolve()), "--format", fmt,
              "--isolated", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    return res.stdout


def _syncs(log: Path) -> list[recording.Frame]:
    return [f for f in recording.frames(log) if f.can_id == 0x080]


def test_sync_line_gap_and_emcys_in_text(tmp_path: Path) -> None:
    """The SYNC producer (node 2) is stopped at 3.998 s: the SYNC line sits above the node
    rows with the log's SYNC count and the one gap; the gap runs from the last SYNC before
    the stop to the first after node 2 runs again; each consumer's EMCY 8100h is an event
    with CANopenNode's SYNC timeout and the µs the stack itself wrote."""
    log = SYNC_STOP[0]
    text = _timeline(SYNC_STOP, "text", tmp_path).splitlines()
    syncs = _syncs(log)
    sync_line = next(k for k, x in enumerate(text) if x.startswith("can0 SYNC "))
    assert sync_line < text.index("can0 node 1:")
    assert text[sync_line] == (
        "can0 SYNC 080h (network): producer node 2 (network), period 20000 us (network), "
        f"median interval {text[sync_line].split('median interval ')[1].split(' us')[0]} us, "
        f"{len(syncs)} frames, 1 gap over the timeout (Y001)")
    stop = next(f for f in recording.frames(log) if (f.can_id, f.data) == (0x000, "0202"))
    last = [f for f in syncs if f.t < stop.t][-1]
    nxt = next(f for f in syncs if f.t > stop.t)
    gap = text[sync_line + 1].split()
    assert gap[:5] == [f"{last.t:.6f}", "..", f"{nxt.t:.6f}", "SYNC", "gap"]
    assert "Y001 error" in text[sync_line + 1]
    # every EMCY the stack sent, under its node, with the detail read from its bytes
    sent = recording.emcys_sent(log)
    assert len(sent) == 4
    for t, node, data in sent:
        block = text[text.index(f"can0 node {node}:"):]
        block = block[:next((k for k, x in enumerate(block[1:], 1) if x.startswith("can0 ")),
                            len(block))]
        line = next(x for x in block if "event: EMCY" in x and abs(float(x.split()[0]) - t)
                    < 0.001)
        code = int.from_bytes(bytes.fromhex(data)[:2], "little")
        info = int.from_bytes(bytes.fromhex(data)[4:], "little")
        assert f"EMCY {code:04X}h" in line
        if code:
            assert line.endswith(f"; CANopenNode: SYNC timeout (us since the last SYNC = "
                                 f"{info}), error bit 18h")
        else:  # CANopenNode's reset repeats the bit it clears: no detail of its own
            assert "CANopenNode" not in line


def test_sync_gap_and_emcy_rows_in_csv_and_json(tmp_path: Path) -> None:
    log = SYNC_STOP[0]
    start = recording.t0(log)
    rows = json.loads(_timeline(SYNC_STOP, "json", tmp_path))
    assert all(set(r) == set(COLUMNS) for r in rows)
    assert {r["kind"] for r in rows} == {"state", "sync_gap", "emcy"}
    [gap] = [r for r in rows if r["kind"] == "sync_gap"]
    syncs = _syncs(log)
    assert (round(gap["start"] - start, 6), round(gap["end"] - start, 6)) == (3.983065, 6.017433)
    assert 3.983065 in [f.t for f in syncs] and 6.017433 in [f.t for f in syncs]
    assert not [f for f in syncs if 3.983065 < f.t < 6.017433]
    assert (gap["rule"], gap["cob_id"], gap["node"], gap["line"]) == ("Y001", "080h", 2, 436)
    emcys = [r for r in rows if r["kind"] == "emcy"]
    sent = sorted(recording.emcys_sent(log), key=lambda e: (e[1], e[0]))
    assert [(r["node"], r["code"]) for r in emcys] == [
        (node, f"{int.from_bytes(bytes.fromhex(d)[:2], 'little'):04X}h") for _t, node, d in sent]
    for r, (t, _node, data) in zip(emcys, sent, strict=True):
        assert abs(r["start"] - start - t) < 0.001 and r["start"] == r["end"]
        info = int.from_bytes(bytes.fromhex(data)[4:], "little")
        assert r["canopennode"] == (None if r["code"] == "0000h" else {
            "error_bit": "18h", "info": info,
            "meaning": f"SYNC timeout (us since the last SYNC = {info})"})
    states = [r for r in rows if r["kind"] == "state"]
    assert states and all(r["state"] and r["source"] for r in states)
    table = list(csv.DictReader(io.StringIO(_timeline(SYNC_STOP, "csv", tmp_path))))
    assert [(r["kind"], r["node"], r["start"], r["code"], r["rule"]) for r in table] == [
        (r["kind"], "" if r["node"] is None else str(r["node"]), f"{r['start']:.6f}",
         r["code"] or "", r["rule"] or "") for r in rows]


def test_rpdo_gap_under_the_consumer(tmp_path: Path) -> None:
    """Node 2 (producer of 182h) is stopped at 3.998 s: D004 of consumer 3 is a `pdo_gap`
    from the last 182h before the stop to the first after node 2 runs again, under node 3,
    and node 3's EMCY 8250h carries the µs the stack wrote as its info."""
    log = RPDO_STOP[0]
    start = recording.t0(log)
    frames = recording.frames(log)
    stop = next(f for f in frames if (f.can_id, f.data) == (0x000, "0202"))
    tpdo = [f for f in frames if f.can_id == 0x182]
    last = [f for f in tpdo if f.t < stop.t][-1]
    nxt = next(f for f in tpdo if f.t > stop.t)
    rows = json.loads(_timeline(RPDO_STOP, "json", tmp_path))
    [gap] = [r for r in rows if r["kind"] == "pdo_gap"]
    assert (gap["node"], gap["rule"], gap["cob_id"]) == (3, "D004", "182h")
    assert (round(gap["start"] - start, 6), round(gap["end"] - start, 6)) == (last.t, nxt.t)
    [(t, node, data)] = [e for e in recording.emcys_sent(log) if e[2][:4] == "5082"]
    [emcy] = [r for r in rows if r["kind"] == "emcy" and r["code"] == "8250h"]
    info = int.from_bytes(bytes.fromhex(data)[4:], "little")
    assert emcy["node"] == node == 3 and abs(emcy["start"] - start - t) < 0.001
    assert emcy["canopennode"] == {"error_bit": "17h", "info": info,
                                   "meaning": f"RPDO timeout (us since the timer was armed = "
                                              f"{info})"}
    text = _timeline(RPDO_STOP, "text", tmp_path).splitlines()
    node3 = text[text.index("can0 node 3:"):text.index("can0 node 4:")]
    [line] = [x for x in node3 if "PDO gap" in x]
    assert line.split()[:6] == [f"{last.t:.6f}", "..", f"{nxt.t:.6f}", "PDO", "gap", "182h"]
    assert "D004 error (line 282): no RPDO 182h for node 3" in line


def test_d001_gap_of_the_spec_vector(checker: Checker) -> None:
    """SPEC §9.5.2 D001: TPDOs at 10.202 and 10.500, event timer 100 ms: the gap runs from
    10.202 to 10.500 under the producer, node 3."""
    log = ("(10.000000) can0 703#00\n(10.001000) can0 000#0103\n(10.002000) can0 183#0100\n"
           "(10.102000) can0 183#0200\n(10.202000) can0 183#0300\n(10.500000) can0 183#0400\n"
           "(10.600000) can0 183#0500\n")
    net = "[nodes.3.tpdo.1]\ncob_id = 0x183\ntransmission_type = 254\nevent_timer_ms = 100\n"
    res = checker.run(log, network=net)
    rows = json.loads(render_timeline(res, "json"))
    assert [(r["kind"], r["node"], r["rule"], r["cob_id"], r["start"], r["end"])
            for r in rows if r["kind"] != "state"] == [
        ("pdo_gap", 3, "D001", "183h", 10.202, 10.5)]
    text = render_timeline(res, "text")
    assert "      0.202000 ..     0.500000  PDO gap 183h     D001 warning (line 6): no TPDO " \
           "183h from node 3 for 298.000 ms" in text


def test_healthy_sync_recording_has_no_gap(tmp_path: Path) -> None:
    """A clean CANopenNode recording with SYNC (produced by node 1 every 20 ms) and
    synchronous PDOs: the SYNC line says no gap, and no gap or EMCY rows appear."""
    log = HEALTHY_SYNC[0]
    assert not [f for f in recording.frames(log) if 0x81 <= f.can_id <= 0xFF]
    text = _timeline(HEALTHY_SYNC, "text", tmp_path)
    assert f"{len(_syncs(log))} frames, 0 gaps over the timeout (Y001)" in text
    assert " gap " not in text.replace("0 gaps over", "")
    rows = json.loads(_timeline(HEALTHY_SYNC, "json", tmp_path))
    assert {r["kind"] for r in rows} == {"state"}


def test_no_sync_no_sync_line(checker: Checker) -> None:
    """A channel without SYNC frames or SYNC configuration has no SYNC line."""
    res = checker.run("(1.000000) can0 702#05\n(1.500000) can0 702#05\n")
    text = render_timeline(res, "text")
    assert "SYNC" not in text and "can0 node 2:" in text


def test_sync_line_on_a_channel_without_nodes(checker: Checker) -> None:
    """SYNC alone (no node seen): the SYNC line still says what the channel carried."""
    res = checker.run("".join(f"({1000 + k * 0.01:.6f}) can0 080#\n" for k in range(50)))
    text = render_timeline(res, "text").splitlines()
    assert text[1].startswith("can0 SYNC 080h (default): producer unknown, period unknown, "
                              "median interval 10000.0 us, 50 frames, ")


def test_sync_line_when_the_profile_turns_y001_off(tmp_path: Path) -> None:
    """Y001 off in the profile: the SYNC line says so instead of counting no gap, and no
    gap row appears."""
    profile = tmp_path / "no_y001.toml"
    profile.write_text('extends = "default"\n\n[rules.Y001]\nenabled = false\n')
    log, net = SYNC_STOP
    res = run("timeline", str(log.resolve()), "--network", str(net.resolve()), "--rules",
              str(profile), "--isolated", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert (f", {len(_syncs(log))} frames, gaps over the timeout: Y001 not checked (the "
            "profile turns it off)") in res.stdout
    assert "SYNC gap" not in res.stdout


def test_sync_line_of_a_log_without_timestamps(checker: Checker) -> None:
    """Times are frame numbers there: the SYNC line measures no interval."""
    res = checker.run("can0 705#05\ncan0 080#\ncan0 080#\ncan0 080#\ncan0 705#05\n")
    assert res.stats.order_only
    assert render_timeline(res, "text").splitlines()[1] == (
        "can0 SYNC 080h (default): producer unknown, period unknown, 3 frames, gaps over the "
        "timeout: Y001 not evaluated")
