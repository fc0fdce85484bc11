"""Reproduce the paper end to end and report, claim by claim, what holds.

Steps: the SF–TF sweep (Fig. 3); the open-loop approach (Fig. 4); closed-loop profiling of grating
TF 0, 1, 3 Hz and natural scene TF 0, 3 Hz (Figs. 6–7); the collision study (Fig. 8) with the
complexity-adaptive detector. Captures run as parallel processes and finished ones (same
configuration) are reused. Every number in the report is computed from the tables written beside
it (``claims.parquet`` holds them too).
"""

from __future__ import annotations

import base64
import dataclasses
import html
import json
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import polars as pl

from analysis.collision import CollisionSettings, collision, collision_table_markdown
from analysis.experiments.approach import ApproachConfig, plot_approach, run_approach
from analysis.experiments.captures import CaptureItem, run_captures
from analysis.experiments.collision_study import phase_items, study_phases
from analysis.experiments.sweep import SweepConfig, monotonicity, paper_cells, plot_paper, run_sweep
from analysis.parquet_io import read_metadata, write_parquet
from analysis.profile import (
    ProfileSettings,
    plot_overview,
    plot_segment,
    segment_summary,
    segments_from_tables,
)
from analysis.rrd_reader import Recording
from analysis.tables import SummarySettings, build_tables
from capture.sim import SimSettings

PROFILE_CONDITIONS = (
    ("grating", 0.0),
    ("grating", 1.0),
    ("grating", 3.0),
    ("natural", 0.0),
    ("natural", 3.0),
)


@dataclasses.dataclass(frozen=True)
class ReproduceSettings:
    """``vdc-analyse reproduce``: durations and repeats; ``quick`` finishes in minutes, the
    default is the paper's. ``make(quick, **overrides)`` applies the quick durations first."""

    quick: bool = False
    profile_minutes: float = 30.0
    collision_minutes: float = 30.0
    approach_repeats: int = 10
    sweep_duration_s: float = 1.0
    seed: int = 1
    jobs: int = 2
    detector: str = "lgmd-plus-arena"
    adjusted: str = "t_ffi=30"

    @classmethod
    def make(cls, quick: bool, **kw: Any) -> ReproduceSettings:
        if quick:
            base = {
                "profile_minutes": 3.0,
                "collision_minutes": 3.0,
                "approach_repeats": 3,
                "sweep_duration_s": 0.5,
            }
            base.update({k: v for k, v in kw.items() if v is not None})
            return cls(quick=True, **base)
        return cls(quick=False, **{k: v for k, v in kw.items() if v is not None})


def profile_items(plan: ReproduceSettings, folder: Path) -> list[CaptureItem]:
    """The closed-loop profiling runs: one per (scene, TF) condition."""
    return [
        (
            f"{scene}-tf{tf:g}",
            SimSettings(scene=scene, tf_hz=tf, minutes=plan.profile_minutes, seed=plan.seed),
            folder / f"{scene}-tf{tf:g}.rrd",
        )
        for scene, tf in PROFILE_CONDITIONS
    ]


@dataclasses.dataclass
class Claim:
    claim: str
    paper: str
    measured: str
    verdict: str  # holds | partly | does not hold


def _verdict(all_ok: bool, any_ok: bool = False) -> str:
    return "holds" if all_ok else ("partly" if any_ok else "does not hold")


def evaluate_claims(out: Path) -> list[Claim]:
    """Every claim, from the tables in ``out`` (nothing else)."""
    claims = []
    mono = pl.read_parquet(out / "sweep" / "monotonicity.parquet")
    tf_rows = mono.filter(pl.col("along") == "tf")
    sf_cols = mono.filter(pl.col("along") == "sf")
    valid_rows = tf_rows.filter(pl.col("fixed_value") < 50)
    ok_rows = bool((valid_rows["rho"] > 0.5).all())
    ok_cols = bool((sf_cols["rho"] < -0.5).all())
    rho_txt = ", ".join(f"{r['fixed']}: ρ = {r['rho']:+.2f}" for r in mono.iter_rows(named=True))
    claims.append(
        Claim(
            "The AVDM response maps monotonically onto SF–TF (Fig. 3)",
            "monotonic: rises with TF, falls with SF",
            f"Spearman ρ of ω̂ along each row/column: {rho_txt}. SF = 50 upc (2 px period, the "
            "Nyquist limit: counter-phase flicker) is not a valid motion stimulus and is excluded.",
            _verdict(ok_rows and ok_cols, ok_rows or ok_cols),
        )
    )

    ap = pl.read_parquet(out / "approach" / "approach.parquet")
    near = (
        ap.filter(pl.col("distance_m") < 0.10)
        .group_by("tf_hz")
        .agg(pl.col("omega_dps").mean().alias("near"))
        .sort("tf_hz")
    )
    far = (
        ap.filter(pl.col("distance_m") > 0.40)
        .group_by("tf_hz")
        .agg(pl.col("omega_dps").mean().alias("far"))
        .sort("tf_hz")
    )
    j = near.join(far, on="tf_hz")
    rises = bool((j["near"] > j["far"]).all())
    by_tf = ap.group_by("tf_hz").agg(pl.col("omega_dps").mean().alias("m")).sort("tf_hz")
    tf_up = bool((by_tf["m"].diff().drop_nulls() > 0).all())
    claims.append(
        Claim(
            "Approaching a wall raises the AVDM response, more so at higher wall TF (Fig. 4)",
            "response grows as the robot nears the wall, and with TF",
            "mean ω̂ > 40 cm / < 10 cm from the wall: "
            + ", ".join(
                f"TF {r['tf_hz']:g}: {r['far']:.1f} → {r['near']:.1f} deg/s"
                for r in j.iter_rows(named=True)
            )
            + "; whole-approach mean by TF: "
            + ", ".join(f"{r['m']:.1f}" for r in by_tf.iter_rows(named=True)),
            _verdict(rises and tf_up, rises or tf_up),
        )
    )

    prof = pl.read_parquet(out / "profiling" / "profile_summary.parquet")
    ratios = prof.select("scene", "wall_tf_hz", "near_wall_centre_ratio").sort(
        "scene", "wall_tf_hz"
    )
    ok_near = bool((ratios["near_wall_centre_ratio"] > 1).all())
    claims.append(
        Claim(
            "The response (visual dynamic complexity) is stronger near the walls (Figs. 6–7)",
            "higher near the walls than in the centre",
            "near-wall / centre mean ω̂: "
            + ", ".join(
                f"{r['scene']} TF {r['wall_tf_hz']:g}: {r['near_wall_centre_ratio']:.2f}"
                for r in ratios.iter_rows(named=True)
            ),
            _verdict(ok_near, bool((ratios["near_wall_centre_ratio"] > 1).any())),
        )
    )

    def frac(scene: str) -> pl.DataFrame:
        return prof.filter(pl.col("scene") == scene).sort("wall_tf_hz")

    # The paper's "AVDM > 100" counts are in the released code's uncalibrated units (a = 100,
    # b = 1); our ω̂ is calibrated in deg/s, where 100 deg/s is mostly the robot's own 120°/s
    # turns. The mean response carries the trend in our units; both are reported.
    g = frac("grating")
    g_mean_up = bool((g["mean"].diff().drop_nulls() > 0).all())
    g_frac_up = bool((g["frac_over_100"].diff().drop_nulls() > 0).all())
    claims.append(
        Claim(
            "The profiled complexity rises with the walls' TF (grating TF 0, 1, 3 Hz)",
            "more AVDM responses over 100 (paper's uncalibrated units) at higher TF",
            "mean ω̂: "
            + ", ".join(
                f"TF {r['wall_tf_hz']:g}: {r['mean']:.1f} deg/s" for r in g.iter_rows(named=True)
            )
            + "; fraction of frames over 100 deg/s: "
            + ", ".join(
                f"TF {r['wall_tf_hz']:g}: {100 * r['frac_over_100']:.1f} %"
                for r in g.iter_rows(named=True)
            )
            + " (in calibrated deg/s, 100 is above the walls' drift and mostly counts the robot's "
            "own turns)",
            _verdict(g_mean_up and g_frac_up, g_mean_up or g_frac_up),
        )
    )
    n = frac("natural")
    n_up = bool((n["mean"].diff().drop_nulls() > 0).all())
    n_near = bool((n["near_wall_centre_ratio"] > 1).all())
    claims.append(
        Claim(
            "A drifting natural scene behaves like the grating",
            "same trends: complexity rises with TF, stronger near walls",
            "natural scene: "
            + ", ".join(
                f"TF {r['wall_tf_hz']:g}: mean {r['mean']:.1f} deg/s, "
                f"{100 * r['frac_over_100']:.1f} % over 100, "
                f"near/centre {r['near_wall_centre_ratio']:.2f}"
                for r in n.iter_rows(named=True)
            ),
            _verdict(n_up and n_near, n_up or n_near),
        )
    )

    col = pl.read_parquet(out / "collision" / "collision_summary.parquet")
    s = {r["phase"]: r for r in col.iter_rows(named=True)}

    def pct(key: str) -> str:
        r = s.get(key)
        return (
            "n/a"
            if r is None
            else f"{100 * r['success_rate']:.1f} % ({r['avoidances']} "
            f"avoidances, {r['crashes']} crashes)"
        )

    if {"tf0", "tf3", "tf3-adjusted"} <= set(s):
        boundary = s["tf3"]["success_rate"] < min(0.9, s["tf0"]["success_rate"])
        works = s["tf0"]["success_rate"] >= 0.9
        recovers = s["tf3-adjusted"]["success_rate"] >= 0.9
        claims.append(
            Claim(
                "The collision detector works on static walls, breaks down at TF 3 Hz, and "
                "recovers with an adjusted threshold (Fig. 8)",
                "success > 90 % in all three phases; 229 → 432 avoidances at TF 3 (extra alerts), "
                "233 with the adjusted threshold",
                f"TF 0: {pct('tf0')}; TF 3: {pct('tf3')}; TF 3 adjusted: {pct('tf3-adjusted')}. "
                "Our breakdown is blindness (crashes) rather than extra avoidances; see README.",
                _verdict(works and boundary and recovers, works or recovers),
            )
        )
    if {"tf0", "tf3-adaptive"} <= set(s):
        a, b = s["tf3-adaptive"], s["tf0"]
        ok_s = a["success_rate"] >= 0.9
        ok_n = abs(a["avoidances"] - b["avoidances"]) <= 0.25 * max(1, b["avoidances"])
        claims.append(
            Claim(
                "Beyond the paper: the complexity-adaptive detector restores TF 0 performance at "
                "TF 3 Hz without hand tuning",
                "(not in the paper)",
                f"TF 3 adaptive: {pct('tf3-adaptive')} vs TF 0: {pct('tf0')}; TF 0 adaptive: "
                f"{pct('tf0-adaptive')}",
                _verdict(ok_s and ok_n, ok_s or ok_n),
            )
        )
    return claims


def _img(path: Path) -> str:
    data = base64.b64encode(path.read_bytes()).decode()
    return f'<img src="data:image/png;base64,{data}" style="max-width:100%">'


FIGURES = (
    ("SF–TF sweep (Fig. 3)", "sweep/sweep.png"),
    ("Open-loop approach (Fig. 4)", "approach/approach.png"),
    ("Profiles per condition (Figs. 6–7)", "profiling/profiles.png"),
    ("Collision study (Fig. 8)", "collision/collision_study.png"),
)


def write_report(
    out: Path, plan: ReproduceSettings, claims: list[Claim], elapsed_s: float
) -> list[Path]:
    """report.md and a self-contained report.html (figures embedded) in ``out``."""
    col = pl.read_parquet(out / "collision" / "collision_summary.parquet")
    mode = "quick" if plan.quick else "full"
    head = (
        f"Mode: {mode} (profiling {plan.profile_minutes:g} min per condition, collision "
        f"phases {plan.collision_minutes:g} min, approach {plan.approach_repeats} repeats, "
        f"sweep {plan.sweep_duration_s:g} s per cell, seed {plan.seed}); wall time "
        f"{elapsed_s:.0f} s. Every number comes from the tables in this folder."
    )
    md = [
        '# vdc: reproducing "Profiling Visual Dynamic Complexity Using a Bio-Robotic Approach"',
        "",
        head,
        "",
        "## Claims",
        "",
        "| claim | paper | measured | verdict |",
        "|---|---|---|---|",
    ]
    md += [f"| {c.claim} | {c.paper} | {c.measured} | **{c.verdict}** |" for c in claims]
    md += ["", "## Collision study", "", collision_table_markdown(col), "", "## Figures", ""]
    md += [f"### {title}\n\n![{title}]({rel})\n" for title, rel in FIGURES if (out / rel).exists()]
    env = environment_markdown(out)
    md += ["## Environment", "", *env, ""]
    md_path = out / "report.md"
    md_path.write_text("\n".join(md) + "\n", encoding="utf-8")

    rows = "".join(
        f"<tr><td>{html.escape(c.claim)}</td><td>{html.escape(c.paper)}</td>"
        f"<td>{html.escape(c.measured)}</td><td class='{c.verdict.replace(' ', '-')}'>"
        f"{html.escape(c.verdict)}</td></tr>"
        for c in claims
    )
    crow = "".join(
        "<tr>" + "".join(f"<td>{html.escape(_fmt(v))}</td>" for v in r) + "</tr>"
        for r in col.with_columns((pl.col("success_rate") * 100).round(1).cast(pl.String) + " %")
        .select(
            "phase",
            "detector",
            "wall_tf_hz",
            "avoidances",
            "crashes",
            "success_rate",
            "false_alarms",
            "paper_avoidances",
            "paper_success",
        )
        .iter_rows()
    )
    figs = "".join(
        f"<h3>{html.escape(t)}</h3>{_img(out / rel)}" for t, rel in FIGURES if (out / rel).exists()
    )
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>vdc reproduction</title>
<style>body{{font-family:sans-serif;max-width:1200px;margin:2em auto}}
table{{border-collapse:collapse}}td,th{{border:1px solid #ccc;padding:4px 8px;vertical-align:top}}
.holds{{background:#d4f4d4}}.partly{{background:#fff3c4}}.does-not-hold{{background:#f8d0d0}}
</style></head><body><h1>vdc: reproducing the paper</h1><p>{html.escape(head)}</p>
<h2>Claims</h2><table><tr><th>claim</th><th>paper</th><th>measured</th><th>verdict</th></tr>
{rows}</table><h2>Collision study</h2><table><tr><th>phase</th><th>detector</th><th>TF (Hz)</th>
<th>avoidances</th><th>crashes</th><th>success</th><th>false alarms</th><th>paper avoidances</th>
<th>paper success</th></tr>{crow}</table><h2>Figures</h2>{figs}
<h2>Environment</h2>{_env_html(env)}</body></html>"""
    html_path = out / "report.html"
    html_path.write_text(page, encoding="utf-8")
    return [md_path, html_path]


def _env_html(lines: list[str]) -> str:
    """The environment section's Markdown table as HTML (the rest as paragraphs)."""
    rows = [ln for ln in lines if ln.startswith("|") and not ln.startswith("|---")]
    text = [ln.strip() for ln in lines if ln.strip() and not ln.startswith("|")]
    cells = [[c.strip() for c in r.strip("|").split("|")] for r in rows]
    table = "".join(
        "<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in cells
    )
    return "".join(f"<p>{html.escape(t)}</p>" for t in text) + f"<table>{table}</table>"


def _fmt(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.3g}" if not math.isnan(v) else "-"
    return str(v)


@dataclasses.dataclass
class ReproduceResult:
    claims: list[Claim]  # each paper claim, what was measured, and the verdict
    paths: list[Path]  # report.md, report.html
    elapsed_s: float

    @property
    def claims_table(self) -> pl.DataFrame:
        return pl.DataFrame([dataclasses.asdict(c) for c in self.claims])


def reproduce(
    plan: ReproduceSettings = ReproduceSettings(),
    out: str | Path = "results/reproduce",
    *,
    log: Callable[[str], None] | None = None,
) -> ReproduceResult:
    """``vdc-analyse reproduce``: run every step into ``out`` (reusing finished recordings)
    and write the claim-by-claim report; ``log`` gets one line per step."""
    t0 = time.perf_counter()
    out = Path(out)
    log = log or (lambda _m: None)
    out.mkdir(parents=True, exist_ok=True)
    rec_dir = out / "recordings"
    log(
        f"recording {len(PROFILE_CONDITIONS)} profiling runs and 5 collision phases "
        f"({plan.jobs} in parallel)"
    )
    items = profile_items(plan, rec_dir / "profiling")
    items += phase_items(
        study_phases(plan.detector, plan.adjusted),
        plan.collision_minutes,
        plan.seed,
        rec_dir / "collision",
    )
    paths = run_captures(items, plan.jobs, log)

    log("SF-TF sweep")
    cfg = SweepConfig(duration_s=plan.sweep_duration_s)
    df = run_sweep("avdm", paper_cells(), cfg)
    meta = {"model": "avdm", "stimulus": dataclasses.asdict(cfg)}
    write_parquet(df, out / "sweep" / "sweep.parquet", meta)
    write_parquet(monotonicity(df), out / "sweep" / "monotonicity.parquet", meta)
    plot_paper(
        df, out / "sweep" / "sweep.png", cfg, "avdm on drifting sine gratings, 100x100 px, 300 Hz"
    )

    log("open-loop approach")
    acfg = ApproachConfig(repeats=plan.approach_repeats, seed=plan.seed)
    runs, summary = run_approach(acfg)
    write_parquet(runs, out / "approach" / "approach.parquet", dataclasses.asdict(acfg))
    write_parquet(summary, out / "approach" / "approach_summary.parquet", dataclasses.asdict(acfg))
    plot_approach(runs, summary, out / "approach" / "approach.png")

    log("profiling")
    prof_paths = [paths[k] for k, _, _ in profile_items(plan, rec_dir / "profiling")]
    settings = SummarySettings()
    tables, tmeta = build_tables(prof_paths, None, settings)
    for name, t in tables.items():
        write_parquet(t, out / "profiling" / f"{name}.parquet", tmeta)
    segs = segments_from_tables(
        tables["frames"],
        tables["model_outputs"],
        tables["summary"],
        tmeta["arena_half_extent_m"],
        "condition",
        settings.warmup_frames,
    )
    ps = ProfileSettings()
    for seg in segs:
        plot_segment(seg, ps, out / "profiling" / f"profile_{seg.key}.png")
    plot_overview(segs, ps, out / "profiling" / "profiles.png")
    write_parquet(
        pl.DataFrame([segment_summary(seg, ps, settings) for seg in segs]),
        out / "profiling" / "profile_summary.parquet",
        tmeta,
    )

    log("collision study")
    col_paths = [str(p) for k, p in paths.items() if k.startswith("tf")]
    collision(col_paths, CollisionSettings(), out / "collision")

    log("report")
    claims = evaluate_claims(out)
    write_parquet(
        pl.DataFrame([dataclasses.asdict(c) for c in claims]),
        out / "claims.parquet",
        {"plan": dataclasses.asdict(plan), "capture_provenance": capture_provenance(paths)},
    )
    paths_written = write_report(out, plan, claims, time.perf_counter() - t0)
    return ReproduceResult(claims, paths_written, time.perf_counter() - t0)


def capture_provenance(paths: dict[str, Path]) -> list[dict[str, Any]]:
    """The distinct (versions, machine) the recordings were captured with, each with the
    recordings that share it (recordings reused from an older run may differ)."""
    groups: dict[str, dict[str, Any]] = {}
    for key, path in sorted(paths.items()):
        prov = Recording(path).properties().get("provenance") or {"unknown": "not recorded"}
        entry = groups.setdefault(
            json.dumps(prov, sort_keys=True), {"provenance": prov, "recordings": []}
        )
        entry["recordings"].append(key)
    return list(groups.values())


def environment_markdown(out: Path) -> list[str]:
    """The versions and machines of the analysis and of the captures, from claims.parquet."""
    meta = read_metadata(out / "claims.parquet")
    lines = [
        "Two reports can be compared number for number only when these agree; Numba compiles "
        "for the host CPU, so floats may differ in the last digits between CPUs.",
        "",
        "| | "
        + " | ".join(
            ["analysis"]
            + [f"capture {i + 1}" for i, _ in enumerate(meta.get("capture_provenance", []))]
        )
        + " |",
    ]
    cols = [{**meta.get("versions", {}), **meta.get("machine", {})}]
    cols += [g["provenance"] for g in meta.get("capture_provenance", [])]
    lines.append("|---" * (len(cols) + 1) + "|")
    keys = list(dict.fromkeys(k for c in cols for k in c))
    lines += [f"| {k} | " + " | ".join(str(c.get(k, "-")) for c in cols) + " |" for k in keys]
    for i, g in enumerate(meta.get("capture_provenance", [])):
        lines.append(f"\ncapture {i + 1}: {', '.join(g['recordings'])}")
    return lines
