"""Parquet writing with the provenance every vdc table carries in its key-value metadata."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import polars as pl
import pyarrow as pa
import pyarrow.parquet as pq

from contract.provenance import machine_info, package_versions


def write_parquet(df: pl.DataFrame, path: Path, meta: dict[str, Any]) -> Path:
    """Write ``df`` to ``path`` with ``meta`` (JSON-encoded per key, prefixed ``vdc.``) and
    the package versions and the machine in the Parquet key-value metadata. Writes
    atomically."""
    table: pa.Table = df.to_arrow()
    kv = {f"vdc.{k}": json.dumps(v, sort_keys=True, default=str) for k, v in meta.items()}
    kv["vdc.versions"] = json.dumps(package_versions(), sort_keys=True)
    kv["vdc.machine"] = json.dumps(machine_info(), sort_keys=True)
    table = table.replace_schema_metadata({**(table.schema.metadata or {}), **kv})
    path.parent.mkdir(parents=True, exist_ok=True)
    # unique per process: two batch workers may write a recording's shared table at once
    tmp = path.with_name(f"{path.name}.partial-{os.getpid()}")
    pq.write_table(table, tmp)
    tmp.replace(path)
    return path


def read_metadata(path: Path) -> dict[str, Any]:
    """The ``vdc.*`` key-value metadata of a Parquet file, JSON-decoded, keys without prefix."""
    raw = pq.read_schema(path).metadata or {}
    return {k.decode()[4:]: json.loads(v) for k, v in raw.items() if k.decode().startswith("vdc.")}
