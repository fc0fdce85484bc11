"""Walking a collection folder: what in it is a source, and what is skipped, said.

Every command that takes a folder (``complexity``; the catalog can use the same walk) finds
its sources here, so all of them skip the same things and say so in one line:

* what vdc wrote itself: every output folder (``--out``) holds a manifest,
  :data:`OUTPUTS_MANIFEST`, naming the files vdc published into it (``vdc.parquet_io.table_set``
  writes it), so a re-run never takes its own ``complexity_*.rrd`` (or ``profiles.rrd``,
  ``collision.rrd``, ``variants.rrd``) as sources, wherever ``--out`` is: inside the
  collection, beside it or the collection folder itself (the manifest names files, not the
  folder, so the collection's own clips stay sources);
* captures still being written or killed (``*.partial.rrd``);
* dangling symbolic links (a clip moved or deleted): a collection that lost a clip must not
  report success silently.
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Callable, Iterable
from pathlib import Path

from vdc.errors import UserError

OUTPUTS_MANIFEST = ".vdc-outputs.json"
# a writer's staging folder inside --out (vdc.parquet_io.table_set): vdc's files, not sources
STAGING_PREFIX = ".vdc-staging-"
PARTIAL = ".partial.rrd"


def read_outputs(folder: Path) -> set[str]:
    """The names of the files vdc published into ``folder`` (its manifest), or an empty set."""
    try:
        data = json.loads((Path(folder) / OUTPUTS_MANIFEST).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return set()
    names = data.get("outputs", []) if isinstance(data, dict) else []
    return {n for n in names if isinstance(n, str)}


def write_outputs(stage: Path, previous: Path | None = None) -> None:
    """Write ``stage``'s manifest: the files in ``stage`` (what is being published) and those
    ``previous``'s manifest named that still exist there (earlier sets in the same folder)."""
    names = {e.name for e in Path(stage).iterdir() if not e.name.startswith(".")}
    if previous is not None and Path(previous).is_dir():
        names |= {n for n in read_outputs(previous) if (Path(previous) / n).exists()}
    text = json.dumps({"outputs": sorted(names), "written_by": "vdc"}, indent=1)
    (Path(stage) / OUTPUTS_MANIFEST).write_text(text + "\n", encoding="utf-8")


def remove_output(folder: Path, name: str) -> bool:
    """Delete ``folder/name`` only if vdc's manifest says vdc wrote it (an earlier run's file
    that this run has nothing to replace with); True if it was removed. A user's file of the
    same name is never touched."""
    path = Path(folder) / name
    if name not in read_outputs(Path(folder)) or not path.is_file():
        return False
    path.unlink(missing_ok=True)
    return True


@dataclasses.dataclass
class FolderScan:
    """A folder's sources (sorted paths) and the entries skipped, counted by reason."""

    found: list[Path]
    skipped: dict[str, int]

    def note(self, folder: str | Path) -> str | None:
        """One line naming how many entries were skipped and why, or None."""
        if not self.skipped:
            return None
        n = sum(self.skipped.values())
        why = ", ".join(f"{k} {reason}" for reason, k in self.skipped.items())
        return f"{str(folder)!r}: skipped {n} entr{'y' if n == 1 else 'ies'}: {why}"


DANGLING = "dangling link(s) (their target is gone)"
VDC_OUTPUT = "output(s) vdc wrote itself (not sources)"
UNFINISHED = "capture(s) still being written or killed (*.partial.rrd)"


def scan_folder(
    folder: str | Path, suffixes: Iterable[str], skip_dirs: Iterable[str] = ()
) -> FolderScan:
    """The files under ``folder`` (recursively, symbolic links to files followed) whose
    suffix is one of ``suffixes`` (lower case, with the dot), sorted; entries in folders
    named in ``skip_dirs`` (below ``folder``) are left out silently (vdc's own working
    folders, e.g. ``parts``), as are table sets being published or left by a killed writer
    (:data:`STAGING_PREFIX`). Skipped and counted: dangling links, files a vdc manifest
    names (:func:`read_outputs`), and unfinished captures."""
    root = Path(folder)
    wanted = tuple(s.lower() for s in suffixes)
    skip = set(skip_dirs)
    found: list[Path] = []
    skipped: dict[str, int] = {}
    for dirpath, dirnames, filenames in os.walk(root):
        here = Path(dirpath)
        dirnames[:] = sorted(
            d for d in dirnames if d not in skip and not d.startswith(STAGING_PREFIX)
        )
        outputs = read_outputs(here)
        for name in sorted(filenames):  # a dangling link is listed with the files
            path = here / name
            if path.is_symlink() and not path.exists():
                skipped[DANGLING] = skipped.get(DANGLING, 0) + 1
                continue
            if not path.is_file() or not name.lower().endswith(wanted):
                continue
            if name in outputs:
                skipped[VDC_OUTPUT] = skipped.get(VDC_OUTPUT, 0) + 1
            elif name.endswith(PARTIAL):
                skipped[UNFINISHED] = skipped.get(UNFINISHED, 0) + 1
            else:
                found.append(path)
    return FolderScan(sorted(found, key=str), skipped)


def not_found(item: str | os.PathLike) -> str:
    """Why ``item`` cannot be read, in one line: no such file; or, for a recording a capture
    still writes or was killed while writing, its partial file (``<stem>.partial.rrd``) by
    name, and what to do."""
    path = Path(item)
    partial = path.with_name(path.name.removesuffix(".rrd") + PARTIAL)
    if path.suffix == ".rrd" and partial.exists():
        return (
            f"{os.fspath(item)!r} does not exist, but {str(partial)!r} does: a capture still "
            "running or killed; analyse that file by name"
        )
    return f"{os.fspath(item)!r}: no such file or folder"


def path_list(items: str | os.PathLike | Iterable[str | os.PathLike]) -> list[str]:
    """The paths a command was given, as a list of ``str``: a single path (a ``str`` or a
    ``Path``) is a list of one. Without this, a ``str`` given where a list is expected is
    iterated character by character: ``"/abs/x.rrd"`` becomes ``"/"``, ``"a"``, ... and the
    first of them walks the whole file system."""
    if isinstance(items, (str, os.PathLike)):
        return [os.fspath(items)]
    return [os.fspath(i) for i in items]


def expand_recordings(
    items: str | Path | Iterable[str | Path], notice: Callable[[str], None] | None = None
) -> list[str]:
    """Recordings and folders → the ``.rrd`` recordings, in order (``batch``, ``tables``): a
    folder gives its recordings and below (:func:`scan_folder`, vdc's ``parts`` folders left
    out), a file is taken as given. What is skipped (vdc's own outputs, unfinished captures,
    dangling links, also a dangling link given by name) ``notice`` hears in one line per
    folder. A missing path, or nothing left to read, raises ValueError."""
    given = path_list(items)
    found: list[str] = []
    dangling: list[str] = []
    for item in given:
        p = Path(item)
        if p.is_dir():
            scan = scan_folder(p, (".rrd",), skip_dirs=("parts",))
            note = scan.note(item)
            if note and notice is not None:
                notice(note)
            found += map(str, scan.found)
        elif p.is_symlink() and not p.exists():
            dangling.append(item)
        elif p.exists():
            found.append(item)
        else:
            raise UserError(not_found(item))
    if dangling and notice is not None:
        notice(
            f"skipped {len(dangling)} entr{'y' if len(dangling) == 1 else 'ies'}: "
            f"{len(dangling)} {DANGLING} (first: {dangling[0]})."
        )
    if not found:
        raise UserError(f"no .rrd recordings in {', '.join(map(repr, given))}.")
    return found
