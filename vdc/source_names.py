"""What a source is and what it is called: a file, a camera index or an image-sequence
pattern (:func:`source_kind`), and the readable, unique names its recordings, parts and
figures take (:func:`source_name`, :func:`unique_source_names`). Apart from
:mod:`vdc.sources`, which reads the frames, so that naming needs no decoder."""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path


def source_kind(source: str) -> str:
    """``file`` (an existing file wins, even one named ``2024`` or ``clip 100%.mkv``),
    ``camera`` (an index such as ``0``) or ``images`` (a pattern with ``%``)."""
    if Path(source).is_file():
        return "file"
    if source.isdigit():
        return "camera"
    return "images" if "%" in source else "file"


def source_name(source: str) -> str:
    """A readable name for a source: its file's stem, a camera's ``camera<N>``, or for an
    image sequence its folder and the prefix before the number (``take1/img_%05d.png`` →
    ``take1-img``); only letters, digits and ``._-``."""
    p = Path(source)
    if source_kind(source) == "camera":
        stem = f"camera{source}"
    elif "%" in p.name and not p.is_file():
        prefix = re.sub(r"[-_.]+$", "", p.name.split("%")[0])
        stem = "-".join(x for x in (p.parent.name, prefix) if x) or "images"
    else:
        stem = p.stem
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", stem)[:60] or "clip"


def unique_source_names(sources: Sequence[str]) -> list[str]:
    """Each source's name (:func:`source_name`: its file's stem), unique within the
    run, so that no two sources share a recording id, a part, a figure or an ``.rrd``: where
    two share one, the parent folder's name is put before it (``day1-take``), then, where
    they still do (``take.mp4`` and ``take.mkv`` in one folder), the file's suffix after it
    (``day1-take-mkv``), and last a number."""
    names = [source_name(s) for s in sources]

    def clashes() -> set[str]:
        return {n for n in names if names.count(n) > 1}

    for widen in (
        lambda src, n: f"{source_name(str(Path(src).parent))}-{n}",
        lambda src, n: f"{n}-{Path(src).suffix.lstrip('.').lower() or 'x'}",
    ):
        dup = clashes()
        names = [widen(src, n) if n in dup else n for src, n in zip(sources, names, strict=True)]
    seen: dict[str, int] = {}
    for i, n in enumerate(list(names)):
        if n in clashes() or n in seen:
            seen[n] = seen.get(n, 0) + 1
            names[i] = f"{n}-{seen[n]}"
    return names
