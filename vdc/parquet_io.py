"""Parquet writing with the provenance every vdc table carries in its key-value metadata."""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import shutil
import tempfile
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pyarrow as pa
import pyarrow.parquet as pq

from vdc.errors import UserError
from vdc.folders import OUTPUTS_MANIFEST, STAGING_PREFIX, read_outputs, write_outputs
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


_STAGE_MARK = ".vdc-stage"  # in each staging folder, locked by its writer while it lives
_JOURNAL = ".vdc-journal.json"  # the set is complete: the commit point of a publish
_INTERNAL = {_STAGE_MARK, _JOURNAL, f"{_JOURNAL}.partial"}


@contextlib.contextmanager
def _locked(folder: Path) -> Iterator[None]:
    """One publisher at a time in ``folder``: an exclusive ``flock`` on the folder itself (no
    file added to it), released by the kernel if the holder dies; none where the file system
    has no locks (a publish then relies on its journal alone)."""
    fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
    try:
        with contextlib.suppress(OSError):
            fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # releases the lock


def _new_stage(out_dir: Path) -> tuple[Path, int]:
    """A staging folder inside ``out_dir`` and the descriptor that holds its mark locked for
    as long as its writer lives: a writer killed (SIGKILL included) releases it."""
    stage = Path(tempfile.mkdtemp(prefix=f"{STAGING_PREFIX}{os.getpid()}-", dir=out_dir))
    fd = os.open(stage / _STAGE_MARK, os.O_RDWR | os.O_CREAT, 0o600)
    with contextlib.suppress(OSError):  # no locks here: _claim falls back on the pid
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    return stage, fd


def _claim(stage: Path) -> int | None:
    """The locked descriptor of a dead writer's staging folder (its mark's lock taken, so no
    other process recovers it at once), or None while its writer lives."""
    try:
        fd = os.open(stage / _STAGE_MARK, os.O_RDWR)
    except OSError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return fd
    except BlockingIOError:
        pass  # its writer holds it: alive
    except OSError:  # a file system without locks: the pid in the name decides
        pid = stage.name[len(STAGING_PREFIX) :].split("-", 1)[0]
        if pid.isdigit() and not pid_alive(int(pid)):
            return fd
    os.close(fd)
    return None


def _recover(out_dir: Path) -> None:
    """Staging folders of writers that died (SIGKILL leaves them) in ``out_dir``: a committed
    one (its journal written) is published, rolled forward; any other is removed, rolled back.
    A staging folder only ever holds what its writer wrote, so removing it removes nothing of
    the user's; a folder of that name without vdc's mark is removed only if empty."""
    for stage in sorted(out_dir.glob(f"{STAGING_PREFIX}*")):
        if stage.is_symlink() or not stage.is_dir():
            continue
        if not (stage / _STAGE_MARK).exists():
            with contextlib.suppress(OSError):  # a writer killed before its mark: empty
                stage.rmdir()
            continue
        fd = _claim(stage)
        if fd is None:
            continue
        try:
            if (stage / _JOURNAL).exists():
                _roll_forward(stage, out_dir)
            shutil.rmtree(stage, ignore_errors=True)
        finally:
            os.close(fd)


def _check(src: Path, dst: Path, ours: set[str] | None) -> None:
    """Raise UserError, before anything moves, where publishing ``src`` at ``dst`` would
    replace an entry vdc did not write: at the top of ``--out`` an existing name must be in
    its manifest (``ours``; None below the top, inside a folder vdc wrote), and nowhere does
    a file take the place of a folder that holds anything."""
    if not os.path.lexists(dst):
        return
    if ours is not None and dst.name not in ours:
        raise UserError(
            f"{str(dst)!r} is not vdc's (its folder's {OUTPUTS_MANIFEST} does not name it) and "
            f"vdc would write its own there; move it, or give another --out."
        )
    dst_folder = dst.is_dir() and not dst.is_symlink()
    if src.is_dir() and dst_folder:
        for child in src.iterdir():
            _check(child, dst / child.name, None)
    elif dst_folder and any(dst.iterdir()):
        raise UserError(
            f"{str(dst)!r} is a folder with entries where vdc writes a file; move it, "
            f"or give another --out."
        )


def _move(src: Path, dst: Path) -> None:
    """``src`` (in a staging folder) published at ``dst``: a file by one rename, replacing
    vdc's older file; a folder renamed whole where ``dst`` is absent, else merged into vdc's
    folder there file by file (what that folder holds besides stays)."""
    dst_folder = dst.is_dir() and not dst.is_symlink()
    if src.is_dir() and not src.is_symlink():
        if dst_folder:
            for child in sorted(src.iterdir()):
                _move(child, dst / child.name)
            return  # src is left empty: removed with the staging folder
        if os.path.lexists(dst):
            os.unlink(dst)  # vdc's file (or link), now a folder
    elif dst_folder:
        dst.rmdir()  # vdc's empty folder, now a file (_check refused a folder with entries)
    os.rename(src, dst)


def _commit(stage: Path) -> None:
    """The journal: the names the set publishes. Written whole (by rename) or not at all: with
    it the set is rolled forward after a crash, without it rolled back."""
    names = sorted(e.name for e in stage.iterdir() if e.name not in _INTERNAL)
    tmp = stage / f"{_JOURNAL}.partial"
    tmp.write_text(json.dumps({"publish": names}) + "\n", encoding="utf-8")
    os.replace(tmp, stage / _JOURNAL)


def _roll_forward(stage: Path, out_dir: Path) -> None:
    """Publish a committed staging folder into ``out_dir``, or finish publishing it: the
    manifest first (so a folder scan never takes a new output as a source), then each entry
    still in ``stage``. Each step is one rename that leaves the entry in ``stage`` or at its
    place, so a crash at any step is finished by the next call."""
    manifest = stage / OUTPUTS_MANIFEST
    if manifest.exists():  # nothing else has moved yet: the manifest goes first
        write_outputs(stage, out_dir)  # merged with out_dir's as it is now, under the lock
        os.replace(manifest, out_dir / OUTPUTS_MANIFEST)
    names = json.loads((stage / _JOURNAL).read_text(encoding="utf-8"))["publish"]
    for name in names:
        if name != OUTPUTS_MANIFEST and os.path.lexists(stage / name):
            _move(stage / name, out_dir / name)


@contextlib.contextmanager
def table_set(out_dir: Path) -> Iterator[Path]:
    """Write a set of tables (and figures) as one: yields a staging folder inside ``out_dir``
    (``.vdc-staging-<pid>-*``); when the block ends, its entries are published into
    ``out_dir``, each by one rename, replacing only vdc's own files of those names.

    Nothing vdc did not write is touched: every other entry of ``out_dir`` (the user's files,
    dot-files such as ``.git``, sub-folders, inputs, files of other commands or earlier sets)
    stays where it is, never moved, linked or copied, and never enters a staging folder. Any
    ``--out`` is written beside its entries and never replaced, so the current folder, a home
    folder, a repository root or a folder that holds the input are valid ``--out``. A name the
    set writes that is taken by an entry vdc did not write (not in the folder's manifest,
    ``vdc.folders.OUTPUTS_MANIFEST``) is refused (UserError) before anything moves.

    The publish: the set is complete in the staging folder, then its journal is written (the
    commit point), then the manifest (naming every file vdc published into the folder, so a
    folder scan never takes them as sources) and each entry are renamed into ``out_dir``; a
    folder of the set merges into vdc's folder of that name file by file. A reader sees each
    file whole, the old one or the new one; a set is all new once the renames (one per entry,
    under an exclusive ``flock`` on ``out_dir`` so two publishers never interleave) are done.
    A writer killed at any moment (SIGKILL) leaves its staging folder: the next writer into
    ``out_dir`` rolls it forward (journal written: the remaining renames) or back (removed:
    it only ever holds vdc's files), telling a dead writer's folder by the lock it held. If
    the block raises (a full disk, a signal), ``out_dir`` is left as it was, the staging
    folder is removed, and an ``out_dir`` this call created is removed again if empty."""
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():  # e.g. an input recording given as --out
        raise UserError(f"--out {str(out_dir)!r} is a file, not a folder; give a folder.")
    created = not out_dir.exists()
    out_dir.mkdir(parents=True, exist_ok=True)
    with _locked(out_dir):
        _recover(out_dir)
    stage, mark = _new_stage(out_dir)
    committed = published = False
    try:
        yield stage
        with _locked(out_dir):
            _recover(out_dir)  # dead writers' sets first: this one lands on top of them
            ours = read_outputs(out_dir) | {OUTPUTS_MANIFEST}
            for entry in stage.iterdir():
                if entry.name not in _INTERNAL:
                    _check(entry, out_dir / entry.name, ours)
            write_outputs(stage, out_dir)  # what vdc wrote: never a source of a folder scan
            _commit(stage)
            committed = True
            _roll_forward(stage, out_dir)
            published = True
    finally:
        # a committed set cut short by an error (a full disk mid-rename) is kept: the next
        # writer rolls it forward
        if published or not committed:
            shutil.rmtree(stage, ignore_errors=True)
        os.close(mark)
        if created and not committed:
            with contextlib.suppress(OSError):
                out_dir.rmdir()  # only if empty: nothing but what this call made


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
