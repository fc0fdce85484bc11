"""Parquet writing with the provenance every vdc table carries in its key-value metadata."""

from __future__ import annotations

import contextlib
import ctypes
import json
import os
import shutil
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pyarrow as pa
import pyarrow.parquet as pq

from vdc.errors import UserError
from vdc.folders import write_outputs
from vdc.provenance import machine_info, package_versions
from vdc.recording import pid_alive

if TYPE_CHECKING:  # polars only in the annotations: a capture imports this module for
    import polars as pl  # WroteFiles and must not pay polars' import or start its threads


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


def write_tables(
    folder: Path, tables: Mapping[str, pl.DataFrame | None], meta: dict[str, Any]
) -> list[Path]:
    """Each table that is not None as ``folder/<name>.parquet`` with ``meta``
    (:func:`write_parquet`); their paths, in the order of ``tables``."""
    return [
        write_parquet(df, folder / f"{name}.parquet", meta)
        for name, df in tables.items()
        if df is not None
    ]


def read_metadata(path: Path) -> dict[str, Any]:
    """The ``vdc.*`` key-value metadata of a Parquet file, JSON-decoded, keys without prefix."""
    raw = pq.read_schema(path).metadata or {}
    return {k.decode()[4:]: json.loads(v) for k, v in raw.items() if k.decode().startswith("vdc.")}


_STAGING = ".staging-"


def _remove_stale_staging(out_dir: Path) -> None:
    """Staging folders of writers that died (SIGKILL leaves them): removed by the next one."""
    for old in out_dir.parent.glob(f".{out_dir.name}{_STAGING}*"):
        pid = old.name.rsplit("-", 1)[-1]
        if pid.isdigit() and not pid_alive(int(pid)):
            shutil.rmtree(old, ignore_errors=True)


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux renameat2 RENAME_EXCHANGE); False where unsupported."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        renameat2 = libc.renameat2
    except (OSError, AttributeError):
        return False
    at_fdcwd, rename_exchange = -100, 2
    rc = renameat2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange)
    return rc == 0


def _publish(stage: Path, out_dir: Path) -> None:
    if not out_dir.exists():
        try:
            os.rename(stage, out_dir)
            return
        except OSError:
            if not out_dir.exists():
                raise
    # files of other commands (or earlier sets) in the folder stay: linked into the new one
    for entry in out_dir.iterdir():
        target = stage / entry.name
        if target.exists() or entry.name.startswith("."):
            continue
        if entry.is_dir():
            os.rename(entry, target)
        else:
            try:
                os.link(entry, target)
            except OSError:
                shutil.copy2(entry, target)
    if _exchange(stage, out_dir):
        shutil.rmtree(stage, ignore_errors=True)  # now the old folder
        return
    old = out_dir.with_name(f".{out_dir.name}.old-{os.getpid()}")
    os.rename(out_dir, old)  # not atomic: for a moment the folder is absent, never mixed
    os.rename(stage, out_dir)
    shutil.rmtree(old, ignore_errors=True)


@contextlib.contextmanager
def table_set(out_dir: Path) -> Iterator[Path]:
    """Write a set of tables (and figures) as one: yields a staging folder beside ``out_dir``;
    when the block ends, the folder replaces ``out_dir`` in one atomic exchange, so a reader
    sees the old set or the new one, never a mix. Files already in ``out_dir`` that the new set
    does not write are kept. The folder's manifest (``vdc.folders.OUTPUTS_MANIFEST``) names
    every file vdc published into it, so a folder scan never takes them as sources. If the
    block raises (a full disk, a signal), ``out_dir`` is left
    as it was and the staging folder is removed; one left by a SIGKILL is removed by the next
    writer."""
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():  # e.g. an input recording given as --out
        raise UserError(f"--out {str(out_dir)!r} is a file, not a folder; give a folder")
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    _remove_stale_staging(out_dir)
    stage = out_dir.with_name(f".{out_dir.name}{_STAGING}{os.getpid()}")
    shutil.rmtree(stage, ignore_errors=True)
    stage.mkdir()
    try:
        yield stage
        write_outputs(stage, out_dir)  # what vdc wrote: never a source of a folder scan
        _publish(stage, out_dir)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


class WroteFiles:
    """A command's result that lists the files it wrote in ``paths``: ``files`` names them by
    role (``result.files.summary``)."""

    paths: list[Path]

    @property
    def files(self) -> Files:
        return Files.of(self.paths)


class Files(dict):
    """The files a command wrote, by role: ``result.files.summary`` or
    ``result.files["summary"]``. The role is the file's stem (``summary`` for
    ``summary.parquet``), with its suffix added where two files share a stem
    (``profiles_png``, ``profiles_rrd``)."""

    @classmethod
    def of(cls, paths: list[Path]) -> Files:
        stems = [p.stem for p in paths]
        return cls(
            (s if stems.count(s) == 1 else f"{s}_{p.suffix.lstrip('.')}", p)
            for s, p in zip(stems, paths, strict=True)
        )

    def __getattr__(self, role: str) -> Path:
        try:
            return self[role]
        except KeyError:
            raise AttributeError(
                f"no file {role!r} was written (roles: {', '.join(self)})"
            ) from None
