"""A Markdown summary for `$GITHUB_STEP_SUMMARY` or a merge-request comment.

Short on purpose: the verdict, one line per input, the findings grouped per
rule and node (with a count), and the nodes folded away in `<details>`.
"""

from __future__ import annotations

from nmtcheck.reporters.common import (
    captures_note,
    counts_phrase,
    duration,
    error_line,
    fail_on,
    final_state,
    group_findings,
    heartbeat_stats,
    measured_mark,
    moment,
    omitted_lines,
    resets,
    unreadable,
    verdict_class,
    verdict_word,
    where_label,
)
from nmtcheck.results import InputResult, summary
from nmtcheck.safe_text import escape_controls

# by `verdict_class`: a pass over a log checked in order only is no green tick
BADGES = {"pass": "✅", "fail": "❌", "not-gated": "⚪", "pass order-only": "⚠️"}
MAX_GROUPS = 50  # a comment people read, not the full report: the rest is counted


def cell(text: object) -> str:
    """Table cell text: a pipe or a newline would break the row, `<` could start HTML;
    control characters are shown as in the text report (`\\xNN`)."""
    return (escape_controls(text).replace("\\", "\\\\").replace("|", "\\|").replace("<", "&lt;")
            .replace("\r", " ").replace("\n", " "))


def _ms(seconds: float | None) -> str:
    return "–" if seconds is None else f"{seconds * 1000:.1f}"


def render(results: list[InputResult], options: dict[str, object]) -> str:
    threshold = fail_on(options)
    word = verdict_word(results, options)
    counts = summary(results)
    out = [f"## nmtcheck: {BADGES[verdict_class(results, options)]} {word}", "",
           f"**{counts_phrase(counts)}** (`--fail-on {threshold}`)", "",
           *[f"**{cell(error_line(res))}**\n" for res in unreadable(results)],
           "| input | format | frames | duration | skipped records | error frames | findings |",
           "|---|---|---:|---:|---:|---:|---:|"]
    for res in results:
        s = res.stats
        if res.error is not None:
            out.append(f"| `{cell(s.path)}` | – | – | – | – | – | cannot be checked: "
                       f"{cell(res.error)} |")
            continue
        span = ("no timestamps: order only" if s.order_only
                else f"{duration(res):.3f} s" + captures_note(res, short=True))
        out.append(f"| `{cell(s.path)}` | {s.format} | {s.frames} | {span} | "
                   f"{s.skipped} | {s.error_frames} | {len(res.findings)} |")
    groups = [g for res in results for g in group_findings(res.findings)]
    out += ["", "### Findings", ""]
    if not groups:
        out.append("No findings.")
    else:
        several = len(results) > 1
        out += ["| severity | rule | " + ("input | " if several else "")
                + "where | first at | line | count | message |",
                "|---|---|" + ("---|" if several else "") + "---|---:|---:|---:|---|"]
        for g in groups[:MAX_GROUPS]:
            res = results[g.input]
            f = g.first
            out.append(f"| {g.severity} | {g.rule} {g.name} | "
                       + (f"`{cell(res.stats.path)}` | " if several else "")
                       + f"{cell(where_label(g.channel, g.node))} | "
                       f"{moment(res, f.time, 3, f=f)} | {f.line or '–'} | {g.count} | "
                       f"{cell(f.message + measured_mark(f))} |")
        if len(groups) > MAX_GROUPS:
            rest = sum(g.count for g in groups[MAX_GROUPS:])
            out += ["", f"… and {rest} more finding(s) in {len(groups) - MAX_GROUPS} more "
                        "group(s): see the full report."]
    out += [f"\n{cell(line)}" for line in omitted_lines(results, options)]
    out += ["", "<details><summary>Nodes</summary>", "",
            "| input | channel | node | error control | heartbeat median (ms) | min | max "
            "| boot-ups | resets | final state |",
            "|---|---|---:|---|---:|---:|---:|---:|---:|---|"]
    for res in results:
        for m in res.nodes():
            hb = heartbeat_stats(m)
            out.append(f"| `{cell(res.stats.path)}` | {cell(m.channel)} | {m.node} | "
                       f"{m.error_control} | {_ms(hb.median)} | {_ms(hb.minimum)} | "
                       f"{_ms(hb.maximum)} | {m.bootup_count} | {resets(m)} | "
                       f"{final_state(m)} |")
    out += ["", "</details>", ""]
    return "\n".join(out)
