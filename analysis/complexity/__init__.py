"""``vdc-analyse complexity``: the complexity of one source or a collection, per frame and per clip.

Modules: ``command`` (settings, the command, its result) → ``source_metrics`` (the AVDM, optic
flow and compression on the model raster beside the native metrics) → ``figures`` (the clip and
collection figures and page); ``avdm_truth`` (the speed-meter protocol: real photographs panned at
known speeds).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from vdc.lazy import lazy_face

if TYPE_CHECKING:
    from analysis.complexity.command import (
        ComplexityResult,
        ComplexitySettings,
        complexity,
        complexity_of_frames,
    )
    from analysis.complexity.meter import MeasureSettings

# the public face: name -> the module that defines it (loaded on first use)
_FACE = {
    "ComplexitySettings": "analysis.complexity.command",
    "ComplexityResult": "analysis.complexity.command",
    "complexity": "analysis.complexity.command",
    "complexity_of_frames": "analysis.complexity.command",
    "MeasureSettings": "analysis.complexity.meter",
}
__all__ = [
    "ComplexityResult",
    "ComplexitySettings",
    "MeasureSettings",
    "complexity",
    "complexity_of_frames",
]
__getattr__, __dir__ = lazy_face(__name__, _FACE)
