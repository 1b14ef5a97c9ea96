"""The HTML timeline's LSS row and the origin of an LSS-assigned node-ID (SPEC §9.4.2), on
CANopenNode's LSS recordings (samples/canopennode/lss/, README there), in the page data
and in a real headless Chromium as tests/test_html_comm.py drives it.

Where the marks must be comes from the log's frames (7E5h requests, 7E4h answers, the
boot-up on 700h + N) and what must be red from what the stack's LSS master said each call
returned (the `.events` file): OK_ILLEGAL_ARGUMENT for the store, TIMEOUT for the bit
timing."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
import stack_recording as recording
from conftest import SAMPLES, Checker
from test_html_comm import FRAMES, _open, _page_data
from test_reporters_html_browser import Browser, browser  # noqa: F401 (the fixture)

from nmtcheck.reporters import html as html_reporter
from nmtcheck.reporters import lss_lane
from nmtcheck.results import InputResult

FOLDER = SAMPLES / "canopennode" / "lss"
OPTIONS: dict[str, object] = {"fail_on": "error"}
BLUE, RED = "rgb(74, 106, 138)", "rgb(179, 38, 30)"


def _log(name: str) -> Path:
    return FOLDER / f"{name}.log"


def _check(name: str) -> InputResult:
    return recording.check(_log(name), None)


def _master_said(name: str) -> list[str]:
    return [e.text.removeprefix("master: ") for e in recording.events(_log(name))
            if e.device == "master" and e.text.startswith("master: ")]


def _requests(name: str) -> list[recording.Frame]:
    return [f for f in recording.frames(_log(name)) if f.can_id == 0x7E5]


def _answer_t(name: str, request: recording.Frame) -> float:
    """When the exchange ends: its 7E4h answer before the next request, else the request."""
    frames = recording.frames(_log(name))
    later = [f for f in frames if f.line > request.line]
    nxt = next((f.line for f in later if f.can_id == 0x7E5), 10**9)
    return next((f.t for f in later if f.can_id == 0x7E4 and f.line < nxt), request.t)


# The element painted at time t on a timeline's LSS row (g.tl-lss) or on a node's row, at
# `dy` px below the row's bar top (the middle of the bar when null)
HIT = """
(function (timelineId, node, t, dy) {
  const svg = document.querySelector('#' + CSS.escape(timelineId) + ' svg.tl-svg');
  const row = node === null ? svg.querySelector('g.tl-lss')
                            : svg.querySelector('g.tl-row[data-node="' + node + '"]');
  row.scrollIntoView({block: 'center'});
  const box = svg.getBoundingClientRect();
  const v0 = +svg.dataset.viewStart, v1 = +svg.dataset.viewEnd;
  const x = box.left + +svg.dataset.plotX + (t - v0) / (v1 - v0) * +svg.dataset.plotWidth;
  const y = box.top + +row.dataset.barY + (dy === null ? +row.dataset.barH / 2 : dy);
  const hit = document.elementFromPoint(x, y);
  const badge = hit && hit.closest('.lss-adopted');
  const titled = badge || hit;
  return {cls: hit && hit.getAttribute('class'), fill: hit && getComputedStyle(hit).fill,
          badge: !!badge, exchange: hit && hit.dataset.exchange,
          title: titled && titled.querySelector(':scope > title')
                 && titled.querySelector(':scope > title').textContent};
})
"""


def _hit(browser: Browser, tid: str, node: int | None, t: float,  # noqa: F811
         dy: float | None = None) -> dict[str, Any]:
    out: dict[str, Any] = browser.evaluate(
        f"{HIT}({json.dumps(tid)}, {json.dumps(node)}, {t}, {json.dumps(dy)})")
    return out


def _view(browser: Browser, tid: str, v0: float, v1: float) -> None:  # noqa: F811
    browser.evaluate(f"window.nmtReport.timelines['{tid}'].setView({v0}, {v1})")
    browser.evaluate(FRAMES)


def test_lss_row_and_node_id_origin_in_the_page_data() -> None:
    """Every 7E5h request is an exchange mark from the request to its answer, none red
    (every call returned OK); node 5's row carries where its node-ID came from, at its
    boot-up, pointing at the configure request."""
    name = "lss_configure_store"
    assert _master_said(name)[1:] == [
        "select 300:4644:0:1 -> OK", "inquire_node -> OK, value 000000FF", "node 5 -> OK",
        "store -> OK", "deselect -> OK"]
    data = _page_data(html_reporter.render([_check(name)], OPTIONS))
    [tl] = data["timelines"]
    requests = _requests(name)
    lane = tl["lss"]
    assert [t for x in lane["exchanges"] for t in x[:2]] == pytest.approx(
        [t for q in requests for t in (q.t, _answer_t(name, q))], abs=2e-6)
    assert [x[2] for x in lane["exchanges"]] == [False] * len(requests)
    assert lane["omitted"] == 0
    [session] = lane["sessions"]  # the selective switch to the switch to waiting
    assert session[0] == pytest.approx(next(q.t for q in requests if q.data[:2] == "43"))
    rows = {row["node"]: row for row in tl["rows"]}
    boot = next(f for f in recording.frames(_log(name)) if (f.can_id, f.data) == (0x705, "00"))
    configure = next(q for q in requests if q.data.startswith("1105"))
    [origin] = rows[5]["lss"]
    assert origin[:2] == pytest.approx([boot.t, configure.t], abs=2e-6)
    assert origin[2].startswith(f"node-ID 5 assigned by LSS: configure node-ID 5 at "
                                f"{configure.t:.6f} s (line {configure.line})")
    assert f"stored; boot-up as node 5 at line {boot.line}" in origin[2]
    assert rows[1]["lss"] == []  # the master has its own node-ID


def test_no_lss_row_without_lss_frames(checker: Checker) -> None:
    res = checker.run("(10.000000) can0 701#00\n(10.100000) can0 701#05\n")
    data = _page_data(html_reporter.render([res], OPTIONS))
    assert data["timelines"][0]["lss"] is None
    assert all(row["lss"] == [] for row in data["timelines"][0]["rows"])


def test_lss_marks_are_bounded(checker: Checker, monkeypatch: pytest.MonkeyPatch) -> None:
    """A channel flooded with LSS requests: the page draws the first ones allowed and
    says how many it left out."""
    monkeypatch.setattr(lss_lane, "MAX_LSS_MARKS", 100)
    monkeypatch.setattr(lss_lane, "MIN_LSS_MARKS_PER_CHANNEL", 50)
    flood = "".join(f"({10 + k * 0.001:.6f}) can0 7E5#5E00000000000000\n" for k in range(300))
    page = html_reporter.render([checker.run(flood)], OPTIONS)
    [tl] = _page_data(page)["timelines"]
    assert len(tl["lss"]["exchanges"]) == 100 and tl["lss"]["omitted"] == 200
    assert "200 LSS requests not drawn (at most 100 per channel)" in tl["left_out"]


def test_lss_row_and_origin_in_chromium(browser: Browser, tmp_path: Path) -> None:  # noqa: F811
    """The LSS row sits between the axis and the node rows; zoomed in, each request is a
    blue mark at its time; node 5's boot-up has the LSS badge, whose click brings the
    configure request into view and marks it."""
    name = "lss_configure_store"
    res = _check(name)
    url = _open(browser, tmp_path, res)
    assert browser.console_errors() == []
    assert [u for u in browser.requested_urls() if u != url] == []
    tid = html_reporter.timeline_id(res, "can0")
    rows = browser.evaluate(f"""Array.from(document.querySelectorAll('#{tid} svg g'))
        .filter(g => g.matches('.tl-lss, .tl-row'))
        .map(g => g.classList.contains('tl-lss') ? 'LSS' : g.dataset.node)""")
    assert rows == ["LSS", "1", "5"]
    requests = _requests(name)
    # at the whole recording the requests (0.3 ms apart) share one pixel: one mark, whose
    # hover text counts the others
    marks = browser.evaluate(f"""Array.from(document.querySelectorAll(
        '#{tid} rect.lss-exchange')).map(r => r.querySelector('title').textContent)""")
    assert len(marks) == 1 and f"(+{len(requests) - 1} more LSS requests here" in marks[0]
    _view(browser, tid, requests[0].t - 0.00005, requests[-1].t + 0.00005)
    assert browser.evaluate(f"document.querySelectorAll('#{tid} rect.lss-exchange').length"
                            ) == len(requests)
    for k, q in enumerate(requests):
        hit = _hit(browser, tid, None, (q.t + _answer_t(name, q)) / 2)
        assert (hit["cls"], hit["fill"], hit["exchange"]) == ("lss-exchange", BLUE, str(k)), q
        assert hit["title"].startswith("LSS ") and f"line {q.line}" in hit["title"]
    configure = next(k for k, q in enumerate(requests) if q.data.startswith("1105"))
    assert _hit(browser, tid, None, requests[configure].t)["title"].startswith(
        "LSS configure node-ID 5 -> ok")
    # the badge at node 5's boot-up, on the bar
    boot = next(f for f in recording.frames(_log(name)) if (f.can_id, f.data) == (0x705, "00"))
    _view(browser, tid, boot.t - 0.01, boot.t + 0.01)
    hit = _hit(browser, tid, 5, boot.t + 0.0001, 6)
    assert hit["badge"] is True and hit["title"].startswith("node-ID 5 assigned by LSS")
    assert _hit(browser, tid, 1, boot.t + 0.0001, 6)["badge"] is False
    browser.evaluate(f"""document.querySelector('#{tid} g.lss-adopted').dispatchEvent(
        new MouseEvent('click', {{bubbles: true}}))""")
    browser.evaluate(FRAMES)
    v0, v1 = browser.evaluate(f"""(() => {{ const s = document.querySelector('#{tid} svg');
        return [+s.dataset.viewStart, +s.dataset.viewEnd]; }})()""")
    assert v0 < requests[configure].t < v1
    focused = browser.evaluate(f"""Array.from(document.querySelectorAll(
        '#{tid} rect.lss-exchange.focus')).map(r => +r.dataset.exchange)""")
    assert focused == [configure]
    assert browser.evaluate(f"document.querySelectorAll('#{tid} .lss-exchange.failed').length"
                            ) == 0
    assert browser.console_errors() == []


@pytest.mark.parametrize(("name", "call", "cs", "rule"), [
    ("lss_store_error", "store -> OK_ILLEGAL_ARGUMENT", "17", "L003"),
    ("lss_bitrate_silent", "bitrate 125 -> TIMEOUT", "13", "L001")])
def test_failed_exchange_is_red_in_chromium(browser: Browser, tmp_path: Path,  # noqa: F811
                                            name: str, call: str, cs: str, rule: str) -> None:
    """The call the stack says failed is the one red mark, at its request, naming the
    finding; still red at the whole recording's zoom; a click brings the finding's row."""
    assert call in _master_said(name)
    res = _check(name)
    _open(browser, tmp_path, res)
    tid = html_reporter.timeline_id(res, "can0")
    red = browser.evaluate(f"document.querySelectorAll('#{tid} .lss-exchange.failed').length")
    assert red == 1
    requests = _requests(name)
    [k] = [k for k, q in enumerate(requests) if q.data.startswith(cs)]
    # zoomed in from the first request to just after the failed one: each drawn apart
    _view(browser, tid, requests[0].t - 0.00005, requests[k].t + 0.0002)
    hit = _hit(browser, tid, None, (requests[k].t + _answer_t(name, requests[k])) / 2)
    assert (hit["cls"], hit["fill"], hit["exchange"]) == ("lss-exchange failed", RED, str(k))
    assert f"\n{rule} " in hit["title"]
    for j, q in enumerate(requests[:k]):
        hit = _hit(browser, tid, None, (q.t + _answer_t(name, q)) / 2)
        assert (hit["cls"], hit["fill"], hit["exchange"]) == ("lss-exchange", BLUE, str(j)), q
    browser.evaluate(f"document.querySelector('#{tid} .lss-exchange.failed').dispatchEvent("
                     "new MouseEvent('click', {bubbles: true}))")
    assert browser.evaluate(f"document.querySelector('tr[data-rule={rule}]').classList"
                            ".contains('flash')") is True
    assert browser.console_errors() == []


def test_node_id_not_adopted_is_red_at_its_configure_request() -> None:
    """Slave C took node-ID 8 (the master: `node 8 -> OK`) but every communication reset
    it printed starts it as node 3 (it was power-cycled before the reset): L006, drawn
    red on the configure node-ID 8 request; no badge anywhere (no boot-up as node 8)."""
    name = "lss_not_adopted"
    assert "node 8 -> OK" in _master_said(name)
    resets = [e.text for e in recording.events(_log(name))
              if e.device == "sC" and e.text.startswith("communication reset")]
    assert resets == ["communication reset: node-ID 3"] * 3
    data = _page_data(html_reporter.render([_check(name)], OPTIONS))
    [tl] = data["timelines"]
    requests = _requests(name)
    [k] = [k for k, q in enumerate(requests) if q.data.startswith("1108")]
    red = [j for j, x in enumerate(tl["lss"]["exchanges"]) if x[2]]
    assert red == [k]
    ex = tl["lss"]["exchanges"][k]
    assert data["groups"][ex[5]]["rule"] == "L006"
    assert data["lssTexts"][ex[3]].startswith("LSS configure node-ID 8 -> ok\nL006 ")
    assert all(row["lss"] == [] for row in tl["rows"])


def test_lely_fastscan_is_not_red_and_has_its_badge() -> None:
    """Lely's master finds CANopenNode slave A by fastscan and gives it node 5, stored (the
    master's own word); A boots as node 5. L007 is information, not a failure: nothing
    red; node 5's badge at its first boot-up names the configure request."""
    log = SAMPLES / "lely" / "lss" / "lely_fastscan.log"
    calls = [e.text.removeprefix("master: ") for e in recording.events(log)
             if e.device == "master"]
    assert "node 5 -> cs 11h error 0 spec 0" in calls
    assert "store -> cs 17h error 0 spec 0" in calls
    data = _page_data(html_reporter.render([recording.check(log, None)], OPTIONS))
    [tl] = data["timelines"]
    frames = recording.frames(log)
    assert len(tl["lss"]["exchanges"]) == len([f for f in frames if f.can_id == 0x7E5])
    assert not [x for x in tl["lss"]["exchanges"] if x[2]]
    assert any(data["lssTexts"][x[3]].split("\n")[1].startswith("L007 ")
               for x in tl["lss"]["exchanges"] if "\n" in data["lssTexts"][x[3]])
    boot = next(f for f in frames if (f.can_id, f.data) == (0x705, "00"))
    configure = next(f for f in frames if f.can_id == 0x7E5 and f.data.startswith("1105"))
    rows = {row["node"]: row for row in tl["rows"]}
    [origin] = rows[5]["lss"]
    assert origin[:2] == pytest.approx([boot.t, configure.t], abs=2e-6)
    assert ", stored; boot-up as node 5" in origin[2]
