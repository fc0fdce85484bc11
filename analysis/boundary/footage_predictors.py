"""Footage mode's predictors (:mod:`analysis.predictors.statistics`): every measure per frame of
every clip, beside the detector's alert at every parameter value. Footage mode
(:mod:`analysis.boundary.footage`) computes them, so they live with it: the predictors package
holds the statistics and the report, and imports nothing of the boundary.

The measures are those ``vdc-analyse complexity`` wrote for the clips
(``OUT/complexity/complexity.parquet``: ``omega_dps`` is ``avdm-natural``) and the paper's
``avdm``, run here on the same working raster and frames, with the detector at each value (one
pass over each clip, an executor task per clip).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from analysis.boundary.settings import number_list, with_override
from analysis.boundary.statistics import WARMUP_FRAMES
from analysis.complexity.command import ComplexitySettings
from analysis.complexity.meter import METRICS
from analysis.predictors.report import write_predictors
from analysis.predictors.statistics import MEASURES, footage_predictors
from analysis.predictors.verdicts import table_note
from avdm.registry import make_model
from avdm.true_time import TrueTimeModel
from vdc.errors import UserError
from vdc.executors import run_tasks_or_raise
from vdc.frame_batches import FrameBatcher, working_camera
from vdc.sources import open_reader


def _resolved(source: str) -> str:
    """A clip's key: its resolved path (as footage mode keys its clips)."""
    return str(Path(source).resolve())


def clip_frames_task(source: str, specs: dict[str, str], fov_deg: float) -> dict[str, Any]:
    """An executor task: one clip read as ``vdc-capture video`` reads it, the paper's AVDM and
    the detector at every value (``specs``: value's key → model spec) run on it. Returns the
    source frame numbers, ``avdm`` (deg/s) and each value's ``alert``, as lists."""

    reader = open_reader(source)
    try:
        shape, fps, ctx = working_camera(reader.info, source, fov_deg, None)
        paper = TrueTimeModel(make_model("avdm", **ctx))
        detectors = {k: make_model(spec, **ctx) for k, spec in specs.items()}
        video = ComplexitySettings
        batches = FrameBatcher(
            reader, shape, fps, repeat_tol=video.repeat_tol, max_repeats=video.max_repeats
        )
        out: dict[str, list] = {"frame": [], "avdm": []} | {k: [] for k in specs}
        while (fb := batches.next_batch()) is not None:
            out["frame"] += fb.frame.tolist()
            out["avdm"] += paper.run(fb.images, fb.t_s, fb.repeat)["omega_dps"].tolist()
            for k, model in detectors.items():
                out[k] += model.run(fb.images)["alert"].tolist()
    finally:
        reader.close()
    return out | {"fps": fps}


def frame_classes(
    frames: np.ndarray,
    alert: np.ndarray,
    collision_frame: int | None,
    window_frames: int,
    warmup_frames: int = 0,
    hazard_onset_frame: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Per frame: (positive, keep). Positive: the detector alerts with no collision in the
    window; negative: it stays quiet; frames from the hazard's onset on (the first frame the
    object is drawn, where the labels give it: a near miss's too), inside the window and after
    the collision are not kept (the object, not the scene, drives the detector there), nor the
    first ``warmup_frames`` (the measures' and the detector's start-up: the AVDM rises from 0 over
    its first frames while a detector that needs a run of frames cannot alert yet, so a busy
    clip's only quiet frames would be those, and every AVDM would "predict" them exactly)."""
    frames = np.asarray(frames)
    keep = frames >= warmup_frames
    if collision_frame is not None:
        keep &= frames < collision_frame - window_frames
    if hazard_onset_frame is not None:
        keep &= frames < hazard_onset_frame
    return (np.asarray(alert) > 0) & keep, keep


def scene_end(row: dict[str, Any], fps: float, window_s: float) -> int | None:
    """The first frame not of the scene the detector faced: the hazard's onset where the
    labels give it (``hazard_onset_frame``), else the alert window's start before a collision;
    None (every frame) for a clip without either."""
    onset = row.get("hazard_onset_frame")
    if onset is not None:
        return int(onset)
    if row["collision_frame"] is not None:
        return int(row["collision_frame"] - round(window_s * fps))
    return None


def scene_column(labels: pl.DataFrame, where: str) -> pl.DataFrame:
    """``labels`` with its optional ``scene`` column (the photograph, place or session clips
    share: the predictors' unit) as text; UserError, in one line naming ``where``, when some
    clips name one and others do not (which clips share what would be unknown)."""
    if "scene" not in labels.columns:
        return labels
    scene = labels["scene"].cast(pl.Utf8).str.strip_chars()
    empty = labels.filter(scene.is_null() | (scene == ""))
    if empty.height:
        raise UserError(
            f"{where}: clip {empty['clip'][0]!r} has no scene: name every clip's scene (the "
            "photograph, place or session it shares) or none."
        )
    return labels.with_columns(scene.alias("scene"))


def footage_predictor_tables(
    s: Any,
    labels: pl.DataFrame,
    clips: pl.DataFrame,
    complexity_dir: Path,
    stage: Path,
    log: Callable[[str], None] | None = None,
) -> tuple[pl.DataFrame, list[Path], str]:
    """The predictor tables of a labelled collection, written into ``stage``: (table, paths,
    report section). ``clips`` is ``boundary_clips.parquet`` (one row per clip and value with
    ``correct`` and each measure's mean); ``complexity_dir`` where ``complexity`` wrote its
    per-frame table. ``log`` is told, in one line, where the clips are taken as independent."""

    values = number_list(s.values, "values", minimum=-math.inf)
    specs = {f"{v:g}": with_override(s.detector, s.param, v) for v in values}
    tasks = [(r["source"], (r["source"], specs, s.fov_deg)) for r in labels.iter_rows(named=True)]
    got = run_tasks_or_raise(clip_frames_task, tasks, s.executor_settings(), "clip")
    per_frame = pl.read_parquet(complexity_dir / "complexity.parquet")
    ids = pl.read_parquet(complexity_dir / "clips.parquet").select("source", "recording_id")
    rid = {_resolved(r["source"]): r["recording_id"] for r in ids.iter_rows(named=True)}
    keep_cols = [m for m in METRICS if m != "omega_dps"]
    frames, paper_means = [], {}
    window = s.alert_window_s
    for row in labels.iter_rows(named=True):
        res = got[row["source"]]
        mine = pl.DataFrame({"frame": np.asarray(res["frame"], np.int64), "avdm": res["avdm"]})
        theirs = per_frame.filter(pl.col("recording_id") == rid[_resolved(row["source"])]).select(
            "frame", pl.col("omega_dps").alias("avdm_natural"), *keep_cols
        )
        table = mine.join(theirs, on="frame", how="left", maintain_order="left")
        cf = row["collision_frame"]
        wf = round(window * res["fps"])
        end = scene_end(row, res["fps"], window)
        scene = table.filter(pl.col("frame") < end) if end is not None else table
        if (scene["frame"] >= WARMUP_FRAMES).any():  # the start-up is not the scene
            scene = scene.filter(pl.col("frame") >= WARMUP_FRAMES)
        mean = scene["avdm"].fill_nan(None).mean()  # 0.0 on a still scene is a number, not NaN
        paper_means[row["clip"]] = float(mean) if mean is not None else math.nan
        for v in values:
            alert = np.asarray(res[f"{v:g}"], float)
            positive, keep = frame_classes(
                table["frame"].to_numpy(),
                alert,
                cf,
                wf,
                WARMUP_FRAMES,
                hazard_onset_frame=row.get("hazard_onset_frame"),
            )
            frames.append(
                table.with_columns(
                    pl.lit(row["clip"]).alias("clip"),
                    pl.lit(v).alias(s.param),
                    pl.Series("alert", alert),
                    pl.Series("positive", positive),
                    pl.Series("keep", keep),
                )
            )
    frames_df = pl.concat(frames, how="diagonal_relaxed")
    measures = [m for m in MEASURES if m in frames_df.columns]
    frames_df = frames_df.select("clip", s.param, "frame", "alert", "positive", "keep", *measures)
    clip_table = clips.rename({"omega_dps": "avdm_natural"}).with_columns(
        pl.col("clip").replace_strict(paper_means, return_dtype=pl.Float64).alias("avdm")
    )
    table = footage_predictors(clip_table, frames_df, s.param)
    note = table_note(table)
    if note and log is not None:
        log(note)
    meta = {"settings": dataclasses.asdict(s)}
    paths, section = write_predictors(
        table,
        frames_df,
        stage,
        meta,
        s.param,
        "footage",
        f"{s.detector}: which measure predicts failure ({labels.height} clips)",
    )
    return table, paths, section
