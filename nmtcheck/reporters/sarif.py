"""SARIF 2.1.0 for code-scanning tools: one result per finding, the log file as the artifact.

Text logs (candump, ASC) point each result at the frame's line, so GitHub code
scanning and IDE SARIF viewers open the log at the spot. Rules carry their full
documentation as help text.
"""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from pathlib import PurePath
from typing import Any

from nmtcheck import __version__
from nmtcheck.checks.base import Rule
from nmtcheck.reporters.common import checked_rules, offset
from nmtcheck.results import InputResult
from nmtcheck.safe_text import dumps_finite

SCHEMA_URI = "https://json.schemastore.org/sarif-2.1.0.json"
LEVELS = {"error": "error", "warning": "warning", "info": "note"}
SRCROOT = "%SRCROOT%"
PIECE_CHARS = 1 << 20  # the results are written in pieces of about this many characters


def artifact_location(path: str) -> dict[str, Any]:
    """Relative paths stay relative to the checkout (code scanning needs that); absolute
    ones become file URIs."""
    p = PurePath(path)
    if p.is_absolute():
        return {"uri": p.as_uri()}
    return {"uri": p.as_posix(), "uriBaseId": SRCROOT}


def rule_descriptor(rule: Rule, severity: str) -> dict[str, Any]:
    return {
        "id": rule.code,
        "name": rule.name,
        "shortDescription": {"text": rule.summary},
        "fullDescription": {"text": rule.doc},
        "help": {"text": rule.doc, "markdown": rule.doc},
        "defaultConfiguration": {"level": LEVELS[severity]},
        "properties": {"tags": ["canopen", "nmt", "cia301"], "nmtcheckSeverity": severity},
    }


def sarif_log(results: list[InputResult], options: dict[str, object]) -> dict[str, Any]:
    """The whole log as one dict (its results a list)."""
    log = _skeleton(results, options)
    log["runs"][0]["results"] = list(_results(results, options))
    return log


def _skeleton(results: list[InputResult], options: dict[str, object]) -> dict[str, Any]:
    """The log without its results (`None` in their place)."""
    rules = checked_rules(options)
    descriptors = [rule_descriptor(r, s) for r, s in rules]
    artifacts = []
    for res in results:
        s = res.stats
        artifacts.append({
            "location": artifact_location(s.path),
            "roles": ["analysisTarget"],
            "properties": {"format": s.format, "frames": s.frames, "skipped": s.skipped,
                           "errorFrames": s.error_frames, "channels": s.channels,
                           "start": s.start, "end": s.end,
                           "omitted": {o.rule: o.count for o in res.omitted}},
        })
    return {
        "$schema": SCHEMA_URI,
        "version": "2.1.0",
        "runs": [{
            "tool": {"driver": {"name": "nmtcheck", "version": __version__,
                                "semanticVersion": __version__, "rules": descriptors}},
            "originalUriBaseIds": {SRCROOT: {"description": {
                "text": "The directory nmtcheck was run from."}}},
            "artifacts": artifacts,
            "results": None,
            # inputs that could not be read: the run did not analyse them (SPEC §4)
            "invocations": [{
                "executionSuccessful": not any(res.error for res in results),
                "toolExecutionNotifications": [
                    {"level": "error", "message": {"text": f"cannot be checked: {res.error}"},
                     "locations": [{"physicalLocation": {
                         "artifactLocation": {**artifact_location(res.stats.path),
                                              "index": res.index}}}]}
                    for res in results if res.error is not None]}],
            "columnKind": "unicodeCodePoints",
        }],
    }


def _results(results: list[InputResult], options: dict[str, object]
             ) -> Iterator[dict[str, Any]]:
    """One SARIF result per finding, in order."""
    rule_index = {r.code: i for i, (r, _s) in enumerate(checked_rules(options))}
    for res in results:
        for f in res.findings:
            physical: dict[str, Any] = {
                "artifactLocation": {**artifact_location(res.stats.path), "index": res.index}}
            if f.line:
                physical["region"] = {"startLine": f.line}
            location: dict[str, Any] = {"physicalLocation": physical}
            if f.channel is not None:  # I-rules: the log file itself is the location
                location["logicalLocations"] = [{
                    "name": "network" if f.node is None else f"node {f.node}",
                    "fullyQualifiedName": f"{f.channel}/"
                                          + ("network" if f.node is None else f"{f.node}"),
                    "kind": "module",
                }]
            result: dict[str, Any] = {
                "ruleId": f.rule,
                "level": LEVELS[f.severity],
                "message": {"text": f.message},
                "locations": [location],
                "properties": {"channel": f.channel, "node": f.node, "time": f.time,
                               "offsetSeconds": round(offset(res, f.time), 6),
                               "frameIndex": f.frame_index, "severity": f.severity},
            }
            if f.rule in rule_index:
                result["ruleIndex"] = rule_index[f.rule]
            yield result


def render(results: list[InputResult], options: dict[str, object]) -> str:
    return "".join(stream(results, options))


def stream(results: list[InputResult], options: dict[str, object]) -> Iterator[str]:
    """The log in pieces, result by result, as `json.dumps(log, indent=2)` writes it: the
    findings are never all held as dicts and text at once (120 k findings took 1.27 GB
    as one document)."""
    log = _skeleton(results, options)
    mark = f"nmtcheck-results-{uuid.uuid4().hex}"
    log["runs"][0]["results"] = mark
    head, tail = dumps_finite(log, indent=2).split(f'"{mark}"', 1)
    yield head + "["
    first = True
    held: list[str] = []
    size = 0
    for result in _results(results, options):
        # a result sits at depth 4 (root, runs, the run, results): 8 more spaces a line
        text = dumps_finite(result, indent=2).replace("\n", "\n        ")
        held.append(("\n        " if first else ",\n        ") + text)
        first = False
        size += len(held[-1])
        if size >= PIECE_CHARS:
            yield "".join(held)
            held, size = [], 0
    if held:
        yield "".join(held)
    yield ("]" if first else "\n      ]") + tail + "\n"
