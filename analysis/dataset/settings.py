"""``vdc-analyse dataset``'s settings (``analysis.dataset.command`` runs the command): a module
of their own, because every pool worker unpickles them with its task, and the command's module
would bring the page's figures, Rerun and the statistics into each worker (about 1 s of CPU
each on this machine)."""

from __future__ import annotations

import dataclasses
import math

from analysis.complexity.meter import DEFAULT_METRICS, MODEL_METRICS, parse_metrics
from analysis.dataset.flags import FLAGS
from vdc.cli_support import option
from vdc.errors import UserError
from vdc.executors import ExecutorSettings, executor_field
from vdc.recording import FOOTAGE_MODEL
from vdc.settings import API_ONLY, AT_LEAST_0, RANGE, Settings, between


@dataclasses.dataclass(frozen=True)
class DatasetSettings(Settings):
    """``vdc-analyse dataset``: what is measured, the thresholds' one free choice (what a
    repeat is), which flags fail a run, and where the episodes run."""

    metrics: str = option(
        # unless told: ``vdc-analyse complexity``'s default set (the angular ones need --fov-deg)
        ",".join(DEFAULT_METRICS),
        "the complexity metrics per frame: comma-separated names as vdc-analyse complexity's "
        "--metrics (omega_dps and flow_dps need --fov-deg)",
    )
    fov_deg: float | None = option(
        None,
        "the cameras' horizontal field of view, degrees: the AVDM's angular speed (omega_dps) "
        "and the shifts in degrees; without it they are left out, with one note",
        range=between(1, 360),
    )
    model: str = option(
        FOOTAGE_MODEL, "the AVDM variant for omega_dps (default: {default}, as complexity)"
    )
    flow_preset: str = option("medium", "DIS optic-flow preset (flow_dps)")
    width: int | None = option(
        None, "working width of the AVDM, px (default: from the fov)", range=between(8, 4096)
    )
    jpeg_quality: int = dataclasses.field(  # jpeg_bpp's quality
        default=75, metadata={**API_ONLY, RANGE: between(1, 100)}
    )
    repeat_tol: float = option(
        0.5,
        "a frame whose mean |difference| from the previous one is at most this (8-bit levels) "
        "shows nothing new (a repeat, a frozen or an idle frame)",
        range=AT_LEAST_0,
    )
    max_repeats: int = option(3, "at most this many repeats in a row", range=AT_LEAST_0)
    fail_on: str = option(
        "",
        "FLAG,...: exit 1 when an episode has one of these flags (all: any flag); the flags: "
        "frozen, dropped, drift, moved, moved_within, lag, idle, idle_tail, blurred, "
        "underexposed, overexposed, short",
    )
    thresholds: str = option(
        "",
        "FLAG=VALUE,...: a flag's threshold in its unit (docs/guides/dataset.md lists the "
        "defaults), or FLAG=off to turn it off, e.g. lag=80,idle_tail=off",
    )
    moving_cameras: str = option(
        "",
        "KEY,...: the cameras that move with the robot (wrist, arm), taken so without learning "
        "it; their view's motion is explained by the state's before a shift is a fault",
    )
    episodes: str | None = option(None, "only these episodes: comma-separated indices")
    page: bool = option(True, "write dataset.html (the episodes worst first, with thumbnails)")
    recordings: bool = option(
        True,
        "write each episode as a Rerun recording, recordings/episode_NNNNNN.rrd (its video "
        "referenced, not decoded; the measures; a blueprint at its flagged frame)",
    )
    executor: str = executor_field("executor")
    jobs: int = executor_field("jobs")
    scheduler: str | None = executor_field("scheduler")

    def __post_init__(self) -> None:
        parse_metrics(self.metrics)
        unknown = [f for f in self.fail_names() if f not in FLAGS]
        if unknown:
            raise UserError(
                f"--fail-on: unknown flag {unknown[0]!r}; choose from {', '.join(FLAGS)} or all."
            )
        self.episode_list()
        self.flag_thresholds()
        self.executor_settings()

    def flag_thresholds(self) -> dict[str, float | None]:
        """The thresholds given (flag → value, None: off)."""
        out: dict[str, float | None] = {}
        for item in filter(None, (t.strip() for t in self.thresholds.split(","))):
            name, eq, value = (x.strip() for x in item.partition("="))
            if name not in FLAGS or not eq:
                raise UserError(
                    f"--thresholds: give FLAG=VALUE or FLAG=off, got {item!r} (the flags: "
                    f"{', '.join(FLAGS)})."
                )
            if value.lower() == "off":
                out[name] = None
                continue
            try:
                v = float(value)
            except ValueError:
                v = math.nan
            if not math.isfinite(v) or v < 0:
                raise UserError(
                    f"--thresholds: {name}'s threshold must be a number >= 0 or off, got {value!r}."
                )
            out[name] = v
        return out

    def moving_camera_list(self) -> tuple[str, ...]:
        return tuple(c.strip() for c in self.moving_cameras.split(",") if c.strip())

    def fail_names(self) -> list[str]:
        names = [n.strip() for n in self.fail_on.split(",") if n.strip()]
        return list(FLAGS) if names == ["all"] else names

    def episode_list(self) -> list[int] | None:
        if self.episodes is None:
            return None
        try:
            return [int(e) for e in self.episodes.split(",") if e.strip()]
        except ValueError:
            raise UserError(
                f"--episodes: give comma-separated indices, got {self.episodes!r}."
            ) from None

    def executor_settings(self) -> ExecutorSettings:
        return ExecutorSettings(self.executor, self.jobs, self.scheduler)

    def native_metrics(self) -> tuple[str, ...]:
        """The metrics computed on the native frames (the MAFD always: repeats need it)."""
        return (*(m for m in parse_metrics(self.metrics) if m not in MODEL_METRICS), "mafd")

    def model_metrics(self) -> tuple[str, ...]:
        """The metrics computed on the AVDM's raster: only with a field of view."""
        if self.fov_deg is None:
            return ()
        return tuple(m for m in parse_metrics(self.metrics) if m in MODEL_METRICS)
