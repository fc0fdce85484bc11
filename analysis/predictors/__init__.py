"""Which complexity measure predicts where a detector fails.

Modules: ``statistics`` (AUROC, rank correlations, cross-validated thresholds; ``arena`` its
arena table, ``verdicts`` the units and the verdicts' rules) → ``report`` (the table, figure
and page: ``PredictorResult``). Per frame on labelled footage, footage mode computes them:
``analysis.boundary.footage_predictors`` (``footage_predictor_tables``).
The measures of an arena grid's profiling runs are taken while they are recorded:
``analysis.experiments.collision.predictor_runs.predictors`` (``vdc.predictors``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from vdc.lazy import lazy_face

if TYPE_CHECKING:
    from analysis.predictors.report import PredictorResult, plot_predictors, write_predictors

# the public face: name -> the module that defines it (loaded on first use)
_FACE = {
    "PredictorResult": "analysis.predictors.report",
    "write_predictors": "analysis.predictors.report",
    "plot_predictors": "analysis.predictors.report",
}
__all__ = [
    "PredictorResult",
    "plot_predictors",
    "write_predictors",
]
__getattr__, __dir__ = lazy_face(__name__, _FACE)
