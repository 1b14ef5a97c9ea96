"""What several reporters need alike: the verdict, the checked rules, grouped findings and
per-node heartbeat statistics, computed once here so every format tells the same story."""

from __future__ import annotations

import bisect
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from datetime import datetime, timezone

import numpy as np

from nmtcheck.checks import BY_CODE, RULES
from nmtcheck.checks.base import SEVERITIES, Rule, fails
from nmtcheck.protocol.nmt import BOOTUP, EPS
from nmtcheck.results import Finding, InputResult, summary
from nmtcheck.safe_text import escape_controls, escape_matching
from nmtcheck.timeline.gaps import Gaps
from nmtcheck.timeline.model import ChannelModel, NodeModel

SEVERITY_ORDER = SEVERITIES  # most severe first (one order, in checks.base)
# Rules whose findings may name no node (a CAN-ID or a frame on 000h belongs to the network):
# their per-channel "network" test cases exist even when nothing fired. C001 never names one.


def is_input_rule(code: str) -> bool:
    """I-rules judge the input itself: their findings name no channel and no node."""
    return BY_CODE[code].scope == "input"


def where_label(channel: str | None, node: int | None) -> str:
    """'can0 node 5', 'can0 network', or 'input' for a finding about the input itself."""
    return "input" if channel is None else f"{channel} {node_label(node)}"


def config_line(options: dict[str, object] | None) -> str | None:
    """Which configuration file was used and the profile in force, when a file was used."""
    cfg = (options or {}).get("config")
    if not isinstance(cfg, dict) or not cfg.get("file"):
        return None
    extra = cfg.get("overrides") or []
    assert isinstance(extra, list)
    return (f"configuration: {cfg['file']} (profile {cfg.get('profile') or 'default'}"
            + (f", with its own [rules] tables for {', '.join(map(str, extra))}" if extra
               else "") + ")")


_FORMULA_START = ("=", "+", "-", "@", "\t", "\r")
_XML_INVALID = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\ufffe\uffff\ud800-\udfff]")


def spreadsheet_safe(cell: object) -> str:
    """A text cell a spreadsheet will not run as a formula (OWASP CSV injection): one that
    starts with = + - @ tab or CR gets a leading apostrophe. Numbers are not text cells.
    Control characters are written as `\\xNN`, as in the text report."""
    text = "" if cell is None else escape_controls(cell)  # NUL, ESC, BEL: shown, not sent
    return "'" + text if text.startswith(_FORMULA_START) else text


def xml_safe(text: str) -> str:
    """Text XML 1.0 can hold: characters it forbids (control characters from a channel
    name, say) are written as \\xNN so the document stays well-formed."""
    return escape_matching(_XML_INVALID, text)


def omitted_lines(results: list[InputResult], options: dict[str, object]) -> list[str]:
    """One line per rule and input whose findings passed the cap (stated, never hidden)."""
    cap = options.get("max_findings")
    return [f"{res.stats.path}: {o.count} more {o.rule} {o.name} ({o.severity}) finding(s) "
            f"left out of this report (--max-findings {cap}); they count for the verdict"
            for res in results for o in res.omitted]


# SPEC §4: what the gate decided, as JSON `summary.verdict` says it and as people read it
VERDICT_WORDS = {"pass": "PASS", "fail": "FAIL", "not-gated": "NOT GATED"}


def verdict(results: list[InputResult], threshold: str) -> str:
    """`pass` (nothing at or above `--fail-on`), `fail`, or `not-gated` (`--fail-on
    never`): never a pass above errors. An input that could not be read fails the run
    (exit 2) whatever the threshold."""
    if unreadable(results):
        return "fail"
    if threshold == "never":
        return "not-gated"
    return "fail" if is_failing(results, threshold) else "pass"


ORDER_ONLY = "order only: timing not checked"


def order_only(results: list[InputResult]) -> list[int]:
    """The indices of the inputs checked in order only (no usable timestamps, I006): JSON
    `summary.order_only` (SPEC §4)."""
    return [res.index for res in results if res.error is None and res.stats.order_only]


def verdict_word(results: list[InputResult], options: dict[str, object]) -> str:
    """PASS, FAIL or NOT GATED; a pass over an input checked in order only says so
    (`PASS (order only: timing not checked)`, SPEC §4): its timing rules never ran, so
    a gate must not read it as a plain pass."""
    decided = verdict(results, fail_on(options))
    untimed = order_only(results)
    if decided != "pass" or not untimed:
        return VERDICT_WORDS[decided]
    readable = sum(1 for res in results if res.error is None)
    part = "" if len(untimed) == readable else f" in {len(untimed)} of {readable} inputs"
    return f"PASS ({ORDER_ONLY}{part})"


def verdict_class(results: list[InputResult], options: dict[str, object]) -> str:
    """The verdict as a class name (`pass`, `fail`, `not-gated`), with `order-only` added
    to a pass over an input checked in order only: never a plain green badge."""
    decided = verdict(results, fail_on(options))
    return f"{decided} order-only" if decided == "pass" and order_only(results) else decided


def unreadable(results: list[InputResult]) -> list[InputResult]:
    """The inputs that could not be read (SPEC §4: named in every report)."""
    return [res for res in results if res.error is not None]


def verdict_line(results: list[InputResult], options: dict[str, object]) -> str:
    """`FAIL: 1 error, 0 warnings, 0 info in 2 inputs (--fail-on error)`: what the exit code
    says, the same words in every format."""
    threshold = fail_on(options)
    inputs = len(results)
    bad = len(unreadable(results))
    return (f"{verdict_word(results, options)}: {counts_phrase(summary(results))} in {inputs} "
            f"input{'s' if inputs != 1 else ''}"
            + (f", {bad} of them could not be read" if bad else "")
            + f" (--fail-on {threshold})")


def measured_mark(f: Finding) -> str:
    """What the text reports add to a finding whose limit was measured from the trace
    (`basis` measured: a factor x the median period, as `nmtcheck monitor` marks a
    provisional finding) or assumed (a producer time x nmtcheck's factor: the consumer
    time is unknown), naming what would give the configured one (SPEC §7)."""
    if f.basis == "assumed":
        return ("  [limit assumed: the heartbeat consumer time (1016h) of the node's consumer "
                "gives the real one: the consumer's device file (--dcf NODE=FILE, e.g. the "
                "master's DCF) or consumer_timeout_ms in --network]")
    if f.basis != "measured":
        return ""
    return "  [limit measured from the trace: --network or --dcf gives the configured one]"


def error_line(res: InputResult) -> str:
    """The line every report gives an input that could not be read."""
    return f"{res.stats.path}: cannot be checked: {res.error}"


def not_logs_line(options: dict[str, object], names: bool = True) -> str | None:
    """Files below a directory argument that are no log (their content is no log format,
    or they are no regular file: a FIFO, a socket, a device): counted, and the first
    named unless `names` is false (-q)."""
    skipped = options.get("not_logs") or []
    not_regular = options.get("not_regular") or []
    assert isinstance(skipped, list) and isinstance(not_regular, list)
    special = set(map(str, not_regular))
    if not skipped:
        return None
    head = f"{plural(len(skipped), 'file')} below the directories given are no log (skipped)"
    if not names:
        return head
    shown = ", ".join(f"{p} (not a regular file)" if str(p) in special else str(p)
                      for p in skipped[:5]) + (", …" if len(skipped) > 5 else "")
    return f"{head}: {shown}"


def utc_start(res: InputResult) -> str | None:
    """When the recording started, as ISO 8601 UTC, when its timestamps are absolute
    (SPEC §7 `start_utc`): epoch stamps of candump, BLF, MCAP, MF4, pcap, TRC with
    `$STARTTIME`. Stamps relative to the recording's start (ASC, candump -tz, TRC without
    `$STARTTIME`) are small numbers: nothing before 1980 is taken for a date."""
    s = res.stats
    if res.error is not None or s.order_only or not s.frames or s.start is None:
        return None
    if s.format in RELATIVE_FORMATS or not ABSOLUTE_FROM <= s.start < ABSOLUTE_UNTIL:
        return None
    stamp = datetime.fromtimestamp(s.start, tz=timezone.utc)
    return stamp.isoformat(timespec="microseconds").replace("+00:00", "Z")


RELATIVE_FORMATS = ("asc",)  # stamps are seconds from the start of the measurement
ABSOLUTE_FROM = 315532800.0  # 1980-01-01: smaller stamps are relative ones
ABSOLUTE_UNTIL = 4102444800.0  # 2100-01-01


def network_notes(options: dict[str, object] | None) -> list[str]:
    """What could not be read from the network and device files (shown, never dropped)."""
    notes = (options or {}).get("network_notes") or []
    assert isinstance(notes, list)
    return [str(n) for n in notes]


def master_line(cm: ChannelModel) -> str:
    """A channel's NMT master and how it is known, or why none is."""
    if cm.master is None:
        return f"{cm.name}: no NMT master known ({cm.master_note or 'none given'})"
    m = cm.master
    how = {"network": "named in the network file", "device-file": "device file 1F80h bit 0",
           "inferred": "inferred from the start-up"}.get(m.source, m.source)
    return f"{cm.name}: NMT master node {m.node} ({how}" + (
        f"; {m.detail})" if m.detail and m.source != "network" else ")")


def fail_on(options: dict[str, object]) -> str:
    return str(options.get("fail_on", "error"))


def is_failing(results: list[InputResult], threshold: str) -> bool:
    """The verdict the exit code gives: any finding at or above `--fail-on`."""
    return fails(summary(results), threshold)


def checked_rules(options: dict[str, object]) -> list[tuple[Rule, str]]:
    """The rules that ran, with their configured severity, in catalogue order.

    The CLI passes `options["rules"]` ({code: severity}); without it (a library caller)
    every rule at its default severity is assumed.
    """
    configured = options.get("rules")
    if not isinstance(configured, dict):
        return [(r, r.severity) for r in RULES]
    return [(r, str(configured[r.code])) for r in RULES if r.code in configured]


@dataclass
class CaptureView:
    """One recording of an input that holds several (`cat run1.log run2.log`: time starts
    again, nmtcheck/readers/captures.py): its span, frames and first line."""

    number: int
    start: float
    end: float
    frames: int
    line: int

    @property
    def duration(self) -> float:
        return max(self.end - self.start, 0.0)


def captures(result: InputResult) -> list[CaptureView]:
    """The input's captures when it holds several, else none: the times of two captures
    never subtract (one that starts earlier than the one before would give a negative
    duration)."""
    s = result.stats
    spans = s.capture_spans
    if len(spans) < 2 or result.error is not None:
        return []
    ends = [first for _a, _b, first, _line in spans[1:]] + [s.frames]
    return [CaptureView(k, a, b, max(nxt - first, 0), line) for k, ((a, b, first, line), nxt)
            in enumerate(zip(spans, ends, strict=True), 1)]


def duration(result: InputResult) -> float:
    """How long the input records: its span, or the sum of its captures' spans. Never
    negative."""
    parts = captures(result)
    if parts:
        return sum(c.duration for c in parts)
    s = result.stats
    return max((s.end or 0.0) - (s.start or 0.0), 0.0)


def captures_note(result: InputResult, short: bool = False) -> str:
    """What a header adds for an input of several captures: each one's frames and span
    (` in 2 captures: 192 frames over 19.046 s from line 1, 351 frames over 4.921 s from
    line 193`; `short`: ` (2 captures: 19.046 s, 4.921 s)`); empty for one."""
    parts = captures(result)
    if not parts:
        return ""
    if short:
        return f" ({len(parts)} captures: {', '.join(f'{c.duration:.3f} s' for c in parts)})"
    return f" in {len(parts)} captures: " + ", ".join(
        f"{c.frames} frames over {c.duration:.3f} s"
        + (f" from line {c.line}" if c.line else "") for c in parts)


def latest(result: InputResult) -> float | None:
    """The input's latest time (`inputs[i].end`): with several captures the latest of
    theirs, never before the first frame's."""
    s = result.stats
    parts = captures(result)
    if not parts or s.end is None:
        return s.end
    return max(s.end, *(c.end for c in parts))


def offset(result: InputResult, t: float) -> float:
    """Seconds from the first frame of the recording: what people read on a time axis."""
    return t - (result.stats.start or 0.0)


def moment(result: InputResult, t: float, digits: int = 6, unit: str = " s",
           f: Finding | None = None) -> str:
    """A time as the reports show it: seconds from the recording's first frame
    (`1.560400 s`; a finding `f` of a later capture of the input: from that capture's
    first frame, as its messages count), or, in an input without timestamps, the frame
    it stands for (`frame 3`, the third frame: its time is the frame index, SPEC §1)."""
    if result.stats.order_only:
        return frame_text(t)
    start = result.stats.start or 0.0 if f is None else capture_start(result, f)
    return f"{t - start:.{digits}f}{unit}"


def capture_start(result: InputResult, f: Finding) -> float:
    """Where the times of finding `f` count from: the input's first frame, or in an input
    of several captures the first frame of `f`'s capture (its channel's, else the one
    holding its frame): a later capture's clock may be behind the first's, and times
    from the input's start would be negative."""
    s = result.stats
    spans = s.capture_spans
    if len(spans) < 2:
        return s.start or 0.0
    if f.channel is not None:
        cm = next((c for c in result.model.channels if c.name == f.channel), None)
        if cm is not None:
            return cm.start
    if f.frame_index is None:
        return s.start or 0.0
    firsts = [first for _a, _b, first, _line in spans]
    k = max(bisect.bisect_right(firsts, f.frame_index) - 1, 0)
    return spans[k][0]


def frame_text(t: float) -> str:
    """`frame N` (1-based) for a time that is a 0-based frame index (no timestamps)."""
    return f"frame {round(t) + 1}"


def node_label(node: int | None) -> str:
    return "network" if node is None else f"node {node}"


@dataclass
class FindingGroup:
    """Repeated findings of one rule on one node of one channel: one row with a count."""

    input: int
    rule: str
    name: str
    severity: str
    channel: str | None  # None: the input itself (I-rules)
    node: int | None
    findings: list[Finding] = field(default_factory=list)

    @property
    def count(self) -> int:
        return len(self.findings)

    @property
    def first(self) -> Finding:
        return self.findings[0]


def group_findings(findings: Iterable[Finding]) -> list[FindingGroup]:
    """Group by (input, channel, node, rule), in order of each group's first finding."""
    groups: dict[tuple[int, str | None, int | None, str], FindingGroup] = {}
    for f in findings:
        key = (f.input, f.channel, f.node, f.rule)
        g = groups.get(key)
        if g is None:
            g = groups[key] = FindingGroup(f.input, f.rule, f.name, f.severity, f.channel, f.node)
        g.findings.append(f)
    return sorted(groups.values(), key=lambda g: (g.input, g.first.time, g.rule))


@dataclass
class HeartbeatStats:
    """Heartbeat intervals of one node in seconds (no interval across a boot-up or reset);
    a long log's dropped runs count as their intervals (`gaps.Gaps`)."""

    intervals: Gaps

    @property
    def count(self) -> int:
        return self.intervals.count

    @property
    def minimum(self) -> float | None:
        return self.intervals.minimum() if self.count else None

    @property
    def median(self) -> float | None:
        return self.intervals.median() if self.count else None

    @property
    def maximum(self) -> float | None:
        return self.intervals.maximum() if self.count else None

    @property
    def jitter(self) -> float | None:
        """Population standard deviation: how far a typical interval strays from the mean."""
        return self.intervals.std() if self.count > 1 else None


def heartbeat_stats(m: NodeModel) -> HeartbeatStats:
    """The same intervals the timeline measures the period from (SPEC §2)."""
    if m.order_only:  # no timestamps: no period or gap was measured (SPEC §1)
        return HeartbeatStats(Gaps(np.zeros(0)))
    return HeartbeatStats(m.heartbeat_gaps())


@dataclass
class ConfiguredVsMeasured:
    """What the network description / SDO writes configured, next to what the trace shows."""

    producer_ms: float | None  # 1017h in force at the end of the trace (0: disabled by SDO)
    consumer_ms: float | None  # smallest consumer time for this node
    consumer_node: int | None
    guard_time_ms: float | None
    life_time_factor: int | None
    median_ms: float | None
    jitter_ms: float | None
    worst_gap_ms: float | None


def configured_vs_measured(m: NodeModel, end: float) -> ConfiguredVsMeasured:
    cfg = m.config_at(end)
    stats = heartbeat_stats(m)

    def ms(x: float | None) -> float | None:
        return None if x is None else round(x * 1000.0, 3)

    return ConfiguredVsMeasured(cfg.heartbeat_ms, cfg.consumer_timeout_ms, cfg.consumer_node,
                                cfg.guard_time_ms, cfg.life_time_factor, ms(stats.median),
                                ms(stats.jitter), ms(stats.maximum))


@dataclass
class Reboots:
    """Boot-ups of a node inside one of its state intervals: it announced a new boot
    (00h) again and again without changing state (a node stuck rebooting: B002, or B003
    where no report came between; one that heartbeats 00h: B003), which a plain bar
    would hide."""

    interval: int  # its position in the node's intervals
    ts: np.ndarray  # the boot-ups' times

    @property
    def count(self) -> int:
        return len(self.ts)


def reboots(m: NodeModel) -> list[Reboots]:
    """Each state interval of `m` that holds boot-ups of its own (after the one that
    began it; stale ones and those that answer a reset command to N since its previous
    boot-up left out), with their times."""
    if m.kind_counts()[BOOTUP] < 2 or not len(m.intervals):
        return []
    ec = m.ec
    rows = np.flatnonzero((ec.kind == BOOTUP) & ~ec.stale)
    ts, idx = ec.ts[rows], ec.idx[rows]
    # each reset command to N explains one boot-up after it (as for B002)
    before = np.searchsorted(m.commands.reset_idx, idx).tolist()
    answers = np.zeros(len(idx), bool)
    used = 0
    for i, n in enumerate(before):
        if n > used:
            answers[i] = True
            used += 1
    k = m.interval_indices(ts)
    inside = (ts > m.intervals.start[k] + EPS) & ~answers
    ts, k = ts[inside], k[inside]
    return [Reboots(int(i), ts[k == i]) for i in np.unique(k).tolist()]


def reboot_note(res: InputResult, m: NodeModel, r: Reboots, shown: int = 3) -> str:
    """`rebooted 19 times while PRE-OPERATIONAL: boot-ups (00h) at 1.610555, 1.710553,
    1.810551 … 3.410540 s`: what the timeline and node table say of them."""
    state = m.intervals[r.interval].state
    times = [moment(res, t, unit="") for t in r.ts[:shown].tolist()]
    more = f" … {moment(res, float(r.ts[-1]), unit='')}" if r.count > shown else ""
    unit = "" if res.stats.order_only else " s"
    return (f"rebooted {plural(r.count, 'time')} while {state}: boot-up (00h) at "
            f"{', '.join(times)}{more}{unit}")


def resets(m: NodeModel) -> int:
    """Reset node / reset communication commands that reached the node (direct or broadcast)."""
    return int(np.count_nonzero(m.commands.is_reset))


def final_state(m: NodeModel) -> str:
    return m.intervals[-1].state if m.intervals else "UNKNOWN"


def nodes_by_channel(result: InputResult, always_network: bool = False
                     ) -> dict[str, list[int | None]]:
    """Every node of each channel that has a model or a finding, in order; `None` (the
    network) last when the channel has node-less findings, or always if asked."""
    out: dict[str, set[int]] = {name: set() for name in result.stats.channels}
    network: set[str] = set()
    for m in result.nodes():
        out.setdefault(m.channel, set()).add(m.node)
    for f in result.findings:
        if f.channel is None:
            continue  # an I-rule finding belongs to the input, not to a channel
        if f.node is None:
            network.add(f.channel)
        else:
            out.setdefault(f.channel, set()).add(f.node)
    return {ch: [*sorted(nodes), *([None] if always_network or ch in network else [])]
            for ch, nodes in out.items()}


def plural(n: int, word: str) -> str:
    return f"{n} {word}" + ("" if n == 1 else "s")


def counts_phrase(counts: dict[str, int]) -> str:
    """'1 error, 2 warnings, 0 info' — the summary line every format shares."""
    return (f"{plural(counts['error'], 'error')}, {plural(counts['warning'], 'warning')}, "
            f"{counts['info']} info")
