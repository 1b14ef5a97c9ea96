"""Human-readable report: per input its counts, findings grouped by channel and node, verdict."""

from __future__ import annotations

from itertools import groupby, islice

from nmtcheck.reporters import boot_report, lss_report
from nmtcheck.reporters.common import (
    capture_start,
    captures_note,
    config_line,
    configured_vs_measured,
    duration,
    error_line,
    final_state,
    master_line,
    measured_mark,
    moment,
    network_notes,
    not_logs_line,
    omitted_lines,
    reboot_note,
    reboots,
    utc_start,
    verdict_line,
    where_label,
)
from nmtcheck.results import Finding, InputResult
from nmtcheck.safe_text import escape_lines

MAX_EVENTS_SHOWN = 50
REPEATS_SHOWN = 3  # findings of one rule on one node listed before the rest is rolled up



def _input_line(res: InputResult) -> list[str]:
    s = res.stats
    span = ("(no timestamps: order only, times below are frame numbers)" if s.order_only
            else f"over {duration(res):.3f} s{captures_note(res)}")
    started = utc_start(res)
    lines = [f"{s.path} ({s.format}): {s.frames} frames {span} on "
             f"{len(s.channels)} channel(s) {', '.join(s.channels)}"
             + (f", recording started {started}" if started else "")]
    counts = [f"skipped records: {s.skipped}"
              + (f" (first at line {', '.join(map(str, s.skipped_lines[:5]))})"
                 if s.skipped_lines else ""),
              f"extended frames: {s.extended}", f"error frames: {s.error_frames}",
              f"remote frames: {s.remote_frames}", f"CAN FD frames: {s.fd_frames}",
              f"non-frame records: {s.ignored}", f"{s.drop_record} dropped: "
              f"{s.dropped}"]
    if s.backwards_timestamps:
        counts.append(f"timestamps going backwards: {s.backwards_timestamps}")
    if s.truncated:
        counts.append("TRUNCATED: the input ends early, read up to the damage")
    lines.append("  " + ", ".join(counts))
    if (left_out := s.left_out_text()) is not None:  # an edit made on purpose: no finding
        lines.append(f"  {left_out}")
    return lines


def _ms(x: float | None) -> str:
    return "-" if x is None else f"{x:g}"


def _node_table(res: InputResult) -> list[str]:
    """Per node: final state, error control, configured vs measured heartbeat timing."""
    nodes = res.nodes()
    if not nodes:
        return []
    rows = [("node", "final state", "control", "boot-ups", "1017h ms", "median ms", "jitter ms",
             "consumer ms", "worst gap ms")]
    for m in nodes:
        c = configured_vs_measured(m, res.model.end_of(m.channel))
        consumer = _ms(c.consumer_ms) + (f" (node {c.consumer_node})"
                                         if c.consumer_node is not None else "")
        rebooting = any(r.interval == len(m.intervals) - 1 for r in reboots(m))
        rows.append((f"{m.channel}/{m.node}", final_state(m) + (" (rebooting)" if rebooting
                                                                else ""), m.error_control,
                     str(m.bootup_count), _ms(c.producer_ms), _ms(c.median_ms),
                     _ms(c.jitter_ms), consumer, _ms(c.worst_gap_ms)))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return ["  " + "  ".join(cell.ljust(w) for cell, w in zip(r, widths, strict=True)).rstrip()
            for r in rows] + [f"  {m.channel}/{m.node} {reboot_note(res, m, r)}"
                              for m in nodes for r in reboots(m)]


def _node_events(res: InputResult) -> list[str]:
    """EMCYs, SDO aborts and configuration written in the trace: context, not findings."""
    out = [f"    {_when(res, e.ts)}  line {e.line or '-':<7} {m.channel} node {m.node}: "
           f"{e.text}" for m, e in islice(res.model.events(), MAX_EVENTS_SHOWN)]
    total = res.model.event_count()
    if total > MAX_EVENTS_SHOWN:
        out.append(f"    … {total - MAX_EVENTS_SHOWN} more (see --format json)")
    return ["  node events (not findings):", *out] if out else []


def _when(res: InputResult, t: float, f: Finding | None = None) -> str:
    """A finding's or event's time in the report's column: `  1.560400 s`, or `frame 3`
    (right-aligned alike) in an input without timestamps."""
    return f"{moment(res, t, unit='', f=f):>10}" + ("" if res.stats.order_only else " s")


def _finding_line(res: InputResult, f: Finding) -> str:
    where = f"line {f.line}" if f.line else f"frame {f.frame_index}"
    return (f"    {_when(res, f.time, f)}  {where:<12} {f.severity:<7} "
            f"{f.rule} {f.name}: {f.message}{measured_mark(f)}")


def _findings(res: InputResult) -> list[str]:
    """Findings grouped by channel and node (the input's own first), each group headed by
    the file's path so a grep across many reports finds it; from the fourth finding of one
    rule on one node on, a single line counts the rest (--format concise lists them all)."""
    out: list[str] = []

    def key(f: Finding) -> tuple[int, str, int]:
        return (0 if f.channel is None else 1, f.channel or "", -1 if f.node is None else f.node)

    for _key, grouped in groupby(sorted(res.findings, key=key), key=key):
        group = list(grouped)
        out.append(f"  {res.stats.path} {where_label(group[0].channel, group[0].node)}:")
        by_rule: dict[str, list[Finding]] = {}
        rank: list[int] = []  # each finding's position among its rule's (linear, not k^2)
        for f in group:
            same = by_rule.setdefault(f.rule, [])
            rank.append(len(same))
            same.append(f)
        for f, k in zip(group, rank, strict=True):
            same = by_rule[f.rule]
            if k < REPEATS_SHOWN or len(same) == REPEATS_SHOWN + 1:
                out.append(_finding_line(res, f))
                out += boot_report.cause_lines(f, capture_start(res, f))
            elif k == REPEATS_SHOWN:
                last = same[-1]
                where = f"line {last.line}" if last.line else f"frame {last.frame_index}"
                out.append(f"    … {len(same) - REPEATS_SHOWN} more {f.rule} {f.name} "
                           f"({f.severity}) up to {moment(res, last.time, f=last)}, {where} "
                           "(--format concise lists every one)")
    return out


def render(results: list[InputResult], options: dict[str, object]) -> str:
    quiet = bool(options.get("quiet", False))
    out: list[str] = []
    config = config_line(options)
    if config and not quiet:
        out.append(config)
    notes = network_notes(options)
    if notes and not quiet:
        out.append("network description: values that could not be read:")
        out += [f"  {n}" for n in notes]
    skipped_files = not_logs_line(options, names=not quiet)
    if skipped_files:  # -q too: how many files a directory's gate did not look at
        out.append(skipped_files)
    for res in results:
        if res.error is not None:  # named, and the others are still checked (SPEC §4)
            out += [error_line(res), ""]
            continue
        if quiet:  # -q: only the findings (headed by their file and node) and the verdict
            found = _findings(res) + [f"  … {line}" for line in omitted_lines([res], options)]
            out += [*found, ""] if found else []
            continue
        out += _input_line(res)
        if res.not_evaluated:
            out.append("  not evaluated: " + "; ".join(
                f"{code} ({why})" for code, why in res.not_evaluated.items()))
        if res.partly_evaluated:
            out.append("  partly evaluated: " + "; ".join(
                f"{code}: {why}" for code, why in res.partly_evaluated.items()))
        out += [f"  {master_line(cm)}" for cm in res.model.channels]
        out += _node_table(res)
        out += _node_events(res)
        out += _findings(res)
        out += [f"  … {line}" for line in omitted_lines([res], options)]
        out += boot_report.text_lines(res)
        out += lss_report.text_lines(res)
        out.append("")
    out.append(verdict_line(results, options))
    return escape_lines(out) + "\n"  # a name's newline or ESC is shown, never sent
