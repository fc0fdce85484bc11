"""The arena campaign of ``vdc-analyse boundary`` (see :mod:`analysis.boundary.command`):
closed-loop runs over the grid and the profiling runs, recorded on the executors and reused when
finished, each measured once; and :func:`boundary`, the command's entry, which sends a labelled
collection to footage mode (:mod:`analysis.boundary.footage`) instead."""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import polars as pl

from analysis.boundary.command import BoundaryResult, published, write_arena_outputs
from analysis.boundary.fit import grid_fits, with_fit
from analysis.boundary.footage import footage_boundary
from analysis.boundary.policy import fit_policy
from analysis.boundary.settings import BoundarySettings
from analysis.boundary.statistics import (
    ROW_VERSION,
    WARMUP_FRAMES,
    boundaries,
    condition_complexity,
    condition_statistics,
    run_row,
)
from analysis.experiments.captures import (
    RunItem,
    capture_is_done,
    check_detectors,
    collision_run_item,
    profiling_items,
)
from analysis.experiments.collision.adaptive import adaptive_boundary
from analysis.experiments.collision.predictor_runs import (
    arena_predictor_tables,
    cached_measures,
    measures_table,
    read_cached_measures,
)
from analysis.predictors.verdicts import table_note
from capture.run import REPLACE_OUTPUT
from capture.sim import record_sim
from vdc.errors import UserError
from vdc.executors import QUIET, ExecutorSettings, Feedback, one_pool, run_tasks_or_raise
from vdc.parquet_io import table_set
from vdc.scratch import no_files_without_out


def record_and_measure(
    key: str, settings: Any, out: str, kind: str, false_alarm_m: float, measure_every: int = 0
) -> dict:
    """An executor task: record the run unless a finished recording of the same configuration
    is there, then measure it; the row is kept beside the recording (``.row.json``) so a
    re-run neither records nor measures it again. A profiling run with ``measure_every`` > 0
    also gets every complexity measure of the predictors, in this worker right after its
    recording (``predictor_runs.cached_measures``, cached beside it the same way), under
    ``"measures"``: no second pool to start, import and warm up after the grid's."""

    path = Path(out)
    run_id = settings.to_config().run_id()
    cache = path.with_suffix(".row.json")
    row = None
    if capture_is_done(path, run_id):
        row = cached_row(path, run_id)
    else:
        record_sim(settings, path, REPLACE_OUTPUT)  # a partial file of a killed run is replaced
    if row is None:
        row = run_row(path, kind, false_alarm_m) | {"row_version": ROW_VERSION}
        tmp = cache.with_suffix(".partial")
        tmp.write_text(json.dumps(row))
        tmp.replace(cache)
        row |= {"reused": False}
    if kind == "profile" and measure_every > 0:
        row["measures"] = cached_measures(path, measure_every)
    return row | {"key": key}


def cached_row(path: Path, run_id: str) -> dict[str, Any] | None:
    """The measured row kept beside a finished recording (``.row.json``), marked reused, or
    None when there is none of this run measured by this version of :func:`run_row`."""
    cache = path.with_suffix(".row.json")
    if not cache.exists():
        return None
    row = json.loads(cache.read_text())
    # a row measured by an older vdc lacks a measurement: measure again, not record
    if row.get("recording_id") == run_id and row.get("row_version") == ROW_VERSION:
        return row | {"reused": True}
    return None


def finished_row(item: RunItem, kind: str, measure_every: int) -> dict[str, Any] | None:
    """:func:`record_and_measure`'s result for a run that has nothing left to do (recorded,
    measured, and with ``measure_every`` its measures cached), read here without a task;
    None when it has."""
    if not item.path.exists():
        return None
    run_id = item.settings.to_config().run_id()
    row = cached_row(item.path, run_id)
    if row is None or not capture_is_done(item.path, run_id):
        return None
    if kind == "profile" and measure_every > 0:
        measures = read_cached_measures(item.path, measure_every)
        if measures is None:
            return None
        row["measures"] = measures
    return row | {"key": item.key}


def _record_all(
    items: Sequence[RunItem],
    kind: str,
    executor: ExecutorSettings,
    false_alarm_m: float,
    feedback: Feedback,
    measure_every: int = 0,
) -> list[dict[str, Any]]:
    """:func:`record_and_measure` of every item on ``executor``: the results in the items'
    order, ``columns`` first."""

    # a detector that cannot be one: one line before the first run, not one failure per run
    check_detectors(it.settings.to_config() for it in items)
    tasks = []
    finished: dict[str, dict[str, Any]] = {}
    for it in items:
        it.settings.to_config()  # a bad configuration fails before any process starts
        it.path.parent.mkdir(parents=True, exist_ok=True)
        # a run with nothing left to do is read here: a re-run of a finished campaign starts
        # no pool (its workers' start-up was most of such a re-run's time)
        row = finished_row(it, kind, measure_every)
        if row is not None:
            finished[it.key] = row
            feedback.expect(1)  # counted done at once; run_tasks_or_raise expects the rest
            feedback.progress(1)
            continue
        task = (it.key, it.settings, str(it.path), kind, false_alarm_m, measure_every)
        tasks.append((it.key, task))
    results = finished | run_tasks_or_raise(
        record_and_measure,
        tasks,
        executor.executor_settings(),
        "run",
        feedback,
        shared_paths=[items[0].path.parent] if items else [],
    )
    rows = [{**it.columns, **results[it.key]} for it in items if it.key in results]
    reused = sum(bool(r.get("reused")) for r in rows)
    if reused:
        feedback.log(f"reused {reused} of {len(items)} {kind} run(s) that an earlier run finished.")
    return rows


def run_grid(
    items: Sequence[RunItem],
    kind: str,
    executor: ExecutorSettings,
    false_alarm_m: float,
    feedback: Feedback,
) -> pl.DataFrame:
    """Record and measure every ``(key, SimSettings, path, columns)`` on ``executor``; one row
    per run with ``columns`` (its condition) first. A failed run does not stop the others:
    they are kept and :class:`vdc.executors.TasksFailed` names the failed ones."""
    rows = _record_all(items, kind, executor, false_alarm_m, feedback)
    return pl.DataFrame(rows).sort("key")


def run_profiles(
    items: Sequence[RunItem],
    executor: ExecutorSettings,
    feedback: Feedback,
    measure_every: int = 0,
) -> tuple[pl.DataFrame, pl.DataFrame | None]:
    """:func:`run_grid` of the profiling runs, and (``measure_every`` > 0) every complexity
    measure of each, taken by the worker that recorded it
    (:func:`analysis.experiments.collision.predictor_runs.measures_table`; else None)."""
    rows = _record_all(items, "profile", executor, 0.0, feedback, measure_every)
    got = {r["key"]: r.pop("measures") for r in rows if "measures" in r}
    measures = None
    if measure_every > 0:
        measures = measures_table([(it.key, it.columns) for it in items], got)
    return pl.DataFrame(rows).sort("key"), measures


def _shortest_run(s: BoundarySettings, sim: Any) -> str:
    """How long runs need to be, as the end of a sentence (``sim``: one run's SimSettings,
    whose arena, robot and camera say how soon a robot can meet a wall and how long the
    warm-up of every measurement is)."""
    c = sim.to_config()
    warmup_s = WARMUP_FRAMES / c.camera.fps
    # from the arena's centre the robot meets a wall in half its length at most
    first_s = c.arena.length_m / 2 / c.robot.speed_mps + warmup_s
    return (
        f"a run meets a wall {first_s:.0f} s in at the earliest ({c.arena.length_m:g}-m arena "
        f"at {c.robot.speed_mps:g} m/s, after the {warmup_s:.1f}-s warm-up of every measure), "
        f"so runs need --minutes {math.ceil(first_s / 6) / 10:g} at the very least, and "
        f"several minutes for a success rate (the default is 10; these were {s.minutes:g})"
    )


def require_evidence(
    runs: pl.DataFrame, complexity: pl.DataFrame | None, s: BoundarySettings, sim: Any
) -> None:
    """UserError, in one line, where the runs hold no evidence to place a boundary on (or fit
    a policy to): no run had an avoidance or a crash, or (``complexity`` given) a condition's
    complexity could not be measured. The line says how long runs need to be."""

    if not runs.height or int(runs["avoidances"].sum() + runs["crashes"].sum()) == 0:
        raise UserError(
            f"no run had an avoidance or a crash ({runs.height} run(s)): there is no evidence "
            f"to place a boundary on; {_shortest_run(s, sim)}."
        )
    if complexity is not None:
        bad = complexity.filter(~pl.col("complexity_dps").is_finite())["condition"].to_list()
        if bad:
            raise UserError(
                f"the complexity of {', '.join(bad)} could not be measured (no frame after "
                f"the warm-up): there is no evidence to place a boundary on; "
                f"{_shortest_run(s, sim)}."
            )


@no_files_without_out
@one_pool()  # its stages share one pool of workers
def boundary(
    settings: BoundarySettings, out: str | Path | None, feedback: Feedback = QUIET
) -> BoundaryResult:
    """Run the grid (arena) or the labelled clips (footage mode: ``settings.labels``) and
    write the tables, the figure, the report and, in the arena, ``policy.csv`` into ``out``."""
    if settings.labels is not None:
        return footage_boundary(settings, Path(out), feedback)
    if settings.design == "adaptive":
        return adaptive_boundary(settings, Path(out), run_grid, feedback)
    return arena_boundary(settings, Path(out), feedback)


def grid_items(s: BoundarySettings, folder: Path) -> list[tuple[str, Any, Path, dict[str, Any]]]:
    """One closed-loop run per (scene, TF, value, seed)."""
    return [
        collision_run_item(
            s,
            scene,
            tf,
            value,
            seed,
            folder,
            {"scene": scene, "tf_hz": tf, s.param: value, "seed": seed},
        )
        for scene, tf in s.conditions()
        for value in s.grid_values()
        for seed in range(s.seed, s.seed + s.seeds)
    ]


def arena_boundary(s: BoundarySettings, out: Path, feedback: Feedback) -> BoundaryResult:
    """Arena mode of :func:`boundary`."""

    rec = out / "recordings"
    items = grid_items(s, rec)
    prof = profiling_items(s, rec) if s.complexity == "profile" else []

    check_detectors(it.settings.to_config() for it in items[:1])  # before a word
    feedback.log(
        f"boundary of {s.detector} over {s.param} = {list(s.grid_values())}: {len(s.conditions())} "
        f"condition(s) x {len(s.grid_values())} value(s) x {s.seeds} seed(s) of "
        f"{s.minutes:g} min = {len(items)} run(s)"
        + (f", plus {len(prof)} profiling run(s)" if prof else "")
        + "."
    )
    # one line per stage on the log (a pipe has no bar): nothing silent between plan and results
    stages = 3 if prof else 2
    feedback.log(f"stage 1/{stages}: {len(items)} closed-loop run(s) of {s.detector}.")
    runs = run_grid(items, "collision", s, s.false_alarm_m, feedback)
    require_evidence(runs, None, s, items[0].settings)  # never a verdict from no evidence
    if prof:
        feedback.log(
            f"stage 2/{stages}: {len(prof)} profiling run(s) (the AVDM's response to each "
            "condition, driving straight)."
        )
        # every complexity measure of a profiling run, by the worker that just recorded it
        every = 0 if s.no_predictors else s.measure_every
        profiles, measures = run_profiles(prof, s, feedback, every)
        complexity = condition_complexity(profiles, "profile_dps")
    else:
        profiles = measures = None
        complexity = condition_complexity(runs, "online_dps")
    require_evidence(runs, complexity, s, items[0].settings)
    feedback.log(
        f"stage {stages}/{stages}: success per condition, the boundary per {s.param} value"
        + ("" if s.no_fit else ", the policy")
        + f"; writing {out}."
    )
    conditions = condition_statistics(runs, complexity, ["condition", s.param])
    fitted, fits = grid_fits(runs, complexity, s.param, s.target)
    bounds = with_fit(boundaries(conditions, s.param, s.target), fitted, s.param, "grid")
    policy = fit_policy(runs, s.param, s.target, s.profile_model) if not s.no_fit else None
    x_label = (
        "complexity: AVDM straight-driving response, profiling runs (deg/s)"
        if s.complexity == "profile"
        else "complexity: on-board AVDM mean in the detector's runs (deg/s)"
    )
    with table_set(out) as stage:
        paths, md = write_arena_outputs(
            stage,
            s,
            {"runs": runs, "conditions": conditions, "bounds": bounds, "profiles": profiles},
            policy,
            f"{s.detector}: success against complexity",
            x_label,
            fits,
        )
        if measures is not None:
            table, more, section = arena_predictor_tables(s, runs, measures, stage)
            note = table_note(table)
            if note:
                feedback.log(note)
            paths += more
            md += "\n" + section
        return published(stage, out, BoundaryResult(runs, conditions, bounds, policy, paths, md))
