"""The AVDM beside the established complexity measures, per frame of one source.

Columns (one per metric, its unit or variant in the name):

* on the **model raster** (the working raster the AVDM's angular calibration holds on: the
  robot camera's pitch, 70°/99 px):

  * ``omega_dps``: the AVDM's angular velocity (deg/s), on new frames over true time;
    ``omega_valid`` (bool, with it): whether that reading is inside the variant's own valid
    regime, as the variant flags it per frame (``avdm``: TF ≤ fps/4 and ≤ 1 px per frame;
    ``avdm-natural``: texture at some scale and ≤ 1 sample per frame at the coarsest); False
    during the warm-up, null for a model without the flag;
  * ``flow_dps``: mean horizontal dense optic-flow speed (OpenCV DIS), mean |u_x| in
    px/frame × deg/px ÷ the true time between new frames, deg/s. Horizontal because the
    AVDM's correlators are horizontal, and because the vertical flow of vertically uniform
    patterns (gratings, walls) is unconstrained (the aperture problem);
  * ``zlib_ratio``: zlib-compressed / raw size of the luma plane (level 6; higher = more
    complex). Not native: zlib costs 190 ms per 1080p frame at level 6 (26 ms at level 1),
    several frame intervals (docs/guides/analysis.md);

* on the **source raster** (``vdc.frame_metrics``: a video's native luma at its bit depth
  and colour range; for the arena and the robot, which have no native frames, the camera's
  own raster, 8-bit full range): ``si_p910``, ``ti_p910``, ``si_legacy``, ``ti_legacy``,
  ``mafd``, ``edge_density``, ``jpeg_bpp``, ``codec_bpp``.

The table's ``raster`` column says which source raster each row's baselines were computed on
(``native`` or ``camera``) with its size (``raster_width_px``, ``raster_height_px``);
:data:`RASTERS` says it per column, and the Parquet metadata carries it. Temporal metrics are
null on a source's first frame. TI, MAFD and flow follow their definitions on every frame (a
repeated frame gives TI = 0); ``flow_dps`` and ``omega_dps`` are computed between new frames
and held over repeats, so both read true motion.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace
from typing import TYPE_CHECKING, Any

import numpy as np
import polars as pl

from analysis.batch import PARTS
from analysis.complexity.meter import (
    METRICS,
    MODEL_METRICS,
    ComplexityMeter,
    MeasureSettings,
    chosen_metrics,
    flags_of,
    fov_free,
    parse_metrics,
)
from analysis.recordings.loading import load_recording
from analysis.stats import spearman
from avdm.true_time import model_rate
from vdc.errors import UserError
from vdc.frame_batches import FrameBatcher, RateLookahead
from vdc.frame_metrics import decide_ranges
from vdc.heartbeat import Count
from vdc.parquet_io import write_parquet
from vdc.pipeline import usable_threads
from vdc.recording import NATIVE_METRICS, ROBOT_DEG_PER_PX, camera_model_context, working_size
from vdc.sources import open_reader
from vdc.stream_counts import end_fields

if TYPE_CHECKING:
    from analysis.recordings.loading import LoadedRecording


# what a clip is, as clips.parquet and the collection's page both show it: its format and
# its frames (each lost frame once: vdc.stream_counts)
CLIP_FORMAT_COLUMNS = (
    "codec",
    "width_px",
    "height_px",
    "fps",
    "duration_s",
    "frames",
    "repeated_frames",
    "dropped_frames",
)


def _frame_table(
    parts: list[pl.DataFrame],
    raster: str,
    size: tuple[int, int],
    recording_id: str,
    metrics: tuple[str, ...] = METRICS,
) -> pl.DataFrame:
    """The per-frame table of one source: recording_id, frame, t_s, repeat, the ``metrics``
    in :data:`METRICS` order, their :data:`VALIDITY_FLAGS` (bool), and the source raster's name and
    size."""
    df = pl.concat(parts, how="diagonal_relaxed")
    flags = flags_of(metrics)
    for m in (*metrics, *flags):
        if m not in df.columns:
            df = df.with_columns(pl.lit(None, pl.Float64).alias(m))
    df = df.with_columns(pl.col(f).cast(pl.Float64).fill_nan(None).cast(pl.Boolean) for f in flags)
    return df.with_columns(
        pl.lit(recording_id).alias("recording_id"),
        pl.lit(raster).alias("raster"),
        pl.lit(size[1], pl.Int64).alias("raster_width_px"),
        pl.lit(size[0], pl.Int64).alias("raster_height_px"),
        pl.col(*metrics).cast(pl.Float64).fill_nan(None),
    ).select(
        "recording_id",
        "frame",
        "t_s",
        "repeat",
        *metrics,
        *flags,
        "raster",
        "raster_width_px",
        "raster_height_px",
    )


@dataclasses.dataclass
class SourceMeasurement:
    """One source measured: its per-frame table and what the clip table says about it."""

    table: pl.DataFrame
    info: dict[str, Any]  # source, kind, codec, width/height, fps, duration, repeats, drops


def _counted(count: Count, progress: Callable[[int], None] | None) -> Callable[[int], None]:
    """One callback for the frames done: the caller's ``progress`` and the command's count."""

    def done(n: int) -> None:
        count.update(n)
        if progress is not None:
            progress(n)

    return done


def measure_recording(
    loaded: LoadedRecording,
    settings: MeasureSettings,
    progress: Callable[[int], None] | None = None,
) -> SourceMeasurement:
    """Every metric per frame of a recording (video, arena, robot): the source-raster
    metrics the capture logged on native frames where it did, else on the camera's frames."""
    ctx = loaded.camera_context()
    cam = loaded.props.get("camera", {})
    path = loaded.rec.path
    if not ctx or "width_px" not in cam:
        raise UserError(f"{str(path)!r} does not record its camera (fps, width, FOV).")
    # the container's rate (the camera's), from which the models' rate is decided again on
    # the whole recording's repeat flags (a video capture decided it on the same flags)
    fps, deg_per_px = float(cam.get("fps", ctx["fps"])), float(ctx["deg_per_px"])
    native = loaded.native
    timing = loaded.frames.select("frame", "t_s", "repeat")
    has_timing = timing["repeat"].null_count() < timing.height
    src = loaded.props.get("video", {})
    rate = None  # the arena's and the robot's camera frames: their own rate
    if has_timing and src.get("kind") != "camera":
        flags = timing["repeat"].fill_null(False).to_numpy()
        rate = model_rate(fps, flags, settings.max_repeats)
    meter = ComplexityMeter(
        fps, deg_per_px, settings, ctx, camera_baselines=native is None, rate=rate
    )
    rows = []
    # the frames counted, of how many, on the command's heartbeat line (vdc.heartbeat)
    count = Count(loaded.frames.height, "measuring", "frame")
    progress = _counted(count, progress)
    for chunk in loaded.rec.iter_frames():
        sel = pl.DataFrame({"frame": chunk.frame.astype(np.int64)}).join(
            timing, on="frame", how="left", maintain_order="left"
        )
        t = sel["t_s"].fill_null(strategy="forward").to_numpy()
        rep = sel["repeat"].fill_null(False).to_numpy() if has_timing else None
        res = meter.update(chunk.images, t, rep)
        flags = rep if rep is not None else np.zeros(len(t), bool)
        rows.append(
            pl.DataFrame({"frame": chunk.frame.astype(np.int64), "t_s": t, "repeat": flags, **res})
        )
        progress(len(chunk.frame))
    count.close()
    df = pl.concat(rows)
    if native is not None:
        df = df.join(native, on="frame", how="left", maintain_order="left")
        size = (int(src.get("src_height_px", 0)), int(src.get("src_width_px", 0)))
        raster = "native"
    else:
        size = (int(cam.get("height_px", 0)), int(cam["width_px"]))
        raster = "camera"
    table = _frame_table([df], raster, size, loaded.recording_id, meter.metrics)
    frames = loaded.frames
    last_t = float(frames["t_s"].max() or 0.0) if frames.height else None
    # a video recording's file as its header said (the ``video`` property); nothing lost
    # after the last frame of a capture stopped before the file's end
    complete = bool(loaded.props.get("run_end", {}).get("complete", False))
    dropped = int(frames["dropped_before"].fill_null(0).sum())
    info = {
        "source": str(path),
        "kind": src.get("kind", loaded.props.get("run", {}).get("source", "recording")),
        "codec": src.get("codec", "none (camera frames)"),
        "width_px": size[1],
        "height_px": size[0],
        "fps": fps,
        "duration_s": float(frames["t_s"].max() or 0.0) if frames.height else 0.0,
        "frames": table.height,
        "repeated_frames": int(frames["repeat"].fill_null(False).sum()),
        **end_fields(src, last_t, fps, table.height, dropped, complete),
        **rate_fields(meter),
        **recorded_ranges(src if native is not None else None),
    }
    return SourceMeasurement(table, info)


def rate_fields(meter: ComplexityMeter | None) -> dict[str, Any]:
    """A clip's ``model_fps`` (None: no model ran), ``model_fps_reason`` (one of
    ``avdm.true_time.RATE_REASONS``) and ``model_fps_note`` (what the command says about it,
    None where the container's rate stands without doubt)."""
    if meter is None or not meter.want_omega:
        return {"model_fps": None, "model_fps_reason": None, "model_fps_note": None}
    r = meter.rate
    return {"model_fps": r.fps, "model_fps_reason": r.reason, "model_fps_note": r.note}


def recorded_ranges(video: dict[str, Any] | None) -> dict[str, str | None]:
    """The colour ranges of a recording's SI/TI (``clips.parquet``'s range columns): camera
    frames (``video`` None) are 8-bit full-range grey, as the recording states them; a video
    recording's native metrics read the ranges its capture recorded (None where an older
    recording did not record one)."""
    if video is None:
        return decide_ranges("full")
    keys = ("color_range_p910", "color_range_p910_source")
    keys += ("color_range_legacy", "color_range_legacy_source")
    out = {k: video.get(k) for k in keys}
    if out["color_range_legacy"] is None:  # a recording that states only FFmpeg's range
        out["color_range_legacy"] = video.get("color_range")
    return out


def measure_video(
    source: str,
    settings: MeasureSettings,
    recording_id: str,
    progress: Callable[[int], None] | None = None,
) -> SourceMeasurement:
    """Every metric per frame of a video file, image sequence (``settings.fps``) or camera,
    decoded once: the source-raster metrics on its native frames, the model-raster ones on
    the working raster ``vdc-capture video`` uses (the same frames, times and repeat flags:
    its recording then gives the same table)."""

    metrics = chosen_metrics(settings)
    if settings.fov_deg is None:  # the pixel metrics only (complexity notes it, once)
        metrics = fov_free(metrics, settings.width)
        if not metrics:
            raise UserError(
                f"{source!r} is a video: give --fov-deg (the camera's horizontal field of view) "
                "for the AVDM and the flow in deg/s, or ask for pixel metrics (--metrics)."
            )
    model_metrics = tuple(m for m in MODEL_METRICS if m in metrics)
    threads = usable_threads()
    # FFmpeg's own threads, as every other entry point reads the file, also while the frames
    # are measured on the other cores (vdc.frame_batches): on a damaged stream the decoder's
    # thread count changes which frames come out (a cut last GOP gave 12 frames lost after
    # the last against 10 with one thread), and the commands must count alike
    # (tests/analysis/complexity/test_lost_frames.py)
    decoder_threads = None
    reader = open_reader(source, settings.fps, decoder_threads)
    batches = None
    # the frames counted, of those the container states, on the command's heartbeat line
    # (vdc.heartbeat): an estimate of what is left however long the clip
    count = Count(reader.info.get("container_frames"), "measuring", "frame")
    progress = _counted(count, progress)
    try:
        info = reader.info
        fps = settings.fps or info["nominal_fps"]
        if not (math.isfinite(fps) and fps > 0):
            raise UserError(f"{source!r} states no frame rate: pass --fps.")
        size = ctx = meter = None
        if model_metrics:
            fov = settings.fov_deg or float(settings.width or 0) * ROBOT_DEG_PER_PX
            size = working_size(info["src_height_px"], info["src_width_px"], fov, settings.width)
            ctx = camera_model_context(size[1], size[0], fps, fov)
        native = tuple(m for m in NATIVE_METRICS if m in metrics)
        batches = FrameBatcher(
            reader,
            size,
            fps,
            batch_frames=128,
            repeat_tol=settings.repeat_tol,
            max_repeats=settings.max_repeats,
            metrics=native,
            threads=threads,
            jpeg_quality=settings.jpeg_quality,
            color_range=settings.color_range,
            # a file or image sequence can be read again (a camera cannot): no second SI/TI
            # pass for the range decision (vdc.frame_batches)
            reopen=None
            if info["kind"] == "camera"
            else lambda: open_reader(source, settings.fps, decoder_threads),
        )
        stream: FrameBatcher | RateLookahead = batches
        if ctx is not None:
            rate = None
            if "omega_dps" in metrics:  # the models' rate, on the stream's evidence
                stream = RateLookahead(
                    batches, settings.max_repeats, info["kind"] == "camera", progress=progress
                )
                rate = stream.rate
            meter = ComplexityMeter(
                fps, float(ctx["deg_per_px"]), settings, ctx, metrics=metrics, rate=rate
            )
        parts = []
        while (fb := stream.next_batch()) is not None:
            res = meter.update(fb.images, fb.t_s, fb.repeat) if meter is not None else {}
            res = {m: v for m, v in res.items() if m in (*metrics, *flags_of(metrics))}
            values = {n: fb.native_metrics[:, k] for k, n in enumerate(NATIVE_METRICS)}
            values = {n: v for n, v in values.items() if n in metrics}
            parts.append(
                pl.DataFrame(
                    {"frame": fb.frame, "t_s": fb.t_s, "repeat": fb.repeat, **res, **values}
                )
            )
            if stream is batches:  # else the lookahead counts
                progress(len(fb.frame))
        if isinstance(stream, RateLookahead) and meter is not None:
            meter.rate = stream.final_rate()  # the same rate; a note where it broke later
        src_size = (int(info["src_height_px"]), int(info["src_width_px"]))
        table = with_p910_corrections(
            _frame_table(parts, "native", src_size, recording_id, metrics),
            batches.p910_late_corrections(),
        )
        meta = {
            "source": source,
            "kind": info["kind"],
            "codec": info["codec"],
            "width_px": src_size[1],
            "height_px": src_size[0],
            "fps": float(fps),
            "duration_s": float(batches.last_t_s or 0.0),
            "frames": table.height,
            "repeated_frames": batches.repeats_total,
            # each lost frame once (vdc.stream_counts.end_fields): before the first frame, a gap
            # in the times (a bad packet's or a late frame's cost) or after the last
            **batches.end_fields(),
            "source_problems": reader.problems,
            **rate_fields(meter),
            "bit_depth": info["bit_depth"],
            "color_range_tag": info.get("color_range_tag"),
            **batches.color_ranges(),
            "decode_error": reader.error,
        }
        return SourceMeasurement(table, meta)
    finally:
        count.close()
        if batches is not None:
            batches.close()
        reader.close()


def with_p910_corrections(table: pl.DataFrame, fix: np.ndarray) -> pl.DataFrame:
    """``table`` with ``si_p910``, ``ti_p910`` of its first len(``fix``) frames replaced by
    ``fix`` (K, 2) (``vdc.frame_batches.FrameBatcher.p910_late_corrections``)."""
    if not len(fix) or not {"si_p910", "ti_p910"} & set(table.columns):
        return table
    k = len(fix)
    first = pl.int_range(pl.len()) < k
    pad = np.full(table.height - k, np.nan)
    return table.with_columns(
        pl.when(first)
        .then(pl.Series(np.concatenate([fix[:, j], pad])).fill_nan(None))
        .otherwise(pl.col(name))
        .alias(name)
        for j, name in enumerate(("si_p910", "ti_p910"))
        if name in table.columns  # --metrics may ask for one of the two
    )


def largest_first(tasks: list[dict[str, str]]) -> list[dict[str, str]]:
    """The tasks with the largest source file first (ties and sources that are not files,
    image sequences and cameras, after them in their order): the pool hands tasks out in
    this order, so the longest clips start first and the short ones fill in beside them,
    instead of one long clip started last keeping a single worker busy alone at the end."""

    def size(t: dict[str, str]) -> int:
        try:
            return Path(t["source"]).stat().st_size
        except OSError:
            return 0

    return sorted(tasks, key=size, reverse=True)  # stable: equal sizes keep their order


# the settings that say where and which sources run, not what their numbers are
RUN_FIELDS = ("executor", "jobs", "scheduler", "shard", "force", "rrd")


def part_path(out: str | Path, key: str) -> Path:
    """Where a source's table lies in a collection's output folder."""
    return Path(out) / PARTS / f"{key}.parquet"


def measured_settings(fields: dict[str, Any]) -> dict[str, Any]:
    """The settings a source's numbers depend on (``ComplexitySettings``' fields as a dict,
    without :data:`RUN_FIELDS`; ``metrics`` as column names)."""
    out = {k: v for k, v in fields.items() if k not in RUN_FIELDS}
    return out | {"metrics": ",".join(parse_metrics(fields.get("metrics", "all")))}


def measure_source(
    source: str,
    recording_id: str,
    settings: MeasureSettings,
    progress: Callable[[int], None] | None = None,
) -> SourceMeasurement:
    """One source measured: a recording (``.rrd``, its own id) or a video
    (``recording_id``)."""
    if source.endswith(".rrd"):
        return measure_recording(load_recording(source), settings, progress)
    return measure_video(source, settings, recording_id, progress)


def complexity_task(
    source: str,
    recording_id: str,
    key: str,
    settings: dict[str, Any],
    out: str,
    progress: Callable[[int], None] | None = None,
) -> dict[str, int]:
    """One source as an executor task of ``vdc-analyse complexity``: measure it and write its
    part (the "done" mark) atomically. Module-level, small arguments (``settings``: the
    ``ComplexitySettings`` fields, checked by the caller), a small result. It lives here, not
    in ``analysis.complexity.command``, so that a pool worker imports only what measuring needs: not
    the figures, Rerun or the command line (1.25 against about 0.5 s of CPU per worker, paid
    on the wall clock whatever the number of workers)."""

    s = SimpleNamespace(**settings)
    m = measure_source(source, recording_id, s, progress)
    meta = {"info": m.info, "settings": measured_settings(settings), "source": source, "key": key}
    write_parquet(m.table, part_path(out, key), meta)
    return {"frames": m.table.height}


def rank_correlations(df: pl.DataFrame, recording_id: str) -> pl.DataFrame:
    """Spearman ρ of every pair of metrics (of those in ``df``) over the frames where both
    are defined."""

    rows = []
    present = [m for m in METRICS if m in df.columns]
    for i, a in enumerate(present):
        for b in present[i + 1 :]:
            d = df.select(a, b).drop_nulls()
            rho = spearman(d[a].to_numpy(), d[b].to_numpy()) if d.height > 2 else math.nan
            rows.append(
                {"recording_id": recording_id, "metric_a": a, "metric_b": b, "spearman": rho}
            )
    return pl.DataFrame(
        rows,
        schema={
            "recording_id": pl.String,
            "metric_a": pl.String,
            "metric_b": pl.String,
            "spearman": pl.Float64,
        },
    )


def metrics_present(df: pl.DataFrame, suffix: str = "") -> list[str]:
    """The metrics (:data:`METRICS` order) a table has columns for (``m + suffix``)."""
    return [m for m in METRICS if m + suffix in df.columns]
