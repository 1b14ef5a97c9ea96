"""The HTML report in a real headless Chromium: loads clean and offline, draws the right states.

Chromium is driven over the DevTools protocol (a websocket, no download of any
browser build). The test fails on any console error or uncaught exception and
on any network request other than the report file itself. Screenshots go to
`build/screenshots/` (or $NMTCHECK_SCREENSHOT_DIR) for people to look at.
Without Chromium the tests are skipped, unless $CI is set: then they fail.
"""

from __future__ import annotations

import base64
import contextlib
import json
import os
import shutil
import subprocess
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from conftest import REPO, SAMPLES

from nmtcheck.engine import check_input, select_rules
from nmtcheck.protocol.nmt import UNKNOWN
from nmtcheck.reporters import html as html_reporter
from nmtcheck.reporters.common import group_findings
from nmtcheck.results import InputResult
from nmtcheck.settings.profiles import load_profile

SAMPLE_NAMES = ["healthy", "heartbeat_loss", "pdo_preop", "guard_toggle", "ignored_command",
                "reset_no_bootup"]
SCREENSHOTS = Path(os.environ.get("NMTCHECK_SCREENSHOT_DIR", REPO / "build" / "screenshots"))
VIEWPORT = (1400, 1000)

# States read off `nmtcheck timeline` of the samples (seconds from the first frame): checked
# against what the page paints, independently of the model that produced the report.
CHECKPOINTS = {
    "heartbeat_loss": [(3, 0.2, "PRE-OPERATIONAL"), (3, 1.0, "OPERATIONAL"), (3, 2.0, "OFFLINE"),
                       (3, 3.0, "OPERATIONAL"), (2, 2.0, "OPERATIONAL")],
    "reset_no_bootup": [(3, 1.0, "OPERATIONAL"), (3, 1.485, "INITIALISING"),
                        (3, 2.5, "PRE-OPERATIONAL")],
    "ignored_command": [(4, 0.5, "PRE-OPERATIONAL"), (4, 2.0, "PRE-OPERATIONAL"),
                        (2, 2.0, "OPERATIONAL")],
    "pdo_preop": [(2, 0.5, "PRE-OPERATIONAL"), (2, 2.0, "OPERATIONAL")],
    "healthy": [(2, 0.1, "PRE-OPERATIONAL")],
    "guard_toggle": [(5, 2.5, "OPERATIONAL")],
}


class DevToolsError(RuntimeError):
    pass


class Browser:
    """A headless Chromium and one page, spoken to over the DevTools protocol."""

    def __init__(self, executable: str, profile_dir: Path) -> None:
        import websocket

        self.process = subprocess.Popen(
            [executable, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
             "--disable-background-networking", "--disable-component-update", "--disable-sync",
             "--disable-extensions", "--disable-default-apps", "--no-first-run",
             "--no-default-browser-check", "--mute-audio", f"--user-data-dir={profile_dir}",
             "--remote-debugging-port=0", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        port_file = profile_dir / "DevToolsActivePort"
        deadline = time.monotonic() + 60
        while not (port_file.exists() and len(port_file.read_text().splitlines()) >= 2):
            if self.process.poll() is not None or time.monotonic() > deadline:
                self.close()
                raise DevToolsError("chromium did not start its DevTools endpoint")
            time.sleep(0.1)
        port, path = port_file.read_text().splitlines()[:2]
        self.ws = websocket.create_connection(f"ws://127.0.0.1:{port}{path}", timeout=60,
                                              suppress_origin=True)
        self.next_id = 0
        self.events: list[dict[str, Any]] = []
        self.session: str | None = None

    def close(self) -> None:
        """Ask Chromium to quit (it ends its own helpers), then make sure it has."""
        ws = getattr(self, "ws", None)
        if ws is not None:
            with contextlib.suppress(Exception):
                self.send("Browser.close", browser_level=True)
            ws.close()
        try:
            self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.terminate()
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(timeout=10)

    def send(self, method: str, params: dict[str, Any] | None = None,
             browser_level: bool = False) -> dict[str, Any]:
        self.next_id += 1
        message: dict[str, Any] = {"id": self.next_id, "method": method, "params": params or {}}
        if self.session and not browser_level:
            message["sessionId"] = self.session
        self.ws.send(json.dumps(message))
        while True:
            reply = json.loads(self.ws.recv())
            if reply.get("id") == self.next_id:
                if "error" in reply:
                    raise DevToolsError(f"{method}: {reply['error']}")
                return dict(reply.get("result", {}))
            if "method" in reply:
                self.events.append(reply)

    def wait_event(self, method: str, timeout: float = 30) -> dict[str, Any]:
        for event in self.events:
            if event["method"] == method:
                return event
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            received: dict[str, Any] = json.loads(self.ws.recv())
            if "method" in received:
                self.events.append(received)
                if received["method"] == method:
                    return received
        raise DevToolsError(f"no {method} within {timeout} s")

    def new_page(self) -> None:
        """A fresh tab with console, log and network reporting on."""
        target = self.send("Target.createTarget", {"url": "about:blank"}, browser_level=True)
        attached = self.send("Target.attachToTarget",
                             {"targetId": target["targetId"], "flatten": True},
                             browser_level=True)
        self.session = attached["sessionId"]
        for domain in ("Page", "Runtime", "Log", "Network"):
            self.send(f"{domain}.enable")
        self.send("Emulation.setDeviceMetricsOverride",
                  {"width": VIEWPORT[0], "height": VIEWPORT[1], "deviceScaleFactor": 1,
                   "mobile": False})

    def open(self, url: str) -> None:
        self.new_page()
        self.events.clear()
        self.send("Page.navigate", {"url": url})
        self.wait_event("Page.loadEventFired")
        # Let the timelines draw (they render on load and on the next animation frames).
        self.evaluate("new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))")

    def evaluate(self, expression: str) -> Any:
        reply = self.send("Runtime.evaluate", {"expression": expression, "returnByValue": True,
                                               "awaitPromise": True})
        if "exceptionDetails" in reply:
            raise DevToolsError(f"{expression[:80]}…: {reply['exceptionDetails']}")
        return reply["result"].get("value")

    def console_errors(self) -> list[str]:
        out = []
        for e in self.events:
            p = e.get("params", {})
            if e["method"] == "Runtime.consoleAPICalled" and p.get("type") in ("error", "assert"):
                out.append(" ".join(str(a.get("value", a.get("description")))
                                    for a in p.get("args", [])))
            elif e["method"] == "Runtime.exceptionThrown":
                out.append(str(p.get("exceptionDetails")))
            elif e["method"] == "Log.entryAdded" and p["entry"]["level"] == "error":
                out.append(p["entry"]["text"])
        return out

    def requested_urls(self) -> list[str]:
        return [e["params"]["request"]["url"] for e in self.events
                if e["method"] == "Network.requestWillBeSent"]

    def screenshot(self, path: Path, full_page: bool = True) -> None:
        height = self.evaluate("document.documentElement.scrollHeight") if full_page \
            else VIEWPORT[1]
        shot = self.send("Page.captureScreenshot", {
            "format": "png", "captureBeyondViewport": full_page,
            "clip": {"x": 0, "y": 0, "width": VIEWPORT[0], "height": height, "scale": 1}})
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(base64.b64decode(shot["data"]))


def _chromium() -> str | None:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        found = shutil.which(name)
        if found:
            return found
    return None


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    executable = _chromium()
    missing = None
    if executable is None:
        missing = ("no chromium binary found (looked for chromium, chromium-browser and "
                   "google-chrome on PATH; on Debian: apt-get install chromium)")
    try:
        import websocket  # noqa: F401
    except ImportError:
        missing = missing or ("the websocket-client package is not installed "
                              "(pip install --group test)")
    if missing is not None or executable is None:
        if os.environ.get("CI"):
            pytest.fail("CI: chromium and websocket-client are required for the HTML report "
                        f"tests (.ci/run installs Debian's chromium): {missing}")
        pytest.skip(f"HTML report browser tests: {missing}")
    with tempfile.TemporaryDirectory(prefix="nmtcheck-chromium-",
                                     ignore_cleanup_errors=True) as profile:
        try:
            b = Browser(executable, Path(profile))
        except DevToolsError as exc:  # e.g. a chromium-browser stub that only names a snap
            if os.environ.get("CI"):
                raise
            pytest.skip(f"HTML report browser tests: {executable} did not start ({exc})")
        try:
            yield b
        finally:
            b.close()


def _results(*names: str) -> list[InputResult]:
    profile = load_profile("default")
    rules = select_rules(profile, [], [])
    return [check_input(str(SAMPLES / f"{name}.log"), i, profile, rules)
            for i, name in enumerate(names)]


def _open_report(browser: Browser, tmp_path: Path, results: list[InputResult]) -> str:
    report = tmp_path / "report.html"
    report.write_text(html_reporter.render(results, {"fail_on": "error"}), encoding="utf-8")
    url = report.as_uri()
    browser.open(url)
    return url


def _rgb(hex_color: str) -> str:
    r, g, b = (int(hex_color[i:i + 2], 16) for i in (1, 3, 5))
    return f"rgb({r}, {g}, {b})"


# Where on screen is time t of a node's row? Scroll the row into view, then ask the page
# what it painted there: the element hit, its state and its computed fill colour.
PAINTED_AT = """
(function (timelineId, node, t) {
  const svg = document.querySelector('#' + CSS.escape(timelineId) + ' svg.tl-svg');
  const row = svg.querySelector('g.tl-row[data-node="' + node + '"]');
  row.scrollIntoView({block: 'center'});
  const box = svg.getBoundingClientRect();
  const v0 = +svg.dataset.viewStart, v1 = +svg.dataset.viewEnd;
  const x = box.left + +svg.dataset.plotX + (t - v0) / (v1 - v0) * +svg.dataset.plotWidth;
  const y = box.top + +row.dataset.barY + +row.dataset.barH / 2;
  const hit = document.elementFromPoint(x, y);
  return {state: hit && hit.getAttribute('data-state'),
          fill: hit && getComputedStyle(hit).fill};
})
"""


def _painted(browser: Browser, timeline_id: str, node: int, t: float) -> dict[str, str]:
    result: dict[str, str] = browser.evaluate(
        f"{PAINTED_AT}({json.dumps(timeline_id)}, {node}, {t})")
    return result


@pytest.mark.parametrize("name", SAMPLE_NAMES)
def test_sample_report_in_chromium(browser: Browser, tmp_path: Path, name: str) -> None:
    results = _results(name)
    res = results[0]
    url = _open_report(browser, tmp_path, results)
    browser.screenshot(SCREENSHOTS / f"{name}.png")

    assert browser.console_errors() == []
    assert [u for u in browser.requested_urls() if u != url] == []
    assert browser.evaluate("document.getElementById('verdict').textContent") == (
        "FAIL" if res.findings else "PASS")

    # One timeline row per node, in node order.
    nodes = res.nodes()
    rows = browser.evaluate("""Array.from(document.querySelectorAll('g.tl-row'))
        .map(g => g.dataset.node)""")
    assert rows == [str(n) for n in sorted(m.node for m in nodes)]

    # The painted colour at the middle of every interval wide enough to hit is its state's.
    timeline_id = html_reporter.timeline_id(res, "can0")
    start = res.stats.start or 0.0
    checked = 0
    for m in nodes:
        for iv in m.intervals:
            if iv.end - iv.start < 0.03 or iv.state == UNKNOWN:
                continue
            t = (iv.start + iv.end) / 2 - start
            painted = _painted(browser, timeline_id, m.node, t)
            assert painted == {"state": iv.state,
                               "fill": _rgb(html_reporter.STATE_COLORS[iv.state])}, (m.node, t)
            checked += 1
    assert checked >= len(nodes)
    for node, t, state in CHECKPOINTS[name]:
        assert _painted(browser, timeline_id, node, t) == {
            "state": state, "fill": _rgb(html_reporter.STATE_COLORS[state])}, (node, t)

    # Each finding is a marker whose hover text names the rule and the message.
    titles = browser.evaluate("""Array.from(document.querySelectorAll('polygon.marker'))
        .map(p => p.querySelector('title').textContent)""")
    assert len(titles) == len(res.findings)
    for f, title in zip(res.findings, titles, strict=True):
        assert title.startswith(f"{f.rule} {f.name}") and f.message in title
    table_rows = browser.evaluate("document.querySelectorAll('#findings-table tbody tr').length")
    assert table_rows == len(group_findings(res.findings))
    if not res.findings:
        assert "No findings" in browser.evaluate("document.getElementById('no-findings')"
                                                 ".textContent")


def test_all_samples_filter_sort_zoom_and_jump(browser: Browser, tmp_path: Path) -> None:
    """One report over every sample: the findings table filters and sorts, the timeline
    zooms, and a finding's time link brings its marker into a zoomed view."""
    results = _results(*SAMPLE_NAMES)
    url = _open_report(browser, tmp_path, results)
    assert browser.console_errors() == []
    assert [u for u in browser.requested_urls() if u != url] == []
    findings = [f for res in results for f in res.findings]
    assert len(findings) >= 5
    timelines = browser.evaluate("document.querySelectorAll('figure.timeline').length")
    assert timelines == len(results)

    def visible() -> list[dict[str, str]]:
        rows: list[dict[str, str]] = browser.evaluate("""Array.from(document.querySelectorAll(
            '#findings-table tbody tr')).filter(r => !r.hidden).map(r => ({
              rule: r.dataset.rule, node: r.dataset.node, severity: r.dataset.severity}))""")
        return rows

    def choose(select_id: str, value: str) -> None:
        browser.evaluate(f"""(() => {{ const s = document.getElementById('{select_id}');
            s.value = {json.dumps(value)}; s.dispatchEvent(new Event('change')); }})()""")

    assert len(visible()) == len(findings)
    choose("filter-rule", "H001")
    assert visible() == [{"rule": "H001", "node": "1/can0/3", "severity": "error"}]
    assert browser.evaluate("document.getElementById('filter-count').textContent") == (
        f"1 of {len(findings)} rows")
    choose("filter-rule", "")
    choose("filter-severity", "info")
    assert visible() == []
    choose("filter-severity", "error")
    assert {r["rule"] for r in visible()} == {f.rule for f in findings if f.severity == "error"}
    choose("filter-severity", "")
    choose("filter-node", "3/can0/5")
    assert visible() == [{"rule": "G001", "node": "3/can0/5", "severity": "error"}]
    choose("filter-node", "")
    browser.evaluate("""(() => { const i = document.getElementById('filter-text');
        i.value = 'toggle bit'; i.dispatchEvent(new Event('input')); })()""")
    assert [r["rule"] for r in visible()] == ["G001"]
    browser.evaluate("""(() => { const i = document.getElementById('filter-text');
        i.value = ''; i.dispatchEvent(new Event('input')); })()""")

    # Sorting by rule, twice: ascending then descending.
    browser.evaluate("document.querySelector('th[data-sort=rule]').click()")
    ascending = [r["rule"] for r in visible()]
    assert ascending == sorted(ascending)
    browser.evaluate("document.querySelector('th[data-sort=rule]').click()")
    assert [r["rule"] for r in visible()] == sorted(ascending, reverse=True)

    # Zoom in with the button: the view halves around its centre.
    hb_timeline = html_reporter.timeline_id(results[1], "can0")
    view = f"""(() => {{ const s = document.querySelector('#{hb_timeline} svg');
        return [+s.dataset.viewStart, +s.dataset.viewEnd]; }})()"""
    v0, v1 = browser.evaluate(view)
    browser.evaluate(f"document.querySelector('#{hb_timeline} button[data-zoom=in]').click()")
    browser.evaluate("new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))")
    z0, z1 = browser.evaluate(view)
    assert z1 - z0 == pytest.approx((v1 - v0) / 2)
    assert (z0 + z1) / 2 == pytest.approx((v0 + v1) / 2)
    browser.evaluate(f"document.querySelector('#{hb_timeline} button[data-zoom=fit]').click()")

    # Real mouse input: the wheel zooms in around the pointer, a drag to the right shows
    # earlier times.
    box = browser.evaluate(f"""(() => {{ const s = document.querySelector('#{hb_timeline} svg');
        s.scrollIntoView({{block: 'center'}}); const b = s.getBoundingClientRect();
        return [b.left + +s.dataset.plotX, b.top + b.height / 2, +s.dataset.plotWidth]; }})()""")
    x, y, plot_width = box
    pointer_x = x + plot_width * 0.75
    browser.send("Input.dispatchMouseEvent", {"type": "mouseWheel", "x": pointer_x, "y": y,
                                              "deltaX": 0, "deltaY": -120})
    browser.evaluate("new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))")
    w0, w1 = browser.evaluate(view)
    assert w1 - w0 < v1 - v0
    pointer_t = v0 + 0.75 * (v1 - v0)  # the time under the pointer stays under it
    assert w0 + 0.75 * (w1 - w0) == pytest.approx(pointer_t, abs=(v1 - v0) / plot_width)
    for kind, px, buttons in (("mousePressed", pointer_x, 1), ("mouseMoved", pointer_x + 40, 1),
                              ("mouseMoved", pointer_x + 100, 1),
                              ("mouseReleased", pointer_x + 100, 0)):
        browser.send("Input.dispatchMouseEvent", {"type": kind, "x": px, "y": y,
                                                  "button": "left", "buttons": buttons,
                                                  "clickCount": 1})
    browser.evaluate("new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))")
    p0, p1 = browser.evaluate(view)
    assert p1 - p0 == pytest.approx(w1 - w0)
    assert w0 - p0 == pytest.approx(100 / plot_width * (w1 - w0), rel=0.02)
    browser.evaluate(f"document.querySelector('#{hb_timeline} button[data-zoom=fit]').click()")

    # The H001 row's time link zooms its timeline to the moment and marks the finding.
    browser.evaluate("document.querySelector('tr[data-rule=H001] a.jump').click()")
    browser.evaluate("new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))")
    h001 = next(f for f in results[1].findings if f.rule == "H001")
    t = h001.time - (results[1].stats.start or 0.0)
    j0, j1 = browser.evaluate(view)
    assert j0 <= t <= j1 and j1 - j0 < v1 - v0
    focused = browser.evaluate(f"""Array.from(document.querySelectorAll(
        '#{hb_timeline} polygon.marker.focus')).map(p => p.dataset.group)""")
    assert len(focused) == 1

    # A rule link opens the rule's embedded documentation.
    browser.evaluate("document.querySelector('tr[data-rule=G001] a.rule-link').click()")
    assert browser.evaluate("document.getElementById('rule-G001').open") is True
    assert "toggle" in browser.evaluate("document.querySelector('#rule-G001 .doc').textContent")
    assert browser.console_errors() == []
    browser.evaluate("window.scrollTo(0, 0)")
    browser.screenshot(SCREENSHOTS / "all_samples.png")


def test_harness_catches_console_errors_and_requests(browser: Browser, tmp_path: Path) -> None:
    """The checks above can fail: a page that logs an error, throws and loads an image is
    caught (the image points at a closed loopback port, nothing leaves the machine)."""
    page = tmp_path / "bad.html"
    page.write_text("<!DOCTYPE html><img src='http://127.0.0.1:9/x.png'>"
                    "<script>console.error('boom'); null.x;</script>", encoding="utf-8")
    url = page.as_uri()
    browser.open(url)
    assert url in browser.requested_urls()
    assert "http://127.0.0.1:9/x.png" in browser.requested_urls()
    errors = browser.console_errors()
    assert any("boom" in e for e in errors)
    assert any("TypeError" in e for e in errors)
