"""``vdc-analyse dataset``: a LeRobot robot-learning dataset profiled episode by episode.

Every camera of every episode is decoded once (an executor task each: the local pool or
Dask), beside the episode's rows of data, and measured: counts, drift between the video's
clock and the data's, dropped, repeated and frozen frames, idle head and tail, the default
complexity metrics (and the AVDM's angular speed in deg/s with ``--fov-deg``), blur and
exposure, the camera's shift against its reference view, and its lag behind the robot's
state. Each measure that crosses its threshold (``analysis.dataset.flags.FLAGS``) flags the
episode. The dataset is read, never imported: pyarrow and PyAV, no torch, no lerobot.

Writes into ``out``: ``episodes.parquet`` (one row per episode × camera), ``frames.parquet``
(one row per decoded frame), ``problems.parquet`` (what could not be read: file, episode,
message) and ``dataset.html`` (the episodes worst first). An unreadable episode is a problem
line, and the others are still profiled; the tables are published whole
(``vdc.parquet_io.table_set``).

This face loads nothing heavy: the work is in ``analysis.dataset.command``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from vdc.cli_support import API_ONLY, non_negative_float, non_negative_int, option, positive_float
from vdc.executors import ExecutorSettings, Feedback, executor_field
from vdc.parquet_io import WroteFiles

__all__ = ["DatasetResult", "DatasetSettings", "dataset"]

# the metrics measured unless told: those of ``vdc-analyse complexity``'s default set that a
# dataset's frames give (the angular ones need --fov-deg)
DEFAULT_METRICS = "omega_dps,si_p910,ti_p910,mafd,flow_dps,codec_bpp"


@dataclasses.dataclass(frozen=True)
class DatasetSettings:
    """``vdc-analyse dataset``: what is measured, the thresholds' one free choice (what a
    repeat is), which flags fail a run, and where the episodes run."""

    metrics: str = option(
        DEFAULT_METRICS,
        "the complexity metrics per frame: comma-separated names as vdc-analyse complexity's "
        "--metrics (omega_dps and flow_dps need --fov-deg)",
    )
    fov_deg: float | None = option(
        None,
        "the cameras' horizontal field of view, degrees: the AVDM's angular speed (omega_dps) "
        "and the shifts in degrees; without it they are left out, with one note",
        type=positive_float,
    )
    model: str = option("avdm-natural", "the AVDM variant for omega_dps")
    flow_preset: str = option("medium", "DIS optic-flow preset (flow_dps)")
    width: int | None = option(None, "working width of the AVDM, px (default: from the fov)")
    jpeg_quality: int = dataclasses.field(default=75, metadata=API_ONLY)
    repeat_tol: float = option(
        0.5,
        "a frame whose mean |difference| from the previous one is at most this (8-bit levels) "
        "shows nothing new (a repeat, a frozen or an idle frame)",
        type=non_negative_float,
    )
    max_repeats: int = option(3, "at most this many repeats in a row", type=non_negative_int)
    fail_on: str = option(
        "",
        "FLAG,...: exit 1 when an episode has one of these flags (all: any flag); the flags: "
        "frozen, dropped, drift, moved, moved_within, lag, idle, idle_tail, blurred, "
        "underexposed, overexposed, short",
    )
    episodes: str | None = option(None, "only these episodes: comma-separated indices")
    page: bool = option(True, "write dataset.html (the episodes worst first, with thumbnails)")
    executor: str = executor_field("executor")
    jobs: int = executor_field("jobs")
    scheduler: str | None = executor_field("scheduler")

    def __post_init__(self) -> None:
        from analysis.dataset.flags import FLAGS
        from analysis.source_metrics import parse_metrics

        parse_metrics(self.metrics)
        unknown = [f for f in self.fail_names() if f not in FLAGS]
        if unknown:
            raise ValueError(
                f"--fail-on: unknown flag {unknown[0]!r}; choose from {', '.join(FLAGS)} or all"
            )
        self.episode_list()
        self.executor_settings()

    def fail_names(self) -> list[str]:
        from analysis.dataset.flags import FLAGS

        names = [n.strip() for n in self.fail_on.split(",") if n.strip()]
        return list(FLAGS) if names == ["all"] else names

    def episode_list(self) -> list[int] | None:
        if self.episodes is None:
            return None
        try:
            return [int(e) for e in self.episodes.split(",") if e.strip()]
        except ValueError:
            raise ValueError(
                f"--episodes: give comma-separated indices, got {self.episodes!r}"
            ) from None

    def executor_settings(self) -> ExecutorSettings:
        return ExecutorSettings(self.executor, self.jobs, self.scheduler)

    def native_metrics(self) -> tuple[str, ...]:
        """The metrics computed on the native frames (the MAFD always: repeats need it)."""
        from analysis.source_metrics import MODEL_METRICS, parse_metrics

        return (*(m for m in parse_metrics(self.metrics) if m not in MODEL_METRICS), "mafd")

    def model_metrics(self) -> tuple[str, ...]:
        """The metrics computed on the AVDM's raster: only with a field of view."""
        from analysis.source_metrics import MODEL_METRICS, parse_metrics

        if self.fov_deg is None:
            return ()
        return tuple(m for m in parse_metrics(self.metrics) if m in MODEL_METRICS)


@dataclasses.dataclass(frozen=True)
class DatasetResult(WroteFiles):
    """What ``dataset`` wrote (``paths``: episodes.parquet, frames.parquet, problems.parquet,
    dataset.html), the episodes table (polars; worst first), the problems as lines, the
    episodes flagged by ``fail_on`` and the notes (e.g. no field of view)."""

    paths: list[Path]
    episodes: Any
    problems: list[str]
    failed: list[int]
    notes: list[str]

    @property
    def exit_status(self) -> int:
        """2 where input was unreadable, else 1 where ``fail_on`` flagged an episode, else 0."""
        return 2 if self.problems else 1 if self.failed else 0


def dataset(
    path: str | Path,
    settings: DatasetSettings | None = None,
    out: str | Path = "results/dataset",
    feedback: Feedback | None = None,
) -> DatasetResult:
    """Profile the LeRobot dataset at ``path`` episode by episode into ``out`` (see the
    module). Needs the ``__main__`` guard in a script (it starts a process pool). A dataset
    that cannot be read at all (no meta/info.json, an unknown codebase_version) raises
    UserError; an unreadable episode is listed in ``problems``."""
    from analysis.dataset.command import run

    return run(Path(path), settings or DatasetSettings(), Path(out), feedback or Feedback())
