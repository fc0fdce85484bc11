"""The reproduction's own figures (the others are drawn by the experiments that make them)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import polars as pl
from matplotlib.figure import Figure

from analysis.experiments.paper.claims import (
    CALIBRATED,
    RELEASED,
    bounds_of,
    estimates,
    per_seed,
    tf_columns,
)
from analysis.stats import (
    mean_ci,
)


def plot_fig6_seeds(tables: dict[str, pl.DataFrame], warmup: int, path: Path) -> Path:
    """Fig. 6 with its spread across seeds (grating): the share of frames over 100 and the mean
    response per wall TF, each reading as mean ± 95 % interval with every seed as a dot; and
    the histograms of responses over 100 in the released code's units, for all frames and for
    straight driving, as the mean share per bin with a shaded 95 % band."""

    summary = tables["summary"]
    fig = Figure(figsize=(15, 10), layout="constrained")
    axes = fig.subplots(2, 2)
    ax_frac, ax_mean, ax_all, ax_straight = axes.ravel()

    def errorbars(ax, model: str, motion: str, metric: str, scale: float, dx: float, label: str):
        t = per_seed(summary, "grating", model, motion, metric)
        if t.height == 0:
            return
        x = np.arange(len(tf_columns(t))) + dx
        est = estimates(t, bounds_of(metric))
        mean = np.array([e.mean for e in est]) * scale
        low = np.array([e.low if math.isfinite(e.low) else e.mean for e in est]) * scale
        high = np.array([e.high if math.isfinite(e.high) else e.mean for e in est]) * scale
        line = ax.errorbar(
            x, mean, yerr=[mean - low, high - mean], fmt="o-", capsize=4, label=label
        )
        for i, c in enumerate(c for c in t.columns if c != "seed"):
            v = t[c].to_numpy() * scale
            ax.scatter(np.full(len(v), x[i]), v, s=12, color=line[0].get_color(), alpha=0.5)
        ax.set_xticks(np.arange(len(tf_columns(t))), [f"TF {tf:g} Hz" for tf in tf_columns(t)])

    errorbars(ax_frac, RELEASED, "all", "frac_over_100", 100, -0.1, f"{RELEASED}, all frames")
    errorbars(ax_frac, CALIBRATED, "all", "frac_over_100", 100, 0.0, "calibrated deg/s, all frames")
    errorbars(
        ax_frac, CALIBRATED, "straight", "frac_over_100", 100, 0.1, "calibrated, straight driving"
    )
    ax_frac.set_ylabel("% of frames with response > 100")
    ax_frac.set_title("'AVDM > 100' per wall TF: mean, 95 % interval, seeds as dots")
    errorbars(ax_mean, CALIBRATED, "all", "mean", 1, -0.05, "all frames")
    errorbars(ax_mean, CALIBRATED, "straight", "mean", 1, 0.05, "straight driving")
    ax_mean.set_ylabel("mean ω̂ (deg/s)")
    ax_mean.set_title("calibrated response per wall TF")
    for ax in (ax_frac, ax_mean):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)

    rows = (
        tables["model_outputs"]
        .filter((pl.col("model") == RELEASED) & (pl.col("frame") >= warmup))
        .select("recording_id", "frame", "omega_dps")
        .join(
            tables["frames"].select("recording_id", "frame", "turning"),
            on=["recording_id", "frame"],
        )
        .join(
            summary.filter((pl.col("model") == RELEASED) & (pl.col("motion") == "all")).select(
                "recording_id", "scene", "seed", "wall_tf_hz"
            ),
            on="recording_id",
        )
        .filter(pl.col("scene") == "grating")
    )
    over = rows.filter(pl.col("omega_dps") > 100)["omega_dps"]
    top = float(np.percentile(over.to_numpy(), 99)) if over.len() else 200.0
    edges = np.linspace(100.0, max(top, 150.0), 31)
    for ax, straight in ((ax_all, False), (ax_straight, True)):
        sel = rows.filter(pl.col("turning").not_()) if straight else rows
        for i, ((tf,), g) in enumerate(
            sel.sort("wall_tf_hz").group_by("wall_tf_hz", maintain_order=True)
        ):
            shares = []
            for (_seed,), gs in g.group_by("seed"):
                counts, _ = np.histogram(gs["omega_dps"].to_numpy(), bins=edges)
                shares.append(100.0 * counts / max(1, gs.height))
            per_bin = [mean_ci(col) for col in np.array(shares).T]
            mean = np.array([e.mean for e in per_bin])
            low = np.array([e.low if math.isfinite(e.low) else e.mean for e in per_bin])
            high = np.array([e.high if math.isfinite(e.high) else e.mean for e in per_bin])
            centres = (edges[:-1] + edges[1:]) / 2
            ax.plot(centres, mean, color=f"C{i}", label=f"TF {tf:g} Hz ({len(shares)} seeds)")
            ax.fill_between(centres, np.clip(low, 0, None), high, color=f"C{i}", alpha=0.2)
        ax.set_xlabel(f"response in the released code's units ({RELEASED})")
        ax.set_ylabel("% of frames per bin")
        ax.set_title(
            "Fig. 6 histogram over 100, "
            + ("straight driving only" if straight else "all frames")
            + ": mean and 95 % band across seeds"
        )
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    return path
