"""What several reporters need alike: the verdict, the checked rules, grouped findings and
per-node heartbeat statistics, computed once here so every format tells the same story."""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from datetime import datetime, timezone

import numpy as np

from nmtcheck.checks import BY_CODE, RULES
from nmtcheck.checks.base import SEVERITIES, Rule, fails
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


def verdict_word(results: list[InputResult], options: dict[str, object]) -> str:
    """PASS, FAIL or NOT GATED."""
    return VERDICT_WORDS[verdict(results, fail_on(options))]


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
    provisional finding), naming what would give the configured one."""
    if f.basis != "measured":
        return ""
    return "  [limit measured from the trace: --network or --dcf gives the configured one]"


def error_line(res: InputResult) -> str:
    """The line every report gives an input that could not be read."""
    return f"{res.stats.path}: cannot be checked: {res.error}"


def not_logs_line(options: dict[str, object]) -> str | None:
    """Files below a directory argument whose content is no log format: counted."""
    skipped = options.get("not_logs") or []
    assert isinstance(skipped, list)
    if not skipped:
        return None
    shown = ", ".join(map(str, skipped[:5])) + (", …" if len(skipped) > 5 else "")
    return (f"{plural(len(skipped), 'file')} below the directories given are no log "
            f"(skipped): {shown}")


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


def duration(result: InputResult) -> float:
    s = result.stats
    return max((s.end or 0.0) - (s.start or 0.0), 0.0)


def offset(result: InputResult, t: float) -> float:
    """Seconds from the first frame of the recording: what people read on a time axis."""
    return t - (result.stats.start or 0.0)


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
