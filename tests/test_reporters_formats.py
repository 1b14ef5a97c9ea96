"""Each report format's contract: SARIF against its schema, JUnit against the shape CI
consumers load, GitHub escaping and `--format auto`, Markdown grouping, HTML size and
self-containment, and several outputs in one CLI run."""

from __future__ import annotations

import csv
import io
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import jsonschema
import pytest
from conftest import SAMPLES, Checker, candump, shared_file
from lxml import etree

from nmtcheck.checks import RULES
from nmtcheck.engine import check_input, select_rules
from nmtcheck.errors import UsageError
from nmtcheck.reporters import (
    auto_format,
    format_for_path,
    github,
    html,
    junit,
    markdown,
    renderer,
    sarif,
)
from nmtcheck.reporters.common import group_findings, heartbeat_stats
from nmtcheck.results import InputResult
from nmtcheck.settings.profiles import load_profile

SARIF_SCHEMA = "schemas/sarif-schema-2.1.0.json"  # ../shared/schemas, or its copy in tests/data
SAMPLE_NAMES = ["healthy", "heartbeat_loss", "pdo_preop", "guard_toggle", "ignored_command",
                "reset_no_bootup"]

# The JUnit shape Jenkins' and GitLab's importers read (after the Jenkins xunit
# junit-10 layout): testsuites > testsuite (name, counts) > properties?, testcase
# (classname, name) > failure|error|skipped|system-out.
JUNIT_XSD = """<?xml version="1.0" encoding="UTF-8"?>
<xs:schema xmlns:xs="http://www.w3.org/2001/XMLSchema" elementFormDefault="qualified">
  <xs:element name="testsuites">
    <xs:complexType>
      <xs:sequence><xs:element ref="testsuite" minOccurs="0" maxOccurs="unbounded"/></xs:sequence>
      <xs:attribute name="name" type="xs:string"/>
      <xs:attribute name="tests" type="xs:nonNegativeInteger"/>
      <xs:attribute name="failures" type="xs:nonNegativeInteger"/>
      <xs:attribute name="errors" type="xs:nonNegativeInteger"/>
      <xs:attribute name="skipped" type="xs:nonNegativeInteger"/>
    </xs:complexType>
  </xs:element>
  <xs:element name="testsuite">
    <xs:complexType>
      <xs:sequence>
        <xs:element name="properties" minOccurs="0">
          <xs:complexType><xs:sequence>
            <xs:element name="property" minOccurs="0" maxOccurs="unbounded">
              <xs:complexType>
                <xs:attribute name="name" type="xs:string" use="required"/>
                <xs:attribute name="value" type="xs:string" use="required"/>
              </xs:complexType>
            </xs:element>
          </xs:sequence></xs:complexType>
        </xs:element>
        <xs:element name="testcase" minOccurs="0" maxOccurs="unbounded">
          <xs:complexType>
            <xs:sequence>
              <xs:element name="skipped" minOccurs="0">
                <xs:complexType><xs:simpleContent><xs:extension base="xs:string">
                  <xs:attribute name="message" type="xs:string"/>
                </xs:extension></xs:simpleContent></xs:complexType>
              </xs:element>
              <xs:element name="failure" minOccurs="0" maxOccurs="unbounded">
                <xs:complexType><xs:simpleContent><xs:extension base="xs:string">
                  <xs:attribute name="type" type="xs:string"/>
                  <xs:attribute name="message" type="xs:string"/>
                </xs:extension></xs:simpleContent></xs:complexType>
              </xs:element>
              <xs:element name="system-out" type="xs:string" minOccurs="0"/>
            </xs:sequence>
            <xs:attribute name="name" type="xs:string" use="required"/>
            <xs:attribute name="classname" type="xs:string" use="required"/>
            <xs:attribute name="file" type="xs:string"/>
            <xs:attribute name="line" type="xs:positiveInteger"/>
          </xs:complexType>
        </xs:element>
      </xs:sequence>
      <xs:attribute name="name" type="xs:string" use="required"/>
      <xs:attribute name="tests" type="xs:nonNegativeInteger" use="required"/>
      <xs:attribute name="failures" type="xs:nonNegativeInteger"/>
      <xs:attribute name="errors" type="xs:nonNegativeInteger"/>
      <xs:attribute name="skipped" type="xs:nonNegativeInteger"/>
    </xs:complexType>
  </xs:element>
</xs:schema>
"""


def _results(*names: str) -> list[InputResult]:
    profile = load_profile("default")
    rules = select_rules(profile, [], [])
    return [check_input(str(SAMPLES / f"{n}.log"), i, profile, rules)
            for i, n in enumerate(names)]


ALL = _results(*SAMPLE_NAMES)
OPTIONS: dict[str, object] = {"fail_on": "error"}


def _repeated_timeouts(tmp_path: Path, gaps: int) -> InputResult:
    """Node 3 heartbeats every 100 ms and falls silent for 0.5 s `gaps` times: H001 x gaps."""
    lines, t = [(0.0, "703#00")], 0.0
    for _ in range(gaps):
        for _ in range(5):
            t += 0.1
            lines.append((t, "703#7F"))
        t += 0.5
        lines.append((t, "703#7F"))
    return Checker(tmp_path).run(candump(lines), select="H001")


# SARIF ---------------------------------------------------------------------------------

def test_sarif_is_valid_against_the_2_1_0_schema() -> None:
    schema = json.loads(shared_file(SARIF_SCHEMA).read_text(encoding="utf-8"))
    log = json.loads(sarif.render(ALL, OPTIONS))
    jsonschema.validate(log, schema, cls=jsonschema.Draft4Validator)
    run = log["runs"][0]
    findings = [f for res in ALL for f in res.findings]
    assert len(run["results"]) == len(findings) == 5
    assert [a["location"]["uri"] for a in run["artifacts"]] == [
        (SAMPLES / f"{n}.log").as_uri() for n in SAMPLE_NAMES]
    rules = run["tool"]["driver"]["rules"]
    assert [r["id"] for r in rules] == [r.code for r in RULES]
    for result, f in zip(run["results"], findings, strict=True):
        assert result["ruleId"] == f.rule and result["message"]["text"] == f.message
        assert rules[result["ruleIndex"]]["id"] == f.rule
        location = result["locations"][0]["physicalLocation"]
        assert location["region"] == {"startLine": f.line}
        assert run["artifacts"][location["artifactLocation"]["index"]]["location"]["uri"] == (
            location["artifactLocation"]["uri"])
    h001 = next(r for r in rules if r["id"] == "H001")
    assert "heartbeat event" in h001["help"]["text"]
    assert h001["defaultConfiguration"]["level"] == "error"


def test_sarif_is_written_result_by_result_as_one_document_would_be(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """120 k findings took 1.27 GB as one SARIF document (issue 39): the log is written in
    pieces, its results one after the other, and the text is `json.dumps(log, indent=2)`'s
    to the byte, with and without results."""
    from nmtcheck.reporters import streamer

    monkeypatch.setattr(sarif, "PIECE_CHARS", 200, raising=False)
    for results in (ALL, ALL[:1], [r for r in ALL if not r.findings][:1]):
        whole = json.dumps(sarif.sarif_log(results, OPTIONS), indent=2, allow_nan=False) + "\n"
        pieces = list(streamer("sarif")(results, OPTIONS))
        assert "".join(pieces) == whole == sarif.render(results, OPTIONS)
        findings = sum(len(r.findings) for r in results)
        assert len(pieces) >= findings + 1  # a piece at least per result past 200 chars


def test_sarif_levels_relative_paths_and_configured_severity(tmp_path: Path) -> None:
    res = _repeated_timeouts(tmp_path, 1)
    res.stats.path = "logs/field.log"
    log = sarif.sarif_log([res], {"rules": {"H001": "info"}})
    run = log["runs"][0]
    assert run["artifacts"][0]["location"] == {"uri": "logs/field.log", "uriBaseId": "%SRCROOT%"}
    assert [r["id"] for r in run["tool"]["driver"]["rules"]] == ["H001"]
    assert run["tool"]["driver"]["rules"][0]["defaultConfiguration"] == {"level": "note"}


# JUnit ---------------------------------------------------------------------------------

def test_junit_validates_and_lists_every_rule_for_every_node() -> None:
    root = etree.fromstring(junit.render(ALL, OPTIONS).encode())
    etree.XMLSchema(etree.fromstring(JUNIT_XSD.encode())).assertValid(root)
    suites = root.findall("testsuite")
    assert [s.get("name") for s in suites] == [str(SAMPLES / f"{n}.log") for n in SAMPLE_NAMES]
    node_rules = [r for r in RULES if r.scope in ("node", "network+node")]
    network_rules = [r for r in RULES if r.scope in ("network", "network+node")]
    input_rules = [r for r in RULES if r.scope == "input"]
    for res, suite in zip(ALL, suites, strict=True):
        cases = suite.findall("testcase")
        assert int(suite.get("tests")) == len(cases)
        assert int(suite.get("failures")) == len(suite.findall("testcase/failure"))
        # + the network's rules (C001, C002, the SYNC rules), + one case per input rule
        # (classname `input`)
        assert len(cases) == (len(res.nodes()) * len(node_rules) + len(network_rules)
                              + len(input_rules))
        names = {(c.get("classname"), c.get("name")) for c in cases}
        assert {("input", f"{r.code} {r.name}") for r in input_rules} <= names
        for m in res.nodes():
            assert (f"can0.node{m.node:03d}", "H001 heartbeat-timeout") in names
        assert ("can0.network", "C001 restricted-can-id") in names
    assert int(root.get("tests")) == sum(int(s.get("tests")) for s in suites)
    assert int(root.get("failures")) == 5
    failure = root.find(".//testcase[@classname='can0.node003'][@name='H001 heartbeat-timeout']"
                        "/failure")
    assert failure is not None and failure.get("type") == "H001"
    assert failure.get("message") == (
        "node 3: no heartbeat from node 3 for 1.101 s (timeout 0.150 s)")
    assert "line 77" in (failure.text or "")


def test_junit_failures_follow_fail_on(tmp_path: Path) -> None:
    res = _repeated_timeouts(tmp_path, 3)
    strict = etree.fromstring(junit.render([res], {"fail_on": "error"}).encode())
    case = strict.find(".//testcase[@name='H001 heartbeat-timeout']")
    assert case is not None and case.find("failure") is not None
    assert (case.find("failure").text or "").count("\n") == 2  # all three findings listed
    assert "(and 2 more)" in case.find("failure").get("message", "")
    lenient = etree.fromstring(junit.render([res], {"fail_on": "never"}).encode())
    assert lenient.get("failures") == "0"
    out = lenient.find(".//testcase[@name='H001 heartbeat-timeout']/system-out")
    assert out is not None and (out.text or "").count("H001") == 3


# GitHub annotations and --format auto ---------------------------------------------------

def test_github_annotations_escape_and_point_at_lines(tmp_path: Path) -> None:
    res = _repeated_timeouts(tmp_path, 1)
    res.stats.path = "logs/a,b:c.log"
    res.findings[0].message = "50% lost\nsecond line"
    lines = github.render([res], OPTIONS).splitlines()
    assert lines[0] == ("::error file=logs/a%2Cb%3Ac.log,line=7,title=H001 heartbeat-timeout "
                        "(can0 node 3)::50%25 lost%0Asecond line [at 0.650 s]  [limit measured "
                        "from the trace: --network or --dcf gives the configured one]")
    assert lines[-1] == "nmtcheck FAIL: 1 error, 0 warnings, 0 info in 1 input (--fail-on error)"


def test_github_notice_for_info() -> None:
    res = ALL[1]
    res_info = InputResult(res.index, res.stats, res.model,
                           [type(f)(**{**f.__dict__, "severity": "info"}) for f in res.findings])
    assert github.render([res_info], OPTIONS).startswith("::notice file=")


def test_auto_format_picks_github_under_actions(monkeypatch: pytest.MonkeyPatch) -> None:
    assert auto_format({"GITHUB_ACTIONS": "true"}) == "github"
    assert auto_format({}) == "text"
    monkeypatch.setenv("GITHUB_ACTIONS", "true")
    assert renderer("auto") is github.render
    monkeypatch.delenv("GITHUB_ACTIONS")
    assert renderer("auto") is renderer("text")


def test_format_for_path_and_unknown_format() -> None:
    assert [format_for_path(p) for p in ("r.html", "R.HTM", "results.xml", "f.sarif",
                                         "f.sarif.json", "r.json", "s.md", "f.csv")] == [
        "html", "html", "junit", "sarif", "sarif", "json", "markdown", "csv"]
    with pytest.raises(UsageError, match="unknown format"):
        renderer("pdf")


# Markdown ------------------------------------------------------------------------------

def test_markdown_groups_repeats_and_escapes_cells(tmp_path: Path) -> None:
    res = _repeated_timeouts(tmp_path, 3)
    res.findings[0].message = "a | b <c>"
    text = markdown.render([res], OPTIONS)
    assert text.startswith("## nmtcheck: ❌ FAIL\n\n**3 errors, 0 warnings, 0 info**")
    rows = [line for line in text.splitlines() if line.startswith("| error |")]
    assert rows == ["| error | H001 heartbeat-timeout | can0 node 3 | 0.650 s | 7 | 3 | "
                    "a \\| b &lt;c>  [limit measured from the trace: --network or --dcf "
                    "gives the configured one] |"]
    assert "<details><summary>Nodes</summary>" in text


def test_markdown_pass_says_so() -> None:
    text = markdown.render(ALL[:1], OPTIONS)
    assert text.startswith("## nmtcheck: ✅ PASS") and "No findings." in text


# HTML ----------------------------------------------------------------------------------

def test_html_is_self_contained() -> None:
    page = html.render(ALL, OPTIONS)
    assert "Content-Security-Policy" in page and "default-src 'none'" in page
    # No resource is loaded from anywhere: no src attributes, no links or imports by URL.
    assert not re.search(r"""\ssrc\s*=|<link[^>]+href=["'](?!data:)|@import|url\((?!#)""", page)
    urls = set(re.findall(r"https?://[^\s\"'<>)]+", page))
    assert urls <= {"http://www.w3.org/2000/svg"}  # the SVG namespace name, never fetched
    script = re.search(r'<script type="application/json" id="report-data">(.*?)</script>',
                       page, re.S)
    assert script is not None
    data = json.loads(script.group(1))
    assert [t["id"] for t in data["timelines"]] == [f"tl-{i}-0" for i in range(len(ALL))]
    hb = data["timelines"][1]["rows"]
    assert [r["node"] for r in hb] == [2, 3]
    assert [data["states"][iv[2]] for iv in hb[1]["iv"]] == [
        "UNKNOWN", "PRE-OPERATIONAL", "OPERATIONAL", "OFFLINE", "OPERATIONAL"]


def test_html_script_data_cannot_close_the_script(tmp_path: Path) -> None:
    res = _repeated_timeouts(tmp_path, 1)
    res.findings[0].message = "</script><script>alert(1)</script> & <!--"
    page = html.render([res], OPTIONS)
    assert "<script>alert(1)" not in page
    assert "&lt;/script&gt;&lt;script&gt;alert(1)" in page  # the table cell, escaped
    assert html.script_json({"m": "</script>"}) == '{"m":"\\u003c/script\\u003e"}'


def test_html_groups_repeats_and_caps_markers(tmp_path: Path,
                                              monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(html, "MAX_OCCURRENCES", 4)
    res = _repeated_timeouts(tmp_path, 6)
    assert len(res.findings) == 6 and len(group_findings(res.findings)) == 1
    context = html.report_context([res], OPTIONS)
    (group,) = context["groups"]
    assert group["count"] == 6 and len(group["occurrences"]) == 4 and group["hidden"] == 2
    assert len(context["timelines"][0]["rows"][0]["marks"]) == 4
    page = html.render([res], OPTIONS)
    assert page.count('<tr id="finding-') == 1
    assert "… and 2 more, not listed" in page


def test_html_size_does_not_grow_with_frames(tmp_path: Path) -> None:
    """Ten times the frames of a steady network: the report barely changes size."""
    def steady(seconds: int) -> str:
        lines = [(0.0, "702#00"), (0.001, "703#00"), (0.01, "000#0100")]
        for k in range(1, seconds * 100):
            t = k * 0.01
            lines += [(t, "702#05"), (t + 0.001, "703#05"), (t + 0.002, "182#0102030405060708")]
        return candump(lines)
    checker = Checker(tmp_path)
    small, big = checker.run(steady(10), select="H"), checker.run(steady(100), select="H")
    assert big.stats.frames > 9 * small.stats.frames
    small_page, big_page = html.render([small], OPTIONS), html.render([big], OPTIONS)
    assert len(big_page) < len(small_page) * 1.1


def test_heartbeat_stats_leave_out_boot_ups_and_resets(tmp_path: Path) -> None:
    lines = [(0.0, "703#00"), (0.1, "703#7F"), (0.2, "703#7F"), (0.25, "000#8103"),
             (0.3, "703#7F"), (0.4, "703#7F"), (0.5, "703#00"), (0.6, "703#7F"),
             (0.72, "703#7F")]
    res = Checker(tmp_path).run(candump(lines))
    (m,) = res.nodes()
    stats = heartbeat_stats(m)
    assert [round(x, 3) for x in stats.intervals.values] == [0.1, 0.1, 0.12]
    assert (round(stats.minimum or 0, 3), round(stats.median or 0, 3),
            round(stats.maximum or 0, 3)) == (0.1, 0.1, 0.12)
    assert stats.jitter == pytest.approx(0.00943, abs=1e-5)  # population σ of the three


# Several outputs in one run, and the installed wheel -------------------------------------

def _run(*args: str, cwd: Path, env: dict[str, str] | None = None
         ) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "nmtcheck", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=120,
                          env={**os.environ, **(env or {})})


def test_cli_writes_every_format_in_one_run(tmp_path: Path) -> None:
    log = str(SAMPLES / "heartbeat_loss.log")
    res = _run("check", log, "-o", "report.html", "-o", "results.xml", "-o", "findings.csv",
               "-o", "findings.sarif", "-o", "summary.md", "-q", cwd=tmp_path)
    assert res.returncode == 1, res.stderr
    assert "H001" in res.stdout  # stdout keeps the text report
    assert 'id="findings-table"' in (tmp_path / "report.html").read_text()
    xml = etree.fromstring((tmp_path / "results.xml").read_bytes())
    assert xml.get("failures") == "1"
    rows = list(csv.DictReader(io.StringIO((tmp_path / "findings.csv").read_text())))
    assert [r["rule"] for r in rows] == ["H001"]
    assert json.loads((tmp_path / "findings.sarif").read_text())["version"] == "2.1.0"
    assert "H001 heartbeat-timeout" in (tmp_path / "summary.md").read_text()


def test_cli_selected_rules_are_what_junit_lists(tmp_path: Path) -> None:
    res = _run("check", str(SAMPLES / "healthy.log"), "--select", "H", "--format", "junit",
               cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    names = {c.get("name") for c in etree.fromstring(res.stdout.encode()).iter("testcase")}
    assert names == {f"{r.code} {r.name}" for r in RULES if r.code.startswith("H")}


def test_cli_format_auto_under_github_actions(tmp_path: Path) -> None:
    log = str(SAMPLES / "heartbeat_loss.log")
    res = _run("check", log, "--format", "auto", cwd=tmp_path, env={"GITHUB_ACTIONS": "true"})
    assert res.returncode == 1
    assert res.stdout.startswith(f"::error file={log},line=77,title=H001 heartbeat-timeout")
    plain = _run("check", log, "--format", "auto", cwd=tmp_path, env={"GITHUB_ACTIONS": ""})
    assert not plain.stdout.startswith("::") and "H001" in plain.stdout


def test_installed_wheel_renders_html(tmp_path: Path) -> None:
    """The console script of an installed (non-editable) wheel finds its template."""
    exe = Path(sys.executable).with_name("nmtcheck")
    if not exe.exists():
        pytest.skip("nmtcheck console script not installed in this environment")
    res = subprocess.run([str(exe), "check", str(SAMPLES / "heartbeat_loss.log"), "-o", "r.html",
                          "-q"], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert res.returncode == 1, res.stderr
    assert "heartbeat-timeout" in (tmp_path / "r.html").read_text()

