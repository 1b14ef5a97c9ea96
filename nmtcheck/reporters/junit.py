"""JUnit XML for CI dashboards (Jenkins, GitLab): what was checked, and what failed.

One `<testsuite>` per input and one `<testcase>` per (rule x node), passing ones
included, so a dashboard lists every check that ran; the input rules (I) get one
case each with classname `input`. A test case fails when it
has a finding at or above `--fail-on`, exactly as the exit code does; findings
below it are kept in the passing case's `<system-out>`. A rule that could not be
evaluated (no network file for N001, no producer time for H003, no timestamps for the
timing rules…) is a skipped case with the reason, never a pass; an input that could not
be read is a suite with one failed case naming why. Each suite's `verdict` property is
the run's: PASS, FAIL or NOT GATED, and a pass over an input checked in order only (no
timestamps) says so: `PASS (order only: timing not checked)`.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

from nmtcheck import __version__
from nmtcheck.checks.base import Rule, is_failing_severity
from nmtcheck.explain.evaluated import NODE_REASONS, node_reason
from nmtcheck.reporters.common import (
    checked_rules,
    duration,
    error_line,
    fail_on,
    moment,
    node_label,
    nodes_by_channel,
    verdict_word,
    xml_safe,
)
from nmtcheck.results import Finding, InputResult


def _finding_text(res: InputResult, f: Finding) -> str:
    where = f"line {f.line}" if f.line else f"frame {f.frame_index}"
    return (f"{f.severity} {f.rule} {f.name} at {moment(res, f.time, f=f)} "
            f"({res.stats.path} {where}): {f.message}")


def _classname(channel: str | None, node: int | None) -> str:
    """Jenkins reads dots as package.class: channel, then node (zero-padded so it sorts);
    `input` for the rules about the input itself."""
    if channel is None:
        return "input"
    return f"{channel}." + ("network" if node is None else f"node{node:03d}")


def _unreadable_suite(res: InputResult, verdict: str) -> ET.Element:
    """An input that could not be read: one failed test case naming why (SPEC §4)."""
    suite = ET.Element("testsuite", name=res.stats.path, tests="1", failures="1", errors="0",
                       skipped="0")
    props = ET.SubElement(suite, "properties")
    ET.SubElement(props, "property", name="verdict", value=verdict)
    case = ET.SubElement(suite, "testcase", classname="input", name="input can be read",
                         file=res.stats.path)
    ET.SubElement(case, "failure", type="input-error",
                  message=f"cannot be checked: {res.error}").text = error_line(res)
    return suite


def _skip_reason(res: InputResult, rule: Rule, channel: str | None, node: int | None
                 ) -> str | None:
    """Why a test case's rule could not be evaluated (on the input, or for this node)."""
    reason = res.not_evaluated.get(rule.code)
    if reason is None and node is not None and rule.code in NODE_REASONS:
        m = next((m for m in res.nodes() if m.channel == channel and m.node == node), None)
        reason = None if m is None else node_reason(rule.code, m)
    return reason


def _suite(res: InputResult, options: dict[str, object], verdict: str) -> ET.Element:
    threshold = fail_on(options)
    rules = checked_rules(options)
    by_case: dict[tuple[str | None, int | None, str], list[Finding]] = {}
    for f in res.findings:
        by_case.setdefault((f.channel, f.node, f.rule), []).append(f)
    s = res.stats
    suite = ET.Element("testsuite", name=s.path)
    props = ET.SubElement(suite, "properties")
    for key, value in (("format", s.format), ("frames", s.frames),
                       # (no timestamps: a span of frame numbers is no duration)
                       ("duration_s", "" if s.order_only else f"{duration(res):.6f}"),
                       ("skipped_records", s.skipped),
                       ("error_frames", s.error_frames), ("channels", ",".join(s.channels)),
                       ("fail_on", threshold), ("verdict", verdict)):
        ET.SubElement(props, "property", name=key, value=str(value))
    if s.order_only:  # no timestamps: the timing rules are skipped cases below
        ET.SubElement(props, "property", name="order_only", value="true")
    for o in res.omitted:  # findings past --max-findings: counted, stated
        ET.SubElement(props, "property", name=f"omitted.{o.rule}", value=str(o.count))
    cases: list[tuple[str | None, int | None, Rule]] = [
        (None, None, rule) for rule, _severity in rules if rule.scope == "input"]
    for name, nodes in nodes_by_channel(res, always_network=True).items():
        for node in nodes:
            for rule, _severity in rules:
                if rule.scope == "input" or (not by_case.get((name, node, rule.code)) and (
                        rule.scope == "network" if node is not None
                        else rule.scope == "node")):
                    continue  # a rule is checked for the network, or per node, or both
                cases.append((name, node, rule))
    tests = failures = skipped = 0
    for channel, node, rule in cases:
        found = by_case.get((channel, node, rule.code), [])
        case = ET.SubElement(suite, "testcase", classname=_classname(channel, node),
                             name=f"{rule.code} {rule.name}", file=s.path)
        tests += 1
        reason = None if found else _skip_reason(res, rule, channel, node)
        if reason is not None:  # could not run: not a pass (SPEC §7 not_evaluated)
            skipped += 1
            ET.SubElement(case, "skipped", message=f"not evaluated: {reason}")
            continue
        failing = [f for f in found if is_failing_severity(f.severity, threshold)]
        if failing:
            failures += 1
            first = failing[0]
            if first.line:
                case.set("line", str(first.line))
            message = first.message + (f" (and {len(failing) - 1} more)"
                                       if len(failing) > 1 else "")
            label = "input" if channel is None else node_label(node)
            failure = ET.SubElement(case, "failure", type=rule.code,
                                    message=f"{label}: {message}")
            failure.text = "\n".join(_finding_text(res, f) for f in failing)
        rest = [f for f in found if f not in failing]
        if rest:
            ET.SubElement(case, "system-out").text = "\n".join(
                _finding_text(res, f) for f in rest)
    for key, value in (("tests", tests), ("failures", failures), ("errors", 0),
                       ("skipped", skipped)):
        suite.set(key, str(value))
    return suite


def render(results: list[InputResult], options: dict[str, object]) -> str:
    root = ET.Element("testsuites", name=f"nmtcheck {__version__}")
    word = verdict_word(results, options)
    suites = [_unreadable_suite(res, word) if res.error is not None
              else _suite(res, options, word) for res in results]
    for key in ("tests", "failures", "errors", "skipped"):
        root.set(key, str(sum(int(s.get(key, "0")) for s in suites)))
    root.extend(suites)
    for el in root.iter():  # any byte of a channel or file name: still well-formed XML
        el.text = None if el.text is None else xml_safe(el.text)
        for key, value in el.attrib.items():
            el.set(key, xml_safe(value))
    ET.indent(root, space="  ")
    return ('<?xml version="1.0" encoding="UTF-8"?>\n'
            + ET.tostring(root, encoding="unicode") + "\n")
