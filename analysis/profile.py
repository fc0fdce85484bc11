"""Complexity profiles (paper Figs. 6–7): 3D circle profiles, "AVDM > 100" histograms and
top-down heat maps of the response, per recording segment or per condition.

A *segment* is the part of one recording under one wall TF (a TF schedule gives several); a
*condition* pools the segments of several recordings with the same scene, TF and model.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
from matplotlib.figure import Figure

from analysis.recordings.analysis_rrd import write_profile_rrd
from analysis.recordings.loading import Notices
from analysis.recordings.recompute import build_tables
from analysis.recordings.segments import (
    ProfileSegment,
    ProfileSettings,
    heat_map,
    histogram_over,
    over_share_by_recording,
    segment_summary,
    segments_from_tables,
)
from avdm.registry import VARIANTS, parse_model_spec
from vdc.parquet_io import WroteFiles, table_set, write_parquet


def _arena_outline(ax, hx: float, hy: float, z: float | None = None) -> None:
    xs = [-hx, hx, hx, -hx, -hx]
    ys = [-hy, -hy, hy, hy, -hy]
    if z is None:
        ax.plot(xs, ys, color="0.5", lw=1)
    else:
        ax.plot(xs, ys, [z] * 5, color="0.5", lw=1)


def save_figure(fig: Figure, path: Path) -> Path:
    """Write ``fig`` as a PNG (100 dpi) to ``path`` and close it."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    return path


def response_densities(
    ax: Any,
    series: Sequence[tuple[str, np.ndarray]],
    threshold_dps: float,
    title: str,
    fontsize: float = 8,
    unit: str = "",
) -> None:
    """Draw on the matplotlib axes ``ax`` the densities of response series ``(label, values
    (N,) in the model's unit)`` as step histograms on shared bins (up to their 99.5th
    percentile), log scale, the threshold dashed: the profile's and the comparison's panel.
    ``unit`` names the responses' unit(s) on the x axis (:func:`units_label`)."""
    finite = [v for _, v in series if len(v)]
    top = max([float(np.nanpercentile(v, 99.5)) for v in finite] + [1.0])
    bins = np.linspace(0, top, 60)
    for label, values in series:
        ax.hist(values, bins=bins, histtype="step", lw=1.2, label=label, density=True)
    ax.axvline(threshold_dps, color="k", ls="--", lw=1)
    ax.set_yscale("log")
    ax.set_xlabel(f"response ({unit})" if unit else "response")
    # density=True: the share of frames per 1 unit of response
    one = unit and ":" not in unit  # one unit for every series (units_label)
    ax.set_ylabel(f"density (per {unit})" if one else "density (per unit of response)")
    ax.legend(fontsize=fontsize)
    ax.set_title(title)


# a column's unit, from the suffix its name carries (names say their unit: omega_dps)
_SUFFIX_UNITS = {"_dps": "deg/s", "_hz": "Hz", "_px": "px", "_deg": "deg"}


def response_unit(model: str, output: str) -> str:
    """The unit of ``model``'s primary ``output`` as an axis shows it: the one its name
    carries, except an AVDM decoded as the released code does (a = 100, b = 1, no contrast
    term: ``avdm-released-units``), whose ``omega_dps`` keeps its name but is in relative
    units, the units the paper's "AVDM > 100" was set in."""
    name, overrides = parse_model_spec(model)
    variant = VARIANTS.get(name)
    decoding = {**(variant.overrides if variant is not None else {}), **overrides}
    if output == "omega_dps" and decoding.get("contrast_term") is False:
        return "relative units"
    return next((u for suffix, u in _SUFFIX_UNITS.items() if output.endswith(suffix)), "")


def units_label(segs: Sequence[ProfileSegment | tuple[str, str]]) -> str:
    """The unit of the responses of ``segs`` (profile segments, or ``(model, output)`` pairs)
    for an axis: one unit, or each with its models (``deg/s: avdm; relative units:
    avdm-released-units``) where they differ."""
    by_unit: dict[str, list[str]] = {}
    for g in segs:
        model, output = g if isinstance(g, tuple) else (g.model, g.output)
        models = by_unit.setdefault(response_unit(model, output) or "model units", [])
        if model not in models:
            models.append(model)
    if len(by_unit) == 1:
        return next(iter(by_unit))
    return "; ".join(f"{unit}: {', '.join(models)}" for unit, models in by_unit.items())


def correlation_panel(
    fig: Figure,
    ax: Any,
    names: Sequence[str],
    pairs: Iterable[tuple[str, str, float]],
    title: str,
    *,
    digits: int = 2,
    fontsize: float = 7,
    cmap: str = "RdBu_r",
) -> None:
    """Draw on ``ax`` the symmetric matrix of ``(name_a, name_b, r)`` correlations in [-1, 1]
    over ``names`` (1 on the diagonal), each cell labelled, with a colour bar on ``fig``: the
    comparison's and the complexity page's panel. A pair never given stays blank (NaN)."""
    n = len(names)
    mat = np.full((n, n), np.nan)
    np.fill_diagonal(mat, 1.0)
    for a, b, r in pairs:
        i, j = names.index(a), names.index(b)
        mat[i, j] = mat[j, i] = r
    im = ax.imshow(mat, vmin=-1, vmax=1, cmap=cmap)
    for i in range(n):
        for j in range(n):
            if np.isfinite(mat[i, j]):
                ax.text(
                    j, i, f"{mat[i, j]:.{digits}f}", ha="center", va="center", fontsize=fontsize
                )
    ax.set_xticks(range(n), names, rotation=40, ha="right", fontsize=fontsize + 1)
    ax.set_yticks(range(n), names, fontsize=fontsize + 1)
    ax.set_title(title)
    fig.colorbar(im, ax=ax, shrink=0.8)


def plot_segment(seg: ProfileSegment, s: ProfileSettings, path: Path) -> Path:
    """One PNG: 3D circle profile, histogram of responses over the threshold, heat map."""
    return save_figure(segment_figure(seg, s), path)


def segment_figure(seg: ProfileSegment, s: ProfileSettings) -> Figure:
    """The profile of one segment as a matplotlib Figure (for notebooks): 3D circle profile,
    histogram of responses over the threshold, heat map of the mean response."""
    if not np.isfinite(seg.x_m).any():
        return _time_series_figure(seg, s)
    fig = Figure(figsize=(16, 5.2), layout="constrained")
    ax3 = fig.add_subplot(1, 3, 1, projection="3d")
    step = max(1, math.ceil(len(seg.response) / s.max_points))
    r = seg.response[::step]
    ref = max(np.percentile(seg.response, 99) if len(seg.response) else 1.0, s.threshold_dps, 1e-9)
    t_min = seg.t_s[::step] / 60
    ax3.plot(seg.x_m[::step], seg.y_m[::step], t_min, color="0.75", lw=0.4)
    sc = ax3.scatter(
        seg.x_m[::step],
        seg.y_m[::step],
        t_min,
        s=2 + 80 * np.clip(r / ref, 0, 1),
        c=np.clip(r, 0, ref),
        cmap="viridis",
        alpha=0.6,
        linewidths=0,
    )
    hx, hy = seg.half_extent
    _arena_outline(ax3, hx, hy, float(t_min.min()) if len(t_min) else 0.0)
    ax3.set_xlabel("x (m)")
    ax3.set_ylabel("y (m)")
    ax3.set_zlabel("time (min)")
    ax3.set_box_aspect((2 * hx, 2 * hy, 1.2))
    ax3.set_title("circle profile: size ∝ response", fontsize=10)
    fig.colorbar(sc, ax=ax3, shrink=0.6, pad=0.12, label=f"{seg.output} ({units_label([seg])})")

    ax_h = fig.add_subplot(1, 3, 2)
    edges, counts = histogram_over(seg.response, s)
    frac = float((seg.response > s.threshold_dps).mean()) if len(seg.response) else 0.0
    ax_h.bar(
        edges[:-1], counts, width=np.diff(edges), align="edge", color="C1", edgecolor="k", lw=0.3
    )
    ax_h.set_xlabel(f"{seg.output} ({units_label([seg])}, bins of {s.bin_dps:g})")
    ax_h.set_ylabel("frames")
    ax_h.set_title(
        f"responses > {s.threshold_dps:g}: {counts.sum()} frames ({100 * frac:.1f} %)", fontsize=10
    )
    ax_h.grid(alpha=0.3)

    ax_m = fig.add_subplot(1, 3, 3)
    xe, ye, mean = heat_map(seg, s)
    im = ax_m.pcolormesh(xe, ye, mean, cmap="magma", shading="flat")
    _arena_outline(ax_m, hx, hy)
    ax_m.set_aspect("equal")
    ax_m.set_xlabel("x (m)")
    ax_m.set_ylabel("y (m)")
    near = seg.response[seg.gap_m <= s.near_wall_m]  # the summary's own split
    centre = seg.response[seg.gap_m > s.centre_m]
    ax_m.set_title(
        f"mean response per {100 * s.cell_m:g} cm cell\nwithin {s.near_wall_m:g} m of a wall "
        f"{near.mean() if len(near) else float('nan'):.1f}, beyond {s.centre_m:g} m "
        f"{centre.mean() if len(centre) else float('nan'):.1f}",
        fontsize=10,
    )
    fig.colorbar(im, ax=ax_m, shrink=0.8, label=f"mean {seg.output} ({units_label([seg])})")
    fig.suptitle(seg.label)
    return fig


def _condition(g: ProfileSegment) -> str:
    """``grating TF 3``; a video has neither scene nor walls."""
    if math.isfinite(g.wall_tf_hz):
        return f"{g.scene} TF {g.wall_tf_hz:g}"
    return "video"


def _time_series_figure(seg: ProfileSegment, s: ProfileSettings) -> Figure:
    """The profile of a source without poses (a video): the response over time and the
    histogram over the threshold; there is no arena to map it onto."""
    fig = Figure(figsize=(16, 5.2), layout="constrained")
    (ax_t, ax_h) = fig.subplots(1, 2, gridspec_kw={"width_ratios": [2, 1]})
    ax_t.plot(seg.t_s, seg.response, lw=0.8, color="C0")
    ax_t.axhline(s.threshold_dps, color="k", ls="--", lw=1, label=f"threshold {s.threshold_dps:g}")
    ax_t.set_xlabel("time (s)")
    ax_t.set_ylabel(f"{seg.output} ({units_label([seg])})")
    ax_t.set_title("response over time (no poses: a time series, not an arena map)")
    ax_t.legend(fontsize=8)
    ax_t.grid(alpha=0.3)
    edges, counts = histogram_over(seg.response, s)
    over = int(counts.sum())
    ax_h.bar(edges[:-1], counts, width=np.diff(edges), align="edge", color="C1", edgecolor="0.4")
    ax_h.set_xlabel(f"{seg.output} ({units_label([seg])}, bins of {s.bin_dps:g})")
    ax_h.set_ylabel("frames")
    share = 100 * over / max(1, len(seg.response))
    ax_h.set_title(f"responses > {s.threshold_dps:g}: {over} frames ({share:.1f} %)")
    fig.suptitle(seg.label)
    return fig


def plot_overview(segs: Sequence[ProfileSegment], s: ProfileSettings, path: Path) -> Path:
    """All segments side by side: fraction over the threshold and the response distributions."""
    fig = Figure(figsize=(14, 5), layout="constrained")
    (ax_b, ax_d) = fig.subplots(1, 2)
    labels = [
        f"{_condition(g)}\n{g.model}\n{g.recording_ids[0][-8:]}"
        if len(g.recording_ids) == 1
        else f"{_condition(g)}\n{g.model}"
        for g in segs
    ]
    # a pooled condition's bar is the mean of its recordings' shares, with a 95 % t-interval
    # over those recordings (the seeds, the independent units); frames within one run are
    # not independent, so a single recording's bar has no interval and says n = 1
    est = [over_share_by_recording(g, s.threshold_dps) for g in segs]
    x = np.arange(len(segs))
    mid, lo, hi = (np.array([100 * getattr(e, f) for e in est]) for f in ("mean", "low", "high"))
    ax_b.bar(x, mid, color="C1")
    ok = np.isfinite(lo)
    if ok.any():
        yerr = [mid[ok] - lo[ok], hi[ok] - mid[ok]]
        ax_b.errorbar(x[ok], mid[ok], yerr=yerr, fmt="none", ecolor="k", capsize=3)
    for k, (e, top) in enumerate(zip(est, np.where(ok, hi, mid), strict=True)):
        # n above the interval (or the bar), clear of both
        ax_b.annotate(
            f"n = {e.n}",
            (k, top),
            xytext=(0, 3),
            textcoords="offset points",
            ha="center",
            va="bottom",
            fontsize=7,
        )
    ax_b.set_xticks(range(len(segs)), labels, fontsize=7)
    unit = units_label(segs)
    over = f"% of frames with response > {s.threshold_dps:g}"
    ax_b.set_ylabel(f"{over} {unit}" if ":" not in unit else f"{over}\n({unit})")
    ax_b.set_title(
        f"'AVDM > {s.threshold_dps:g}' per segment: mean over n recordings, "
        "95 % t-interval over recordings (n ≥ 2)",
        fontsize=9,
    )
    ax_b.grid(axis="y", alpha=0.3)
    series = [(label.replace("\n", " "), g.response) for label, g in zip(labels, segs, strict=True)]
    response_densities(
        ax_d, series, s.threshold_dps, "response distributions", fontsize=7, unit=unit
    )
    return save_figure(fig, path)


@dataclasses.dataclass
class ProfileResult(WroteFiles):
    """Profiles of every segment (or condition), their summary table, and the files written.
    ``figure(i)`` draws segment ``i`` as a matplotlib Figure."""

    settings: ProfileSettings
    segments: list[ProfileSegment]
    summary: pl.DataFrame
    tables: dict[str, pl.DataFrame]
    meta: dict
    paths: list[Path]
    notices: list[str]

    def report(self) -> list[str]:
        """What the command line prints: the files, then one line per profile."""
        s, files = self.settings, self.files
        pngs = [
            p for role, p in files.items() if role.startswith("profile_") and p.suffix == ".png"
        ]
        lines = [
            f"{len(self.segments)} profile(s) by {s.by}: {len(pngs)} PNGs, "
            f"{files.get('profiles_png')}, {files.get('profiles_rrd')}, "
            f"{files.get('profile_summary')}"
        ]
        return lines + [
            f"  {r['segment']:<44} n={r['n_frames']:>6}  > {s.threshold_dps:g}: "
            f"{100 * r['frac_over_threshold']:5.1f} %  near wall {r['near_wall_mean']:.1f} / "
            f"centre {r['centre_mean']:.1f}"
            for r in self.summary.iter_rows(named=True)
        ]

    def figure(self, i: int = 0) -> Figure:
        return segment_figure(self.segments[i], self.settings)


def profile(
    recordings: str | Path | Sequence[str | Path],
    settings: ProfileSettings = ProfileSettings(),
    out: str | Path | None = None,
    *,
    progress: Callable[[int], None] | None = None,
    notice: Callable[[str], None] | None = None,
) -> ProfileResult:
    """``vdc-analyse profile`` (paper Figs. 6–7): a 3D circle profile, the histogram of
    responses over the threshold and a heat map per recording segment or condition.

    With ``out``: a PNG per profile, ``profiles.png``, ``profile_summary.parquet`` and
    ``profiles.rrd``; with ``out=None`` only the result (segments and summary in hand;
    draw one with :func:`plot_segment`)."""

    notes = Notices(notice)
    tables, meta = build_tables(recordings, settings.models or None, settings, progress, notes)
    segs = segments_from_tables(
        tables["frames"],
        tables["model_outputs"],
        tables["summary"],
        meta["arena_half_extent_m"],
        settings.by,
        settings.warmup_frames,
        settings.exclude_turns,
    )
    summary = pl.DataFrame([segment_summary(seg, settings, settings) for seg in segs])
    meta = {
        **meta,
        "profile": {
            "threshold_dps": settings.threshold_dps,
            "bin_dps": settings.bin_dps,
            "cell_m": settings.cell_m,
            "by": settings.by,
            "motion": settings.motion,
        },
    }
    paths: list[Path] = []
    if out is not None:
        out = Path(out)
        with table_set(out) as stage:  # published whole: never a mix of two runs
            paths = [plot_segment(seg, settings, stage / f"profile_{seg.key}.png") for seg in segs]
            paths.append(plot_overview(segs, settings, stage / "profiles.png"))
            paths.append(write_parquet(summary, stage / "profile_summary.parquet", meta))
            rid = "profile-" + hashlib.sha1("|".join(meta["recordings"]).encode()).hexdigest()[:8]
            paths.append(write_profile_rrd(segs, settings, stage / "profiles.rrd", rid))
        paths = [out / p.name for p in paths]
    return ProfileResult(settings, segs, summary, tables, meta, paths, list(notes))
