"""The HTML report's SYNC row, EMCY markers, "PDO streams" table and nested chains (SPEC
§9.4.2, §9.3.6), on CANopenNode recordings (samples/canopennode/, README there) and in a
real headless Chromium as tests/test_reporters_html_browser.py drives it.

What the page must show comes from the log's frames and the stack's own `.events` (the
EMCYs it says it sent), and for the PDO table from the JSON report, which the page must
agree with."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import pytest
import stack_recording as recording
from conftest import SAMPLES, Checker
from test_reporters_html_browser import SCREENSHOTS, Browser, browser  # noqa: F401 (the fixture)

from nmtcheck.engine import check_input, select_rules
from nmtcheck.reporters import comm_lanes
from nmtcheck.reporters import html as html_reporter
from nmtcheck.reporters.json import report_dict
from nmtcheck.results import InputResult
from nmtcheck.settings.network import load_network
from nmtcheck.settings.profiles import load_profile

CN = SAMPLES / "canopennode"
SYNC_STOP = (CN / "sync_emcy" / "sync_producer_stopped.log",
             CN / "sync_emcy" / "network_sync_stopped.toml")
RPDO_STOP = (CN / "pdo" / "rpdo_producer_stopped.log",
             CN / "pdo" / "network_rpdo_producer_stopped.toml")
HEALTHY_SYNC = (CN / "pdo" / "sync_tpdo.log", CN / "pdo" / "network_sync_tpdo.toml")
OPTIONS: dict[str, object] = {"fail_on": "error"}
FRAMES = "new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))"


def _check(pair: tuple[Path, Path]) -> InputResult:
    profile = load_profile("default")
    return check_input(str(pair[0]), 0, profile, select_rules(profile, [], []),
                       network=load_network(str(pair[1])))


def _page_data(page: str) -> dict[str, Any]:
    m = re.search(r'<script type="application/json" id="report-data">(.*?)</script>', page,
                  re.S)
    assert m is not None
    data: dict[str, Any] = json.loads(m.group(1))
    return data


def _open(browser: Browser, tmp_path: Path, res: InputResult) -> str:  # noqa: F811
    report = tmp_path / "report.html"
    report.write_text(html_reporter.render([res], OPTIONS), encoding="utf-8")
    url = report.as_uri()
    browser.open(url)
    return url


# At time t of a timeline's SYNC row or of a node's row (at the bar's lower edge, where
# the EMCY markers sit): the element the page painted there, its class and fill.
HIT = """
(function (timelineId, node, t, dy) {
  const svg = document.querySelector('#' + CSS.escape(timelineId) + ' svg.tl-svg');
  const row = node === null ? svg.querySelector('g.tl-sync')
                            : svg.querySelector('g.tl-row[data-node="' + node + '"]');
  row.scrollIntoView({block: 'center'});
  const box = svg.getBoundingClientRect();
  const v0 = +svg.dataset.viewStart, v1 = +svg.dataset.viewEnd;
  const x = box.left + +svg.dataset.plotX + (t - v0) / (v1 - v0) * +svg.dataset.plotWidth;
  const y = box.top + +row.dataset.barY + (dy === null ? +row.dataset.barH / 2 : dy);
  const hit = document.elementFromPoint(x, y);
  return {cls: hit && hit.getAttribute('class'), fill: hit && getComputedStyle(hit).fill,
          title: hit && hit.querySelector('title') && hit.querySelector('title').textContent};
})
"""


def _hit(browser: Browser, timeline_id: str, node: int | None, t: float,  # noqa: F811
         dy: float | None = None) -> dict[str, str]:
    out: dict[str, str] = browser.evaluate(
        f"{HIT}({json.dumps(timeline_id)}, {json.dumps(node)}, {t}, {json.dumps(dy)})")
    return out


def test_sync_lane_and_emcy_marks_in_the_page_data() -> None:
    """Without a browser: the SYNC row carries every SYNC of the log and Y001's gap, each
    consumer's row its EMCYs at the times the stack sent them, by code class."""
    log = SYNC_STOP[0]
    res = _check(SYNC_STOP)
    data = _page_data(html_reporter.render([res], OPTIONS))
    [tl] = data["timelines"]
    sync = tl["sync"]
    syncs = [f.t for f in recording.frames(log) if f.can_id == 0x080]
    assert sync["ticks"] == pytest.approx(syncs, abs=2e-6) and sync["bins"] is None
    [gap] = sync["gaps"]
    assert gap[:2] == [3.983065, 6.017433] and gap[4] is False
    assert data["groups"][gap[2]]["rule"] == "Y001"
    emcy = {row["node"]: row["emcy"] for row in tl["rows"]}
    for t, node, payload in recording.emcys_sent(log):
        [mark] = [m for m in emcy[node] if abs(m[0] - t) < 0.001]
        cls = data["emcyClasses"][mark[1]]
        assert cls == ("reset" if payload.startswith("0000") else "communication")
        text = data["emcyTexts"][mark[2]]
        assert text.startswith("EMCY " + ("0000h" if payload.startswith("0000") else "8100h"))
    assert emcy[1] == emcy[2] == []


def test_sync_ticks_are_binned_past_the_limit(checker: Checker) -> None:
    """A long SYNC log: the page keeps counts in MAX_SYNC_TICKS bins, not one time per
    frame, and the counts add up to the frames."""
    n = comm_lanes.MAX_SYNC_TICKS + 5000
    res = checker.run("".join(f"({1000 + k * 0.001:.6f}) can0 080#\n" for k in range(n)))
    lane = comm_lanes.sync_ticks(res, "can0", res.stats.start or 0.0)
    assert lane is not None and lane["ticks"] is None
    assert len(lane["bins"]["counts"]) == comm_lanes.MAX_SYNC_TICKS
    assert sum(lane["bins"]["counts"]) == n == lane["frames"]
    page = html_reporter.render([res], OPTIONS)
    assert len(page) < 400_000


def test_sync_ticks_are_shared_among_many_channels(checker: Checker,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """Many channels with SYNC share the page's budget: each gets its share as bins."""
    monkeypatch.setattr(comm_lanes, "MAX_SYNC_TICKS_PAGE", 3000)
    monkeypatch.setattr(comm_lanes, "MIN_SYNC_TICKS", 500)
    text = "".join(f"({1000 + k * 0.001:.6f}) can{c} 080#\n" for k in range(2000)
                   for c in range(4))
    res = checker.run(text)
    assert comm_lanes.sync_ticks_per_channel([res]) == 750
    ctx = html_reporter.report_context([res], OPTIONS)
    lanes = [tl["sync"] for tl in ctx["timelines"]]
    assert len(lanes) == 4 and all(lane["ticks"] is None and len(lane["bins"]["counts"]) == 750
                                   and sum(lane["bins"]["counts"]) == 2000 for lane in lanes)


def test_chain_is_a_nested_list_with_reactions_folded() -> None:
    """SPEC §9.3.6: node 3's S005 is explained by its EMCY, that by Y001, that by the stop
    of the SYNC producer: three nested lists; Y001's reactions (the consumers' EMCYs) in
    a folded <details>."""
    page = html_reporter.render([_check(SYNC_STOP)], OPTIONS)
    row = page[page.index('data-rule="S005" data-node="0/can0/3"'):]
    row = row[:row.index("</tr>")]
    chain = row[row.index('<ul class="chain">'):]
    depths = [int(d) for d in re.findall(r'<li class="cause [^"]* depth-(\d)"', chain)]
    assert depths == [1, 2, 3]
    # each deeper entry inside the list item of the one it explains
    assert re.search(r'depth-1".*?<ul class="chain"><li [^>]*depth-2".*?<ul class="chain">'
                     r'<li [^>]*depth-3"[^>]*>.*?NMT stop to node 2.*?</li></ul></li></ul></li>',
                     chain, re.S)
    y001 = page[page.index('data-rule="Y001"'):]
    y001 = y001[:y001.index("</tr>")]
    folded = re.search(r'<details class="reactions" data-reactions="2">(.*?)</details>', y001,
                       re.S)
    assert folded is not None and folded.group(1).count("EMCY 8100h") == 2


def test_sync_row_emcy_markers_in_chromium(browser: Browser, tmp_path: Path) -> None:  # noqa: F811
    """The SYNC row is above the node rows, red where Y001 fires and grey ticks elsewhere;
    each EMCY is a dot at its time on its node's row, in its class's colour."""
    log = SYNC_STOP[0]
    res = _check(SYNC_STOP)
    url = _open(browser, tmp_path, res)
    assert browser.console_errors() == []
    assert [u for u in browser.requested_urls() if u != url] == []
    tid = html_reporter.timeline_id(res, "can0")
    rows = browser.evaluate(f"""Array.from(document.querySelectorAll('#{tid} svg g'))
        .filter(g => g.matches('.tl-sync, .tl-row'))
        .map(g => g.classList.contains('tl-sync') ? 'SYNC' : g.dataset.node)""")
    assert rows == ["SYNC", "1", "2", "3", "4"]
    # the gap, in red, from the last SYNC before the stop to the first after
    gap = _hit(browser, tid, None, (3.983065 + 6.017433) / 2)
    assert gap["cls"] == "sync-gap" and gap["fill"] == "rgb(179, 38, 30)"
    assert gap["title"].startswith("no SYNC from 3.983065 s to 6.017433 s, 2034.368 ms\nY001")
    edges = browser.evaluate(f"""(() => {{ const r = document.querySelector('#{tid} .sync-gap');
        return [+r.dataset.start, +r.dataset.end]; }})()""")
    assert edges == [3.983065, 6.017433]
    for t in (2.0, 8.0):  # SYNC every 20 ms: ticks merged into a grey band, not red
        assert _hit(browser, tid, None, t)["cls"] == "sync-tick"
    browser.screenshot(SCREENSHOTS / "sync_producer_stopped.png")
    # zoomed in to 100 ms around 2 s the ticks are drawn apart, one per SYNC
    browser.evaluate(f"window.nmtReport.timelines['{tid}'].setView(1.95, 2.05)")
    browser.evaluate(FRAMES)
    in_view = [t for t in (f.t for f in recording.frames(log) if f.can_id == 0x080)
               if 1.95 <= t <= 2.05]
    ticks = browser.evaluate(f"document.querySelectorAll('#{tid} rect.sync-tick').length")
    assert ticks == len(in_view) >= 4
    colours = {k: html_reporter.EMCY_COLORS[k] for k in ("communication", "reset")}
    for t, node, payload in recording.emcys_sent(log):
        browser.evaluate(f"window.nmtReport.timelines['{tid}'].setView(0, 100)")
        browser.evaluate(FRAMES)
        dots = browser.evaluate(f"""Array.from(document.querySelectorAll(
            '#{tid} g.tl-row[data-node="{node}"] circle.emcy-marker')).map(c => [
            +c.dataset.time, c.dataset.class, getComputedStyle(c).fill])""")
        cls = "reset" if payload.startswith("0000") else "communication"
        [dot] = [d for d in dots if abs(d[0] - t) < 0.001]
        r, g, b = (int(colours[cls][i:i + 2], 16) for i in (1, 3, 5))
        assert dot[1:] == [cls, f"rgb({r}, {g}, {b})"]
        # a zoom around it puts the dot under the pointer at its time on the bar's edge
        browser.evaluate(f"window.nmtReport.timelines['{tid}'].setView({t - 0.01}, {t + 0.01})")
        browser.evaluate(FRAMES)
        hit = _hit(browser, tid, node, dot[0], 18 - 3)
        assert hit["cls"] == "emcy-marker", (node, t, hit)
        assert hit["title"].startswith("EMCY ")
        if cls == "communication":
            assert "CANopenNode: SYNC timeout" in hit["title"]
    # no EMCY on the rows of the nodes that sent none
    for node in (1, 2):
        assert browser.evaluate(f"""document.querySelectorAll(
            '#{tid} g.tl-row[data-node="{node}"] circle.emcy-marker').length""") == 0
    # a click on the gap brings its finding's row
    browser.evaluate(f"window.nmtReport.timelines['{tid}'].setView(0, 100)")
    browser.evaluate(FRAMES)
    browser.evaluate(f"document.querySelector('#{tid} .sync-gap').dispatchEvent("
                     "new MouseEvent('click', {bubbles: true}))")
    assert browser.evaluate("document.querySelector('tr[data-rule=Y001]').classList"
                            ".contains('flash')") is True
    # a chain's entry links to its moment: node 3's S005, its deepest cause (the stop)
    browser.evaluate("""document.querySelector('tr[data-rule=S005][data-node="0/can0/3"] '
        + 'li.depth-3 a.cause-jump').click()""")
    browser.evaluate(FRAMES)
    v0, v1 = browser.evaluate(f"""(() => {{ const s = document.querySelector('#{tid} svg');
        return [+s.dataset.viewStart, +s.dataset.viewEnd]; }})()""")
    assert v0 < 3.997872 < v1 and v1 - v0 < 2
    assert browser.console_errors() == []


def test_pdo_streams_table_in_chromium(browser: Browser, tmp_path: Path) -> None:  # noqa: F811
    """The "PDO streams" table lists every stream with the values the JSON report gives,
    a histogram of its intervals, and D004 on 182h; the consumer's RPDO timeout is an EMCY
    dot on node 3's row."""
    res = _check(RPDO_STOP)
    streams = report_dict([res], OPTIONS)["pdo_streams"]
    url = _open(browser, tmp_path, res)
    assert browser.console_errors() == []
    assert [u for u in browser.requested_urls() if u != url] == []
    assert browser.evaluate("document.getElementById('pdo-streams').textContent") == (
        "PDO streams")
    rows = browser.evaluate("""Array.from(document.querySelectorAll('table.pdo-table tbody tr'))
        .map(tr => ({cob: tr.dataset.cob, cells: Array.from(tr.cells).map(td =>
          td.textContent.replace(/\\s+/g, ' ').trim()), bars: tr.querySelectorAll(
          'svg.histogram rect').length, label: (tr.querySelector('svg.histogram') || {
          getAttribute: () => null}).getAttribute('aria-label')}))""")
    assert [r["cob"] for r in rows] == [s["cob_id"] for s in streams] and len(rows) >= 4
    for row, st in zip(rows, streams, strict=True):
        cells = row["cells"]
        par, mea = st["parameters"], st["measured"]
        consumers = ", ".join(f"node {c['node']}" for c in st["consumers"]) or "–"
        assert cells[:3] == ["can0", st["cob_id"], f"node {st['producer']['node']} → {consumers}"]
        assert cells[3:6] == [str(par["transmission_type"]["value"]),
                              str(par["event_timer_ms"]["value"]),
                              str(par["inhibit_100us"]["value"])]
        assert cells[6] == (", ".join(str(c["event_timer_ms"]["value"])
                                      for c in st["consumers"]) or "–")
        assert cells[7:10] == [str(mea["frames"]), str(mea["period_median_ms"]),
                               str(mea["worst_gap_ms"])]
        assert cells[10] == (", ".join(f"{k} × {n}" for k, n in st["findings"].items()) or "–")
        assert row["bars"] >= 1 and row["label"].startswith(f"intervals of {st['cob_id']}: ")
    [d004] = [r for r in rows if r["cob"] == "182h"]
    assert d004["cells"][10] == "D004 × 1"
    tid = html_reporter.timeline_id(res, "can0")
    [(t, node, _data)] = [e for e in recording.emcys_sent(RPDO_STOP[0]) if e[2][:4] == "5082"]
    dots = browser.evaluate(f"""Array.from(document.querySelectorAll(
        '#{tid} g.tl-row[data-node="{node}"] circle.emcy-marker')).map(c => +c.dataset.time)""")
    assert any(abs(d - t) < 0.001 for d in dots)
    assert browser.evaluate(f"document.querySelectorAll('#{tid} g.tl-sync').length") == 0
    browser.screenshot(SCREENSHOTS / "rpdo_producer_stopped.png")


def test_healthy_sync_recording_no_red_in_chromium(browser: Browser,  # noqa: F811
                                                   tmp_path: Path) -> None:
    """A clean recording with SYNC every 20 ms: a SYNC row of ticks, nothing red."""
    res = _check(HEALTHY_SYNC)
    assert res.findings == []
    url = _open(browser, tmp_path, res)
    assert browser.console_errors() == []
    assert [u for u in browser.requested_urls() if u != url] == []
    tid = html_reporter.timeline_id(res, "can0")
    assert browser.evaluate(f"document.querySelectorAll('#{tid} g.tl-sync').length") == 1
    assert browser.evaluate(f"document.querySelectorAll('#{tid} .sync-gap').length") == 0
    assert browser.evaluate(f"document.querySelectorAll('#{tid} rect.sync-tick').length") >= 1
    assert browser.evaluate("document.querySelectorAll('circle.emcy-marker').length") == 0


def test_emcy_markers_are_bounded(checker: Checker, monkeypatch: pytest.MonkeyPatch) -> None:
    """A node that floods EMCYs: the page draws at most the markers allowed per node (the
    first ones), says how many it left out, and keeps each distinct text once."""
    monkeypatch.setattr(comm_lanes, "MAX_EMCY_MARKS", 1000)
    monkeypatch.setattr(comm_lanes, "MIN_EMCY_MARKS_PER_NODE", 100)
    n = 5000
    data = ("0000000000000000", "0081101800000000")  # a reset, a SYNC timeout
    frames = ["(1000.000000) can0 705#05"] + [
        f"({1000.001 + k * 0.0005:.6f}) can0 085#{data[k % 2]}" for k in range(n)]
    res = checker.run("".join(f + "\n" for f in frames))
    ctx = html_reporter.report_context([res], OPTIONS)
    [tl] = ctx["timelines"]
    [row] = tl["rows"]
    assert len(row["emcy"]) == 1000 and row["emcy"][0][0] == pytest.approx(0.001)
    assert tl["left_out"] == f"{n - 1000} EMCYs not drawn (at most 1000 per node; the JSON " \
                             "report has all)"
    page = _page_data(html_reporter.render([res], OPTIONS))
    assert len(page["emcyTexts"]) == 2
    assert len(html_reporter.render([res], OPTIONS)) < 200_000


def test_binned_sync_row_in_chromium(browser: Browser, tmp_path: Path,  # noqa: F811
                                     checker: Checker) -> None:
    """More SYNCs than the page keeps: the row is drawn from the counted bins, and Y001's
    gap (by the measured period) is still red at its place."""
    n = comm_lanes.MAX_SYNC_TICKS + 5000
    times = [k * 0.001 + (0.2 if k >= n // 2 else 0.0) for k in range(n)]
    res = checker.run("".join(f"({1000 + t:.6f}) can0 080#\n" for t in times))
    assert [f.rule for f in res.findings] == ["Y001"]
    url = _open(browser, tmp_path, res)
    assert browser.console_errors() == []
    assert [u for u in browser.requested_urls() if u != url] == []
    tid = html_reporter.timeline_id(res, "can0")
    assert browser.evaluate("window.nmtReport.data.timelines[0].sync.ticks") is None
    last, nxt = times[n // 2 - 1], times[n // 2]
    gap = _hit(browser, tid, None, (last + nxt) / 2)
    assert gap["cls"] == "sync-gap" and gap["title"].startswith(
        f"no SYNC from {last:.6f} s to {nxt:.6f} s")
    for t in (1.0, times[-1] - 1.0):
        assert _hit(browser, tid, None, t)["cls"] == "sync-tick"
    # zoomed in to 20 ms: the bins (1.26 ms each, every one with frames) make one band,
    # never a tick per SYNC the page does not have
    browser.evaluate(f"window.nmtReport.timelines['{tid}'].setView(5, 5.02)")
    browser.evaluate(FRAMES)
    assert browser.evaluate(f"document.querySelectorAll('#{tid} rect.sync-tick').length") == 1
    assert _hit(browser, tid, None, 5.01)["cls"] == "sync-tick"
    assert browser.console_errors() == []
