"""The `lss_bit_timing` chain link (SPEC §9.3.4) and the causes of the L findings.

An LSS "activate bit timing" (15h) request switches every slave in configuration state to
the bit rate configured before, after the switch delay: a slave that left the master's
bit rate falls silent, its heartbeat stops and its LSS answers never come. So an entry of
kind `lss_bit_timing` explains a silence, error frames and the timeouts H001, Y001, D001,
D003 (a)/(e), D004, L001 and L006 whose effect began within `causes_before_ms` after such
a request (D001 and D003 through `explain/pdo_links.py`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from nmtcheck.explain.entries import cause_entry
from nmtcheck.processes import lss as lss_stage
from nmtcheck.protocol.nmt import EPS

if TYPE_CHECKING:
    from nmtcheck.results import Finding

LINKED = ("H001", "Y001", "D001", "D003", "D004", "L001", "L006")  # the findings the link explains
ROOTS = ("L001", "L006")  # the L findings that carry causes (SPEC §9.3.5)


def bit_timing_entries(model: Any, channel: str | None, te: float, before: float
                       ) -> list[dict[str, Any]]:
    """Each activate-bit-timing request on the channel in [t_e - before, t_e]."""
    analysis = lss_stage.of(model)
    lc = analysis.channels.get(str(channel)) if analysis is not None else None
    if lc is None:
        return []
    out = []
    for ex in lc.exchanges:
        q = ex.request
        if ex.cs != lss_stage.ACTIVATE_BIT_TIMING or not te - before - EPS <= q.ts <= te + EPS:
            continue
        delay = ex.argument or 0
        out.append(cause_entry(
            "lss_bit_timing", q.ts, q.idx, q.line,
            f"LSS activate bit timing, switch delay {delay} ms: the slaves in configuration "
            "state may have left for another bit rate", link="lss_bit_timing"))
    return out


def lss_entries(model: Any, f: Finding, before: float
                ) -> tuple[list[dict[str, Any]], float] | None:
    """An L001 or L006 finding's causes (§9.3.2: t_e is the unanswered request, or the
    trigger of L006): the activate-bit-timing requests before t_e."""
    analysis = lss_stage.of(model)
    if analysis is None:
        return None
    found = analysis.effects.get((str(f.channel), f.rule, round(f.time, 9)))
    if found is None:
        return None
    _a0, te = found
    return bit_timing_entries(model, f.channel, te, before), te
