"""The results dataset: Parquet tables, hive-partitioned by the log's start date.

    RESULTS/_nmtcheck_dataset.json           {"schema_version": 2, ...}
    RESULTS/inputs/date=2026-11-23/part-<batch>.parquet
    RESULTS/findings/date=2026-11-23/part-<batch>.parquet
    RESULTS/node_stats/date=2026-11-23/part-<batch>.parquet
    RESULTS/boot/date=2026-11-23/part-<batch>.parquet      (SPEC_BOOT §8.5)
    RESULTS/sync_stats/, pdo_stats/, emcy/ date=.../part-<batch>.parquet  (SPEC_COMM §9.4.2)
    RESULTS/runs/date=2026-11-24/run-<run_id>.parquet
    RESULTS/<table>/date=1970-01-01/part-schema.parquet   zero rows: the table's schema

Plain Parquet with fixed schemas, so pandas, pyarrow, DuckDB and Spark read it without
nmtcheck. A batch's files have names derived from what it checked (the inputs' identities,
nmtcheck's version and the profile): writing them again replaces them, never duplicates.
`inputs` is written last and is the commit record the next run's skip list reads.
Every table holds a zero-row file of its schema from the dataset's creation on (issue 25):
a query of `findings/` on a fleet whose logs are all clean returns zero rows, not "no such
path", and a reader that infers the schema from the files gets the whole one.

One run at a time (issue 24): a run holds an exclusive lock on a local dataset
(`_nmtcheck_run.lock`, flock: released however the run ends, `kill -9` too); a second run
into the same `--results` meanwhile is a usage error naming the first. Two runs could
otherwise both check every log (each with an empty skip list, each with its own batching),
and the raw tables would hold each log's rows twice. Under the lock a run first removes
the row files (ROW_TABLES) whose batch never wrote its `inputs` file (a run killed or
stopped by a full disk between them): rows without their commit record. An object store
(s3://, gs://, ...) has no such lock: the docs say to run one fleet run per dataset there.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
import uuid
from collections.abc import Iterable
from typing import Any

from nmtcheck.fleet import lss_table
from nmtcheck.fleet.storage import LocalFS, filesystem, is_local

# 2: the SPEC_COMM §9.4.2 tables (sync_stats, pdo_stats, emcy, lss) and the findings'
# cob_id, causes, reactions and root_kind
SCHEMA_VERSION = 2
MARKER = "_nmtcheck_dataset.json"
LOCK = "_nmtcheck_run.lock"
# each table's zero-row file: `part-` as the batches' files (readers that skip `_`/`.` names
# read it), a name no batch has (theirs are `part-<24 hex>`), under a date (`unknown` would
# make DuckDB's hive partitioning read every `date` as text, not as DATE)
SCHEMA_PART = ("date=1970-01-01", "part-schema.parquet")
TABLES = ("runs", "inputs", "findings", "node_stats", "boot", "sync_stats", "pdo_stats", "emcy",
          "lss")
# the tables a batch writes before `inputs`, its commit record
ROW_TABLES = ("findings", "node_stats", "boot", "sync_stats", "pdo_stats", "emcy", "lss")
DATASET_ENTRIES = (*(f"{t}/" for t in TABLES), MARKER, LOCK)  # what a dataset's folder holds
SEVERITY_COLUMNS = ("n_error", "n_warning", "n_info")



def _value(name: str) -> list[tuple[str, str]]:
    """The columns of a value with its source (SPEC_COMM §9.4.1 `{"value", "source"}`, with
    `node` for a file's value, `time` and `line` for a confirmed SDO download)."""
    return [(f"{name}_value", "int64"), (f"{name}_source", "string"),
            (f"{name}_node", "int64"), (f"{name}_time", "float64"), (f"{name}_line", "int64")]


# (name, arrow type) per table; the partition column `date` is in the path, not the files.
_KEY = [("input_id", "string"), ("batch_id", "string"), ("url", "string"),
        ("device", "string"), ("session", "string"), ("split", "string")]
COLUMNS: dict[str, list[tuple[str, str]]] = {
    "runs": [("run_id", "string"), ("started_at", "timestamp"), ("finished_at", "timestamp"),
             ("nmtcheck_version", "string"), ("profile_digest", "string"),
             ("executor", "string"), ("sources", "string"), ("files", "int64"),
             ("skipped", "int64"), ("checked", "int64"), ("ok", "int64"),
             ("input_error", "int64"), ("crashed", "int64"), ("unsupported", "int64"),
             ("bytes", "int64"), ("n_error", "int64"), ("n_warning", "int64"),
             ("n_info", "int64"), ("seconds", "float64")],
    "inputs": [*_KEY, ("etag", "string"), ("size", "int64"), ("mtime", "timestamp"),
               ("fingerprint", "string"), ("format", "string"), ("status", "string"),
               ("error", "string"), ("frames", "int64"), ("skipped", "int64"),
               ("ignored", "int64"), ("extended", "int64"), ("error_frames", "int64"),
               ("remote_frames", "int64"), ("fd_frames", "int64"), ("dropped", "int64"),
               ("backwards", "int64"), ("truncated", "bool"), ("channels", "string"),
               ("nodes", "int64"), ("start", "float64"), ("end", "float64"),
               ("start_time", "timestamp"), ("n_error", "int64"), ("n_warning", "int64"),
               ("n_info", "int64"), ("omitted", "int64"), ("attempts", "int64"),
               ("nmtcheck_version", "string"), ("profile_digest", "string"),
               ("run_id", "string"), ("checked_at", "timestamp"), ("seconds", "float64")],
    "findings": [*_KEY, ("rule", "string"), ("name", "string"), ("severity", "string"),
                 ("channel", "string"), ("node", "int64"), ("time", "float64"),
                 ("abs_time", "timestamp"), ("frame_index", "int64"), ("line", "int64"),
                 ("message", "string"),
                 # SPEC_COMM §9.4.2: the JSON finding's cob_id, causes and reactions (JSON
                 # text, null for a rule without causes), and the deepest first cause's kind
                 ("cob_id", "string"), ("causes", "string"), ("causes_omitted", "int64"),
                 ("reactions", "string"), ("reactions_omitted", "int64"),
                 ("root_kind", "string")],
    "node_stats": [*_KEY, ("channel", "string"), ("node", "int64"),
                   ("first_seen", "float64"), ("last_seen", "float64"),
                   ("final_state", "string"), ("bootups", "int64"),
                   ("error_control", "string"), ("heartbeat_period_ms", "float64"),
                   ("s_unknown", "float64"), ("s_initialising", "float64"),
                   ("s_pre_operational", "float64"), ("s_operational", "float64"),
                   ("s_stopped", "float64"), ("s_offline", "float64"),
                   ("heartbeats", "int64"), ("hb_p50_ms", "float64"), ("hb_p95_ms", "float64"),
                   ("hb_max_ms", "float64"), ("worst_gap_ms", "float64"),
                   ("worst_gap_at", "float64"), ("n_error", "int64"), ("n_warning", "int64"),
                   ("n_info", "int64")],
    # SPEC_BOOT §8.5: one row per boot process of a node (fleet/tasks.py boot_rows)
    "boot": [*_KEY, ("channel", "string"), ("node", "int64"), ("manager", "string"),
             ("process", "int64"), ("processes", "int64"), ("last", "bool"),
             ("status", "string"), ("letter", "string"), ("letter_text", "string"),
             ("letter_source", "string"), ("reason", "string"), ("anchor", "string"),
             ("start", "float64"), ("end", "float64"), ("abs_start", "timestamp"),
             ("started_at", "float64"), ("attempts", "int64"), ("keep_alive", "bool"),
             ("last_step", "string"), ("evidence_time", "float64"),
             ("evidence_frame_index", "int64"), ("evidence_line", "int64"),
             ("findings", "string"), ("assignment", "string"), ("mandatory", "bool"),
             ("assignment_source", "string")],
    # SPEC_COMM §9.4.2 (fleet/comm_rows.py): the JSON report's `channels[i].sync`,
    # `pdo_streams[]` and `nodes[i].emcy` fields, flattened with `_`; maps (`dlc`,
    # per-rule `findings`) as JSON text
    "sync_stats": [*_KEY, ("channel", "string"), ("cob_id", "string"),
                   ("cob_id_source", "string"), ("producer_node", "int64"),
                   ("producer_source", "string"), *_value("period_us"), *_value("window_us"),
                   *_value("counter_overflow"), ("counter_overflow_largest_seen", "int64"),
                   ("frames", "int64"), ("dlc", "string"), ("segments", "int64"),
                   ("measured_intervals", "int64"), ("measured_period_min_us", "float64"),
                   ("measured_period_median_us", "float64"),
                   ("measured_period_max_us", "float64"), ("measured_jitter_p99_us", "float64"),
                   ("measured_worst_gap_us", "float64"), ("measured_worst_gap_at", "float64"),
                   ("notes", "list<string>")],
    "pdo_stats": [*_KEY, ("channel", "string"), ("cob_id", "string"), ("kind", "string"),
                  ("valid", "bool"), ("producer_node", "int64"), ("producer_pdo", "int64"),
                  ("producer_source", "string"), ("consumers", "consumers"),
                  *_value("parameters_transmission_type"), *_value("parameters_inhibit_100us"),
                  *_value("parameters_event_timer_ms"),
                  ("parameters_mapping_entries", "list<string>"),
                  ("parameters_mapping_bytes", "int64"), ("parameters_mapping_source", "string"),
                  ("measured_frames", "int64"), ("measured_dlc", "string"),
                  ("measured_period_min_ms", "float64"), ("measured_period_median_ms", "float64"),
                  ("measured_period_max_ms", "float64"), ("measured_worst_gap_ms", "float64"),
                  ("findings", "string")],
    "emcy": [*_KEY, ("channel", "string"), ("node", "int64"), ("cob_id", "string"),
             ("cob_id_source", "string"), *_value("inhibit_100us"), *_value("error_behaviour"),
             ("frames", "int64"), ("in_error_at_end", "bool"), ("last_register", "string"),
             ("stack", "string"), ("notes", "list<string>"), ("code", "string"),
             ("meaning", "string"), ("count", "int64"), ("first", "float64"),
             ("last", "float64"), ("registers", "list<string>")],
    "lss": [*_KEY, *lss_table.COLUMNS],  # SPEC §9.4.2: one row per LSS request
}
# one consumer of a PDO stream (`pdo_stats.consumers`, a list of these): its JSON fields
# flattened as the table's (an RPDO has no inhibit time: the JSON's is null)
CONSUMER_FIELDS: list[tuple[str, str]] = [
    ("node", "int64"), ("pdo", "int64"), ("source", "string"), *_value("transmission_type"),
    *_value("event_timer_ms"), ("mapping_entries", "list<string>"), ("mapping_bytes", "int64"),
    ("mapping_source", "string")]
STATE_COLUMNS = {"UNKNOWN": "s_unknown", "INITIALISING": "s_initialising",
                 "PRE-OPERATIONAL": "s_pre_operational", "OPERATIONAL": "s_operational",
                 "STOPPED": "s_stopped", "OFFLINE": "s_offline"}


def arrow_without_pandas() -> None:
    """Keep pyarrow from importing pandas in this process (0.3-0.5 s of start-up per
    process, per worker of a fleet run, for nothing: nmtcheck writes Arrow tables from
    Python lists). pyarrow looks for pandas once per process, at its first conversion of
    Python objects; made then with `import pandas` failing, pyarrow takes it as absent for
    its optional checks and still imports it for an explicit `to_pandas()`. Only for
    processes nmtcheck owns (the CLI's fleet run, its local and dask-local workers): there a
    DataFrame is never handed to pyarrow. Does nothing where pandas is already imported."""
    import sys

    if "pandas" in sys.modules:
        return
    try:
        import pyarrow as pa
    except ImportError:  # said where a table is written
        return

    class NoPandas:
        @staticmethod
        def find_spec(name: str, *_args: Any) -> None:
            if name == "pandas":
                raise ModuleNotFoundError("No module named 'pandas'", name=name)

    blocker = NoPandas()
    sys.meta_path.insert(0, blocker)
    try:
        pa.array([0])
    finally:
        sys.meta_path.remove(blocker)


def arrow_types() -> dict[str, Any]:
    """The Arrow type of each column kind of COLUMNS."""
    import pyarrow as pa

    types = {"string": pa.string(), "int64": pa.int64(), "float64": pa.float64(),
             "bool": pa.bool_(), "timestamp": pa.timestamp("us", tz="UTC"),
             "list<string>": pa.list_(pa.string())}
    types["consumers"] = pa.list_(pa.struct([(n, types[t]) for n, t in CONSUMER_FIELDS]))
    return types


def schema(table: str) -> Any:
    import pyarrow as pa

    types = arrow_types()
    return pa.schema([(n, types[t]) for n, t in COLUMNS[table]],
                     metadata={"nmtcheck.schema_version": str(SCHEMA_VERSION),
                               "nmtcheck.table": table})


def to_table(table: str, rows: list[dict[str, Any]]) -> Any:
    """Rows as an Arrow table of the table's fixed schema (timestamps given as epoch s)."""
    import pyarrow as pa

    sch = schema(table)
    cols = {}
    for name, kind in COLUMNS[table]:
        values = [r.get(name) for r in rows]
        if kind in ("float64", "timestamp"):  # never a non-finite number in the dataset
            values = [v if v is None or math.isfinite(v) else None for v in values]
        if kind == "timestamp":
            # int(): round() of a numpy float is a numpy float with numpy < 2
            values = [None if v is None else int(round(v * 1e6))  # noqa: RUF046
                      for v in values]
            # made as the timestamp type directly: a cast would import pyarrow.compute,
            # 0.2 s of the driver's CPU at the end of every fleet run
            cols[name] = pa.array(values, sch.field(name).type)
        else:
            cols[name] = pa.array(values, sch.field(name).type)
    return pa.table(cols, schema=sch)


def date_of(seconds: float | None) -> str:
    """The partition value: the UTC date of an epoch time, `unknown` without one."""
    if seconds is None:
        return "unknown"
    return time.strftime("%Y-%m-%d", time.gmtime(seconds))


class Dataset:
    """A results dataset at a directory or URL."""

    def __init__(self, url: str, storage_options: dict[str, Any] | None = None) -> None:
        self.url = url.rstrip("/") or url
        self.storage_options = storage_options or {}
        self.fs, self.root = filesystem(self.url, self.storage_options)
        self.local = is_local(url)

    def path(self, *parts: str) -> str:
        return "/".join([self.root.rstrip("/"), *parts])

    def ensure(self) -> None:
        """Create the dataset (its marker file) or check that it is one of a version this
        nmtcheck writes; a location that cannot be written is a usage error, before any
        log is checked."""
        from nmtcheck.errors import UsageError

        try:
            self._ensure()
        except UsageError:
            raise
        except Exception as exc:  # noqa: BLE001 - fsspec backends raise many kinds
            reason = f"{type(exc).__name__}: {exc}".replace("\n", " ")[:300]
            raise UsageError(f"--results {self.url}: cannot write there: {reason}") from None

    def _ensure(self) -> None:
        from nmtcheck.errors import UsageError

        marker = self.path(MARKER)
        if self.fs.exists(marker):
            version = self.schema_version()
            if version != SCHEMA_VERSION:
                raise UsageError(f"--results {self.url}: dataset schema version "
                                 f"{version}, this nmtcheck writes "
                                 f"{SCHEMA_VERSION}: use a new results location")
        else:
            if self.local:
                self.fs.makedirs(self.root, exist_ok=True)
            self._put_bytes(marker, json.dumps({
                "schema_version": SCHEMA_VERSION, "tables": list(TABLES),
                "partitioning": "hive: date=YYYY-MM-DD (the log's start date, UTC)",
            }, indent=2).encode() + b"\n")
        self._schema_files()

    def schema_version(self) -> object:
        """The `schema_version` of the dataset's marker file (None where it has none, or
        the file is no JSON object)."""
        with self.fs.open(self.path(MARKER), "rb") as f:
            try:
                meta = json.loads(f.read() or b"{}")
            except ValueError:
                return None
        return meta.get("schema_version") if isinstance(meta, dict) else None

    def _schema_files(self) -> None:
        """Each table's zero-row file, where missing (a dataset of an earlier nmtcheck, a
        file removed by hand): written once, so that a run with nothing to do writes
        nothing."""
        for table in TABLES:
            path = self.path(table, *SCHEMA_PART)
            if not self.fs.exists(path):
                self._put_table(path, schema(table).empty_table())

    def lock(self) -> Any:
        """Take the dataset's run lock (local datasets; None elsewhere): an open file whose
        flock the OS releases when this process ends, however it ends. A dataset another
        run holds is a usage error."""
        from nmtcheck.errors import UsageError

        if not self.local:
            return None
        import fcntl

        # opened, never written: a run that finds nothing to do changes no file
        handle = open(self.path(LOCK), "ab")  # noqa: SIM115 - held for the run's lifetime
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            handle.close()
            raise UsageError(f"--results {self.url}: another run is writing this dataset; "
                             "one run at a time (wait for it, or give another --results)"
                             ) from None
        return handle

    def remove_uncommitted(self) -> int:
        """Remove the row files (ROW_TABLES) of batches without an `inputs` file (their commit
        record): what a run stopped between the two left. The number removed."""
        committed = {p.rsplit("/", 1)[-1] for p in self.files("inputs")} | {SCHEMA_PART[1]}
        removed = 0
        for table in ROW_TABLES:
            for path in self.files(table):
                if path.rsplit("/", 1)[-1] not in committed:
                    self.fs.rm(path)
                    removed += 1
        return removed

    def write(self, table: str, name: str, rows: list[dict[str, Any]]) -> list[str]:
        """The rows as Parquet files `TABLE/date=D/NAME.parquet`, one per date; returns the
        paths. Local files are written beside their target and renamed into place."""
        by_date: dict[str, list[dict[str, Any]]] = {}
        for r in rows:
            by_date.setdefault(r["date"], []).append(r)
        written = []
        for date, part in sorted(by_date.items()):
            path = self.path(table, f"date={date}", f"{name}.parquet")
            self._put_table(path, to_table(table, part))
            written.append(path)
        return written

    def _put_table(self, path: str, arrow_table: Any) -> None:
        import pyarrow.parquet as pq

        parent = path.rsplit("/", 1)[0]
        if self.local:
            self.fs.makedirs(parent, exist_ok=True)
            tmp = f"{parent}/.{uuid.uuid4().hex}.tmp"
            try:
                pq.write_table(arrow_table, tmp, compression="zstd")
                os.replace(tmp, path)
            finally:
                if os.path.exists(tmp):
                    os.unlink(tmp)
            return
        with self.fs.open(path, "wb") as f:
            pq.write_table(arrow_table, f, compression="zstd")

    def _put_bytes(self, path: str, data: bytes) -> None:
        with self.fs.open(path, "wb") as f:
            f.write(data)

    def files(self, table: str) -> list[str]:
        base = self.path(table)
        if not self.fs.exists(base):
            return []
        return sorted(p for p in self.fs.find(base) if p.endswith(".parquet")
                      and not p.rsplit("/", 1)[-1].startswith("."))

    def read(self, table: str, columns: Iterable[str] | None = None) -> Any:
        """One table as Arrow (with its `date` column), empty with the schema when absent."""
        import pyarrow as pa
        import pyarrow.dataset as ds

        files = self.files(table)
        sch = schema(table)
        full = pa.schema([*sch, pa.field("date", pa.string())])
        cols = list(columns) if columns is not None else None
        if not files:
            empty = full.empty_table()
            return empty.select(cols) if cols else empty
        part = ds.partitioning(pa.schema([pa.field("date", pa.string())]), flavor="hive")
        fs = None if isinstance(self.fs, LocalFS) else self.fs  # pyarrow's own local files
        dataset = ds.dataset(files, schema=full, filesystem=fs, format="parquet",
                             partitioning=part, partition_base_dir=self.path(table))
        return dataset.to_table(columns=cols)

    def done(self, version: str, digest: str) -> dict[bytes, tuple[str, int, int, int]]:
        """The skip list: the logs this nmtcheck version with this profile has already
        checked, as done_key(url, fingerprint) -> (status, errors, warnings, infos) of the
        latest check. 16-byte keys and only the matching rows: a million logs take tens of
        MB on the client, not the inputs table."""
        import pyarrow.compute as pc

        t = self.read("inputs", ["url", "fingerprint", "nmtcheck_version", "profile_digest",
                                 "status", "checked_at", *SEVERITY_COLUMNS])
        out: dict[bytes, tuple[str, int, int, int]] = {}
        if t.num_rows == 0:
            return out
        t = t.filter(pc.and_(pc.equal(t["nmtcheck_version"], version),
                             pc.equal(t["profile_digest"], digest))).sort_by("checked_at")
        cols = [t[c].to_pylist() for c in ("url", "fingerprint", "status", *SEVERITY_COLUMNS)]
        for url, fp, status, e, w, i in zip(*cols, strict=True):
            out[done_key(url, fp)] = (status, e or 0, w or 0, i or 0)
        return out


def done_key(url: str, fingerprint: str) -> bytes:
    return hashlib.blake2b(f"{url}\x1f{fingerprint}".encode(), digest_size=16).digest()


def latest(tables: dict[str, Any]) -> dict[str, Any]:
    """The newest check of each URL (pandas frames): older checks of a log that changed, or
    of an older nmtcheck or profile, and rows of a batch superseded by a --force re-run with
    other batches, are left out."""
    import numpy as np

    inputs = tables["inputs"]
    if len(inputs) == 0:
        return tables
    newest = (inputs.sort_values(["checked_at", "batch_id"], kind="stable")
              .drop_duplicates("url", keep="last"))
    keep = set(zip(newest["input_id"], newest["batch_id"], strict=True))
    out = dict(tables)
    out["inputs"] = newest.reset_index(drop=True)
    for name in ROW_TABLES:
        if name not in tables:
            continue
        df = tables[name]
        mask = [(a, b) in keep for a, b in zip(df["input_id"], df["batch_id"], strict=True)]
        out[name] = df.loc[np.asarray(mask, dtype=bool)].reset_index(drop=True)  # [] keeps rows
    return out
