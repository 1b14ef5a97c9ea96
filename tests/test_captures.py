"""Several captures in one input (nmtcheck/readers/captures.py): `cat run1.asc run2.asc`, candump
logs joined out of order. Where time starts again, each recording is checked as the trace
it is: the findings of the joined file are those of its parts, no more and no fewer."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from conftest import SAMPLES, Checker, candump, run_cli

from nmtcheck.readers import InputStats
from nmtcheck.readers.captures import RESTART_S, Captures
from nmtcheck.readers.frames import FrameBatch

# Pairs of recordings from real stacks, each joined in the order that makes time go back
# (the second was recorded earlier, or both count from 0 s). Healthy with faulty, faulty
# with healthy: a joined file found faults of one in the other (H001 "for the rest of the
# trace", S001 against the other's states), and a second boot-up was a spontaneous reboot.
PAIRS = [
    ("heartbeat_loss.asc", "healthy.asc"),
    ("healthy.asc", "heartbeat_loss.asc"),
    ("pdo_preop.asc", "ignored_command.asc"),
    ("reset_no_bootup.asc", "healthy.asc"),
    ("lely/unplugged_heartbeat.log", "lely/healthy.log"),
    ("lely/healthy.log", "lely/unplugged_heartbeat.log"),
    ("canopen_master/unplugged.log", "canopen_master/healthy.log"),
    ("canopen_master/reboot.log", "canopen_master/healthy.log"),
    ("canopennode/healthy.log", "canopennode/healthy.log"),
    ("canopennode/self_start.log", "canopennode/late_master.log"),
]


def _findings(checker: Checker, text: str, suffix: str,
              **kw: object) -> Counter[tuple[str, int | None, str]]:
    res = checker.run(text, suffix=suffix, **kw)  # type: ignore[arg-type]
    return Counter((f.rule, f.node, f.message) for f in res.findings if f.rule != "I005")


@pytest.mark.parametrize(("first", "second"), PAIRS)
def test_joined_recordings_give_the_findings_of_their_parts(
        checker: Checker, first: str, second: str) -> None:
    a, b = (SAMPLES / first).read_text(), (SAMPLES / second).read_text()
    suffix = Path(first).suffix
    res = checker.run(a + b, suffix=suffix)
    assert len(res.stats.restarts) == 1, res.stats.restarts
    joined = Counter((f.rule, f.node, f.message) for f in res.findings if f.rule != "I005")
    assert joined == _findings(checker, a, suffix) + _findings(checker, b, suffix)
    # the second recording's findings point into it, on its own channel
    first_lines = len(a.splitlines())
    (idx, line, _t) = res.stats.restarts[0]
    assert line == next(i for i, text in enumerate(b.splitlines(), first_lines + 1)
                        if _is_frame_line(text, suffix))
    for f in res.findings:
        if f.rule == "I005":
            assert "time starts again at line" in f.message and "2 captures" in f.message
        elif f.line and f.line > first_lines:
            assert f.channel is not None and f.channel.endswith("(capture 2)"), f
            assert f.frame_index is not None and f.frame_index >= idx
        else:
            assert f.channel is None or "capture" not in f.channel, f


def _is_frame_line(text: str, suffix: str) -> bool:
    """A frame record of the samples' candump -L or ASC text."""
    if suffix == ".log":
        return text.startswith("(")
    parts = text.split()
    return len(parts) > 3 and parts[0].replace(".", "").isdigit() and parts[3] in ("Rx", "Tx")


def test_the_files_configuration_applies_to_every_capture(checker: Checker) -> None:
    """The network file names channel `can0`; its second capture `can0 (capture 2)` is the
    same network: its consumer times, master and expected nodes hold there too."""
    folder = SAMPLES / "canopennode"
    healthy = (folder / "healthy.log").read_text()
    network = (folder / "network.toml").read_text()
    res = checker.run(healthy + healthy, network=network)
    assert [f.rule for f in res.findings] == ["I005"]
    masters = {cm.name: cm.master for cm in res.model.channels}
    assert set(masters) == {"can0", "can0 (capture 2)"}
    assert masters["can0"] == masters["can0 (capture 2)"] and masters["can0"] is not None
    assert masters["can0"].source == "network"
    # a node the file expects and neither recording has: missing in each of them
    extra = network + "\n[nodes.9]\nheartbeat_ms = 100\n"
    res = checker.run(healthy + healthy, network=extra, select="N001")
    got = [(f.channel, f.node, f.line) for f in res.findings]
    n = len(healthy.splitlines())
    assert got == [("can0", 9, 1), ("can0 (capture 2)", 9, n + 1)], got


def test_a_small_step_back_is_no_new_capture(checker: Checker) -> None:
    """A merged log whose frames go back by milliseconds is one recording: I005 warns,
    the channels keep their names."""
    beats = [(0.1 * i, "701#05") for i in range(30)]
    beats[10] = (0.85, "701#05")  # 50 ms before the frame ahead of it
    res = checker.run(candump(beats), select="I005")
    assert res.stats.backwards_timestamps == 1 and res.stats.restarts == []
    assert [cm.name for cm in res.model.channels] == ["can0"]
    assert "may be unreliable" in res.findings[0].message


def test_three_captures_and_a_channel_only_the_second_has(checker: Checker) -> None:
    """Three recordings from 0 s each; can1 appears first in the second and keeps its
    name there, and is `can1 (capture 3)` in the third."""
    boot = [(0.0, "701#00"), *[(0.1 * i, "701#05") for i in range(1, 30)]]
    both = "".join(x + y for x, y in zip(candump(boot).splitlines(True),
                                         candump(boot, "can1").splitlines(True), strict=True))
    text = candump(boot) + both + both
    res = checker.run(text)
    assert len(res.stats.restarts) == 2
    assert sorted(cm.name for cm in res.model.channels) == [
        "can0", "can0 (capture 2)", "can0 (capture 3)", "can1", "can1 (capture 3)"]
    assert [f.rule for f in res.findings] == ["I005"], res.findings
    spans = {cm.name: (cm.start, cm.end) for cm in res.model.channels}
    assert spans["can1"] == spans["can0 (capture 2)"] == (1000.0, 1002.9)


def test_channel_option_takes_every_capture_of_the_channel(tmp_path: Path) -> None:
    log = tmp_path / "joined.log"
    folder = SAMPLES / "canopennode"
    log.write_text((folder / "healthy.log").read_text() * 2)
    res = run_cli("check", str(log), "--channel", "can0", "--format", "json",
                  "--fail-on", "never", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    report = json.loads(res.stdout)
    names = {n["channel"] for n in report["nodes"]}
    assert names == {"can0", "can0 (capture 2)"}, names
    n = len((folder / "healthy.log").read_text().splitlines())
    assert report["inputs"][0]["restarts"] == [
        {"frame_index": n, "line": n + 1, "time": report["inputs"][0]["restarts"][0]["time"]}]


def _batch(ts: list[float], chan: list[int], first: int = 0) -> FrameBatch:
    n = len(ts)
    return FrameBatch(ts=np.asarray(ts, np.float64), chan=np.asarray(chan, np.int32),
                      can_id=np.full(n, 0x701, np.uint32), ext=np.zeros(n, bool),
                      rtr=np.zeros(n, bool), err=np.zeros(n, bool), fd=np.zeros(n, bool),
                      dlc=np.ones(n, np.int16), data=np.zeros((n, 8), np.uint8),
                      index=np.arange(first, first + n, dtype=np.int64),
                      line=np.arange(first + 1, first + n + 1, dtype=np.int64))


def test_restarts_are_found_across_and_within_batches() -> None:
    """A restart at a batch's first row, a restart at a batch's last row (the next
    batch's frames confirm it), two in one batch, jitter that goes back by less than
    RESTART_S and one frame written seconds late: each later capture's frames get its
    channel codes, and only those."""
    stats = InputStats(path="x")
    a, b = stats.channel_code("can0"), stats.channel_code("can1")
    captures = Captures(stats)
    batches = [
        _batch([10.0, 11.0, 12.0], [a, a, b]),
        # 0.5 after 1.0: jitter; 5.0 after 6.0 ... 0.0: written late, time goes on after it
        _batch([0.0, 1.0, 0.5, 2.0, 6.0, 0.0, 6.1, 6.2, 0.1, 0.2, 0.3, 0.4, 1.5],
               [a, b, a, a, a, a, a, a, a, b, a, a, b], first=3),
        _batch([1.6, 1.7, 1.8, 1.9], [a, a, a, a], first=16),
    ]
    out = list(captures.split(iter(batches)))
    names = [[stats.channels[c] for c in x.chan.tolist()] for x in out]
    two, three, four = (f"{{}} (capture {k})" for k in (2, 3, 4))
    assert names == [
        ["can0", "can0", "can1"],
        [two.format("can0"), two.format("can1"), *[two.format("can0")] * 6,
         three.format("can0"), three.format("can1"), three.format("can0"),
         three.format("can0"), three.format("can1")],
        [three.format("can0")] * 4]
    assert [(c.number, c.first_index, c.start, c.end) for c in captures.list] == [
        (1, 0, 10.0, 12.0), (2, 3, 0.0, 6.2), (3, 11, 0.1, 1.9)]
    assert 0.5 < RESTART_S < 6.0  # the jitter stays, the late frame would be a restart
    assert four.format("can0") not in stats.channels
    assert batches[1].chan.tolist()[:2] == [a, b]  # the reader's batch is unchanged


def test_a_restart_at_a_batch_end_waits_for_the_next_batch() -> None:
    """The last frame of a batch goes back; the next batch's first frames stay back: a
    capture from that frame. At the input's end, too few frames confirm nothing."""
    stats = InputStats(path="x")
    a = stats.channel_code("can0")
    captures = Captures(stats)
    batches = [_batch([10.0, 11.0, 12.0, 0.0], [a] * 4),
               _batch([0.1, 0.2, 0.3, 0.4, 0.5, 13.0, 0.0], [a] * 7, first=4)]
    out = list(captures.split(iter(batches)))
    assert [c.first_index for c in captures.list] == [0, 3]
    assert [stats.channels[c] for c in out[0].chan.tolist()] == ["can0"] * 3 + [
        "can0 (capture 2)"]
    assert set(out[1].chan.tolist()) == {stats.channels.index("can0 (capture 2)")}


def test_a_single_capture_passes_its_batches_unchanged() -> None:
    stats = InputStats(path="x")
    a = stats.channel_code("can0")
    batch = _batch([0.0, 0.5, 0.4, 3.0], [a] * 4)
    (out,) = Captures(stats).split(iter([batch]))
    assert out is batch and stats.channels == ["can0"]


def test_each_capture_has_a_timeline_of_its_own_span(checker: Checker) -> None:
    """The HTML timelines: the second recording (10 s earlier than the first, candump
    epoch stamps) counts from its own first frame and spans its own length, with its
    finding's marker on it; the first keeps its whole length. Drawn from the input's
    start and length, the second's bars and markers lay before the axis."""
    from nmtcheck.reporters import html

    first = [(0.1 * i, "701#05") for i in range(50)]  # 4.9 s
    second = [(0.1 * i, "702#05") for i in range(20)] + [(3.0, "702#05")]  # a 1.1 s gap
    text = candump([(10.0 + t, f) for t, f in first]) + candump(second)
    res = checker.run(text, select="H001")
    assert [(f.rule, f.channel) for f in res.findings] == [("H001", "can0 (capture 2)")]
    tl = {t["channel"]: t for t in html.report_context([res], {"fail_on": "error"})["timelines"]}
    assert tl["can0"]["duration"] == pytest.approx(4.9) and tl["can0"]["shift"] == 0.0
    two = tl["can0 (capture 2)"]
    assert two["duration"] == pytest.approx(3.0) and two["shift"] == pytest.approx(-10.0)
    (row,) = two["rows"]
    assert row["iv"] and all(0.0 <= iv[0] <= iv[1] <= 3.0 + 1e-6 for iv in row["iv"])
    ((t, _g, _k),) = row["marks"]
    assert 1.9 < t < 3.0


def test_a_clock_step_within_a_recording_is_spliced(checker: Checker) -> None:
    """NTP steps the logger's clock back 1.5 s in the middle of a 12 s recording (the
    CANopenNode master unplugged): time goes back, but not to the recording's start, and
    stays back. Split there, the second part lost the master the first part showed and
    the 1017h values written in it, and the master's heartbeat timeout was no longer
    found (a review: FAIL became PASS); read as one trace with time going back, the
    timeline went wrong (S001 and more). The frames after the step are timed as if it
    had not been: the findings are the recording's, I005 names the step."""
    folder = SAMPLES / "canopennode"
    network = (folder / "network.toml").read_text()
    lines = (folder / "master_unplugged.log").read_text().splitlines(keepends=True)
    stepped = lines[:234] + [_shifted(line, -1.5) for line in lines[234:]]
    res = checker.run("".join(stepped), network=network)
    whole = checker.run("".join(lines), network=network)
    assert res.stats.restarts == [] and [cm.name for cm in res.model.channels] == ["can0"]
    ((idx, line, step),) = res.stats.clock_steps
    assert (idx, line) == (234, 235) and 1.4 < step < 1.6
    assert sorted((f.rule, f.node, f.line) for f in res.findings if f.rule != "I005") == sorted(
        (f.rule, f.node, f.line) for f in whole.findings)
    (i005,) = [f for f in res.findings if f.rule == "I005"]
    assert "clock stepped back 1.5" in i005.message and "line 235" in i005.message


def test_a_log_pasted_in_overlapping_pieces_is_two_captures(checker: Checker) -> None:
    """Two pieces of one recording pasted one after the other, the second beginning
    seconds before the first ends: its frames are ones the input already had (time and
    CAN-ID to the microsecond), so it is a capture of its own, not a clock step."""
    lines = (SAMPLES / "canopennode" / "healthy.log").read_text().splitlines(keepends=True)
    n = len(lines)
    res = checker.run("".join(lines[:2 * n // 3] + lines[n // 2:]))
    assert len(res.stats.restarts) == 1 and res.stats.clock_steps == []
    assert [f.rule for f in res.findings] == ["I005"]


def _shifted(line: str, by: float) -> str:
    stamp, rest = line.split(")", 1)
    return f"({float(stamp[1:]) + by:.6f}){rest}"


def test_two_loggers_clocks_merged_are_no_captures(checker: Checker) -> None:
    """can1's logger runs 2 s behind can0's, the two merged in bursts of 8 frames: time
    goes back 2 s at every burst of can1, but no channel's own time goes back. A review
    found 69 captures (12,500 in 200,000 frames, 35 times slower) and 251 errors."""
    a = [(0.1 * i, "701#05") for i in range(100)]
    b = [(0.1 * i - 2.0, "702#05") for i in range(100)]
    text = "".join(candump(a[k:k + 8]) + candump(b[k:k + 8], "can1")
                   for k in range(0, 100, 8))
    res = checker.run(text, select="I005,H001")
    assert res.stats.restarts == [] and sorted(cm.name for cm in res.model.channels) == [
        "can0", "can1"]
    assert res.stats.backwards_timestamps == 13


def test_the_channel_option_on_a_later_capture_keeps_the_files_nodes(
        checker: Checker, tmp_path: Path) -> None:
    """`--channel "can0 (capture 2)"` with a network file that puts its nodes on `can0`:
    they did transmit there (a review found N001 for every node)."""
    folder = SAMPLES / "canopennode"
    log = tmp_path / "joined.log"
    log.write_text((folder / "healthy.log").read_text() * 2)
    net = tmp_path / "net.toml"
    net.write_text((folder / "network.toml").read_text().replace(
        "[nodes.2]", '[nodes.2]\nchannel = "can0"'))
    res = run_cli("check", "--isolated", str(log), "--network", str(net), "--channel",
                  "can0 (capture 2)", "--format", "json", "--fail-on", "never", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    report = json.loads(res.stdout)
    assert [f["rule"] for f in report["findings"]] == ["I005"], report["findings"]
    assert {n["channel"] for n in report["nodes"]} == {"can0 (capture 2)"}


def test_captures_are_capped(checker: Checker, monkeypatch: pytest.MonkeyPatch) -> None:
    """Past MAX_CAPTURES, time going back is I005's alone."""
    from nmtcheck.readers import captures

    monkeypatch.setattr(captures, "MAX_CAPTURES", 2)
    run = [(0.1 * i, "701#05") for i in range(30)]
    res = checker.run(candump(run) * 3)
    assert len(res.stats.restarts) == 1 and len(res.model.channels) == 2


def test_restarts_past_the_cap_are_one_finding(checker: Checker,
                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """A logger that resets its clock every second (issue 39): past MAX_CAPTURES each
    reset is a step back in the last capture, counted by I005's one finding, not an
    H002 of every node at every reset."""
    from nmtcheck.readers import captures

    monkeypatch.setattr(captures, "MAX_CAPTURES", 2)
    block = sorted((0.01 * i + 0.001 * n, f"70{n}#05") for i in range(100) for n in (1, 2))
    res = checker.run(candump(block) * 12)
    assert len(res.stats.restarts) == 1
    assert [f.rule for f in res.findings] == ["I005"], res.findings
    assert "timestamps go backwards 11 times" in res.findings[0].message


def test_a_restart_costs_the_frames_up_to_it_not_the_rest_of_the_batch(
        checker: Checker, monkeypatch: pytest.MonkeyPatch) -> None:
    """A logger that resets its clock every second (issue 39): each search for the next
    step back looked through the rest of the batch, so 1,500 resets took 45 s. Looked for
    among the next 2 x WINDOW frames first, the frames searched stay a few times the
    input's, however many resets it has; the captures are the same."""
    from nmtcheck.readers import captures

    block = sorted((0.01 * i + 0.001 * n, f"70{n}#05") for i in range(40) for n in (1, 2))
    text = candump(block) * 150
    whole = checker.run(text)
    monkeypatch.setattr(captures, "WINDOW", 64, raising=False)
    searched: list[int] = []
    real_back = captures.Captures._back

    def spy(self: Captures, ts: np.ndarray, *args: object, **kw: object) -> object:
        searched.append(len(ts))
        return real_back(self, ts, *args, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(captures.Captures, "_back", spy)
    res = checker.run(text)
    assert len(res.stats.restarts) == len(whole.stats.restarts) == 149
    assert [f.message for f in res.findings] == [f.message for f in whole.findings]
    assert sum(searched) < 4 * len(block) * 150, sum(searched)


@pytest.mark.parametrize(("first", "second"), PAIRS[:4] + PAIRS[6:8])
def test_small_windows_find_the_captures_the_whole_batch_finds(
        checker: Checker, monkeypatch: pytest.MonkeyPatch, first: str, second: str) -> None:
    from nmtcheck.readers import captures

    a, b = (SAMPLES / first).read_text(), (SAMPLES / second).read_text()
    suffix = Path(first).suffix
    whole = checker.run(a + b, suffix=suffix)
    monkeypatch.setattr(captures, "WINDOW", 4)
    res = checker.run(a + b, suffix=suffix)
    assert (res.stats.restarts, res.stats.clock_steps) == (
        whole.stats.restarts, whole.stats.clock_steps)
    assert [f.message for f in res.findings] == [f.message for f in whole.findings]


def test_a_few_lines_pasted_twice_are_a_capture_of_their_own(checker: Checker) -> None:
    """Two screens of a terminal pasted with 20 lines in both: time goes back less than a
    second, to frames the input already had (time and CAN-ID to the microsecond). Read
    as one trace, the repeated answers gave G001 ("toggle bit repeats"), a repeated
    boot-up B003 and a repeated guarding answer C003: a review found 15 of 45 healthy
    and faulty real-stack logs with errors they do not have. The second piece is a
    capture of its own; the recording's own errors stay."""
    for log in ("healthy.log", "power_cycle.log"):
        lines = (SAMPLES / "canopennode" / log).read_text().splitlines(keepends=True)
        k = 280
        res = checker.run("".join(lines[:k] + lines[k - 20:]))
        whole = checker.run("".join(lines))
        assert len(res.stats.restarts) == 1, log
        assert res.stats.restarts[0][1] == k + 1
        errors = sorted((f.rule, f.node) for f in res.findings if f.severity == "error")
        assert errors == sorted((f.rule, f.node) for f in whole.findings
                                if f.severity == "error"), (log, res.findings)


def test_a_later_capture_keeps_the_master_its_channel_showed(checker: Checker) -> None:
    """Lely's manager resets every node at its start-up, which shows it is the master;
    a piece of the log pasted again from the middle starts after that. Its capture takes
    the master the channel's first capture showed: the master's own heartbeats after its
    `reset node` broadcast are no B001 (a review found one)."""
    lines = (SAMPLES / "lely" / "reset_all" / "reset_all.log").read_text().splitlines(
        keepends=True)
    res = checker.run("".join(lines[:300] + lines[249:]))
    assert len(res.stats.restarts) == 1
    masters = {cm.name: cm.master for cm in res.model.channels}
    assert masters["vcan0"] is not None and masters["vcan0 (capture 2)"] is not None
    assert masters["vcan0 (capture 2)"].node == masters["vcan0"].node == 1
    assert "as in vcan0" in masters["vcan0 (capture 2)"].detail
    assert [f.rule for f in res.findings if f.severity == "error"] == []


@pytest.mark.parametrize("note", ["[... snip ...]", "...", "--- cut ---", "  [...]"])
def test_a_note_that_frames_were_left_out_begins_a_capture(checker: Checker,
                                                           note: str) -> None:
    """A log pasted with a piece left out (`[... snip ...]` in place of two seconds): the
    timeouts across the left-out frames were H001 and G002 errors on a healthy network
    (a review: 44 of 45 real-stack logs FAILed so). The piece after the note is a
    capture of its own; the input summary names the note's line. The note is an edit
    made on purpose, no finding: time does not go backwards there, so no I005 (issue
    38). A note above the first frame leaves nothing out."""
    lines = (SAMPLES / "lely" / "healthy.log").read_text().splitlines(keepends=True)
    text = "".join([note + "\n", *lines[:200], note + "\n", *lines[260:]])
    res = checker.run(text)
    assert [f.rule for f in res.findings] == [], res.findings
    assert res.stats.left_out_restarts == [(202, 203)]
    assert len(res.stats.restarts) == 1 and res.stats.restarts[0][1] == 203
    assert "frames were left out at line 202" in (res.stats.left_out_text() or "")
    assert sorted(cm.name for cm in res.model.channels) == ["vcan0", "vcan0 (capture 2)"]


def test_a_note_between_two_whole_recordings_and_time_going_back(checker: Checker) -> None:
    """Both at once: `...` between two pastes of one log. One capture begins after the
    note; I005 names the note, and the time that went back there needs nothing else."""
    text = (SAMPLES / "canopennode" / "healthy.log").read_text()
    res = checker.run(text + "...\n" + text)
    assert len(res.stats.restarts) == 1 and res.stats.left_out_restarts
    (i005,) = [f for f in res.findings if f.rule == "I005"]
    assert "left out" in i005.message and "may be unreliable" not in i005.message
    assert [f.rule for f in res.findings] == ["I005"]


def test_a_clock_step_back_under_a_second_is_spliced_too(checker: Checker) -> None:
    """A step of 0.5 s in the python-canopen master's broadcast recording: the TPDOs
    before it in the file were judged by the states of heartbeats after it whose stamps
    were earlier (a review found S001 on 8 TPDOs of operational nodes)."""
    folder = SAMPLES / "canopen_master"
    network = (folder / "network.toml").read_text()
    lines = (folder / "broadcast.log").read_text().splitlines(keepends=True)
    res = checker.run("".join(lines[:227] + [_shifted(line, -0.5) for line in lines[227:]]),
                      network=network)
    whole = checker.run("".join(lines), network=network)
    assert len(res.stats.clock_steps) == 1 and res.stats.restarts == []
    assert [(f.rule, f.node) for f in res.findings if f.rule != "I005"] == [
        (f.rule, f.node) for f in whole.findings]
