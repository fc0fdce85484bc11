"""The AVDM beside established complexity measures, per frame (``vdc-analyse complexity``).

Columns (one per metric, unit or variant in the name; see shared reference
complexity_metrics.md):

* ``omega_dps``: the AVDM's angular velocity (deg/s), on new frames over true time;
* ``si_p910`` / ``ti_p910``: ITU-T P.910 (07/2022+) SI and TI as siti-tools computes them
  (full-range 8-bit luma → BT.1886 display, 300 cd/m² → PQ → ×255);
* ``si_legacy`` / ``ti_legacy``: the pre-2022 definition on code values (siti-tools' legacy);
* ``mafd``: mean absolute frame difference, 8-bit levels (VMAF-motion's family);
* ``flow_dps``: mean horizontal dense optic-flow speed (OpenCV DIS), mean |u_x| in px/frame ×
  deg/px ÷ the true time between new frames, deg/s. Horizontal because the AVDM's correlators
  are horizontal, and because the vertical flow of vertically uniform patterns (gratings,
  walls) is unconstrained (the aperture problem): DIS then returns noise-driven vertical flow
  of tens of px/frame on codec-compressed gratings;
* ``edge_density``: share of Canny edge pixels (thresholds 100/200 on 8-bit luma);
* ``zlib_ratio``: zlib-compressed / raw size of the luma plane (level 6; higher = more complex);
* ``jpeg_bpp``: bits per pixel of the frame as JPEG at quality 75 (OpenCV).

Temporal metrics are null on a source's first frame. TI, MAFD and flow follow their standard
definitions on every frame (a repeated frame gives TI = 0); ``flow_dps`` and ``omega_dps`` are
computed between new frames and held over repeats, so both read true motion.
"""

from __future__ import annotations

import dataclasses
import math
import zlib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import polars as pl
from siti_tools.siti import ColorRange, SiTiCalculator

from avdm.registry import make_model
from avdm.true_time import TrueTimeModel, repeat_flags
from vdc.cli_support import API_ONLY, option
from vdc.parquet_io import WroteFiles
from vdc.recording import FOOTAGE_MODEL, camera_model_context, working_size

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
)
DIS_PRESETS = {
    "ultrafast": cv2.DISOPTICAL_FLOW_PRESET_ULTRAFAST,
    "fast": cv2.DISOPTICAL_FLOW_PRESET_FAST,
    "medium": cv2.DISOPTICAL_FLOW_PRESET_MEDIUM,
}


@dataclasses.dataclass(frozen=True)
class ComplexitySettings:
    """``vdc-analyse complexity``: the AVDM variant and the baselines' few free choices."""

    model: str = option(
        FOOTAGE_MODEL,
        "the AVDM variant (default: {default}, valid 1-300 deg/s on real footage; avdm is the "
        "paper's, valid up to about 1 px of motion per frame)",
    )
    flow_preset: str = option(  # "medium" keeps the finest scale on small frames
        "medium", "DIS optic-flow preset", choices=("ultrafast", "fast", "medium")
    )
    jpeg_quality: int = option(75, "JPEG quality, 1-100")
    zlib_level: int = dataclasses.field(default=6, metadata=API_ONLY)

    def __post_init__(self) -> None:
        from avdm.registry import require_angular_velocity

        require_angular_velocity(self.model, "complexity")
        if self.flow_preset not in DIS_PRESETS:
            raise ValueError(f"--flow-preset must be one of {', '.join(DIS_PRESETS)}")
        if not 1 <= self.jpeg_quality <= 100:
            raise ValueError(f"--jpeg-quality must be 1-100, got {self.jpeg_quality}")
        if not 0 <= self.zlib_level <= 9:
            raise ValueError(f"--zlib-level must be 0-9, got {self.zlib_level}")


class _SiTi:
    """Per-frame SI and TI with siti-tools' own transforms, on full-range 8-bit luma."""

    def __init__(self, legacy: bool) -> None:
        self.calc = SiTiCalculator(color_range=ColorRange.FULL, legacy=legacy)
        self.legacy = legacy
        self.prev: np.ndarray | None = None

    def domain(self, frame: np.ndarray) -> np.ndarray:
        x = self.calc.normalize_between_0_1(frame.astype(np.float64))
        if not self.legacy:
            c = self.calc
            x = SiTiCalculator.apply_display_model(
                x, eotf_function=c.eotf_function, l_max=c.l_max, l_min=c.l_min, gamma=c.gamma
            )
            x = c.oetf_function(x, **c.oetf_function_kwargs)
        return x

    def __call__(self, frame: np.ndarray) -> tuple[float, float]:
        x = self.domain(frame)
        si = float(self.calc.normalize_to_original_si_range(SiTiCalculator.si(x)))
        ti = (
            math.nan
            if self.prev is None
            else float(self.calc.normalize_to_original_si_range(SiTiCalculator.ti(x, self.prev)))
        )
        self.prev = x
        return si, ti


class ComplexityMeter:
    """Streams frames through every metric; ``update`` continues from earlier chunks.

    frames (T, H, W) uint8 luma; t_s (T,) seconds; repeat (T,) bool (None: detect them)."""

    def __init__(
        self,
        fps: float,
        deg_per_px: float,
        settings: ComplexitySettings = ComplexitySettings(),
        context: dict[str, Any] | None = None,
    ) -> None:
        self.s = settings
        self.fps = fps
        self.deg_per_px = deg_per_px
        ctx = context or {"fps": fps, "deg_per_px": deg_per_px}
        self.model = TrueTimeModel(make_model(settings.model, **ctx))
        self.siti = _SiTi(legacy=False)
        self.siti_legacy = _SiTi(legacy=True)
        self.dis = cv2.DISOpticalFlow_create(DIS_PRESETS[settings.flow_preset])
        self.prev: np.ndarray | None = None  # the previous frame
        self.prev_new: np.ndarray | None = None  # the previous new (non-repeated) frame
        self.prev_new_t: float | None = None
        self.flow_held = math.nan
        self.run = 0

    def update(
        self, frames: np.ndarray, t_s: np.ndarray, repeat: np.ndarray | None = None
    ) -> dict[str, np.ndarray]:
        if repeat is None:
            repeat = repeat_flags(frames, self.prev, self.run)
            for r in repeat:
                self.run = self.run + 1 if r else 0
        out = {m: np.full(len(frames), np.nan) for m in METRICS}
        out["omega_dps"] = self.model.run(frames, t_s, repeat)["omega_dps"]
        for i, f in enumerate(frames):
            out["si_p910"][i], out["ti_p910"][i] = self.siti(f)
            out["si_legacy"][i], out["ti_legacy"][i] = self.siti_legacy(f)
            if self.prev is not None:
                out["mafd"][i] = float(np.abs(f.astype(np.int16) - self.prev).mean())
            if not repeat[i]:
                if self.prev_new is not None:
                    flow = self.dis.calc(self.prev_new, f, None)
                    px = float(np.abs(flow[..., 0]).mean())  # horizontal: the AVDM's axis
                    dt = float(t_s[i]) - (self.prev_new_t or 0.0)
                    dt = dt if dt > 0 else 1.0 / self.fps
                    self.flow_held = px * self.deg_per_px / dt
                self.prev_new, self.prev_new_t = f, float(t_s[i])
            out["flow_dps"][i] = self.flow_held
            out["edge_density"][i] = float((cv2.Canny(f, 100, 200) > 0).mean())
            raw = f.tobytes()
            out["zlib_ratio"][i] = len(zlib.compress(raw, self.s.zlib_level)) / len(raw)
            ok, jpg = cv2.imencode(".jpg", f, [cv2.IMWRITE_JPEG_QUALITY, self.s.jpeg_quality])
            out["jpeg_bpp"][i] = 8.0 * len(jpg) / f.size if ok else math.nan
            self.prev = f.astype(np.int16)
        return out


def complexity_of_frames(
    frames: np.ndarray,
    fps: float,
    fov_deg: float,
    t_s: np.ndarray | None = None,
    settings: ComplexitySettings = ComplexitySettings(),
    width: int | None = None,
) -> pl.DataFrame:
    """Every metric per frame of ``frames`` (T, H, W) uint8 luma at the source's resolution,
    filmed at ``fps`` Hz (or at the times ``t_s``, seconds) by a camera whose horizontal field
    of view is ``fov_deg``.

    The frames are area-resized to the working raster ``vdc-capture video`` uses (``width``
    px, default the robot camera's angular pitch; ``vdc.recording.working_size``) and the
    models are built with the same context, so this function and ``vdc-capture video`` then
    ``vdc-analyse complexity`` give the same readings for the same decoded frames.

    Returns a DataFrame: frame, t_s, repeat, then one column per metric (see the module)."""
    frames = np.asarray(frames)
    if frames.ndim != 3 or frames.dtype != np.uint8 or len(frames) == 0:
        raise ValueError(f"frames must be a non-empty (T, H, W) uint8 array, got {frames.shape}")
    h, w = working_size(frames.shape[1], frames.shape[2], fov_deg, width)
    if (h, w) != frames.shape[1:]:
        frames = np.stack([cv2.resize(f, (w, h), interpolation=cv2.INTER_AREA) for f in frames])
    t = np.arange(len(frames)) / fps if t_s is None else np.asarray(t_s, np.float64)
    # whole nanoseconds, as a recording stores times: the true-time scaling then matches
    t = np.rint(t * 1e9) / 1e9
    ctx = camera_model_context(w, h, fps, fov_deg)
    meter = ComplexityMeter(fps, float(ctx["deg_per_px"]), settings, ctx)
    repeat = repeat_flags(frames)
    out = meter.update(frames, t, repeat)
    return pl.DataFrame(
        {"frame": np.arange(len(frames), dtype=np.int64), "t_s": t, "repeat": repeat, **out}
    ).with_columns(pl.col(*METRICS).fill_nan(None))


@dataclasses.dataclass
class ComplexityResult(WroteFiles):
    table: pl.DataFrame  # recording_id, frame, t_s, repeat, metrics...
    correlations: pl.DataFrame  # Spearman rank correlation of every pair, per recording
    paths: list[Path]
    notices: list[str]


def complexity(
    recordings: Sequence[str | Path],
    settings: ComplexitySettings = ComplexitySettings(),
    out: str | Path | None = None,
    *,
    progress: Callable[[int], None] | None = None,
    notice: Callable[[str], None] | None = None,
) -> ComplexityResult:
    """``vdc-analyse complexity``: every metric per frame of any recording (video, arena,
    robot). With ``out``: ``complexity.parquet`` (settings and versions in its metadata),
    ``complexity_correlations.parquet``, and per recording a figure (metrics over time,
    normalised, and their rank correlations) and an ``.rrd`` with the source's recording id
    (open it beside the source: ``rerun REC OUT/complexity_<id>.rrd``)."""
    from analysis.tables import DistinctRecordings, Notices, load_recording
    from vdc.parquet_io import table_set, write_parquet

    parts, corrs, paths, notes = [], [], [], Notices(notice)
    distinct = DistinctRecordings()
    for path in recordings:
        loaded = load_recording(path)
        distinct.add(loaded.recording_id, path)
        notes.of(loaded)
        ctx = loaded.camera_context()
        cam = loaded.props.get("camera", {})
        if not ctx or "width_px" not in cam:
            raise ValueError(f"{str(path)!r} does not record its camera (fps, width, FOV)")
        fps, deg_per_px = float(ctx["fps"]), float(ctx["deg_per_px"])
        meter = ComplexityMeter(fps, deg_per_px, settings, ctx)
        timing = loaded.frames.select("frame", "t_s", "repeat")
        has_timing = timing["repeat"].null_count() < timing.height
        rows = []
        for chunk in loaded.rec.iter_frames():
            sel = pl.DataFrame({"frame": chunk.frame.astype(np.int64)}).join(
                timing, on="frame", how="left", maintain_order="left"
            )
            t = sel["t_s"].fill_null(strategy="forward").to_numpy()
            rep = sel["repeat"].fill_null(False).to_numpy() if has_timing else None
            res = meter.update(chunk.images, t, rep)
            rows.append(pl.DataFrame({"frame": chunk.frame.astype(np.int64), "t_s": t, **res}))
            if progress is not None:
                progress(len(chunk.frame))
        df = (
            pl.concat(rows)
            .with_columns(pl.lit(loaded.recording_id).alias("recording_id"))
            .with_columns(pl.col(*METRICS).fill_nan(None))
            .select("recording_id", "frame", "t_s", *METRICS)
        )
        parts.append(df)
        corrs.append(rank_correlations(df, loaded.recording_id))
    table = pl.concat(parts)
    corr = pl.concat(corrs)
    if out is not None:
        meta = {
            "settings": dataclasses.asdict(settings),
            "recordings": sorted(table["recording_id"].unique().to_list()),
            "metrics": list(METRICS),
        }
        with table_set(Path(out)) as stage:  # published whole: never a mix of two runs
            paths.append(write_parquet(table, stage / "complexity.parquet", meta))
            paths.append(write_parquet(corr, stage / "complexity_correlations.parquet", meta))
            for df, c in zip(parts, corrs, strict=True):
                rid = df["recording_id"][0]
                paths.append(plot_complexity(df, c, stage / f"complexity_{rid}.png"))
                paths.append(write_complexity_rrd(df, rid, stage / f"complexity_{rid}.rrd"))
        paths = [Path(out) / p.name for p in paths]
    return ComplexityResult(table, corr, paths, list(notes))


def rank_correlations(df: pl.DataFrame, recording_id: str) -> pl.DataFrame:
    """Spearman ρ of every pair of metrics over the frames where both are defined."""
    from analysis.stats import spearman

    rows = []
    for i, a in enumerate(METRICS):
        for b in METRICS[i + 1 :]:
            d = df.select(a, b).drop_nulls()
            rho = spearman(d[a].to_numpy(), d[b].to_numpy()) if d.height > 2 else math.nan
            rows.append(
                {"recording_id": recording_id, "metric_a": a, "metric_b": b, "spearman": rho}
            )
    return pl.DataFrame(rows)


def _normalised(df: pl.DataFrame) -> dict[str, np.ndarray]:
    """Each metric divided by its 99th percentile (so all share one axis)."""
    out = {}
    for m in METRICS:
        v = df[m].cast(pl.Float64).fill_null(np.nan).to_numpy()
        top = np.nanpercentile(v, 99) if np.isfinite(v).any() else np.nan
        out[m] = v / top if top and np.isfinite(top) and top > 0 else v * np.nan
    return out


def plot_complexity(df: pl.DataFrame, corr: pl.DataFrame, path: Path) -> Path:
    from matplotlib.figure import Figure

    from analysis.profile import save_figure

    norm = _normalised(df)
    t = df["t_s"].to_numpy()
    fig = Figure(figsize=(16, 5.5), layout="constrained")
    (ax, axc) = fig.subplots(1, 2, gridspec_kw={"width_ratios": [2.2, 1]})
    for m in METRICS:
        ax.plot(t, norm[m], lw=1.6 if m == "omega_dps" else 0.8, label=m, alpha=0.9)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("metric / its 99th percentile")
    ax.set_title("complexity metrics over time (normalised)")
    ax.legend(fontsize=7, ncol=2)
    ax.grid(alpha=0.3)
    n = len(METRICS)
    mat = np.eye(n)
    for r in corr.iter_rows(named=True):
        i, j = METRICS.index(r["metric_a"]), METRICS.index(r["metric_b"])
        mat[i, j] = mat[j, i] = r["spearman"]
    im = axc.imshow(mat, vmin=-1, vmax=1, cmap="RdBu_r")
    for i in range(n):
        for j in range(n):
            if np.isfinite(mat[i, j]):
                axc.text(j, i, f"{mat[i, j]:.2f}", ha="center", va="center", fontsize=6)
    axc.set_xticks(range(n), METRICS, rotation=45, ha="right", fontsize=7)
    axc.set_yticks(range(n), METRICS, fontsize=7)
    axc.set_title("Spearman rank correlation over frames")
    fig.colorbar(im, ax=axc, shrink=0.8)
    fig.suptitle(str(df["recording_id"][0]))
    return save_figure(fig, path)


def write_complexity_rrd(df: pl.DataFrame, recording_id: str, path: Path) -> Path:
    """The normalised metrics under ``/complexity/<metric>`` with the source's recording id,
    on its ``frame`` and ``time`` timelines (so it merges with the source in the viewer)."""
    import rerun as rr

    from vdc.recording import APP_ID, COMPLEXITY_ROOT, FRAME_TIMELINE, TIME_TIMELINE

    path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream(APP_ID, recording_id=recording_id)
    rec.save(str(path))
    norm = _normalised(df)
    idx = [
        rr.TimeColumn(FRAME_TIMELINE, sequence=df["frame"].to_numpy()),
        rr.TimeColumn(
            TIME_TIMELINE,
            duration=np.rint(df["t_s"].to_numpy() * 1e9).astype("timedelta64[ns]"),
        ),
    ]
    for m in METRICS:
        entity = f"{COMPLEXITY_ROOT}/{m}"
        rec.log(entity, rr.SeriesLines(names=[f"{m} (normalised)"]), static=True)
        rec.send_columns(entity, indexes=idx, columns=rr.Scalars.columns(scalars=norm[m]))
    rec.flush()
    rec.disconnect()
    return path
