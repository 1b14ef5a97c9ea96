"""What checking an input yields: its findings, the ones past the per-rule cap, the rules
that could not be evaluated, and the verdict's counts. These types sit below the engine
that makes them and every stage that reads them (explain, reporters, live, fleet, the API),
so that none of those imports the engine for a type."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from nmtcheck.checks.base import SEVERITIES
from nmtcheck.processes.boot_records import BootAnalysis
from nmtcheck.readers import InputStats
from nmtcheck.timeline.model import InputModel, NodeModel


@dataclass
class Finding:
    input: int
    rule: str
    name: str
    severity: str
    channel: str | None  # None: the input itself (I-rules)
    node: int | None
    time: float
    frame_index: int | None
    line: int | None
    message: str
    # configured | measured: where the limit of a time rule came from (SPEC §7), else None
    basis: str | None = None
    # SPEC §8: P findings' Lely-compatible letter and proving frame; the events that may
    # explain H001, G002, B001 (a), B002 and S004 findings (None: the field does not apply)
    boot_letter: str | None = None
    evidence: dict[str, Any] | None = None
    causes: list[dict[str, Any]] | None = None
    causes_omitted: int | None = None
    # SPEC §9.3: what came after the effect began (the master's reset after a timeout, the
    # node's EMCY that reports it), each with its role; None where `causes` is None
    reactions: list[dict[str, Any]] | None = None
    reactions_omitted: int | None = None


MAX_FINDINGS_PER_RULE = 10000  # per input; the rest is counted, never silently dropped


@dataclass
class Omitted:
    """Findings of one rule past the per-rule cap: counted and stated in every report."""

    rule: str
    name: str
    severity: str
    count: int


@dataclass
class InputResult:
    index: int
    stats: InputStats
    model: InputModel
    findings: list[Finding] = field(default_factory=list)
    omitted: list[Omitted] = field(default_factory=list)
    # selected rules that could not be evaluated on this input: code -> reason (SPEC §7)
    not_evaluated: dict[str, str] = field(default_factory=dict)
    # rules that judged part of it and skipped the rest: code -> reason and scope (§9.1.3)
    partly_evaluated: dict[str, str] = field(default_factory=dict)
    # SPEC §9.3.6: each EMCY event's chain, by (channel, node, frame index); the causes of
    # each timeline interval that begins with a change no NMT command explains, by
    # (channel, node, the interval's start rounded to 1 ns)
    event_causes: dict[tuple[str, int, int], list[dict[str, Any]]] = field(
        default_factory=dict)
    interval_causes: dict[tuple[str, int, float], list[dict[str, Any]]] = field(
        default_factory=dict)
    error: str | None = None  # why the input could not be read (then it has nothing else)
    boot: BootAnalysis | None = None  # the CiA 302-2 boot processes (SPEC §8.5)

    def nodes(self) -> list[NodeModel]:
        return list(self.model.nodes())


def summary(results: list[InputResult]) -> dict[str, int]:
    counts = dict.fromkeys(SEVERITIES, 0)
    for res in results:
        for f in res.findings:
            counts[f.severity] += 1
        for o in res.omitted:  # left out of the reports, not out of the verdict
            counts[o.severity] += o.count
    return counts
