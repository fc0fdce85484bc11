"""vdc: profiling the visual dynamic complexity of what a camera sees.

``import vdc`` is the flat API for notebooks and scripts; names load on first use, so the
import itself is fast (no NumPy, Numba or Rerun until a name is used)::

    import vdc

    rec = vdc.record_sim(vdc.SimSettings(tf_hz=3, minutes=3), "run.rrd")
    t = vdc.tables([rec.path], out="tables")
    t.summary                                   # a polars DataFrame
    model = vdc.make_model("avdm-natural", fps=30, deg_per_px=0.7)

Every command of ``vdc-capture`` and ``vdc-analyse`` is one of these functions with its
settings dataclass; the command lines only parse and print.

The package also holds what capture and analysis agree on (neither imports the other for it):

* ``vdc.recording``: the recording contract: application id, timelines, entity paths,
  property sections, the partial-file and claim names of captures in progress;
* ``vdc.provenance``: the package versions and the machine every recording and table carries;
* ``vdc.parquet_io``: the table contract: atomic Parquet files with that provenance in their
  key-value metadata, and table sets published whole;
* ``vdc.executors``: where independent tasks run (a local process pool, a Dask cluster);
* ``vdc.cli_support``: one-line errors and argparse helpers shared by both command lines;
* ``vdc.launch``: the console scripts' entry points.
"""

from __future__ import annotations

from importlib.metadata import version as _version

from vdc.lazy import api_stub as _api_stub
from vdc.lazy import lazy_face as _lazy_face

# name -> module that defines it
_API = {
    # capture
    "SimSettings": "capture.sim",
    "record_sim": "capture.sim",
    "VideoSettings": "capture.video",
    "record_video": "capture.video",
    "RobotSettings": "capture.robot_capture",
    "record_robot": "capture.robot_capture",
    "CaptureOptions": "capture.run",
    "CampaignSettings": "capture.campaign",
    "campaign": "capture.campaign",
    # reading recordings
    "Recording": "analysis.recordings.reader",
    "load_recording": "analysis.recordings.loading",
    # analysis
    "TablesSettings": "analysis.recordings.recompute",
    "tables": "analysis.recordings.recompute",
    "ProfileSettings": "analysis.recordings.segments",
    "profile": "analysis.profile",
    "CompareSettings": "analysis.compare",
    "compare": "analysis.compare",
    "ComplexitySettings": "analysis.complexity.command",
    "complexity": "analysis.complexity.command",
    "complexity_of_frames": "analysis.complexity.command",
    # a robot-learning dataset (LeRobot), episode by episode
    "DatasetSettings": "analysis.dataset.settings",
    "dataset": "analysis.dataset.command",
    # many recordings as one dataset, and inline viewing (extras: catalog, notebook)
    "CatalogSettings": "analysis.catalog.build",
    "open_catalog": "analysis.catalog.server",
    "show": "analysis.notebook",
    "BatchSettings": "analysis.batch",
    "batch": "analysis.batch",
    "summarise": "analysis.batch",
    "CollisionSettings": "analysis.collision",
    "collision": "analysis.collision",
    "SweepSettings": "analysis.experiments.paper.sweep",
    "sweep": "analysis.experiments.paper.sweep",
    "CalibrateSettings": "analysis.experiments.paper.calibrate",
    "calibrate": "analysis.experiments.paper.calibrate",
    "CollisionStudySettings": "analysis.experiments.paper.collision_study",
    "collision_study": "analysis.experiments.paper.collision_study",
    "ReproduceSettings": "analysis.experiments.paper.plan",
    "reproduce": "analysis.experiments.paper.reproduce",
    # where a detector breaks, and a learnt policy tested where it was not learnt
    "BoundarySettings": "analysis.boundary.settings",
    "boundary": "analysis.experiments.collision.boundary_campaign",
    "AdaptationSettings": "analysis.experiments.collision.adaptation",
    "adaptation": "analysis.experiments.collision.adaptation",
    "predictors": "analysis.experiments.collision.predictor_runs",
    # the pre-registered plan (docs/findings/power_plan.md), run from nothing, and its answer
    "PowerStudySettings": "analysis.experiments.power.study",
    "power_study": "analysis.experiments.power.study",
    "Policy": "avdm.policy",
    "load_policy": "avdm.policy",
    # models
    "make_model": "avdm.registry",
    "make_params": "avdm.registry",
    "describe_models": "avdm.registry",
    "calibration_for": "avdm.calibration_store",
    # where tasks run, and what a long command tells its caller as it goes
    "ExecutorSettings": "vdc.executors",
    "Feedback": "vdc.executors",
}

__all__ = sorted(_API)
__version__ = _version("visual-dynamic-complexity")  # written once, in pyproject.toml


# public name -> the name its module gives it, where the two differ (``vdc.summarise`` is
# ``vdc-analyse summarise``; in its module it says which of the summaries it is)
_RENAMED = {"summarise": "summarise_batch"}

# name -> a module of the API itself (``vdc.catalog.query(...)``)
_MODULES = {"catalog": "vdc.catalog"}


__getattr__, __dir__ = _lazy_face(__name__, _API, _RENAMED, _MODULES)


def _stub() -> str:
    """The text of ``vdc/__init__.pyi`` (``vdc.lazy.api_stub``): regenerate it with
    ``python -c 'import vdc; open("vdc/__init__.pyi", "w").write(vdc._stub())'``."""
    return _api_stub(_API, _RENAMED, _MODULES, "__version__: str")
