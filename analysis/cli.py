"""``vdc-analyse``: offline analysis (sweeps, calibration, and later recordings and reports)."""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from avdm.cli_support import (
    OneLineParser,
    UserError,
    fail,
    parse_float_list,
    parse_size,
    positive_float,
)
from avdm.registry import describe_models

PROG = "vdc-analyse"


def _progress(total: int, desc: str):  # -> tqdm
    from tqdm import tqdm

    # disable=None: a bar on terminals, silence in pipes and CI logs
    return tqdm(total=total, desc=desc, unit="cell", disable=None, leave=False, file=sys.stderr)


def cmd_sweep(args: argparse.Namespace) -> int:
    import polars as pl

    from analysis.parquet_io import write_parquet
    from analysis.sweep import (
        DEFAULT_SFS_UPC,
        DEFAULT_TFS_HZ,
        SweepConfig,
        check_cells,
        grid_cells,
        monotonicity,
        paper_cells,
        plot_grid,
        plot_paper,
        run_sweep,
    )
    from avdm.registry import canonical_name, make_params

    config = SweepConfig(
        size=args.size,
        fps=args.fps,
        duration_s=args.duration,
        contrast=args.contrast,
        waveform="square" if args.square else "sine",
    )
    if not 0 < args.contrast <= 1:
        raise UserError(f"--contrast must be in (0, 1], got {args.contrast:g}")
    grid = args.sf is not None or args.tf is not None
    if grid:
        cells = grid_cells(args.sf or DEFAULT_SFS_UPC, args.tf or DEFAULT_TFS_HZ)
    else:
        if config.size[1] < 100 or config.fps < 300:
            raise UserError(
                "the paper layout needs SF up to 50 upc and TF up to 150 Hz: use --size of at "
                "least 100 px wide and --fps of at least 300, or give --sf and --tf lists"
            )
        cells = paper_cells()
    check_cells(cells, config)
    name = canonical_name(args.model)
    params = make_params(args.model, fps=config.fps, deg_per_px=config.deg_per_px)
    out = Path(args.out)
    with _progress(len(cells), f"sweep {name}") as bar:
        df = run_sweep(args.model, cells, config, progress=bar.update)
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
            "layout": "grid" if grid else "paper",
        },
    }
    write_parquet(df, out / "sweep.parquet", meta)
    # the paper layout's cross-sections have 3 cells: only its six full rows/columns count
    mono = monotonicity(df, min_points=3 if grid else 4)
    write_parquet(mono, out / "monotonicity.parquet", meta)
    title = (
        f"{name} on drifting {config.waveform} gratings, {config.size[1]}x{config.size[0]} px, "
        f"{config.fps:g} Hz, contrast {config.contrast:g}"
    )
    png = (plot_grid if grid else plot_paper)(
        df, out / "sweep.png", *(() if grid else (config,)), title
    )
    print(f"{len(df)} cells -> {out / 'sweep.parquet'}, {png}")
    print("monotonicity of the response (Spearman rho of omega_dps):")
    for r in mono.iter_rows(named=True):
        print(
            f"  vs {r['along'].upper():<2} at {r['fixed']:<12} n={r['n']:<3} "
            f"rho={r['rho']:+.3f}  {r['trend']}"
        )
    inc = mono.filter(pl.col("along") == "tf")
    dec = mono.filter(pl.col("along") == "sf")
    print(
        f"summary: {int((inc['trend'] == 'increasing').sum())}/{inc.height} TF rows increasing, "
        f"{int((dec['trend'] == 'decreasing').sum())}/{dec.height} SF columns decreasing"
    )
    return 0


def cmd_calibrate(args: argparse.Namespace) -> int:
    from analysis.calibrate import plot_calibration, update_shipped, write_calibration
    from avdm.calibration import fit_decoding, valid_periods_px, valid_tfs_hz
    from avdm.registry import canonical_name, make_params

    h, w = args.size
    deg_per_px = args.deg_per_px if args.deg_per_px is not None else 360.0 / w
    spec = args.model
    base = make_params(
        spec + (":" if ":" not in spec else ",") + "a=1,b=1", fps=args.fps, deg_per_px=deg_per_px
    )
    contrasts = tuple(args.contrast)
    n_cells = len(valid_periods_px(w)) * len(valid_tfs_hz(args.fps)) * len(contrasts)
    with _progress(n_cells, "calibrate") as bar:
        result = fit_decoding(base, size=(h, w), contrasts=contrasts, progress=bar.update)  # type: ignore[arg-type]
    out = Path(args.out)
    name = args.name or f"fps{args.fps:g}-{w}x{h}"
    entry = write_calibration(result, out / "calibration.json", name, canonical_name(spec), base)
    png = plot_calibration(result, out / "calibration.png")
    print(f"calibration {name}: fps={args.fps:g} Hz, {deg_per_px:.6g} deg/px, {w}x{h} px")
    print(f"  a = {result.a:.6g}   b = {result.b:.6g}")
    print(
        f"  log-log R^2 = {result.r2:.4f}; over {result.n_points} valid cells the decoded "
        f"omega is off by {100 * result.rms_rel_error:.1f} % RMS, "
        f"{100 * result.max_rel_error:.1f} % at worst"
    )
    print(f"  use it as: --model {spec.split(':')[0]}:a={result.a:.6g},b={result.b:.6g}")
    print(f"  wrote {out / 'calibration.json'} and {png}")
    if args.update_defaults:
        path = update_shipped(entry)
        print(f"  updated the shipped defaults in {path}")
    return 0


def _frame_progress(desc: str):  # -> tqdm
    from tqdm import tqdm

    return tqdm(total=None, desc=desc, unit="frame", disable=None, leave=False, file=sys.stderr)


def _notice(msg: str) -> None:
    print(f"{PROG}: note: {msg}", file=sys.stderr)


def _table_settings(args: argparse.Namespace):  # -> TableSettings
    from analysis.tables import TableSettings

    return TableSettings(
        threshold_dps=args.threshold, near_wall_m=args.near_wall_m, centre_m=args.centre_m
    )


def cmd_tables(args: argparse.Namespace) -> int:
    from analysis.tables import build_tables, write_tables

    settings = _table_settings(args)
    with _frame_progress("tables") as bar:
        tables, meta = build_tables(args.recordings, args.model, settings, bar.update, _notice)
    paths = write_tables(tables, Path(args.out), meta)
    for path, (name, df) in zip(paths, tables.items(), strict=True):
        print(f"{name:<14} {df.height:>8} rows -> {path}")
    summary = tables["summary"]
    print("summary (primary output after warm-up):")
    for r in summary.iter_rows(named=True):
        print(
            f"  {r['recording_id']}  {r['model']:<16} TF {r['wall_tf_hz']:g} Hz: "
            f"mean {r['mean']:.1f}, p95 {r['p95']:.1f}, > 100: {100 * r['frac_over_100']:.1f} %, "
            f"near wall / centre {r['near_wall_centre_ratio']:.2f}"
        )
    return 0


def cmd_profile(args: argparse.Namespace) -> int:
    import hashlib

    import polars as pl

    from analysis.analysis_rrd import write_profile_rrd
    from analysis.parquet_io import write_parquet
    from analysis.profile import (
        ProfileSettings,
        plot_overview,
        plot_segment,
        segment_summary,
        segments_from_tables,
    )
    from analysis.tables import build_tables

    settings = _table_settings(args)
    prof = ProfileSettings(threshold_dps=args.threshold, bin_dps=args.bin_dps, cell_m=args.cell_m)
    with _frame_progress("profile") as bar:
        tables, meta = build_tables(args.recordings, args.model, settings, bar.update, _notice)
    segs = segments_from_tables(
        tables["frames"],
        tables["model_outputs"],
        tables["summary"],
        meta["arena_half_extent_m"],
        args.by,
        settings.warmup_frames,
    )
    out = Path(args.out)
    pngs = [plot_segment(seg, prof, out / f"profile_{seg.key}.png") for seg in segs]
    overview = plot_overview(segs, prof, out / "profiles.png")
    summary = pl.DataFrame([segment_summary(seg, prof, settings) for seg in segs])
    meta = {
        **meta,
        "profile": {
            "threshold_dps": prof.threshold_dps,
            "bin_dps": prof.bin_dps,
            "cell_m": prof.cell_m,
            "by": args.by,
        },
    }
    write_parquet(summary, out / "profile_summary.parquet", meta)
    rid = "profile-" + hashlib.sha1("|".join(meta["recordings"]).encode()).hexdigest()[:8]
    rrd = write_profile_rrd(segs, prof, out / "profiles.rrd", rid)
    print(
        f"{len(segs)} profile(s) by {args.by}: {len(pngs)} PNGs, {overview}, {rrd}, "
        f"{out / 'profile_summary.parquet'}"
    )
    for r in summary.iter_rows(named=True):
        print(
            f"  {r['segment']:<44} n={r['n_frames']:>6}  > {prof.threshold_dps:g}: "
            f"{100 * r['frac_over_threshold']:5.1f} %  near wall {r['near_wall_mean']:.1f} / "
            f"centre {r['centre_mean']:.1f}"
        )
    return 0


def cmd_compare(args: argparse.Namespace) -> int:
    from analysis.analysis_rrd import write_variants_rrd
    from analysis.compare import pairwise_correlations, plot_compare, variant_statistics
    from analysis.parquet_io import write_parquet
    from analysis.tables import load_recording, model_params, recompute
    from avdm.registry import canonical_name, make_model

    if len(args.model) < 2:
        raise UserError("compare needs at least two --model variants")
    names = [canonical_name(m) for m in args.model]
    if len(set(names)) != len(names):
        raise UserError(f"the same variant is given twice: {', '.join(names)}")
    settings = _table_settings(args)
    loaded = load_recording(args.recording)
    if loaded.rec.notice:
        _notice(loaded.rec.notice)
    with _frame_progress("compare") as bar:
        outputs = recompute(loaded, args.model, bar.update)
    stats = variant_statistics(loaded, outputs, settings)
    corr = pairwise_correlations(outputs, settings.warmup_frames)
    out = Path(args.out)
    meta = {
        "params": model_params(loaded, args.model),
        "recording": loaded.recording_id,
        "settings": {
            "threshold_dps": settings.threshold_dps,
            "near_wall_m": settings.near_wall_m,
            "centre_m": settings.centre_m,
            "warmup_frames": settings.warmup_frames,
        },
    }
    write_parquet(stats, out / "compare_summary.parquet", meta)
    write_parquet(corr, out / "compare_correlations.parquet", meta)
    png = plot_compare(
        outputs,
        stats,
        corr,
        settings,
        f"{loaded.recording_id}: variants on identical frames",
        out / "compare.png",
    )
    ctx = loaded.camera_context()
    units = {
        n: {o.name: o.unit for o in make_model(m, **ctx).outputs}
        for n, m in zip(names, args.model, strict=True)
    }
    rrd = write_variants_rrd(
        loaded.recording_id, outputs, units, out / "variants.rrd", loaded.online_model
    )
    print(f"{len(names)} variants on {loaded.frames.height} frames -> {png}, {rrd}")
    for r in stats.iter_rows(named=True):
        print(
            f"  {r['model']:<22} mean {r['mean']:8.2f}  p95 {r['p95']:8.2f}  "
            f"> {settings.threshold_dps:g}: {100 * r['frac_over_threshold']:5.1f} %  "
            f"near wall / centre {r['near_wall_centre_ratio']:.2f}"
        )
    for r in corr.iter_rows(named=True):
        print(
            f"  corr {r['model_a']} ~ {r['model_b']}: pearson {r['pearson']:.3f}, "
            f"spearman {r['spearman']:.3f}"
        )
    print(f"view together: rerun {args.recording} {rrd}")
    return 0


def cmd_collision(args: argparse.Namespace) -> int:
    from analysis.collision import CollisionSettings, collision_outputs, collision_table_markdown

    s = CollisionSettings(false_alarm_m=args.false_alarm_m, bin_m=args.bin_m)
    out = Path(args.out)
    summary, _ = collision_outputs(args.recordings, out, s, _notice)
    print(collision_table_markdown(summary))
    print(f"wrote {out / 'collision_summary.parquet'}, collision_*.png, {out / 'collision.rrd'}")
    return 0


def cmd_collision_study(args: argparse.Namespace) -> int:
    from analysis.collision import CollisionSettings, collision_outputs, collision_table_markdown
    from analysis.collision_study import run_phases, study_phases
    from avdm.registry import parse_model_spec

    parse_model_spec(args.detector)  # a bad detector fails before anything runs
    if args.adjusted:
        parse_model_spec(f"{args.detector.split(':')[0]}:{args.adjusted}")
    out = Path(args.out)
    phases = study_phases(args.detector, args.adjusted)
    print(
        f"collision study: {len(phases)} phases of {args.minutes:g} min, detector "
        f"{args.detector}, adjusted threshold {args.adjusted or '(none)'}",
        file=sys.stderr,
    )
    paths = run_phases(
        phases,
        args.minutes,
        args.seed,
        out / "recordings",
        args.jobs,
        lambda m: print(m, file=sys.stderr),
    )
    s = CollisionSettings(false_alarm_m=args.false_alarm_m)
    summary, _ = collision_outputs([str(p) for p in paths.values()], out, s, _notice)
    table = collision_table_markdown(summary)
    print(table)
    (out / "collision_study.md").write_text(
        "# Collision study\n\n" + table + "\n\nPaper: 229, 432 and 233 avoidances in three "
        "30-min phases (TF 0, TF 3, TF 3 with the adjusted threshold), success > 90 % in "
        "each.\n",
        encoding="utf-8",
    )
    print(f"wrote {out / 'collision_study.md'}, {out / 'collision_study.png'}")
    return 0


def cmd_reproduce(args: argparse.Namespace) -> int:
    from analysis.reproduce import Plan, reproduce

    plan = Plan.make(
        args.quick,
        profile_minutes=args.profile_minutes,
        collision_minutes=args.collision_minutes,
        approach_repeats=args.repeats,
        seed=args.seed,
        jobs=args.jobs,
    )
    out = Path(args.out)
    t0 = time.perf_counter()
    paths = reproduce(plan, out, lambda m: print(m, file=sys.stderr, flush=True))
    from analysis.reproduce import evaluate_claims

    for c in evaluate_claims(out):
        print(f"[{c.verdict:^13}] {c.claim}")
    print(f"report: {paths[0]} and {paths[1]} ({time.perf_counter() - t0:.0f} s)")
    return 0


def build_parser() -> argparse.ArgumentParser:
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
    sw.add_argument("--out", default="results/sweep", help="output folder (default: %(default)s)")
    sw.add_argument("--model", default="avdm", help="model variant (default: %(default)s)")
    sw.add_argument("--sf", type=parse_float_list, help="spatial frequencies, upc, e.g. 1,5,10")
    sw.add_argument("--tf", type=parse_float_list, help="temporal frequencies, Hz, e.g. 1,3,10")
    sw.add_argument(
        "--size",
        type=parse_size,
        default=(100, 100),
        help="stimulus WIDTHxHEIGHT px; the width spans 360 deg (default: 100x100)",
    )
    sw.add_argument(
        "--fps", type=positive_float, default=300.0, help="frame rate, Hz (default: %(default)s)"
    )
    sw.add_argument(
        "--duration",
        type=positive_float,
        default=1.0,
        help="seconds of stimulus per cell (default: %(default)s)",
    )
    sw.add_argument(
        "--contrast",
        type=positive_float,
        default=1.0,
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
    ca.add_argument(
        "--fps", type=positive_float, default=300.0, help="frame rate, Hz (default: %(default)s)"
    )
    ca.add_argument(
        "--deg-per-px",
        type=positive_float,
        default=None,
        help="degrees per pixel (default: 360/width, the offline-stimulus convention)",
    )
    ca.add_argument(
        "--size",
        type=parse_size,
        default=(100, 100),
        help="frame WIDTHxHEIGHT px (default: 100x100)",
    )
    ca.add_argument("--model", default="avdm", help="AVDM variant to calibrate (default: avdm)")
    ca.add_argument(
        "--contrast",
        type=parse_float_list,
        default=[0.5, 1.0],
        help="grating contrasts to include (default: 0.5,1)",
    )
    ca.add_argument(
        "--out", default="results/calibration", help="output folder (default: %(default)s)"
    )
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
            "--threshold",
            type=positive_float,
            default=100.0,
            help="response threshold, deg/s (default: %(default)s, the paper's)",
        )
        p.add_argument(
            "--near-wall-m",
            type=positive_float,
            default=0.15,
            help="'near the wall' = robot centre within this of a wall, m (default: %(default)s)",
        )
        p.add_argument(
            "--centre-m",
            type=positive_float,
            default=0.25,
            help="'centre' = farther than this from every wall, m (default: %(default)s)",
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
    tb.add_argument("--out", default="results/tables", help="output folder (default: %(default)s)")
    tb.add_argument("--model", action="append", help="recompute this variant (repeatable)")
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
    pr.add_argument("--out", default="results/profile", help="output folder (default: %(default)s)")
    pr.add_argument("--model", action="append", help="recompute this variant (repeatable)")
    pr.add_argument(
        "--by",
        choices=["recording", "condition"],
        default="recording",
        help="one profile per recording segment, or pooled per scene/TF/model",
    )
    pr.add_argument(
        "--bin-dps",
        type=positive_float,
        default=20.0,
        help="histogram bin width (default: %(default)s)",
    )
    pr.add_argument(
        "--cell-m",
        type=positive_float,
        default=0.05,
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
    cp.add_argument(
        "--model", action="append", required=True, help="a variant to run (give at least two)"
    )
    cp.add_argument("--out", default="results/compare", help="output folder (default: %(default)s)")
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
    co.add_argument(
        "--out", default="results/collision", help="output folder (default: %(default)s)"
    )
    co.add_argument(
        "--false-alarm-m",
        type=positive_float,
        default=0.30,
        help="avoidance with the wall farther ahead than this = false alarm, m "
        "(default: %(default)s)",
    )
    co.add_argument(
        "--bin-m",
        type=positive_float,
        default=0.02,
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
        default=30.0,
        help="length of each phase (default: %(default)s, the paper's)",
    )
    cs.add_argument(
        "--out", default="results/collision-study", help="output folder (default: %(default)s)"
    )
    cs.add_argument(
        "--detector",
        default="lgmd-plus-arena",
        help="collision detector (default: %(default)s; lgmd-plus = released "
        "parameters, which never alert on this arena's static walls)",
    )
    cs.add_argument(
        "--adjusted",
        default="t_ffi=30",
        help="detector overrides of the 'adjusted threshold' phase (default: %(default)s)",
    )
    cs.add_argument("--seed", type=int, default=1, help="random seed (default: %(default)s)")
    cs.add_argument(
        "--jobs",
        type=int,
        default=max(1, os.cpu_count() or 1),
        help="parallel capture processes (default: the number of cores)",
    )
    cs.add_argument(
        "--false-alarm-m",
        type=positive_float,
        default=0.30,
        help="false-alarm distance, m (default: %(default)s)",
    )
    cs.set_defaults(func=cmd_collision_study)

    rp = sub.add_parser(
        "reproduce",
        help="reproduce the paper end to end and write a claim-by-claim report",
        description=(
            "Run the SF-TF sweep, the open-loop approach, closed-loop profiling (grating TF 0, "
            "1, 3 Hz; natural scene TF 0, 3 Hz) and the collision study (with the adaptive "
            "detector), then write report.md and a self-contained report.html that put each "
            "paper claim beside what was measured. --quick uses short runs (minutes); the "
            "default uses the paper's 30-minute durations. Runs already recorded with the same "
            "configuration are reused."
        ),
    )
    rp.add_argument("--quick", action="store_true", help="short runs: 3 min, 3 repeats")
    rp.add_argument(
        "--out", default="results/reproduce", help="output folder (default: %(default)s)"
    )
    rp.add_argument(
        "--jobs",
        type=int,
        default=max(1, os.cpu_count() or 1),
        help="parallel capture processes (default: the number of cores)",
    )
    rp.add_argument("--seed", type=int, default=1, help="random seed (default: %(default)s)")
    rp.add_argument("--profile-minutes", type=positive_float, help="override: profiling run length")
    rp.add_argument(
        "--collision-minutes", type=positive_float, help="override: collision phase length"
    )
    rp.add_argument("--repeats", type=int, help="override: approach repeats per TF")
    rp.set_defaults(func=cmd_reproduce)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    func: Callable[[argparse.Namespace], int] = args.func
    try:
        return func(args)
    except (UserError, ValueError) as exc:
        fail(f"{PROG} {args.command}", str(exc))
    except OSError as exc:
        fail(f"{PROG} {args.command}", f"{exc.strerror or exc}: {exc.filename or ''}".rstrip(": "))
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
