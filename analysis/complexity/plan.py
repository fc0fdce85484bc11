"""Which sources a ``vdc-analyse complexity`` run measures: the named recordings, videos,
image sequences and folders expanded (:func:`expand_sources`), the metrics a video without a
field of view leaves out (:func:`without_fov`), and one task per source with its recording id
and its part's key (:func:`plan_sources`)."""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from analysis.batch import PARTS
from analysis.complexity.complexity_rrd import OUTPUT_MARKER
from analysis.complexity.meter import (
    ANGULAR_METRICS,
    fov_free,
)
from analysis.complexity.settings import ComplexitySettings
from analysis.recordings.reader import Recording, RecordingError
from analysis.recordings.recompute import DistinctRecordings
from vdc.errors import UserError
from vdc.folders import not_found, path_list, scan_folder
from vdc.source_names import unique_source_names
from vdc.sources import VIDEO_SUFFIXES


def expand_sources(
    items: Sequence[str | Path], notice: Callable[[str], None] | None = None
) -> list[str]:
    """Recordings, video files, image-sequence patterns and folders → the sources, in order:
    a folder gives the recordings and videos in it and below, sorted, less what vdc wrote
    itself, unfinished captures and dangling links (``vdc.folders.scan_folder``), which
    ``notice`` hears about in one line per folder. A folder without any source, a missing
    file or a pattern that matches nothing raises ValueError, as does an empty list."""
    sources: list[str] = []
    if not path_list(items):
        raise UserError("complexity was given no sources: name a recording, video or folder.")
    for item in path_list(items):
        p = Path(item)
        if p.is_dir():
            scan = scan_folder(p, (*VIDEO_SUFFIXES, ".rrd"), skip_dirs=(PARTS,))
            note = scan.note(item)
            if note and notice is not None:
                notice(note)
            if not scan.found:
                raise UserError(
                    f"folder {item!r} holds no videos ({', '.join(VIDEO_SUFFIXES[:5])}, ...) "
                    f"or .rrd recordings{f' ({note})' if note else ''}."
                )
            sources += map(str, scan.found)
        elif p.is_file():
            sources.append(item)
        elif "%" in item:
            folder = p.parent if str(p.parent) else Path(".")
            head = p.name.split("%")[0]
            if not folder.is_dir() or not any(
                f.name.startswith(head) for f in folder.iterdir() if f.is_file()
            ):
                raise UserError(f"image sequence {item!r} matches no files.")
            sources.append(item)
        else:
            raise UserError(not_found(item))
    return sources


def without_fov(sources: Sequence[str], settings: ComplexitySettings) -> str | None:
    """What a run without ``--fov-deg`` leaves out, as one note (None: nothing). A video's
    angular metrics need its camera's field of view (a recording states its own); the others
    are measured. Only angular metrics asked of videos alone raise ValueError."""
    videos = [s for s in sources if not s.endswith(".rrd")]
    if settings.fov_deg is not None or not videos:
        return None
    chosen = settings.metric_names()
    kept = fov_free(chosen, settings.width)
    left = [m for m in chosen if m not in kept]
    if not left:
        return None
    if not kept and len(videos) == len(sources):
        raise UserError(
            f"{', '.join(left)} need the camera's field of view: give --fov-deg (the horizontal "
            "field of view, degrees) or ask for pixel metrics (--metrics)."
        )
    why = "deg/s" if set(left) <= set(ANGULAR_METRICS) else "deg/s, or the model raster"
    return (
        f"no --fov-deg: {', '.join(left)} left out for the {len(videos)} video source(s) "
        f"(they need the camera's horizontal field of view for {why}); "
        f"{', '.join(kept) or 'nothing else'} measured"
    )


def _stamp(source: str) -> tuple:
    """What identifies a source's content: its path and, for files, size and mtime."""
    p = Path(source)
    if p.is_file():
        st = p.stat()
        return (str(p.resolve()), st.st_size, st.st_mtime_ns)
    return (source,)


def plan_sources(
    sources: Sequence[str],
    settings: ComplexitySettings,
    notice: Callable[[str], None] | None = None,
) -> list[dict[str, str]]:
    """One task per source: its recording id (a recording's own, checked distinct; a video's
    from its file name, the parent folder added where two share a name) and its part's key
    (the name and a hash of the content and the settings, so a changed file or setting is
    measured again). A recording vdc derived from another (its ``vdc_output`` property: a
    ``complexity_<id>.rrd`` copied away from its folder's manifest) is not a source: left
    out, and ``notice`` hears how many."""

    opened: dict[str, Any] = {}
    for s in sources:
        if s.endswith(".rrd"):
            try:
                opened[s] = Recording(s)
            except (RecordingError, OSError):  # fails as its own task: never sinks the others
                opened[s] = None
    derived = [s for s, rec in opened.items() if rec is not None and is_vdc_output(rec)]
    if derived:
        if notice is not None:
            notice(
                f"skipped {len(derived)} recording(s) vdc derived from others (first: "
                f"{derived[0]}): outputs, not sources."
            )
        if len(derived) == len(sources):
            raise UserError(
                f"{derived[0]!r} is an output of vdc-analyse complexity, not a source; give "
                "the recording or video it measured."
            )
        sources = [s for s in sources if s not in derived]
    names = unique_source_names(sources)
    distinct = DistinctRecordings()  # two files of one recording would mix their rows
    tasks = []
    for src, name in zip(sources, names, strict=True):
        digest = hashlib.sha1(repr((_stamp(src), settings.measured())).encode()).hexdigest()
        if src.endswith(".rrd") and opened[src] is not None:
            rid = opened[src].recording_id
            distinct.add(rid, src)
        elif src.endswith(".rrd"):
            rid = f"unreadable-{name}"  # its task fails with the reason, in failures.parquet
        else:
            rid = f"video-{name}"
        tasks.append({"source": src, "recording_id": rid, "key": f"{name}-{digest[:8]}"})
    keys = [t["key"] for t in tasks]
    if len(set(keys)) != len(keys):  # the same name and content twice
        raise UserError("two sources are the same file; give each once.")
    return tasks


def is_vdc_output(rec: Any) -> bool:
    """Whether a recording (``analysis.recordings.reader.Recording``) is one vdc derived from
    another (it carries the ``vdc_output`` property :func:`write_complexity_rrd` sets)."""
    return OUTPUT_MARKER in rec.properties()
