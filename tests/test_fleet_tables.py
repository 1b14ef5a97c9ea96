"""Every table of the results dataset exists with its schema from the first run on (issue
25): on a fleet whose logs are all clean, DuckDB and pyarrow.dataset read `findings/` (and
each other table) as zero rows with every column, never "no such path"."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import SAMPLES

pa = pytest.importorskip("pyarrow")
pytest.importorskip("fsspec")
duckdb = pytest.importorskip("duckdb")
import pyarrow.dataset as pads  # noqa: E402

from nmtcheck.fleet.dataset import COLUMNS, SCHEMA_PART, TABLES, Dataset  # noqa: E402


def run(tmp_path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "nmtcheck", "check", *args, "--isolated",
                           "--results", "results", "--executor", "local:1"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=300,
                          env=dict(os.environ))


def clean_fleet(tmp_path: Path) -> None:
    """Two clean logs: one healthy network (nodes, no findings), one of SYNC frames only
    (no node at all)."""
    logs = tmp_path / "logs"
    logs.mkdir()
    shutil.copy(SAMPLES / "healthy.log", logs / "healthy.log")
    (logs / "sync.log").write_text("".join(f"({1700000000 + i}.000000) can0 080#\n"
                                           for i in range(5)))


def rows(results: Path, table: str) -> tuple[int, list[str], int, list[str]]:
    """(rows, columns) of one table as DuckDB reads it, then as pyarrow.dataset does."""
    glob = str(results / table / "**" / "*.parquet")
    rel = duckdb.sql(f"select * from read_parquet('{glob}', hive_partitioning=true)")
    [(n_duck,)] = duckdb.sql(f"select count(*) from read_parquet('{glob}', "
                             "hive_partitioning=true)").fetchall()
    arrow = pads.dataset(str(results / table), format="parquet",
                         partitioning="hive").to_table()
    return n_duck, list(rel.columns), arrow.num_rows, arrow.column_names


def test_every_table_of_an_all_clean_fleet_reads_as_zero_rows(tmp_path: Path) -> None:
    clean_fleet(tmp_path)
    res = run(tmp_path, "logs/*.log")
    assert res.returncode == 0, res.stderr
    assert "fleet: 0 errors, 0 warnings, 0 info" in res.stdout
    results = tmp_path / "results"
    # the SYNC-only log's channel has its sync_stats row (SPEC_COMM §9.4.2: a measurement,
    # not a finding); no PDO, no EMCY
    expected_rows = {"runs": 1, "inputs": 2, "findings": 0, "node_stats": None, "boot": 0,
                     "sync_stats": 1, "pdo_stats": 0, "emcy": 0, "lss": 0}
    for table in TABLES:
        n_duck, duck_cols, n_arrow, arrow_cols = rows(results, table)
        columns = [name for name, _kind in COLUMNS[table]] + ["date"]
        assert duck_cols == columns, table
        assert arrow_cols == columns, table
        assert n_duck == n_arrow, table
        if expected_rows[table] is not None:
            assert n_duck == expected_rows[table], table
    # the healthy log's nodes have their rows; the SYNC-only log has none
    n_nodes = rows(results, "node_stats")[0]
    assert n_nodes > 0
    # dates stay DATEs for DuckDB (the schema files' partition is a date too)
    date_type = duckdb.sql(
        f"select typeof(date) from read_parquet('{results}/inputs/**/*.parquet', "
        "hive_partitioning=true) limit 1").fetchall()
    assert date_type == [("DATE",)]


def test_a_fleet_without_any_node_has_empty_findings_and_node_stats(tmp_path: Path) -> None:
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "sync.log").write_text("(1700000000.000000) can0 080#\n")
    res = run(tmp_path, "logs/*.log")
    assert res.returncode == 0, res.stderr
    results = tmp_path / "results"
    for table in ("findings", "node_stats"):
        n_duck, _cols, n_arrow, _acols = rows(results, table)
        assert n_duck == n_arrow == 0, table
    # the API and the summary read the empty tables too
    import nmtcheck

    data = nmtcheck.read_results(results)
    assert len(data.findings) == 0 and len(data.node_stats) == 0
    assert list(data.findings.columns) == [n for n, _k in COLUMNS["findings"]] + ["date"]


def test_schema_files_are_written_once_and_kept(tmp_path: Path) -> None:
    """A dataset of an earlier nmtcheck (no schema files) gets them at its next run; a run
    with nothing to do writes nothing; removing uncommitted batches keeps them."""
    clean_fleet(tmp_path)
    assert run(tmp_path, "logs/*.log").returncode == 0
    results = tmp_path / "results"
    schema_files = [results / t / SCHEMA_PART[0] / SCHEMA_PART[1] for t in TABLES]
    assert all(p.is_file() for p in schema_files)
    schema_files[2].unlink()
    ds = Dataset(str(results))
    ds.ensure()
    assert schema_files[2].is_file()
    assert ds.remove_uncommitted() == 0
    mtimes = {p.stat().st_mtime_ns for p in results.rglob("*") if p.is_file()}
    assert run(tmp_path, "logs/*.log").returncode == 0  # nothing new: nothing written
    assert {p.stat().st_mtime_ns for p in results.rglob("*") if p.is_file()} == mtimes


def test_check_results_names_the_next_step(tmp_path: Path) -> None:
    """After `check --results DIR`, the run's summary says that `nmtcheck fleet summary
    DIR` is the next step (issue 23, 12); -q leaves it out."""
    out = tmp_path / "my results"
    cmd = [sys.executable, "-m", "nmtcheck", "check", "--isolated",
           str(SAMPLES / "healthy.log"), "--results", str(out)]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    assert res.stdout.splitlines()[-1] == f"next: nmtcheck fleet summary '{out}'"
    quiet = subprocess.run([*cmd, "-q"], capture_output=True, text=True, timeout=300,
                           cwd=tmp_path)
    assert "next:" not in quiet.stdout
