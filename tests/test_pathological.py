"""Logs full of events: a state change on every heartbeat, nothing but NMT commands.

The timeline keeps intervals, commands and NMT frames as columns, checks hand the
engine columnar batches, and the JSON report is written in pieces: memory follows
the frames, not the events (bench/pathological.py measures 1 M and 5 M frames).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
from test_memory import peak_rss_mb

from nmtcheck.checks import RULES
from nmtcheck.engine import check_input
from nmtcheck.reporters import html, streamer
from nmtcheck.reporters import json as json_report
from nmtcheck.results import InputResult
from nmtcheck.settings.profiles import load_profile

CODES = ("05", "7F", "04")  # OPERATIONAL, PRE-OPERATIONAL, STOPPED: every heartbeat changes


def write_flapping(path: Path, frames: int, nodes: int = 10) -> None:
    """Heartbeats of `nodes` nodes, 1 ms apart, each reporting another state than its last."""
    with open(path, "w") as out:
        out.writelines(f"({1700000000 + i / 1000:.6f}) can0 {0x700 + i % nodes + 1:03X}#"
                       f"{CODES[(i // nodes) % 3]}\n" for i in range(frames))


def write_commands(path: Path, frames: int, nodes: int = 10) -> None:
    """Every NMT command to every node and to all, with a heartbeat of each node now and then."""
    specifiers = ("01", "02", "80", "81", "82")
    with open(path, "w") as out:
        for i in range(frames):
            ts = f"({1700000000 + i / 1000:.6f}) can0 "
            node = i % (nodes + 1)  # 0: broadcast
            if i % 7 == 0:
                out.write(f"{ts}{0x700 + (node or 1):03X}#05\n")
            else:
                out.write(f"{ts}000#{specifiers[i % 5]}{node:02X}\n")


def check(path: Path, max_findings: int = 10000) -> InputResult:
    profile = load_profile("default")
    return check_input(str(path), 0, profile, list(RULES), max_findings=max_findings)


def test_a_state_change_on_every_heartbeat_is_one_interval_each(tmp_path: Path) -> None:
    log = tmp_path / "flap.log"
    write_flapping(log, 3000)
    res = check(log, max_findings=0)
    node = res.model.channels[0].nodes[1]
    assert len(node.intervals) == 300  # UNKNOWN replaced at the first heartbeat: 300 states
    assert [iv.state for iv in node.intervals][:4] == [
        "OPERATIONAL", "PRE-OPERATIONAL", "STOPPED", "OPERATIONAL"]
    ends = node.intervals.end[:-1]
    assert (ends == node.intervals.start[1:]).all()  # no gap, no overlap
    s005 = [f for f in res.findings if f.rule == "S005" and f.node == 1]
    assert len(s005) == 299  # every change after the first state is unexplained
    assert s005[0].message == ("node 1 changed from OPERATIONAL to PRE-OPERATIONAL without "
                               "an NMT command")


def test_a_columnar_batch_is_capped_in_order_and_the_rest_counted(tmp_path: Path) -> None:
    log = tmp_path / "flap.log"
    write_flapping(log, 3000)
    full = [f for f in check(log, max_findings=0).findings if f.rule == "S005"]
    capped = check(log, max_findings=25)
    kept = [f for f in capped.findings if f.rule == "S005"]
    # the first 25 the rule found (node 1's first, then on), each with its own message
    assert [(f.node, f.time, f.message) for f in kept] == sorted(
        [(f.node, f.time, f.message) for f in full if f.node == 1][:25], key=lambda t: t[1])
    assert [(o.rule, o.count) for o in capped.omitted] == [("S005", len(full) - 25)]


def test_commands_are_applied_per_node_as_columns(tmp_path: Path) -> None:
    log = tmp_path / "cmd.log"
    write_commands(log, 2200)
    res = check(log)
    ch = res.model.channels[0]
    direct = sum(1 for i in range(2200) if i % 7 and i % 11 == 3)
    node3 = ch.nodes[3]
    broadcast = int(node3.commands.broadcast.sum())
    assert len(node3.commands) - broadcast == direct
    assert broadcast > 0 and node3.commands.reset_idx.size > 0
    assert len(ch.nmt) == sum(1 for i in range(2200) if i % 7)
    assert ch.nmt.valid.all()
    first = node3.commands[0]  # materialised on demand, with its name
    assert first.name in ("start", "stop", "enter pre-operational", "reset node",
                          "reset communication") or first.name.endswith("(broadcast)")


def test_the_json_report_in_pieces_is_the_json_report(tmp_path: Path) -> None:
    log = tmp_path / "flap.log"
    write_flapping(log, 2000)
    res = check(log)
    options: dict[str, object] = {"fail_on": "error"}
    text = "".join(streamer("json")([res], options))
    assert text == json_report.render([res], options)
    doc = json.loads(text)
    assert doc == json.loads(json.dumps(json_report.report_dict([res], options)))
    assert len(doc["timeline"]) == sum(len(m.intervals) for m in res.nodes())


def test_the_html_report_draws_a_bounded_number_of_intervals(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    log = tmp_path / "flap.log"
    write_flapping(log, 2000)
    res = check(log)
    monkeypatch.setattr(html, "MAX_DRAWN_INTERVALS", 500)
    monkeypatch.setattr(html, "MIN_DRAWN_PER_NODE", 20)
    assert html.drawn_per_node(10) == 50 and html.drawn_per_node(100) == 20
    ctx = html.report_context([res], {"fail_on": "error"})
    rows = ctx["timelines"][0]["rows"]
    assert [len(r["iv"]) for r in rows] == [50] * 10
    hidden = sum(len(m.intervals) for m in res.nodes()) - 500
    assert ctx["timelines"][0]["left_out"] == (
        f"{hidden} state intervals not drawn (at most 50 per node; the JSON report has all)")
    page = html.render([res], {"fail_on": "error"})
    assert f"{hidden} state intervals not drawn" in page


@pytest.mark.skipif(not hasattr(os, "wait4"), reason="needs os.wait4 (POSIX)")
def test_memory_follows_frames_not_state_changes(tmp_path: Path) -> None:
    """Four times the state changes, written as a JSON report: well under the 5 KB per
    state change the object timeline took (200 k more changes would be 1 GB)."""
    small, large = tmp_path / "small.log", tmp_path / "large.log"
    write_flapping(small, 100_000)
    write_flapping(large, 400_000)
    small_mb = peak_rss_mb(small, "-o", str(tmp_path / "small.json"))
    large_mb = peak_rss_mb(large, "-o", str(tmp_path / "large.json"))
    assert large_mb - small_mb < 100, (small_mb, large_mb)  # < 350 bytes per state change
    doc = json.loads((tmp_path / "large.json").read_text())
    # a state per heartbeat, and UNKNOWN before the first one of nodes 2..10 (node 1's
    # first heartbeat is the log's first frame)
    assert len(doc["timeline"]) == 400_000 + 9
