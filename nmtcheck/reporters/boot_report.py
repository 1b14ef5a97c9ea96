"""The boot report's pieces for every output (SPEC §8.5, §8.6): what JSON, text and HTML
add for the boot process and the cause chains, in one place so the reporters stay small."""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from nmtcheck.processes.boot_records import NodeBootReport
    from nmtcheck.results import Finding, InputResult

CAUSE_RULES = ("H001", "G002", "B001", "B002", "S004")


def node_boot(res: InputResult, channel: str, node: int) -> dict[str, Any] | None:
    """`nodes[i].boot`: the node's boot status on a channel where the group ran, else None."""
    b = res.boot
    if b is None:
        return None
    cb = b.channels.get(channel)
    rep = b.nodes.get((channel, node))
    if cb is None or not cb.ran:
        return None
    if rep is None:  # the master, or a node the manager never probed
        return {"status": "not-managed", "letter": None, "letter_source": None,
                "reason": None, "assignment": None, "processes": 0, "process": None}
    return rep.as_dict()


def channel_boot(res: InputResult, channel: str) -> dict[str, Any] | None:
    """`channels[i].boot`."""
    b = res.boot
    cb = b.channels.get(channel) if b is not None else None
    return None if cb is None else cb.as_dict()


def finding_fields(f: Finding) -> dict[str, Any]:
    """The SPEC §8 fields of one finding: only those that apply to its rule."""
    out: dict[str, Any] = {}
    if f.rule.startswith("P"):
        out["boot_letter"] = f.boot_letter
        out["evidence"] = f.evidence
    if f.causes is not None:
        out["causes"] = f.causes
        out["causes_omitted"] = f.causes_omitted or 0
        out["reactions"] = f.reactions or []
        out["reactions_omitted"] = f.reactions_omitted or 0
    return out


def cause_lines(f: Finding, start: float) -> Iterator[str]:
    """Text: one indented line per cause under the finding, then one `after:` line per
    reaction with its role (SPEC §9.3.6), times as the finding shows them (seconds from the
    recording's first frame, `start`)."""
    for c in f.causes or ():  # a chain's deeper causes indented two more each (§9.3.6)
        link = c.get("link")
        yield ("        " + "  " * (int(c.get("depth") or 1) - 1) + "cause: "
               + entry_text(c, start)
               + (f"  [{link.replace('_', ' ')}]" if link and link != "window" else ""))
    if f.causes_omitted:
        yield f"        cause: ... {f.causes_omitted} more"
    for c in f.reactions or ():
        yield "        after: " + entry_text(c, start) + f"  [{c['role']}]"
    if f.reactions_omitted:
        yield f"        after: ... {f.reactions_omitted} more"


def entry_text(c: dict[str, Any], start: float) -> str:
    """A cause or reaction as one line of text: its time or span, text, node and line."""
    where = []
    if c.get("node") is not None:
        where.append(f"node {c['node']}")
    if c.get("line"):
        where.append(f"line {c['line']}")
    span = f"{c['time'] - start:.6f}" + (
        f"-{c['end'] - start:.6f}" if c.get("end") is not None else "")
    return f"{span} s {c['text']}" + (f" ({', '.join(where)})" if where else "")


def failure_finding(rep: NodeBootReport, findings: list[Finding]) -> Finding | None:
    """The P finding that failed a node's boot: the table's row shows its message, time
    and line, so that table and finding never disagree on when it failed."""
    return next((f for f in findings if f.rule.startswith("P") and f.node == rep.node
                 and f.channel == rep.channel), None)


def _detail(rep: NodeBootReport, findings: list[Finding]) -> str:
    x = rep.process
    if rep.status == "ok" and rep.letter == "L":
        return "already OPERATIONAL: manager sends no start"
    if rep.status == "ok" and x is not None and x.started_at is not None:
        delta = (x.started_at.time - x.start) * 1000.0
        anchor = {"bootup": "boot-up", "reset": "reset", "master-bootup": "the manager's boot-up"}
        return f"started {delta:g} ms after {anchor[x.anchor]} ({x.transfers} SDO)"
    if rep.status == "failed":
        mine = failure_finding(rep, findings)
        if mine is not None:
            return mine.message
        return rep.reason or ""
    if rep.status == "incomplete" and x is not None:
        from nmtcheck.processes.boot import describe_step

        last = next((s for s in reversed(x.steps) if s.row >= 0), None)
        what = describe_step(last) if last is not None else "its anchor"
        return f"stopped after {what}; candidates {rep.candidates or 'no start'}"
    return ""


def text_lines(res: InputResult) -> Iterator[str]:
    """Text: the boot section (one line per node) of one input, nothing if the group never
    ran; times as the findings show them (seconds from the recording's first frame)."""
    b = res.boot
    if b is None or not any(cb.ran for cb in b.channels.values()):
        return
    start = res.stats.start or 0.0
    for name, cb in b.channels.items():
        yield f"  boot-slave processes (CiA 302-2), {name}: {cb.heading()}"
        if not cb.ran:
            continue
        for (channel, node), rep in sorted(b.nodes.items()):
            if channel != name:
                continue
            x = rep.process
            w = x.evidence if x is not None else None
            when = (f"{w.time - start:.6f} s (line {w.line})" if w is not None and w.line
                    else f"{w.time - start:.6f} s" if w is not None else "")
            failed = failure_finding(rep, res.findings) if rep.status == "failed" else None
            if failed is not None:  # when the finding says it failed (P004: C_N expired)
                when = f"{failed.time - start:.6f} s" + (
                    f" (line {failed.line})" if failed.line else "")
            if rep.status == "incomplete":
                when = f"{res.model.end_of(channel) - start:.6f} s"
            letter = rep.letter or "-"
            status = "FAILED" if rep.status == "failed" else rep.status
            detail = _detail(rep, res.findings)
            yield (f"    {channel} node {node}  {status:<11} {letter}  {when}  {detail}"
                   .rstrip())
