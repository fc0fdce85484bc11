"""The power study's units and where each measure fails to rank them, scene by scene (for
:mod:`analysis.experiments.power.answer`).

* :func:`arena_units` / :func:`footage_units`: one row per condition (arena) or clip
  (footage), with its scene, failure and each measure;
* :func:`per_scene` / :func:`plot_per_scene` (exploratory: a post hoc reading, no interval, no
  test): per scene, over the pairs of units whose failure differs, the **discordant share**
  (:func:`discordant_share`): the share the measure orders against the failure (a higher
  measure, less failure; ties half). 0: it ranks the scene's units perfectly; 0.5: no better
  than chance; 1: inverted. :data:`ACROSS` takes the pairs whose units lie in different
  scenes;
* :func:`icc_oneway`: the share of the failure's variance the scenes set.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import polars as pl
from matplotlib.figure import Figure

from analysis.boundary.statistics import WARMUP_FRAMES
from analysis.predictors.report import label, settings_meta
from analysis.predictors.statistics import MEASURES

ACROSS = "across scenes"


def discordant_share(x: np.ndarray, fail: np.ndarray, group: np.ndarray | None = None) -> float:
    """Over the pairs of units whose failure differs (``group`` given: only pairs in different
    groups), the share the measure ``x`` (N,) orders against the failure ``fail`` (N,) (a
    higher measure with less failure), ties in ``x`` counting half; NaN without such a pair."""
    x, fail = np.asarray(x, float), np.asarray(fail, float)
    ok = np.isfinite(x) & np.isfinite(fail)
    x, fail = x[ok], fail[ok]
    dx = np.sign(x[:, None] - x[None, :])
    df = np.sign(fail[:, None] - fail[None, :])
    use = np.triu(df != 0, 1)
    if group is not None:
        g = np.asarray(group)[ok]
        use &= g[:, None] != g[None, :]
    if not use.any():
        return math.nan
    d = dx[use] * df[use]
    return float(((d < 0) + 0.5 * (d == 0)).mean())


def icc_oneway(values: np.ndarray, groups: np.ndarray) -> float:
    """The share of ``values``' variance its ``groups`` (scenes) set: ICC(1) of a one-way
    ANOVA (Donner & Klar 2000, with n0 for unequal groups); NaN with fewer than 2 groups or
    nothing within them. It may come out below 0 by chance (reported as it is)."""
    x, g = np.asarray(values, float), np.asarray(groups)
    ok = np.isfinite(x)
    x, g = x[ok], g[ok]
    names, idx, n_g = np.unique(g, return_inverse=True, return_counts=True)
    k, n = len(names), len(x)
    if k < 2 or n - k < 1:
        return math.nan
    means = np.bincount(idx, x) / n_g
    msb = float((n_g * (means - x.mean()) ** 2).sum() / (k - 1))
    msw = float(((x - means[idx]) ** 2).sum() / (n - k))
    n0 = (n - (n_g**2).sum() / n) / (k - 1)
    denom = msb + (n0 - 1) * msw
    return math.nan if denom <= 0 else (msb - msw) / denom


def arena_units(folder: Path) -> pl.DataFrame:
    """One row per condition of an arena study: scene, failure (1 − the mean of its seeds'
    success shares, as the predictors take it), ``failing`` (its success below the study's
    target, as the predictors count it) and each measure's mean over its profiling runs."""
    target = settings_meta(folder).get("target", 0.9)
    runs = pl.read_parquet(folder / "boundary_runs.parquet")
    measures = pl.read_parquet(folder / "predictor_measures.parquet")
    names = [m for m in MEASURES if m in measures.columns]
    events = pl.col("avoidances") + pl.col("crashes")
    fail = (
        runs.filter(events > 0)
        .group_by("condition")
        .agg((1 - (pl.col("avoidances") / events).mean()).alias("failure"))
    )
    means = measures.group_by("condition", "scene").agg(pl.col(names).mean())
    units = means.join(fail, on="condition", how="inner").sort("condition")
    return units.with_columns((1 - pl.col("failure") < target).alias("failing"))


def footage_units(folder: Path, labels: pl.DataFrame) -> pl.DataFrame:
    """One row per clip of a footage study: its background photograph as the scene, failure
    (1: the detector got it wrong) and each measure's mean over the scene's frames
    (``omega_dps`` is avdm-natural there)."""
    clips = pl.read_parquet(folder / "boundary_clips.parquet").rename({"omega_dps": "avdm_natural"})
    scene = pl.col("scene") if "scene" in labels.columns else pl.col("background").alias("scene")
    bg = labels.select("clip", scene, "hazard_onset_frame")
    clips = clips.join(bg, on="clip", how="left").join(
        paper_avdm(folder, bg), on="clip", how="left"
    )
    names = [m for m in MEASURES if m in clips.columns]
    return clips.select(
        "clip",
        "scene",
        (~pl.col("correct")).cast(pl.Float64).alias("failure"),
        (~pl.col("correct")).alias("failing"),
        *names,
    )


def paper_avdm(folder: Path, onsets: pl.DataFrame) -> pl.DataFrame:
    """Per clip, the paper's AVDM (``avdm``) as the footage predictors take it: its mean over
    the frames before the hazard's onset (all of them where the object never comes into view),
    the model's start-up left out where frames after it remain."""
    frames = (
        pl.read_parquet(folder / "predictor_frames.parquet")
        .select("clip", "frame", "avdm")
        .unique(["clip", "frame"])
        .join(onsets.select("clip", "hazard_onset_frame"), on="clip", how="left")
        .filter(
            pl.col("hazard_onset_frame").is_null()
            | (pl.col("frame") < pl.col("hazard_onset_frame"))
        )
    )
    after = (pl.col("frame") >= WARMUP_FRAMES).any().over("clip")
    kept = frames.filter(~after | (pl.col("frame") >= WARMUP_FRAMES))
    return kept.group_by("clip").agg(pl.col("avdm").fill_nan(None).mean())


def per_scene(units: pl.DataFrame) -> pl.DataFrame:
    """Per measure and scene (and :data:`ACROSS`), the discordant share
    (:func:`discordant_share`) with the units it is over: ``n``, ``n_failing`` and ``n_correct``
    (as the predictors count them). Exploratory: no interval."""
    names = [m for m in MEASURES if m in units.columns]
    scenes = units["scene"].unique(maintain_order=True).to_list()
    rows = []
    for m in names:
        for sc in [*scenes, ACROSS]:
            part = units if sc == ACROSS else units.filter(pl.col("scene") == sc)
            f = part["failure"].to_numpy()
            group = part["scene"].to_numpy() if sc == ACROSS else None
            rows.append(
                {
                    "measure": m,
                    "scene": sc,
                    "n": part.height,
                    "n_failing": int(part["failing"].sum()),
                    "n_correct": int((~part["failing"]).sum()),
                    "discordant_share": discordant_share(part[m].to_numpy(), f, group),
                }
            )
    return pl.DataFrame(rows)


def plot_scene_table(scenes: pl.DataFrame, path: Path, quick: bool) -> Path:
    """:func:`plot_per_scene` from the per-scene table (``per_scene.parquet``): a heat map per
    study (``source``, ``detector``), in the table's order."""
    tables = (
        {}
        if scenes.is_empty()
        else {
            f"{src}: {det}": t.drop("source", "detector")
            for (src, det), t in scenes.group_by(["source", "detector"], maintain_order=True)
        }
    )
    return plot_per_scene(tables, path, quick)


def plot_per_scene(tables: dict[str, pl.DataFrame], path: Path, quick: bool) -> Path:
    """One heat map per study: measures down, scenes across, the discordant share in each cell
    (green 0: ranks perfectly; yellow 0.5: chance; red 1: inverted; grey: no pair to rank)."""
    n = max(1, len(tables))
    widest = max((t["scene"].n_unique() for t in tables.values()), default=1)
    # many scenes: a study a row, as wide as its scenes need, the values left to the colour
    # (their numbers are in per_scene.parquet); few: up to three studies side by side
    cols = 1 if widest > 8 else min(n, 3)
    width = 4.0 + 0.45 * widest if cols == 1 else 6.2 * cols
    fig = Figure(figsize=(width, 5.2 * math.ceil(n / cols)), layout="constrained")
    axes = np.atleast_1d(fig.subplots(math.ceil(n / cols), cols)).ravel()
    image = None
    for ax, (title, t) in zip(axes, tables.items(), strict=False):
        measures = t["measure"].unique(maintain_order=True).to_list()
        scenes = t["scene"].unique(maintain_order=True).to_list()
        grid = np.full((len(measures), len(scenes)), np.nan)
        for r in t.iter_rows(named=True):
            grid[measures.index(r["measure"]), scenes.index(r["scene"])] = r["discordant_share"]
        ax.set_facecolor("0.85")
        image = ax.imshow(grid, cmap="RdYlGn_r", vmin=0, vmax=1, aspect="auto")
        for (i, j), v in np.ndenumerate(grid if len(scenes) <= 12 else np.empty((0, 0))):
            ax.text(j, i, "–" if np.isnan(v) else f"{v:.2f}", ha="center", va="center", size=7)
        sizes = dict(zip(t["scene"], t["n"], strict=True))  # the units each column rests on
        ticks = [f"{sc} (n {sizes[sc]})" for sc in scenes]
        ax.set_xticks(range(len(scenes)), ticks, rotation=40, ha="right", size=8)
        ax.set_yticks(range(len(measures)), [label(m) for m in measures], size=8)
        ax.axvline(len(scenes) - 1.5, color="k", lw=1)  # the across-scenes column apart
        ax.set_title(title, size=10)
    for ax in axes[len(tables) :]:
        ax.set_axis_off()
    if image is not None:
        bar = fig.colorbar(image, ax=axes.tolist(), shrink=0.6)
        bar.set_label("discordant share: 0 ranks the scene's units, 0.5 chance, 1 inverted")
    head = "QUICK RUN (--quick): not findings. " if quick else ""
    fig.suptitle(
        f"{head}Exploratory (post hoc, no interval): where each measure fails to rank the "
        "conditions (arena) or clips (footage), scene by scene",
        color="C3" if quick else "k",
    )
    fig.savefig(path, dpi=110)
    return path
