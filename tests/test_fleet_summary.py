"""`nmtcheck fleet summary` as a fleet analyst reads it (issue 23 item 12): without
`--path-pattern` the log is the unit (never "0 devices", never paths called devices), the
docs' DuckDB query keeps logs without a device apart, the per-day chart has axes, dates
and counts, and rules come most findings first. Real sample logs from real stacks (the
repository's candump samples and Lely's), checked by real `check --results` runs; three
copies of heartbeat_loss.log are moved by whole days to give the chart several dates."""

from __future__ import annotations

import itertools
import os
import re
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from datetime import date, timedelta
from pathlib import Path

import pytest
from conftest import REPO, SAMPLES

pd = pytest.importorskip("pandas")
pytest.importorskip("pyarrow")
pytest.importorskip("fsspec")

import nmtcheck as api  # noqa: E402

FLAT = ["heartbeat_loss.log", "healthy.log", "guard_toggle.log", "reset_no_bootup.log",
        "lely/reboot.log", "lely/unplugged_heartbeat.log", "lely/self_1017.log",
        "lely/unplugged_guarded.log"]
DAY = 86400


def cli(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "nmtcheck", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=300, env=dict(os.environ))


def shifted(src: Path, dest: Path, days: int) -> None:
    """A candump -L log moved by whole days: the same traffic, another date."""
    def move(m: re.Match[str]) -> str:
        return f"({int(m.group(1)) + days * DAY}.{m.group(2)})"

    dest.parent.mkdir(parents=True, exist_ok=True)
    dest.write_text(re.sub(r"^\((\d+)\.(\d+)\)", move, src.read_text(), flags=re.M))


def check(root: Path, results: str, *args: str) -> None:
    res = cli("check", *args, "--results", results, "--isolated", "--executor", "local:1",
              cwd=root)
    assert res.returncode == 1, res.stdout + res.stderr  # the samples have error findings


@pytest.fixture(scope="module")
def fleets(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """`flat`: 8 logs in one folder, no device field. `mixed`: DEV1, DEV2 and two logs that
    the path pattern does not match. `devices`: only the DEVn logs (4 dates, one without
    findings between them)."""
    root = tmp_path_factory.mktemp("fleets")
    flat = _mkdir(root / "flat")
    for name in FLAT:
        shutil.copy(SAMPLES / name, flat / Path(name).name)
    hb = SAMPLES / "heartbeat_loss.log"
    shutil.copy(hb, _mkdir(root / "dev" / "DEV1") / "a.log")
    shifted(hb, root / "dev" / "DEV1" / "b.log", 1)
    shifted(hb, root / "dev" / "DEV2" / "c.log", 3)
    shutil.copy(SAMPLES / "reset_no_bootup.log", root / "dev" / "DEV2" / "d.log")
    shutil.copy(SAMPLES / "lely" / "reboot.log", root / "dev" / "reboot.log")
    shutil.copy(SAMPLES / "lely" / "unplugged_heartbeat.log", root / "dev" / "unplugged.log")
    check(root, "flat-results", "flat/*.log")
    check(root, "mixed-results", "dev/**/*.log", "--path-pattern", "DEV{device}/{split}.log")
    check(root, "devices-results", "dev/DEV*/*.log", "--path-pattern",
          "DEV{device}/{split}.log")
    return root


def _mkdir(p: Path) -> Path:
    p.mkdir(parents=True, exist_ok=True)
    return p


def summary(root: Path, results: str, *args: str) -> subprocess.CompletedProcess[str]:
    res = cli("fleet", "summary", results, *args, cwd=root)
    assert res.returncode == 0 and "Traceback" not in res.stderr, res.stderr
    return res


# 1. the unit: devices with --path-pattern, logs without

def test_without_a_device_field_the_summary_counts_and_lists_logs(fleets: Path) -> None:
    res = summary(fleets, "flat-results", "-o", "flat.html", "-o", "flat.csv")
    lines = res.stdout.splitlines()
    assert lines[1].startswith("8 logs, no device names (each log is its own unit")
    assert "0 devices" not in res.stdout and "worst devices" not in res.stdout
    h001 = lines.index("H001: worst logs")
    assert lines[h001 + 1].split()[:4] == ["log", "findings", "logs", "nodes"]
    # self_1017's 24 gaps over an assumed timeout are one H001 (issue 38): a tie at 1
    rows = [line.split()[:2] for line in lines[h001 + 2:h001 + 10]]
    assert [str(fleets / "flat" / "self_1017.log"), "1"] in rows
    assert all(count == "1" for _log, count in rows[:3])
    page = (fleets / "flat.html").read_text()
    assert "0 devices" not in page and "Worst devices" not in page
    assert "8 logs, no device names" in page and "<h3>Worst logs</h3>" in page
    table = pd.read_csv(fleets / "flat.csv")
    assert "devices" not in set(table["section"])
    logs = table[table["section"] == "logs"]
    assert logs["device"].isna().all() and logs["log"].str.endswith(".log").all()
    nodes = table[table["section"] == "nodes"]
    assert nodes["device"].isna().all() and nodes["log"].notna().all()


def test_with_a_device_field_the_summary_counts_and_lists_devices(fleets: Path) -> None:
    res = summary(fleets, "devices-results", "-o", "devices.csv")
    lines = res.stdout.splitlines()
    assert lines[1].startswith("4 logs, 2 devices, ")
    h001 = lines.index("H001: worst devices")
    assert lines[h001 + 1].split()[:4] == ["device", "findings", "logs", "nodes"]
    # DEV1 holds two of the three heartbeat_loss copies
    assert lines[h001 + 2].split()[:3] == ["1", "2", "2"]
    assert "worst logs" not in res.stdout and "no device" not in res.stdout
    table = pd.read_csv(fleets / "devices.csv")
    assert "logs" not in set(table["section"]) and table["log"].isna().all()


def test_logs_the_pattern_does_not_match_count_as_logs_beside_the_devices(
        fleets: Path) -> None:
    res = summary(fleets, "mixed-results")
    lines = res.stdout.splitlines()
    assert lines[1].startswith("6 logs, 2 devices and 2 logs without a device, ")
    h001 = lines.index("H001: worst devices and logs")
    assert lines[h001 + 1].split()[:3] == ["device", "log", "findings"]
    rows = lines[h001 + 2:lines.index("H001: worst nodes", h001)]
    assert rows[0].split()[:3] == ["1", "2", "2"]
    by_log = {r.split()[0]: r.split()[1] for r in rows if r.split()[0].startswith("/")}
    assert by_log == {str(fleets / "dev" / "reboot.log"): "1",
                      str(fleets / "dev" / "unplugged.log"): "1"}


# 2. the DuckDB query of docs/reference/dataset.md

def _docs_query() -> str:
    page = (REPO / "docs" / "reference" / "dataset.md").read_text(encoding="utf-8")
    blocks: list[str] = re.findall(r"```sql\n(.*?)```", page, flags=re.S)
    [sql] = [q for q in blocks if "rule = 'H001'" in q]
    return sql


@pytest.mark.parametrize("results", ["flat-results", "mixed-results", "devices-results"])
def test_the_docs_duckdb_query_keeps_logs_without_a_device_apart(
        fleets: Path, results: str, monkeypatch: pytest.MonkeyPatch) -> None:
    duckdb = pytest.importorskip("duckdb")
    monkeypatch.chdir(fleets)
    sql = _docs_query().replace("'results/", f"'{results}/")
    table = duckdb.sql(sql).to_arrow_table()  # fetchall() of a timestamptz needs pytz
    rows = list(zip(*(table.column(c).to_pylist() for c in range(4)), strict=True))
    # what it must say, from nmtcheck's own reader: H001 per device, or per log without one
    f = api.read_results(fleets / results).findings
    f = f[f["rule"] == "H001"]
    units = f["device"].fillna(f["url"])
    want = (f.assign(unit=units).groupby(["unit", "channel", "node"]).size()
            .sort_values(ascending=False))
    assert len(rows) == min(len(want), 10)
    assert all(isinstance(r[0], str) for r in rows)
    got = {(r[0], r[1], int(r[2])): r[3] for r in rows}
    assert got == {(u, c, int(n)): k for (u, c, n), k in want.items()}
    if results == "flat-results":  # two Lely logs share vcan0 node 3: NULL merged them
        assert sum(1 for u, c, n in got if (c, n) == ("vcan0", 3)) == 2


# 3. the per-day chart

def _chart(page: str) -> ET.Element:
    [svg] = re.findall(r"<svg.*?</svg>", page, flags=re.S)
    return ET.fromstring(svg)


def test_the_per_day_chart_has_dates_counts_and_a_y_axis(fleets: Path) -> None:
    summary(fleets, "devices-results", "-o", "devices.html")
    svg = _chart((fleets / "devices.html").read_text())
    f = api.read_results(fleets / "devices-results").findings
    per_day = f["abs_time"].dt.strftime("%Y-%m-%d").value_counts().to_dict()
    assert len(per_day) == 3  # D, D+1 and D+3: the reset_no_bootup and heartbeat logs
    first = date.fromisoformat(min(per_day))
    span = [str(first + timedelta(days=i)) for i in range(4)]
    assert sorted(per_day) == [span[0], span[1], span[3]]
    # every day of the span under its bar, the day without findings too
    dates = [t.text for t in svg.iter("text") if t.get("class") == "date"]
    assert dates == span
    days = {g.get("data-date"): g for g in svg.iter("g") if g.get("class") == "day"}
    assert list(days) == span
    for day in span:
        n = per_day.get(day, 0)
        counts = [t.text for t in days[day].iter("text") if t.get("class") == "count"]
        assert counts == ([str(n)] if n else [])
        assert days[day].find("title").text.startswith(f"{day}: {n} finding")  # type: ignore[union-attr]
        assert (days[day].find("rect") is not None) == (n > 0)
    ticks = [int(t.text) for t in svg.iter("text") if t.get("class") == "tick"]  # type: ignore[arg-type]
    assert ticks[0] == 0 and ticks[-1] >= max(per_day.values()) and len(ticks) >= 3
    assert len({b - a for a, b in itertools.pairwise(ticks)}) == 1  # an even scale
    titles = [t.text for t in svg.iter("text") if t.get("class") == "axis-title"]
    assert titles == ["findings", "day (UTC)"]


def test_a_span_too_long_for_one_bar_per_day_shows_the_days_with_findings(
        fleets: Path) -> None:
    page = summary(fleets, "flat-results", "--format", "html").stdout
    svg = _chart(page)
    f = api.read_results(fleets / "flat-results").findings
    per_day = f["abs_time"].dt.strftime("%Y-%m-%d").value_counts()
    assert [t.text for t in svg.iter("text") if t.get("class") == "date"] == sorted(per_day.index)
    assert "only the days with findings are shown" in page


def test_a_fleet_without_findings_has_no_chart(tmp_path: Path) -> None:
    shutil.copy(SAMPLES / "healthy.log", tmp_path / "healthy.log")
    res = cli("check", "healthy.log", "--results", "results", "--isolated", "--executor",
              "local:1", cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    page = summary(tmp_path, "results", "--format", "html").stdout
    assert "<svg" not in page and "No findings." in page
    assert "1 logs, no device names" in page


# 4. rules by count

def test_rule_sections_come_most_findings_first_ties_by_code(fleets: Path) -> None:
    res = summary(fleets, "flat-results", "--format", "text")
    f = api.read_results(fleets / "flat-results").findings
    counts = f["rule"].value_counts()
    want = sorted(counts.index, key=lambda r: (-counts[r], r))
    assert want != sorted(want)  # not alphabetical here: H001 has 24 of self_1017's findings
    assert len(set(counts.values)) < len(counts)  # and there are ties
    got = [line.split(":")[0] for line in res.stdout.splitlines()
           if re.fullmatch(r"[A-Z]\d{3}: worst (devices|logs|devices and logs)", line)]
    assert got == want
    heads = [line for line in res.stdout.splitlines() if re.match(r"[A-Z]\d{3} \S+: \d+ ", line)]
    assert heads[0].startswith(f"H001 heartbeat-timeout: {counts['H001']} findings in ")
    page = summary(fleets, "flat-results", "--format", "html").stdout
    assert re.findall(r"<h2>([A-Z]\d{3}) ", page) == want
    table = pd.read_csv(pd.io.common.StringIO(
        summary(fleets, "flat-results", "--format", "csv").stdout))
    rules = table[table["section"] == "rules"]
    assert rules["rule"].tolist() == want
    assert rules["findings"].astype(int).tolist() == [int(counts[r]) for r in want]
