"""Reproduce the paper end to end and report, claim by claim, what holds.

Steps: the SF–TF sweep (Fig. 3); the open-loop approach (Fig. 4); closed-loop profiling of grating
TF 0, 1, 3 Hz and natural scene TF 0, 3 Hz (Figs. 6–7); the collision study (Fig. 8) with the
complexity-adaptive detector. Every closed-loop condition runs with several seeds (the same
seeds everywhere); each claim is reported as means with 95 % intervals across seeds and, for
trends, a one-sided test with its p-value, and "holds" only if it holds at that confidence
(analysis/stats.py). The Fig. 6 count "AVDM > 100" is read three ways: in the released code's
units (``avdm-released-units``, the units the paper's threshold was set in), in calibrated
deg/s over all frames, and in calibrated deg/s while the robot drives straight (its own turns
excluded). Captures run as parallel processes and finished ones (same configuration) are
reused. Every number in the report is computed from the tables written beside it
(``claims.parquet`` holds them too).

This module is the recipe; the plan is ``plan.py``, the claims and their numbers
``claims.py``, the report ``report.py`` and its own figure ``figures.py``.
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import polars as pl

from analysis.collision import (
    CollisionSettings,
    collision,
)
from analysis.experiments.captures import CaptureItem, run_captures
from analysis.experiments.paper.approach import ApproachConfig, plot_approach, run_approach
from analysis.experiments.paper.claims import (
    CALIBRATED,
    PROFILE_CONDITIONS,
    PROFILE_MODELS,
    Claim,
    claims_frame,
    evaluate_claims,
)
from analysis.experiments.paper.collision_study import phase_items, study_phases
from analysis.experiments.paper.figures import plot_fig6_seeds
from analysis.experiments.paper.plan import ReproduceSettings
from analysis.experiments.paper.report import (
    write_report,
)
from analysis.experiments.paper.sweep import (
    SweepConfig,
    monotonicity,
    paper_cells,
    plot_paper,
    run_sweep,
)
from analysis.profile import plot_overview, plot_segment
from analysis.recordings.reader import Recording
from analysis.recordings.recompute import SummarySettings, build_tables, summary_rows
from analysis.recordings.segments import ProfileSettings, segment_summary, segments_from_tables
from capture.sim import SimSettings
from vdc.executors import QUIET, Feedback, one_pool
from vdc.heartbeat import Count
from vdc.parquet_io import WroteFiles, write_parquet
from vdc.scratch import no_files_without_out


def profile_items(plan: ReproduceSettings, folder: Path) -> list[CaptureItem]:
    """The closed-loop profiling runs: one per (scene, TF) condition and seed."""
    return [
        (
            f"{scene}-tf{tf:g}-seed{seed}",
            SimSettings(scene=scene, tf_hz=tf, minutes=plan.profile_minutes, seed=seed),
            folder / f"seed{seed}" / f"{scene}-tf{tf:g}.rrd",
        )
        for seed in plan.seed_list
        for scene, tf in PROFILE_CONDITIONS
    ]


def with_motion_summaries(tables: dict[str, pl.DataFrame], s: SummarySettings) -> pl.DataFrame:
    """The tables' summary (all frames) plus the same rows for straight driving and for the
    frames while the robot turns (``motion`` column)."""
    summary = tables["summary"]
    cond_cols = ["scene", "period_m", "seed", "source"]
    parts = [summary]
    for motion in ("straight", "turning"):
        for (rid,), frames in tables["frames"].group_by("recording_id", maintain_order=True):
            cond = (
                summary.filter(pl.col("recording_id") == rid).select(cond_cols).row(0, named=True)
            )
            outputs = tables["model_outputs"].filter(pl.col("recording_id") == rid)
            parts.append(summary_rows(str(rid), cond, frames, outputs, s, motion))
    return pl.concat(parts, how="diagonal_relaxed").sort(
        "recording_id", "model", "wall_tf_hz", "motion"
    )


@dataclasses.dataclass
class ReproduceResult(WroteFiles):
    claims: list[Claim]  # each paper claim, what was measured, and the verdict
    paths: list[Path]  # report.md, report.html
    elapsed_s: float

    @property
    def claims_table(self) -> pl.DataFrame:
        """claims.parquet's rows: one per claim, condition and quantity (:func:`claims_frame`)."""
        return claims_frame(self.claims)


@no_files_without_out
@one_pool()  # its stages share one pool of workers
def reproduce(
    plan: ReproduceSettings = ReproduceSettings(),
    out: str | Path | None = "results/reproduce",
    *,
    log: Callable[[str], None] | None = None,
    feedback: Feedback = QUIET,
) -> ReproduceResult:
    """``vdc-analyse reproduce``: run every step into ``out`` (reusing finished recordings)
    and write the claim-by-claim report; ``feedback`` (or just ``log``) gets one line per
    step and counts the simulated runs (``vdc.Feedback.printing()`` prints them)."""
    t0 = time.perf_counter()
    out = Path(out)
    log = log or feedback.log
    out.mkdir(parents=True, exist_ok=True)
    rec_dir = out / "recordings"
    phases = study_phases(plan.detector, plan.adjusted)
    log(
        f"Stage 1 of 6: recording {len(PROFILE_CONDITIONS)} profiling conditions and "
        f"{len(phases)} collision phases x {plan.seeds} seeds ({plan.where()})."
    )
    items = profile_items(plan, rec_dir / "profiling")
    items += phase_items(phases, plan.collision_minutes, plan.seed_list, rec_dir / "collision")
    paths = run_captures(items, plan, log, feedback)

    log("Stage 2 of 6: the SF-TF sweep (Fig. 3).")
    cfg = SweepConfig(duration_s=plan.sweep_duration_s)
    cells = paper_cells()
    with Count(len(cells), "SF-TF sweep", "cell") as count:  # on the heartbeat, if one runs
        df = run_sweep("avdm", cells, cfg, progress=count.update)
    meta = {"model": "avdm", "stimulus": dataclasses.asdict(cfg)}
    write_parquet(df, out / "sweep" / "sweep.parquet", meta)
    write_parquet(monotonicity(df), out / "sweep" / "monotonicity.parquet", meta)
    plot_paper(
        df, out / "sweep" / "sweep.png", cfg, "avdm on drifting sine gratings, 100x100 px, 300 Hz"
    )

    log("Stage 3 of 6: the open-loop approach (Fig. 4).")
    acfg = ApproachConfig(repeats=plan.approach_repeats, seed=plan.seed)
    with Count(len(acfg.tfs_hz) * acfg.repeats, "approach", "approach") as count:
        runs, summary = run_approach(acfg, progress=count.update)
    write_parquet(runs, out / "approach" / "approach.parquet", dataclasses.asdict(acfg))
    write_parquet(summary, out / "approach" / "approach_summary.parquet", dataclasses.asdict(acfg))
    plot_approach(runs, summary, out / "approach" / "approach.png")

    log("Stage 4 of 6: profiling tables and figures (Figs. 6-7).")
    prof_items = profile_items(plan, rec_dir / "profiling")
    prof_paths = [paths[k] for k, _, _ in prof_items]
    settings = SummarySettings()
    # the frames the runs were planned to hold: the heartbeat's total, for its estimate
    planned = sum(
        round(c.duration_s * c.camera.fps) for c in (s.to_config() for _, s, _ in prof_items)
    )
    with Count(planned, "profiling", "frame") as count:
        tables, tmeta = build_tables(prof_paths, PROFILE_MODELS, settings, count.update)
    tables["summary"] = with_motion_summaries(tables, settings)
    for name, t in tables.items():
        write_parquet(t, out / "profiling" / f"{name}.parquet", tmeta)
    plot_fig6_seeds(tables, settings.warmup_frames, out / "profiling" / "fig6_seeds.png")
    calibrated = tables["model_outputs"].filter(pl.col("model") == CALIBRATED)
    segs = segments_from_tables(
        tables["frames"],
        calibrated,
        tables["summary"].filter(pl.col("motion") == "all"),
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

    log("Stage 5 of 6: the collision study (Fig. 8).")
    col_paths = [str(p) for k, p in paths.items() if k.startswith("tf")]  # phase keys
    with Count(len(col_paths), "collision study", "recording") as count:
        collision(col_paths, CollisionSettings(), out / "collision", progress=count.update)

    log("Stage 6 of 6: the claims and the report.")
    claims = evaluate_claims(out)
    write_parquet(
        claims_frame(claims),
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
