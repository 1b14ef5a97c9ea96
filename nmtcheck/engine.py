"""Runs one input through read -> decode -> timeline -> rules and stamps the findings.

Per-node checks are called here for each node and what they yield gets its channel
and node; every problem then gets its rule code, name and configured severity,
moments get the first frame at or after them, and the SPEC's UNKNOWN exemption and
the per-rule cap are applied in one place for every rule.
"""

from __future__ import annotations

import difflib
import gc
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, fields, replace
from functools import partial
from typing import Any, Protocol, cast

import numpy as np

from nmtcheck.checks import BY_CODE, RULES
from nmtcheck.checks.base import (
    Check,
    Located,
    NodeCheck,
    NodeContext,
    Problem,
    Problems,
    Rule,
)
from nmtcheck.checks.inputs import refuse_mostly_unread
from nmtcheck.errors import InputError, NmtcheckError, UsageError
from nmtcheck.explain import causes as cause_stage
from nmtcheck.explain.evaluated import finding_bases, partly_evaluated
from nmtcheck.explain.evaluated import not_evaluated as rules_not_evaluated
from nmtcheck.processes import boot as boot_stage
from nmtcheck.processes import emcy as emcy_stage
from nmtcheck.processes import lss as lss_stage
from nmtcheck.processes import pdo as pdo_stage
from nmtcheck.processes import sync as sync_stage
from nmtcheck.processes.sdo_transfers import SdoSpool, tee
from nmtcheck.protocol.nmt import UNKNOWN
from nmtcheck.readers import CUT_IF_DAMAGED, InputStats, open_input, printable_path
from nmtcheck.readers.captures import Captures, channel_spans
from nmtcheck.readers.frames import FrameBatch
from nmtcheck.results import (
    MAX_FINDINGS_PER_RULE,
    Finding,
    InputResult,
    Omitted,
    PackedResult,
    for_reports,
)
from nmtcheck.settings.network import Network
from nmtcheck.settings.profiles import Profile, RuleSettings
from nmtcheck.settings.values import quoted
from nmtcheck.timeline.build import build
from nmtcheck.timeline.decode import FrameAt, decode
from nmtcheck.timeline.model import (
    InputModel,
    Master,
    NodeConfig,
    NodeModel,
    TimelineParams,
    Timeout,
)
from nmtcheck.timeline.readback import unsafe_nodes

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
            close = difflib.get_close_matches(
                pat.lower(), [r.name for r in RULES] + [r.code.lower() for r in RULES], 1, 0.6)
            hint = (f" (did you mean {close[0].upper() if close[0][1:].isdigit() else close[0]!r}?)"
                    if close else "")
            raise UsageError(f"{where}: {quoted(pat)} matches no rule code or name{hint}")


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
        bootup_grace_s=profile["B001"].params["grace_ms"] / 1000.0,
        repeat_window_ms=profile["B003"].params["repeat_window_ms"],
    )


def known_masters(network: Network | None, channels: list[str],
                  log_name: Callable[[str], str] = str) -> dict[str, Master]:
    """Each channel's master as the network file or a device file names it (SPEC §2);
    `log_name`: the name the files know a channel by (a later capture's:
    nmtcheck/readers/captures.py)."""
    out: dict[str, Master] = {}
    if network is None:
        return out
    for name in channels:
        found = network.master_for(log_name(name))
        if found is not None:
            out[name] = Master(*found)
    return out


def _inherit_masters(model: InputModel, masters: dict[str, Master]) -> bool:
    """Give a later capture's channel whose start-up shows no master the master its
    channel's first capture showed (the same network: nmtcheck/readers/captures.py); whether
    any was given. A capture that begins after the master's start-up cannot show it."""
    first = {cm.name: cm.master for cm in model.channels if cm.network_name == cm.name}
    given = False
    for cm in model.channels:
        found = first.get(cm.network_name) if cm.network_name != cm.name else None
        if found is not None and cm.master is None and cm.name not in masters:
            masters[cm.name] = Master(found.node, found.source,
                                      f"as in {cm.log_name}: {found.detail}".rstrip(": "))
            given = True
    return given


def _configs(network: Network | None, stats: InputStats
             ) -> dict[tuple[str | None, int], NodeConfig]:
    """The files' node configurations by (channel, node-ID); a channel's are also those of
    its later captures' channels (nmtcheck/readers/captures.py)."""
    configs = network.configs() if network else {}
    for own, name in stats.capture_channels.items():
        configs.update({(own, n): cfg for (ch, n), cfg in list(configs.items()) if ch == name})
    return configs


def check_input(path: str, index: int, profile: Profile, rules: list[Rule],
                network: Network | None = None, input_format: str | None = None,
                strict: bool = False, channel: str | None = None,
                reader_options: dict[str, Any] | None = None,
                progress: Callable[[int], object] | None = None,
                max_findings: int = MAX_FINDINGS_PER_RULE) -> InputResult:
    opened = open_input(path, input_format, strict, reader_options)
    pdo_ids = {c for cfg, _channel in (network.nodes.values() if network else ())
               for c in [*cfg.tpdo_cob_ids.values(), *cfg.rpdo_cob_ids.values()] if c is not None}
    pdo_ids |= {t.cob_id & 0x7FF for keys in (network.comm_nodes.values() if network else ())
                for t in [*keys.tpdo.values(), *keys.rpdo.values()]  # PDOs above 4 too
                if t.cob_id is not None and not t.cob_id & 0xA0000000}
    stats = opened.stats
    selected = [r.code for r in rules]
    spool = SdoSpool()  # the SDO and error frames, per server (SPEC §8.3.1, §8.6)
    captures = Captures(stats)  # where time starts again, a new recording begins
    batches = tee(captures.split(_in_order(
        _without_cut_frame(opened.batches, stats, opened.cut_line), stats)), spool)
    decoded = decode(_counted(batches, progress) if progress else batches, pdo_ids,
                     protect_s=timeline_params(profile).obey_s,
                     sync_cob_ids=sync_stage.sync_cob_ids(network))
    collecting = _pause_collector()
    try:
        # most of it skipped: a pass over the rest would be no verdict on the input
        refuse_mostly_unread(stats, decoded.standard_frames, profile["I003"].params)
        if stats.frames == 0:
            start = end = 0.0
        elif stats.order_only:  # the frame index stands for the time (SPEC §1)
            start, end = 0.0, float(stats.frames - 1)
            stats.start, stats.end = start, end
            profile = order_only_profile(profile)
            rules = [r for r in rules if r.code not in TIME_RULES]
        else:
            start, end = float(stats.start or 0.0), float(stats.end or 0.0)
            last = decoded.last_event_ts
            if last is not None:
                end = max(end, last)
        spans = channel_spans(captures)
        configs = _configs(network, stats)
        params = replace(timeline_params(profile), order_only=stats.order_only)
        masters = known_masters(network, stats.channels, stats.log_channel)
        # the model from the decoded frames (`masters` may gain a later capture's)
        rebuild = partial(build, decoded, stats.channels, start, end, params, configs,
                          masters, spans)
        model = rebuild()
        if _inherit_masters(model, masters):
            model = rebuild()
        if decoded.ec_runs or decoded.ec_guard_runs:  # a long log: a node whose dropped
            tolerance = profile["H003"].params["tolerance"]  # runs a limit cuts is read whole
            silence = float(profile.timeline.get("silence_min_ms", 100.0)) / 1000.0
            unsafe = unsafe_nodes(model, tolerance, silence)
            every = set(decoded.ec_runs) | set(decoded.ec_guard_runs)
            for keys in (unsafe, every):  # then, if limits moved: every node
                if not unsafe:
                    break
                decoded.restore_ec(keys)
                model = rebuild()
                unsafe = unsafe_nodes(model, tolerance, silence)
            late = _boot_evidence_in_runs(model, spool, network, profile, max_findings)
            if late:
                decoded.restore_ec(late)
                model = rebuild()
        decoded.events = decoded.events[:0].copy()  # the SDO rows are paired into the model
        model.stats = stats
        model.expected = network.expected() if network else []
        if channel is not None:
            if channel not in stats.channels:
                raise UsageError(f"--channel {channel}: not in {stats.path} (channels: "
                                 f"{', '.join(stats.channels) or 'none'})")
            model.channels = [cm for cm in model.channels  # (and its later captures')
                              if channel in (cm.name, cm.network_name)]
        result = InputResult(index, stats, model)
        result.boot = boot_stage.run(model, spool, network, profile, max_findings)
        # SPEC §9.1: the SYNC of each channel and the EMCYs of each node, for the Y and E
        # rules and the reports
        sync_stage.attach(model, sync_stage.analyse(model, network))
        pdo_stage.attach(model, pdo_stage.analyse(
            model, network, spool, float(profile.timeline.get("sdo_timeout_ms", 1000.0)) / 1e3))
        emcy_stage.attach(model, emcy_stage.analyse(
            model, network, emcy_stage.resolution(stats, profile.timeline)))
        lss_stage.attach(model, lss_stage.analyse(  # SPEC §9.1.8
            model, network, float(profile.timeline.get("lss_response_timeout_ms", 1000.0))))
        problems: list[tuple[Rule, Problem]] = []
        nodes: dict[tuple[str | None, int], NodeModel] = {
            (cm.name, m.node): m for cm in model.channels for m in cm.nodes.values()}
        contexts = [NodeContext(model, cm) for cm in model.channels]  # made once: a log
        for r in rules:  # may have tens of thousands of channels
            found = _node_problems(r, contexts, profile[r.code].params) if r.per_node else (
                _input_problems(r, model, profile[r.code].params, nodes))
            left = _keep(r, found, problems, max_findings)
            if left:
                result.omitted.append(Omitted(r.code, r.name, profile[r.code].severity, left))
        _locate(model, problems)
        for r, p in problems:
            settings: RuleSettings = profile[r.code]
            result.findings.append(Finding(index, r.code, r.name, settings.severity, p.channel,
                                           p.node, p.time, p.frame_index, p.line, p.message))
        result.findings.sort(key=lambda f: (f.time, f.frame_index or 0, f.rule))
        finding_bases(model, result.findings)
        cause_stage.attach(result, spool, profile)
        result.not_evaluated = not_evaluated(model, selected, stats.order_only, network)
        result.partly_evaluated = partly_evaluated(
            model, [c for c in selected if c not in result.not_evaluated])
        return result
    finally:
        if collecting:
            gc.enable()
        decoded.close()
        spool.close()


def _pause_collector() -> bool:
    """Pause the cyclic garbage collector while the model is built and checked; return
    whether it ran. The model's objects (a dozen per node, tens of thousands of nodes in a
    log of many channels) live until the reports are written, so its passes over them
    while they are made free nothing: a fifth of the time at 40,000 channels. The
    decoding before is not paused (a reader may make cycles per bad record); whatever
    the checks leave in cycles is collected once it runs again."""
    was = gc.isenabled()
    gc.disable()
    return was


# (the node when known, a problem or a batch): the rule's problems in the order it found them
_Found = Iterator[tuple["NodeModel | None", "Problem | Problems"]]


def _input_problems(r: Rule, model: InputModel, params: dict[str, Any],
                   nodes: dict[tuple[str | None, int], NodeModel]) -> _Found:
    """A per-input rule's problems, each with its node's model (None: no such node;
    `nodes`: every node of the input by channel name and node-ID, made once)."""
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


def _node_problems(r: Rule, contexts: list[NodeContext], params: dict[str, Any]) -> _Found:
    """A per-node rule over every node, channels in model order (`contexts`: one per
    channel), nodes in number order; what it yields stamped with channel and node."""
    check = cast(NodeCheck, r.check)
    for ctx in contexts:
        cm = ctx.channel
        for m in cm.nodes.values():
            for found in check(m, ctx, params):
                if isinstance(found, Problems):
                    yield m, replace(found, channel=cm.name, node=m.node)
                elif len(found) == 2:
                    yield m, Problem(cm.name, m.node, found[0], found[1])
                elif isinstance(found[2], Timeout):  # its frame comes after the wait's start
                    yield m, Problem(cm.name, m.node, found[0], found[1],
                                     after=found[2].after_idx)
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


# rules that need time: not evaluated on an input without timestamps (SPEC §1, I006)
TIME_RULES = {"H001": "heartbeat timeouts need time", "H002": "heartbeat spacing needs time",
              "H003": "heartbeat periods need time", "H004": "consumer times need time",
              "G002": "guarding response times need time",
              "G003": "guarding intervals need time",
              "S004": "obey_ms: whether a report came too late needs time",
              "Y001": "SYNC timeouts need time", "Y005": "SYNC periods need time",
              "Y004": "the synchronous window needs time",
              "D001": "event timers need time", "D002": "inhibit times need time",
              "D004": "RPDO deadlines need time",
              "E001": "EMCY inhibit times need time",
              "L006": "boot-up waits after LSS need time",
              "I007": "recording gaps need time"}
# the time windows of the rules that need only order: a frame index stands for the time,
# so each window is made empty (grace, obey) or endless (explaining, repeating, awaiting)
_ORDER_ONLY_PARAMS = {("B001", "bootup_timeout_ms"): float("inf"),
                      ("B001", "late_start_ms"): float("inf"), ("B001", "grace_ms"): 0.0,
                      ("B002", "reset_window_ms"): float("inf"),
                      ("B003", "repeat_window_ms"): float("inf"),
                      ("S001", "grace_ms"): 0.0, ("S003", "grace_ms"): 0.0,
                      ("S004", "obey_ms"): 0.0,
                      # the timeline's: N's data frame right after a remote request to
                      # 700h+N answers it, however many frames of others come between
                      ("G002", "response_timeout_ms"): float("inf")}
MAX_TIMELESS_LOOKAHEAD = 1 << 20  # frames held back while every timestamp so far is equal


def order_only_profile(profile: Profile) -> Profile:
    """The profile for an input without timestamps: the order rules' windows as above."""
    out = Profile({code: replace(st, params=dict(st.params)) for code, st in profile.items()})
    out.timeline = dict(profile.timeline, master_window_ms=float("inf"))
    for (code, name), value in _ORDER_ONLY_PARAMS.items():
        if code in out and name in out[code].params:
            out[code].params[name] = value
    return out


def _in_order(batches: Iterator[FrameBatch], stats: InputStats) -> Iterator[FrameBatch]:
    """The batches, with the frame index as the time when the input has no usable
    timestamps (none written, or every one equal: SPEC §1): the timeline is then ordered
    by frame index. Frames are held back while every timestamp so far is equal (up to
    MAX_TIMELESS_LOOKAHEAD of them), so that a log whose stamps are all equal is known
    as one before its frames go on."""
    held: list[FrameBatch] = []
    count = 0
    first: float | None = None
    for batch in batches:
        if stats.order_only or not stats.timestamped:
            stats.order_only = True
            yield from (_by_index(b) for b in held)
            held.clear()
            yield _by_index(batch)
            continue
        if count <= MAX_TIMELESS_LOOKAHEAD and len(batch):
            first = float(batch.ts[0]) if first is None else first
            if bool((batch.ts == first).all()) and count + len(batch) <= MAX_TIMELESS_LOOKAHEAD:
                held.append(batch)
                count += len(batch)
                continue
        yield from held
        held.clear()
        count = MAX_TIMELESS_LOOKAHEAD + 1  # stamps differ: nothing is held back any more
        yield batch
    if held and count >= 2:
        stats.order_only = True
        yield from (_by_index(b) for b in held)
    else:
        yield from held


# the fewest data bytes a CANopen object's frame has (CiA 301): NMT command, EMCY, TIME,
# SDO; an error-control data frame has its state byte
_LEAST_BYTES = ((0x000, 0x000, 2), (0x081, 0x0FF, 8), (0x100, 0x100, 6), (0x581, 0x5FF, 8),
                (0x601, 0x67F, 8), (0x701, 0x77F, 1))


def _without_cut_frame(batches: Iterator[FrameBatch], stats: InputStats,
                       cut_line: int | None) -> Iterator[FrameBatch]:
    """The batches, but a last frame that a cut explains: on a text file's last line
    without a newline (`cut_line`), with fewer data bytes than its CANopen object has
    (`000#01` of `000#0105`). A recording killed mid-write or a file copied while it was
    written ends so; read as a frame it would be a malformed NMT command (C002) or
    heartbeat (C003) and fail the gate. It is a skipped record and the input is truncated
    (I002). A short frame on a last line with its newline, or a whole frame on one
    without (a pasted log saved without a final newline), is read as it is. In a
    compressed log whose stream is damaged, the last line read is where it was cut."""
    if cut_line is None:  # the input ends with a newline, the usual case
        yield from batches
        return
    held: FrameBatch | None = None  # the last batch is known once the next is not
    for batch in batches:
        if held is not None:
            yield held
        held = batch
    if held is None:
        return
    if cut_line == CUT_IF_DAMAGED:  # a compressed log: cut where its stream is damaged
        cut_line = int(held.line[-1]) if stats.truncated and len(held) else None
    if len(held) and int(held.line[-1]) == cut_line and _short(held):
        held = replace(held, **{f.name: getattr(held, f.name)[:-1] for f in fields(held)})
        stats.frames -= 1
        stats.end = float(held.ts[-1]) if len(held) else stats.end
        stats.truncated = True
        stats.skip(cut_line, "cut off: the input ends inside this line (no newline after it) "
                   "and its frame has fewer data bytes than a CANopen frame of its CAN-ID")
    yield held


def _short(batch: FrameBatch) -> bool:
    """Whether the batch's last frame is an 11-bit data frame shorter than its object."""
    if batch.ext[-1] or batch.rtr[-1] or batch.err[-1]:
        return False
    can_id, dlc = int(batch.can_id[-1]), int(batch.dlc[-1])
    return any(lo <= can_id <= hi and dlc < least for lo, hi, least in _LEAST_BYTES)


def _by_index(batch: FrameBatch) -> FrameBatch:
    return replace(batch, ts=batch.index.astype(np.float64))


def not_evaluated(model: InputModel, codes: list[str], order_only: bool,
                  network: Network | None) -> dict[str, str]:
    """The selected rules that could not be evaluated on this input, with the reason:
    those that need time on an input without timestamps (SPEC §1, I006), and those that
    lack the configuration they compare with (nmtcheck/explain/evaluated.py)."""
    out = {c: f"no timestamps: {TIME_RULES[c]}" for c in codes
           if order_only and c in TIME_RULES}
    found = rules_not_evaluated(model, [c for c in codes if c not in out], network is not None)
    return {c: out.get(c) or found[c] for c in codes if c in out or c in found}


def failed_input(path: str, index: int, reason: str) -> InputResult:
    """The result of an input that could not be read, among several (SPEC §4): no counts,
    nodes or findings, only the reason, named in every report."""
    stats = InputStats(path=printable_path(path))
    decoded = decode(iter(()))
    try:
        model = build(decoded, [], 0.0, 0.0, TimelineParams(), {})
    finally:
        decoded.close()
    model.stats = stats
    return InputResult(index, stats, model, error=reason)


def _counted(batches: Iterator[FrameBatch], progress: Callable[[int], object]
             ) -> Iterator[FrameBatch]:
    """The batches, telling `progress` how many frames each one has (for a progress bar)."""
    for batch in batches:
        progress(len(batch))
        yield batch


def _boot_evidence_in_runs(model: InputModel, spool: SdoSpool, network: Network | None,
                           profile: Profile, cap: int) -> set[int]:
    """A long log's nodes whose boot evidence (the first report after a process's last
    transfer: SPEC §8) is the kept row after a dropped run, where the report the boot
    analysis wants may lie: the SDO transfers of a boot process do not divide runs (a
    master polling a node by SDO would keep every heartbeat). Read back whole, they give
    the whole log's boot report. The analysis runs once more on the final model."""
    analysis = boot_stage.run(model, spool, network, profile, cap)
    if analysis is None:
        return set()
    channels = {cm.name: cm for cm in model.channels}
    bad: set[int] = set()
    for (name, n), rep in analysis.nodes.items():
        ev = rep.spans.ev_idx[rep.spans.ev_idx >= 0]
        cm = channels.get(name)
        m = cm.nodes.get(n) if cm is not None else None
        if m is None or not len(ev):
            continue
        rows = np.flatnonzero(np.isin(m.ec.idx, ev))
        runs, guard = m.ec.runs, m.ec.guard_runs
        if (runs is not None and bool((runs.at_rows(rows) >= 0).any())) or (
                guard is not None and bool(np.isin(rows, guard.pos).any())):
            bad.add(m.key)
    return bad


def error_reason(exc: InputError) -> str:
    """An input error's one-line reason without the path (`inputs[i].error`)."""
    return f"line {exc.line}: {exc.message}" if exc.line else exc.message


def check_inputs(paths: Sequence[str], jobs: int, profile: Profile, rules: list[Rule],
                 progress: Progress | None = None, keep_going: bool = False,
                 reports_only: bool = False, **options: Any) -> list[InputResult]:
    """`check_input` for each path (index = position; `options` are its keyword arguments),
    results in order. With jobs > 1 the inputs are checked in that many processes: checking
    many logs is CPU-bound and scales with the cores. The first input that fails (in order)
    raises, as in a serial run — unless `keep_going`: then an input that cannot be read
    gets a result with its `error` and the others are checked (SPEC §4). A worker that dies
    (a crash in a library, the OOM killer) costs only the logs it was checking, which are
    tried again; a log that kills its worker every time is an input error naming it, never
    a BrokenProcessPool for every other log. `reports_only`: each result keeps only what
    the reports read (results.for_reports), as soon as it is made: `nmtcheck check` on a
    directory of 100,000 small logs holds every result until the reports are written."""
    if jobs <= 1 or len(paths) <= 1:
        results = []
        for i, path in enumerate(paths):
            kw = dict(options)
            if progress:
                progress.start_input(path)
                kw["progress"] = progress.frames
            try:
                result = check_input(path, i, profile, rules, **kw)
                results.append(for_reports(result) if reports_only else result)
            except InputError as exc:
                if not keep_going:
                    raise
                results.append(failed_input(path, i, error_reason(exc)))
        return results
    from nmtcheck.fleet.executors import ResilientPool

    pool = ResilientPool(min(jobs, len(paths)))
    try:
        # Rules travel as codes: their decorated check functions do not pickle.
        codes = [r.code for r in rules]
        for i, path in enumerate(paths):
            pool.submit(i, _check_in_worker, path, i, profile, codes, options, reports_only)
        outcomes: dict[int, Any] = {}
        # the first input (in order) that failed, and how many inputs from the first on
        # have ended: kept as outcomes come, not looked for among all of them each time
        # (100,000 inputs took a quadratic 5e9 steps)
        first_bad: int | None = None
        ended = 0
        while len(outcomes) < len(paths):
            for key, outcome in pool.done():
                assert isinstance(key, int)
                if isinstance(outcome, PackedResult):
                    outcome = outcome.unpack()
                if progress and isinstance(outcome, InputResult):
                    progress.start_input(paths[key])
                    progress.frames(outcome.stats.frames)
                if keep_going:  # an unreadable input is a result of its own
                    outcome = _failed(paths[key], key, outcome)
                outcomes[key] = outcome
                if not isinstance(outcome, InputResult) and (first_bad is None
                                                             or key < first_bad):
                    first_bad = key
            while ended in outcomes:
                ended += 1
            if first_bad is not None and ended >= first_bad:
                raise _error_of(outcomes[first_bad], paths[first_bad])
        return [outcomes[i] for i in range(len(paths))]
    finally:
        pool.close()


def _error_of(bad: Any, path: str) -> BaseException:
    """What a serial run would have raised for the input whose outcome is `bad`."""
    from nmtcheck.fleet.executors import Crashed

    if isinstance(bad, _Failure):
        return bad.error()
    if isinstance(bad, Crashed):
        return InputError(path, f"{bad.reason}; no report was written (run it alone to see "
                          "the crash)")
    return cast(BaseException, bad)


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


def _failed(path: str, index: int, outcome: Any) -> Any:
    """A worker's input error (or the crash of every try) as the input's failed result;
    anything else (a usage error) as it was."""
    from nmtcheck.fleet.executors import Crashed

    if isinstance(outcome, _Failure) and outcome.kind == "input":
        error = outcome.error()
        assert isinstance(error, InputError)
        return failed_input(path, index, error_reason(error))
    if isinstance(outcome, Crashed):
        return failed_input(path, index, f"{outcome.reason} (run it alone to see the crash)")
    return outcome


def _check_in_worker(path: str, index: int, profile: Profile, codes: list[str],
                     options: dict[str, Any], reports_only: bool = False
                     ) -> InputResult | PackedResult | _Failure:
    try:
        result = check_input(path, index, profile, [BY_CODE[c] for c in codes], **options)
        return PackedResult.of(result) if reports_only else result
    except InputError as exc:
        return _Failure("input", (exc.path, exc.message, exc.line))
    except UsageError as exc:
        return _Failure("usage", (str(exc),))


def _locate(model: InputModel, problems: list[tuple[Rule, Problem]]) -> None:
    """Give moment findings the first frame at or after their moment."""
    moments = [p for _r, p in problems if p.frame_index is None]
    # a later capture's moment lies after its first frame (nmtcheck/readers/captures.py)
    firsts = {cm.name: cm.first_index - 1 for cm in model.channels if cm.first_index}
    found = model.decoded.first_frame_at_or_after(
        [p.time for p in moments],
        [p.after if p.after is not None else firsts.get(p.channel)  # type: ignore[arg-type]
         for p in moments])
    last: tuple[float, FrameAt] | None = None
    for p, hit in zip(moments, found, strict=True):
        if hit is None and p.after is not None:  # time went back and never came up to the
            if last is None:  # moment again: the trace's end, as for "the rest of the trace"
                last = model.decoded.last_frame(model.end)
            hit = last[1] if last is not None else None
        if hit is not None:
            p.frame_index, p.line = hit
