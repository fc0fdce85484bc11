"""The answer of ``vdc-analyse power-study`` (:mod:`analysis.experiments.power.study`), from
the tables its studies wrote.

* ``primary.parquet``: per study (source, detector), the primary comparison named in advance
  (the AVDM against P.910 TI; arena: the difference of their Spearman ρ with the failure rate
  over conditions; footage: of their clip AUROCs), with its 95 % interval, p, n and verdict,
  and each measure's own statistic with its interval;
* ``secondaries.parquet``: every other comparison, Holm-corrected within its study
  (:mod:`analysis.predictors.statistics`);
* ``per_scene.parquet`` / ``per_scene.png`` (exploratory: a post hoc reading, no interval, no
  test; each cell on its scene's few units, ``n``): where each measure fails to rank the
  conditions (arena) or clips (footage, by background photograph). Per scene, over the pairs
  of units whose failure differs, the **discordant share**: the share the measure orders against the
  failure (a higher measure, less failure; ties half). 0: it ranks the scene's units
  perfectly; 0.5: no better than chance; 1: inverted. The column ``across scenes`` takes the
  pairs whose units lie in different scenes: a measure may rank within scenes and not across
  them (the interaction the plan expects), or the reverse;
* ``answer.md``: its first paragraph generated from the corrected table: the verdicts that
  stand after Holm's correction over the judged studies, each study's unit and n (scenes,
  conditions or clips, failing and correct), and what the runs cannot tell.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
from matplotlib.figure import Figure

from analysis.boundary.statistics import WARMUP_FRAMES
from analysis.predictors.inference import holm
from analysis.predictors.report import label, settings_meta, units_phrase
from analysis.predictors.statistics import HEADLINE, MEASURES
from analysis.predictors.verdicts import MIN_CONDITIONS, MIN_FAILURES, MIN_SCENES
from analysis.stats import ALPHA
from vdc.parquet_io import write_parquet

QUICK_BANNER = (
    "**Quick run (`--quick`): its verdicts are not findings.** This is the reduced version of "
    "the plan (a few conditions, a few clips, seconds-long runs) that checks every step "
    "works; far below the plan's power, nothing here answers the question. The plan itself "
    "runs without `--quick` (docs/findings/power_plan.md)."
)
ACROSS = "across scenes"
# the plan's target share of failing conditions (arena) or clips (footage): both classes well
# populated (docs/findings/power_plan.md)
FAILURE_TARGET = (0.30, 0.50)
FAILING = ("miss", "early", "false_alarm")  # a clip's failure modes (boundary footage mode)


def _cell(text: str) -> str:
    """A whole sentence in one Markdown table cell: never cut mid-word (a cell was cut at 100
    characters: "there is no evidence to pla"), its pipes and line breaks escaped."""
    return " ".join(str(text).split()).replace("|", "\\|")


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
    """Per measure and scene (and :data:`ACROSS`), the discordant share (see the module) with
    the units it is over: ``n``, ``n_failing`` and ``n_correct`` (as the predictors count
    them). Exploratory: no interval."""
    names = [m for m in MEASURES if m in units.columns]
    scenes = units["scene"].unique(maintain_order=True).to_list()
    rows = []
    for m in names:
        for sc in [*scenes, ACROSS]:
            part = units if sc == ACROSS else units.filter(pl.col("scene") == sc)
            f = part["failure"].to_numpy()
            group = part["scene"].to_numpy() if sc == ACROSS else None
            rows.append({
                "measure": m,
                "scene": sc,
                "n": part.height,
                "n_failing": int(part["failing"].sum()),
                "n_correct": int((~part["failing"]).sum()),
                "discordant_share": discordant_share(part[m].to_numpy(), f, group),
            })  # fmt: skip
    return pl.DataFrame(rows)


def plot_per_scene(tables: dict[str, pl.DataFrame], path: Path, quick: bool) -> Path:
    """One heat map per study: measures down, scenes across, the discordant share in each cell
    (green 0: ranks perfectly; yellow 0.5: chance; red 1: inverted; grey: no pair to rank)."""
    n = max(1, len(tables))
    fig = Figure(figsize=(6.2 * min(n, 3), 5.2 * math.ceil(n / 3)), layout="constrained")
    axes = np.atleast_1d(fig.subplots(math.ceil(n / 3), min(n, 3))).ravel()
    image = None
    for ax, (title, t) in zip(axes, tables.items(), strict=False):
        measures = t["measure"].unique(maintain_order=True).to_list()
        scenes = t["scene"].unique(maintain_order=True).to_list()
        grid = np.full((len(measures), len(scenes)), np.nan)
        for r in t.iter_rows(named=True):
            grid[measures.index(r["measure"]), scenes.index(r["scene"])] = r["discordant_share"]
        ax.set_facecolor("0.85")
        image = ax.imshow(grid, cmap="RdYlGn_r", vmin=0, vmax=1, aspect="auto")
        for (i, j), v in np.ndenumerate(grid):
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


def _fmt(e: Any, lo: Any, hi: Any, digits: int = 2) -> str:
    if e is None or (isinstance(e, float) and math.isnan(e)):
        return "—"
    if lo is None or hi is None:
        return f"{e:.{digits}f}"
    return f"{e:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


def _p(v: Any) -> str:
    return "—" if v is None else f"{v:.2g}" if v >= 0.001 else "< 0.001"


def primary_row(study: dict[str, Any], table: pl.DataFrame | None) -> dict[str, Any]:
    """The primary comparison of one study (``table``: its predictors.parquet; None: it holds
    no evidence), with the AVDM's and TI's own statistic; a study named in advance as unable
    to inform (``cannot_inform``) keeps its numbers and gets that as its verdict."""
    row = _primary_row(study, table)
    row["deviation"] = study.get("deviation") or ""
    row["planned_value"] = study.get("planned_value", study["value"])
    if study.get("cannot_inform"):
        row["verdict"] = study["cannot_inform"]
    return row


def _primary_row(study: dict[str, Any], table: pl.DataFrame | None) -> dict[str, Any]:
    row = {k: study[k] for k in ("source", "detector", "param", "value", "status")}
    prim = None if table is None else table.filter(pl.col("role") == "primary")
    if prim is None or prim.height == 0:
        return row | {"verdict": study["status"] if table is None else "undetermined"}
    p = prim.row(0, named=True)
    stat = HEADLINE[study["source"]]
    own = {r["measure"]: r for r in table.filter(pl.col("statistic") == stat).iter_rows(named=True)}
    fail, ok = p["n_failing"], p["n_correct"]
    share = fail / (fail + ok) if fail is not None and ok is not None and fail + ok else None
    out = row | {"statistic": stat, "n": p["n"], "n_failing": fail, "n_correct": ok,
                 "failure_share": share, "unit": p["unit"], "n_units": p["n_units"]}  # fmt: skip
    for name, m in (("avdm", "avdm"), ("ti", "ti_p910")):
        r = own.get(m, {})
        out |= {f"{name}_{k}": r.get(k) for k in ("estimate", "ci_low", "ci_high")}
    return out | {
        "difference": p["estimate"],
        "difference_low": p["ci_low"],
        "difference_high": p["ci_high"],
        "p_value": p["p_value"],
        "verdict": p["verdict"],
    }


def share_phrase(r: dict[str, Any]) -> str:
    """A study's failure share beside the plan's target."""
    share = r.get("failure_share")
    if share is None:
        return ""
    lo, hi = FAILURE_TARGET
    where = "inside" if lo <= share <= hi else "outside"
    return f"{100 * share:.0f} % failing, {where} the plan's {100 * lo:.0f}-{100 * hi:.0f} %"


def in_words(r: dict[str, Any]) -> str:
    """One study's primary comparison as a clause, with its unit and n."""
    who = f"{r['source']}, {r['detector']} ({r['param']} {r['value']:g})"
    v = r.get("verdict") or ""
    if r.get("deviation"):
        who += f" [{r['deviation']}]"
    if v.startswith("cannot inform"):
        return f"{who}: {v}; left out of the verdicts"
    if v.startswith("no evidence"):
        return f"{who}: {v.split(';')[0]}"
    if r.get("statistic") is None:
        return f"{who}: undetermined"
    stat = "ρ with the failure rate" if r["source"] == "arena" else "clip AUROC"
    counted = "conditions" if r["source"] == "arena" else "clips"
    icc = r.get("icc_failure")
    icc = "" if icc is None or math.isnan(icc) else f", the failure's ICC over scenes {icc:.2f}"
    est = (
        f"over {units_phrase(r, counted)}{f' ({share})' if (share := share_phrase(r)) else ''}"
        f"{icc}"
        f"; the AVDM's {stat} is "
        f"{_fmt(r['avdm_estimate'], r['avdm_ci_low'], r['avdm_ci_high'])}, TI's "
        f"{_fmt(r['ti_estimate'], r['ti_ci_low'], r['ti_ci_high'])}; the difference "
        f"{_fmt(r['difference'], r['difference_low'], r['difference_high'])}, "
        f"p = {_p(r['p_value'])}"
    )
    if "too few to judge" in v:
        return f"{who}: {est}: no verdict ({v})"
    if v == "both against the expected sign":
        return f"{who}: {est}: both against the expected sign, so neither is better"
    if v in ("better", "worse"):
        across = r.get("p_holm_across")
        held = across is None or across < ALPHA
        tail = "" if held else " alone at 5 %, not after Holm's correction over the studies"
        return f"{who}: {est}: the AVDM predicts the failures {v} than TI{tail}"
    if v.startswith("not shown"):
        return f"{who}: {est}: {v}"
    return f"{who}: {est}: no difference at this power"


# the verdicts a judged study gets (its p tested; the rest: too few units, or no evidence)
JUDGED = (
    "better",
    "worse",
    "no difference shown",
    "both against the expected sign",
    "not shown: the better of the two does not predict failure beyond chance",
)


def with_holm_across(primary: pl.DataFrame) -> pl.DataFrame:
    """``p_holm_across``: each judged study's primary p, Holm-adjusted over the judged studies
    (the plan judges each alone at 5 %; this says which verdicts survive all of them at once).
    Null where a study was not judged."""
    if "p_value" not in primary.columns:
        return primary.with_columns(pl.lit(None, pl.Float64).alias("p_holm_across"))
    judged = primary["verdict"].is_in(list(JUDGED)).to_numpy()
    p = np.where(judged, primary["p_value"].cast(pl.Float64).fill_null(np.nan).to_numpy(), np.nan)
    adj = holm(p)
    return primary.with_columns(
        pl.Series("p_holm_across", [None if np.isnan(v) else float(v) for v in adj], pl.Float64)
    )


def first_paragraph(primary: pl.DataFrame) -> str:
    """answer.md's first paragraph, generated from the corrected table: the verdicts that stand
    after Holm's correction over the judged studies (none is counted uncorrected), each
    study's unit and n, and what the runs cannot tell."""
    rows = list(primary.iter_rows(named=True))
    judged = [r for r in rows if r.get("verdict") in JUDGED]
    decided = [r for r in judged if r.get("verdict") in ("better", "worse")]
    kept = [r for r in decided if (r.get("p_holm_across") or 1.0) < ALPHA]
    few = [r for r in rows if "too few to judge" in (r.get("verdict") or "")]
    mute = [r for r in rows if (r.get("verdict") or "").startswith("cannot inform")]
    parts = []
    if judged:
        names = ", ".join(f"{r['source']} {r['detector']}" for r in kept) or "none"
        parts.append(
            f"with Holm's correction over the {len(judged)} judged "
            f"stud{'ies' if len(judged) != 1 else 'y'}, {len(kept)} of the {len(decided)} "
            f"verdicts {'stands' if len(kept) == 1 else 'stand'} ({names})"
        )
        for r in kept:
            parts.append(
                f"in {r['source']} {r['detector']} the AVDM predicts the failures "
                f"{r['verdict']} than TI"
            )
        inverted = [r for r in judged if r["verdict"] == "both against the expected sign"]
        if inverted:
            names = ", ".join(f"{r['source']} {r['detector']}" for r in inverted)
            parts.append(f"in {names} both are against the expected sign: neither is better")
    if few:
        names = ", ".join(f"{r['source']} {r['detector']}" for r in few)
        parts.append(
            f"{len(few)} of the {len(rows)} studies cannot be judged ({names}): too few "
            "scenes, or units in a class, each says which below ("
            f"{MIN_SCENES} arena scenes and {MIN_CONDITIONS} conditions, or {MIN_SCENES} "
            "footage scenes with "
            f"{MIN_FAILURES} failing and as many correct clips, are needed)"
        )
    if mute:
        names = ", ".join(f"{r['source']} {r['detector']}" for r in mute)
        parts.append(
            f"{len(mute)} named before the runs as unable to inform ({names}) and left out"
        )
    unjudged = len(rows) - len(judged) - len(few) - len(mute)
    if unjudged:
        parts.append(f"{unjudged} without evidence")
    gist = "; ".join(parts) if parts else "no study"
    sure = (
        " How sure: each verdict is a two-sided test at 5 % over scenes (intervals clustered on "
        "them), and only those that survive Holm's correction over the judged studies are "
        "counted here."
    )
    cannot = (
        " What these runs cannot tell: which measure predicts better where a study has too "
        "few scenes; whether other scenes, detector values or settings would change this; "
        "a difference smaller than the plan's powered gap; the per-scene reading below is "
        "exploratory."
    )
    return (
        "**Does the AVDM predict where collision detectors fail better than P.910 TI, over "
        f"scenes?** Across the plan's {len(rows)} studies: {gist}.{sure}{cannot} "
        + "; ".join(in_words(r) for r in rows)
        + "."
    )


def write_answer(
    studies: pl.DataFrame, out: Path, *, quick: bool, plan: Any
) -> tuple[pl.DataFrame, list[Path], str]:
    """The answer's files into ``out`` from the studies' folders: (primary table, paths,
    answer.md's text)."""
    meta = {"quick": quick, "not_findings": quick}
    labels_csv = out / "footage" / "clips" / "labels.csv"
    labels = pl.read_csv(labels_csv) if labels_csv.exists() else None
    prim_rows, secondaries, scene_tables = [], [], {}
    for st in studies.filter(pl.col("source").is_in(list(HEADLINE))).iter_rows(named=True):
        if st["detector"] == "looming-footage":
            continue
        folder = Path(st["folder"])
        ran = st["status"] == "ran" and (folder / "predictors.parquet").exists()
        table = pl.read_parquet(folder / "predictors.parquet") if ran else None
        prim_rows.append(primary_row(st, table))
        if table is None:
            continue
        secondaries.append(
            table.filter(pl.col("role") == "secondary").with_columns(
                pl.lit(st["source"]).alias("source"), pl.lit(st["detector"]).alias("detector")
            )
        )
        units = (
            arena_units(folder)
            if st["source"] == "arena"
            else footage_units(folder, labels if labels is not None else pl.DataFrame())
        )
        # how much of the failure its scene sets: the design effect the power assumed
        prim_rows[-1]["icc_failure"] = icc_oneway(units["failure"].to_numpy(),
                                                  units["scene"].to_numpy())  # fmt: skip
        scene_tables[f"{st['source']}: {st['detector']}"] = per_scene(units).with_columns(
            pl.lit(st["source"]).alias("source"), pl.lit(st["detector"]).alias("detector")
        )
    primary = with_holm_across(pl.DataFrame(prim_rows, infer_schema_length=None))
    sec = pl.concat(secondaries, how="diagonal_relaxed") if secondaries else pl.DataFrame()
    scenes = pl.concat(list(scene_tables.values())) if scene_tables else pl.DataFrame()
    paths = [
        write_parquet(primary, out / "primary.parquet", meta),
        write_parquet(sec, out / "secondaries.parquet", meta),
        write_parquet(scenes, out / "per_scene.parquet", meta),
        plot_per_scene(scene_tables, out / "per_scene.png", quick),
        write_parquet(studies, out / "studies.parquet", meta),
    ]
    text = answer_markdown(primary, sec, studies, quick, plan, scenes)
    md = out / "answer.md"
    tmp = md.with_suffix(".partial")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(md)
    return primary, [*paths, md], text


def scene_sizes(scenes: pl.DataFrame) -> str:
    """The units each scene's cell rests on, in words (the per-scene table's ``units``)."""
    if not scenes.height or "n" not in scenes.columns:
        return ""
    own = scenes.filter(pl.col("scene") != ACROSS)
    if not own.height:
        return ""
    lo, hi = int(own["n"].min()), int(own["n"].max())
    n = f"{lo}" if lo == hi else f"{lo}-{hi}"
    return f"Each scene's cell rests on {n} units."


def answer_markdown(
    primary: pl.DataFrame,
    sec: pl.DataFrame,
    studies: pl.DataFrame,
    quick: bool,
    plan: Any,
    scene_units: pl.DataFrame | None = None,
) -> str:
    """answer.md (see the module); ``scene_units``: the per-scene table."""
    scene_units = pl.DataFrame() if scene_units is None else scene_units
    lines = [QUICK_BANNER + "\n"] if quick else []
    lines += [first_paragraph(primary) + "\n", "## The primary comparison\n"]
    lines += [
        "The AVDM against P.910 TI, named before the runs (docs/findings/power_plan.md and "
        "its amendment): arena, the "
        "difference of their Spearman ρ with a condition's failure rate (Steiger's test, Zou's "
        "interval); footage, of their clip AUROCs (DeLong). 95 % intervals over the scenes "
        "(clustered; t on scenes − 1 degrees of freedom); judged at 5 % alone, and only on at "
        f"least {MIN_SCENES} arena scenes and {MIN_CONDITIONS} conditions, or {MIN_SCENES} "
        "footage scenes with "
        f"{MIN_FAILURES} failing and as many correct clips; a verdict stands in the first "
        "paragraph only after Holm's correction over the judged studies. Failing: the share "
        f"beside the plan's target of {100 * FAILURE_TARGET[0]:.0f}-"
        f"{100 * FAILURE_TARGET[1]:.0f} %.\n",
        "| source | detector | deviation from the plan | units | n | failing | correct | "
        f"failing share (target {100 * FAILURE_TARGET[0]:.0f}-{100 * FAILURE_TARGET[1]:.0f} %)"
        " | AVDM | TI | AVDM − TI | p | Holm p over the studies | verdict |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in primary.iter_rows(named=True):
        dev = r.get("deviation") or "none"
        if r.get("statistic") is None:
            lines.append(f"| {r['source']} | {r['detector']} | {dev} |" + " — |" * 10
                         + f" {_cell(r.get('verdict') or '')} |")  # fmt: skip
            continue
        across = r.get("p_holm_across")
        lines.append(
            f"| {r['source']} | {r['detector']} ({r['param']} {r['value']:g}) | {dev} | "
            f"{r['n_units']} {r['unit']}s | {r['n']} | {r['n_failing']} | {r['n_correct']} | "
            f"{share_phrase(r)} | "
            f"{_fmt(r['avdm_estimate'], r['avdm_ci_low'], r['avdm_ci_high'])} | "
            f"{_fmt(r['ti_estimate'], r['ti_ci_low'], r['ti_ci_high'])} | "
            f"{_fmt(r['difference'], r['difference_low'], r['difference_high'], 3)} | "
            f"{_p(r['p_value'])} | {_p(across) if across is not None else '—'} | "
            f"{r['verdict']} |"
        )
    lines += ["", "## Secondary comparisons (Holm-corrected within each study)\n"]
    if sec.height:
        judged = sec.filter(pl.col("p_holm").is_not_null())
        kept = judged.filter(pl.col("survives"))
        lines.append(
            f"{sec.height} secondary comparisons (`secondaries.parquet`); {judged.height} "
            f"judged (the rest below the power thresholds), {kept.height} survive Holm's "
            "correction at 5 %" + (":\n" if kept.height else ".\n")
        )
        if kept.height:
            lines += ["| detector | comparison | measure | AVDM − measure | Holm p |",
                      "|---|---|---|---|---|"]  # fmt: skip
            for r in kept.sort("p_holm").iter_rows(named=True):
                lines.append(
                    f"| {r['source']}: {r['detector']} | {r['statistic']} | {label(r['measure'])}"
                    f" | {_fmt(r['estimate'], r['ci_low'], r['ci_high'], 3)} | "
                    f"{_p(r['p_holm'])} |"
                )
            lines.append("")
    else:
        lines.append("None: no study held the evidence to compare measures.\n")
    lines += [
        "## Where each measure fails to rank the conditions (exploratory)\n",
        "![per scene: the share of pairs each measure orders against the failure](per_scene.png)\n",
        "**Exploratory: a post hoc reading, not planned, with no interval and no test.** Per "
        "scene (arena: wall scene, its conditions the drawn TFs; footage: the background "
        "photograph, its units the clips), over the pairs of units whose failure differs, the "
        "share the measure orders against the failure (0: ranks them; 0.5: chance; 1: "
        "inverted); the last column takes the pairs from different scenes "
        f"(`per_scene.parquet`, with each cell's units). {scene_sizes(scene_units)}\n",
        "## The studies\n",
        f"The plan: {plan.conditions()} arena conditions ({len(plan.scenes)} scenes × "
        f"{plan.tf_draws} TFs from {plan.tf_range} Hz) × {plan.seeds} seed(s) of "
        f"{plan.minutes:g}-min runs, {plan.arena_runs()} runs with the profiling; "
        f"{plan.clips} clips of {plan.clip_seconds:g} s. Version "
        f"{getattr(plan, 'name', '2026-11')} of the plan"
        + (
            " (docs/findings/power_plan_amendment.md)"
            if getattr(plan, "name", "") == "2026-12"
            else " (docs/findings/power_plan.md)"
        )
        + ".\n",
        "| source | detector | units | failing in the confirmation | deviation from the plan "
        "| computed by this call | status | folder |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in studies.iter_rows(named=True):
        conf = r.get("first_seed_failing")
        conf = "—" if conf is None else f"{100 * conf:.0f} %"
        dev = r.get("deviation") or "none"
        lines.append(f"| {r['source']} | {r['detector']} | {r['units']} | {conf} | {dev} | "
                     f"{r['recomputed']} | {_cell(r['status'])} | "
                     f"`{Path(r['folder']).name}` |")  # fmt: skip
    cmd = f"vdc-analyse power-study --plan {getattr(plan, 'name', '2026-11')}" + (
        " --quick" if quick else ""
    )
    lines += ["", f"Re-run (finished runs are reused): `{cmd} --out <this folder>`.\n"]
    return "\n".join(lines)
