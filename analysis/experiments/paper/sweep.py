"""The SF–TF sweep of paper Fig. 3: AVDM response to drifting gratings at 100×100 px, 300 Hz.

Default ("paper") layout: response against TF at SF = 1, 10 and 50 upc, and against SF at
TF = 1, 5 and 50 Hz. With explicit SF and TF lists, the full grid instead.
Each cell is a fresh model on a ``duration_s`` grating; its value is the mean over the frames
after a warm-up of ``2·Tw`` frames.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import matplotlib
import numpy as np
import polars as pl
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from analysis.stats import spearman
from avdm.registry import canonical_name, make_model, make_params, require_angular_velocity
from avdm.stimuli import WAVEFORMS, grating, omega_true_dps, period_px_from_sf
from vdc.cli_support import option, parse_size
from vdc.errors import UserError
from vdc.parquet_io import WroteFiles, table_set, write_parquet
from vdc.settings import AT_LEAST_0, POSITIVE, SIDE_PX, Settings, between

PAPER_SF_UPC = (1.0, 10.0, 50.0)  # rows: response vs TF
PAPER_TF_HZ = (1.0, 5.0, 50.0)  # columns: response vs SF
DEFAULT_TFS_HZ = (1, 2, 3, 5, 7, 10, 15, 20, 30, 40, 50, 60, 75, 100, 125, 150)
DEFAULT_SFS_UPC = (1, 2, 3, 4, 5, 6, 8, 10, 12, 15, 20, 25, 30, 35, 40, 45, 50)
OUTPUT_COLUMNS = ("omega_dps", "lambda_px", "motion", "contrast")


@dataclass(frozen=True)
class SweepConfig:
    """Stimulus settings of a sweep (recorded in the Parquet metadata)."""

    size: tuple[int, int] = (100, 100)  # (H, W) px; W px stand for 360°
    fps: float = 300.0
    duration_s: float = 1.0
    contrast: float = 1.0
    waveform: str = "sine"

    @property
    def deg_per_px(self) -> float:
        return 360.0 / self.size[1]


def paper_cells(
    sfs: Sequence[float] = DEFAULT_SFS_UPC, tfs: Sequence[float] = DEFAULT_TFS_HZ
) -> list[tuple[float, float]]:
    """(sf_upc, tf_hz) cells of the Fig. 3 layout, without duplicates, sorted."""
    cells = {(float(sf), float(tf)) for sf in PAPER_SF_UPC for tf in tfs}
    cells |= {(float(sf), float(tf)) for tf in PAPER_TF_HZ for sf in sfs}
    return sorted(cells)


def grid_cells(sfs: Sequence[float], tfs: Sequence[float]) -> list[tuple[float, float]]:
    """Every (sf_upc, tf_hz) pair of two lists."""
    return sorted({(float(sf), float(tf)) for sf in sfs for tf in tfs})


def check_cells(cells: Sequence[tuple[float, float]], config: SweepConfig) -> None:
    """Raise ValueError for cells a sweep cannot show (non-positive SF/TF, beyond Nyquist)."""
    w = config.size[1]
    for sf, tf in cells:
        if not (math.isfinite(sf) and sf > 0):
            raise UserError(f"spatial frequency must be > 0 upc, got {sf:g}.")
        if sf > w / 2:
            raise UserError(
                f"SF {sf:g} upc is above the spatial Nyquist limit of {w / 2:g} upc at {w} px wide."
            )
        if not (math.isfinite(tf) and tf > 0):
            raise UserError(f"temporal frequency must be > 0 Hz, got {tf:g}.")
        if tf > config.fps / 2:
            raise UserError(
                f"TF {tf:g} Hz is above the temporal Nyquist limit of {config.fps / 2:g} Hz."
            )


def run_sweep(
    model_spec: str,
    cells: Sequence[tuple[float, float]],
    config: SweepConfig = SweepConfig(),
    progress: Callable[[], None] | None = None,
) -> pl.DataFrame:
    """Run a fresh ``model_spec`` model on a grating per cell; one row per cell.

    Columns: model, sf_upc, tf_hz, period_px, omega_true_dps, omega_dps, lambda_px, motion,
    contrast, omega_sd_dps (temporal standard deviation), n_frames.
    """
    check_cells(cells, config)
    name = canonical_name(model_spec)
    model = make_model(
        model_spec,
        fps=config.fps,
        deg_per_px=config.deg_per_px,
        width_px=config.size[1],  # the raster, for models whose scales depend on it
        height_px=config.size[0],
    )
    warm = 2 * int(getattr(model.params, "tw", 10))
    n_frames = round(config.duration_s * config.fps)
    if n_frames <= warm:
        raise UserError(
            f"duration {config.duration_s:g} s gives {n_frames} frames: need more than the "
            f"{warm}-frame warm-up."
        )
    rows = []
    for sf, tf in cells:
        frames = grating(
            size=config.size,
            fps=config.fps,
            tf_hz=tf,
            sf_upc=sf,
            n_frames=n_frames,
            contrast=config.contrast,
            waveform=config.waveform,
        )
        model.reset()
        out = model.run(frames)
        row = {
            "model": name,
            "sf_upc": sf,
            "tf_hz": tf,
            "period_px": period_px_from_sf(sf, config.size[1]),
            "omega_true_dps": omega_true_dps(sf, tf),
        }
        for col in OUTPUT_COLUMNS:  # an output this model lacks (λ̂ of avdm-natural) is NaN
            row[col] = float(np.mean(out[col][warm:])) if col in out else math.nan
        row["omega_sd_dps"] = float(np.std(out["omega_dps"][warm:]))
        row["n_frames"] = n_frames
        rows.append(row)
        if progress is not None:
            progress()
    return pl.DataFrame(rows).sort("sf_upc", "tf_hz")


def monotonicity(df: pl.DataFrame, min_points: int = 4) -> pl.DataFrame:
    """Spearman ρ of ω̂ along every row (vs TF at fixed SF) and column (vs SF at fixed TF).

    Rows and columns with fewer than ``min_points`` cells (the cross-sections the paper layout
    only touches) are left out. Columns: along ("tf" or "sf"), fixed ("sf_upc=10" ...), n, rho,
    trend
    ("increasing", "decreasing", "flat" for |ρ| < 0.5, "undefined" when ω̂ is constant).
    """
    out = []
    for along, fixed in (("tf_hz", "sf_upc"), ("sf_upc", "tf_hz")):
        for key, group in df.group_by(fixed, maintain_order=True):
            if group.height < min_points:
                continue
            g = group.sort(along)
            rho = spearman(g[along].to_numpy(), g["omega_dps"].to_numpy())
            if math.isnan(rho):
                trend = "undefined"
            elif abs(rho) < 0.5:
                trend = "flat"
            else:
                trend = "increasing" if rho > 0 else "decreasing"
            out.append(
                {
                    "along": along.split("_")[0],
                    "fixed": f"{fixed}={key[0]:g}",
                    "fixed_value": float(key[0]),
                    "n": g.height,
                    "rho": rho,
                    "trend": trend,
                }
            )
    if not out:
        return pl.DataFrame(
            schema={
                "along": pl.String,
                "fixed": pl.String,
                "fixed_value": pl.Float64,
                "n": pl.Int64,
                "rho": pl.Float64,
                "trend": pl.String,
            }
        )
    return pl.DataFrame(out).sort("along", "fixed_value", descending=[True, False])


# a grating whose period is 2 px (SF = W/2) sits at the Nyquist limit: counter-phase flicker,
# not a motion stimulus; reproduce's claim 1 leaves it out, and the figure says so
NYQUIST_PERIOD_PX = 2.0


def _valid_band(ax: Axes, x_lo: float, x_hi: float, bad_from: float, label: str) -> None:
    if bad_from < x_hi:
        ax.axvspan(max(bad_from, x_lo), x_hi, color="0.9", zorder=0, label=label)


def plot_paper(df: pl.DataFrame, path: Path, config: SweepConfig, title: str) -> Path:
    """Six panels as in paper Fig. 3: ω̂ vs TF (top, per SF) and vs SF (bottom, per TF)."""
    fig = Figure(figsize=(13, 7.5), layout="constrained")
    axes = fig.subplots(2, 3)
    w = config.size[1]
    rho = {(r["along"], r["fixed_value"]): r["rho"] for r in monotonicity(df).iter_rows(named=True)}
    # the top row per SF across TF, the bottom per TF across SF: (fixed values, their column,
    # the x column and label, where aliasing starts on x, its label, the panel's title)
    rows = (
        (
            PAPER_SF_UPC,
            "sf_upc",
            "tf_hz",
            "TF (Hz)",
            config.fps / 4,
            "TF > fps/4 (near aliasing)",
            lambda sf: f"SF = {sf:g} upc (period {w / sf:g} px)",
        ),
        (
            PAPER_TF_HZ,
            "tf_hz",
            "sf_upc",
            "SF (units per circle)",
            w / 4,
            "period < 4 px (spatial aliasing)",
            lambda tf: f"TF = {tf:g} Hz",
        ),
    )
    for row_axes, (fixed, fixed_col, x_col, x_label, bad_from, band, named) in zip(
        axes, rows, strict=True
    ):
        for ax, value in zip(row_axes, fixed, strict=True):
            g = df.filter(pl.col(fixed_col) == value).sort(x_col)
            _panel(ax, g[x_col], g, x_label)
            _valid_band(ax, g[x_col].min(), g[x_col].max() * 1.1, bad_from, band)
            along = x_col.split("_")[0]  # as monotonicity names it
            panel = f"{named(value)}   ρ = {rho.get((along, value), np.nan):+.2f}"
            if fixed_col == "sf_upc" and w / value <= NYQUIST_PERIOD_PX:
                # counter-phase flicker, not motion: shown, and said to be left out of the claim
                panel += "\nexcluded: at the Nyquist limit"
                ax.set_facecolor("0.94")
            ax.set_title(panel)
    for ax in axes.flat:
        ax.legend(fontsize=7, loc="best")
    fig.suptitle(title)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return path


def _panel(ax: Axes, x: pl.Series, g: pl.DataFrame, xlabel: str) -> None:
    xs = x.to_numpy()
    est = g["omega_dps"].to_numpy()
    sd = g["omega_sd_dps"].to_numpy()
    pos = est > 0
    ax.plot(xs[pos], est[pos], "o-", color="C0", ms=4, label="AVDM ω̂ (mean ± sd over time)")
    ax.fill_between(
        xs[pos],
        np.maximum(est[pos] - sd[pos], est[pos] / 10),
        est[pos] + sd[pos],
        color="C0",
        alpha=0.2,
        lw=0,
    )
    if (~pos).any():  # a log axis cannot show 0: mark zero responses on the bottom edge
        ax.plot(
            xs[~pos],
            np.full((~pos).sum(), 0.02),
            "v",
            color="C3",
            ms=6,
            clip_on=False,
            transform=ax.get_xaxis_transform(),
            label="ω̂ = 0",
        )
    ax.plot(xs, g["omega_true_dps"], "--", color="k", lw=1, label="true ω = TF·360/SF")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("angular velocity (deg/s)")
    ax.grid(True, which="both", alpha=0.3)


def plot_grid(df: pl.DataFrame, path: Path, title: str) -> Path:
    """Heat map of mean ω̂ over the SF × TF grid (log colour scale) beside the true ω."""
    sfs = sorted(df["sf_upc"].unique().to_list())
    tfs = sorted(df["tf_hz"].unique().to_list())
    est = np.full((len(sfs), len(tfs)), np.nan)
    true = np.full_like(est, np.nan)
    index = {(r["sf_upc"], r["tf_hz"]): r for r in df.iter_rows(named=True)}
    for i, sf in enumerate(sfs):
        for j, tf in enumerate(tfs):
            r = index.get((sf, tf))
            if r is not None:
                est[i, j] = r["omega_dps"]
                true[i, j] = r["omega_true_dps"]
    positive = est[np.isfinite(est) & (est > 0)]
    vmin = max(float(positive.min()) if positive.size else 1.0, 1e-2)
    vmax = float(max(np.nanmax(true), np.nanmax(est), vmin * 10))
    norm = matplotlib.colors.LogNorm(vmin=vmin, vmax=vmax)
    fig = Figure(figsize=(12, 5), layout="constrained")
    axes = fig.subplots(1, 2)
    for ax, data, name in ((axes[0], est, "AVDM ω̂ (deg/s)"), (axes[1], true, "true ω (deg/s)")):
        im = ax.imshow(
            np.where(data > 0, data, np.nan),
            origin="lower",
            aspect="auto",
            norm=norm,
            cmap="viridis",
        )
        ax.set_xticks(range(len(tfs)), [f"{t:g}" for t in tfs], rotation=90)
        ax.set_yticks(range(len(sfs)), [f"{s:g}" for s in sfs])
        ax.set_xlabel("TF (Hz)")
        ax.set_ylabel("SF (units per circle)")
        ax.set_title(name)
        fig.colorbar(im, ax=ax)
    fig.suptitle(title)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return path


@dataclass(frozen=True)
class SweepSettings(Settings):
    """``vdc-analyse sweep``: the model, the cells (paper layout unless ``sf_upc`` or
    ``tf_hz`` lists are given: then their full grid) and the stimulus."""

    model: str = option("avdm", "model variant")
    sf_upc: tuple[float, ...] | None = option(
        None, "spatial frequencies, upc, e.g. 1,5,10", "--sf", range=POSITIVE
    )
    tf_hz: tuple[float, ...] | None = option(
        None, "temporal frequencies, Hz, e.g. 1,3,10", "--tf", range=AT_LEAST_0
    )
    size: tuple[int, int] = option(  # (H, W) px; W px stand for 360°
        (100, 100),
        "stimulus WIDTHxHEIGHT px; the width spans 360 deg",
        type=parse_size,
        range=SIDE_PX,
    )
    fps: float = option(300.0, "frame rate, Hz", range=POSITIVE)
    duration_s: float = option(1.0, "seconds of stimulus per cell", "--duration", range=POSITIVE)
    contrast: float = option(
        1.0, "Michelson contrast, peak-normalised, (0, 1]", range=between(0, 1, lo_open=True)
    )
    waveform: str = option("sine", "grating profile (--square: square)", choices=WAVEFORMS)

    def __post_init__(self) -> None:
        if self.waveform not in WAVEFORMS:
            raise UserError(f"waveform must be sine or square, got {self.waveform!r}.")
        if not self.grid and (self.size[1] < 100 or self.fps < 300):
            raise UserError(
                "the paper layout needs SF up to 50 upc and TF up to 150 Hz: use --size of at "
                "least 100 px wide and --fps of at least 300, or give --sf and --tf lists."
            )
        check_cells(self.cells(), self.stimulus)
        make_params(self.model)  # an unknown model fails before any cell runs
        require_angular_velocity(self.model, "the sweep")

    @property
    def grid(self) -> bool:
        return self.sf_upc is not None or self.tf_hz is not None

    @property
    def stimulus(self) -> SweepConfig:
        return SweepConfig(self.size, self.fps, self.duration_s, self.contrast, self.waveform)

    def cells(self) -> list[tuple[float, float]]:
        if self.grid:
            return grid_cells(self.sf_upc or DEFAULT_SFS_UPC, self.tf_hz or DEFAULT_TFS_HZ)
        return paper_cells()


@dataclass
class SweepResult(WroteFiles):
    table: pl.DataFrame  # one row per cell: sf_upc, tf_hz, ..., omega_dps, ...
    monotonicity: pl.DataFrame  # Spearman rho along every row and column
    paths: list[Path]

    def report(self) -> list[str]:
        """The monotonicity of the response, as lines for people."""
        lines = ["monotonicity of the response (Spearman rho of omega_dps):"]
        for r in self.monotonicity.iter_rows(named=True):
            lines.append(
                f"  vs {r['along'].upper():<2} at {r['fixed']:<12} n={r['n']:<3} "
                f"rho={r['rho']:+.3f}  {r['trend']}"
            )
        inc = self.monotonicity.filter(pl.col("along") == "tf")
        dec = self.monotonicity.filter(pl.col("along") == "sf")
        lines.append(
            f"summary: {int((inc['trend'] == 'increasing').sum())}/{inc.height} TF rows "
            f"increasing, {int((dec['trend'] == 'decreasing').sum())}/{dec.height} SF columns "
            "decreasing"
        )
        return lines


def sweep(
    settings: SweepSettings = SweepSettings(),
    out: str | Path | None = None,
    *,
    progress: Callable[[], None] | None = None,
) -> SweepResult:
    """``vdc-analyse sweep`` (paper Fig. 3). With ``out``: ``sweep.parquet``,
    ``monotonicity.parquet`` and ``sweep.png``. ``progress`` is called once per cell."""

    config = settings.stimulus
    name = canonical_name(settings.model)
    params = make_params(settings.model, fps=config.fps, deg_per_px=config.deg_per_px)
    df = run_sweep(settings.model, settings.cells(), config, progress=progress)
    # the paper layout's cross-sections have 3 cells: only its six full rows/columns count
    mono = monotonicity(df, min_points=3 if settings.grid else 4)
    paths: list[Path] = []
    if out is not None:
        out = Path(out)
        meta = {
            "model": name,
            "params": params.to_dict(),
            "stimulus": {
                "size_hw": list(config.size),
                "fps": config.fps,
                "duration_s": config.duration_s,
                "contrast": config.contrast,
                "waveform": config.waveform,
                "normalisation": "peak",
                "dtype": "uint8",
                "layout": "grid" if settings.grid else "paper",
            },
        }
        with table_set(out) as stage:  # published whole: never a mix of two runs
            paths.append(write_parquet(df, stage / "sweep.parquet", meta))
            paths.append(write_parquet(mono, stage / "monotonicity.parquet", meta))
            title = (
                f"{name} on drifting {config.waveform} gratings, {config.size[1]}x{config.size[0]} "
                f"px, {config.fps:g} Hz, contrast {config.contrast:g}"
            )
            if settings.grid:
                paths.append(plot_grid(df, stage / "sweep.png", title))
            else:
                paths.append(plot_paper(df, stage / "sweep.png", config, title))
        paths = [out / p.name for p in paths]
    return SweepResult(df, mono, paths)
