"""``vdc-analyse dataset``: a LeRobot robot-learning dataset profiled episode by episode.

Every camera of every episode is decoded once (an executor task each: the local pool or
Dask), beside the episode's rows of data, and measured: counts, drift between the video's
clock and the data's, dropped, repeated and frozen frames, idle head and tail, the default
complexity metrics (and the AVDM's angular speed in deg/s with ``--fov-deg``), blur and
exposure, the camera's shift against its reference view beyond what the robot's motion
explains (each camera's motion learnt against the state over the dataset: a wrist camera's pan
is not a fault), and its lag behind the robot's state and behind the episode's first camera.
Each flag whose evidence (an estimate's interval, not its point) reaches its threshold
(``analysis.dataset.flags.FLAGS``) flags the episode; the flagged episodes are listed with
the ``lerobot-edit-dataset`` command that deletes them (``flagged_episodes.json``). The
dataset is read, never imported: pyarrow and PyAV, no torch, no lerobot.

Writes into ``out``: ``episodes.parquet`` (one row per episode × camera), ``frames.parquet``
(one row per decoded frame), ``problems.parquet`` (what could not be read, or contradicts the
rest of the dataset: file, episode, message), ``dataset.html`` (the episodes worst first)
and ``recordings/episode_NNNNNN.rrd`` (each episode as a vdc recording: its video
referenced, its measures, a segment of the catalog). An unreadable episode is a problem
line, and the others are still profiled; the tables are published whole
(``vdc.parquet_io.table_set``). Each camera of each episode is kept
as it is measured (``episode_results/``), so a killed run resumes where it stopped.

Modules: ``command`` (settings, the command, its result) → ``layout`` (the dataset's files) →
``resume`` (results kept per episode) → ``window`` (an episode's frames) → ``measure`` (one
camera of one episode) → ``flags`` (what the whole dataset decides) → ``page`` (dataset.html),
``episode_rrd`` (the recordings); ``synthetic`` (test datasets with faults).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from vdc.lazy import lazy_face

if TYPE_CHECKING:
    from analysis.dataset.command import DatasetResult, dataset
    from analysis.dataset.settings import DatasetSettings

# the public face: name -> the module that defines it (loaded on first use)
_FACE = {
    "DatasetSettings": "analysis.dataset.settings",
    "DatasetResult": "analysis.dataset.command",
    "dataset": "analysis.dataset.command",
}
__all__ = ["DatasetResult", "DatasetSettings", "dataset"]
__getattr__, __dir__ = lazy_face(__name__, _FACE)
