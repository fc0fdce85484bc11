"""``vdc-analyse boundary --design adaptive``: find each value's boundary in few runs.

Instead of every wall TF × seed of a grid, the runs of each parameter value go along a
continuous TF range (``--tf-range LO:HI``), in batches, where the boundary is still uncertain:

1. **The profile.** Profiling runs (as the grid's: ring turns, no detector, seed ``--seed``) at
   the range's ends and middle, per scene, measure the AVDM's straight-driving response; a TF
   in between is mapped to its complexity (deg/s) by linear interpolation
   (:func:`analysis.boundary.fit.tf_to_dps`), and back.
2. **The first batch** per value: 4 runs at TFs evenly spread over the range (scenes in turn).
3. **Each next batch** (``max(2, --jobs)`` runs per value): the success curve is fitted to the
   value's runs so far (:func:`analysis.boundary.fit.fit_crossing`: a monotone logistic curve
   of success against complexity, the boundary's 95 % profile-likelihood interval), and the
   batch's complexities are drawn from the normalised likelihood of the crossing: runs go
   where the crossing plausibly is, more where it is more plausible. Each is made a TF of a
   scene whose range reaches it (the scene used least so far, on a tie), within the range.
4. **A value stops** when its interval is narrower than ``--precision`` (deg/s), when the
   boundary is placed beyond or below the range at 95 %, or at ``--budget`` runs.

Runs are recorded and measured on the executors exactly as the grid's
(``analysis.experiments.collision.boundary_campaign.run_grid``: finished runs reused). The
placement draws from a generator seeded by ``--seed`` and reused runs give the same rows, so a
re-run places the same runs and records only what is missing. Each run is its own condition
(``<scene>-tf<TF>``) with its own seed (``--seed`` + its index among the value's runs).

:func:`design_runs` (``analysis.experiments.collision.design``) is the loop alone, with the runs
made by a function it is given: the benchmark's coverage check drives it with simulated
detectors of known boundary. ``--per-scene``: :func:`design_runs_per_scene`
(``analysis.experiments.collision.per_scene``: each scene its own budget, TF axis, boundary).
This module runs the campaign: the profile, the batches on the executors, the files.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from analysis.boundary.command import BoundaryResult, published, write_arena_outputs
from analysis.boundary.fit import CrossingFit, fit_columns, with_fit
from analysis.boundary.policy import fit_policy
from analysis.boundary.scenes import scene_fields
from analysis.boundary.settings import BoundarySettings, condition_name
from analysis.boundary.statistics import boundaries, condition_statistics
from analysis.experiments.captures import RunItem, collision_run_item
from analysis.experiments.collision.design import (
    DesignSettings,
    DesignSpace,
    ProfileMap,
    design_runs,
)
from analysis.experiments.collision.per_scene import (
    design_runs_per_scene,
    first_failure,
    grid_fits_per_scene,
    per_scene_bounds,
)
from capture.sim import SimSettings
from vdc.executors import Feedback
from vdc.parquet_io import table_set

# the loop's names, importable from here as before the loop had its own modules
__all__ = [
    "DesignSettings",
    "DesignSpace",
    "ProfileMap",
    "adaptive_boundary",
    "campaign_conditions",
    "design_runs",
    "design_runs_per_scene",
    "first_failure",
    "grid_fits_per_scene",
    "in_fitted_range",
    "policy_from_campaign",
    "profile_runs",
    "run_items",
]

PROFILE_POINTS = 3  # profiling TFs per scene: the range's ends and middle


def profile_runs(s: BoundarySettings, folder: Path) -> list[RunItem]:
    """The profiling runs: per scene, ``PROFILE_POINTS`` TFs over the range, seed ``--seed``."""
    lo, hi = s.tf_bounds()
    items = []
    for scene in s.scene_list():
        for tf in np.linspace(lo, hi, PROFILE_POINTS):
            tf = round(float(tf), 2)
            cond = condition_name(scene, tf)
            run = {"tf_hz": tf, "minutes": s.minutes, "seed": s.seed, "model": s.profile_model}
            settings = SimSettings(**scene_fields(scene), **run)
            cols = {"condition": cond, "scene": scene, "tf_hz": tf, "seed": s.seed}
            path = folder / "profile" / cond / f"seed{s.seed}.rrd"
            items.append(RunItem(f"profile-{cond}-seed{s.seed}", settings, path, cols))
    return items


def run_items(s: BoundarySettings, placed: list[dict[str, Any]], folder: Path) -> list[RunItem]:
    """Closed-loop runs for the placed (value, scene, TF, seed)s, as the grid records them."""
    return [
        collision_run_item(
            s, p["scene"], p["tf_hz"], p["value"], p["seed"], folder, {s.param: p["value"]} | p
        )
        for p in placed
    ]


def adaptive_boundary(
    s: BoundarySettings, out: Path, run_grid: Callable[..., pl.DataFrame], feedback: Feedback
) -> BoundaryResult:
    """Arena mode with ``--design adaptive``, recording with the grid's ``run_grid``
    (:func:`analysis.experiments.collision.boundary_campaign.run_grid`, passed in by the
    command's entry, which imports this module): the profile, the batches, the fits; writes the
    same files as the grid (``boundary.md``, ``boundary.png``, ``boundary_runs.parquet``: one
    row per run the design placed, ``boundary.parquet`` with the fitted columns,
    ``boundary_profiles.parquet``, ``policy.csv``)."""
    rec = out / "recordings"
    scenes, values = s.scene_list(), s.grid_values()
    prof_items = profile_runs(s, rec)
    feedback.log(
        f"adaptive boundary of {s.detector} over {s.param} = {values}: up to {s.budget} run(s) "
        f"per value along wall TF {s.tf_range} Hz ({', '.join(scenes)}), plus "
        f"{len(prof_items)} profiling run(s)."
    )
    profiles = run_grid(prof_items, "profile", s, s.false_alarm_m, feedback)
    pmap = ProfileMap.from_runs(profiles)

    def run_batch(placed: list[dict[str, Any]]) -> list[dict[str, Any]]:
        done = run_grid(run_items(s, placed, rec), "collision", s, s.false_alarm_m, feedback)
        return done.to_dicts()

    if s.per_scene:
        return _per_scene_outputs(s, out, pmap, profiles, run_batch, feedback)
    rows, fits = design_runs(
        DesignSpace.of(s, pmap), run_batch, DesignSettings.of(s), log=feedback.log
    )
    runs = pl.DataFrame(rows).drop("value").sort(s.param, "batch", "seed")
    conditions = campaign_conditions(runs, s.param)
    first = scenes[0]
    fitted = pl.DataFrame(
        [{s.param: v} | fit_columns(f, lambda d: pmap.to_tf(first, d)) for v, f in fits.items()]
    )
    bounds = with_fit(boundaries(conditions, s.param, s.target), fitted, s.param, "adaptive")
    return _outputs(s, out, "adaptive design", runs, conditions, bounds, profiles, fits)


def _outputs(
    s: BoundarySettings,
    out: Path,
    design: str,
    runs: pl.DataFrame,
    conditions: pl.DataFrame,
    bounds: pl.DataFrame,
    profiles: pl.DataFrame,
    fits: dict[Any, CrossingFit],
) -> BoundaryResult:
    """An adaptive ``design``'s files (those of the grid) and result, with its policy."""
    policy = None if s.no_fit else policy_from_campaign(runs, s)
    tables = {"runs": runs, "conditions": conditions, "bounds": bounds, "profiles": profiles}
    with table_set(out) as stage:
        paths, md = write_arena_outputs(
            stage,
            s,
            tables,
            policy,
            f"{s.detector}: {design}, {runs.height} runs",
            "complexity: AVDM straight-driving response, profile interpolated (deg/s)",
            fits,
        )
        return published(stage, out, BoundaryResult(runs, conditions, bounds, policy, paths, md))


def _per_scene_outputs(
    s: BoundarySettings,
    out: Path,
    pmap: ProfileMap,
    profiles: pl.DataFrame,
    run_batch: Callable[[list[dict[str, Any]]], list[dict[str, Any]]],
    feedback: Feedback,
) -> BoundaryResult:
    """``--per-scene``: the loop (:func:`design_runs_per_scene`) and the files, with one row of
    ``boundary.parquet`` per (value, scene) (a ``scene`` column; the TF columns through that
    scene's profile; the bracket from that scene's runs)."""
    rows, fits = design_runs_per_scene(
        DesignSpace.of(s, pmap), run_batch, DesignSettings.of(s), log=feedback.log
    )
    runs = pl.DataFrame(rows).drop("value").sort(s.param, "batch", "seed")
    conditions = campaign_conditions(runs, s.param)
    bounds = per_scene_bounds(conditions, fits, s.param, s.target, pmap.to_tf)
    return _outputs(s, out, "adaptive design per scene", runs, conditions, bounds, profiles, fits)


def campaign_conditions(runs: pl.DataFrame, by: str) -> pl.DataFrame:
    """Per-condition statistics (:func:`analysis.boundary.statistics.condition_statistics`) of an
    adaptive campaign's runs, each condition at its own interpolated complexity."""
    complexity = runs.select(
        "condition",
        "complexity_dps",
        pl.col("complexity_dps").alias("complexity_low"),
        pl.col("complexity_dps").alias("complexity_high"),
    ).unique("condition", maintain_order=True)
    return condition_statistics(runs.drop("complexity_dps"), complexity, ["condition", by])


def policy_from_campaign(runs: pl.DataFrame, s: BoundarySettings, bins: int = 3) -> Any:
    """The policy (:func:`analysis.boundary.policy.fit_policy`) from an adaptive campaign's
    runs: each
    scene's TF range cut in ``bins`` equal parts, the runs of a part pooled as one condition
    (``<scene>-tf<LO>-<HI>``); parts where some value has no run are left out (the policy
    compares the values on the same conditions). None when no part has every value."""
    lo, hi = s.tf_bounds()
    edges = np.linspace(lo, hi, bins + 1)
    part = np.clip(np.searchsorted(edges, runs["tf_hz"].to_numpy(), side="right") - 1, 0, bins - 1)
    names = [f"tf{round(edges[i], 2):g}-{round(edges[i + 1], 2):g}" for i in part]
    binned = runs.with_columns((pl.col("scene") + "-" + pl.Series(names)).alias("condition"))
    n_values = len(s.grid_values())
    full = binned.group_by("condition").agg(pl.col(s.param).n_unique().alias("n"))
    keep = full.filter(pl.col("n") == n_values)["condition"]
    binned = binned.filter(pl.col("condition").is_in(keep.implode()))
    if binned.height == 0:
        return None
    return fit_policy(binned, s.param, s.target, s.profile_model)


def in_fitted_range(scene: str, tf_hz: float | None, fitted: set[str]) -> bool:
    """Whether (scene, TF) lies in a TF range an adaptive campaign's policy was fitted on (its
    evidence's conditions ``<scene>-tf<LO>-<HI>``, :func:`policy_from_campaign`)."""
    if tf_hz is None:
        return False
    for name in fitted:
        m = re.fullmatch(r"(\w+)-tf([\d.]+)-([\d.]+)", name)
        if m and m[1] == scene and float(m[2]) <= tf_hz <= float(m[3]):
            return True
    return False
