"""The fleet dataset's SPEC_COMM §9.4.2 tables (`sync_stats`, `pdo_stats`, `emcy`) and the
findings' `cob_id`, `causes`, `reactions` and `root_kind`, on CANopenNode recordings
(samples/canopennode/sync_emcy/ and pdo/, each with its network file, as
tests/test_samples_sync_emcy.py and tests/test_samples_pdo.py run them).

Each row must equal the JSON report of the same log (`nmtcheck check --format json`, a
separate process): the dataset is the JSON's `channels[i].sync`, `pdo_streams[]` and
`nodes[i].emcy` flattened with `_`, never a second derivation. The flattening here is the
test's own, written from the docs' rule (docs/reference/dataset.md), not nmtcheck's.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from conftest import SAMPLES

pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")
duckdb = pytest.importorskip("duckdb")

from nmtcheck.fleet.dataset import COLUMNS, CONSUMER_FIELDS, MARKER, SCHEMA_VERSION  # noqa: E402

CN = SAMPLES / "canopennode"
# (log, network file): every sync_emcy and pdo recording, and a log without SYNC/PDO/EMCY
LOGS = {
    "sync_counter": (CN / "sync_emcy" / "sync_counter.log",
                     CN / "sync_emcy" / "network_sync_counter.toml"),
    "sync_counter_skip": (CN / "sync_emcy" / "sync_counter_skip.log",
                          CN / "sync_emcy" / "network_sync_counter.toml"),
    "sync_producer_stopped": (CN / "sync_emcy" / "sync_producer_stopped.log",
                              CN / "sync_emcy" / "network_sync_stopped.toml"),
    "emcy_inhibit": (CN / "sync_emcy" / "emcy_inhibit.log",
                     CN / "sync_emcy" / "network_emcy.toml"),
    **{name: (CN / "pdo" / f"{name}.log", CN / "pdo" / f"network_{name}.toml")
       for name in ("rpdo_producer_stopped", "rpdo_timeout_stale_heartbeat",
                    "tpdo_event_timer", "tpdo_inhibit_bypass", "rpdo_length", "sync_tpdo")},
    "healthy": (SAMPLES / "healthy.log", None),
}
MAPS = {"dlc", "measured_dlc", "findings"}  # maps of varying keys: JSON text in the dataset


def nmtcheck(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "nmtcheck", *args], capture_output=True,
                          text=True, timeout=300, cwd=cwd, env=dict(os.environ))


def flatten(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, dict) and f"{prefix}{k}" not in MAPS:
            out.update(flatten(v, f"{prefix}{k}_"))
        else:
            out[f"{prefix}{k}"] = v
    return out


@pytest.fixture(scope="module")
def checked(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[dict[str, Any],
                                                                         dict[str, Any]]]:
    """Per log: (its JSON report, its dataset's tables as Python rows by table)."""
    out = {}
    for name, (log, network) in LOGS.items():
        net = ["--network", str(network)] if network is not None else []
        res = nmtcheck("check", str(log), *net, "--isolated", "--format", "json")
        assert res.returncode in (0, 1), res.stderr
        report = json.loads(res.stdout)
        results = tmp_path_factory.mktemp(name) / "results"
        res = nmtcheck("check", str(log), *net, "--isolated", "--results", str(results),
                       "--executor", "local:1")
        assert res.returncode in (0, 1), res.stderr
        tables = {t: _rows(results, t) for t in ("sync_stats", "pdo_stats", "emcy", "findings")}
        tables["_dir"] = results  # type: ignore[assignment]
        out[name] = (report, tables)
    return out


def _rows(results: Path, table: str) -> list[dict[str, Any]]:
    """The table's rows of the log's batch (the zero-row schema file left aside)."""
    files = [p for p in (results / table).rglob("part-*.parquet")
             if p.name != "part-schema.parquet"]
    return [r for p in files for r in pq.read_table(p).to_pylist()]


def _equal(row: dict[str, Any], expected: dict[str, Any], what: str) -> None:
    """Each JSON field is the row's column of its flattened name, maps as JSON text; a
    field that is not null has its column (nothing left out of the dataset)."""
    for key, value in expected.items():
        if key in MAPS:
            assert json.loads(row[key]) == value, (what, key)
        elif value is None:
            assert row.get(key) is None, (what, key)
        else:
            assert key in row, (what, key, "not in the dataset")
            assert row[key] == value, (what, key, row[key], value)


def _value_nulls(row: dict[str, Any], expected: dict[str, Any]) -> None:
    """The columns of a value the JSON leaves out (`node`, `time`, `line` where they do
    not apply) are null, never filled in."""
    for key in row:
        if key.endswith(("_node", "_time", "_line")) and key not in expected \
                and key != "producer_node":
            assert row[key] is None, key


@pytest.mark.parametrize("name", list(LOGS))
def test_sync_stats_rows_are_the_json_channels_sync(checked: Any, name: str) -> None:
    report, tables = checked[name]
    expected = [{"channel": c["name"], **flatten(c["sync"])} for c in report["channels"]
                if c["sync"] is not None]
    rows = sorted(tables["sync_stats"], key=lambda r: r["channel"])
    assert len(rows) == len(expected)
    for row, exp in zip(rows, expected, strict=True):
        _equal(row, exp, f"{name} sync")
        _value_nulls(row, exp)


def test_the_sync_recordings_have_their_sync_rows(checked: Any) -> None:
    """Not an empty comparison: the SYNC logs have a row with the period of their network
    file and the frames the log holds."""
    for name in ("sync_counter", "sync_producer_stopped"):
        _report, tables = checked[name]
        [row] = tables["sync_stats"]
        log, _net = LOGS[name]
        syncs = sum(1 for line in log.read_text().splitlines() if " 080#" in line)
        assert row["frames"] == syncs > 0
        assert (row["period_us_value"], row["period_us_source"]) == (20000, "network")
        assert row["measured_intervals"] > 0


@pytest.mark.parametrize("name", list(LOGS))
def test_pdo_stats_rows_are_the_json_pdo_streams(checked: Any, name: str) -> None:
    report, tables = checked[name]
    rows = {(r["channel"], r["cob_id"]): r for r in tables["pdo_stats"]}
    assert len(rows) == len(tables["pdo_stats"]) == len(report["pdo_streams"])
    for st in report["pdo_streams"]:
        row = rows[(st["channel"], st["cob_id"])]
        exp = flatten({k: v for k, v in st.items() if k not in ("input", "consumers")})
        _equal(row, exp, f"{name} pdo {st['cob_id']}")
        _value_nulls(row, exp)
        assert len(row["consumers"]) == len(st["consumers"])
        for got, consumer in zip(row["consumers"], st["consumers"], strict=True):
            _equal(got, flatten(consumer), f"{name} pdo {st['cob_id']} consumer")


def test_the_pdo_recordings_have_streams_with_consumers(checked: Any) -> None:
    """rpdo_producer_stopped: node 2's TPDO 182h is consumed by node 3's RPDO with the
    network file's event timer (250 ms), and D004 is counted on it."""
    _report, tables = checked["rpdo_producer_stopped"]
    [row] = [r for r in tables["pdo_stats"] if r["cob_id"] == "182h"]
    assert (row["kind"], row["producer_node"]) == ("tpdo", 2)
    assert [(c["node"], c["event_timer_ms_value"], c["event_timer_ms_source"])
            for c in row["consumers"]] == [(3, 250, "network")]
    assert json.loads(row["findings"]) == {"D004": 1}
    assert row["measured_frames"] > 0


@pytest.mark.parametrize("name", list(LOGS))
def test_emcy_rows_are_the_json_nodes_emcy_codes(checked: Any, name: str) -> None:
    report, tables = checked[name]
    expected = []
    for n in report["nodes"]:
        if n["emcy"] is None:
            continue
        node = {"channel": n["channel"], "node": n["node"],
                **flatten({k: v for k, v in n["emcy"].items() if k != "codes"})}
        expected += [{**node, **code} for code in n["emcy"]["codes"]]
    rows = {(r["channel"], r["node"], r["code"]): r for r in tables["emcy"]}
    assert len(rows) == len(tables["emcy"]) == len(expected)
    for exp in expected:
        _equal(rows[(exp["channel"], exp["node"], exp["code"])], exp, f"{name} emcy")


def test_the_emcy_rows_count_what_the_stack_sent(checked: Any) -> None:
    """emcy_inhibit: per node and code, the rows count the EMCY frames on the node's
    COB-ID in the log (dev.c's CO_EM callback names each one it sent, the sample tests
    check that); node 2 ends in error as the JSON says."""
    _report, tables = checked["emcy_inhibit"]
    log, _net = LOGS["emcy_inhibit"]
    on_bus: dict[tuple[int, str], int] = {}
    for line in log.read_text().splitlines():
        parts = line.split()
        if len(parts) != 3 or "#" not in parts[2]:
            continue
        can_id, data = parts[2].split("#", 1)
        if 0x081 <= int(can_id, 16) <= 0x0FF and len(data) >= 4 and not data.startswith("R"):
            code = f"{int(data[2:4] + data[0:2], 16):04X}h"
            key = (int(can_id, 16) - 0x80, code)
            on_bus[key] = on_bus.get(key, 0) + 1
    assert on_bus
    assert {(r["node"], r["code"]): r["count"] for r in tables["emcy"]} == on_bus
    assert {r["in_error_at_end"] for r in tables["emcy"] if r["node"] == 2} == {True}


@pytest.mark.parametrize("name", list(LOGS))
def test_findings_carry_cob_id_causes_and_reactions_as_the_json(checked: Any,
                                                                name: str) -> None:
    report, tables = checked[name]
    rows = tables["findings"]
    assert len(rows) == len(report["findings"])
    key = lambda f: (f["rule"], f["node"] if f["node"] is not None else -1,  # noqa: E731
                     f["frame_index"] if f["frame_index"] is not None else -1, f["message"])
    for row, f in zip(sorted(rows, key=key), sorted(report["findings"], key=key),
                      strict=True):
        assert row["cob_id"] == f.get("cob_id")
        if "causes" in f:
            assert json.loads(row["causes"]) == f["causes"]
            assert json.loads(row["reactions"]) == f["reactions"]
            assert (row["causes_omitted"], row["reactions_omitted"]) == (
                f["causes_omitted"], f["reactions_omitted"])
            assert (row["root_kind"] is None) == (not f["causes"])
        else:  # a rule without causes: null, as the JSON leaves the fields out
            assert (row["causes"], row["reactions"], row["root_kind"]) == (None, None, None)


def test_root_kind_of_the_rpdo_producer_stopped_chain(checked: Any) -> None:
    """node 2 stopped by the master -> D004 on node 3 (RPDO 182h) -> EMCY 8250h -> node 3
    PRE-OPERATIONAL (S005): the deepest first cause of both findings is the NMT stop, a
    frame the log holds (000#0202: stop node 2) at the line the chain names."""
    report, tables = checked["rpdo_producer_stopped"]
    [s005] = [f for f in report["findings"] if (f["rule"], f["node"]) == ("S005", 3)]
    assert [(c["kind"], c.get("code"), c.get("rule"), c["depth"])
            for c in s005["causes"]] == [("emcy", "8250h", None, 1),
                                         ("finding", None, "D004", 2),
                                         ("nmt", None, None, 3)]
    log, _net = LOGS["rpdo_producer_stopped"]
    line = log.read_text().splitlines()[s005["causes"][2]["line"] - 1]
    assert line.split()[-1] == "000#0202"
    by_rule = {(r["rule"], r["node"]): r for r in tables["findings"]}
    assert by_rule[("S005", 3)]["root_kind"] == "nmt"
    assert by_rule[("D004", 3)]["root_kind"] == "nmt"
    assert by_rule[("D004", 3)]["cob_id"] == "182h"
    # grouping "why" across a fleet: DuckDB reads the column without nmtcheck
    results = tables["_dir"]
    glob = f"{results}/findings/**/*.parquet"
    got = duckdb.sql(f"select rule, root_kind, count(*) from read_parquet('{glob}', "
                     "hive_partitioning = true) where root_kind is not null "
                     "group by all order by rule").fetchall()
    assert got == [("D004", "nmt", 1), ("S005", "nmt", 1)]


def test_types_in_parquet(checked: Any) -> None:
    """Each file has the schema of COLUMNS: lists as Parquet lists, consumers as a list of
    structs, values as int64, times as double; DuckDB unnests the consumers."""
    want = {"string": pa.string(), "int64": pa.int64(), "float64": pa.float64(),
            "bool": pa.bool_(), "timestamp": pa.timestamp("us", tz="UTC"),
            "list<string>": pa.list_(pa.string())}
    want["consumers"] = pa.list_(pa.struct([(n, want[t]) for n, t in CONSUMER_FIELDS]))
    for table in ("sync_stats", "pdo_stats", "emcy", "findings"):
        files = [p for _report, tables in checked.values()
                 for p in (tables["_dir"] / table).rglob("*.parquet")]
        assert any(p.name != "part-schema.parquet" for p in files), table  # rows, not only
        for path in files:  # the zero-row schema files
            sch = pq.read_schema(path)
            assert [(f.name, f.type) for f in sch] == [(n, want[t]) for n, t in
                                                       COLUMNS[table]], (table, path)
            assert sch.metadata[b"nmtcheck.schema_version"] == str(SCHEMA_VERSION).encode()
    results = checked["rpdo_producer_stopped"][1]["_dir"]
    assert dict((n, t) for n, t in COLUMNS["pdo_stats"])["parameters_event_timer_ms_value"] \
        == "int64"
    glob = f"{results}/pdo_stats/**/*.parquet"
    got = duckdb.sql(f"select cob_id, c.node, c.event_timer_ms_value from (select cob_id, "
                     f"unnest(consumers) as c from read_parquet('{glob}', "
                     "hive_partitioning = true))").fetchall()
    assert got == [("182h", 3, 250)]


def test_the_api_reads_the_new_tables(checked: Any) -> None:
    import nmtcheck as api

    _report, tables = checked["sync_producer_stopped"]
    data = api.read_results(tables["_dir"])
    assert data.schema_version == SCHEMA_VERSION
    assert len(data.sync_stats) == 1 and len(data.emcy) == len(tables["emcy"]) > 0
    assert data.sync_stats["period_us_value"].tolist() == [20000]
    assert set(data.emcy["code"]) == {r["code"] for r in tables["emcy"]}
    assert list(data.pdo_stats.columns) == [n for n, _t in COLUMNS["pdo_stats"]] + ["date"]


# -- a dataset of schema version 1 -----------------------------------------------------------

def _as_schema_1(results: Path) -> None:
    """What an nmtcheck of schema 1 left: its marker, no §9.4.2 tables, findings files
    without the columns version 2 added."""
    import shutil

    meta = json.loads((results / MARKER).read_text())
    meta.update(schema_version=1, tables=["runs", "inputs", "findings", "node_stats", "boot"])
    (results / MARKER).write_text(json.dumps(meta))
    for table in ("sync_stats", "pdo_stats", "emcy"):
        shutil.rmtree(results / table)
    added = {"cob_id", "causes", "causes_omitted", "reactions", "reactions_omitted",
             "root_kind"}
    for path in (results / "findings").rglob("*.parquet"):
        t = pq.read_table(path, partitioning=None)
        t = t.select([n for n in t.column_names if n not in added])
        t = t.replace_schema_metadata({b"nmtcheck.schema_version": b"1",
                                       b"nmtcheck.table": b"findings"})
        pq.write_table(t, path)


def test_a_schema_1_dataset_is_read_and_refused_for_writing(tmp_path: Path) -> None:
    log, net = LOGS["rpdo_producer_stopped"]
    results = tmp_path / "results"
    args = ["check", str(log), "--network", str(net), "--isolated", "--results", str(results),
            "--executor", "local:1"]
    assert nmtcheck(*args).returncode == 1
    _as_schema_1(results)
    import nmtcheck as api

    data = api.read_results(results)
    assert data.schema_version == 1
    assert len(data.findings) == 4 and data.findings["root_kind"].isna().all()
    assert len(data.sync_stats) == len(data.pdo_stats) == len(data.emcy) == 0
    assert "consumers" in data.pdo_stats.columns
    res = nmtcheck("fleet", "summary", str(results))
    assert res.returncode == 0, res.stderr
    assert "D004" in res.stdout
    # writing into it: one line naming the dataset, exit 2, no traceback
    res = nmtcheck(*args, "--force")
    assert res.returncode == 2
    assert res.stderr.strip().count("\n") == 0 and "Traceback" not in res.stderr
    assert str(results) in res.stderr and "schema version 1" in res.stderr


def test_a_dataset_of_a_newer_schema_is_refused_in_one_line(tmp_path: Path) -> None:
    log, net = LOGS["sync_counter"]
    results = tmp_path / "results"
    assert nmtcheck("check", str(log), "--network", str(net), "--isolated", "--results",
                    str(results), "--executor", "local:1").returncode == 0
    meta = json.loads((results / MARKER).read_text())
    (results / MARKER).write_text(json.dumps({**meta, "schema_version": SCHEMA_VERSION + 1}))
    res = nmtcheck("fleet", "summary", str(results))
    assert res.returncode == 2
    assert res.stderr.strip().count("\n") == 0 and "Traceback" not in res.stderr
    assert f"schema version {SCHEMA_VERSION + 1}" in res.stderr and str(results) in res.stderr


def _docs_query(after: str, results: Path) -> str:
    """The SQL block of docs/reference/dataset.md after the text `after`, on `results`."""
    page = (Path(__file__).resolve().parents[1] / "docs" / "reference" / "dataset.md"
            ).read_text()
    block = page[page.index("```sql", page.index(after)) + len("```sql"):]
    return block[:block.index("```")].replace("'results/", f"'{results}/")


def test_the_docs_queries_run_as_they_stand(checked: Any) -> None:
    """The two DuckDB queries of the docs' SYNC, PDO and EMCY section, on the
    rpdo_producer_stopped dataset (its log dated 2026-12-07 UTC: the week's filter is
    dropped, the rest runs as written)."""
    _report, tables = checked["rpdo_producer_stopped"]
    results = tables["_dir"]
    why = _docs_query("from which kind of cause", results).replace(
        " AND date >= current_date - INTERVAL 7 DAY", "")
    assert sorted(duckdb.sql(why).fetchall()) == [("D004", "nmt", 1, 1), ("S005", "nmt", 1, 1)]
    consumers = duckdb.sql(_docs_query("Each RPDO's consumers", results)).fetchall()
    [(unit, cob_id, producer, consumer, deadline, worst)] = consumers
    assert (unit.endswith("rpdo_producer_stopped.log"), cob_id, producer, consumer,
            deadline) == (True, "182h", 2, 3, 250)
    [row] = [r for r in tables["pdo_stats"] if r["cob_id"] == "182h"]
    assert worst == row["measured_worst_gap_ms"]


def test_uncommitted_rows_of_the_new_tables_are_removed(tmp_path: Path) -> None:
    """A batch killed between its row files and its `inputs` file (its commit record)
    leaves sync_stats/pdo_stats/emcy files too: the next run removes them as it removes
    findings; committed ones and the schema files stay."""
    from nmtcheck.fleet.dataset import ROW_TABLES, Dataset

    ds = Dataset(str(tmp_path / "results"))
    ds.ensure()
    key = {"input_id": "i", "batch_id": "b", "url": "u", "date": "2026-12-07"}
    for table, row in (("sync_stats", {"channel": "can0", "cob_id": "080h"}),
                       ("pdo_stats", {"channel": "can0", "cob_id": "182h", "consumers": []}),
                       ("emcy", {"channel": "can0", "node": 3, "code": "8250h"})):
        ds.write(table, "part-committed", [{**key, **row}])
        ds.write(table, "part-orphan", [{**key, **row}])
    ds.write("inputs", "part-committed", [{**key, "status": "ok"}])
    assert {"sync_stats", "pdo_stats", "emcy"} <= set(ROW_TABLES)
    assert ds.remove_uncommitted() == 3
    for table in ("sync_stats", "pdo_stats", "emcy"):
        names = sorted(p.rsplit("/", 1)[-1] for p in ds.files(table))
        assert names == ["part-committed.parquet", "part-schema.parquet"], table
