"""``vdc-analyse``: offline analysis (sweeps, calibration, and later recordings and reports)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from vdc.cli_inputs import catalog_inputs, inputs, reproduce_inputs, summarise_inputs, sweep_inputs
from vdc.cli_runners import campaign_runner, over_recordings
from vdc.cli_support import (
    Command,
    command_line,
    command_of,
    flag_values,
    progress_bar,
    reference_markdown,
    run_command_line,
    say,
    settings_from_args,
    tasks_line,
)
from vdc.executors import Feedback, TasksFailed, one_pool

PROG = "vdc-analyse"


def _notice(msg: str) -> None:
    print(f"{PROG}: note: {msg}", file=sys.stderr)


def cmd_sweep(args: argparse.Namespace) -> int:
    from analysis.experiments.paper.sweep import SweepSettings, sweep
    from avdm.registry import canonical_name

    settings = settings_from_args(SweepSettings, args)
    with progress_bar(len(settings.cells()), f"sweep {canonical_name(settings.model)}") as bar:
        res = sweep(settings, args.out, progress=bar.update)
    print(f"{res.table.height} cells -> {res.files.sweep_parquet}, {res.files.sweep_png}")
    print("\n".join(res.report()))
    return 0


def cmd_calibrate(args: argparse.Namespace) -> int:
    from analysis.experiments.paper import calibrate as fit

    s = settings_from_args(fit.CalibrateSettings, args)
    with progress_bar(s.n_cells(), "calibrate") as bar:
        res = fit.calibrate(s, args.out, progress=bar.update)
    print("\n".join(res.report(s)))
    if not res.usable:
        say(
            f"{PROG} calibrate: error: the fit is poor (R^2 {res.fit.r2:.2f} < "
            f"{fit.MIN_CALIBRATION_R2}): not offered for use: over this geometry's narrow "
            "valid band the law explains too little of the response (try a larger --size or "
            "a higher --fps)."
        )
        return 1
    return 0


def cmd_collision(args: argparse.Namespace) -> int:
    from analysis.collision import CollisionSettings, collision

    out = Path(args.out)
    res = collision(
        args.recordings, settings_from_args(CollisionSettings, args), out, notice=_notice
    )
    print(res.markdown())
    print(f"wrote {out / 'collision_summary.parquet'}, collision_*.png, {out / 'collision.rrd'}")
    return 0


def cmd_collision_study(args: argparse.Namespace) -> int:
    from analysis.experiments.paper.collision_study import CollisionStudySettings, collision_study

    out = Path(args.out)
    res = collision_study(
        settings_from_args(CollisionStudySettings, args), out, log=say, notice=_notice
    )
    print(res.markdown)
    print(f"wrote {out / 'collision_study.md'}, {out / 'collision_study.png'}")
    return 0


def cmd_complexity(args: argparse.Namespace) -> int:
    from analysis.complexity.command import ComplexitySettings, complexity, expand_sources

    settings = settings_from_args(ComplexitySettings, args)
    # walked once, its skip notes said here: complexity() then takes the files themselves
    sources = expand_sources(args.sources, _notice)
    n = len(sources)
    with (
        progress_bar(None, "measuring", "frame") as frames,
        progress_bar(n, "measuring", "clip", quiet=n == 1) as clips,
    ):
        bars = {"progress": frames.update, "clip_progress": clips.update}
        res = complexity(sources, settings, args.out, **bars, notice=_notice, log=say)
    print("\n".join(res.report()))
    for source, error in res.failures:
        print(f"FAILED {source}: {error}", file=sys.stderr)
    return 1 if res.failures else 0


def cmd_catalog(args: argparse.Namespace) -> int:
    from analysis.catalog.build import CatalogSettings
    from analysis.catalog.query import query_to
    from analysis.catalog.server import dataset_url, serve

    s = settings_from_args(CatalogSettings, args)
    if args.action == "query":
        for path, df in query_to(args.folders, s, args.out, notice=_notice):
            print(f"{path.stem:<14} {df.height:>8} rows -> {path}")
        return 0

    def ready(cat, web: str | None) -> None:
        layers = ", ".join(cat.found.layers)
        print(f"dataset {cat.name}: {len(cat.found.segments)} segment(s), layers: base, {layers}")
        print(f"open it: rerun {dataset_url(cat)}" + (f"\nweb viewer: {web}" if web else ""))
        print("serving until Ctrl-C", flush=True)

    serve(args.folders, s, ready, notice=_notice)
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    from analysis.experiments.paper.plan import ReproduceSettings
    from analysis.experiments.paper.reproduce import reproduce

    plan = ReproduceSettings.make(args.quick, **flag_values(ReproduceSettings, args))
    with progress_bar(None, "reproduce", "run") as bar:
        res = reproduce(plan, args.out, feedback=Feedback(say, bar.update, bar.expect))
    for c in res.claims:
        print(f"[{c.verdict:^13}] {c.claim}")
    print(f"report: {res.files.report_md} and {res.files.report_html} ({res.elapsed_s:.0f} s)")
    return 0


def cmd_batch(args: argparse.Namespace) -> int:
    from analysis.batch import BatchSettings, batch

    settings = settings_from_args(BatchSettings, args)
    with progress_bar(None, "batch", "task") as bar:
        res = batch(args.recordings, settings, args.out, progress=bar.update, log=say)
    ran = len(res.outcomes) - len([o for o in res.outcomes if o.error])
    print(tasks_line(res, "tasks", ran, "ran"))
    if res.tables is not None:
        print(f"summarised into {args.out}/: " + ", ".join(p.name for p in res.paths))
    elif res.failures == [] and settings.shard is not None:
        print(f"this shard is done; when all are: vdc-analyse summarise {args.out}")
    for task, err in res.failures:
        print(f"FAILED {task}: {err}", file=sys.stderr)
    return 1 if res.failures else 0


def cmd_summarise(args: argparse.Namespace) -> int:
    from analysis.batch import summarise_batch

    tables, paths = summarise_batch(args.out)
    for path, (name, df) in zip(paths, tables.items(), strict=True):
        print(f"{name:<14} {df.height:>8} rows -> {path}")
    return 0


# the sub-commands: each one's flags are its settings dataclass's fields (vdc.cli_support)
COMMANDS = {
    "sweep": Command(
        "analysis.experiments.paper.sweep:SweepSettings",
        cmd_sweep,
        "response to drifting gratings over SF and TF (paper Fig. 3)",
        "Reproduce paper Fig. 3: the AVDM's response to drifting sine gratings at 100x100 px "
        "and 300 Hz, against TF at SF = 1, 10, 50 upc and against SF at TF = 1, 5, 50 Hz. Give "
        "--sf and/or --tf lists to sweep a full grid instead. Writes sweep.parquet, "
        "monotonicity.parquet and sweep.png into --out and prints the Spearman rho along "
        "every row and column.",
        inputs=sweep_inputs,
        models=True,
    ),
    "calibrate": Command(
        "analysis.experiments.paper.calibrate:CalibrateSettings",
        cmd_calibrate,
        "least-squares fit of the AVDM decoding constants (a, b)",
        "Fit omega = a * lambda^b * (1+C)/(2C) * sqrt(Rbar) against the true angular velocity "
        "of drifting gratings in the valid band (>= 2 periods across, >= 4 px per period, TF "
        "<= fps/4, responsive). Prints the fit and writes calibration.json and calibration.png "
        "into --out.",
        inputs=inputs("results/calibration", None),
    ),
    "tables": Command(
        "analysis.recordings.recompute:TablesSettings",
        over_recordings("analysis.recordings.recompute:tables", _notice),
        "recordings -> frames, model_outputs, events, summary Parquet tables",
        "Read recordings and write frames.parquet, model_outputs.parquet, events.parquet and "
        "summary.parquet into --out. Without --model the online model's logged outputs are "
        "used; each --model (repeatable) is recomputed from the raw frames instead.",
        inputs=inputs("results/tables", ".rrd recordings or folders of them"),
        models=True,
    ),
    "profile": Command(
        "analysis.recordings.segments:ProfileSettings",
        over_recordings("analysis.profile:profile", _notice),
        "3D circle profiles, 'AVDM > 100' histograms and heat maps (paper Figs. 6-7)",
        "For every recording segment (one wall TF) or condition: a 3D circle profile (x, y "
        "against time, circle size proportional to the response), the histogram of responses "
        "over the threshold, and a heat map of the mean response per arena cell. Writes PNGs, "
        "profiles.png (overview), profile_summary.parquet and profiles.rrd (open it with "
        "`rerun`).",
        inputs=inputs("results/profile"),
    ),
    "compare": Command(
        "analysis.compare:CompareSettings",
        over_recordings("analysis.compare:compare", _notice, "recording"),
        "run model variants on the same recorded frames and compare them",
        "Recompute every --model variant on the recording's raw frames; write per-variant "
        "statistics and pairwise correlations (Parquet), compare.png, and variants.rrd with "
        "the traces under /model_variants/<name>/..., which opens alongside the original: "
        "`rerun REC OUT/variants.rrd`.",
        "example:\n  vdc-analyse compare rec.rrd --model avdm --model avdm-on "
        "--model avdm:beta=0.5 --out results/compare",
        inputs=inputs("results/compare", "one .rrd recording", one=True),
        models=True,
    ),
    "collision": Command(
        "analysis.collision:CollisionSettings",
        cmd_collision,
        "collision-study metrics and density maps of closed-loop recordings (Fig. 8)",
        "For every collision-mode recording (vdc-capture sim --behaviour collision): "
        "avoidances, crashes, success rate = avoidances / (avoidances + crashes), false alarms "
        "(avoidances with the wall farther than --false-alarm-m ahead), distance to collision "
        "at each avoidance, and density maps of the trajectory, avoidance and crash positions. "
        "Writes collision_summary.parquet, collision_events.parquet, a PNG per recording, "
        "collision_study.png and collision.rrd.",
        inputs=inputs("results/collision", "collision-mode .rrd files"),
    ),
    "collision-study": Command(
        "analysis.experiments.paper.collision_study:CollisionStudySettings",
        cmd_collision_study,
        "record and analyse the three-phase collision protocol (+ adaptive detector)",
        "Run the paper's protocol in simulation: TF 0, TF 3 Hz, and TF 3 Hz with the adjusted "
        "detection threshold, each --minutes long, plus the complexity-adaptive detector at "
        "TF 3 and TF 0 (beyond the paper). Phases run in parallel processes and finished ones "
        "are reused. Writes the recordings, the collision analysis and collision_study.md "
        "with the paper's numbers beside ours.",
        inputs=inputs("results/collision-study", None),
    ),
    "boundary": Command(
        "analysis.boundary.settings:BoundarySettings",
        campaign_runner("analysis.experiments.collision.boundary_campaign:boundary", "run"),
        "where a detector breaks as complexity rises (arena grid or labelled footage)",
        "Arena: closed-loop runs over scene x TF x --param values x seeds (finished runs "
        "reused), each condition profiled with the AVDM; per condition, success, avoidances, "
        "crashes and distance to collision with 95 % intervals; the boundary (where success "
        "falls below --target at 95 % confidence) per value; a policy fitted from the grid "
        "(policy.csv). Footage (--labels): hit rate, false alarms and the time to collision "
        "of the first alert per clip and per group of clips of similar complexity.",
        "example:\n  vdc-analyse boundary --labels clips/labels.csv --fov-deg 60 "
        "--detector examples.looming:Looming --param threshold --values 0.05,0.15",
        inputs=inputs("results/boundary", None),
    ),
    "looming-footage": Command(
        "analysis.experiments.collision.looming_footage:LoomingFootageSettings",
        campaign_runner("analysis.experiments.collision.looming_footage:looming_footage", "clip"),
        "render a labelled collection of looming clips over real photographs",
        "Render --clips H.264 clips of an object approaching over scikit-image's photographs "
        "(camera yaw, contrast, light, noise; collisions and near misses) and labels.csv with "
        "collision_frame, hazard_onset_frame (docs/guides/boundary.md). Clips written are reused.",
        inputs=inputs("footage/looming", None),
    ),
    "power-study": Command(
        "analysis.experiments.power.study:PowerStudySettings",
        campaign_runner("analysis.experiments.power.study:power_study", "run"),
        "re-run the pre-registered plan (docs/findings/power_plan.md) anew and write its answer",
        "The plan's studies, resumed, then answer.md; --quick: a minute, not findings.",
        inputs=inputs("results/power-study", None),
    ),
    "adaptation": Command(
        "analysis.experiments.collision.adaptation:AdaptationSettings",
        campaign_runner("analysis.experiments.collision.adaptation:adaptation", "run"),
        "test a learnt policy on held-out conditions against the hand-made controllers",
        "Closed-loop runs on held-out wall TFs, scenes and a TF schedule changing mid-run, "
        "with the detector as is, the paper's hand threshold (--hand), vdc's adaptive rule "
        "and the policy (--policy, running online); the same seeds for all; the policy's "
        "paired differences against each, and a verdict computed from them.",
        inputs=inputs("results/adaptation", None),
    ),
    "batch": Command(
        "analysis.batch:BatchSettings",
        cmd_batch,
        "many recordings x many variants: one task each, on all cores or a Dask cluster",
        "Every (recording, --model) pair is one task: it reads the raw frames, recomputes the "
        "variant and writes its own Parquet parts atomically under "
        "OUT/parts/recording_id=.../model=.../. Finished parts are skipped on a re-run "
        "(--force recomputes). At the end the parts are concatenated into the same frames, "
        "model_outputs, events and summary tables `tables` writes. A failing task is listed "
        "and does not stop the others (exit status 1).",
        inputs=inputs("results/batch", ".rrd recordings or folders of them"),
        models=True,
    ),
    "summarise": Command(
        None,
        cmd_summarise,
        "concatenate a batch's finished parts into the four tables",
        "After sharded batch runs: OUT/parts/... -> "
        "OUT/{frames,model_outputs,events,summary}.parquet, as `tables` writes them.",
        inputs=summarise_inputs,
    ),
    "complexity": Command(
        "analysis.complexity.command:ComplexitySettings",
        cmd_complexity,
        "the AVDM beside P.910 SI/TI, optic flow and compression, per frame",
        "For recordings (video, arena, robot), video files, image sequences and folders of "
        "them: per frame the AVDM's omega_dps and DIS optic-flow speed in deg/s (on the model "
        "raster), and ITU-T P.910 SI and TI (2022, as siti-tools; legacy, as FFmpeg's siti), "
        "mean absolute frame difference, edge density, JPEG and codec bits per pixel on the "
        "source's native frames. Each source is one task (--executor, --jobs) writing its own "
        "part: a re-run resumes, a corrupt file is listed in failures.parquet. Writes "
        "complexity.parquet, clips.parquet (per clip: mean, max, p95 of each metric), "
        "complexity_collection.png and complexity.html; per clip (--rrd, always for one "
        "source) a PNG and an .rrd that opens beside the source.",
        "examples:\n"
        "  vdc-analyse complexity recordings/clip.rrd\n"
        "  vdc-analyse complexity footage/ --fov-deg 70 --jobs 2 --out results/footage\n"
        "  vdc-analyse complexity 'shots/%05d.png' --fps 25 --fov-deg 90",
        inputs=inputs(
            "results/complexity", "recordings, videos, image patterns or folders", dest="sources"
        ),
    ),
    "dataset": Command(
        "analysis.dataset.settings:DatasetSettings",
        campaign_runner("analysis.dataset.command:dataset", "camera", "recording"),
        "profile a LeRobot dataset episode by episode, its camera faults flagged",
        "Each camera of each episode of a LeRobot dataset (v3.0, v2.1): docs/guides/dataset.md.",
        inputs=inputs("results/dataset", "a LeRobot dataset folder", one=True),
    ),
    "catalog": Command(
        "analysis.catalog.build:CatalogSettings",
        cmd_catalog,
        "browse and query many recordings as one Rerun dataset (a catalog server)",
        "serve: every recording under the folders as a segment of one dataset (properties "
        "as columns), the outputs of compare, batch and complexity as layers of their "
        "source's segment, on a catalog server on 127.0.0.1 until Ctrl-C (open it with "
        "`rerun URL`). query: the frames and model_outputs tables of the segments matching "
        "--where, read in one call, as `tables` writes them.",
        "examples:\n"
        "  vdc-analyse catalog serve results/reproduce --web\n"
        "  vdc-analyse catalog query results/campaign --where scene=natural --out results/q",
        inputs=catalog_inputs,
    ),
    "reproduce": Command(
        "analysis.experiments.paper.plan:ReproduceSettings",
        cmd_reproduce,
        "reproduce the paper end to end and write a claim-by-claim report",
        "Run the SF-TF sweep, the open-loop approach, closed-loop profiling (grating TF 0, 1, "
        "3 Hz; natural scene TF 0, 3 Hz) and the collision study (with the adaptive "
        "detector), then write report.md and a self-contained report.html that put each paper "
        "claim beside what was measured. --quick uses short runs (minutes); the default uses "
        "the paper's 30-minute durations. Every condition runs with --seeds seeds; each claim "
        "is reported with means, 95 % intervals and a trend test across them, and holds only "
        "if it holds at that confidence. Runs already recorded with the same configuration "
        "are reused.",
        inputs=reproduce_inputs,
    ),
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser, with the flags of ``command`` generated (see ``vdc.cli_support``)."""
    about = "Offline analysis for vdc: recordings to tables and figures, model variants, sweeps"
    return command_line(PROG, about + " and calibration.", COMMANDS, command)


def cli_reference() -> str:
    """docs/cli.md: every command and flag of ``vdc-capture`` and ``vdc-analyse``, rendered from
    the settings dataclasses; a test keeps the file equal."""
    import capture.cli

    return reference_markdown([capture.cli, sys.modules[__name__]])


def main(argv: Sequence[str] | None = None) -> int:
    # a campaign with failed runs keeps the finished ones; a re-run retries the failed;
    # its stages share one pool of workers (their start-up paid once)
    with one_pool():
        return run_command_line(
            PROG, build_parser(command_of(argv, COMMANDS)), argv, {TasksFailed: ""}
        )


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
