"""``vdc-analyse complexity``: the AVDM beside the standard complexity measures, per frame
and per clip, for one source or a whole collection.

A source is a recording (``.rrd``), a video file, an image-sequence pattern
(``frames/%05d.png``) or a folder of them. Each source is decoded once, as one executor task
(a process pool or Dask, as ``batch``), which writes its own atomic part
``OUT/parts/<clip>-<hash>.parquet``: a re-run skips finished sources, and a source that fails
(a corrupt file) is listed in ``failures.parquet`` without stopping the others. Then:

* ``complexity.parquet``: one row per frame (columns: ``analysis.complexity.source_metrics``; only
the
  metrics ``--metrics`` asks for, and without ``--fov-deg`` a video's angular ones left out);
* ``clips.parquet``: one row per clip: source, codec, resolution, fps, duration, repeated
  and dropped frames (each lost frame once: ``frames + dropped_frames == container_frames``
  where the source states its count; ``lost_after_last`` of them after the last frame,
  ``missing_s`` those in seconds; ``vdc.stream_counts.end_fields``), and each metric's mean, max
  and p95 (P.910 clause 7.8.4 recommends the mean and the max per sequence), and
  ``omega_valid_share``, the share of frames the AVDM's reading is valid on;
* ``complexity_correlations.parquet``: Spearman ρ of every pair of metrics per clip;
* ``complexity_collection.png``: clips ranked by the AVDM and by TI, and the AVDM against TI
  and SI; ``complexity.html``: that figure with the clip table;
* per clip (``--rrd``; always for a single source): a figure of its metrics over time and an
  ``.rrd`` with the source's recording id, which opens beside it in the viewer.
"""

from __future__ import annotations

import dataclasses
import math
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from analysis.batch import parse_shard, readable_part
from analysis.complexity import figures
from analysis.complexity.complexity_rrd import write_complexity_rrd
from analysis.complexity.meter import (
    MODEL_METRICS,
    RASTERS,
    ComplexityMeter,
    flags_of,
)
from analysis.complexity.plan import expand_sources, plan_sources, without_fov
from analysis.complexity.settings import ComplexitySettings
from analysis.complexity.source_metrics import (
    CLIP_FORMAT_COLUMNS,
    complexity_task,
    largest_first,
    metrics_present,
    part_path,
    rank_correlations,
)
from avdm.true_time import model_rate, repeats_of
from vdc.errors import UserError
from vdc.executors import TaskOutcome, run_tasks
from vdc.folders import remove_output
from vdc.frame_metrics import (
    RANGE_COLUMNS,
    NativeMeter,
    decide_ranges,
    leaves_limited,
)
from vdc.parquet_io import WroteFiles, read_metadata, table_set, write_parquet
from vdc.recording import NATIVE_METRICS, camera_model_context, working_size
from vdc.resize import area_resize


def complexity_of_frames(
    frames: np.ndarray,
    fps: float,
    fov_deg: float,
    t_s: np.ndarray | None = None,
    settings: ComplexitySettings | None = None,
    width: int | None = None,
    native: np.ndarray | None = None,
    color_range: str | None = "full",
) -> pl.DataFrame:
    """Every metric per frame of ``frames`` (T, H, W) uint8 grey at the source's resolution,
    filmed at ``fps`` Hz (or at the times ``t_s``, seconds) by a camera whose horizontal field
    of view is ``fov_deg``.

    The source-raster metrics are computed on ``native`` (T, H, W) uint8 luma code values in
    ``color_range``, the range their stream tags (default: ``frames`` themselves, full range;
    None: unspecified, decided as ``vdc.frame_metrics.decide_ranges`` says, with
    ``settings.color_range``). The model-raster metrics
    are computed after area-resizing ``frames`` to the working raster ``vdc-capture video``
    uses (``width`` px, default the robot camera's angular pitch), with repeats judged on the
    native frames, as ``vdc-analyse complexity`` does on a video file: given a file's decoded
    grey frames and Y planes, this function gives that command's table.

    Returns a DataFrame: frame, t_s, repeat, then one column per metric of
    ``settings.metrics`` (see the module), then ``omega_valid`` (bool) with ``omega_dps``."""

    settings = settings or ComplexitySettings()
    frames = np.asarray(frames)
    if frames.ndim != 3 or frames.dtype != np.uint8 or len(frames) == 0:
        raise UserError(f"frames must be a non-empty (T, H, W) uint8 array, got {frames.shape}.")
    native = frames if native is None else np.asarray(native)
    if native.shape[0] != frames.shape[0]:
        raise UserError("native must hold one image per frame.")
    metrics = settings.metric_names()
    h, w = working_size(frames.shape[1], frames.shape[2], fov_deg, width)
    t = np.arange(len(frames)) / fps if t_s is None else np.asarray(t_s, np.float64)
    t = np.rint(t * 1e9) / 1e9  # whole nanoseconds, as a recording stores times
    ctx = camera_model_context(w, h, fps, fov_deg)
    native_names = (*(m for m in NATIVE_METRICS if m in metrics), "mafd")
    leaves = any(leaves_limited(f, 8) for f in native) if color_range is None else None
    ranges = decide_ranges(color_range, settings.color_range, leaves)
    nm = NativeMeter(
        8,
        str(ranges["color_range_legacy"]),
        settings.jpeg_quality,
        native_names,
        p910_range=str(ranges["color_range_p910"]),
    )
    rows = np.stack([nm.row(f) for f in native])
    mafd = rows[:, NATIVE_METRICS.index("mafd")]
    repeat = repeats_of(mafd, 0, settings.repeat_tol, settings.max_repeats)
    out = {name: rows[:, k] for k, name in enumerate(NATIVE_METRICS)}
    if any(m in metrics for m in MODEL_METRICS):
        small = np.stack([area_resize(f, (h, w)) for f in frames])  # as FrameBatcher
        rate = model_rate(fps, repeat, settings.max_repeats)  # on all the frames' evidence
        meter = ComplexityMeter(
            fps, float(ctx["deg_per_px"]), settings, ctx, metrics=metrics, rate=rate
        )
        out |= meter.update(small, t, repeat)
    df = pl.DataFrame({"frame": np.arange(len(frames), dtype=np.int64), "t_s": t, "repeat": repeat})
    df = df.with_columns(*[pl.Series(m, out[m]).fill_nan(None) for m in metrics])
    flags = [pl.Series(f, out[f]).fill_nan(None).cast(pl.Boolean) for f in flags_of(metrics)]
    return df.with_columns(*flags)


def clip_row(table: pl.DataFrame, info: dict[str, Any]) -> dict[str, Any]:
    """A clip's row of ``clips.parquet``: what the source is, then each metric's mean, max and
    95th percentile over its frames (where defined), and ``omega_valid_share``: the share of
    frames whose AVDM reading is inside its variant's valid regime."""
    row = {
        "recording_id": table["recording_id"][0],
        **{
            k: info.get(k)
            for k in (
                "source",
                "kind",
                *CLIP_FORMAT_COLUMNS,
                "container_frames",
                "lost_after_last",
                "header_duration_s",
                "missing_s",
                "model_fps",
                "model_fps_reason",
                *RANGE_COLUMNS,
            )
        },
        "raster": table["raster"][0],
    }
    for m in metrics_present(table):
        v = table[m].drop_nulls().cast(pl.Float64)
        row[f"{m}_mean"] = float(v.mean()) if v.len() else None
        row[f"{m}_max"] = float(v.max()) if v.len() else None
        row[f"{m}_p95"] = float(v.quantile(0.95, "linear")) if v.len() else None
    for flag in (f for f in flags_of(tuple(metrics_present(table))) if f in table.columns):
        v = table[flag].drop_nulls()  # the share of frames whose reading its model vouches for
        row[f"{flag}_share"] = float(v.cast(pl.Float64).mean()) if v.len() else None
    return row


@dataclasses.dataclass
class ComplexityResult(WroteFiles):
    table: pl.DataFrame  # recording_id, frame, t_s, repeat, metrics..., raster
    clips: pl.DataFrame  # one row per clip (see clip_row)
    correlations: pl.DataFrame  # Spearman rank correlation of every pair, per clip
    failures: list[tuple[str, str]]  # (source, error)
    paths: list[Path]
    notices: list[str]
    planned: int = 0
    skipped: int = 0  # finished by an earlier run

    def report(self) -> list[str]:
        """What the command line prints: the files, the ten clips of highest AVDM response."""
        files = self.files
        lines = [
            f"{self.clips.height} clip(s), {self.table.height} frames -> "
            f"{files.complexity_parquet}, {files.clips}, {files.complexity_html}"
        ]
        rank = figures.ranking(self.clips)
        top = self.clips.sort(f"{rank[0]}_mean", descending=True, nulls_last=True)
        shown = [m for m in ("omega_dps", "si_p910", "ti_p910") if m in rank] or rank[:3]
        unit = {"omega_dps": " deg/s", "flow_dps": " deg/s"}

        def value(r: dict, m: str) -> str:
            v = r[f"{m}_mean"]
            return f"{m} {math.nan if v is None else v:.4g}{unit.get(m, '')}"

        lines += [
            f"  {r['recording_id']}: {r['frames']} frames, mean "
            + ", ".join(value(r, m) for m in shown)
            + f" ({r['raster']} raster)"
            for r in top.head(10).iter_rows(named=True)
        ]
        if top.height > 10:
            lines.append(
                f"  ... and {top.height - 10} more (highest {rank[0]} first): "
                f"{files.complexity_html}"
            )
        return lines


def _run_inline(
    tasks: list[dict[str, str]],
    settings: ComplexitySettings,
    out: Path,
    progress: Callable[[int], None] | None,
    single: bool,
) -> list[TaskOutcome]:
    """One source on the local executor: measured here, with a progress bar over frames. The
    only source of a command (``single``) that fails is bad input (one line, exit 2); one
    source of a collection is listed as failed."""
    outcomes = []
    for t in tasks:
        try:
            args = (t["recording_id"], t["key"], dataclasses.asdict(settings), str(out))
            done = complexity_task(t["source"], *args, progress=progress)
            outcomes.append(TaskOutcome(t["source"], done, None))
        except (ValueError, OSError) as exc:
            if single:
                raise
            outcomes.append(TaskOutcome(t["source"], None, f"{type(exc).__name__}: {exc}"))
    return outcomes


def complexity(
    sources: str | Path | Sequence[str | Path],
    settings: ComplexitySettings = ComplexitySettings(),
    out: str | Path | None = "results/complexity",
    *,
    progress: Callable[[int], None] | None = None,
    clip_progress: Callable[[int], None] | None = None,
    notice: Callable[[str], None] | None = None,
    log: Callable[[str], None] | None = None,
) -> ComplexityResult:
    """``vdc-analyse complexity`` on recordings, video files, image sequences and folders
    (see the module). ``progress`` counts frames (a single source), ``clip_progress`` sources
    as they finish. A bad single source raises ValueError; in a collection, failed sources
    are listed in ``result.failures`` and ``failures.parquet``. ``out=None`` writes nothing
    (the work is done in a folder removed before this returns) and returns the tables."""

    if out is None:
        with tempfile.TemporaryDirectory(prefix="vdc-complexity-") as tmp:
            res = complexity(
                sources,
                settings,
                tmp,
                progress=progress,
                clip_progress=clip_progress,
                notice=notice,
                log=log,
            )
        res.paths = []  # nothing written remains
        return res
    out = Path(out)
    notes: list[str] = []

    def say(message: str) -> None:
        notes.append(message)
        if notice is not None:
            notice(message)

    listed = expand_sources(sources, say)
    without = without_fov(listed, settings)  # before any decoding
    if without:
        say(without)
    tasks = plan_sources(listed, settings, say)
    shard = parse_shard(settings.shard)
    mine = tasks if shard is None else tasks[shard[0] :: shard[1]]
    todo = [t for t in mine if settings.force or not readable_part(part_path(out, t["key"]))]
    if len(mine) > len(todo):
        say(f"{len(mine) - len(todo)} of {len(mine)} source(s) already measured in {out}.")
    if settings.executor == "local" and len(todo) == 1:
        outcomes = _run_inline(todo, settings, out, progress, single=len(tasks) == 1)
        if clip_progress is not None:
            clip_progress(1)
    else:
        by_source = {t["source"]: t for t in todo}

        def done(o: TaskOutcome) -> None:
            if clip_progress is not None:
                clip_progress(1)

        args = [
            (
                t["source"],
                (t["source"], t["recording_id"], t["key"], dataclasses.asdict(settings), str(out)),
            )
            for t in largest_first(list(by_source.values()))
        ]
        # before the Dask workers are asked whether they see it (a new folder did not exist)
        out.mkdir(parents=True, exist_ok=True)
        outcomes = run_tasks(
            complexity_task,
            args,
            settings.executor_settings(),
            on_done=done,
            log=log,
            shared_paths=[listed[0], out],
        )
    failures = [(o.key, o.error or "") for o in outcomes if o.error]
    parts, infos = [], []
    for t in tasks:
        path = part_path(out, t["key"])
        if readable_part(path):
            parts.append(pl.read_parquet(path))
            infos.append(read_metadata(path)["info"])
    if not parts:
        raise UserError(
            "no source could be measured: "
            + "; ".join(f"{src}: {err}" for src, err in failures[:3])
        )
    pending = len(tasks) - len(parts) - len(failures)
    if pending > 0:
        say(f"{pending} source(s) of other shards are not measured yet.")
    table = pl.concat(parts, how="diagonal_relaxed")
    for info in infos:  # a file cut short (or that stops decoding) is not a whole clip
        if info.get("cut_note") or info.get("decode_error"):
            why = info.get("cut_note") or f"decoding stopped ({info['decode_error']})"
            say(f"{info['source']}: {why}; its row covers {info['frames']} frames.")
    for info in infos:  # the models' rate, where it is not the container's or is in doubt
        if info.get("model_fps_note"):
            say(f"{info['source']}: {info['model_fps_note']}")
    uncounted = [  # files whose end cannot be counted (parts of older runs do not say)
        i["source"]
        for i in infos
        if i.get("kind") == "file" and "container_frames" in i and i["container_frames"] is None
    ]
    if uncounted:
        say(
            f"{len(uncounted)} file(s) whose container states no frame count (nor a duration "
            f"at a constant rate), first {uncounted[0]}: frames lost after their last frame are "
            "unknown, not counted (container_frames and lost_after_last null)."
        )
    rows = [clip_row(p, i) for p, i in zip(parts, infos, strict=True)]
    clips = pl.DataFrame(rows, infer_schema_length=None)  # sources may differ in metrics
    clips = clips.with_columns(
        pl.col("header_duration_s", "missing_s").cast(pl.Float64),
        pl.col("container_frames", "lost_after_last").cast(pl.Int64),
    )
    corr = pl.concat([rank_correlations(p, p["recording_id"][0]) for p in parts])
    paths: list[Path] = []
    meta = {
        "settings": settings.measured(),
        "recordings": sorted(table["recording_id"].unique().to_list()),
        "metrics": metrics_present(table),
        "rasters": {m: RASTERS[m] for m in metrics_present(table)},
        "raster_note": "model: the AVDM's working raster (70/99 deg per px); source: the "
        "native frames where the source has them, else the camera's raster (column raster)",
    }
    per_clip = settings.rrd or len(tasks) == 1
    if log is not None:  # seconds of figures and pages: said, so the heartbeat names them
        log(f"writing the tables, figures and page of {len(parts)} clip(s) into {out}.")
    with table_set(out) as stage:  # published whole: never a mix of two runs
        paths.append(write_parquet(table, stage / "complexity.parquet", meta))
        paths.append(write_parquet(clips, stage / "clips.parquet", meta))
        paths.append(write_parquet(corr, stage / "complexity_correlations.parquet", meta))
        fails = pl.DataFrame(failures, schema=["source", "error"], orient="row")
        if failures:
            paths.append(write_parquet(fails, stage / "failures.parquet", meta))
        paths.append(figures.plot_collection(clips, stage / "complexity_collection.png"))
        shown = paths[-1]  # the page's figure: the collection's, or one clip's over time
        if per_clip:
            for p in parts:
                rid = p["recording_id"][0]
                c = corr.filter(pl.col("recording_id") == rid)
                paths.append(figures.plot_complexity(p, c, stage / f"complexity_{rid}.png"))
                shown = paths[-1] if len(parts) == 1 else shown
                paths.append(write_complexity_rrd(p, rid, stage / f"complexity_{rid}.rrd"))
        paths.append(figures.write_summary_html(clips, failures, stage / "complexity.html", shown))
    if not failures:  # an earlier run's failures are measured now (only vdc's own file)
        remove_output(out, "failures.parquet")
    paths = [out / p.name for p in paths]
    return ComplexityResult(
        table, clips, corr, failures, paths, notes, len(mine), len(mine) - len(todo)
    )
