"""``vdc-analyse complexity``'s settings (:class:`ComplexitySettings`): the metrics, the AVDM
variant, the baselines' few free choices, how video sources are read and where they run. Each
field is a flag of the command line (``vdc.cli_support.option``)."""

from __future__ import annotations

import dataclasses
from typing import Any

from analysis.batch import parse_shard
from analysis.complexity.meter import (
    DEFAULT_METRICS,
    DIS_PRESETS,
    METRICS,
    parse_metrics,
)
from analysis.complexity.source_metrics import (
    measured_settings,
)
from avdm.registry import require_angular_velocity
from vdc.cli_support import option
from vdc.errors import UserError
from vdc.executors import ExecutorSettings, executor_field
from vdc.frame_metrics import (
    RANGE_CHOICES,
)
from vdc.recording import FOOTAGE_MODEL
from vdc.settings import API_ONLY, AT_LEAST_0, RANGE, Settings, between


@dataclasses.dataclass(frozen=True)
class ComplexitySettings(Settings):
    """``vdc-analyse complexity``: the AVDM variant, the baselines' few free choices, how
    video sources are read (as ``vdc-capture video`` reads them), and where the sources run."""

    metrics: str = option(
        ",".join(DEFAULT_METRICS),
        "the metrics to compute: comma-separated column names ("
        + ", ".join(METRICS)
        + ") or all; the default set is chosen for need and speed (docs/guides/video.md)",
    )
    model: str = option(
        FOOTAGE_MODEL,
        "the AVDM variant (default: {default}, valid 1-300 deg/s on real footage; avdm is the "
        "paper's, valid up to about 1 px of motion per frame)",
    )
    flow_preset: str = option(  # "medium" keeps the finest scale on small frames
        "medium", "DIS optic-flow preset", choices=tuple(DIS_PRESETS)
    )
    jpeg_quality: int = option(75, "JPEG quality, 1-100", range=between(1, 100))
    zlib_level: int = dataclasses.field(  # zlib_ratio's compression level
        default=6, metadata={**API_ONLY, RANGE: between(0, 9)}
    )
    fov_deg: float | None = option(
        None,
        "video sources: the camera's horizontal field of view, degrees (needed for the AVDM "
        "and the flow in deg/s; without it a video gives the other metrics)",
        range=between(1, 360),
    )
    fps: float | None = option(
        None,
        "image sequences: frame rate, Hz (videos state their own)",
        range=between(0, 10_000, lo_open=True),
    )
    width: int | None = option(
        None,
        "video sources: working width, px (default: fov / (70/99 deg), the robot's pitch)",
        range=between(8, 4096),
    )
    repeat_tol: float = option(
        0.5,
        "video sources: a frame whose mean |difference| from the previous native frame is at "
        "most this (8-bit levels) repeats it",
        range=AT_LEAST_0,
    )
    max_repeats: int = option(
        3, "longer still stretches are a still scene, not repeats", range=AT_LEAST_0
    )
    color_range: str = option(
        "auto",
        "video sources: the luma's colour range for SI/TI; auto: the stream's tag, else as "
        "each reference tool reads it (P.910: full if the luma leaves 16-235, as siti-tools; "
        "legacy: limited, as FFmpeg's siti)",
        choices=RANGE_CHOICES,
    )
    rrd: bool = option(
        False,
        "per clip, also a figure of its metrics over time and an .rrd that opens beside the "
        "source (always for a single source)",
    )
    executor: str = executor_field("executor")
    jobs: int = executor_field("jobs")
    scheduler: str | None = executor_field("scheduler")
    shard: str | None = option(
        None, "I/N: measure only sources I, I+N, ... (0-based; default in a SLURM array: its own)"
    )
    force: bool = option(False, "measure finished sources again")

    def __post_init__(self) -> None:
        require_angular_velocity(self.model, "complexity")
        parse_metrics(self.metrics)
        if self.flow_preset not in DIS_PRESETS:
            raise UserError(f"--flow-preset must be one of {', '.join(DIS_PRESETS)}.")
        if self.color_range not in RANGE_CHOICES:
            choices = ", ".join(RANGE_CHOICES)
            raise UserError(f"--color-range must be one of {choices}, got {self.color_range!r}.")
        self.executor_settings()
        parse_shard(self.shard)

    def metric_names(self) -> tuple[str, ...]:
        """``metrics`` as column names, in the tables' order."""
        return parse_metrics(self.metrics)

    def executor_settings(self) -> ExecutorSettings:
        return ExecutorSettings(self.executor, self.jobs, self.scheduler)

    def measured(self) -> dict[str, Any]:
        """The settings a source's numbers depend on (not where or which it runs)."""
        return measured_settings(dataclasses.asdict(self))
