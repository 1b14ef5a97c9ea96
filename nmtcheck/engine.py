"""Runs one input through read -> decode -> timeline -> rules and stamps the findings.

Per-node checks are called here for each node and what they yield gets its channel
and node; every problem then gets its rule code, name and configured severity,
moments get the first frame at or after them, and the SPEC's UNKNOWN exemption and
the per-rule cap are applied in one place for every rule.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Protocol, cast

import numpy as np

from nmtcheck.checks import BY_CODE, RULES
from nmtcheck.checks.base import (
    SEVERITIES,
    Check,
    Located,
    NodeCheck,
    NodeContext,
    Problem,
    Problems,
    Rule,
)
from nmtcheck.decode import decode
from nmtcheck.errors import InputError, NmtcheckError, UsageError
from nmtcheck.frames import FrameBatch
from nmtcheck.model import InputModel, Master, NodeModel, TimelineParams
from nmtcheck.network import Network
from nmtcheck.nmt import UNKNOWN
from nmtcheck.profiles import Profile, RuleSettings
from nmtcheck.readers import InputStats, open_input
from nmtcheck.timeline import build


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

    def nodes(self) -> list[NodeModel]:
        return list(self.model.nodes())


EXACT = 100  # the specificity of a whole code or a rule name


def _specificity(rule: Rule, pattern: str) -> int:
    """How specifically `pattern` names `rule`: the prefix length for a code prefix, EXACT
    for the whole code or the rule's name, -1 if it does not match."""
    if pattern.lower() == rule.name or pattern.upper() == rule.code:
        return EXACT
    return len(pattern) if rule.code.startswith(pattern.upper()) else -1


def check_patterns(patterns: list[str], where: str = "--select/--ignore") -> None:
    """Every pattern names at least one rule (else a usage error naming `where`)."""
    for pat in patterns:
        if not any(_specificity(r, pat) >= 0 for r in RULES):
            raise UsageError(f"{where}: {pat!r} matches no rule code or name")


def select_rules(profile: Profile, select: list[str], ignore: list[str]) -> list[Rule]:
    """Enabled rules after --select/--ignore: codes, letter prefixes or rule names.

    As in ruff, the most specific pattern that matches a rule decides (`--ignore H
    --select H001` checks H001 and no other H rule); at equal specificity --ignore wins.
    Without --select the profile's enabled rules are the base; a rule the profile turns
    off is checked only when --select names it (or a prefix of it)."""
    check_patterns(select + ignore)
    chosen = []
    for r in RULES:
        chosen_by = max((_specificity(r, p) for p in select), default=-1)
        ignored_by = max((_specificity(r, p) for p in ignore), default=-1)
        if select:
            keep = chosen_by >= 0 and chosen_by > ignored_by
        else:
            keep = profile[r.code].enabled and ignored_by < 0
        if keep:
            chosen.append(r)
    return chosen


def timeline_params(profile: Profile) -> TimelineParams:
    """The timeline uses some rules' parameters: the timeouts define OFFLINE, a command's
    obey time which reports are stale, a master's start-up and a node's boot-ups (SPEC §2)."""
    return TimelineParams(
        timeout_factor=profile["H001"].params["timeout_factor"],
        early_factor=profile["H002"].params["early_factor"],
        response_timeout_s=profile["G002"].params["response_timeout_ms"] / 1000.0,
        obey_s=profile["S004"].params["obey_ms"] / 1000.0,
        master_window_s=profile.timeline["master_window_ms"] / 1000.0,
        reset_window_s=profile["B002"].params["reset_window_ms"] / 1000.0,
        bootup_timeout_s=profile["B001"].params["bootup_timeout_ms"] / 1000.0,
        repeat_window_ms=profile["B003"].params["repeat_window_ms"],
    )


def known_masters(network: Network | None, channels: list[str]) -> dict[str, Master]:
    """Each channel's master as the network file or a device file names it (SPEC §2)."""
    out: dict[str, Master] = {}
    if network is None:
        return out
    for name in channels:
        found = network.master_for(name)
        if found is not None:
            out[name] = Master(*found)
    return out


def check_input(path: str, index: int, profile: Profile, rules: list[Rule],
                network: Network | None = None, input_format: str | None = None,
                strict: bool = False, channel: str | None = None,
                reader_options: dict[str, Any] | None = None,
                progress: Callable[[int], object] | None = None,
                max_findings: int = MAX_FINDINGS_PER_RULE) -> InputResult:
    opened = open_input(path, input_format, strict, reader_options)
    pdo_ids = {c for cfg, _channel in (network.nodes.values() if network else ())
               for c in [*cfg.tpdo_cob_ids.values(), *cfg.rpdo_cob_ids.values()] if c is not None}
    decoded = decode(_counted(opened.batches, progress) if progress else opened.batches,
                     pdo_ids)
    stats = opened.stats
    try:
        if stats.frames == 0:
            start = end = 0.0
        else:
            start, end = float(stats.start or 0.0), float(stats.end or 0.0)
            last = decoded.last_event_ts
            if last is not None:
                end = max(end, last)
        configs = network.configs() if network else {}
        model = build(decoded, stats.channels, start, end, timeline_params(profile), configs,
                      known_masters(network, stats.channels))
        decoded.events = decoded.events[:0].copy()  # the SDO rows are paired into the model
        model.stats = stats
        model.expected = network.expected() if network else []
        if channel is not None:
            if channel not in stats.channels:
                raise UsageError(f"--channel {channel}: not in {stats.path} (channels: "
                                 f"{', '.join(stats.channels) or 'none'})")
            model.channels = [cm for cm in model.channels if cm.name == channel]
        result = InputResult(index, stats, model)
        problems: list[tuple[Rule, Problem]] = []
        for r in rules:
            found = _node_problems(r, model, profile[r.code].params) if r.per_node else (
                _input_problems(r, model, profile[r.code].params))
            left = _keep(r, found, problems, max_findings)
            if left:
                result.omitted.append(Omitted(r.code, r.name, profile[r.code].severity, left))
        _locate(model, problems)
        for r, p in problems:
            settings: RuleSettings = profile[r.code]
            result.findings.append(Finding(index, r.code, r.name, settings.severity, p.channel,
                                           p.node, p.time, p.frame_index, p.line, p.message))
        result.findings.sort(key=lambda f: (f.time, f.frame_index or 0, f.rule))
        return result
    finally:
        decoded.close()


# (the node when known, a problem or a batch): the rule's problems in the order it found them
_Found = Iterator[tuple["NodeModel | None", "Problem | Problems"]]


def _input_problems(r: Rule, model: InputModel, params: dict[str, Any]) -> _Found:
    """A per-input rule's problems, each with its node's model (None: no such node)."""
    nodes: dict[tuple[str | None, int], NodeModel] = {
        (cm.name, m.node): m for cm in model.channels for m in cm.nodes.values()}
    check = cast(Check, r.check)
    for p in check(model, params):
        if isinstance(p, Problems) and p.nodes is not None:  # each row its own node
            yield None, p if r.exempt_from_unknown else _known(p, nodes)
            continue
        yield (nodes.get((p.channel, p.node)) if p.node is not None else None), p


def _known(p: Problems, nodes: dict[tuple[str | None, int], NodeModel]) -> Problems:
    """A batch without the problems of nodes in UNKNOWN (SPEC §3) or not in the model;
    those of the network (node -1) stay."""
    assert p.nodes is not None
    keep = p.nodes < 0
    for n in np.unique(p.nodes[p.nodes >= 0]).tolist():
        m = nodes.get((p.channel, n))
        if m is not None:
            sel = np.flatnonzero(p.nodes == n)
            keep[sel] = m.known_at(p.time[sel])
    return p if keep.all() else p.subset(np.flatnonzero(keep))


def _node_problems(r: Rule, model: InputModel, params: dict[str, Any]) -> _Found:
    """A per-node rule over every node, channels in model order, nodes in number order;
    what it yields stamped with channel and node."""
    check = cast(NodeCheck, r.check)
    for cm in model.channels:
        ctx = NodeContext(model, cm)
        for m in cm.nodes.values():
            for found in check(m, ctx, params):
                if isinstance(found, Problems):
                    yield m, replace(found, channel=cm.name, node=m.node)
                elif len(found) == 2:
                    yield m, Problem(cm.name, m.node, found[0], found[1])
                else:
                    idx, line = _frame_of(found[2])
                    yield m, Problem(cm.name, m.node, found[0], found[1], idx, line)


def _frame_of(at: Located | tuple[int, int]) -> tuple[int, int]:
    """(index, line) of what a finding points at: a frame, or an (index, line) pair."""
    if isinstance(at, tuple) and not hasattr(at, "idx"):  # a named tuple is a frame
        return at
    frame = cast(Located, at)
    return frame.idx, frame.line


def _keep(r: Rule, found: _Found, problems: list[tuple[Rule, Problem]],
          max_findings: int) -> int:
    """Add a rule's problems to `problems`, but those of a node in UNKNOWN (unless the rule
    is exempt, SPEC §3) and those past the first `max_findings`; return how many of the
    latter were left out."""
    kept = left = 0
    for m, p in found:
        gated = p.node is not None and not r.exempt_from_unknown
        if isinstance(p, Problems):
            rows = np.arange(len(p))
            if gated:
                rows = rows[:0] if m is None else rows[m.known_at(p.time)]
            room = len(rows) if not max_findings else max(max_findings - kept, 0)
            problems.extend((r, p.problem(i)) for i in rows[:room].tolist())
            kept += min(room, len(rows))
            left += max(len(rows) - room, 0)
            continue
        if gated and (m is None or m.state_at(p.time) == UNKNOWN):
            continue
        if max_findings and kept >= max_findings:
            left += 1
            continue
        kept += 1
        problems.append((r, p))
    return left


def _counted(batches: Iterator[FrameBatch], progress: Callable[[int], object]
             ) -> Iterator[FrameBatch]:
    """The batches, telling `progress` how many frames each one has (for a progress bar)."""
    for batch in batches:
        progress(len(batch))
        yield batch


def check_inputs(paths: Sequence[str], jobs: int, profile: Profile, rules: list[Rule],
                 progress: Progress | None = None, **options: Any) -> list[InputResult]:
    """`check_input` for each path (index = position; `options` are its keyword arguments),
    results in order. With jobs > 1 the inputs are checked in that many processes: checking
    many logs is CPU-bound and scales with the cores. The first input that fails (in order)
    raises, as in a serial run. A worker that dies (a crash in a library, the OOM killer)
    costs only the logs it was checking, which are tried again; a log that kills its worker
    every time is an input error naming it, never a BrokenProcessPool for every other log."""
    if jobs <= 1 or len(paths) <= 1:
        results = []
        for i, path in enumerate(paths):
            kw = dict(options)
            if progress:
                progress.start_input(path)
                kw["progress"] = progress.frames
            results.append(check_input(path, i, profile, rules, **kw))
        return results
    from nmtcheck.fleet.executors import Crashed, ResilientPool

    pool = ResilientPool(min(jobs, len(paths)))
    try:
        # Rules travel as codes: their decorated check functions do not pickle.
        codes = [r.code for r in rules]
        for i, path in enumerate(paths):
            pool.submit(i, _check_in_worker, path, i, profile, codes, options)
        outcomes: dict[int, Any] = {}
        while len(outcomes) < len(paths):
            for key, outcome in pool.done():
                assert isinstance(key, int)
                outcomes[key] = outcome
                if progress and isinstance(outcome, InputResult):
                    progress.start_input(paths[key])
                    progress.frames(outcome.stats.frames)
            first_bad = min((i for i, o in outcomes.items()
                             if not isinstance(o, InputResult)), default=None)
            if first_bad is not None and all(i in outcomes for i in range(first_bad)):
                bad = outcomes[first_bad]
                if isinstance(bad, _Failure):
                    raise bad.error()
                if isinstance(bad, Crashed):
                    raise InputError(paths[first_bad], f"{bad.reason}; no report was written "
                                     "(run it alone to see the crash)")
                raise bad
        return [outcomes[i] for i in range(len(paths))]
    finally:
        pool.close()


class Progress(Protocol):
    """What check_inputs tells a progress display."""

    def start_input(self, path: str) -> object: ...
    def frames(self, n: int) -> object: ...


@dataclass
class _Failure:
    """An exit-2 error from a worker process, carried back in picklable form."""

    kind: str  # "input" or "usage"
    args: tuple[Any, ...]

    def error(self) -> NmtcheckError:
        return InputError(*self.args) if self.kind == "input" else UsageError(*self.args)


def _check_in_worker(path: str, index: int, profile: Profile, codes: list[str],
                     options: dict[str, Any]) -> InputResult | _Failure:
    try:
        return check_input(path, index, profile, [BY_CODE[c] for c in codes], **options)
    except InputError as exc:
        return _Failure("input", (exc.path, exc.message, exc.line))
    except UsageError as exc:
        return _Failure("usage", (str(exc),))


def _locate(model: InputModel, problems: list[tuple[Rule, Problem]]) -> None:
    """Give moment findings the first frame at or after their moment."""
    moments = [p for _r, p in problems if p.frame_index is None]
    found = model.decoded.first_frame_at_or_after([p.time for p in moments])
    for p, hit in zip(moments, found, strict=True):
        if hit is not None:
            p.frame_index, p.line = hit


def summary(results: list[InputResult]) -> dict[str, int]:
    counts = dict.fromkeys(SEVERITIES, 0)
    for res in results:
        for f in res.findings:
            counts[f.severity] += 1
        for o in res.omitted:  # left out of the reports, not out of the verdict
            counts[o.severity] += o.count
    return counts
