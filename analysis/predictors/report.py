"""The predictors' figure, report section and files (``predictors.png``, the section of
``boundary.md``, ``predictors.parquet``): what :mod:`analysis.predictors.statistics` computed,
ranked and
written."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from pathlib import Path
from textwrap import fill
from typing import Any

import numpy as np
import polars as pl
import pyarrow.parquet as pq
from matplotlib.figure import Figure

from analysis.predictors.statistics import HEADLINE
from analysis.predictors.verdicts import MIN_CONDITIONS, MIN_FAILURES, MIN_SCENES, table_note
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


# measures and statistics as a person names them, with units (the table keeps the ids)
LABELS = {
    "avdm": "AVDM, paper (deg/s)",
    "avdm_natural": "AVDM, natural (deg/s)",
    "si_p910": "spatial information, P.910",
    "ti_p910": "temporal information, P.910",
    "si_legacy": "spatial information, P.910 (1999)",
    "ti_legacy": "temporal information, P.910 (1999)",
    "mafd": "mean absolute frame difference (grey levels)",
    "flow_dps": "optic flow, DIS (deg/s)",
    "edge_density": "edge density (share of pixels)",
    "jpeg_bpp": "JPEG size (bits/pixel)",
    "codec_bpp": "H.264 size (bits/pixel)",
    "zlib_ratio": "zlib compression ratio",
}
STATS = {
    "rho_failure": "rank correlation with the failure rate (Spearman ρ, over conditions)",
    "loco_balanced_accuracy": "held-out balanced accuracy (one condition left out at a time)",
    "clip_auroc": "AUROC: a clip the detector gets wrong",
    "clip_auroc_miss": "AUROC: a missed collision (no alert, or too late)",
    "clip_auroc_early": "AUROC: an alert too early",
    "clip_auroc_false_alarm": "AUROC: an alert on a clip without collision",
    "frame_auroc_pooled": "AUROC per frame: a false alert (frames pooled, clustered by clip)",
    "frame_auroc_within_clip": "AUROC per frame within a clip (mean over clips)",
}
CHANCE = {"rho_failure": 0.0}  # the rest: AUROC-like, chance 0.5
EMPTY = (
    "no statistic could be computed: the arena needs at least 3 conditions with runs whose "
    "success varies (4 for an interval on ρ; {conds} conditions over {scenes} scenes to "
    "compare two measures); footage "
    "needs clips the detector gets wrong and clips it gets right ({fails} of each, over "
    "{scenes} scenes, to compare)"
)


def _empty() -> str:
    return EMPTY.format(conds=MIN_CONDITIONS, fails=MIN_FAILURES, scenes=MIN_SCENES)


def label(measure: str) -> str:
    """A measure, or a set of measures joined by ``+``, as a person names it."""
    return " + ".join(LABELS.get(m, m) for m in measure.split("+"))


def plot_predictors(table: pl.DataFrame, path: Path, title: str) -> Path:
    """Each measure's predictive power with its 95 % interval, ranked, one panel per headline
    statistic present, one colour per parameter value; with none, one panel saying why."""
    stats = [s for s in STATS if table.filter(pl.col("statistic") == s).height]
    fig = Figure(figsize=(6 * max(1, len(stats)), 5.5), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, max(1, len(stats))))
    if not stats:  # never a blank figure: the reason, in the panel
        ax = axes[0]
        ax.text(0.5, 0.5, fill(_empty(), 60), ha="center", va="center", transform=ax.transAxes)
        ax.set_axis_off()
        ax.set_title("no estimate")
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
                ax.errorbar(
                    r["estimate"],
                    y,
                    xerr=[[r["estimate"] - lo], [hi - r["estimate"]]],
                    fmt="o",
                    color=f"C{k % 10}",
                    ms=4,
                    capsize=2,
                    label=f"{v:g}" if r["measure"] == order[-1] else None,
                )
        ax.set_yticks(range(len(order)), [label(m) for m in order], fontsize=7)
        ax.axvline(CHANCE.get(stat, 0.5), color="k", lw=0.8, ls=":")
        # an empty panel says why rather than showing nothing
        name = fill(STATS[stat], 45)
        ax.set_title(name if drawn else f"{name}: no estimate (success did not vary)", fontsize=9)
        ax.set_xlabel("estimate and its 95 % interval (dotted: chance)")
        ax.grid(alpha=0.3)
        if drawn:
            ax.legend(fontsize=7, title="value", title_fontsize=7)
    # wrapped to the figure's width: one panel is 6 in, about 50 characters of a suptitle
    # (14.4 pt, a character about 0.6 of that wide); a detector's module path runs longer
    fig.suptitle(fill(title, max(30, int(fig.get_figwidth() * 72 / (14.4 * 0.6)))))
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    return path


def _fmt(r: dict[str, Any] | None, digits: int = 2) -> str:
    if r is None or r["estimate"] is None:
        return "—"
    e, lo, hi = r["estimate"], r["ci_low"], r["ci_high"]
    if lo is None or hi is None:
        return f"{e:.{digits}f}"
    return f"{e:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


def _p(v: Any) -> str:
    return "—" if v is None else f"{v:.2g}" if v >= 0.001 else "< 0.001"


def units_phrase(r: dict[str, Any], counted: str) -> str:
    """A row's units in words: "8 scenes, 96 clips" where it clusters on scenes, else "96 clips
    taken as independent"; then its failing and correct units."""
    if r["unit"] == "scene":
        units = f"{r['n_units']} scenes, {r['n']} {counted}"
    else:
        units = f"{r['n']} {counted} taken as independent"
    if r.get("n_failing") is None:
        return units
    return f"{units}: {r['n_failing']} failing, {r['n_correct']} correct"


def primary_clause(r: dict[str, Any], avdm: str, ti: str) -> str:
    """What the primary comparison row ``r`` says, in words (``avdm``/``ti``: their own
    statistics as text)."""
    v = r["verdict"] or ""
    if "too few to judge" in v:
        return f"no verdict: {v}"
    if v in ("better", "worse"):
        return f"the AVDM predicts the failures {v} than TI (p = {_p(r['p_value'])})"
    if v == "both against the expected sign":
        return (
            f"no verdict: both are against the expected sign (AVDM {avdm}, TI {ti}: a higher "
            "measure with less failure), so neither predicts it and neither is better"
        )
    if v.startswith("not shown"):
        return f"no verdict: {v.removeprefix('not shown: ')}"
    return "no evidence that the AVDM does better or worse than TI"


def predictor_headline(table: pl.DataFrame, param: str, mode: str) -> str:
    """The section's first paragraph, generated from the judged table: the paper's question
    (the AVDM against P.910 TI, named in advance) answered per parameter value with its unit
    and n; how many secondary comparisons survive Holm; and what the runs cannot tell."""
    counted = "conditions" if mode == "arena" else "clips"
    prim = table.filter(pl.col("role") == "primary")
    if not table.height or not prim.height:
        why = _empty()
        return f"These runs cannot say whether the AVDM predicts failure better than TI: {why}."
    stat = HEADLINE[mode]
    parts = []
    for r in prim.iter_rows(named=True):
        own = table.filter((pl.col("statistic") == stat) & (pl.col("value") == r["value"]))
        get = {x["measure"]: x for x in own.iter_rows(named=True)}
        avdm, ti = _fmt(get.get("avdm")), _fmt(get.get("ti_p910"))
        at = f"at {param} {r['value']:g} ({units_phrase(r, counted)}; AVDM {avdm}, TI {ti})"
        parts.append(f"{at}: {primary_clause(r, avdm, ti)}")
    sec = table.filter(pl.col("role") == "secondary")
    judged = sec.filter(pl.col("p_holm").is_not_null())
    kept = judged.filter(pl.col("verdict").is_in(["better", "worse"]))
    second = (
        f" Of {sec.height} secondary comparison{'s' if sec.height != 1 else ''}, "
        f"{judged.height} had the units to be judged "
        f"and {kept.height} {'keeps a verdict' if kept.height == 1 else 'keep a verdict'} after "
        "Holm's correction."
    )
    cannot = []
    if prim.filter(pl.col("verdict").str.contains("too few to judge")).height:
        cannot.append(
            "which measure predicts better, from fewer scenes or failures than a verdict needs"
        )
    note = table_note(table)
    if note:
        cannot.append(f"whether it holds over scenes: the {counted} were taken as independent")
    cannot.append("whether other scenes, detector values or settings would change this")
    return (
        "**In one sentence:** does the paper's AVDM predict where this detector fails better "
        f"than P.910 TI ({STATS[stat]}; 95 % intervals)? "
        + "; ".join(parts)
        + "."
        + second
        + " What these runs cannot tell: "
        + "; ".join(cannot)
        + "."
    )


def predictors_report(table: pl.DataFrame, param: str, mode: str) -> str:
    """The ``## Which measure predicts it`` section of ``boundary.md``: the answer first, then
    every measure's statistic, then each comparison with its units, n, p, Holm's p and whether
    it survives."""
    note = table_note(table)
    over = (
        "scenes (conditions' wall scenes; clips' `scene`)"
        if note is None
        else ("conditions (seeds resampled within them)" if mode == "arena" else "clips")
    )
    lines = [
        "## Which measure predicts where it breaks\n",
        predictor_headline(table, param, mode) + "\n",
        *([f"**{note}**\n"] if note else []),
        "![each measure's predictive power, ranked, 95 % intervals](predictors.png)\n",
        f"Every measure per value of `{param}`, with its 95 % interval over the {over} "
        "(`predictors.parquet`: each row names its `unit`, `n_units`, its n and its failing "
        "and correct units). The one comparison named in advance is the paper's AVDM against "
        "P.910 TI; every other is Holm-corrected. No comparison is judged on fewer than "
        f"{MIN_SCENES} scenes and {MIN_CONDITIONS} conditions (arena) or {MIN_SCENES} scenes "
        f"and {MIN_FAILURES} failing "
        "and as many correct clips (footage): 80 % power for the effects in question, and "
        "enough scenes for an interval over them to hold (docs/method/boundary.md). A measure is "
        "better only when it predicts the failures beyond chance itself.\n",
    ]
    values = table["value"].unique(maintain_order=True).to_list()
    for stat in STATS:
        t = table.filter(pl.col("statistic") == stat)
        if not t.height:
            continue
        order = ranked(table, stat)["measure"].to_list()
        lines.append(
            f"### {STATS[stat]} (intervals over {t['n_units'].max()} {t['unit'][0]}s; "
            f"n = {t['n'].max()} at most)\n"
        )
        lines.append("| measure | " + " | ".join(f"{param} {v:g}" for v in values) + " |")
        lines.append("|---|" + "---|" * len(values))
        for m in order:
            cells = []
            for v in values:
                r = t.filter((pl.col("measure") == m) & (pl.col("value") == v))
                cells.append(_fmt(r.row(0, named=True)) if r.height else "—")
            lines.append(f"| {label(m)} | " + " | ".join(cells) + " |")
        lines.append("")
    cmp = table.filter(pl.col("role").is_not_null())
    if cmp.height:
        lines.append("### Comparisons (the AVDM minus the measure; Holm-corrected but the first)\n")
        lines.append(
            f"| against | statistic | {param} | difference [95 %] | units | n | failing | "
            "correct | p | Holm p | survives | verdict |"
        )
        lines.append("|---|---|---|---|---|---|---|---|---|---|---|---|")
        cmp = cmp.sort(pl.col("role") != "primary", "statistic", "value")
        for r in cmp.iter_rows(named=True):
            ref = r["statistic"].rsplit("_vs_", 1)[-1]
            head = r["statistic"].removeprefix("paired_").rsplit("_vs_", 1)[0]
            stat = STATS.get(head, head).split(" (")[0]
            who = (
                f"{label(ref)} vs {label(r['measure'])}"
                if r["statistic"].startswith("paired_")
                else f"{label(r['measure'])} vs SI + TI"
            )
            if r["role"] == "primary":
                who = f"**{who} (primary)**"
            surv = "—" if r["survives"] is None else "yes" if r["survives"] else "no"
            lines.append(
                f"| {who} | {stat} | {r['value']:g} | {_fmt(r, 3)} | {r['n_units']} "
                f"{r['unit']}s | {r['n']} | {r['n_failing']} | {r['n_correct']} | "
                f"{_p(r['p_value'])} | {_p(r['p_holm'])} | {surv} | {r['verdict']} |"
            )
        lines.append("")
    if not table.height:
        lines.append(_empty().capitalize() + ".\n")
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
    note = table_note(table)  # the units taken as independent, said in the table too
    paths = [
        write_parquet(table, stage / "predictors.parquet", meta | {"units_note": note}),
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
    raise UserError(f"{str(folder)!r} holds no boundary tables (boundary_runs.parquet).")


Log = Callable[[str], None]
