"""The work of ``vdc-analyse dataset`` (its face is ``analysis.dataset``)."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import polars as pl

from analysis.dataset import DatasetResult, DatasetSettings
from analysis.dataset.flags import finish, severity
from analysis.dataset.layout import EpisodeVideo, Problem, open_dataset
from vdc.executors import Feedback, run_tasks
from vdc.parquet_io import table_set, write_tables


def _task(video: EpisodeVideo, settings: DatasetSettings, fps: float) -> dict[str, Any]:
    from analysis.dataset.measure import measure_episode

    return measure_episode(video, settings, fps)


def no_fov_note(settings: DatasetSettings) -> str | None:
    """One note where the angular measures are left out for want of a field of view."""
    from analysis.source_metrics import ANGULAR_METRICS, parse_metrics

    left = [m for m in parse_metrics(settings.metrics) if m in ANGULAR_METRICS]
    if settings.fov_deg is not None or not left:
        return None
    return (
        f"no --fov-deg: {', '.join(left)} and the shifts in degrees left out (they need the "
        "cameras' horizontal field of view); the other measures are taken"
    )


def run(root: Path, settings: DatasetSettings, out: Path, feedback: Feedback) -> DatasetResult:
    ds = open_dataset(root)
    problems: list[Problem] = list(ds.problems)
    wanted = settings.episode_list()
    videos = [v for v in ds.videos if wanted is None or v.episode in wanted]
    notes = [n for n in [no_fov_note(settings)] if n]
    for n in notes:
        feedback.log(n)
    feedback.log(
        f"{root}: LeRobot {ds.version}, {len(set(v.episode for v in videos))} episode(s), "
        f"{len(ds.cameras)} camera(s), {ds.fps:g} fps"
    )
    tasks = [(f"{v.episode}:{v.camera}", (v, settings, ds.fps)) for v in videos]
    by_key = {f"{v.episode}:{v.camera}": v for v in videos}
    results: dict[str, dict[str, Any]] = {}

    def done(outcome: Any) -> None:
        feedback.progress(1)
        if outcome.error is None:
            results[outcome.key] = outcome.result
            return
        v = by_key[outcome.key]
        msg = (
            outcome.error.split(": ", 1)[1]
            if outcome.error.startswith("ValueError")
            else outcome.error
        )
        problems.append(Problem(v.path, v.episode, f"{v.camera}: {msg}"))

    run_tasks(_task, tasks, settings.executor_settings(), done,
              feedback.log, shared_paths=(root,))  # fmt: skip
    rows = [results[k]["row"] for k in sorted(results, key=_order)]
    frames = [
        results[k]["frames"].with_columns(
            pl.lit(results[k]["row"]["episode_index"]).alias("episode_index"),
            pl.lit(results[k]["row"]["camera"]).alias("camera"),
        )
        for k in sorted(results, key=_order)
    ]
    views = {(r["row"]["episode_index"], r["row"]["camera"]): r["views"] for r in results.values()}
    widths = {cam: _width(ds.info, cam) for cam in ds.cameras}
    meta = {"command": "dataset", "dataset": str(root), "version": ds.version,
            "settings": dataclasses.asdict(settings)}  # fmt: skip
    problem_table = pl.DataFrame(
        {"file": [p.file for p in problems], "episode_index": [p.episode for p in problems],
         "message": [p.message for p in problems]},
        schema={"file": pl.String, "episode_index": pl.Int64, "message": pl.String},
    )  # fmt: skip
    eps = None
    if rows:
        eps, frame_table = finish(rows, pl.concat(frames, how="diagonal_relaxed"), views,
                                  widths, settings.fov_deg)  # fmt: skip
        eps = severity(eps)
    with table_set(out) as stage:
        tables = {"episodes": eps, "frames": frame_table if rows else None,
                  "problems": problem_table}  # fmt: skip
        paths = write_tables(stage, tables, meta)
        if settings.page and eps is not None:
            from analysis.dataset.page import write_page

            paths.append(write_page(stage / "dataset.html", ds, eps, frame_table, problems))
    paths = [out / p.name for p in paths]
    fail = set(settings.fail_names())
    failed = []
    if eps is not None and fail:
        for r in eps.iter_rows(named=True):
            if fail & set(filter(None, r["flags"].split(","))):
                failed.append(int(r["episode_index"]))
    return DatasetResult(paths, eps, [p.line() for p in problems], sorted(set(failed)), notes)


def _order(key: str) -> tuple[int, str]:
    e, cam = key.split(":", 1)
    return int(e), cam


def _width(info: dict, cam: str) -> int:
    feat = info.get("features", {}).get(cam, {})
    shape = feat.get("shape") or [0, 0]
    names = feat.get("names") or []
    if "width" in names:
        return int(shape[names.index("width")])
    return int(shape[1]) if len(shape) > 1 else 0
