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

:func:`design_runs` is the loop alone, with the runs made by a function it is given: the
benchmark's coverage check drives it with simulated detectors of known boundary.
``--per-scene``: :func:`design_runs_per_scene` (each scene its own budget, TF axis, boundary).
"""

from __future__ import annotations

import dataclasses
import math
import re
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from analysis.boundary.command import BoundaryResult, published, write_arena_outputs
from analysis.boundary.fit import (
    CrossingFit,
    dps_to_tf,
    fit_columns,
    fit_crossing,
    tf_to_dps,
    with_fit,
)
from analysis.boundary.policy import fit_policy
from analysis.boundary.scenes import scene_fields
from analysis.boundary.settings import BoundarySettings, condition_name
from analysis.boundary.statistics import boundaries, condition_statistics
from analysis.experiments.captures import RunItem, collision_run_item
from analysis.stats import condition_share_bounds
from capture.sim import SimSettings
from vdc.executors import Feedback
from vdc.parquet_io import table_set

FIRST_BATCH = 4
PROFILE_POINTS = 3  # profiling TFs per scene: the range's ends and middle


@dataclasses.dataclass(frozen=True, kw_only=True)
class DesignSettings:
    """What an adaptive design (:func:`design_runs`, :func:`design_runs_per_scene`) aims at and
    may spend: the success ``target`` (share), runs per value (``budget``), the interval width
    that settles a value (``precision_dps``, deg/s), runs per batch and the placement's seed."""

    target: float
    budget: int
    precision_dps: float
    batch: int
    seed: int

    @classmethod
    def of(cls, s: BoundarySettings) -> DesignSettings:
        """A boundary campaign's design: a batch fills the pool (at least two runs)."""
        b = max(2, s.jobs)
        return cls(
            target=s.target, budget=s.budget, precision_dps=s.precision, batch=b, seed=s.seed
        )


@dataclasses.dataclass(frozen=True)
class ProfileMap:
    """Wall TF ↔ complexity (deg/s) per scene, from profiling runs (scene, tf_hz,
    profile_dps)."""

    points: dict[str, tuple[np.ndarray, np.ndarray]]  # scene -> (TFs, deg/s)

    @classmethod
    def from_runs(cls, profiles: pl.DataFrame) -> ProfileMap:
        pts = {}
        for (scene,), g in profiles.group_by("scene", maintain_order=True):
            pts[scene] = (g["tf_hz"].to_numpy(), g["profile_dps"].to_numpy())
        return cls(pts)

    def to_dps(self, scene: str, tf_hz: Any) -> Any:
        return tf_to_dps(tf_hz, *self.points[scene])

    def to_tf(self, scene: str, dps: Any) -> Any:
        return dps_to_tf(dps, *self.points[scene])


@dataclasses.dataclass(frozen=True)
class DesignSpace:
    """Where an adaptive design (:func:`design_runs`, :func:`design_runs_per_scene`) places
    runs: the detector parameter's ``values`` (one boundary each), the ``scenes``, their
    complexity ``profile`` and the wall TF range ``tf_range`` (Hz)."""

    values: Sequence[float]
    scenes: Sequence[str]
    profile: ProfileMap
    tf_range: tuple[float, float]

    @classmethod
    def of(cls, s: BoundarySettings, profile: ProfileMap) -> DesignSpace:
        """A boundary campaign's space: its values, scenes and TF range, over ``profile``."""
        return cls(s.grid_values(), s.scene_list(), profile, s.tf_bounds())


def sample_runs(
    fit: CrossingFit,
    rng: np.random.Generator,
    size: int,
    scenes: Sequence[str],
    profile: ProfileMap,
    tf_range: tuple[float, float],
    used: dict[str, int],
) -> list[tuple[str, float]]:
    """``size`` (scene, TF) drawn where ``fit``'s crossing plausibly is (see the module);
    ``used`` counts each scene's runs so far (updated)."""
    out = []
    lo, hi = tf_range
    for dps in fit.sample(rng, size):
        reach = {s: (profile.to_dps(s, lo), profile.to_dps(s, hi)) for s in scenes}
        fits = [s for s in scenes if reach[s][0] <= dps <= reach[s][1]]
        if not fits:  # no scene's range reaches it: the scene whose end is nearest
            fits = [min(scenes, key=lambda s: min(abs(dps - reach[s][0]), abs(dps - reach[s][1])))]
        scene = min(fits, key=lambda s: (used[s], scenes.index(s)))
        used[scene] += 1
        tf = float(np.clip(profile.to_tf(scene, dps), lo, hi))
        out.append((scene, round(tf, 2)))
    return out


def _place(
    placed: list[dict[str, Any]],
    profile: ProfileMap,
    value: float,
    scene: str,
    tf: float,
    first_seed: int,
    batch: int,
) -> None:
    """Add to the batch ``placed`` a run of ``value`` on ``scene`` at ``tf`` Hz, seeded after
    ``first_seed`` (the value's next seed before this batch) and the value's runs placed so far
    in this batch, with its complexity on that scene's profile."""
    seed = first_seed + sum(p["value"] == value for p in placed)
    placed.append({"value": value, "scene": scene, "tf_hz": tf, "seed": seed, "batch": batch,
                   "complexity_dps": float(profile.to_dps(scene, tf))})  # fmt: skip


def _settled(fit: CrossingFit, precision_dps: float) -> bool:
    """Whether a fit needs no more runs: the boundary lies outside the range, or within it
    to ``precision_dps`` (the 95 % interval's width)."""
    return fit.state in ("beyond", "below") or (fit.state == "within" and fit.width < precision_dps)


def design_runs(
    space: DesignSpace,
    run_batch: Callable[[list[dict[str, Any]]], list[dict[str, Any]]],
    design: DesignSettings,
    *,
    log: Callable[[str], None] = lambda _m: None,
) -> tuple[list[dict[str, Any]], dict[float, CrossingFit]]:
    """The adaptive loop (see the module). ``run_batch`` gets the batch's runs (value, scene,
    tf_hz, seed, batch, complexity_dps) and returns one row per run with those keys and the
    run's ``avoidances`` and ``crashes``. Returns every row and the last fit per value."""
    target, budget, precision_dps, batch, seed = dataclasses.astuple(design)  # field order
    values, scenes, profile, tf_range = space.values, space.scenes, space.profile, space.tf_range
    rng = np.random.default_rng(seed)
    lo, hi = tf_range
    domain = (
        min(profile.to_dps(s, lo) for s in scenes),
        max(profile.to_dps(s, hi) for s in scenes),
    )
    rows: dict[float, list[dict[str, Any]]] = {v: [] for v in values}
    used = {v: dict.fromkeys(scenes, 0) for v in values}
    fits: dict[float, CrossingFit] = {}
    active = list(values)
    round_no = 0
    while active:
        placed = []
        for v in active:
            if round_no == 0:
                n_first = min(FIRST_BATCH, budget)
                tfs = np.linspace(lo, hi, n_first)
                where = [(scenes[i % len(scenes)], round(float(t), 2)) for i, t in enumerate(tfs)]
                for sc, _ in where:
                    used[v][sc] += 1
            else:
                size = min(batch, budget - len(rows[v]))
                where = sample_runs(fits[v], rng, size, scenes, profile, tf_range, used[v])
            for scene, tf in where:
                _place(placed, profile, v, scene, tf, seed + len(rows[v]), round_no)
        for r in run_batch(placed):
            rows[r["value"]].append(r)
        still = []
        for v in active:
            g = rows[v]
            k = [r["avoidances"] for r in g]
            n = [r["avoidances"] + r["crashes"] for r in g]
            x = [r["complexity_dps"] for r in g]
            fits[v] = fit_crossing(x, k, n, target, domain, scene=[r["scene"] for r in g])
            f = fits[v]
            log(
                f"  value {v:g}, batch {round_no}: {len(g)} run(s), boundary {f.boundary:.1f} "
                f"deg/s, 95 % [{f.low:.1f}, {f.high:.1f}] ({f.state})."
            )
            if not _settled(f, precision_dps) and len(g) < budget:
                still.append(v)
        active = still
        round_no += 1
    return [r for v in values for r in rows[v]], fits


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
                _place(placed, profile, v, sc, tf, seed + n_value, round_no)
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
            if not _settled(f, precision_dps) and len(g) < cap(key[0]):
                still.append(key)
        for key in active:
            if key not in still:  # settled or spent: its unspent runs go to its value's others
                spare[key[0]] += max(0, cap(key[0]) - len(rows[key]))
        active = still
        round_no += 1
    return [r for key in keys for r in rows[key]], fits


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
