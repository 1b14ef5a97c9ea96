"""The fleet dataset's `boot` table (SPEC_BOOT §8.5): one row per boot process, read back
with DuckDB and pyarrow, and the same rows in the Python API. Real Lely recordings
(samples/lely/: every boot `ok`, node 3 of reboot.log booted twice) and the SPEC's P001
vector (a product-code mismatch, letter M) as a device's failed boot, once last week and
once a month ago."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from conftest import SAMPLES
from test_rules_boot import P001_LOG as P001_VECTOR
from test_rules_boot import P001_NET

pa = pytest.importorskip("pyarrow")
pytest.importorskip("fsspec")
duckdb = pytest.importorskip("duckdb")
import pyarrow.dataset as pads  # noqa: E402

import nmtcheck  # noqa: E402
from nmtcheck.fleet.dataset import COLUMNS  # noqa: E402

LELY = SAMPLES / "lely"
# SPEC_BOOT §8.7, P001 (verbatim, from the rule's tests) with its network file: letter M at
# 10.026 s, line 9
P001_LOG = P001_VECTOR.lstrip("\n")
DAY = 86400.0


def failed_m_query(results: Path) -> str:
    """The docs' query (docs/reference/dataset.md, the SQL block after "letter M"), with
    the results folder filled in: the test runs what the page shows."""
    page = (Path(__file__).resolve().parents[1] / "docs" / "reference" / "dataset.md"
            ).read_text()
    block = page[page.index("```sql", page.index("with letter M")) + len("```sql"):]
    return block[:block.index("```")].replace("'results/", f"'{results}/")



def cli(cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    res = subprocess.run([sys.executable, "-m", "nmtcheck", "check", *args, "--isolated",
                          "--results", "results", "--executor", "local:1",
                          "--path-pattern", "{device}/{split}.log", "--fail-on", "never"],
                         cwd=cwd, capture_output=True, text=True, timeout=300,
                         env=dict(os.environ))
    assert res.returncode == 0, res.stdout + res.stderr
    return res


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tmp = tmp_path_factory.mktemp("fleet_boot")
    for name in ("healthy", "reboot", "unplugged_guarded"):
        (tmp / "lely" / f"DEV{name}").mkdir(parents=True)
        shutil.copy(LELY / f"{name}.log", tmp / "lely" / f"DEV{name}" / "run.log")
    cli(tmp, "lely/**/*.log", "--network", str(LELY / "network.toml"))
    now = time.time()
    for device, age in (("DEVM", 2 * DAY), ("DEVOLD", 30 * DAY)):
        log = tmp / "p001" / device / "run.log"
        log.parent.mkdir(parents=True)
        log.write_text(P001_LOG)
        os.utime(log, (now - age, now - age))  # no epoch times: dated by the file
    (tmp / "boot.toml").write_text(P001_NET)
    cli(tmp, "p001/**/*.log", "--network", "boot.toml")
    return tmp / "results"


def test_boot_table_reads_with_duckdb_and_pyarrow(fleet: Path) -> None:
    glob = f"{fleet}/boot/**/*.parquet"
    rel = duckdb.sql(f"select * from read_parquet('{glob}', hive_partitioning=true)")
    assert rel.columns == [n for n, _k in COLUMNS["boot"]] + ["date"]
    arrow = pads.dataset(str(fleet / "boot"), format="parquet", partitioning="hive").to_table()
    assert arrow.column_names == rel.columns
    rows = duckdb.sql(f"select device, node, process, processes, last, status, letter "
                      f"from read_parquet('{glob}', hive_partitioning=true) "
                      "order by device, node, process").fetchall()
    assert len(rows) == arrow.num_rows
    by_device: dict[str, list[tuple[object, ...]]] = {}
    for device, *rest in rows:
        by_device.setdefault(device, []).append(tuple(rest))
    # the Lely manager boots nodes 2, 3, 4: ok; node 3 of reboot.log twice (the second
    # after its spontaneous reboot), node 4 of unplugged_guarded.log after its reset
    assert by_device["DEVhealthy"] == [(n, 0, 1, True, "ok", None) for n in (2, 3, 4)]
    assert by_device["DEVreboot"] == [(2, 0, 1, True, "ok", None), (3, 0, 2, False, "ok", None),
                                      (3, 1, 2, True, "ok", None), (4, 0, 1, True, "ok", None)]
    assert [r[:4] for r in by_device["DEVunplugged_guarded"]] == [
        (2, 0, 1, True), (3, 0, 1, True), (4, 0, 2, False), (4, 1, 2, True)]
    assert by_device["DEVM"] == by_device["DEVOLD"] == [(2, 0, 1, True, "failed", "M")]


def test_failed_with_letter_m_last_week(fleet: Path) -> None:
    got = duckdb.sql(failed_m_query(fleet)).fetchall()
    assert len(got) == 1  # DEVOLD failed the same way a month ago
    device, channel, node, letter, text, line, _date = got[0]
    assert (device, channel, node, letter, line) == ("DEVM", "can0", 2, "M", 9)
    assert text.startswith("Value of object 1018 sub-index 02 from CANopen device is "
                           "different to value in object 1F86")


def test_failed_row_carries_the_proving_frame(fleet: Path) -> None:
    data = nmtcheck.read_results(fleet)
    b = data.boot
    row = b[(b["device"] == "DEVM")].iloc[0]
    assert (row["evidence_time"], row["evidence_frame_index"], row["evidence_line"]) == (
        10.026, 8, 9)
    assert (row["anchor"], row["attempts"], row["findings"], row["letter_source"]) == (
        "bootup", 1, "P001", "observed")
    assert pd_isna(row["abs_start"])  # 10.0 s is no date: no absolute time
    ok = b[(b["device"] == "DEVhealthy") & (b["node"] == 2)].iloc[0]
    assert ok["abs_start"].year == 2023 and ok["started_at"] > ok["start"]
    # an ok process is proved by the start command: `000#0102`, line 68 of healthy.log
    assert ok["last_step"] == "start" and ok["evidence_line"] == 68
    assert (LELY / "healthy.log").read_text().splitlines()[67].endswith("000#0102")


def test_api_check_has_the_same_rows() -> None:
    report = nmtcheck.check([LELY / "reboot.log"], network=LELY / "network.toml")
    b = report.boot
    assert list(b[["node", "process", "status"]].itertuples(index=False, name=None)) == [
        (2, 0, "ok"), (3, 0, "ok"), (3, 1, "ok"), (4, 0, "ok")]
    assert set(b["path"]) == {str(LELY / "reboot.log")}
    assert b["start_utc"].notna().all()
    # a log with no boot process: an empty table with the columns
    empty = nmtcheck.check([SAMPLES / "heartbeat_loss.log"]).boot
    assert len(empty) == 0 and {"status", "letter", "letter_text"} <= set(empty.columns)


def pd_isna(v: Any) -> bool:
    import pandas as pd

    return bool(pd.isna(v))


def test_api_boot_table_has_the_letters_the_lely_master_reported() -> None:
    """samples/lely/boot/identity: Lely's own OnBoot verdicts (the .onboot.jsonl beside the
    log) are the boot table's letters, node by node; node 7, which booted, is `ok`."""
    import json

    folder = LELY / "boot" / "identity"
    said = [json.loads(line) for line in
            (folder / "identity.onboot.jsonl").read_text().splitlines() if line.strip()]
    lely = {int(d["node"]): d["es"] or None for d in said}
    b = nmtcheck.check([folder / "identity.log"], network=folder / "network.toml").boot
    last = b[b["last"]]
    got = {int(r.node): (r.status, None if pd_isna(r.letter) else r.letter)
           for r in last.itertuples() if r.node in lely}
    assert got == {n: ("ok", None) if es is None else ("failed", es)
                   for n, es in lely.items()}
    assert sorted(x for x in lely.values() if x) == ["C", "D", "M", "N", "O"]
