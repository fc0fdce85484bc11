"""The time the predictors (issue 32) add to ``vdc-analyse boundary`` in the arena: the grid is
run with ``--no-predictors`` and timed, then its predictors are computed from its recordings
(every measure of every profiling run, then the statistics) and timed; the second time as a
share of the first (target: at most 20 %).

    python benchmarks/bench_predictors.py                       # a small grid (~2 min on 2 cores)
    python benchmarks/bench_predictors.py --default --out /tmp/grid   # the default grid (≳ 7 min)
    python benchmarks/bench_predictors.py --existing /tmp/grid  # a finished grid: predictors only

With ``--existing`` the grid's own time is not measured here: give it with ``--grid-s``.
The first use of ``avdm-natural`` at the arena camera's 33 Hz fits its calibration once per
user (cached); the benchmark fits it before timing, as a user's second grid would find it.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=None, help="grid folder (default: a temporary one)")
    ap.add_argument("--default", action="store_true", help="the default grid (150 runs)")
    ap.add_argument("--existing", default=None, help="a finished grid: time the predictors only")
    ap.add_argument("--grid-s", type=float, default=None, help="with --existing: its time, s")
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()

    import dataclasses

    from analysis.boundary import BoundarySettings
    from analysis.experiments.boundary_campaign import boundary
    from analysis.experiments.predictor_runs import predictors_for_folder
    from avdm.registry import make_model
    from vdc.recording import camera_model_context

    make_model("avdm-natural", **camera_model_context(99, 72, 33.0, 70.0))  # calibrated once
    tmp = None
    if args.existing:
        folder = Path(args.existing)
        grid_s = args.grid_s
    else:
        folder = Path(args.out or (tmp := tempfile.mkdtemp(prefix="bench-predictors-")))
        s = (
            BoundarySettings(jobs=args.jobs)
            if args.default
            else BoundarySettings(
                tf="0,1,3", scenes="grating", values="12,30", seeds=3, minutes=2.0, jobs=args.jobs
            )
        )
        s = dataclasses.replace(s, no_predictors=True)
        t0 = time.perf_counter()
        boundary(s, folder)
        grid_s = time.perf_counter() - t0
    for cache in folder.glob("recordings/profile/**/*.measures.json"):
        cache.unlink()  # measure every profiling run afresh
    t0 = time.perf_counter()
    res = predictors_for_folder(folder, executor={"jobs": args.jobs})
    pred_s = time.perf_counter() - t0
    runs = res.measures.height
    print(f"profiling runs measured: {runs}, every {int(res.measures['every'][0])}th frame pair")
    print(f"predictors: {pred_s:.1f} s ({pred_s / max(runs, 1):.1f} s per profiling run)")
    if grid_s:
        print(
            f"grid: {grid_s:.1f} s; predictors add {100 * pred_s / grid_s:.0f} % (target <= 20 %)"
        )
    print(res.top().head(5))
    if tmp:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
