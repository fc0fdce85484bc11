"""The boundary campaign's grid on the executors: the issue's 30-minute target on 2 cores.

Run: ``python benchmarks/bench_boundary.py [--jobs 2] [--minutes 10] [--seeds 5]
[--executor local|dask] [--out DIR]``. Runs ``vdc-analyse boundary``'s default grid (wall TF
0, 1, 3 Hz x grating and natural walls x LGMD+ T_ffi 12, 20, 30, 45 x 5 seeds of 10-min
closed-loop runs, plus the 30 profiling runs that give each condition its complexity) from
scratch, then again (every run reused: the resume path), and prints the wall-clock times and
the recorded minutes per wall-clock minute. The plain reference measured in the same run: one
of the grid's runs recorded alone in this process (the cost of one run without the executor),
times the number of runs divided by the workers: the ideal the campaign is held against.

``--coverage`` checks the adaptive design's 95 % interval (issue #34) on simulated detectors of
known boundary: a detector whose success is a known function of the wall TF it is given
(logit success = logit 0.9 - slope x (complexity - truth), complexity the profile of
``docs/guides/boundary.md``'s grid, a random effect between runs of sd 0.3 on the logit, 20-80
approaches per run), run through the design's own loop (``design_runs``: the placement, the
fits, the stopping) with the default budget and precision, 20 repeats with different seeds and
true boundaries; it prints how many intervals cover the truth (target: >= 18).

``--economy --grid DIR`` compares an adaptive campaign (LGMD+ at T_ffi 12 and 45, the default
budget, kept in ``--out``) with a finished default grid in DIR (``vdc-analyse boundary --out
DIR``): each value's boundary and how many runs each design spent (target: the adaptive one
within one grid step, the span between the grid's conditions around its boundary, of the
grid's, with <= 40 % of the grid's runs for those values).

``--economy --per-scene --grid DIR`` does the same for the per-scene design (``--per-scene``,
kept in ``--out``), judged per (T_ffi, scene) against the grid's per-scene fit (each scene's runs
up to its first clearly failing one): where the grid places a boundary, the adaptive one within
one grid step of it (the gap between that scene's two grid conditions around it); where the
grid places none (the scene fails from its least complex condition, or never), the same state.

``--scaling`` instead runs a smaller grid (``--minutes 2 --seeds 2`` unless given) from scratch
on the local pool and on a local Dask cluster (127.0.0.1) with 1 and 2 workers and prints the
times and speed-ups: how the campaign scales on a cluster.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from pathlib import Path

from analysis.boundary.settings import BoundarySettings
from analysis.experiments.collision.boundary_campaign import boundary, grid_items
from capture.run import REPLACE_OUTPUT
from capture.sim import record_sim


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=2, help="workers (default: %(default)s)")
    ap.add_argument("--minutes", type=float, default=10.0, help="run length (default: %(default)s)")
    ap.add_argument("--seeds", type=int, default=5, help="seeds (default: %(default)s)")
    ap.add_argument("--executor", default="local", choices=("local", "dask"))
    ap.add_argument("--out", default=None, help="keep the campaign here (default: a temp folder)")
    ap.add_argument("--scaling", action="store_true", help="local and Dask, 1 and 2 workers")
    ap.add_argument("--coverage", action="store_true", help="the adaptive interval's coverage")
    ap.add_argument("--economy", action="store_true", help="adaptive against a finished grid")
    ap.add_argument("--grid", default=None, help="--economy: the finished default grid's folder")
    ap.add_argument(
        "--per-scene", action="store_true", help="--economy: the per-scene design, judged per scene"
    )
    args = ap.parse_args()
    if args.coverage:
        coverage()
        return
    if args.economy:
        economy_per_scene(args) if args.per_scene else economy(args)
        return
    if args.scaling:
        scaling(args)
        return
    s = BoundarySettings(
        minutes=args.minutes, seeds=args.seeds, jobs=args.jobs, executor=args.executor
    )
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.out or tmp)
        key, one, path, _ = grid_items(s, Path(tmp) / "alone")[-1]
        record_sim(one, path)  # warm: compile caches, calibrations
        t0 = time.perf_counter()
        record_sim(one, path, REPLACE_OUTPUT)
        alone = time.perf_counter() - t0
        grid = len(grid_items(s, out))
        n_runs = grid + grid // len(s.grid_values())  # plus one profiling run per condition
        t0 = time.perf_counter()
        res = boundary(s, out)
        cold = time.perf_counter() - t0
        t0 = time.perf_counter()
        boundary(s, out)
        warm = time.perf_counter() - t0
    recorded_min = n_runs * args.minutes
    print(
        f"grid: {n_runs} runs of {args.minutes:g} min ({recorded_min:.0f} recorded minutes) "
        f"on {args.jobs} {args.executor} worker(s)"
    )
    print(
        f"one run alone ({key}): {alone:.1f} s -> ideal for the grid on {args.jobs} "
        f"workers: {alone * n_runs / args.jobs / 60:.1f} min"
    )
    print(
        f"campaign from scratch: {cold / 60:.1f} min ({recorded_min / (cold / 60):.0f} "
        f"recorded minutes per minute; target < 30 min)"
    )
    print(f"campaign again (all reused): {warm:.1f} s")
    for row in res.boundaries.iter_rows(named=True):
        print(
            f"  boundary at t_ffi={row['t_ffi']:g}: {row['where']} "
            f"{row['boundary_low_dps']:.1f}-{row['boundary_high_dps']:.1f} deg/s"
        )


def scaling(args: argparse.Namespace) -> None:
    minutes = args.minutes if args.minutes != 10.0 else 2.0
    seeds = args.seeds if args.seeds != 5 else 2
    base = {}
    print(f"grid: 3 TF x 2 scenes x 4 T_ffi x {seeds} seeds of {minutes:g} min, plus profiling")
    for executor in ("local", "dask"):
        for jobs in (1, 2):
            s = BoundarySettings(minutes=minutes, seeds=seeds, jobs=jobs, executor=executor)
            with tempfile.TemporaryDirectory() as tmp:
                t0 = time.perf_counter()
                boundary(s, tmp)
                secs = time.perf_counter() - t0
            base.setdefault(executor, secs)
            n = len(grid_items(s, Path("."))) * 5 // 4
            print(
                f"  {executor:5s} {jobs} worker(s): {secs:6.1f} s for {n} runs "
                f"({base[executor] / secs:.2f}x of 1 worker)"
            )


# the default grid's measured profile (docs/findings/boundary.md): wall TF (Hz) -> deg/s per scene
PROFILE = {
    "grating": ([0.0, 1.0, 3.0], [6.7, 12.0, 28.5]),
    "natural": ([0.0, 1.0, 3.0], [10.9, 13.0, 18.5]),
}


def coverage(repeats: int = 20, spread: float = 0.3, slope: float = 0.5) -> None:
    import numpy as np
    import scipy.special

    from analysis.experiments.collision.adaptive import (
        DesignSettings,
        DesignSpace,
        ProfileMap,
        design_runs,
    )

    s = BoundarySettings(design="adaptive")
    profile = ProfileMap({k: (np.array(a), np.array(b)) for k, (a, b) in PROFILE.items()})
    covered, spent, widths = 0, [], []
    for r in range(repeats):
        rng = np.random.default_rng(2000 + r)
        truth = float(rng.uniform(9.0, 24.0))  # deg/s, inside the design's range

        def run_batch(placed: list[dict], truth=truth, rng=rng) -> list[dict]:
            out = []
            for p in placed:  # success a known function of the run's TF (through the profile)
                x = float(profile.to_dps(p["scene"], p["tf_hz"]))
                eta = scipy.special.logit(s.target) - slope * (x - truth) + rng.normal(0, spread)
                n = int(rng.integers(20, 80))
                k = int(rng.binomial(n, scipy.special.expit(eta)))
                out.append(p | {"avoidances": k, "crashes": n - k})
            return out

        rows, fits = design_runs(
            DesignSpace([1.0], ["grating", "natural"], profile, s.tf_bounds()),
            run_batch,
            dataclasses.replace(DesignSettings.of(s), batch=2, seed=r),
        )
        f = fits[1.0]
        hit = f.low <= truth <= f.high
        covered += hit
        spent.append(len(rows))
        widths.append(f.width)
        print(
            f"  repeat {r + 1:2d}: truth {truth:5.1f} deg/s, boundary {f.boundary:5.1f} "
            f"[{f.low:.1f}, {f.high:.1f}] ({f.state}), {len(rows)} runs: "
            f"{'covers' if hit else 'MISSES'}"
        )
    print(
        f"coverage: the 95 % interval covers the true boundary in {covered} of {repeats} "
        f"repeats (target >= 18); median {float(np.median(spent)):.0f} runs, median width "
        f"{float(np.median(widths)):.1f} deg/s -> {'holds' if covered >= 18 else 'FAILS'}"
    )


def economy(args: argparse.Namespace) -> None:
    import math

    import polars as pl

    from analysis.boundary.fit import grid_fits
    from analysis.boundary.statistics import condition_complexity

    if not args.grid:
        raise SystemExit("--economy needs --grid DIR (a finished default grid)")
    grid_dir = Path(args.grid)
    runs = pl.read_parquet(grid_dir / "boundary_runs.parquet")
    prof = pl.read_parquet(grid_dir / "boundary_profiles.parquet")
    complexity = condition_complexity(prof, "profile_dps")
    values = (12.0, 45.0)
    runs = runs.filter(pl.col("t_ffi").is_in(values))
    fitted, _ = grid_fits(runs, complexity, "t_ffi", 0.9)
    from analysis.boundary.statistics import boundaries, condition_statistics

    bracket = boundaries(
        condition_statistics(runs, complexity, ["condition", "t_ffi"]), "t_ffi", 0.9
    )
    grid_runs = runs.height + prof.height * len(values) // 4  # its share of the profiling runs
    s = BoundarySettings(design="adaptive", values=values, jobs=args.jobs, executor=args.executor)
    out = Path(args.out or "/tmp/bench-adaptive")
    t0 = time.perf_counter()
    res = boundary(s, out)
    secs = time.perf_counter() - t0
    adaptive_runs = res.runs.height + len(s.scene_list()) * 3
    print(
        f"runs: adaptive {adaptive_runs} ({res.runs.height} + {len(s.scene_list()) * 3} "
        f"profiling) against the grid's {grid_runs} for T_ffi 12 and 45 ({runs.height} + "
        f"{prof.height * len(values) // 4}, its share of the profiling runs): "
        f"{100 * adaptive_runs / grid_runs:.0f} % (target <= 40 %); campaign {secs / 60:.1f} min"
    )
    within = 0
    for v in values:
        a = res.boundaries.filter(pl.col("t_ffi") == v).row(0, named=True)
        g = fitted.filter(pl.col("t_ffi") == v).row(0, named=True)
        b = bracket.filter(pl.col("t_ffi") == v).row(0, named=True)
        step = b["boundary_high_dps"] - b["boundary_low_dps"]
        grid_point = g["boundary_dps"] if g["fit_state"] == "within" else b["boundary_dps"]
        # found = a placed boundary: an undetermined fit's point estimate is not one
        found = a["fit_state"] == "within"
        ok = found and math.isfinite(step) and abs(a["boundary_dps"] - grid_point) <= step
        within += ok
        print(
            f"  T_ffi {v:g}: adaptive {a['boundary_dps']:.1f} deg/s "
            f"[{a['boundary_dps_low']:.1f}, {a['boundary_dps_high']:.1f}] ({a['fit_state']}); "
            f"grid fitted {g['boundary_dps']:.1f} [{g['boundary_dps_low']:.1f}, "
            f"{g['boundary_dps_high']:.1f}] ({g['fit_state']}), bracket {b['where']} "
            f"{b['boundary_low_dps']:.1f}-{b['boundary_high_dps']:.1f}; one grid step "
            f"{step:.1f} deg/s: {'within' if ok else 'NOT within'}"
            f"{'' if found else ' (the adaptive design placed no boundary)'}"
        )
    print(f"economy: {within} of {len(values)} values within one grid step")


def economy_per_scene(args: argparse.Namespace) -> None:
    """``--economy --per-scene``: the per-scene design's campaign against the grid's per-scene
    fit (:func:`analysis.experiments.collision.adaptive.grid_fits_per_scene`), judged per
    (T_ffi, scene)."""
    import math

    import polars as pl

    from analysis.boundary.statistics import condition_complexity
    from analysis.experiments.collision.adaptive import grid_fits_per_scene

    if not args.grid:
        raise SystemExit("--economy needs --grid DIR (a finished default grid)")
    grid_dir = Path(args.grid)
    values = (12.0, 45.0)
    runs = pl.read_parquet(grid_dir / "boundary_runs.parquet")
    runs = runs.filter(pl.col("t_ffi").is_in(values))
    prof = pl.read_parquet(grid_dir / "boundary_profiles.parquet")
    grid = grid_fits_per_scene(runs, condition_complexity(prof, "profile_dps"), "t_ffi", 0.9)
    grid_runs = runs.height + prof.height * len(values) // 4  # its share of the profiling runs
    s = BoundarySettings(
        design="adaptive", per_scene=True, values=values, jobs=args.jobs, executor=args.executor
    )
    out = Path(args.out or "/tmp/bench-adaptive-per-scene")
    t0 = time.perf_counter()
    res = boundary(s, out)
    secs = time.perf_counter() - t0
    n_prof = len(s.scene_list()) * 3
    adaptive_runs = res.runs.height + n_prof
    share = adaptive_runs / grid_runs
    print(
        f"runs: adaptive per scene {adaptive_runs} ({res.runs.height} + {n_prof} profiling) "
        f"against the grid's {grid_runs} for T_ffi 12 and 45 ({runs.height} + "
        f"{prof.height * len(values) // 4}, its share of the profiling runs): "
        f"{100 * share:.0f} % (target <= 40 %); campaign {secs / 60:.1f} min"
    )
    placed = agreed = n_placed = n_none = 0
    for a in res.boundaries.sort("t_ffi", "scene").iter_rows(named=True):
        v, sc = a["t_ffi"], a["scene"]
        g = grid.filter((pl.col("t_ffi") == v) & (pl.col("scene") == sc)).row(0, named=True)
        used = res.runs.filter((pl.col("t_ffi") == v) & (pl.col("scene") == sc)).height
        text = (
            f"  T_ffi {v:g}, {sc}: adaptive {_interval(a)} ({a['fit_state']}, {used} runs); "
            f"grid fitted {_interval(g)} ({g['fit_state']}, {g['fit_runs']} runs), bracket "
            f"{g['where']}"
        )
        grid_has = g["fit_state"] == "within" or g["where"] == "within"
        if grid_has:  # the grid places a boundary: the adaptive one within one grid step of it
            n_placed += 1
            point = g["boundary_dps"] if g["fit_state"] == "within" else g["bracket_dps"]
            step = g["step_dps"]
            ok = (
                a["fit_state"] == "within"
                and math.isfinite(step)
                and abs(a["boundary_dps"] - point) <= step
            )
            placed += ok
            gap = abs(a["boundary_dps"] - point) if a["fit_state"] == "within" else math.nan
            text += (
                f"; one grid step {step:.1f} deg/s, |adaptive - grid| {gap:.1f}: "
                f"{'within' if ok else 'NOT within'}"
                f"{'' if a['fit_state'] == 'within' else ' (the adaptive design placed none)'}"
            )
        else:  # the grid places none (fails from the least complex point, or never fails)
            n_none += 1
            ok = a["fit_state"] == g["fit_state"]  # below and below, beyond and beyond
            agreed += ok
            text += f"; the grid places none: {'agrees' if ok else 'DISAGREES'}"
        print(text)
    met = placed == n_placed and share <= 0.4
    print(
        f"economy per scene (issue 34: every boundary the grid places found within one grid "
        f"step, <= 40 % of its runs): {placed} of {n_placed} at {100 * share:.0f} % -> "
        f"{'met' if met else 'NOT met'}; scenes where the grid places none: {agreed} of "
        f"{n_none} in the same state"
    )


def _interval(row: dict) -> str:
    return (
        f"{row['boundary_dps']:.1f} [{row['boundary_dps_low']:.1f}, "
        f"{row['boundary_dps_high']:.1f}] deg/s (TF {row['boundary_tf_hz']:.2f} Hz)"
    )


if __name__ == "__main__":
    main()
