"""A fleet's results dataset read back as DataFrames (`nmtcheck.read_results`): what
`nmtcheck fleet summary` and the Python API read."""

from __future__ import annotations

from dataclasses import dataclass, field
from os import PathLike
from typing import Any

import pandas as pd


@dataclass
class Results:
    """A fleet's results dataset as DataFrames (see nmtcheck.fleet.dataset for the schema)."""

    runs: pd.DataFrame
    inputs: pd.DataFrame
    findings: pd.DataFrame
    node_stats: pd.DataFrame
    schema_version: int
    boot: pd.DataFrame = field(default_factory=pd.DataFrame)  # SPEC_BOOT §8.5
    # SPEC_COMM §9.4.2: one row per input and channel with SYNC, per PDO stream, per node
    # and EMCY code (empty in a schema-1 dataset, which predates them)
    sync_stats: pd.DataFrame = field(default_factory=pd.DataFrame)
    pdo_stats: pd.DataFrame = field(default_factory=pd.DataFrame)
    emcy: pd.DataFrame = field(default_factory=pd.DataFrame)
    lss: pd.DataFrame = field(default_factory=pd.DataFrame)  # SPEC §9.4.2: LSS requests


def read_results(url: str | PathLike[str], *, storage_options: dict[str, Any] | None = None,
                 latest: bool = True) -> Results:
    """The dataset `nmtcheck check --results URL` wrote. With `latest` (default) each log's
    newest check only: older checks of a log that changed since, or by an older nmtcheck or
    profile, are left out. A dataset of schema version 1 reads with the tables and columns
    version 2 added empty or null."""
    from nmtcheck.errors import UsageError
    from nmtcheck.fleet.dataset import MARKER, SCHEMA_VERSION, TABLES, Dataset
    from nmtcheck.fleet.dataset import latest as newest

    ds = Dataset(str(url), storage_options)
    if not ds.fs.exists(ds.path(MARKER)):
        raise UsageError(f"{url}: not an nmtcheck results dataset (no {MARKER})")
    version = ds.schema_version()
    if not isinstance(version, int) or not 1 <= version <= SCHEMA_VERSION:
        raise UsageError(f"{url}: dataset schema version {version}, this nmtcheck reads "
                         f"versions 1 to {SCHEMA_VERSION}: read it with the nmtcheck that "
                         "wrote it")
    import pyarrow as pa

    # integer columns with missing values (a finding's node) stay integers: pandas' Int64
    ints = {pa.int64(): pd.Int64Dtype()}.get
    tables = {t: ds.read(t).to_pandas(types_mapper=ints) for t in TABLES}
    for df in tables.values():
        if "date" in df.columns:
            df["date"] = df["date"].astype(str)
    if latest:
        tables = newest(tables)
    return Results(tables["runs"], tables["inputs"], tables["findings"], tables["node_stats"],
                   version, tables["boot"], tables["sync_stats"], tables["pdo_stats"],
                   tables["emcy"], tables["lss"])
