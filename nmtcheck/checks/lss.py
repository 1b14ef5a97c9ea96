"""LSS rules L001-L007 (SPEC §9.2.4): the LSS reconstruction of `nmtcheck/processes/lss.py`
judged. They judge frames, not a node's state: exempt from the UNKNOWN rule. A finding's
node is byte 1 of a configure-node-ID request when it is 1-127, else none (SPEC §9.2.0).
"""

from __future__ import annotations

from collections.abc import Iterator

from nmtcheck.checks.base import Param, Params, Problem, input_rule
from nmtcheck.processes import lss
from nmtcheck.processes.lss import Exchange, LssChannel
from nmtcheck.timeline.model import InputModel
from nmtcheck.timeline.moments import at

EPS = 1e-9
# L001: confirmed requests, judged while some slave is in configuration state
CONFIRMED = (lss.CONFIGURE_NODE_ID, lss.CONFIGURE_BIT_TIMING, lss.STORE,
             0x5A, 0x5B, 0x5C, 0x5D, lss.INQUIRE_NODE_ID)
# L004: requests only a slave in configuration state acts on
CONFIGURATION_ONLY = (*CONFIRMED, lss.ACTIVATE_BIT_TIMING)
# L005: requests one slave answers (4Fh and 50h answers come from every slave that matches)
ONE_ANSWER = (*CONFIRMED, lss.SELECTIVE_SERIAL)


def _channels(model: InputModel) -> Iterator[LssChannel]:
    analysis = lss.of(model)
    if analysis is not None:
        yield from analysis.channels.values()


def _at(model: InputModel, lc: LssChannel, t: float) -> str:
    start = next((cm.start for cm in model.channels if cm.name == lc.channel), model.start)
    return at(t, start, model.timeline.order_only)


def _effect(model: InputModel, lc: LssChannel, rule: str, t: float, a0: float, te: float
            ) -> None:
    """Keep a finding's a0 and t_e for its causes (explain/lss_link.py)."""
    analysis = lss.of(model)
    if analysis is not None:
        analysis.effect(lc.channel, rule, t, a0, te)


def _unanswered(model: InputModel, lc: LssChannel, ex: Exchange
                ) -> tuple[float, int | None, str] | None:
    """When a request's wait for an answer ended unanswered (SPEC §9.2.4 L001 "Time"):
    (the moment, the frame there when it is the next request, how it ended); None when
    the trace ends first."""
    due = ex.request.ts + lc.timeout_s
    nxt = ex.next_request
    if nxt is not None and nxt.ts <= due + EPS:
        return nxt.ts, nxt.idx, (f"; the next request followed at {_at(model, lc, nxt.ts)} "
                                 f"(line {nxt.line})")
    if model.timeline.order_only or lc.end < due - EPS:
        return None
    return due, None, ""


@input_rule("L001", "lss-no-response", "warning", exempt_from_unknown=True,
            scope="network+node")
def lss_no_response(model: InputModel, params: Params) -> Iterator[Problem]:
    """A confirmed LSS request gets no answer.

    **What it checks.** A request 11h (configure node-ID), 13h (configure bit timing),
    17h (store configuration) or 5Ah-5Eh (inquire) on 7E5h, sent while the channel's
    LSS slaves are in configuration state (after `04 01`, a selective switch answered by
    44h or a completed fastscan), that no 7E4h frame of its response cs answers before
    the next 7E5h frame or `[timeline] lss_response_timeout_ms` (1000 ms, CANopenNode's
    master default), the earlier. Never after `04 00` (L004 says so) or before any
    switch state is known (the trace start, an NMT reset), never for requests whose
    silence is their negative answer (selective switch, identify, fastscan), and not
    when the trace ends before the timeout. Without timestamps only the next request
    ends the wait.

    **Why it matters.** The master gives up on the slave: the node-ID or bit rate it
    meant to set is not set, or not stored, and the machine boots with the old one.
    CANopenNode slaves ignore a request whose DLC is not 8.

    **Example.** `7E5#0401...` at 10.000, `7E5#1105...` at 10.010, nothing on 7E4h
    until 12.000.
    """
    for lc in _channels(model):
        for ex in lc.exchanges:
            if ex.cs not in CONFIRMED or ex.cfg not in ("all", "some") or ex.responses:
                continue
            found = _unanswered(model, lc, ex)
            if found is None:
                continue
            t, idx, how = found
            limit = lc.timeout_s * 1000
            text = (f"no answer to {ex.service} ({ex.cs:02X}h) sent at "
                    f"{_at(model, lc, ex.request.ts)} (line {ex.request.line})"
                    + (f" within {limit:g} ms" if not model.timeline.order_only else "")
                    + how)
            if ex.request.dlc != 8:
                text += f"; the request has DLC {ex.request.dlc}: CANopenNode slaves ignore it"
            if ex.cs == lss.CONFIGURE_BIT_TIMING:
                text += "; CANopenNode slaves without bit-rate support stay silent"
            line = ex.next_request.line if idx is not None and ex.next_request else None
            _effect(model, lc, "L001", t, ex.request.ts, ex.request.ts)
            yield Problem(lc.channel, ex.node, t, text, idx, line, after=ex.request.idx)


@input_rule("L002", "lss-selective-no-match", "warning", exempt_from_unknown=True,
            scope="network")
def lss_selective_no_match(model: InputModel, params: Params) -> Iterator[Problem]:
    """No slave answers a selective switch.

    **What it checks.** A switch state selective serial number (43h), with vendor-ID
    (40h), product code (41h) and revision (42h) all sent since the last switch state
    request, that no 44h answers before the next 7E5h frame or
    `lss_response_timeout_ms`, the earlier. When the four were not sent in the order
    40h, 41h, 42h, 43h the message says so. A 43h without all three before it asked for
    no identity and is left alone.

    **Why it matters.** No slave of that identity is on the bus, or it is not in the
    waiting state: the configuration the master meant for it goes nowhere. Lely slaves
    reset their match on a wrong order; CANopenNode compares the four values at 43h.

    **Example.** 40h 00000300h, 41h 00004644h, 42h 0, 43h 1 and no `7E4#44`.
    """
    for lc in _channels(model):
        for ex in lc.exchanges:
            if ex.cs != lss.SELECTIVE_SERIAL or ex.responses or not all(
                    c in ex.sequence for c in (0x40, 0x41, 0x42)):
                continue
            found = _unanswered(model, lc, ex)
            if found is None:
                continue
            t, idx, how = found
            text = f"no slave answered selective switch {lss.identity_text(ex.identity)}"
            if ex.sequence != (0x40, 0x41, 0x42, 0x43):
                text += ("; requests out of order ("
                         + ", ".join(f"{c:02X}h" for c in ex.sequence) + ")")
            line = ex.next_request.line if idx is not None and ex.next_request else None
            yield Problem(lc.channel, None, t, text + how, idx, line, after=ex.request.idx)


@input_rule("L003", "lss-error-response", "error", exempt_from_unknown=True,
            scope="network+node")
def lss_error_response(model: InputModel, params: Params) -> Iterator[Problem]:
    """A slave answers configure node-ID, configure bit timing or store with an error.

    **What it checks.** A response 11h, 13h or 17h on 7E4h, paired with its request,
    whose status byte 1 is not 0: 1 (node-ID out of range, bit timing or store not
    supported), 2 (storage media access error), FFh (manufacturer-specific, byte 2 its
    code).

    **Why it matters.** The slave itself says the configuration did not happen: the
    node-ID or bit rate is not set, or will be lost at the next power cycle.

    **Example.** `7E5#1180...` (node-ID 128) answered `7E4#1101...`.
    """
    for lc in _channels(model):
        for ex in lc.exchanges:
            if ex.cs not in lss.STATUS_TEXT:
                continue
            for r in ex.responses:
                status, text = ex.response_text(r)
                if not status:
                    continue
                extra = f", manufacturer code {r.data[2]}" if status == 0xFF else ""
                yield Problem(lc.channel, ex.node, r.ts,
                              f"{ex.service}{ex.argument_text()}: slave answered {status} "
                              f"({text}){extra}", r.idx, r.line)


@input_rule("L004", "lss-not-in-configuration", "warning", exempt_from_unknown=True,
            scope="network+node")
def lss_not_in_configuration(model: InputModel, params: Params) -> Iterator[Problem]:
    """A configuration request after "switch to waiting", with no switch to configuration
    since.

    **What it checks.** A request 11h, 13h, 15h, 17h or 5Ah-5Eh sent after a switch
    state global waiting (`04 00`) with no `04 01`, answered selective switch or
    completed fastscan since. Not at the trace start or after an NMT reset, where the
    switch state is not known.

    **Why it matters.** Every slave is in the waiting state and ignores it: the master
    lost track of the LSS state, and the configuration it sends goes nowhere.

    **Example.** `7E5#0400...` then `7E5#1105...`.
    """
    for lc in _channels(model):
        for ex in lc.exchanges:
            if ex.cs not in CONFIGURATION_ONLY or ex.cfg != "none":
                continue
            w = ex.waiting_since
            since = (f" at {_at(model, lc, w.ts)} (line {w.line})" if w is not None else "")
            yield Problem(lc.channel, ex.node, ex.request.ts,
                          f'{ex.service} sent after switch state global "waiting"{since} '
                          "with no switch to configuration since: no slave can act on it",
                          ex.request.idx, ex.request.line)


@input_rule("L005", "lss-several-responders", "error", exempt_from_unknown=True,
            scope="network+node")
def lss_several_responders(model: InputModel, params: Params) -> Iterator[Problem]:
    """Several slaves answer one LSS request.

    **What it checks.** A request 11h, 13h, 17h, 43h or 5Ah-5Eh paired with more than one
    response frame. Identical answers sent at once merge into one frame on the bus, so
    only differing or separated answers are seen; the answers to identify and fastscan
    requests (4Fh, 50h) come from every matching slave by design and are left alone.

    **Why it matters.** More than one slave is in configuration state: a configure
    node-ID gives each the same node-ID, and the network then has a duplicate.

    **Example.** `7E5#5A...` answered by `7E4#5A00030000...` and `7E4#5A19000000...`.
    """
    for lc in _channels(model):
        for ex in lc.exchanges:
            if ex.cs not in ONE_ANSWER or len(ex.responses) < 2:
                continue
            second = ex.responses[1]
            values = _values(ex)
            text = (f"{len(ex.responses)} answers to {ex.service} at "
                    f"{_at(model, lc, ex.request.ts)} (line {ex.request.line}): more than "
                    f"one slave is in configuration state ({values})")
            if ex.cs == lss.CONFIGURE_NODE_ID and ex.node is not None:
                text += f"; each that answered 0 took node-ID {ex.node}"
            yield Problem(lc.channel, ex.node, second.ts, text, second.idx, second.line)


def _values(ex: Exchange) -> str:
    if 0x5A <= ex.cs <= 0x5D:
        name = lss.PART_NAMES[ex.cs - 0x5A] + "s"
        return f"{name} " + " and ".join(lss.hex32(r.u32()) for r in ex.responses)
    if ex.cs == lss.INQUIRE_NODE_ID:
        return "node-IDs " + " and ".join(f"{r.data[1]}" if r.data[1] != 0xFF else "FFh"
                                          for r in ex.responses)
    if ex.cs in lss.STATUS_TEXT:
        return "status " + " and ".join(str(r.data[1]) for r in ex.responses)
    return " and ".join(r.data.hex().upper() for r in ex.responses)


@input_rule("L006", "lss-node-id-not-adopted", "error",
            Param("bootup_timeout_ms", int, "how long after the reset (or the switch to "
                  "waiting of a non-configured slave) the boot-up under the new node-ID "
                  "may take (B001's default)", 5000),
            exempt_from_unknown=True, scope="node")
def lss_node_id_not_adopted(model: InputModel, params: Params) -> Iterator[Problem]:
    """No boot-up under the node-ID LSS configured.

    **What it checks.** After a configure node-ID N (1-127) answered once with status 0,
    a trigger: (a) an NMT reset node or reset communication, broadcast, or to the
    slave's active node-ID when an inquire node-ID (5Eh) answer gave one; or (b) a
    switch state global waiting (`04 00`) while the slave is known to be non-configured
    (5Eh answered FFh, or a 50h answer). No boot-up on 700h + N follows within
    `bootup_timeout_ms` of the trigger, and the trace goes on past that. Without a
    trigger a configured slave keeps its node-ID until its next reset, and the LSS
    report shows the node-ID as pending.

    **Why it matters.** The slave did not take the node-ID it acknowledged: it still
    runs under its old node-ID, or not at all, and the master's boot of the new node
    fails.

    **Example.** `5E` answered `FF`, `11 07` answered `00`, `04 00` at 10.005, and no
    `707#00` by 15.005.
    """
    wait = float(params["bootup_timeout_ms"]) / 1000.0
    for lc in _channels(model):
        for s in lc.slaves:
            for c in s.configured:
                if c.trigger is None:
                    continue
                t, idx, line, what = c.trigger
                due = t + wait
                if c.bootup is not None and c.bootup[0] <= due + EPS:
                    continue
                if lc.end < due - EPS:
                    continue
                ex = lc.exchanges[c.exchange]
                text = (f"no boot-up of node {c.node_id} within {wait * 1000:g} ms after "
                        f"{what} (line {line}); LSS configured node-ID {c.node_id} at "
                        f"{_at(model, lc, ex.request.ts)}")
                if what == "switch to waiting":
                    text += ("; a non-configured CANopenNode slave resets itself here, a "
                             "Lely slave waits for an NMT reset communication "
                             "(src/co/nmt.c 3353-3357)")
                _effect(model, lc, "L006", due, ex.request.ts, t)
                yield Problem(lc.channel, c.node_id, due, text, after=idx)


@input_rule("L007", "lss-fastscan", "info", exempt_from_unknown=True, scope="network")
def lss_fastscan(model: InputModel, params: Params) -> Iterator[Problem]:
    """A fastscan completed, found nothing, or was abandoned.

    **What it checks.** Each fastscan session (from a 51h request with BitChecked 80h to
    the next one, a `04 00`, an NMT reset or the trace end) once: complete (a 4Fh
    answers a request with BitChecked 0 and LSSNext below LSSSub), or incomplete and
    ended by a new fastscan reset, a `04 00` or an NMT reset, or incomplete with the
    trace going on at least `lss_response_timeout_ms` after its last frame. At the
    session's last frame.

    **Why it matters.** A fastscan is how a master finds slaves with no node-ID; the
    report says which identity it found, or that none answered, so a commissioning run
    can be read without decoding 7E4h/7E5h by hand.

    **Example.** A reset `7E5#51...80...` answered by `7E4#4F`, then one request per
    part with BitChecked 0, each answered.
    """
    for lc in _channels(model):
        for fs in lc.fastscans:
            last = fs.last or fs.start
            if not fs.complete and fs.ended_by == "end" and (
                    model.timeline.order_only or lc.end < last.ts + lc.timeout_s - EPS):
                continue
            n = fs.requests
            if fs.complete:
                text = f"fastscan found {lss.identity_text(fs.identity)} ({n} requests)"
            elif not fs.answered_reset:
                text = "fastscan: no non-configured slave answered the reset"
            else:
                known = [k for k, v in enumerate(fs.found) if v is not None]
                if known:
                    k = known[-1]
                    text = (f"fastscan abandoned after {lss.PART_NAMES[k]} = "
                            f"{lss.hex32(fs.found[k])} ({n} requests)")
                else:
                    text = f"fastscan abandoned before any part was found ({n} requests)"
            yield Problem(lc.channel, None, last.ts, text, last.idx, last.line)
