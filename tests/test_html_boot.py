"""The HTML report's boot table (SPEC §8.5.3) and cause chains (SPEC §8.6)."""

from __future__ import annotations

import json
import re
from html.parser import HTMLParser
from typing import Any

from conftest import REPO, Checker

# SPEC_BOOT §8.7 vectors, as tests/test_rules_boot.py holds them: P001 (node 2's product
# code differs from 1F86h, letter M) and C1 (node 5's heartbeat stops; its EMCY 8140h when
# it comes back)
from test_rules_boot import C1_LOG, C2_LOG, P001_LOG, P001_NET

from nmtcheck.engine import check_input, select_rules
from nmtcheck.processes.boot_records import LETTERS
from nmtcheck.reporters import html
from nmtcheck.settings.network import load_network
from nmtcheck.settings.profiles import load_profile

OPTIONS: dict[str, object] = {"fail_on": "error"}



class _Tables(HTMLParser):
    """Rows of every table with class `boot-table` (cells' text), and the script data."""

    def __init__(self) -> None:
        super().__init__()
        self.rows: list[dict[str, Any]] = []
        self.depth = 0  # nesting of tables inside a boot table
        self.cell: list[str] | None = None
        self.data = ""
        self.in_data = False

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        if tag == "table" and ("boot-table" in (a.get("class") or "") or self.depth):
            self.depth += 1
        elif tag == "tr" and self.depth == 1 and "data-node" in a:
            self.rows.append({**a, "cells": []})
        elif tag == "td" and self.depth == 1 and self.rows:
            self.cell = []
            self.rows[-1]["cells"].append(self.cell)
        elif tag == "abbr" and self.depth == 1 and self.rows:
            self.rows[-1]["letter_title"] = a.get("title")
        elif tag == "script" and a.get("id") == "report-data":
            self.in_data = True

    def handle_endtag(self, tag: str) -> None:
        if tag == "table" and self.depth:
            self.depth -= 1
        elif tag == "td" and self.depth == 1:
            self.cell = None
        elif tag == "script":
            self.in_data = False

    def handle_data(self, data: str) -> None:
        if self.cell is not None:
            self.cell.append(data)
        if self.in_data:
            self.data += data


def _parse(page: str) -> _Tables:
    p = _Tables()
    p.feed(page)
    return p


def _text(cell: list[str]) -> str:
    return re.sub(r"\s+", " ", "".join(cell)).strip()


def test_failed_boot_row_has_status_letter_and_proving_frame(checker: Checker) -> None:
    res = checker.run(P001_LOG.strip() + "\n", network=P001_NET)
    page = html.render([res], OPTIONS)
    assert 'id="boot"' in page and "Boot (CiA 302-2)" in page
    assert "manager network" in page  # the channel's manager line above the table
    parsed = _parse(page)
    row = next(r for r in parsed.rows if r["data-node"] == "2")
    assert (row["data-status"], row["data-letter"]) == ("failed", "M")
    assert row["letter_title"] == LETTERS["M"]
    cells = [_text(c) for c in row["cells"][:6]]
    assert cells[0] == "2" and cells[1] == "failed" and cells[2].startswith("M")
    start = res.stats.start or 0.0
    assert float(cells[3]) == round(10.026 - start, 6) and cells[4] == "9"  # proving frame
    assert cells[5].startswith("1")  # attempts
    detail = _text(row["cells"][6])
    assert "0x00004644" in detail and "0x00004645" in detail  # the P001 message
    assert "1018:02" in detail and "product_code" in detail  # the steps


def test_causes_under_the_finding_and_on_the_timeline(checker: Checker) -> None:
    """C2 (SPEC §9.3.7): node 2's B002 has the boot-up cluster as its cause, listed under
    the finding and marked on node 2's timeline row."""
    res = checker.run(C2_LOG.strip() + "\n")
    page = html.render([res], OPTIONS)
    m = re.search(r'<div class="causes" data-causes="1">(.*?)</div>', page, re.S)
    assert m is not None
    assert 'data-kind="bootup_cluster"' in m.group(1) and "boot-ups of node(s) 3, 4" in m.group(1)
    assert "line 7" in m.group(1)
    data = json.loads(_parse(page).data)
    rows = [r for tl in data["timelines"] for r in tl["rows"] if r["node"] == 2]
    (row,) = rows
    start = res.stats.start or 0.0
    assert [c[0] for c in row["causes"]] == [round(11.5 - start, 6)]
    gid = row["causes"][0][1]
    assert data["groups"][gid]["rule"] == "B002"
    cause = data["groups"][gid]["occurrences"][0]["causes"][0]
    assert cause["kind"] == "bootup_cluster" and cause["end"] == round(11.54 - start, 6)


def test_reactions_are_folded_under_the_finding(checker: Checker) -> None:
    """C1 (SPEC §9.3.7): node 5's EMCY came after its heartbeat timeout: no cause, one
    reaction (the node's report) in a folded <details>, not on the timeline as a cause."""
    res = checker.run(C1_LOG.strip() + "\n")
    page = html.render([res], OPTIONS)
    assert '<div class="causes" data-causes' not in page
    m = re.search(r'<details class="reactions" data-reactions="1">(.*?)</details>', page, re.S)
    assert m is not None
    assert "after the effect began: 1 event(s)" in m.group(1)
    assert 'data-kind="emcy"' in m.group(1) and "8140h recovered from bus" in m.group(1)
    assert "[report]" in m.group(1) and "line 5" in m.group(1)
    data = json.loads(_parse(page).data)
    (row,) = [r for tl in data["timelines"] for r in tl["rows"] if r["node"] == 5]
    assert row["causes"] == []


def test_no_boot_section_without_a_manager(checker: Checker) -> None:
    page = html.render([checker.run(C1_LOG.strip() + "\n")], OPTIONS)
    assert 'id="boot"' not in page


def test_findings_of_other_rules_have_no_causes(checker: Checker) -> None:
    res = checker.run(P001_LOG.strip() + "\n", network=P001_NET)
    context = html.report_context([res], OPTIONS)
    p001 = next(g for g in context["groups"] if g["rule"] == "P001")
    assert "causes" not in p001["occurrences"][0]
    assert 'class="causes' not in html.render([res], OPTIONS).split('id="boot"')[0]


def test_cause_and_boot_text_is_escaped(checker: Checker) -> None:
    for log, rule, field in ((C2_LOG, "B002", "causes"), (C1_LOG, "H001", "reactions")):
        res = checker.run(log.strip() + "\n")
        f = next(f for f in res.findings if f.rule == rule)
        entries = getattr(f, field)
        assert entries
        entries[0]["text"] = "<img src=x onerror=alert(1)></script>"
        page = html.render([res], OPTIONS)
        assert "<img src=x" not in page
        assert "&lt;img src=x onerror=alert(1)&gt;&lt;/script&gt;" in page
        assert "\\u003cimg src=x" in page  # and in the page data


def test_lely_mandatory_sample() -> None:
    lely = REPO / "samples" / "lely" / "mandatory"
    prof = load_profile("default")
    res = check_input(str(lely / "mandatory_lost.log"), 0, prof, select_rules(prof, [], []),
                      load_network(str(lely / "network.toml")))
    page = html.render([res], OPTIONS)
    rows = {r["data-node"]: r for r in _parse(page).rows}
    assert set(rows) == {"1", "2", "3", "4"}
    assert rows["1"]["data-status"] == "not-managed"
    assert all(rows[n]["data-status"] == "ok" for n in "234")
    detail = _text(rows["3"]["cells"][6])
    assert "started" in detail and "after reset" in detail
    # H001 of node 3: the broadcast resets, under the finding
    assert "NMT reset communication to all nodes" in page
