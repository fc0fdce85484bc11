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
  conditions (arena) or clips (footage, by background photograph;
  :mod:`analysis.experiments.power.units`). Per scene, over the pairs of units whose failure
  differs, the **discordant share**: the share the measure orders against the failure (a
  higher measure, less failure; ties half). 0: it ranks the scene's units perfectly; 0.5: no
  better than chance; 1: inverted. The column ``across scenes`` takes the pairs whose units
  lie in different scenes: a measure may rank within scenes and not across them (the
  interaction the plan expects), or the reverse;
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

from analysis.experiments.power.units import (
    ACROSS,
    arena_units,
    discordant_share,
    footage_units,
    icc_oneway,
    per_scene,
    plot_scene_table,
)
from analysis.predictors.inference import holm
from analysis.predictors.report import CHANCE, label, units_phrase
from analysis.predictors.statistics import HEADLINE
from analysis.predictors.verdicts import MIN_CONDITIONS, MIN_FAILURES, MIN_SCENES
from analysis.stats import ALPHA
from vdc.parquet_io import write_parquet

# the units' names, importable from here as before they had their own module
__all__ = [
    "FAILURE_TARGET",
    "QUICK_BANNER",
    "against_sign",
    "answer_markdown",
    "discordant_share",
    "first_paragraph",
    "footage_units",
    "icc_oneway",
    "in_words",
    "primary_row",
    "scene_sizes",
    "share_phrase",
    "study_lines",
    "with_holm_across",
    "write_answer",
]

QUICK_BANNER = (
    "**Quick run (`--quick`): its verdicts are not findings.** This is the reduced version of "
    "the plan (a few conditions, a few clips, seconds-long runs) that checks every step "
    "works; far below the plan's power, nothing here answers the question. The plan itself "
    "runs without `--quick` (docs/findings/power_plan.md)."
)
# the plan's target share of failing conditions (arena) or clips (footage): both classes well
# populated (docs/findings/power_plan.md)
FAILURE_TARGET = (0.30, 0.50)
FAILING = ("miss", "early", "false_alarm")  # a clip's failure modes (boundary footage mode)


def _cell(text: str) -> str:
    """A whole sentence in one Markdown table cell: never cut mid-word (a cell was cut at 100
    characters: "there is no evidence to pla"), its pipes and line breaks escaped."""
    return " ".join(str(text).split()).replace("|", "\\|")


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
    out = row | {
        "statistic": stat,
        "n": p["n"],
        "n_failing": fail,
        "n_correct": ok,
        "failure_share": share,
        "unit": p["unit"],
        "n_units": p["n_units"],
    }
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


# the plan's detectors by the names a reader knows them (the tables keep the specs)
DETECTOR_NAMES = {
    "lgmd-plus-arena": "LGMD+",
    "lgmd-plus": "LGMD+",
    "flow-ttc": "optic-flow TTC",
    "examples.looming:Looming": "OpenCV looming",
}
WHERE = {"arena": "in the arena", "footage": "on footage"}


def _and(items: list[str]) -> str:
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + " and " + items[-1]


def _names(rows: list[dict[str, Any]]) -> str:
    return _and(
        [
            f"{DETECTOR_NAMES.get(r['detector'], r['detector'])} "
            f"{WHERE.get(r['source'], r['source'])}"
            for r in rows
        ]
    )


def _ps(rows: list[dict[str, Any]]) -> str:
    """The AVDM − TI difference's p of each row, alone and after Holm over the studies."""
    alone = _and([_p(r.get("p_value")) for r in rows])
    holm_ = _and([_p(r.get("p_holm_across")) for r in rows])
    return f"p {alone} alone, {holm_} after Holm's correction over the studies"


def against_sign(r: dict[str, Any], measure: str = "avdm") -> bool:
    """True when ``measure``'s own interval lies wholly against the expected sign."""
    high = r.get(f"{measure}_ci_high")
    # chance: ρ 0, AUROC 0.5; the expected sign is above it (more complexity, more failure)
    chance = CHANCE.get(r.get("statistic") or "", 0.5)
    return high is not None and not math.isnan(high) and high < chance


def first_paragraph(primary: pl.DataFrame) -> str:
    """answer.md's first paragraph, generated from the corrected table, in plain words: the
    answer (only verdicts that stand after Holm's correction over the judged studies count),
    what each kind of study showed, how sure (the unit and n), and what the runs cannot tell.
    The numbers follow it, a study a line (:func:`study_lines`)."""
    rows = list(primary.iter_rows(named=True))
    judged = [r for r in rows if r.get("verdict") in JUDGED]
    kept = [
        r
        for r in judged
        if r.get("verdict") in ("better", "worse") and (r.get("p_holm_across") or 1.0) < ALPHA
    ]
    better = [r for r in kept if r["verdict"] == "better"]
    worse = [r for r in kept if r["verdict"] == "worse"]
    inverted = [r for r in judged if r["verdict"] == "both against the expected sign"]
    chance = [r for r in judged if (r.get("verdict") or "").startswith("not shown")]
    few = [r for r in rows if "too few to judge" in (r.get("verdict") or "")]
    mute = [r for r in rows if (r.get("verdict") or "").startswith("cannot inform")]
    if better:
        answer = f"Yes, in {len(better)} of the {len(judged)} studies judged ({_names(better)})."
    elif judged:
        answer = f"No: in none of the {len(judged)} studies judged does it predict them better."
    else:
        answer = "Not known: no study could be judged."
    parts = [answer]
    if judged:
        parts.append(
            "(Expected: the more complex the scene, the more the detector fails, so a Spearman ρ "
            "above 0 with the failure rate in the arena, a clip AUROC above 0.5 on footage.)"
        )
    if worse:
        parts.append(f"TI predicts them better for {_names(worse)}.")
    if inverted:
        parts.append(
            f"For {_names(inverted)}, both measures' estimates fall against that sign, so "
            f"neither predicts the failures as expected (their difference: {_ps(inverted)})."
        )
    if chance:
        lead = [r for r in chance if (r.get("difference") or 0.0) < 0]
        parts.append(
            f"For {_names(chance)}, neither predicts the failures beyond chance"
            + (
                f"; TI came out ahead of the AVDM ({_ps(lead)})"
                if lead and len(lead) == len(chance)
                else f" (their difference: {_ps(chance)})"
            )
            + "."
        )
    rest = [r for r in judged if r not in kept + inverted + chance]
    if rest:
        parts.append(
            f"For {_names(rest)}, no difference survives Holm's correction over the studies."
        )
    wholly = [r for r in judged if against_sign(r)]
    if wholly:
        parts.append(
            f"The AVDM's own interval lies wholly against the expected sign for {_names(wholly)}:"
            " where it responds more, the detector fails less (read from the intervals, not a"
            " planned test)."
        )
    if few:
        parts.append(
            f"Too few scenes, or units in a class, to judge {_names(few)} ({MIN_SCENES} arena "
            f"scenes and {MIN_CONDITIONS} conditions, or {MIN_SCENES} footage scenes with "
            f"{MIN_FAILURES} failing and as many correct clips, are needed)."
        )
    if mute:
        parts.append(
            f"{'The study' if len(mute) == 1 else 'The studies'} {_names(mute)} "
            f"{'was' if len(mute) == 1 else 'were'} named before the runs as unable to inform, "
            "and left out."
        )
    if judged:
        sizes = ", ".join(
            sorted(
                {
                    f"{r['n_units']} {r['unit']}s {WHERE.get(r['source'], r['source'])}"
                    for r in judged
                }
            )
        )
        parts.append(
            f"How sure: each study is a two-sided test at 5 % with the scene as the unit "
            f"({sizes}; intervals clustered on scenes), and a verdict counts only if it "
            f"survives Holm's correction over the {len(judged)} judged studies."
        )
    parts.append(
        "What these runs cannot tell: whether other scenes, detector values or settings "
        "would change this; a difference smaller than the plan was powered to find; why a "
        "measure goes against its expected sign (answer.md's per-scene reading is exploratory)."
    )
    return (
        "**Does the AVDM predict where collision detectors fail better than P.910 TI, over "
        "scenes?** " + " ".join(parts)
    )


def study_lines(primary: pl.DataFrame) -> list[str]:
    """Each study's primary comparison in words, a bullet each (:func:`in_words`)."""
    return [f"- {in_words(r)}." for r in primary.iter_rows(named=True)]


def write_answer(
    studies: pl.DataFrame, out: Path, *, quick: bool, plan: Any
) -> tuple[pl.DataFrame, list[Path], str]:
    """The answer's files into ``out`` from the studies' folders: (primary table, paths,
    answer.md's text)."""
    meta = {"quick": quick, "not_findings": quick}
    labels_csv = out / "footage" / "clips" / "labels.csv"
    labels = pl.read_csv(labels_csv) if labels_csv.exists() else None
    prim_rows, secondaries, scene_tables = [], [], []
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
        prim_rows[-1]["icc_failure"] = icc_oneway(
            units["failure"].to_numpy(), units["scene"].to_numpy()
        )
        scene_tables.append(
            per_scene(units).with_columns(
                pl.lit(st["source"]).alias("source"), pl.lit(st["detector"]).alias("detector")
            )
        )
    primary = with_holm_across(pl.DataFrame(prim_rows, infer_schema_length=None))
    sec = pl.concat(secondaries, how="diagonal_relaxed") if secondaries else pl.DataFrame()
    scenes = pl.concat(scene_tables) if scene_tables else pl.DataFrame()
    paths = [
        write_parquet(primary, out / "primary.parquet", meta),
        write_parquet(sec, out / "secondaries.parquet", meta),
        write_parquet(scenes, out / "per_scene.parquet", meta),
        plot_scene_table(scenes, out / "per_scene.png", quick),
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
    lines += [
        first_paragraph(primary) + "\n",
        *study_lines(primary),
        "",
        "## The primary comparison\n",
    ]
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
            lines.append(
                f"| {r['source']} | {r['detector']} | {dev} |"
                + " — |" * 10
                + f" {_cell(r.get('verdict') or '')} |"
            )
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
            lines += [
                "| detector | comparison | measure | AVDM − measure | Holm p |",
                "|---|---|---|---|---|",
            ]
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
        lines.append(
            f"| {r['source']} | {r['detector']} | {r['units']} | {conf} | {dev} | "
            f"{r['recomputed']} | {_cell(r['status'])} | "
            f"`{Path(r['folder']).name}` |"
        )
    cmd = f"vdc-analyse power-study --plan {getattr(plan, 'name', '2026-11')}" + (
        " --quick" if quick else ""
    )
    lines += ["", f"Re-run (finished runs are reused): `{cmd} --out <this folder>`.\n"]
    return "\n".join(lines)
