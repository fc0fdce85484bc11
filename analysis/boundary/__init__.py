"""``vdc-analyse boundary``: where a detector breaks, against complexity.

A boundary campaign reads, in order: ``settings`` → ``statistics`` (per-run and per-condition
statistics, the boundary per scene) → ``fit`` (the fitted success curve, its crossing and
interval) → ``plot``, ``report`` and ``report_tables`` (the figure and the report) → ``command``
(the result, the files every mode writes). ``footage`` is the
labelled-footage mode, ``footage_predictors`` its per-frame predictor tables. The arena campaign
itself records simulated runs, so it lives with the experiments:
``analysis.experiments.collision.boundary_campaign.boundary`` (``vdc.boundary``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from vdc.lazy import lazy_face

if TYPE_CHECKING:
    from analysis.boundary.command import BoundaryResult
    from analysis.boundary.fit import fit_crossing
    from analysis.boundary.footage import footage_boundary
    from analysis.boundary.footage_predictors import footage_predictor_tables
    from analysis.boundary.plot import plot_boundary
    from analysis.boundary.settings import BoundarySettings

# the public face: name -> the module that defines it (loaded on first use)
_FACE = {
    "BoundarySettings": "analysis.boundary.settings",
    "BoundaryResult": "analysis.boundary.command",
    "fit_crossing": "analysis.boundary.fit",
    "footage_boundary": "analysis.boundary.footage",
    "footage_predictor_tables": "analysis.boundary.footage_predictors",
    "plot_boundary": "analysis.boundary.plot",
}
__all__ = [
    "BoundaryResult",
    "BoundarySettings",
    "fit_crossing",
    "footage_boundary",
    "footage_predictor_tables",
    "plot_boundary",
]
__getattr__, __dir__ = lazy_face(__name__, _FACE)
