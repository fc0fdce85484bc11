"""The predictors' figure, report section and files (``predictors.png``, the section of
``boundary.md``, ``predictors.parquet``): what :mod:`analysis.predictors.statistics` computed,
ranked and
written."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
import pyarrow.parquet as pq
from matplotlib.figure import Figure

from vdc.errors import UserError
from vdc.parquet_io import WroteFiles, write_parquet


def ranked(table: pl.DataFrame, statistic: str) -> pl.DataFrame:
    """The measures by ``statistic``, best first: per measure the mean over the parameter's
    values of estimate and interval ends, and the values' estimates."""
    t = table.filter(pl.col("statistic") == statistic)
    return (
        t.group_by("measure")
        .agg(
            pl.col("estimate").mean().alias("mean"),
            pl.col("ci_low").mean().alias("ci_low"),
            pl.col("ci_high").mean().alias("ci_high"),
        )
        .sort("mean", descending=True, nulls_last=True)
    )


def plot_predictors(table: pl.DataFrame, path: Path, title: str) -> Path:
    """Each measure's predictive power with its 95 % interval, ranked, one panel per headline
    statistic present, one colour per parameter value."""
    stats = [
        s
        for s in (
            "rho_failure",
            "loco_balanced_accuracy",
            "clip_auroc",
            "frame_auroc_pooled",
            "frame_auroc_within_clip",
        )
        if table.filter(pl.col("statistic") == s).height
    ]
    fig = Figure(figsize=(5 * max(1, len(stats)), 5.5), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, max(1, len(stats))))
    for ax, stat in zip(axes, stats, strict=False):
        order = ranked(table, stat)["measure"].to_list()[::-1]
        t = table.filter(pl.col("statistic") == stat)
        values = t["value"].unique(maintain_order=True).to_list()
        drawn = 0
        for k, v in enumerate(values):
            tv = t.filter(pl.col("value") == v)
            for r in tv.iter_rows(named=True):
                if r["estimate"] is None:
                    continue
                drawn += 1
                y = order.index(r["measure"]) + (k - (len(values) - 1) / 2) * 0.15
                lo = r["ci_low"] if r["ci_low"] is not None else r["estimate"]
                hi = r["ci_high"] if r["ci_high"] is not None else r["estimate"]
                ax.errorbar(r["estimate"], y, xerr=[[r["estimate"] - lo], [hi - r["estimate"]]],
                            fmt="o", color=f"C{k % 10}", ms=4, capsize=2,
                            label=f"{v:g}" if r["measure"] == order[-1] else None)  # fmt: skip
        ax.set_yticks(range(len(order)), order)
        chance = 0.0 if stat == "rho_failure" else 0.5
        ax.axvline(chance, color="k", lw=0.8, ls=":")
        # an empty panel says why rather than showing nothing
        ax.set_title(stat if drawn else f"{stat}: no estimate (success did not vary)")
        ax.set_xlabel("estimate and its 95 % interval (dotted: chance)")
        ax.grid(alpha=0.3)
        if drawn:
            ax.legend(fontsize=7, title="value", title_fontsize=7)
    fig.suptitle(title)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    return path


def _fmt(r: dict[str, Any]) -> str:
    e, lo, hi = r["estimate"], r["ci_low"], r["ci_high"]
    if e is None:
        return "—"
    if lo is None or hi is None:
        return f"{e:.2f}"
    return f"{e:.2f} [{lo:.2f}, {hi:.2f}]"


def predictors_report(table: pl.DataFrame, param: str, mode: str) -> str:
    """The ``## Which measure predicts it`` section of ``boundary.md``."""
    lines = [
        "## Which measure predicts where it breaks\n",
        "![each measure's predictive power, ranked, 95 % intervals](predictors.png)\n",
        "Every measure's statistic per value of "
        f"`{param}` with its 95 % bootstrap interval (`predictors.parquet`; the statistics: "
        "`vdc.predictors` and docs/boundary.md).\n",
    ]
    stats = (
        ["rho_failure", "loco_balanced_accuracy"]
        if mode == "arena"
        else ["clip_auroc", "frame_auroc_pooled", "frame_auroc_within_clip"]
    )
    values = table["value"].unique(maintain_order=True).to_list()
    for stat in stats:
        t = table.filter(pl.col("statistic") == stat)
        if not t.height:
            continue
        order = ranked(table, stat)["measure"].to_list()
        lines.append(f"### {stat}\n")
        lines.append("| measure | " + " | ".join(f"{param} {v:g}" for v in values) + " |")
        lines.append("|---|" + "---|" * len(values))
        for m in order:
            cells = []
            for v in values:
                r = t.filter((pl.col("measure") == m) & (pl.col("value") == v))
                cells.append(_fmt(r.row(0, named=True)) if r.height else "—")
            lines.append(f"| {m} | " + " | ".join(cells) + " |")
        lines.append("")
    paired = table.filter(pl.col("statistic").str.starts_with("paired_"))
    if paired.height:
        lines.append("### The AVDM against each measure (paired, AVDM minus measure)\n")
        counts = paired.group_by("statistic", "verdict").len().sort("statistic", "verdict")
        for (stat,), g in counts.group_by("statistic", maintain_order=True):
            parts = ", ".join(f"{r['verdict']} {r['len']}" for r in g.iter_rows(named=True))
            lines.append(f"- `{stat}`: {parts}")
        worse = paired.filter(pl.col("verdict") == "worse")
        for r in worse.iter_rows(named=True):
            lines.append(
                f"  - worse than `{r['measure']}` at {param} {r['value']:g} "
                f"(`{r['statistic']}`: {_fmt(r)})"
            )
        lines.append("")
    comb = table.filter(pl.col("statistic").str.starts_with("cv_logloss"))
    if comb.height:
        lines.append(
            "### Combined: held-out cross-entropy of a logistic model (lower is better; gain "
            "over SI/TI, positive is better)\n"
        )
        lines.append(f"| measures | {param} | cv_logloss | gain over SI/TI | verdict |")
        lines.append("|---|---|---|---|---|")
        loss = comb.filter(pl.col("statistic") == "cv_logloss")
        for r in loss.iter_rows(named=True):
            gain = comb.filter(
                (pl.col("statistic") != "cv_logloss")
                & (pl.col("measure") == r["measure"])
                & (pl.col("value") == r["value"])
            )
            g = gain.row(0, named=True) if gain.height else None
            lines.append(
                f"| {r['measure']} | {r['value']:g} | {_fmt(r)} | "
                f"{_fmt(g) if g else '—'} | {g['verdict'] if g else 'reference'} |"
            )
        lines.append("")
    return "\n".join(lines) + "\n"


@dataclasses.dataclass
class PredictorResult(WroteFiles):
    """``predictors``: the predictor table; ``measures``: what it was computed from (per
    profiling run in the arena, per frame on footage)."""

    predictors: pl.DataFrame
    measures: pl.DataFrame
    paths: list[Path]
    markdown: str

    def top(self, statistic: str | None = None) -> pl.DataFrame:
        """The measures ranked by ``statistic`` (default: the mode's headline)."""
        if statistic is None:
            stats = set(self.predictors["statistic"].to_list())
            statistic = "rho_failure" if "rho_failure" in stats else "clip_auroc"
        return ranked(self.predictors, statistic)


def write_predictors(
    table: pl.DataFrame,
    measures: pl.DataFrame,
    stage: Path,
    meta: dict[str, Any],
    param: str,
    mode: str,
    title: str,
) -> tuple[list[Path], str]:
    """Write ``predictors.parquet``, the measures table and ``predictors.png`` into ``stage``;
    return the paths and the report section."""

    name = "predictor_measures.parquet" if mode == "arena" else "predictor_frames.parquet"
    paths = [
        write_parquet(table, stage / "predictors.parquet", meta),
        write_parquet(measures, stage / name, meta),
        plot_predictors(table, stage / "predictors.png", title),
    ]
    return paths, predictors_report(table, param, mode)


def settings_meta(folder: Path) -> dict[str, Any]:
    """The boundary settings a folder's tables were written with (Parquet metadata)."""

    for name in ("boundary_runs.parquet", "boundary_clips.parquet"):
        p = folder / name
        if p.exists():
            kv = pq.read_schema(p).metadata or {}
            raw = kv.get(b"vdc.settings")
            if raw:
                return json.loads(raw)
    raise UserError(f"{str(folder)!r} holds no boundary tables (boundary_runs.parquet)")


Log = Callable[[str], None]
