"""The boundary campaign's grid on the executors: the issue's 30-minute target on 2 cores.

Run: ``python benchmarks/bench_boundary.py [--jobs 2] [--minutes 10] [--seeds 5]
[--executor local|dask] [--out DIR]``. Runs ``vdc-analyse boundary``'s default grid (wall TF
0, 1, 3 Hz x grating and natural walls x LGMD+ T_ffi 12, 20, 30, 45 x 5 seeds of 10-min
closed-loop runs, plus the 30 profiling runs that give each condition its complexity) from
scratch, then again (every run reused: the resume path), and prints the wall-clock times and
the recorded minutes per wall-clock minute. The plain reference measured in the same run: one
of the grid's runs recorded alone in this process (the cost of one run without the executor),
times the number of runs divided by the workers: the ideal the campaign is held against.

``--scaling`` instead runs a smaller grid (``--minutes 2 --seeds 2`` unless given) from scratch
on the local pool and on a local Dask cluster (127.0.0.1) with 1 and 2 workers and prints the
times and speed-ups: how the campaign scales on a cluster.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from analysis.boundary import BoundarySettings
from analysis.experiments.boundary import boundary, grid_items
from capture.sim import record_sim


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jobs", type=int, default=2, help="workers (default: %(default)s)")
    ap.add_argument("--minutes", type=float, default=10.0, help="run length (default: %(default)s)")
    ap.add_argument("--seeds", type=int, default=5, help="seeds (default: %(default)s)")
    ap.add_argument("--executor", default="local", choices=("local", "dask"))
    ap.add_argument("--out", default=None, help="keep the campaign here (default: a temp folder)")
    ap.add_argument("--scaling", action="store_true", help="local and Dask, 1 and 2 workers")
    args = ap.parse_args()
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
        record_sim(one, path, force=True)
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


if __name__ == "__main__":
    main()
