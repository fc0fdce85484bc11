"""Footage mode of ``vdc-analyse boundary``: a detector on a labelled collection of clips.

The labels table (CSV or Parquet) has one row per clip:

* ``clip``: the video file (or image-sequence pattern), relative to the table's folder;
* ``label``: free text (what the clip shows, e.g. ``looming`` or ``background``);
* ``collision_frame``: the source frame (0-based) at which the object reaches the camera, or
  empty when nothing collides;
* ``hazard_onset_frame`` (optional): the frame at which the hazard enters the scene; the
  clip's complexity is measured on the frames before it, and an alert before it is early;
* ``scene`` (optional): the photograph, place or session clips share, the predictors' unit
  (:mod:`analysis.predictors.statistics`); without it clips are taken as independent.

Each clip is read as ``vdc-capture video`` reads it (the working raster, its true frame rate)
and the detector runs on it; the clip's complexity is measured as ``vdc-analyse complexity``
measures it (the AVDM and the baselines). Per clip:

* a collision clip is a **hit** when the detector's first alert comes at least ``min_ttc_s``
  before the collision frame and not before the hazard's onset (without an onset: at most
  ``alert_window_s`` before the collision); an earlier first alert is an **early alert** (a
  false alarm: it would have turned away from nothing), none, or one later than ``min_ttc_s``
  before the collision (too late to turn), a **miss**; ``failure`` names which (scored apart
  by the predictors: their signs oppose);
* a clip without a collision is a false alarm when the detector alerts at all (an early alert
  when it alerts before the onset the labels give);
* **success** = the share of collision clips that are hits (as in the arena, where success is
  avoidances among avoidances and crashes); a clip is **correct** when it is a hit, or has no
  alert where nothing collides;
* the **time to collision of the first alert** = (collision frame − first alert) / fps.

Hit rate, false alarms and success come with exact 95 % intervals across clips, overall and in
groups of clips of similar complexity (``--groups N``; by default up to 5 groups of at least 4
clips). The boundary is the crossing of a monotone logistic curve fitted to the collision clips
themselves, each a hit or a miss at its complexity, with its 95 % interval
(:mod:`analysis.boundary.fit`); the groups' bracket is given beside it.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from analysis.boundary.command import BoundaryResult, published
from analysis.boundary.fit import fit_columns, fit_crossing, with_fit
from analysis.boundary.fit_text import describe_boundary, fit_section
from analysis.boundary.footage_predictors import footage_predictor_tables, scene_end
from analysis.boundary.labels import read_labels
from analysis.boundary.plot import plot_boundary
from analysis.boundary.report_tables import interval, markdown_table
from analysis.boundary.settings import BoundarySettings, number_list, with_override
from analysis.boundary.statistics import WARMUP_FRAMES, boundaries
from analysis.complexity.command import ComplexitySettings, complexity
from analysis.complexity.meter import METRICS
from analysis.stats import mean_ci, share_ci
from avdm.base import alert_frames, require_alert
from avdm.registry import check_detector, make_model
from vdc.errors import UserError
from vdc.executors import Feedback, run_tasks_or_raise
from vdc.frame_batches import FrameBatcher, working_camera
from vdc.parquet_io import table_set, write_tables
from vdc.sources import open_reader

COMPLEXITY = "omega_dps"  # the clips' complexity: the AVDM's mean response (deg/s)


def clip_camera(
    source: str, fov_deg: float, width: int | None = None
) -> tuple[tuple[int, int], dict[str, Any]]:
    """The clip's working raster (H, W) and the camera facts a model is built with for it (as
    ``vdc-capture video``)."""

    reader = open_reader(source)
    try:
        shape, _fps, ctx = working_camera(reader.info, source, fov_deg, width)
        return shape, ctx
    finally:
        reader.close()


def detector_alerts(
    source: str, spec: str, fov_deg: float, width: int | None = None
) -> tuple[np.ndarray, np.ndarray, float]:
    """The detector ``spec`` run on a clip as ``vdc-capture video`` would run it (its repeat
    rules too): the source frames' numbers (T,) int64, its ``alert`` output (T,) float64 and
    the frame rate (Hz)."""

    reader = open_reader(source)
    try:
        shape, fps, ctx = working_camera(reader.info, source, fov_deg, width)
        model = make_model(spec, **ctx)
        require_alert(model)
        video = ComplexitySettings  # the repeat rules vdc-capture video reads sources with
        batches = FrameBatcher(
            reader, shape, fps, repeat_tol=video.repeat_tol, max_repeats=video.max_repeats
        )
        frames, alerts = [], []
        while (fb := batches.next_batch()) is not None:
            frames.append(fb.frame)
            alerts.append(model.run(fb.images)["alert"])
    finally:
        reader.close()
    return np.concatenate(frames), np.concatenate(alerts), fps


def judge_clip(
    frames: np.ndarray,
    alert: np.ndarray,
    fps: float,
    collision_frame: int | None,
    window_s: float,
    min_ttc_s: float = 0.0,
    hazard_onset_frame: int | None = None,
) -> dict[str, Any]:
    """Hit, miss or false alarm of one clip (see the module). A NaN alert counts as no
    alert, and its frames are counted (``alert_nan_frames``): :func:`nan_alert_note`.

    ``failure`` scores the ways to be wrong apart (issue 42; their signs oppose on real
    footage): ``miss`` (no alert, or a first alert less than ``min_ttc_s`` before the
    collision: too late to turn away), ``early`` (the scene alone set it off), ``false_alarm``
    (an alert on a clip without collision); ``hit`` and ``quiet`` (no alert, nothing collides)
    are right. Where the labels give the ``hazard_onset_frame`` (the first frame the object is
    in view), "early" is an alert before it, on any clip, and a collision clip's first alert
    from the onset on is a hit with ``min_ttc_s`` to spare however long before contact: the
    object's own entry, not a fixed window, divides the scene from the hazard (an object that
    enters 3 s before contact may be seen 3 s before). Without it, "early" is a first alert
    more than ``window_s`` before the collision."""
    flags, undefined = alert_frames(alert)
    on = np.flatnonzero(flags)
    first = int(frames[on[0]]) if on.size else None
    row: dict[str, Any] = {
        "alert_nan_frames": undefined,
        "first_alert_frame": first,
        "hit": False,
        "false_alarm": False,
        "ttc_first_alert_s": math.nan,
    }
    early = first is not None and (
        first < hazard_onset_frame
        if hazard_onset_frame is not None
        else collision_frame is not None
        and first <= collision_frame
        and (collision_frame - first) / fps > window_s + 1e-9
    )
    if collision_frame is None:
        row["false_alarm"] = first is not None
    elif first is not None and first <= collision_frame:
        row["ttc_first_alert_s"] = (collision_frame - first) / fps
        if early:
            row["false_alarm"] = True
        elif row["ttc_first_alert_s"] >= min_ttc_s - 1e-9:  # 1e-9: frame / fps rounding
            row["hit"] = True
    row["correct"] = row["hit"] or (collision_frame is None and not row["false_alarm"])
    if early:
        row["failure"] = "early"
    elif collision_frame is None:
        row["failure"] = "false_alarm" if row["false_alarm"] else "quiet"
    else:
        row["failure"] = "hit" if row["hit"] else "miss"
    return row


def nan_alert_note(clips: pl.DataFrame, detector: str) -> str | None:
    """One line when the detector's ``alert`` was NaN on some frames (``clips``: the per-clip
    rows, with ``alert_nan_frames``), else None: those frames were read as no alert."""
    if "alert_nan_frames" not in clips.columns:
        return None
    bad = clips.filter(pl.col("alert_nan_frames") > 0)
    if bad.height == 0:
        return None
    n = int(bad["alert_nan_frames"].sum())
    return (
        f"detector {detector!r}: its 'alert' is NaN on {n} frame(s) of {bad.height} clip run(s) "
        f"(first: {bad['clip'][0]!r}); they count as no alert (column alert_nan_frames)"
    )


def clip_task(
    source: str,
    spec: str,
    collision_frame: int | None,
    fov_deg: float,
    window_s: float,
    min_ttc_s: float = 0.0,
    hazard_onset_frame: int | None = None,
) -> dict[str, Any]:
    """An executor task: one clip judged (its complexity is measured separately, once)."""
    frames, alert, fps = detector_alerts(source, spec, fov_deg)
    return {
        "fps": fps,
        "frames": len(frames),
        **judge_clip(frames, alert, fps, collision_frame, window_s, min_ttc_s, hazard_onset_frame),
    }


def clip_complexity(
    labels: pl.DataFrame, fov_deg: float, window_s: float, executor: dict[str, Any], out: Path
) -> pl.DataFrame:
    """Each clip's complexity: the mean of every metric of ``vdc-analyse complexity`` over the
    frames before the alert window (a collision clip) or over all frames (the scene the
    detector faced, not the object on its way in). Columns: source, then one per metric."""

    s = ComplexitySettings(fov_deg=fov_deg, metrics="all", **executor)
    res = complexity(labels["source"].to_list(), s, out)
    if res.failures:
        src, err = res.failures[0]
        raise UserError(f"clip {src!r} cannot be measured: {err}")
    ids = {
        _key(r["source"]): (r["recording_id"], r["fps"]) for r in res.clips.iter_rows(named=True)
    }
    rows = []
    for row in labels.iter_rows(named=True):
        rid, fps = ids[_key(row["source"])]
        frames = res.table.filter(pl.col("recording_id") == rid)
        end = scene_end(row, fps, window_s)
        if end is not None:
            frames = frames.filter(pl.col("frame") < end)
            if frames.height == 0:
                raise UserError(
                    f"clip {row['clip']!r} has no frame before its alert window ({window_s:g} s "
                    "before the collision frame) to measure the scene on: use a longer clip or a "
                    "shorter --alert-window-s."
                )
        # the models' start-up (the AVDM rises from 0, running means fill) is not the scene:
        # its frames are left out where the clip has frames after it
        startup = WARMUP_FRAMES if (frames["frame"] >= WARMUP_FRAMES).any() else 0
        frames = frames.filter(pl.col("frame") >= startup)
        means = {m: frames[m].cast(pl.Float64).mean() for m in METRICS}
        rows.append(
            {
                "source": row["source"],
                **means,
                "complexity_frames": frames.height,
                "startup_frames_left_out": startup,
            }
        )
    return pl.DataFrame(rows)


def _key(source: str) -> str:
    return str(Path(source).resolve())


def group_statistics(clips: pl.DataFrame, by: str, groups: int) -> pl.DataFrame:
    """Per parameter value, clips in ``groups`` groups of similar complexity: complexity with
    its 95 % interval, success, hit rate and false alarms with exact 95 % intervals."""
    rows = []
    for (value,), g in clips.group_by(by, maintain_order=True):
        g = g.sort(COMPLEXITY)
        for k, part in enumerate(np.array_split(np.arange(g.height), groups)):
            sub = g[part.tolist()]
            c = mean_ci(sub[COMPLEXITY].to_numpy(), bounds=(0.0, math.inf))
            row = {
                by: value,
                "condition": f"group {k + 1}",
                "clips": sub.height,
                "complexity_dps": c.mean,
                "complexity_low": c.low,
                "complexity_high": c.high,
            }
            hits = sub.filter(pl.col("collision"))["hit"]
            row |= share_row("success", hits) | share_row("hit_rate", hits)
            row |= share_row("false_alarm_rate", sub["false_alarm"])
            rows.append(row)
    return pl.DataFrame(rows)


def share_row(name: str, flags: pl.Series) -> dict[str, float]:
    """A share of clips with its exact 95 % interval (``name``, ``_low``, ``_high``)."""
    n = flags.len()
    if n == 0:
        return {name: math.nan, f"{name}_low": math.nan, f"{name}_high": math.nan}
    e = share_ci(np.array([int(flags.sum())]), np.array([n]))
    mean_key = "success_rate" if name == "success" else name
    return {mean_key: e.mean, f"{name}_low": e.low, f"{name}_high": e.high}


def footage_boundary(s: BoundarySettings, out: Path, feedback: Feedback) -> BoundaryResult:
    """Footage mode of :func:`analysis.experiments.collision.boundary_campaign.boundary`."""

    if s.fov_deg is None:
        raise UserError("footage mode needs --fov-deg (the camera's horizontal field of view).")
    values = number_list(s.values, "values", minimum=-math.inf)
    specs = {v: with_override(s.detector, s.param, v) for v in values}
    labels = read_labels(s.labels or "")

    # each value built and stepped on one frame of the clips' raster, before any clip runs: a
    # factory that raises, a model without alert or one whose step cannot give it fails now
    shape, ctx = clip_camera(labels["source"][0], s.fov_deg)
    for spec in specs.values():
        check_detector(spec, ctx, shape)
    if labels["collision_frame"].drop_nulls().len() == 0:  # as arena mode's require_evidence
        raise UserError(
            f"no clip in {s.labels!r} has a collision (collision_frame is empty in all "
            f"{labels.height}): there is no evidence to place a boundary on; label at least one "
            "clip with the frame of its collision."
        )
    feedback.log(
        f"footage: {labels.height} clip(s) x {len(values)} value(s) of {s.param}, {s.detector}."
    )
    complexity = clip_complexity(
        labels,
        s.fov_deg,
        s.alert_window_s,
        {"executor": s.executor, "jobs": s.jobs, "scheduler": s.scheduler},
        out / "complexity",
    )
    tasks = [
        (
            f"{row['clip']} {s.param}={v:g}",
            (
                row["source"],
                spec,
                row["collision_frame"],
                s.fov_deg,
                s.alert_window_s,
                s.min_ttc_s,
                row.get("hazard_onset_frame"),
            ),
        )
        for v, spec in specs.items()
        for row in labels.iter_rows(named=True)
    ]
    results = run_tasks_or_raise(clip_task, tasks, s.executor_settings(), "clip", feedback)
    by_source = {r["source"]: r for r in complexity.iter_rows(named=True)}
    rows = []
    for v in values:
        for row in labels.iter_rows(named=True):
            c = by_source[row["source"]]
            rows.append(
                {
                    "clip": row["clip"],
                    "label": row["label"],
                    "collision_frame": row["collision_frame"],
                    "collision": row["collision_frame"] is not None,
                    **({"scene": row["scene"]} if "scene" in row else {}),
                    s.param: v,
                    **results[f"{row['clip']} {s.param}={v:g}"],
                    **{k: v for k, v in c.items() if k != "source"},
                }
            )
    clips = pl.DataFrame(rows)
    note = nan_alert_note(clips, s.detector)
    if note:
        feedback.log(note)
    if clips["first_alert_frame"].drop_nulls().len() == 0:
        raise UserError(
            f"{s.detector} never alerted on any of the {labels.height} clip(s) at any value of "
            f"{s.param} ({s.values}): there is no evidence to place a boundary on; try values "
            "that make it more sensitive."
        )
    groups = s.groups or max(1, min(5, labels.height // 4))
    stats = group_statistics(clips, s.param, groups)
    fitted, fits = clip_fits(clips, s.param, s.target)
    bounds = with_fit(boundaries(stats, s.param, s.target), fitted, s.param, "groups")
    overall = [
        {s.param: v, "clips": g.height}
        | share_row("hit_rate", g.filter(pl.col("collision"))["hit"])
        | share_row("false_alarm_rate", g["false_alarm"])
        | share_row("correct", g["correct"])
        | _ttc(g)
        for (v,), g in clips.group_by(s.param, maintain_order=True)
    ]
    summary = pl.DataFrame(overall)
    named = {
        "boundary_clips": clips,
        "boundary_conditions": stats,
        "boundary": bounds,
        "boundary_summary": summary,
    }
    with table_set(out) as stage:
        paths = write_tables(stage, named, {"settings": dataclasses.asdict(s)})
        paths.append(
            plot_boundary(
                stats,
                bounds,
                s.param,
                s.target,
                stage / "boundary.png",
                f"{s.detector} on {labels.height} labelled clips",
                "complexity: AVDM mean response of the clips' group (deg/s)",
                energy=("false_alarm_rate", 100.0, "false alarms (% of clips)"),
                fits=fits,
            )
        )
        md = footage_report(s, summary, stats, bounds, clips)
        if not s.no_predictors:  # every measure judged by the clips (and frames) it gets wrong
            _, more, section = footage_predictor_tables(
                s, labels, clips, out / "complexity", stage, feedback.log
            )
            paths += more
            md += "\n" + section
        return published(stage, out, BoundaryResult(clips, stats, bounds, None, paths, md))


def clip_fits(clips: pl.DataFrame, by: str, target: float) -> tuple[pl.DataFrame, dict[float, Any]]:
    """The fitted boundary per value over the collision clips themselves (each a hit or a
    miss at its complexity, ``analysis.boundary.fit``), not over groups; no wall TF."""
    rows, fits = [], {}
    hit = clips.filter(pl.col("collision"))
    domain = (float(clips[COMPLEXITY].min()), float(clips[COMPLEXITY].max()))
    for (value,), g in clips.group_by(by, maintain_order=True):
        g = hit.filter(pl.col(by) == value)
        f = fit_crossing(g[COMPLEXITY], g["hit"].cast(pl.Int64), [1] * g.height, target, domain)
        fits[value] = f
        rows.append({by: value} | fit_columns(f))
    return pl.DataFrame(rows), fits


def _ttc(g: pl.DataFrame) -> dict[str, float]:
    ttc = g.filter(pl.col("hit"))["ttc_first_alert_s"].to_numpy()
    e = mean_ci(ttc, bounds=(0.0, math.inf))
    return {
        "ttc_first_alert_s": e.mean,
        "ttc_first_alert_s_low": e.low,
        "ttc_first_alert_s_high": e.high,
    }


def footage_report(
    s: BoundarySettings,
    summary: pl.DataFrame,
    stats: pl.DataFrame,
    bounds: pl.DataFrame,
    clips: pl.DataFrame,
) -> str:
    """``boundary.md`` of footage mode."""
    lines = [
        f"# {s.detector} on labelled footage\n",
        f"Labels: `{s.labels}`; a hit is a first alert at most {s.alert_window_s:g} s before "
        f"the collision frame. Target success {100 * s.target:g} %. Intervals are exact 95 % "
        "intervals across clips.\n",
        "![success and false alarms against complexity](boundary.png)\n",
        "## Overall\n",
    ]
    table = pl.DataFrame(
        [
            {
                s.param: r[s.param],
                "clips": r["clips"],
                "hit rate (%)": interval(r, "hit_rate", 100.0),
                "false alarms (% of clips)": interval(r, "false_alarm_rate", 100.0),
                "correct clips (%)": interval(r, "correct", 100.0),
                "TTC of the first alert (s)": interval(r, "ttc_first_alert_s", digits=2),
            }
            for r in summary.iter_rows(named=True)
        ]
    )
    lines += [markdown_table(table, table.columns), "## The boundary\n"]
    lines += fit_section(bounds, s.param)
    for row in bounds.iter_rows(named=True):
        lines.append(f"- {s.param} = {row[s.param]:g}: {describe_boundary(row)}")
    lines += ["", "## Per group of clips of similar complexity\n"]
    table = pl.DataFrame(
        [
            {
                s.param: r[s.param],
                "group": r["condition"],
                "clips": r["clips"],
                "complexity (deg/s)": interval(r, "complexity"),
                "success (%)": interval(r, "success", 100.0),
                "hit rate (%)": interval(r, "hit_rate", 100.0),
                "false alarms (%)": interval(r, "false_alarm_rate", 100.0),
            }
            for r in stats.iter_rows(named=True)
        ]
    )
    lines += [markdown_table(table, table.columns), "## Per clip\n"]
    cols = [
        "clip",
        "label",
        "collision_frame",
        s.param,
        "first_alert_frame",
        "hit",
        "false_alarm",
        "ttc_first_alert_s",
        COMPLEXITY,
    ]
    lines.append(markdown_table(clips, [c for c in cols if c in clips.columns]))
    return "\n".join(lines) + "\n"
