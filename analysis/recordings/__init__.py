"""Recordings as analysis reads them: the ``.rrd`` reader (the only module that knows Rerun's
read API), one recording loaded as a frames table and its logged outputs, the models recomputed on
the raw frames and the table set (``vdc-analyse tables``), segments and the analysis recordings.

Modules: ``reader`` (Rerun's read API) → ``loading`` (frames table, logged outputs) →
``recompute`` (the ``tables`` command: recomputation, summaries) → ``segments`` (per-condition
segments, histograms, heat maps); ``ego_motion`` (the robot's yaw rate); ``analysis_rrd``
(analysis recordings and their blueprints).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from vdc.lazy import lazy_face

if TYPE_CHECKING:
    from analysis.recordings.loading import load_recording
    from analysis.recordings.reader import Recording
    from analysis.recordings.recompute import SummarySettings, TablesResult, TablesSettings, tables
    from analysis.recordings.segments import ProfileSettings

# the public face: name -> the module that defines it (loaded on first use)
_FACE = {
    "Recording": "analysis.recordings.reader",
    "load_recording": "analysis.recordings.loading",
    "TablesSettings": "analysis.recordings.recompute",
    "TablesResult": "analysis.recordings.recompute",
    "tables": "analysis.recordings.recompute",
    "SummarySettings": "analysis.recordings.recompute",
    "ProfileSettings": "analysis.recordings.segments",
}
__all__ = [
    "ProfileSettings",
    "Recording",
    "SummarySettings",
    "TablesResult",
    "TablesSettings",
    "load_recording",
    "tables",
]
__getattr__, __dir__ = lazy_face(__name__, _FACE)
