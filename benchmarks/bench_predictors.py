"""The time the predictors (issue 32) add to ``vdc-analyse boundary`` in the arena: the same
grid is run twice from scratch in this one process, on the same machine state, once with
``--no-predictors`` (the grid's own time) and once with them (every measure of every profiling
run, taken by the worker that recorded it, then the statistics); the difference as a share of
the grid's own time (target: at most 15 % on the default grid, issue 47; issue 32 asked 20 %).
With ``--rounds N`` the two arms alternate (A B, B A, ...) so a change of the machine's load
falls on both; the medians are compared.

    python benchmarks/bench_predictors.py                  # the small grid (~3 min on 2 cores)
    python benchmarks/bench_predictors.py --rounds 2       # interleaved: A B B A
    python benchmarks/bench_predictors.py --default        # the issue's real case (≳ 15 min)
    python benchmarks/bench_predictors.py --existing /tmp/grid --grid-s 420   # a finished grid:
                                          # its predictors measured afterwards, in a second pool

The first use of ``avdm-natural`` at the arena camera's 33 Hz fits its calibration once per
user (cached); the benchmark fits it before timing, as a user's second grid would find it.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

TARGET = 0.15  # issue 47, on the default grid (issue 32 asked 20 %)


def time_grid(s, no_predictors: bool) -> float:
    """Seconds of one ``boundary`` run of ``s`` from scratch (a fresh folder, nothing reused)."""
    import dataclasses

    from analysis.experiments.collision.boundary_campaign import boundary

    folder = Path(tempfile.mkdtemp(prefix="bench-predictors-"))
    try:
        t0 = time.perf_counter()
        boundary(dataclasses.replace(s, no_predictors=no_predictors), folder)
        return time.perf_counter() - t0
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--default", action="store_true", help="the default grid (the issue's case)")
    ap.add_argument("--rounds", type=int, default=1, help="pairs of arms, alternating order")
    ap.add_argument("--existing", default=None, help="a finished grid: time the predictors only")
    ap.add_argument("--grid-s", type=float, default=None, help="with --existing: its time, s")
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()

    from analysis.boundary.settings import BoundarySettings
    from avdm.registry import make_model
    from vdc.recording import camera_model_context

    make_model("avdm-natural", **camera_model_context(99, 72, 33.0, 70.0))  # calibrated once
    if args.existing:
        from analysis.experiments.collision.predictor_runs import predictors_for_folder

        folder = Path(args.existing)
        for cache in folder.glob("recordings/profile/**/*.measures.json"):
            cache.unlink()  # measure every profiling run afresh
        t0 = time.perf_counter()
        res = predictors_for_folder(folder, executor={"jobs": args.jobs})
        pred_s = time.perf_counter() - t0
        print(f"predictors of {folder}, measured afterwards: {pred_s:.1f} s")
        if args.grid_s:
            print(f"grid: {args.grid_s:.1f} s; predictors add {pred_s / args.grid_s:.0%}")
        print(res.top().head(5))
        return
    if args.default:
        s, name = BoundarySettings(jobs=args.jobs), "default grid (the issue's real case)"
    else:
        s = BoundarySettings(
            tf="0,1,3", scenes="grating", values="12,30", seeds=3, minutes=2.0, jobs=args.jobs
        )
        name = "small grid (the quick one; --default for the issue's real case)"
    print(f"{name}: {s.tf=} {s.scenes=} {s.values=} {s.seeds=} {s.minutes=} jobs={s.jobs}")
    without, with_ = [], []
    for r in range(args.rounds):
        for no_pred in (True, False) if r % 2 == 0 else (False, True):
            load = os.getloadavg()[0]
            secs = time_grid(s, no_pred)
            (without if no_pred else with_).append(secs)
            arm = "--no-predictors" if no_pred else "with predictors"
            print(f"  round {r + 1}: {arm:16s} {secs:7.1f} s (load {load:.1f} at start)")
    a, b = statistics.median(without), statistics.median(with_)
    share = (b - a) / a
    verdict = "meets" if share <= TARGET else "misses"
    print(f"grid's own time (--no-predictors): {a:.1f} s; with predictors: {b:.1f} s")
    print(
        f"predictors add {b - a:.1f} s = {share:.0%} of the grid's own time "
        f"(target <= {TARGET:.0%}: {verdict} it)"
    )


if __name__ == "__main__":
    main()
