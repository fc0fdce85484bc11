"""Model variants on identical recorded frames: statistics, pairwise correlations, overlays."""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Callable
from pathlib import Path

import numpy as np
import polars as pl
from matplotlib.figure import Figure

from analysis.profile import correlation_panel, response_densities, save_figure, units_label
from analysis.recordings.analysis_rrd import write_variants_rrd
from analysis.recordings.loading import LoadedRecording, Notices, load_recording
from analysis.recordings.recompute import (
    SummarySettings,
    TablesSettings,
    frames_in_statistics,
    model_params,
    primary_output,
    recompute,
    summary_statistics,
)
from analysis.stats import spearman
from avdm.registry import canonical_name, make_model
from vdc.cli_support import option
from vdc.errors import UserError
from vdc.parquet_io import WroteFiles, table_set, write_parquet


def variant_statistics(
    loaded: LoadedRecording, outputs: dict[str, pl.DataFrame], s: SummarySettings
) -> pl.DataFrame:
    """Per variant (frames after warm-up; straight driving only with ``exclude_turns``):
    mean, p95, fraction over threshold, near-wall/centre ratio, ... of its primary output."""
    gap = loaded.frames.select("frame", "wall_gap_m", "turning")
    rows = []
    for name, df in outputs.items():
        out = primary_output(df)
        g = frames_in_statistics(df.join(gap, on="frame", how="left"), s, loaded.recording_id)
        rows.append(
            {
                "recording_id": loaded.recording_id,
                "model": name,
                "output": out,
                "n_frames": g.height,
                "threshold_dps": s.threshold_dps,
                **summary_statistics(g[out].to_numpy(), g["wall_gap_m"].to_numpy(), s),
            }
        )
    return pl.DataFrame(rows)


def pairwise_correlations(outputs: dict[str, pl.DataFrame], warmup: int) -> pl.DataFrame:
    """Pearson and Spearman correlation of every pair of variants' primary outputs."""
    series = {}
    for name, df in outputs.items():
        d = df.filter(pl.col("frame") >= warmup)
        series[name] = d[primary_output(d)].to_numpy()
    rows = []
    for a, b in itertools.combinations(series, 2):
        x, y = series[a], series[b]
        pearson = float(np.corrcoef(x, y)[0, 1]) if x.std() > 0 and y.std() > 0 else float("nan")
        rows.append(
            {
                "model_a": a,
                "model_b": b,
                "pearson": pearson,
                "spearman": spearman(x, y),
                "mean_ratio_b_over_a": float(y.mean() / x.mean()) if x.mean() else float("nan"),
            }
        )
    schema = {
        "model_a": pl.String,
        "model_b": pl.String,
        "pearson": pl.Float64,
        "spearman": pl.Float64,
        "mean_ratio_b_over_a": pl.Float64,
    }
    return pl.DataFrame(rows, schema=schema)


def busiest_window(values: np.ndarray, width: int) -> slice:
    """The ``width``-frame window with the largest summed response (for the trace panel)."""
    if len(values) <= width:
        return slice(0, len(values))
    c = np.concatenate([[0.0], np.cumsum(np.nan_to_num(values))])
    start = int(np.argmax(c[width:] - c[:-width]))
    return slice(start, start + width)


def compare_figure(
    outputs: dict[str, pl.DataFrame],
    stats: pl.DataFrame,
    corr: pl.DataFrame,
    s: SummarySettings,
    title: str,
    window_frames: int = 1980,
) -> Figure:
    """Traces over the busiest minute, response distributions, and the correlation matrix."""
    names = list(outputs)
    fig = Figure(figsize=(15, 9), layout="constrained")
    grid = fig.add_gridspec(2, 2, height_ratios=[1, 1.1])
    ax_t = fig.add_subplot(grid[0, :])
    first = outputs[names[0]]
    out0 = primary_output(first)
    win = busiest_window(first[out0].to_numpy(), window_frames)
    for i, name in enumerate(names):
        df = outputs[name]
        out = primary_output(df)
        ax_t.plot(
            df["t_s"].to_numpy()[win],
            df[out].to_numpy()[win],
            lw=0.9,
            color=f"C{i}",
            label=f"{name} ({out}, {units_label([(name, out)])})",
        )
    ax_t.axhline(s.threshold_dps, color="k", ls="--", lw=0.8)
    ax_t.set_xlabel("time (s)")
    unit = units_label([(name, primary_output(outputs[name])) for name in names])
    ax_t.set_ylabel(f"response ({unit})" if ":" not in unit else "response (units in the legend)")
    ax_t.set_title("the busiest minute of the recording")
    ax_t.legend(fontsize=8, loc="upper right")
    ax_t.grid(alpha=0.3)

    ax_d = fig.add_subplot(grid[1, 0])
    series = []
    for name in names:
        df = outputs[name].filter(pl.col("frame") >= s.warmup_frames)
        row = stats.filter(pl.col("model") == name).row(0, named=True)
        label = (
            f"{name}: mean {row['mean']:.1f}, "
            f"{100 * row['frac_over_threshold']:.1f} % > {s.threshold_dps:g}"
        )
        series.append((label, df[primary_output(df)].to_numpy()))
    response_densities(ax_d, series, s.threshold_dps, "distributions", fontsize=8, unit=unit)

    ax_c = fig.add_subplot(grid[1, 1])
    pairs = ((r["model_a"], r["model_b"], r["pearson"]) for r in corr.iter_rows(named=True))
    correlation_panel(
        fig,
        ax_c,
        names,
        pairs,
        "Pearson correlation over frames",
        digits=3,
        fontsize=8,
        cmap="coolwarm",
    )
    fig.suptitle(title)
    return fig


@dataclasses.dataclass(frozen=True)
class CompareSettings(TablesSettings):
    """``vdc-analyse compare``: at least two distinct variants plus the summary settings."""

    models: tuple[str, ...] = option(
        (), "a variant to run (give at least two)", flag="--model", metavar="MODEL", required=True
    )

    def __post_init__(self) -> None:
        super().__post_init__()
        if len(self.models) < 2:
            raise UserError("compare needs at least two --model variants.")
        names = [canonical_name(m) for m in self.models]
        if len(set(names)) != len(names):
            raise UserError(f"the same variant is given twice: {', '.join(names)}")


@dataclasses.dataclass
class CompareResult(WroteFiles):
    """Every variant's outputs on the same frames, their statistics and correlations."""

    recording_id: str
    settings: CompareSettings
    outputs: dict[str, pl.DataFrame]  # canonical variant name -> frame, t_s, outputs
    statistics: pl.DataFrame
    correlations: pl.DataFrame
    paths: list[Path]
    notices: list[str]
    source: str = ""  # the recording as given (what ``rerun`` opens beside the variants)

    def report(self, source: str | None = None) -> list[str]:
        """What the command line prints: statistics and correlations of the variants, and how
        to view them beside ``source`` (default: the recording compared)."""
        n_frames = self.outputs[next(iter(self.outputs))].height
        files, t = self.files, self.settings.threshold_dps
        lines = [
            f"{len(self.outputs)} variants on {n_frames} frames -> {files.compare}, "
            f"{files.variants}"
        ]
        lines += [
            f"  {r['model']:<22} mean {r['mean']:8.2f}  p95 {r['p95']:8.2f}  > {t:g}: "
            f"{100 * r['frac_over_threshold']:5.1f} %  near wall / centre "
            f"{r['near_wall_centre_ratio']:.2f}"
            for r in self.statistics.iter_rows(named=True)
        ]
        lines += [
            f"  corr {r['model_a']} ~ {r['model_b']}: pearson {r['pearson']:.3f}, "
            f"spearman {r['spearman']:.3f}"
            for r in self.correlations.iter_rows(named=True)
        ]
        return [*lines, f"view together: rerun {source or self.source} {files.variants}"]

    def figure(self) -> Figure:
        """Traces over the busiest minute, distributions and correlations (compare.png)."""
        return compare_figure(
            self.outputs,
            self.statistics,
            self.correlations,
            self.settings,
            f"{self.recording_id}: variants on identical frames",
        )


def compare(
    recording: str | Path,
    settings: CompareSettings,
    out: str | Path | None = None,
    *,
    progress: Callable[[int], None] | None = None,
    notice: Callable[[str], None] | None = None,
) -> CompareResult:
    """``vdc-analyse compare``: recompute every variant on the recording's raw frames.

    With ``out``: ``compare_summary.parquet``, ``compare_correlations.parquet``,
    ``compare.png`` and ``variants.rrd`` (the traces under ``/model_variants/<name>/``, with
    the source's recording id, so ``rerun REC variants.rrd`` shows them together)."""

    loaded = load_recording(recording, settings)
    notes = Notices(notice)
    notes.of(loaded)
    outputs = recompute(loaded, settings.models, progress)
    stats = variant_statistics(loaded, outputs, settings)
    corr = pairwise_correlations(outputs, settings.warmup_frames)
    paths: list[Path] = []
    result = CompareResult(
        loaded.recording_id, settings, outputs, stats, corr, paths, list(notes), str(recording)
    )
    if out is not None:
        out = Path(out)
        meta = {
            "params": model_params(loaded, settings.models),
            "recording": loaded.recording_id,
            "settings": dataclasses.asdict(settings.summary_settings()),
        }
        with table_set(out) as stage:  # published whole: never a mix of two runs
            paths.append(write_parquet(stats, stage / "compare_summary.parquet", meta))
            paths.append(write_parquet(corr, stage / "compare_correlations.parquet", meta))
            paths.append(save_figure(result.figure(), stage / "compare.png"))
            ctx = loaded.camera_context()
            units = {
                canonical_name(m): {o.name: o.unit for o in make_model(m, **ctx).outputs}
                for m in settings.models
            }
            paths.append(
                write_variants_rrd(
                    loaded.recording_id, outputs, units, stage / "variants.rrd", loaded.online_model
                )
            )
        paths[:] = [out / p.name for p in paths]
    return result
