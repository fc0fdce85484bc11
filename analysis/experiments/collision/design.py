"""The adaptive design's loop (``vdc-analyse boundary --design adaptive``, the method in
``analysis.experiments.collision.adaptive``): where a batch's runs go and when a value stops.

:func:`design_runs` is the loop alone, with the runs made by a function it is given: the
benchmark's coverage check drives it with simulated detectors of known boundary.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import polars as pl

from analysis.boundary.fit import CrossingFit, dps_to_tf, fit_crossing, tf_to_dps
from analysis.boundary.settings import BoundarySettings

FIRST_BATCH = 4


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
    """``size`` (scene, TF) drawn where ``fit``'s crossing plausibly is (the method:
    ``analysis.experiments.collision.adaptive``);
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


def place_run(
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
    placed.append(
        {
            "value": value,
            "scene": scene,
            "tf_hz": tf,
            "seed": seed,
            "batch": batch,
            "complexity_dps": float(profile.to_dps(scene, tf)),
        }
    )


def is_settled(fit: CrossingFit, precision_dps: float) -> bool:
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
    """The adaptive loop (``analysis.experiments.collision.adaptive``). ``run_batch`` gets the
    batch's runs (value, scene, tf_hz, seed, batch, complexity_dps) and returns one row per run
    with those keys and the run's ``avoidances`` and ``crashes``. Returns every row and the last
    fit per value."""
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
                place_run(placed, profile, v, scene, tf, seed + len(rows[v]), round_no)
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
            if not is_settled(f, precision_dps) and len(g) < budget:
                still.append(v)
        active = still
        round_no += 1
    return [r for v in values for r in rows[v]], fits
