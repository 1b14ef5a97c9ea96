"""Issue 38, an honest gate round 3, the verdicts: a log without timestamps never gets a
plain PASS (item 2), a limit nmtcheck assumed is said to be one (3), no negative
durations (7), a recorder's gap is no network failure (8), one time base per report
(10), a node that keeps booting is drawn as one (11)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from conftest import SAMPLES, Checker, candump
from conftest import run_cli as run

from nmtcheck.engine import check_input, select_rules
from nmtcheck.reporters import renderer
from nmtcheck.reporters.html import report_context
from nmtcheck.results import InputResult
from nmtcheck.settings.network import load_network
from nmtcheck.settings.profiles import load_profile

HEALTHY = SAMPLES / "healthy.log"
HB_LOSS = SAMPLES / "heartbeat_loss.log"
RESET = SAMPLES / "reset_no_bootup.log"
FORMATS = ("text", "concise", "json", "junit", "markdown", "github", "sarif", "csv", "html")
PROFILE = load_profile("default")
RULES = select_rules(PROFILE, [], [])
ORDER_ONLY = "PASS (order only: timing not checked)"


def _check(path: Path, network: Path | None = None) -> InputResult:
    return check_input(str(path), 0, PROFILE, RULES,
                       load_network(str(network)) if network else None)


def _render(results: list[InputResult], fmt: str) -> str:
    options: dict[str, object] = {"fail_on": "error"}
    return renderer(fmt)(results, options)


def _stripped(path: Path, tmp_path: Path) -> Path:
    """The sample with its timestamps stripped: candump -L without `(stamp) `, an ASC log
    with every stamp equal (SPEC §1: both are logs without usable timestamps)."""
    text = path.read_text(encoding="utf-8", errors="replace")
    if path.suffix == ".asc":
        text = re.sub(r"(?m)^(\s*)\d+\.\d+ ", r"\g<1>0.000000 ", text)
    else:
        text = re.sub(r"(?m)^\(\d+\.\d+\) ", "", text)
    out = tmp_path / f"{path.parent.name}_{path.name}"
    out.write_text(text, encoding="utf-8")
    return out


# 2. a log without timestamps never gets a plain PASS ----------------------------------

def _plain_pass(fmt: str, out: str) -> bool:
    """Whether a report says PASS without saying that timing was not checked."""
    if fmt == "json":
        summary = json.loads(out)["summary"]
        return summary["verdict"] == "pass" and not summary["order_only"]
    return bool(re.search(r"PASS(?! \(order only: timing not checked)", out))


SHIPPED = sorted([*SAMPLES.rglob("*.log"), *SAMPLES.rglob("*.asc")])


@pytest.mark.parametrize("sample", SHIPPED, ids=lambda p: str(p.relative_to(SAMPLES)))
def test_no_shipped_sample_stripped_of_its_timestamps_gets_a_plain_pass(
        sample: Path, tmp_path: Path) -> None:
    """The issue's acceptance: in every format (CSV and SARIF carry no verdict at all)."""
    res = _check(_stripped(sample, tmp_path))
    assert res.stats.order_only
    for fmt in FORMATS:
        out = _render([res], fmt)
        assert not _plain_pass(fmt, out), (fmt, out[-400:])
        if fmt in ("csv", "sarif"):
            assert "PASS" not in out


def test_the_verdict_says_order_only_everywhere(tmp_path: Path) -> None:
    log = _stripped(HB_LOSS, tmp_path)
    text = run("check", str(log), cwd=tmp_path)
    assert text.returncode == 0
    assert text.stdout.splitlines()[-1] == (
        f"{ORDER_ONLY}: 0 errors, 1 warning, 0 info in 1 input (--fail-on error)")
    concise = run("check", str(log), "--format", "concise", cwd=tmp_path).stdout
    assert concise.splitlines()[-1].startswith(f"nmtcheck {ORDER_ONLY}: ")
    github = run("check", str(log), "--format", "github", cwd=tmp_path).stdout
    assert github.splitlines()[-1].startswith(f"nmtcheck {ORDER_ONLY}: ")
    markdown = run("check", str(log), "--format", "markdown", cwd=tmp_path).stdout
    assert markdown.splitlines()[0] == f"## nmtcheck: ⚠️ {ORDER_ONLY}"
    assert "✅" not in markdown and "| no timestamps: order only |" in markdown
    junit = run("check", str(log), "--format", "junit", cwd=tmp_path).stdout
    assert f'<property name="verdict" value="{ORDER_ONLY}" />' in junit
    assert '<property name="order_only" value="true" />' in junit
    doc = json.loads(run("check", str(log), "--format", "json", cwd=tmp_path).stdout)
    assert doc["summary"]["verdict"] == "pass" and doc["summary"]["order_only"] == [0]
    assert doc["inputs"][0]["duration"] is None  # a span of frame numbers is no duration
    page = run("check", str(log), "--format", "html", cwd=tmp_path).stdout
    badge = re.search(r'<div class="verdict ([^"]*)" id="verdict">([^<]*)</div>', page)
    assert badge is not None and badge.groups() == ("pass order-only", ORDER_ONLY)
    # with a timed input beside it: which ones were checked in order only
    both = json.loads(run("check", str(HEALTHY), str(log), "--format", "json",
                          cwd=tmp_path).stdout)["summary"]
    assert both["verdict"] == "pass" and both["order_only"] == [1]
    timed = json.loads(run("check", str(HEALTHY), "--format", "json", cwd=tmp_path).stdout)
    assert timed["summary"]["order_only"] == []
    line = run("check", str(HEALTHY), str(log), cwd=tmp_path).stdout.splitlines()[-1]
    assert line.startswith("PASS (order only: timing not checked in 1 of 2 inputs): ")


def test_untimed_times_are_frames_not_seconds(tmp_path: Path) -> None:
    """Text and concise give `frame N` (the N-th frame); the HTML timeline counts frames;
    no message quotes a time computed from frame numbers (master inference)."""
    log = _stripped(HB_LOSS, tmp_path)
    text = run("check", str(log), cwd=tmp_path).stdout
    assert "     frame 1  line 1       warning I006 no-timestamps" in text
    assert not re.search(r"\d\.\d{6} s", text)
    concise = run("check", str(log), "--format", "concise", cwd=tmp_path).stdout
    assert concise.startswith(f"{log}:1: frame 1 I006 [warning] ")
    res = _check(log)
    context = report_context([res], {"fail_on": "error"})
    assert [tl["frames"] for tl in context["timelines"]] == [True]
    assert context["groups"][0]["when"] == "frame 1"
    timeline = run("timeline", str(log), cwd=tmp_path).stdout
    assert "    frame 13 ..    frame 192  OPERATIONAL      (command)" in timeline
    # Lely's start-up without timestamps: the master is inferred from the order alone
    lely = _check(_stripped(SAMPLES / "lely" / "healthy.log", tmp_path))
    (cm,) = lely.model.channels
    master = cm.master
    assert master is not None
    assert re.fullmatch(r"boot-up at frame \d+, then broadcast reset communication at frame "
                        r"\d+ that node 1 did not obey", master.detail), master.detail
    b003 = _check(_stripped(RESET, tmp_path)).findings
    assert [f.message for f in b003 if f.rule == "B003"] == [
        "after reset node at frame 74 (line 74), node 3 sent boot-up (00h) 19 more times in "
        "a row over 76 frames without a reset command"]


def test_the_html_axis_counts_frames() -> None:
    """The page's script labels the axis in frames where the timeline has no time."""
    from importlib import resources

    script = (resources.files("nmtcheck.reporters") / "templates" / "report.js").read_text()
    assert 'spec.frames ? "frame" : "time (s)"' in script


# 3. a limit nmtcheck assumed is shown as one ------------------------------------------

def test_an_assumed_limit_is_marked_and_said_once_per_node(tmp_path: Path) -> None:
    log = SAMPLES / "lely" / "self_1017.log"
    doc = json.loads(run("check", str(log), "--format", "json", cwd=tmp_path).stdout)
    h001 = [f for f in doc["findings"] if f["rule"] == "H001"]
    assert [(f["node"], f["basis"]) for f in h001] == [(2, "assumed")]  # was 24 x configured
    assert h001[0]["message"].startswith(
        "node 2's heartbeat interval exceeds the assumed timeout 24 times in a row (0.250 s")
    assert "timeout 0.150 s assumed: 1.5 x producer time 0.100 s, no consumer time known" in (
        h001[0]["message"])
    text = run("check", str(log), cwd=tmp_path).stdout
    assert text.count(" H001 ") == 1
    assert ("[limit assumed: the heartbeat consumer time (1016h) of the node's consumer gives "
            "the real one: the consumer's device file (--dcf NODE=FILE, e.g. the master's DCF) "
            "or consumer_timeout_ms in --network]") in text


def test_a_configured_consumer_time_is_configured_and_each_gap_counts(checker: Checker
                                                                      ) -> None:
    frames = [(0.0, "702#00")] + [(0.1 * k, "702#05") for k in range(1, 6)]
    assumed = checker.run(candump(frames), select="H001",
                          network="[nodes.2]\nheartbeat_ms = 50\n")
    assert [f.basis for f in assumed.findings] == ["assumed"]
    consumer = checker.run(candump(frames), select="H001",
                           network="[nodes.2]\nheartbeat_ms = 50\nconsumer_timeout_ms = 75\n")
    assert [f.basis for f in consumer.findings] == ["configured"] * 4  # real timeouts each


# 7. no negative durations ---------------------------------------------------------------

def test_joined_recordings_give_each_capture_its_span(tmp_path: Path) -> None:
    log = tmp_path / "joined.log"
    log.write_text(HB_LOSS.read_text() + HEALTHY.read_text())
    text = run("check", str(log), cwd=tmp_path).stdout
    assert ("543 frames over 8.856 s in 2 captures: 192 frames over 3.935 s from line 1, "
            "351 frames over 4.921 s from line 193 on 2 channel(s)") in text.splitlines()[0]
    assert " -0." not in text.splitlines()[0]
    markdown = run("check", str(log), "--format", "markdown", cwd=tmp_path).stdout
    assert "| 543 | 8.856 s (2 captures: 3.935 s, 4.921 s) |" in markdown
    (inp,) = json.loads(run("check", str(log), "--format", "json", cwd=tmp_path).stdout)[
        "inputs"]
    assert inp["end"] >= inp["start"] and inp["duration"] == pytest.approx(8.855905)
    assert [(c["frames"], c["line"]) for c in inp["captures"]] == [(192, 1), (351, 193)]
    assert all(c["end"] >= c["start"] for c in inp["captures"])
    plain = json.loads(run("check", str(HEALTHY), "--format", "json", cwd=tmp_path).stdout)
    assert plain["inputs"][0]["captures"] == []


# 8. a recorder's gap is no network failure ---------------------------------------------

def _shifted(path: Path, after: int, seconds: float) -> str:
    """The log with every frame from line `after` on `seconds` later."""
    out = []
    for k, line in enumerate(path.read_text().splitlines()):
        stamp, rest = line[1:].split(")", 1)
        out.append(f"({float(stamp) + (seconds if k >= after else 0.0):.6f}){rest}")
    return "\n".join(out) + "\n"


def test_a_forward_clock_step_is_one_recording_gap(tmp_path: Path) -> None:
    log = tmp_path / "step.log"
    log.write_text(_shifted(HEALTHY, 175, 100.0))
    res = run("check", str(log), "--format", "json", cwd=tmp_path)
    assert res.returncode == 0, res.stdout  # was 3 x H001, FAIL
    (f,) = json.loads(res.stdout)["findings"]
    assert (f["rule"], f["name"], f["severity"], f["channel"], f["node"], f["line"]) == (
        "I007", "recording-gap", "warning", "can0", None, 176)
    assert f["message"].startswith("no frame recorded on can0 for 100.000 s, from 2.634985 s "
                                   "to 102.635121 s: longer than every heartbeat or guarding "
                                   "limit running there (at most 0.150 s)")
    assert "nodes 2, 3, 4 are not judged for it" in f["message"]
    junit = run("check", str(log), "--format", "junit", cwd=tmp_path).stdout
    assert re.search(r'<testcase classname="can0.network" name="I007 recording-gap"[^>]*>\s*'
                     r"<system-out>warning I007", junit)


def test_two_recordings_joined_half_a_second_apart(tmp_path: Path) -> None:
    first = HEALTHY.read_text().splitlines()
    last = float(first[-1][1:].split(")")[0])
    start = float(first[0][1:].split(")")[0])
    second = [f"({float(x[1:].split(')')[0]) - start + last + 0.5:.6f}){x.split(')', 1)[1]}"
              for x in first]
    log = tmp_path / "two.log"
    log.write_text("\n".join(first + second) + "\n")
    doc = json.loads(run("check", str(log), "--format", "json", cwd=tmp_path).stdout)
    rules = [(f["rule"], f["node"]) for f in doc["findings"]]
    assert ("I007", None) in rules and doc["summary"]["error"] == 0, rules  # parts: 0 each
    assert not [r for r, _n in rules if r in ("H001", "G002")]


def test_a_single_node_falling_silent_is_still_h001() -> None:
    res = _check(HB_LOSS)
    assert [(f.rule, f.node) for f in res.findings] == [("H001", 3)]
    assert not res.model.channels[0].recording_gaps


def test_a_node_silent_after_the_gap_is_judged_from_its_end(checker: Checker) -> None:
    frames = [(0.0, "702#00"), (0.0, "703#00")]
    frames += [(0.1 * k, f"70{n}#05") for k in range(1, 11) for n in (2, 3)]
    frames += [(10.0 + 0.1 * k, "702#05") for k in range(0, 11)]  # node 3 never again
    got = checker.findings(candump(frames), select="H001,I007")
    assert got == [("I007", None, 10.0), ("H001", 3, 10.15)], got  # 0.15 s after its end


def test_guarding_across_a_recording_gap(checker: Checker) -> None:
    def polled(t0: float, t1: float, answers: bool) -> list[tuple[float, str]]:
        out = []
        k = 0
        t = t0
        while t < t1 - 1e-9:
            out.append((t, "705#R"))
            if answers:
                out.append((t + 0.005, f"705#{0x85 if k % 2 else 0x05:02X}"))
            k += 1
            t = round(t + 0.1, 6)
        return out

    # node 5 guarded, node 2 a heartbeat producer beside it: both fall silent at 2.0 s
    hb2 = [(0.0, "702#00")] + [(0.1 * k + 0.05, "702#05") for k in range(20)]
    hb2 += [(5.0 + 0.1 * k + 0.05, "702#05") for k in range(10)]
    before = [(0.0, "705#00")] + polled(0.1, 2.0, True) + [(2.0, "705#R")]  # then nothing
    after = polled(5.0, 6.0, True)
    res = checker.run(candump(sorted(hb2 + before + after)), select="G002,I007")
    assert [f.rule for f in res.findings] == ["I007"]
    silent = checker.run(candump(sorted(hb2 + before + polled(5.0, 6.0, False))),
                         select="G002,I007")
    g002 = [f for f in silent.findings if f.rule == "G002"]
    assert len(g002) == 1 and g002[0].time - 1000.0 == pytest.approx(5.1)


def test_a_request_superseded_before_a_recording_gap_timed_out_then(checker: Checker
                                                                      ) -> None:
    """Node 3's request at 1.0 s goes unanswered and the master asks again at 1.3 s: that
    G002 is over before the channel falls silent (1.3 s to 3.0 s), so the gap takes
    nothing from it; the request at 1.3 s, whose answer may lie in the gap, is no finding
    and no second request of the run. (Found by the live monitor's corpus: a live G002
    before a gap that the offline check had dropped.)"""
    frames = [(0.1 * k, "702#05") for k in range(14)]
    frames += [(3.0 + 0.1 * k, "702#05") for k in range(5)]
    for k, t in enumerate((0.1, 0.4, 0.7)):
        frames += [(t, "703#R"), (t + 0.002, f"703#{0x85 if k % 2 else 0x05:02X}")]
    frames += [(1.0, "703#R"), (1.3, "703#R"), (3.05, "703#R"), (3.052, "703#05")]
    res = checker.run(candump(sorted(frames)), select="G002,I007")
    start = res.stats.start or 0.0
    assert [(f.rule, f.node, round(f.time - start, 3)) for f in res.findings] == [
        ("G002", 3, 1.3), ("I007", None, 3.0)]
    assert res.findings[0].message == (
        "no guarding response from node 3 to the remote request at 1.000000 s")
    assert "node 2 is not judged for it" in res.findings[1].message


def test_the_bootup_wait_does_not_count_a_recording_gap(checker: Checker) -> None:
    frames = [(0.0, "702#00"), (0.0, "703#00"), (0.0, "704#00")]
    frames += [(0.1 * k, f"70{n}#05") for k in range(1, 11) for n in (2, 3, 4)]
    frames += [(1.05, "000#8103")]  # reset node 3, then the recorder is off for 6 s
    frames += [(7.05, "702#05"), (7.05, "704#05"), (7.06, "703#00")]
    frames += [(7.05 + 0.1 * k, f"70{n}#7F") for k in range(1, 10) for n in (2, 3, 4)]
    got = [r for r, _n, _t in checker.findings(candump(frames), select="B001,H001,I007")]
    assert got == ["I007"], got


# 10. one time base per report -----------------------------------------------------------

def test_the_boot_table_and_its_finding_agree(tmp_path: Path) -> None:
    folder = SAMPLES / "lely" / "boot" / "sequence"
    res = _check(folder / "sequence.log", folder / "network.toml")
    (p004,) = [f for f in res.findings if f.rule == "P004"]
    start = res.stats.start or 0.0
    when = f"{p004.time - start:.6f} s (line {p004.line})"
    assert when == "0.300417 s (line 44)"
    text = _render([res], "text")
    row = next(line for line in text.splitlines() if "vcan0 node 3  FAILED" in line)
    assert f"FAILED      K  {when}  no heartbeat of node 3" in row
    context = report_context([res], {"fail_on": "error"})
    (boot,) = context["boot"]
    node3 = next(r for r in boot["rows"] if r["node"] == 3)
    assert (node3["time"], node3["line"]) == (pytest.approx(0.300417), 44)


def test_boot_messages_count_seconds_from_the_start(checker: Checker) -> None:
    log = """(1795694867.000000) can0 701#00
(1795694867.010000) can0 000#8200
(1795694867.020000) can0 702#00
(1795694867.021000) can0 602#4000100000000000
(1795694867.022000) can0 582#4300100092010200
(1795694867.023000) can0 602#4018100100000000
(1795694867.024000) can0 582#4318100100030000
(1795694868.000000) can0 080#
(1795694869.000000) can0 080#
(1795694870.000000) can0 080#
"""
    net = ("master = 1\n[boot]\nmanager = true\nboot_time_ms = 2000\n[nodes.2]\n"
           "mandatory = true\n")
    res = checker.run(log, network=net)
    (p006,) = [f for f in res.findings if f.rule == "P006"]
    assert "of the manager's boot-up at 0.000000 s (line 1)" in p006.message
    for f in res.findings:
        assert not re.search(r"\b1795694\d{3}\.\d", f.message), f.message


def test_no_finding_message_quotes_an_epoch_time() -> None:
    """Over the shipped samples (with their network files): every time in a message is
    seconds from the start, as the reports show the findings' times."""
    for sample in sorted(SAMPLES.rglob("*.log")):
        net = sample.parent / "network.toml"
        for network in ([None, net] if net.exists() else [None]):
            res = _check(sample, network)
            for f in res.findings:
                assert not re.search(r"\b1[6-9]\d{8}\.\d", f.message), (sample, f.message)


# 11. a node that keeps booting ----------------------------------------------------------

def test_a_node_that_keeps_booting_is_drawn_as_one(tmp_path: Path) -> None:
    timeline = run("timeline", str(RESET), cwd=tmp_path).stdout
    assert ("      1.510556 ..     3.435174  PRE-OPERATIONAL  (bootup)\n"
            "                  rebooted 19 times while PRE-OPERATIONAL: boot-up (00h) at "
            "1.610555, 1.710552, 1.810563 … 3.410528 s\n") in timeline
    text = run("check", str(RESET), cwd=tmp_path).stdout
    assert re.search(r"can0/3 +PRE-OPERATIONAL \(rebooting\) +heartbeat +21 ", text)
    assert ("  can0/3 rebooted 19 times while PRE-OPERATIONAL: boot-up (00h) at 1.610555, "
            "1.710552, 1.810563 … 3.410528 s") in text
    assert ("B003 bootup-repeated: after reset node at 1.460 s (line 74), node 3 sent boot-up "
            "(00h) 19 more times in a row over 1.900 s without a reset command") in text
    res = _check(RESET)
    context = report_context([res], {"fail_on": "error"})
    (tl,) = context["timelines"]
    row = next(r for r in tl["rows"] if r["node"] == 3)
    assert row["iv"][-1][2:] == [2, 1, 19]  # PRE-OPERATIONAL, boot-up, 19 boot-ups inside
    assert len(row["boots"]) == 19 and row["boots"][0] == pytest.approx(1.610555)
    assert all(len(iv) == 4 for r in tl["rows"] if r["node"] != 3 for iv in r["iv"])
    assert context["rebooting"]
    assert [(n["node"], n["reboots"]) for n in context["nodes"]] == [(2, 0), (3, 19)]
    assert "rebooted 19 times</span>" in _render([res], "html")


def test_a_reset_answered_twice_is_no_reboot(tmp_path: Path) -> None:
    """Lely's master resets with 000#8100 and 000#8200 back to back: two boot-ups, each
    answers one reset (samples/lely/mandatory)."""
    res = _check(SAMPLES / "lely" / "mandatory" / "mandatory_lost.log")
    text = _render([res], "text")
    assert "rebooted" not in text and "(rebooting)" not in text
