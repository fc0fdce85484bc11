"""``--per-scene``: each (value, scene) its own adaptive design, fitted to its *first* crossing
(:func:`design_runs_per_scene`), and the same fit per scene of a grid's runs
(:func:`grid_fits_per_scene`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import polars as pl

from analysis.boundary.fit import CrossingFit, dps_to_tf, fit_columns, fit_crossing
from analysis.boundary.statistics import boundaries, condition_statistics
from analysis.experiments.collision.design import (
    DesignSettings,
    DesignSpace,
    is_settled,
    place_run,
)
from analysis.stats import condition_share_bounds

PER_SCENE_FIRST = 3  # per-scene design: the first batch per scene, the range's ends and middle


def first_failure(
    x: Sequence[float], k: Sequence[float], n: Sequence[float], target: float, phi: float = 1.0
) -> float:
    """The least complexity among conditions that clearly fail (the 95 % upper bound of their
    success below ``target``, seed spread counted:
    :func:`analysis.stats.condition_share_bounds`); inf when none does. The per-scene
    design's boundary is the *first* crossing: runs past this one are not fitted (a detector
    can fail in the middle of a scene's range and recover at its end)."""
    xs, _, upper = condition_share_bounds(x, k, n, phi)
    failing = xs[upper < target]
    return float(failing.min()) if failing.size else math.inf


def first_recovery(
    x: Sequence[float],
    k: Sequence[float],
    n: Sequence[float],
    target: float,
    failed: float,
    phi: float = 1.0,
) -> float:
    """The least complexity above ``failed`` (the first clearly failing condition's) among
    conditions that clearly succeed again (the 95 % lower bound of their success above
    ``target``, seed spread counted): where the success recovers; inf when none does."""
    xs, lower, _ = condition_share_bounds(x, k, n, phi)
    back = xs[(xs > failed) & (lower > target)]
    return float(back.min()) if back.size else math.inf


def fit_first_crossing(
    rows: Sequence[dict[str, Any]], target: float, domain: tuple[float, float]
) -> tuple[CrossingFit, float]:
    """The monotone curve (:func:`fit_crossing`) fitted to one scene's runs (complexity_dps,
    avoidances, crashes) below the first that clearly holds again past the first clearly
    failing one (:func:`first_recovery`, :func:`first_failure`): the *first* crossing, with
    every run on the falling side of it. Returns the fit and the first failing run's
    complexity (inf: none fails, every run fitted). A clearly failing run at the least complex
    point of ``domain`` makes the state ``below`` (95 %: < it)."""
    x = [r["complexity_dps"] for r in rows]
    k = [r["avoidances"] for r in rows]
    n = [r["avoidances"] + r["crashes"] for r in rows]
    # twice: binomial bounds find the falling side, whose runs' dispersion then widens a lone
    # run's bounds (a dispersion with runs past a recovery in it would be the dip's)
    phi = 1.0
    for _ in range(2):
        cut = first_failure(x, k, n, target, phi)
        back = first_recovery(x, k, n, target, cut, phi)
        keep = [i for i, xi in enumerate(x) if xi < back]
        pick = [x[i] for i in keep], [k[i] for i in keep], [n[i] for i in keep]
        if len(keep) > 2:
            phi = fit_crossing(*pick, target, domain, band=False).dispersion
    fit = fit_crossing(*pick, target, domain)
    if cut <= min(domain) + 1e-9:  # a run at the scene's least complex point clearly fails
        fit = dataclasses.replace(fit, state="below", boundary=math.nan, low=-math.inf, high=cut)
    return fit, cut


def sample_within(
    fit: CrossingFit, rng: np.random.Generator, size: int, low: float, high: float
) -> np.ndarray:
    """``size`` crossings (deg/s) drawn from ``fit``'s normalised likelihood restricted to
    [``low``, ``high``] (a scene's range, up to its first clearly failing run): no run is spent
    at an end only because the crossing may lie past it. Clipped draws if none of the
    likelihood lies there."""
    inside = (fit.t_grid >= low) & (fit.t_grid <= high)
    w = np.where(inside, fit.weights, 0.0)
    if w.sum() <= 0:
        return np.clip(fit.sample(rng, size), low, high)
    return rng.choice(fit.t_grid, size=size, p=w / w.sum())


def design_runs_per_scene(
    space: DesignSpace,
    run_batch: Callable[[list[dict[str, Any]]], list[dict[str, Any]]],
    design: DesignSettings,
    *,
    log: Callable[[str], None] = lambda _m: None,
) -> tuple[list[dict[str, Any]], dict[tuple[float, str], CrossingFit]]:
    """The per-scene adaptive loop (``--per-scene``): each (value, scene) its own design.
    ``budget`` runs per value are split evenly among the scenes (a scene that settles early
    leaves its unspent runs to the value's scenes still running); per scene a first batch of
    ``PER_SCENE_FIRST`` runs at TFs spread over the range, then batches of ``batch`` runs whose
    complexities (that scene's profile) are drawn from the likelihood of its first crossing
    (:func:`fit_first_crossing`: the runs up to where success clearly recovers) within that
    scene's range and below its first clearly failing run (:func:`sample_within`), and made
    TFs of that scene. A (value, scene) stops as :func:`design_runs`' values do (or at its
    share of the budget). ``run_batch`` as :func:`design_runs`'; returns every row and the
    last fit per (value, scene)."""
    target, budget, precision_dps, batch, seed = dataclasses.astuple(design)  # field order
    values, scenes, profile, tf_range = space.values, space.scenes, space.profile, space.tf_range
    rng = np.random.default_rng(seed)
    lo, hi = tf_range
    per_scene = max(2, budget // len(scenes))
    domain = {sc: (float(profile.to_dps(sc, lo)), float(profile.to_dps(sc, hi))) for sc in scenes}
    keys = [(v, sc) for v in values for sc in scenes]
    rows: dict[tuple[float, str], list[dict[str, Any]]] = {key: [] for key in keys}
    fits: dict[tuple[float, str], CrossingFit] = {}
    cuts: dict[tuple[float, str], float] = {}
    active = list(keys)
    spare = dict.fromkeys(values, 0)  # runs a value's settled scenes left unspent

    def cap(v: float) -> int:  # a scene's share: its own plus the unspent runs shared out
        return per_scene + spare[v] // max(1, sum(key[0] == v for key in active))

    round_no = 0
    while active:
        placed: list[dict[str, Any]] = []
        for v, sc in active:
            done = rows[(v, sc)]
            if round_no == 0:
                tfs = [
                    round(float(t), 2) for t in np.linspace(lo, hi, min(PER_SCENE_FIRST, per_scene))
                ]
            else:
                size = min(batch, cap(v) - len(done))
                top = min(domain[sc][1], cuts[(v, sc)])
                dps = sample_within(fits[(v, sc)], rng, size, domain[sc][0], top)
                tfs = [round(float(np.clip(profile.to_tf(sc, d), lo, hi)), 2) for d in dps]
            for tf in tfs:
                n_value = sum(len(rows[(v, s2)]) for s2 in scenes)
                place_run(placed, profile, v, sc, tf, seed + n_value, round_no)
        for r in run_batch(placed):
            rows[(r["value"], r["scene"])].append(r)
        still = []
        for key in active:
            g = rows[key]
            fits[key], cuts[key] = fit_first_crossing(g, target, domain[key[1]])
            f = fits[key]
            log(
                f"  value {key[0]:g}, {key[1]}, batch {round_no}: {len(g)} run(s), boundary "
                f"{f.boundary:.1f} deg/s, 95 % [{f.low:.1f}, {f.high:.1f}] ({f.state})"
                + (
                    f"; first failing run at {cuts[key]:.1f} deg/s"
                    if math.isfinite(cuts[key])
                    else ""
                )
                + "."
            )
            if not is_settled(f, precision_dps) and len(g) < cap(key[0]):
                still.append(key)
        for key in active:
            if key not in still:  # settled or spent: its unspent runs go to its value's others
                spare[key[0]] += max(0, cap(key[0]) - len(rows[key]))
        active = still
        round_no += 1
    return [r for key in keys for r in rows[key]], fits


def per_scene_bounds(
    conditions: pl.DataFrame,
    fits: dict[tuple[float, str], CrossingFit],
    by: str,
    target: float,
    to_tf: Callable[[str, Any], Any],
    design: str = "adaptive",
) -> pl.DataFrame:
    """``boundary.parquet`` per (value, scene): the bracket of that scene's conditions
    (:func:`analysis.boundary.statistics.boundaries`), the fitted columns of
    ``fits[(value, scene)]`` (TF through ``to_tf(scene, deg/s)``), the ``design``."""
    parts = []
    for v, sc in fits:
        mine = conditions.filter((pl.col(by) == v) & pl.col("condition").str.starts_with(f"{sc}-"))
        bracket = boundaries(mine, by, target).rename({"boundary_dps": "bracket_dps"})
        fitted = fit_columns(fits[(v, sc)], lambda d, sc=sc: to_tf(sc, d))
        parts.append(
            bracket.with_columns(
                pl.lit(sc).alias("scene"),
                *[pl.lit(val).alias(name) for name, val in fitted.items()],
                pl.lit(design).alias("design"),
            )
        )
    return pl.concat(parts, how="diagonal_relaxed")


def grid_fits_per_scene(
    runs: pl.DataFrame, complexity: pl.DataFrame, by: str, target: float
) -> pl.DataFrame:
    """A grid's boundary per (value, scene), as ``--per-scene`` fits its own: each scene's runs
    (condition, scene, tf_hz, ``by``, avoidances, crashes) at their condition's complexity
    (condition, complexity_dps, complexity_low, complexity_high) up to where success clearly
    recovers past the first clearly failing run (:func:`fit_first_crossing`), over that
    scene's conditions' range; deg/s to wall TF through that scene's conditions. Columns as
    :func:`per_scene_bounds`', plus ``step_dps``: the gap between the scene's two grid
    conditions around the fitted boundary (or its bracket), the grid's resolution there (NaN
    where it places none)."""
    data = runs.join(complexity.select("condition", "complexity_dps"), on="condition", how="left")
    conditions = condition_statistics(runs, complexity, ["condition", by])
    fits, points = {}, {}
    for (scene,), g in data.group_by("scene", maintain_order=True):
        prof = g.unique("condition").sort("tf_hz")
        points[scene] = (prof["tf_hz"].to_numpy(), prof["complexity_dps"].to_numpy())
        domain = (float(g["complexity_dps"].min()), float(g["complexity_dps"].max()))
        for (value,), gv in g.group_by(by, maintain_order=True):
            fits[(value, scene)], _ = fit_first_crossing(gv.to_dicts(), target, domain)
    bounds = per_scene_bounds(conditions, fits, by, target, lambda sc, d: dps_to_tf(d, *points[sc]))
    steps = []
    for r in bounds.iter_rows(named=True):
        grid = np.sort(points[r["scene"]][1])
        at = r["boundary_dps"] if r["fit_state"] == "within" else r["bracket_dps"]
        i = np.searchsorted(grid, at) if at is not None and math.isfinite(at) else -1
        steps.append(float(grid[i] - grid[i - 1]) if 0 < i < grid.size else math.nan)
    return bounds.with_columns(pl.Series("step_dps", steps))
