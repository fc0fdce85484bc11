"""The per-frame measures on the model raster (the AVDM, the optic flow, zlib), the metric
names and their parsing: what measuring one frame needs, apart from the commands that read
sources and write tables (``analysis.complexity.source_metrics``). Kept apart so a pool worker
that only measures frames (``vdc-analyse dataset``'s episodes) imports no more than that:
the commands' own imports (recordings, statistics, Rerun) cost a worker about 2 s of start-up
on this machine's two cores."""

from __future__ import annotations

import math
import zlib
from typing import Any, Protocol

import cv2
import numpy as np

from avdm.registry import make_model
from avdm.true_time import ModelRate, TrueTimeModel, repeat_flags
from vdc.errors import UserError
from vdc.frame_metrics import NativeMeter
from vdc.recording import NATIVE_METRICS


class MeasureSettings(Protocol):
    """What measuring a source needs of its settings
    (``analysis.complexity.command.ComplexitySettings``
    has it all)."""

    model: str
    flow_preset: str
    jpeg_quality: int
    zlib_level: int
    fov_deg: float | None
    fps: float | None
    width: int | None
    repeat_tol: float
    max_repeats: int
    metrics: str  # --metrics: comma-separated column names, or all
    color_range: str


MODEL_METRICS = ("omega_dps", "flow_dps", "zlib_ratio")
# a metric's validity flag, a column beside the metrics (not one of them: never averaged,
# ranked or correlated), present whenever the metric is
VALIDITY_FLAGS = {"omega_dps": "omega_valid"}
# in deg/s: a video source needs its camera's field of view for these
ANGULAR_METRICS = ("omega_dps", "flow_dps")
METRICS = (
    "omega_dps",
    "si_p910",
    "ti_p910",
    "si_legacy",
    "ti_legacy",
    "mafd",
    "flow_dps",
    "edge_density",
    "zlib_ratio",
    "jpeg_bpp",
    "codec_bpp",
)
# what ``--metrics`` gives unless told (docs/guides/video.md says why): the AVDM and the flow (the
# motion it reads, and the independent check of it), P.910 SI/TI (the standard), the MAFD (free:
# repeats are judged on it) and the codec's own bits (free: the packet sizes). Left out: the
# legacy SI/TI (superseded in 2022; a second pass), edge density (Canny) and JPEG (a second
# encoder) at native resolution, and zlib: together more than half the per-frame cost.
DEFAULT_METRICS = ("omega_dps", "si_p910", "ti_p910", "mafd", "flow_dps", "codec_bpp")
# the raster each column is computed on: "model" (the AVDM's working raster) or "source"
# (native frames where the source has them, else the camera's raster: the `raster` column)
RASTERS = {m: "model" if m in MODEL_METRICS else "source" for m in METRICS}
DIS_PRESETS = {
    "ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
    "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
    "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM,
}


def parse_metrics(text: str | tuple[str, ...] | list[str]) -> tuple[str, ...]:
    """``--metrics``: comma-separated column names (or a sequence of them), or ``all``
    → the names in :data:`METRICS` order. An unknown or missing name raises ValueError."""
    names = [n.strip() for n in (text.split(",") if isinstance(text, str) else text)]
    names = [n for n in names if n]
    if names == ["all"]:
        return METRICS
    unknown = [n for n in names if n not in METRICS]
    if unknown or not names:
        raise UserError(
            f"--metrics: {'unknown ' + ', '.join(unknown) if unknown else 'no metric named'}; "
            f"choose from {', '.join(METRICS)} (or all)."
        )
    return tuple(m for m in METRICS if m in names)


def chosen_metrics(settings: Any) -> tuple[str, ...]:
    """The metrics a settings object asks for (its ``metrics``; all where it has none)."""
    return parse_metrics(getattr(settings, "metrics", "all"))


class ComplexityMeter:
    """Streams model-raster frames through the model-raster metrics; ``update`` continues from
    earlier chunks. With ``camera_baselines`` it also measures the source-raster metrics on
    these frames (8-bit, full range): sources without native frames. Only the metrics in
    ``metrics`` (default: the settings') are computed; the others are NaN.

    ``rate``: the rate the model is built at and why (``avdm.true_time.model_rate``, decided
    on the whole stream's repeats by the caller); None: the camera's own rate (``fps``: the
    arena's and the robot's frames, which no one doubles).

    frames (T, H, W) uint8 luma; t_s (T,) seconds; repeat (T,) bool (None: detect them)."""

    def __init__(
        self,
        fps: float,
        deg_per_px: float,
        settings: MeasureSettings,
        context: dict[str, Any] | None = None,
        camera_baselines: bool = False,
        metrics: tuple[str, ...] | None = None,
        rate: ModelRate | None = None,
    ) -> None:
        self.s = settings
        self.fps = fps
        self.deg_per_px = deg_per_px
        self.metrics = chosen_metrics(settings) if metrics is None else metrics
        self.context = dict(context or {"fps": fps, "deg_per_px": deg_per_px})
        self.rate = rate or ModelRate(float(fps), 1.0, "camera frames")
        self.want_omega = "omega_dps" in self.metrics
        self.model: TrueTimeModel | None = None  # built on the first frames, at self.rate
        self.model_fps: float | None = None
        want_flow = "flow_dps" in self.metrics
        self.dis = (
            cv2.DISOpticalFlow_create(DIS_PRESETS[settings.flow_preset]) if want_flow else None
        )
        native = tuple(m for m in NATIVE_METRICS if m in self.metrics)
        self.camera = (
            NativeMeter(8, "full", settings.jpeg_quality, (*native, "mafd"))
            if camera_baselines
            else None
        )
        self.prev_new: np.ndarray | None = None  # the previous new (non-repeated) frame
        self.prev_new_t: float | None = None
        self.prev: np.ndarray | None = None
        self.flow_held = math.nan
        self.run = 0

    def update(
        self, frames: np.ndarray, t_s: np.ndarray, repeat: np.ndarray | None = None
    ) -> dict[str, np.ndarray]:
        if repeat is None:
            repeat = repeat_flags(frames, self.prev, self.run)
            for r in repeat:
                self.run = self.run + 1 if r else 0
        out = {m: np.full(len(frames), np.nan) for m in MODEL_METRICS}
        if self.want_omega:
            if self.model is None:
                self.model_fps = self.rate.fps
                ctx = self.context | {"fps": self.model_fps}
                cadence = self.rate.reason == "regular cadence"
                self.model = TrueTimeModel(make_model(self.s.model, **ctx), cadence)
            res = self.model.run(frames, t_s, repeat)  # repeats hold the last new frame's
            out["omega_dps"] = res["omega_dps"]
            out["omega_valid"] = res.get("omega_valid", np.full(len(frames), np.nan))
        if self.camera is not None:
            rows = np.stack([self.camera.row(f) for f in frames])
            out |= {name: rows[:, k] for k, name in enumerate(NATIVE_METRICS)}
        want_zlib = "zlib_ratio" in self.metrics
        for i, f in enumerate(frames):
            if self.dis is not None:
                if not repeat[i]:
                    if self.prev_new is not None:
                        flow = self.dis.calc(self.prev_new, f, None)
                        px = float(np.abs(flow[..., 0]).mean())  # horizontal: the AVDM's axis
                        dt = float(t_s[i]) - (self.prev_new_t or 0.0)
                        dt = dt if dt > 0 else 1.0 / self.fps
                        self.flow_held = px * self.deg_per_px / dt
                    self.prev_new, self.prev_new_t = f, float(t_s[i])
                out["flow_dps"][i] = self.flow_held
            if want_zlib:
                raw = f.tobytes()
                out["zlib_ratio"][i] = len(zlib.compress(raw, self.s.zlib_level)) / len(raw)
        self.prev = frames[-1] if len(frames) else self.prev
        return out


def flags_of(metrics: tuple[str, ...]) -> tuple[str, ...]:
    """The validity flags (:data:`VALIDITY_FLAGS`) that come with ``metrics``."""
    return tuple(VALIDITY_FLAGS[m] for m in metrics if m in VALIDITY_FLAGS)


def fov_free(metrics: tuple[str, ...], width: int | None = None) -> tuple[str, ...]:
    """The ``metrics`` a video can give without its field of view: all but the angular ones
    (deg/s), and but zlib_ratio unless ``width`` sets the model raster (else the FOV does)."""
    need = ANGULAR_METRICS if width else MODEL_METRICS
    return tuple(m for m in metrics if m not in need)
