"""The figure of ``vdc-analyse boundary``: success and the energy spent avoiding against
complexity, per parameter value, with the boundary (bracketed, or fitted with its band)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
from matplotlib.figure import Figure

from analysis.boundary.fit import draw_fit


def plot_boundary(
    conditions: pl.DataFrame,
    bounds: pl.DataFrame,
    by: str,
    target: float,
    path: Path,
    title: str,
    x_label: str = "complexity: AVDM response (deg/s)",
    energy: tuple[str, float, str] = (
        "avoidances_per_30min",
        1.0,
        "avoidances per 30 min (energy spent turning)",
    ),
    fits: dict[Any, Any] | None = None,
) -> Path:
    """Success (with the target and each curve's boundary) and the energy spent avoiding
    (avoidances per 30 min) against complexity, one curve per value of ``by``, 95 % intervals
    as error bars. ``fits`` keyed by value, or by (value, scene) for a fitted curve per scene
    (solid grating, dash-dot natural)."""
    fig = Figure(figsize=(13, 5), layout="constrained")
    ax_s, ax_e = fig.subplots(1, 2)
    for i, ((value,), g) in enumerate(conditions.group_by(by, maintain_order=True)):
        color = f"C{i % 10}"
        x = g["complexity_dps"].to_numpy()
        xerr = _err(x, g["complexity_low"], g["complexity_high"])
        for ax, name, scale in ((ax_s, "success", 100.0), (ax_e, energy[0], energy[1])):
            mean_col = "success_rate" if name == "success" else name
            y = g[mean_col].to_numpy() * scale
            yerr = _err(y, g[f"{name}_low"] * scale, g[f"{name}_high"] * scale)
            ax.errorbar(
                x,
                y,
                yerr=yerr,
                xerr=xerr,
                fmt="-",
                color=color,
                capsize=3,
                alpha=0.45,
                label=f"{by} = {value:g}",
            )
            for kind, marker in _MARKERS.items():  # the scene (or group) each point is
                on = np.array([str(c).startswith(kind) for c in g["condition"]])
                if on.any():
                    ax.plot(x[on], y[on], marker, color=color, ms=7)
        b = bounds.filter(pl.col(by) == value).row(0, named=True)
        per_scene = [k for k in (fits or {}) if isinstance(k, tuple) and k[0] == value]
        if per_scene:  # --per-scene: a curve per scene, keyed (value, scene)
            for key in per_scene:
                draw_fit(ax_s, fits[key], color, ls=_SCENE_LINES.get(key[1], "-"))
        elif fits is not None and value in fits:  # the fitted curve, its band and interval
            draw_fit(ax_s, fits[value], color)
        elif b["where"] == "within":
            ax_s.axvspan(b["boundary_low_dps"], b["boundary_high_dps"], color=color, alpha=0.08)
            ax_s.axvline(b["boundary_dps"], color=color, ls="--", lw=1)
    ax_s.axhline(100 * target, color="k", ls=":", lw=1, label=f"target {100 * target:g} %")
    for kind, marker in _MARKERS.items():  # which marker is which scene, in the legend
        if any(str(c).startswith(kind) for c in conditions["condition"]):
            per_scene_fit = any(isinstance(k, tuple) and k[1] == kind for k in (fits or {}))
            ls = _SCENE_LINES.get(kind, "-") if per_scene_fit else ""
            ax_s.plot([], [], marker=marker[0], ls=ls, color="0.35", label=kind)
    ax_s.set_ylabel("success (%)")
    ax_s.set_ylim(-2, 102)
    ax_s.set_title(
        "success: dashed = boundary, band = where it lies; o grating, ■ natural"
        if fits is None
        else "success: fitted curve, 95 % band; boundary dashed, its 95 % interval at the foot"
    )
    ax_e.set_ylabel(energy[2])
    ax_e.set_title(energy[2].split(" (")[0])
    for ax in (ax_s, ax_e):
        ax.set_xlabel(x_label)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        low, high = ax.get_xlim()
        if low < 0:  # complexity is a speed, ≥ 0: an interval reaching below 0 is cut there
            ax.set_xlim(0, high)
    fig.suptitle(title)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    return path


_MARKERS = {"grating": "o", "natural": "s", "group": "D"}
_SCENE_LINES = {"grating": "-", "natural": "-."}  # --per-scene: each scene's fitted curve


def _err(y: np.ndarray, low: Any, high: Any) -> np.ndarray | None:
    lo, hi = np.asarray(low, float), np.asarray(high, float)
    err = np.vstack([y - lo, hi - y])
    return np.nan_to_num(np.clip(err, 0, None)) if np.isfinite(err).any() else None
