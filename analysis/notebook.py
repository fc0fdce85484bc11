"""Recordings and catalog segments inline in Jupyter (``vdc.show``), with Rerun's notebook
widget served from this machine: labs and clusters are often offline, and by default the
widget would load its code from app.rerun.io."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import rerun as rr

from analysis.recordings.reader import Recording
from vdc.errors import UserError
from vdc.recording import APP_ID

NOTEBOOK_EXTRA = "pip install 'visual-dynamic-complexity[notebook]'"


def _viewer_class() -> Any:
    # the widget's JavaScript and Wasm ship in the wheel: serve them locally (set before
    # rerun_notebook is first imported; a value the user set wins)
    os.environ.setdefault("RERUN_NOTEBOOK_ASSET", "serve-local")
    try:
        from rerun.notebook import Viewer  # lazy: optional extra
    except ImportError:
        raise UserError(f"vdc.show needs the notebook extra: {NOTEBOOK_EXTRA}") from None
    return Viewer


def show(
    target: str | Path | Any,
    segment: str | None = None,
    *,
    width: int | str = "auto",
    height: int = 640,
) -> Any:
    """Display a recording inline: ``show("run.rrd")``; or a segment of a running catalog:
    ``show(cat, "grating-tf3-s1-...")`` with ``cat`` from ``vdc.catalog.open_catalog``.
    Returns the widget (Rerun's ``notebook.Viewer``); in a notebook it shows itself."""

    viewer_cls = _viewer_class()
    if segment is not None:
        viewer = viewer_cls(width=width, height=height)
        viewer.open_url(target.dataset.segment_url(segment))
        return viewer
    path = Path(target)
    if not path.is_file():
        raise UserError(f"{str(path)!r}: no such recording.")

    rec = rr.RecordingStream(APP_ID, recording_id=Recording(path).recording_id)
    rr.log_file_from_path(path, recording=rec)
    return viewer_cls(width=width, height=height, recording=rec)
