"""The arena's predictor table (:mod:`analysis.predictors.statistics`): the measures of an arena
grid's profiling runs against its conditions' failure rates, over the wall scenes the
conditions share (or the conditions, where all share one)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import polars as pl

from analysis.predictors.held_out import loco_interval, loco_threshold
from analysis.predictors.inference import (
    BOOTSTRAP,
    cluster_draws,
    hierarchical_means,
    permutation_p,
    rho_difference,
    rho_interval,
    rho_p_clustered,
    spearman_masked,
    spearman_rows,
)
from analysis.predictors.statistics import (
    AVDMS,
    _combined_rows,
    _role,
    _row,
    _table,
    finite_spearman,
    measures_present,
)
from analysis.predictors.verdicts import Units, units_of


def _padded(parts: Sequence[np.ndarray]) -> np.ndarray:
    """Per-condition arrays (S_c, ...) stacked into (C, max S_c, ...), NaN-padded."""
    s_max = max(len(p) for p in parts)
    out = np.full((len(parts), s_max, *parts[0].shape[1:]), np.nan)
    for i, p in enumerate(parts):
        out[i, : len(p)] = p
    return out


def arena_predictors(
    runs: pl.DataFrame,
    measures: pl.DataFrame,
    param: str,
    target: float,
    *,
    seed: int = 0,
) -> pl.DataFrame:
    """The predictor table of an arena grid; its units are the scenes (the wall textures its
    conditions share), or the conditions where all share one scene.

    ``runs``: one row per closed-loop run (condition, ``param``, seed, avoidances, crashes);
    ``measures``: one row per profiling run (condition, seed, one column per measure in
    :data:`MEASURES`, and ``scene``: the condition's wall scene). A condition's success is the
    mean of its seeds' shares (as ``boundary`` computes it); its measure the mean over its
    profiling runs. With 2 or more scenes, ρ's interval and p are over the scenes
    (:func:`~analysis.predictors.inference.cluster_draws`: scenes resampled with all their
    conditions, t on scenes − 1 degrees of freedom); with one, over the conditions (the
    hierarchical bootstrap, conditions then seeds; the exact permutation p). Returns
    :data:`PREDICTOR_COLUMNS`."""
    names = measures_present(measures.columns)
    rng = np.random.default_rng(seed)
    rows: list[dict[str, Any]] = []
    conds = [c for c in measures["condition"].unique(maintain_order=True)]
    mtab = {
        c: measures.filter(pl.col("condition") == c).select(names).to_numpy().astype(float)
        for c in conds
    }
    scene_of = (
        dict(measures.select("condition", "scene").unique("condition").iter_rows())
        if "scene" in measures.columns
        else None
    )
    for (value,), g in runs.group_by(param, maintain_order=True):
        shares, used = [], []
        for c in conds:
            r = g.filter(pl.col("condition") == c)
            n = (r["avoidances"] + r["crashes"]).to_numpy()
            k = r["avoidances"].to_numpy()
            if (n > 0).any() and len(mtab[c]):
                shares.append(k[n > 0] / n[n > 0])
                used.append(c)
        if len(used) < 3:
            continue
        m = len(used)
        units = units_of(None if scene_of is None else [scene_of[c] for c in used], "conditions", m)
        succ0 = np.array([s.mean() for s in shares])
        meas0 = np.array([np.nanmean(mtab[c], 0) for c in used])
        fails = succ0 < target
        counts = (int(fails.sum()), int((~fails).sum()))
        per_seed = (_padded(shares), _padded([mtab[c] for c in used]))
        rows += rho_rows(names, meas0, 1 - succ0, units, value, counts, rng, per_seed)
        for j, name in enumerate(names):
            x = meas0[:, j]
            ok = np.isfinite(x)
            # leave-one-condition-out needs >= 2 failing and >= 2 passing conditions: with
            # one, the held-out failing condition leaves no failure to fit a threshold on,
            # and a perfect predictor would score 0.5
            enough = min(int(fails[ok].sum()), int((~fails[ok]).sum())) >= 2
            loco = loco_threshold(x, fails) if enough else math.nan
            loco_ci = (
                loco_interval(x, fails, rng, cluster=units.cluster)
                if enough
                else (math.nan, math.nan)
            )
            rows.append(
                _row(
                    name,
                    value,
                    "loco_balanced_accuracy",
                    loco,
                    *loco_ci,
                    int(ok.sum()),
                    units,
                    units.n_units(ok),
                    *counts,
                )
            )
        unit_table = pl.DataFrame(meas0, schema=names, orient="row")
        rows += _combined_rows(unit_table, 1 - succ0, value, units, counts)
    return _table(rows, "arena")


def rho_rows(
    names: list[str],
    meas: np.ndarray,
    fail: np.ndarray,
    units: Units,
    value: float,
    counts: tuple[int, int],
    rng: np.random.Generator,
    per_seed: tuple[np.ndarray, np.ndarray] | None = None,
) -> list[dict[str, Any]]:
    """The ``rho_failure`` rows of each measure (``meas`` (C, M), the conditions' means) with
    the failure rate ``fail`` (C,), and the paired rows of each AVDM against the others.

    Clustered ``units`` (scenes): one cluster bootstrap (:func:`~analysis.predictors.inference.
    cluster_draws`, the same draws for every measure), ρ's interval and one-sided p on t with
    scenes − 1 degrees of freedom, the paired difference's from the same draws. Independent
    conditions: the hierarchical bootstrap of ``per_seed`` (the conditions' per-seed success
    shares and measures, NaN-padded), the exact permutation p."""
    rows: list[dict[str, Any]] = []
    m = len(fail)
    k_cl = units.clusters
    if units.cluster is not None:
        draws = cluster_draws(units.cluster, rng, BOOTSTRAP)
        fail_b = np.where(draws >= 0, fail[np.maximum(draws, 0)], np.nan)
    elif per_seed is not None:
        succ_b, drawn = hierarchical_means(per_seed[0], rng, BOOTSTRAP)
        meas_b, _ = hierarchical_means(per_seed[1], rng, BOOTSTRAP, drawn)
    rho: dict[str, float] = {}
    ci: dict[str, tuple[float, float]] = {}
    boots: dict[str, np.ndarray | None] = {}
    for j, name in enumerate(names):
        x = meas[:, j]
        ok = np.isfinite(x)
        boot = None
        if units.cluster is not None:
            r = finite_spearman(x, fail)
            p = math.nan
            if ok.all():
                xb = np.where(draws >= 0, x[np.maximum(draws, 0)], np.nan)
                boot = spearman_masked(xb, fail_b)
                p = rho_p_clustered(r, m, boot, units.n_units())
        else:
            r, p = permutation_p(x, fail, rng)
            if per_seed is not None and ok.all():
                xb = meas_b[:, :, j]
                fin = np.isfinite(xb).all(1)
                boot = spearman_rows(xb[fin], 1 - succ_b[fin])
        k_units = units.n_units(ok)
        rho[name] = r
        ci[name] = rho_interval(r, int(ok.sum()), boot, k_cl and k_units)
        boots[name] = boot
        rows.append(
            _row(
                name, value, "rho_failure", r, *ci[name], int(ok.sum()), units, k_units, *counts, p
            )
        )
    for ref in AVDMS:
        if ref not in rho:
            continue
        for j, name in enumerate(names):
            if name == ref or (name in AVDMS and names.index(name) < names.index(ref)):
                continue
            r12 = finite_spearman(meas[:, names.index(ref)], meas[:, j])
            b1, b2 = boots[ref], boots[name]
            pair = (b1, b2) if k_cl and b1 is not None and b2 is not None else None
            d, lo, hi, p = rho_difference(
                rho[ref], ci[ref], rho[name], ci[name], r12, m, pair, k_cl
            )
            stat = f"paired_rho_failure_vs_{ref}"
            rows.append(
                _row(
                    name,
                    value,
                    stat,
                    d,
                    lo,
                    hi,
                    m,
                    units,
                    units.n_units(),
                    *counts,
                    p,
                    _role(ref, name, stat),
                )
            )
    return rows
