"""``vdc-analyse``: offline analysis (sweeps, calibration, and later recordings and reports)."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from avdm.registry import describe_models
from vdc.cli_support import (
    OneLineParser,
    UserError,
    add_executor_options,
    bind_commands,
    command_of,
    fail,
    field_default,
    load_settings_class,
    parse_float_list,
    parse_size,
    positive_float,
    settings_from_args,
)
from vdc.executors import TasksFailed
from vdc.recording import FOOTAGE_MODEL

PROG = "vdc-analyse"


def _progress(total: int | None, desc: str, unit: str = "cell"):  # -> tqdm
    from tqdm import tqdm

    # disable=None: a bar on terminals, silence in pipes and CI logs
    return tqdm(total=total, desc=desc, unit=unit, disable=None, leave=False, file=sys.stderr)


def _tf(v: float | None) -> str:
    """A wall TF for printing; recordings of a video have none."""
    return "no walls" if v is None else f"TF {v:g} Hz"


def _notice(msg: str) -> None:
    print(f"{PROG}: note: {msg}", file=sys.stderr)


def _stderr(msg: str) -> None:
    print(msg, file=sys.stderr, flush=True)


def cmd_sweep(args: argparse.Namespace) -> int:
    import polars as pl

    from analysis.experiments.sweep import SweepSettings, sweep
    from avdm.registry import canonical_name

    settings = settings_from_args(SweepSettings, args, waveform="square" if args.square else "sine")
    with _progress(len(settings.cells()), f"sweep {canonical_name(settings.model)}") as bar:
        res = sweep(settings, args.out, progress=bar.update)
    print(f"{res.table.height} cells -> {res.files.sweep_parquet}, {res.files.sweep_png}")
    print("monotonicity of the response (Spearman rho of omega_dps):")
    for r in res.monotonicity.iter_rows(named=True):
        print(
            f"  vs {r['along'].upper():<2} at {r['fixed']:<12} n={r['n']:<3} "
            f"rho={r['rho']:+.3f}  {r['trend']}"
        )
    inc = res.monotonicity.filter(pl.col("along") == "tf")
    dec = res.monotonicity.filter(pl.col("along") == "sf")
    print(
        f"summary: {int((inc['trend'] == 'increasing').sum())}/{inc.height} TF rows increasing, "
        f"{int((dec['trend'] == 'decreasing').sum())}/{dec.height} SF columns decreasing"
    )
    return 0


def cmd_calibrate(args: argparse.Namespace) -> int:
    from analysis.experiments.calibrate import MIN_CALIBRATION_R2, CalibrateSettings, calibrate

    s = settings_from_args(CalibrateSettings, args)
    with _progress(s.n_cells(), "calibrate") as bar:
        res = calibrate(s, args.out, progress=bar.update)
    fit, (h, w) = res.fit, s.size
    print(
        f"calibration {s.resolved_name}: fps={s.fps:g} Hz, "
        f"{s.resolved_deg_per_px:.6g} deg/px, {w}x{h} px"
    )
    print(f"  a = {fit.a:.6g}   b = {fit.b:.6g}")
    print(
        f"  log-log R^2 = {fit.r2:.4f}; over {fit.n_points} valid cells the decoded "
        f"omega is off by {100 * fit.rms_rel_error:.1f} % RMS, "
        f"{100 * fit.max_rel_error:.1f} % at worst"
    )
    print(f"  wrote {res.files.calibration_json} and {res.files.calibration_png}")
    if not res.usable:
        print(
            f"{PROG} calibrate: error: the fit is poor (R^2 {fit.r2:.2f} < {MIN_CALIBRATION_R2}):"
            " not offered for use: over this geometry's narrow valid band the law explains too"
            " little of the response (try a larger --size or a higher --fps)",
            file=sys.stderr,
        )
        return 1
    print(f"  use it as: --model {s.model.split(':')[0]}:a={fit.a:.6g},b={fit.b:.6g}")
    if s.update_defaults:
        print(f"  updated the shipped defaults in {res.files.calibrations}")
    return 0


def cmd_tables(args: argparse.Namespace) -> int:
    from analysis.tables import TablesSettings, tables

    with _progress(None, "tables", "frame") as bar:
        res = tables(
            args.recordings,
            settings_from_args(TablesSettings, args),
            args.out,
            progress=bar.update,
            notice=_notice,
        )
    for path, (name, df) in zip(res.paths, res.tables.items(), strict=True):
        print(f"{name:<14} {df.height:>8} rows -> {path}")
    print("summary (primary output after warm-up):")
    for r in res.summary.iter_rows(named=True):
        print(
            f"  {r['recording_id']}  {r['model']:<16} {_tf(r['wall_tf_hz'])}: "
            f"mean {r['mean']:.1f}, p95 {r['p95']:.1f}, > 100: {100 * r['frac_over_100']:.1f} %, "
            f"near wall / centre {r['near_wall_centre_ratio']:.2f}"
        )
    return 0


def cmd_profile(args: argparse.Namespace) -> int:
    from analysis.profile import ProfileSettings, profile

    s = settings_from_args(ProfileSettings, args)
    with _progress(None, "profile", "frame") as bar:
        res = profile(args.recordings, s, args.out, progress=bar.update, notice=_notice)
    files = res.files
    pngs = [p for role, p in files.items() if role.startswith("profile_") and p.suffix == ".png"]
    print(
        f"{len(res.segments)} profile(s) by {s.by}: {len(pngs)} PNGs, {files.profiles_png}, "
        f"{files.profiles_rrd}, {files.profile_summary}"
    )
    for r in res.summary.iter_rows(named=True):
        print(
            f"  {r['segment']:<44} n={r['n_frames']:>6}  > {s.threshold_dps:g}: "
            f"{100 * r['frac_over_threshold']:5.1f} %  near wall {r['near_wall_mean']:.1f} / "
            f"centre {r['centre_mean']:.1f}"
        )
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    from analysis.compare import CompareSettings, compare

    s = settings_from_args(CompareSettings, args)
    with _progress(None, "compare", "frame") as bar:
        res = compare(args.recording, s, args.out, progress=bar.update, notice=_notice)
    n_frames = res.outputs[next(iter(res.outputs))].height
    files = res.files
    print(f"{len(res.outputs)} variants on {n_frames} frames -> {files.compare}, {files.variants}")
    for r in res.statistics.iter_rows(named=True):
        print(
            f"  {r['model']:<22} mean {r['mean']:8.2f}  p95 {r['p95']:8.2f}  "
            f"> {s.threshold_dps:g}: {100 * r['frac_over_threshold']:5.1f} %  "
            f"near wall / centre {r['near_wall_centre_ratio']:.2f}"
        )
    for r in res.correlations.iter_rows(named=True):
        print(
            f"  corr {r['model_a']} ~ {r['model_b']}: pearson {r['pearson']:.3f}, "
            f"spearman {r['spearman']:.3f}"
        )
    print(f"view together: rerun {args.recording} {files.variants}")
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
    from analysis.experiments.collision_study import CollisionStudySettings, collision_study

    out = Path(args.out)
    res = collision_study(
        settings_from_args(CollisionStudySettings, args), out, log=_stderr, notice=_notice
    )
    print(res.markdown)
    print(f"wrote {out / 'collision_study.md'}, {out / 'collision_study.png'}")
    return 0


def cmd_complexity(args: argparse.Namespace) -> int:
    import polars as pl

    from analysis.complexity import ComplexitySettings, complexity

    with _progress(None, "complexity", "frame") as bar:
        res = complexity(
            args.recordings,
            settings_from_args(ComplexitySettings, args),
            args.out,
            progress=bar.update,
            notice=_notice,
        )
    print(f"{res.table.height} frames -> " + ", ".join(str(p) for p in res.paths))
    means = res.table.group_by("recording_id", maintain_order=True).mean()
    for r in means.iter_rows(named=True):
        print(
            f"  {r['recording_id']}: mean omega {r['omega_dps']:.1f} deg/s, flow "
            f"{r['flow_dps']:.1f} deg/s, SI {r['si_p910']:.1f} / TI {r['ti_p910']:.2f} (P.910), "
            f"SI {r['si_legacy']:.1f} / TI {r['ti_legacy']:.2f} (legacy)"
        )
    rho = res.correlations.filter(pl.col("metric_a") == "omega_dps")
    for r in rho.iter_rows(named=True):
        print(f"  rho(omega_dps, {r['metric_b']}) = {r['spearman']:+.2f}  [{r['recording_id']}]")
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    from analysis.experiments.reproduce import ReproduceSettings, reproduce

    fields = [f.name for f in dataclasses.fields(ReproduceSettings)]
    plan = ReproduceSettings.make(args.quick, **{k: getattr(args, k) for k in fields})
    res = reproduce(plan, args.out, log=_stderr)
    for c in res.claims:
        print(f"[{c.verdict:^13}] {c.claim}")
    print(f"report: {res.files.report_md} and {res.files.report_html} ({res.elapsed_s:.0f} s)")
    return 0


def cmd_batch(args: argparse.Namespace) -> int:
    from analysis.batch import BatchSettings, batch

    settings = settings_from_args(BatchSettings, args)
    with _progress(None, "batch", "task") as bar:
        res = batch(args.recordings, settings, args.out, progress=bar.update, log=_stderr)
    ran = len(res.outcomes) - len([o for o in res.outcomes if o.error])
    print(
        f"{res.planned} tasks: {res.skipped} already done, {ran} ran, {len(res.failures)} "
        f"failed ({res.elapsed_s:.1f} s)"
    )
    if res.tables is not None:
        print(f"summarised into {args.out}/: " + ", ".join(p.name for p in res.paths))
    elif res.failures == [] and settings.shard is not None:
        print(f"this shard is done; when all are: vdc-analyse summarise {args.out}")
    for task, err in res.failures:
        print(f"FAILED {task}: {err}", file=sys.stderr)
    return 1 if res.failures else 0


def cmd_summarise(args: argparse.Namespace) -> int:
    from analysis.batch import summarise

    tables, paths = summarise(args.out)
    for path, (name, df) in zip(paths, tables.items(), strict=True):
        print(f"{name:<14} {df.height:>8} rows -> {path}")
    return 0


def add_out(p: argparse.ArgumentParser, default: str) -> None:
    p.add_argument("--out", default=default, help="output folder (default: %(default)s)")


def add_seed_options(p: argparse.ArgumentParser, seeds: int | None) -> None:
    """--seed (the first) and --seeds (how many runs per condition)."""
    p.add_argument("--seed", type=int, help="first random seed (default: %(default)s)")
    p.add_argument(
        "--seeds",
        type=int,
        default=seeds,
        help="runs per condition, seeds --seed, --seed+1, ...: every figure is given as a mean "
        "with its 95 %% interval across them (default: "
        + (f"{seeds})" if seeds else "5, 3 with --quick)"),
    )


def add_models(
    p: argparse.ArgumentParser,
    required: bool = False,
    help: str = "recompute this variant (repeatable)",
) -> None:
    """--model, repeatable: the variants a command recomputes from the raw frames."""
    p.add_argument("--model", dest="models", action="append", required=required, help=help)


# each sub-command's settings dataclass: the one source of its flags' defaults
SETTINGS = {
    "tables": "analysis.tables:TablesSettings",
    "profile": "analysis.profile:ProfileSettings",
    "compare": "analysis.compare:CompareSettings",
    "complexity": "analysis.complexity:ComplexitySettings",
    "batch": "analysis.batch:BatchSettings",
    "collision": "analysis.collision:CollisionSettings",
    "sweep": "analysis.experiments.sweep:SweepSettings",
    "calibrate": "analysis.experiments.calibrate:CalibrateSettings",
    "collision-study": "analysis.experiments.collision_study:CollisionStudySettings",
    "reproduce": "analysis.experiments.reproduce:ReproduceSettings",
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The parser, with the settings of ``command`` bound (see ``bind_commands``)."""
    parser = OneLineParser(
        prog=PROG,
        description=(
            "Offline analysis for vdc: recordings to tables and figures, model variants, "
            "sweeps and calibration."
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="models (--model NAME or NAME:key=value,...):\n" + describe_models(),
    )
    sub = parser.add_subparsers(dest="command", required=True, parser_class=OneLineParser)

    sw = sub.add_parser(
        "sweep",
        help="response to drifting gratings over SF and TF (paper Fig. 3)",
        description=(
            "Reproduce paper Fig. 3: the AVDM's response to drifting sine gratings at "
            "100x100 px and 300 Hz, against TF at SF = 1, 10, 50 upc and against SF at "
            "TF = 1, 5, 50 Hz. Give --sf and/or --tf lists to sweep a full grid instead. "
            "Writes sweep.parquet, monotonicity.parquet and sweep.png into --out and prints "
            "the Spearman rho along every row and column."
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="models:\n" + describe_models(),
    )
    add_out(sw, "results/sweep")
    sw.add_argument("--model", help="model variant (default: %(default)s)")
    sw.add_argument(
        "--sf-upc",
        "--sf",
        dest="sf_upc",
        type=parse_float_list,
        help="spatial frequencies, upc, e.g. 1,5,10",
    )
    sw.add_argument(
        "--tf-hz",
        "--tf",
        dest="tf_hz",
        type=parse_float_list,
        help="temporal frequencies, Hz, e.g. 1,3,10",
    )
    sw.add_argument(
        "--size",
        type=parse_size,
        help="stimulus WIDTHxHEIGHT px; the width spans 360 deg (default: 100x100)",
    )
    sw.add_argument("--fps", type=positive_float, help="frame rate, Hz (default: %(default)s)")
    sw.add_argument(
        "--duration-s",
        "--duration",
        dest="duration_s",
        type=positive_float,
        help="seconds of stimulus per cell (default: %(default)s)",
    )
    sw.add_argument(
        "--contrast",
        type=positive_float,
        help="Michelson contrast, peak-normalised (default: %(default)s)",
    )
    sw.add_argument("--square", action="store_true", help="square-wave instead of sine gratings")
    sw.set_defaults(func=cmd_sweep)

    ca = sub.add_parser(
        "calibrate",
        help="least-squares fit of the AVDM decoding constants (a, b)",
        description=(
            "Fit omega = a * lambda^b * (1+C)/(2C) * sqrt(Rbar) against the true angular "
            "velocity of drifting gratings in the valid band (>= 2 periods across, >= 4 px per "
            "period, TF <= fps/4, responsive). Prints the fit and writes calibration.json and "
            "calibration.png into --out."
        ),
    )
    ca.add_argument("--fps", type=positive_float, help="frame rate, Hz (default: %(default)s)")
    ca.add_argument(
        "--deg-per-px",
        type=positive_float,
        help="degrees per pixel (default: 360/width, the offline-stimulus convention)",
    )
    ca.add_argument(
        "--size",
        type=parse_size,
        help="frame WIDTHxHEIGHT px (default: 100x100)",
    )
    ca.add_argument("--model", help="AVDM variant to calibrate (default: avdm)")
    ca.add_argument(
        "--contrasts",
        "--contrast",
        dest="contrasts",
        type=parse_float_list,
        help="grating contrasts to include (default: 0.5,1)",
    )
    add_out(ca, "results/calibration")
    ca.add_argument("--name", help="name of this calibration (default: from fps and size)")
    ca.add_argument(
        "--update-defaults",
        action="store_true",
        help="also store the fit as the shipped default for this fps and deg/px "
        "(edits avdm/calibrations.json in an editable install)",
    )
    ca.set_defaults(func=cmd_calibrate)

    def add_summary_options(p: argparse.ArgumentParser) -> None:
        p.add_argument(
            "--threshold-dps",
            "--threshold",
            dest="threshold_dps",
            type=positive_float,
            help="response threshold, deg/s (default: %(default)s, the paper's)",
        )
        p.add_argument(
            "--near-wall-m",
            type=positive_float,
            help="'near the wall' = robot centre within this of a wall, m (default: %(default)s)",
        )
        p.add_argument(
            "--centre-m",
            type=positive_float,
            help="'centre' = farther than this from every wall, m (default: %(default)s)",
        )
        p.add_argument(
            "--exclude-turns",
            action="store_true",
            help="summarise straight driving only: leave out frames where the robot turns "
            "(or turned within --turn-hold-frames), so its own rotation is not counted as the "
            "scene's complexity",
        )
        p.add_argument(
            "--turn-threshold-dps",
            type=positive_float,
            help="the robot turns when its own yaw rate exceeds this, deg/s (default: %(default)s)",
        )
        p.add_argument(
            "--turn-hold-frames",
            type=int,
            help="frames after a turn still counted as turning: the AVDM remembers a turn for "
            "its 10-frame window (default: %(default)s)",
        )

    tb = sub.add_parser(
        "tables",
        help="recordings -> frames, model_outputs, events, summary Parquet tables",
        description=(
            "Read recordings and write frames.parquet, model_outputs.parquet, events.parquet "
            "and summary.parquet into --out. Without --model the online model's logged outputs "
            "are used; each --model (repeatable) is recomputed from the raw frames instead."
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="models:\n" + describe_models(),
    )
    tb.add_argument("recordings", nargs="+", metavar="REC", help=".rrd recordings")
    add_out(tb, "results/tables")
    add_models(tb)
    add_summary_options(tb)
    tb.set_defaults(func=cmd_tables)

    pr = sub.add_parser(
        "profile",
        help="3D circle profiles, 'AVDM > 100' histograms and heat maps (paper Figs. 6-7)",
        description=(
            "For every recording segment (one wall TF) or condition: a 3D circle profile "
            "(x, y against time, circle size proportional to the response), the histogram of "
            "responses over the threshold, and a heat map of the mean response per arena "
            "cell. Writes PNGs, profiles.png (overview), profile_summary.parquet and "
            "profiles.rrd (open it with `rerun`)."
        ),
    )
    pr.add_argument("recordings", nargs="+", metavar="REC", help=".rrd recordings")
    add_out(pr, "results/profile")
    add_models(pr)
    pr.add_argument(
        "--by",
        choices=["recording", "condition"],
        help="one profile per recording segment, or pooled per scene/TF/model",
    )
    pr.add_argument(
        "--bin-dps",
        type=positive_float,
        help="histogram bin width (default: %(default)s)",
    )
    pr.add_argument(
        "--cell-m",
        type=positive_float,
        help="heat-map cell size, m (default: %(default)s)",
    )
    add_summary_options(pr)
    pr.set_defaults(func=cmd_profile)

    cp = sub.add_parser(
        "compare",
        help="run model variants on the same recorded frames and compare them",
        description=(
            "Recompute every --model variant on the recording's raw frames; write per-variant "
            "statistics and pairwise correlations (Parquet), compare.png, and variants.rrd with "
            "the traces under /model_variants/<name>/..., which opens alongside the original: "
            "`rerun REC OUT/variants.rrd`."
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="example:\n  vdc-analyse compare rec.rrd --model avdm --model avdm-on "
        "--model avdm:beta=0.5 --out results/compare\n\nmodels:\n" + describe_models(),
    )
    cp.add_argument("recording", metavar="REC", help="one .rrd recording")
    add_models(cp, required=True, help="a variant to run (give at least two)")
    add_out(cp, "results/compare")
    add_summary_options(cp)
    cp.set_defaults(func=cmd_compare)

    co = sub.add_parser(
        "collision",
        help="collision-study metrics and density maps of closed-loop recordings (Fig. 8)",
        description=(
            "For every collision-mode recording (vdc-capture sim --behaviour collision): "
            "avoidances, crashes, success rate = avoidances / (avoidances + crashes), false "
            "alarms (avoidances with the wall farther than --false-alarm-m ahead), distance to "
            "collision at each avoidance, and density maps of the trajectory, avoidance and "
            "crash positions. Writes collision_summary.parquet, collision_events.parquet, a PNG "
            "per recording, collision_study.png and collision.rrd."
        ),
    )
    co.add_argument("recordings", nargs="+", metavar="REC", help="collision-mode .rrd files")
    add_out(co, "results/collision")
    co.add_argument(
        "--false-alarm-m",
        type=positive_float,
        help="avoidance with the wall farther ahead than this = false alarm, m "
        "(default: %(default)s)",
    )
    co.add_argument(
        "--bin-m",
        type=positive_float,
        help="density-map bin, m (default: %(default)s)",
    )
    co.set_defaults(func=cmd_collision)

    cs = sub.add_parser(
        "collision-study",
        help="record and analyse the three-phase collision protocol (+ adaptive detector)",
        description=(
            "Run the paper's protocol in simulation: TF 0, TF 3 Hz, and TF 3 Hz with the "
            "adjusted detection threshold, each --minutes long, plus the complexity-adaptive "
            "detector at TF 3 and TF 0 (beyond the paper). Phases run in parallel processes "
            "and finished ones are reused. Writes the recordings, the collision analysis and "
            "collision_study.md with the paper's numbers beside ours."
        ),
    )
    cs.add_argument(
        "--minutes",
        type=positive_float,
        help="length of each phase (default: %(default)s, the paper's)",
    )
    add_out(cs, "results/collision-study")
    cs.add_argument(
        "--detector",
        help="collision detector (default: %(default)s; lgmd-plus = released "
        "parameters, which never alert on this arena's static walls)",
    )
    cs.add_argument(
        "--adjusted",
        help="detector overrides of the 'adjusted threshold' phase (default: %(default)s)",
    )
    add_seed_options(cs, 5)
    add_executor_options(cs, "simulated runs")
    cs.add_argument(
        "--false-alarm-m",
        type=positive_float,
        help="false-alarm distance, m (default: %(default)s)",
    )
    cs.set_defaults(func=cmd_collision_study)

    bt = sub.add_parser(
        "batch",
        help="many recordings x many variants: one task each, on all cores or a Dask cluster",
        description=(
            "Every (recording, --model) pair is one task: it reads the raw frames, recomputes "
            "the variant and writes its own Parquet parts atomically under "
            "OUT/parts/recording_id=.../model=.../. Finished parts are skipped on a re-run "
            "(--force recomputes). At the end the parts are concatenated into the same "
            "frames, model_outputs, events and summary tables `tables` writes. A failing "
            "task is listed and does not stop the others (exit status 1)."
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="models:\n" + describe_models(),
    )
    bt.add_argument("recordings", nargs="+", metavar="REC", help=".rrd recordings")
    add_out(bt, "results/batch")
    add_models(bt, required=True)
    add_summary_options(bt)
    add_executor_options(bt, "analysis tasks")
    bt.add_argument(
        "--shard",
        help="I/N: run only tasks I, I+N, ... (0-based; default in a SLURM array: its own); "
        "then `vdc-analyse summarise OUT`",
    )
    bt.add_argument("--force", action="store_true", help="recompute finished parts")
    bt.set_defaults(func=cmd_batch)

    sm = sub.add_parser(
        "summarise",
        help="concatenate a batch's finished parts into the four tables",
        description="After sharded batch runs: OUT/parts/... -> OUT/{frames,model_outputs,"
        "events,summary}.parquet, as `tables` writes them.",
    )
    sm.add_argument("out", metavar="OUT", help="the batch's --out folder")
    sm.set_defaults(func=cmd_summarise)

    cx = sub.add_parser(
        "complexity",
        help="the AVDM beside P.910 SI/TI, optic flow and compression, per frame",
        description=(
            "For any recording (video, arena, robot): per frame the AVDM's omega_dps, ITU-T "
            "P.910 SI and TI (2022 and legacy, via siti-tools), mean absolute frame "
            "difference, DIS optic-flow speed in deg/s, edge density, zlib and JPEG "
            "compression. Writes complexity.parquet, complexity_correlations.parquet, and "
            "per recording a PNG and an .rrd that opens beside the source "
            "(`rerun REC OUT/complexity_<id>.rrd`)."
        ),
    )
    cx.add_argument("recordings", nargs="+", metavar="REC", help=".rrd recordings")
    add_out(cx, "results/complexity")
    cx.add_argument(
        "--model",
        default=FOOTAGE_MODEL,
        help="the AVDM variant (default: %(default)s, valid 1-300 deg/s on real footage; "
        "avdm is the paper's, valid up to about 1 px of motion per frame)",
    )
    cx.add_argument(
        "--flow-preset",
        choices=["ultrafast", "fast", "medium"],
        help="DIS optic-flow preset (default: %(default)s)",
    )
    cx.add_argument("--jpeg-quality", type=int, help="JPEG quality (default: 75)")
    cx.set_defaults(func=cmd_complexity)

    rp = sub.add_parser(
        "reproduce",
        help="reproduce the paper end to end and write a claim-by-claim report",
        description=(
            "Run the SF-TF sweep, the open-loop approach, closed-loop profiling (grating TF 0, "
            "1, 3 Hz; natural scene TF 0, 3 Hz) and the collision study (with the adaptive "
            "detector), then write report.md and a self-contained report.html that put each "
            "paper claim beside what was measured. --quick uses short runs (minutes); the "
            "default uses the paper's 30-minute durations. Every condition runs with --seeds "
            "seeds; each claim is reported with means, 95 % intervals and a trend test across "
            "them, and holds only if it holds at that confidence. Runs already recorded with "
            "the same configuration are reused."
        ),
    )
    rp.add_argument("--quick", action="store_true", help="short runs: 3 min, 3 repeats, 3 seeds")
    add_out(rp, "results/reproduce")
    add_executor_options(rp, "simulated runs")
    add_seed_options(rp, None)
    rp.add_argument("--profile-minutes", type=positive_float, help="override: profiling run length")
    rp.add_argument(
        "--collision-minutes", type=positive_float, help="override: collision phase length"
    )
    rp.add_argument(
        "--approach-repeats",
        "--repeats",
        dest="approach_repeats",
        type=int,
        help="override: approach repeats per TF",
    )
    rp.add_argument(
        "--sweep-duration-s", type=positive_float, help="override: seconds per sweep cell"
    )
    rp.add_argument("--detector", help="collision detector of the study (default: %(default)s)")
    rp.add_argument(
        "--adjusted",
        help="detector overrides of the 'adjusted threshold' phase (default: %(default)s)",
    )
    rp.set_defaults(func=cmd_reproduce)
    bind_commands(sub, SETTINGS, command)
    return parser


def cli_reference() -> str:
    """docs/cli.md: every command and flag of ``vdc-capture`` and ``vdc-analyse``, rendered from
    the parsers (whose defaults are the settings dataclasses'); a test keeps the file equal."""
    import capture.cli

    lines = [
        "# CLI reference",
        "",
        "Generated from the command lines' parsers by `analysis.cli.cli_reference()`; "
        "`tests/test_layout.py` keeps this page equal to it. Each flag is the field of the same "
        "name of the command's settings dataclass (see the README's table of functions).",
        "",
    ]
    clis = ((capture.cli.PROG, capture.cli), (PROG, sys.modules[__name__]))
    for prog, cli in clis:
        parser = cli.build_parser()
        subs = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        for name, sub in subs.choices.items():
            target = cli.SETTINGS.get(name)
            fields = (
                {f.name: field_default(f) for f in dataclasses.fields(load_settings_class(target))}
                if target
                else {}
            )
            lines += [f"## `{prog} {name}`", "", (sub.description or "").strip(), ""]
            lines += ["| flag | default | meaning |", "|---|---|---|"]
            for act in sub._actions:
                if isinstance(act, argparse._HelpAction):
                    continue
                flag = ", ".join(f"`{o}`" for o in act.option_strings) or f"`{act.dest.upper()}`"
                default = fields.get(act.dest, act.default)  # the settings' default first
                if any(default is v for v in (None, False, argparse.SUPPRESS, dataclasses.MISSING)):
                    default = ""  # identity: 0 and 0.0 are defaults worth showing
                elif default == ():
                    default = ""
                text = (act.help or "").replace("|", "\\|").replace("\n", " ")
                text = text.replace("%(default)s", str(act.default)).replace("%%", "%")
                lines.append(f"| {flag} | {f'`{default}`' if default != '' else ''} | {text} |")
            lines.append("")
    return "\n".join(lines).rstrip() + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser(command_of(argv, SETTINGS))
    args = parser.parse_args(argv)
    func: Callable[[argparse.Namespace], int] = args.func
    try:
        return func(args)
    except (UserError, ValueError) as exc:
        fail(f"{PROG} {args.command}", str(exc))
    except TasksFailed as exc:  # the finished runs are kept; a re-run retries the failed
        print(f"{PROG} {args.command}: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:
        fail(f"{PROG} {args.command}", f"{exc.strerror or exc}: {exc.filename or ''}".rstrip(": "))
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
