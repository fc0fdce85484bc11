"""``vdc-analyse``: offline analysis (sweeps, calibration, and later recordings and reports)."""

from __future__ import annotations

import argparse
import sys
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


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog=PROG,
        description="Offline analysis for vdc: AVDM sweeps and calibration on synthetic gratings.",
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
