"""The figures and page of ``vdc-analyse complexity``: a collection's clips ranked
(``complexity_collection.png``), one source's metrics over time (``complexity.png``) and the
self-contained ``complexity.html``."""

from __future__ import annotations

import base64
import html
import math
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
from matplotlib.figure import Figure

from analysis.complexity.meter import METRICS
from analysis.complexity.source_metrics import CLIP_FORMAT_COLUMNS, metrics_present
from analysis.profile import correlation_panel, save_figure
from vdc.recording import COMPLEXITY_UNITS

_LABELS = {
    "omega_dps": "AVDM ω̂ (deg/s)",
    "ti_p910": "TI, P.910 (2022)",
    "si_p910": "SI, P.910 (2022)",
    "flow_dps": "DIS flow (deg/s)",
}
# what the collection figure and the report rank clips by, the first measured
_RANK_ORDER = ("omega_dps", "ti_p910", "si_p910", "flow_dps", *METRICS)


def ranking(clips: pl.DataFrame) -> list[str]:
    """The measured metrics in the order the figure and the report rank clips by."""
    have = metrics_present(clips, "_mean")
    return list(dict.fromkeys(m for m in _RANK_ORDER if m in have))


def plot_collection(clips: pl.DataFrame, path: Path) -> Path:
    """The collection at a glance: clips ranked by their mean AVDM response and by their mean
    TI (P.910), and each clip's mean AVDM against its mean TI and SI."""

    n = clips.height
    fig = Figure(figsize=(14, 6 + 0.15 * min(n, 60)), layout="constrained")
    axes = fig.subplots(2, 2)
    names = clips["recording_id"].to_list()
    rank = ranking(clips)
    first, second = rank[0], rank[1 % len(rank)]
    x_a, x_b = (rank[1:] + rank[:1] * 2)[:2]
    for ax, col, what in (
        (axes[0, 0], f"{first}_mean", f"mean {_LABELS.get(first, first)}"),
        (axes[0, 1], f"{second}_mean", f"mean {_LABELS.get(second, second)}"),
    ):
        v = clips[col].fill_null(np.nan).to_numpy()
        order = np.argsort(np.nan_to_num(v, nan=-np.inf))[-60:]  # the 60 highest
        ax.barh(range(len(order)), v[order], color="tab:blue" if "omega" in col else "tab:orange")
        ax.set_yticks(range(len(order)), [names[i] for i in order], fontsize=7)
        ax.set_xlabel(what)
        ax.set_title(f"clips ranked by {what}" + (f" (top 60 of {n})" if n > 60 else ""))
        ax.grid(axis="x", alpha=0.3)
    omega = clips[f"{first}_mean"].fill_null(np.nan).to_numpy()
    for ax, col, what in (
        (axes[1, 0], f"{x_a}_mean", f"mean {_LABELS.get(x_a, x_a)}"),
        (axes[1, 1], f"{x_b}_mean", f"mean {_LABELS.get(x_b, x_b)}"),
    ):
        x = clips[col].fill_null(np.nan).to_numpy()
        ax.scatter(x, omega, s=25)
        for xi, yi, name in zip(x, omega, names, strict=True):
            if n <= 40:
                ax.annotate(name, (xi, yi), fontsize=6, xytext=(3, 2), textcoords="offset points")
        ax.set_xlabel(what)
        ax.set_ylabel(f"mean {_LABELS.get(first, first)}")
        ax.set_title(
            f"{_LABELS.get(first, first).split(' (')[0].split(',')[0]} against "
            f"{what.split(',')[0].replace('mean ', '')} ({n} clips)"
        )
        ax.grid(alpha=0.3)
    fig.suptitle("complexity of the collection: one point or bar per clip, its mean over frames")
    return save_figure(fig, path)


def write_summary_html(
    clips: pl.DataFrame, failures: list[tuple[str, str]], path: Path, figure: Path
) -> Path:
    """A self-contained page: ``figure`` (the collection's, or one clip's over time), then the
    clip table (means and maxima)."""
    cols = [
        "recording_id",
        *CLIP_FORMAT_COLUMNS,
        "raster",
        "omega_dps_mean",
        "omega_dps_max",
        "si_p910_mean",
        "si_p910_max",
        "ti_p910_mean",
        "ti_p910_max",
        "flow_dps_mean",
        "jpeg_bpp_mean",
        "codec_bpp_mean",
    ]

    cols = [c for c in cols if c in clips.columns]

    def cell(v: Any) -> str:
        if isinstance(v, float):
            return "-" if not math.isfinite(v) else f"{v:.4g}"
        return html.escape("-" if v is None else str(v))

    head = "".join(f"<th>{html.escape(c)}</th>" for c in cols)
    rows = "".join(
        "<tr>" + "".join(f"<td>{cell(r.get(c))}</td>" for c in cols) + "</tr>"
        for r in clips.iter_rows(named=True)
    )
    failed = "".join(f"<li>{html.escape(s)}: {html.escape(e)}</li>" for s, e in failures)
    one = clips.height == 1
    heading = (
        f"Complexity of {clips['recording_id'][0]}"
        if one
        else (f"Complexity of {clips.height} clips")
    )
    shown = (
        "The clip over time: each metric in its own unit, and how they correlate over frames."
        if one
        else "The collection: clips ranked by their mean, and the AVDM against the others."
    )
    img = base64.b64encode(figure.read_bytes()).decode()
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>vdc complexity</title>
<style>body{{font-family:sans-serif;margin:2em}}table{{border-collapse:collapse;font-size:12px}}
td,th{{border:1px solid #ccc;padding:3px 6px;text-align:right}}</style></head><body>
<h1>{html.escape(heading)}</h1>
<p>{shown}</p>
<p>Per clip, the mean and max over its frames. SI/TI follow ITU-T P.910 (2022) on the
source's native frames (column raster); the AVDM and the flow are in deg/s on the model
raster. Per-frame values: complexity.parquet; every statistic: clips.parquet.</p>
<img src="data:image/png;base64,{img}" style="max-width:100%">
<h2>Clips</h2><table><tr>{head}</tr>{rows}</table>
{f"<h2>Failed</h2><ul>{failed}</ul>" if failures else ""}</body></html>"""
    path.write_text(page, encoding="utf-8")
    return path


def plot_complexity(df: pl.DataFrame, corr: pl.DataFrame, path: Path) -> Path:
    """One source over time: a panel per metric in its own unit (on a shared time axis), and
    the Spearman correlations of every pair over frames."""
    t = df["t_s"].to_numpy()
    metrics = metrics_present(df)
    fig = Figure(figsize=(16, max(5.5, 1.3 * len(metrics) + 1)), layout="constrained")
    grid = fig.add_gridspec(len(metrics), 2, width_ratios=[2.2, 1])
    first = None
    for k, m in enumerate(metrics):
        ax = fig.add_subplot(grid[k, 0], sharex=first)
        first = first or ax
        v = df[m].cast(pl.Float64).fill_null(np.nan).to_numpy()
        ax.plot(t, v, lw=1.2 if m == "omega_dps" else 0.9, color=f"C{k % 10}")
        ax.set_ylabel(f"{m}\n({COMPLEXITY_UNITS.get(m, '')})", fontsize=7)
        ax.tick_params(labelsize=7)
        if np.isfinite(v).any() and np.nanmin(v) >= 0:
            ax.set_ylim(bottom=0)  # every metric is ≥ 0: no axis below its range
        ax.grid(alpha=0.3)
        if k < len(metrics) - 1:
            ax.tick_params(labelbottom=False)
        else:
            ax.set_xlabel("time (s)")
    if first is not None:
        first.set_title("each metric over time, in its own unit")
        if len(t) > 1:
            first.set_xlim(float(np.nanmin(t)), float(np.nanmax(t)))  # the clip, no margin
    axc = fig.add_subplot(grid[:, 1])
    pairs = ((r["metric_a"], r["metric_b"], r["spearman"]) for r in corr.iter_rows(named=True))
    correlation_panel(fig, axc, metrics, pairs, "Spearman rank correlation over frames", fontsize=6)
    fig.suptitle(str(df["recording_id"][0]))
    return save_figure(fig, path)
