"""The fleet dataset's `lss` table (SPEC §9.4.2): one row per LSS request, written by
`nmtcheck check --results` and read back by `nmtcheck.read_results` and DuckDB, on the
CANopenNode LSS recordings."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import SAMPLES

pytest.importorskip("pyarrow")
pytest.importorskip("fsspec")
duckdb = pytest.importorskip("duckdb")

import nmtcheck  # noqa: E402
from nmtcheck.fleet.dataset import COLUMNS  # noqa: E402

LSS = SAMPLES / "canopennode" / "lss"


def test_lss_table(tmp_path: Path) -> None:
    for name in ("lss_configure_store", "lss_store_error"):
        (tmp_path / "logs" / f"DEV{name}").mkdir(parents=True)
        shutil.copy(LSS / f"{name}.log", tmp_path / "logs" / f"DEV{name}" / "run.log")
    res = subprocess.run([sys.executable, "-m", "nmtcheck", "check", "logs/**/*.log",
                          "--isolated", "--results", "results", "--executor", "local:1",
                          "--path-pattern", "{device}/{split}.log", "--fail-on", "never"],
                         cwd=tmp_path, capture_output=True, text=True, timeout=300,
                         env=dict(os.environ))
    assert res.returncode == 0, res.stdout + res.stderr
    glob = f"{tmp_path}/results/lss/**/*.parquet"
    rel = duckdb.sql(f"select * from read_parquet('{glob}', hive_partitioning=true)")
    assert rel.columns == [n for n, _k in COLUMNS["lss"]] + ["date"]
    data = nmtcheck.read_results(tmp_path / "results")
    t = data.lss
    mine = t[t["device"] == "DEVlss_store_error"].sort_values("exchange")
    assert list(mine["service"]) == [
        "switch-state-selective-vendor", "switch-state-selective-product",
        "switch-state-selective-revision", "switch-state-selective-serial",
        "configure-node-id", "store-configuration", "switch-state-global"]
    store = mine[mine["service"] == "store-configuration"].iloc[0]
    assert store["result"] == "error" and store["cfg"] == "some"
    assert json.loads(store["responses"])[0]["text"] == "not supported"
    assert len(t[t["device"] == "DEVlss_configure_store"]) == 8
