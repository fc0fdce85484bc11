"""The fitted boundary's 95 % interval against psignifit 4's on the same data (issues 42, 57).

psignifit (Schuett et al. 2016; ``pip install psignifit``, not a vdc dependency) is the
reference for a psychometric threshold with beta-binomial overdispersion: one eta per fit,
each block's variance n psi (1 - psi) [1 + (n - 1) eta^2], a credible interval with the
nuisance parameters integrated out. It is given the same counts twice: one block per run
(its default reading of such data) and one block per condition (the pooled seeds). vdc's fit
(:func:`analysis.boundary.fit.fit_crossing`) takes the runs with their conditions and scenes.
Designs and truths as in ``tests/analysis/boundary/test_boundary_coverage.py`` (the default
grid of 2 scenes x 3 TFs x 5 seeds, each scene its own profile): no extra variation, a per-run
effect (sd 0.4 on the log-odds), a per-condition effect (sd 0.5) and a scene effect (sd 0.5); the
truth an interval must cover is the population's boundary (the success averaged over the
effects crosses 90 %); the coverage of the median scene's (16 deg/s) is printed beside it.

psignifit is fitted to the failure rate (rising), a logistic with guess and lapse rates fixed
at 0 (the truth has no floor) and ``thresh_PC`` 0.1: its threshold is then vdc's boundary.

    python benchmarks/bench_boundary_psignifit.py --repeats 200 [--truths none,per-run]

prints, per truth and method, the coverage among bounded intervals, how many were bounded,
the median width and the seconds per fit.
"""

from __future__ import annotations

import argparse
import math
import time
import warnings

import numpy as np

from analysis.boundary.fit import fit_crossing
from tests.analysis.boundary.test_boundary_coverage import (
    DOMAIN,
    TARGET,
    TRUTH,
    campaign,
    population_boundary,
)

TRUTHS = {
    "none": {},
    "per-run": {"run_sd": 0.4},
    "per-condition": {"condition_sd": 0.5},
    "scene": {"scene_sd": 0.5},
}


def psignifit_interval(x: np.ndarray, k: np.ndarray, n: np.ndarray) -> tuple[float, float]:
    import psignifit

    data = np.column_stack([x, n - k, n]).astype(float)  # failures: the curve rises
    with warnings.catch_warnings():  # thresh_PC != 0.5: a note on its default prior
        warnings.simplefilter("ignore", UserWarning)
        res = psignifit.psignifit(
            data,
            sigmoid="logistic",
            experiment_type="yes/no",
            fixed_parameters={"lambda": 0.0, "gamma": 0.0},
            thresh_PC=1 - TARGET,
            verbose=False,
        )
    lo, hi = res.confidence_intervals["threshold"]["0.95"]
    return float(lo), float(hi)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=200)
    ap.add_argument(
        "--truths", default=",".join(TRUTHS), help="comma-separated, of " + ", ".join(TRUTHS)
    )
    ap.add_argument(
        "--blocks",
        default="run,condition",
        help="psignifit's readings, comma-separated: run (a block per run, its slowest: 1-2 s "
        "per fit), condition (a block per condition)",
    )
    args = ap.parse_args()
    for truth in args.truths.split(","):
        effects = TRUTHS[truth]
        population = population_boundary(math.hypot(*effects.values()))
        rng = np.random.default_rng(7)
        got: dict[str, list[tuple[float, float, float]]] = {
            "vdc fit_crossing": [],
            "psignifit, a block per run": [],
            "psignifit, a block per condition": [],
        }
        for _ in range(args.repeats):
            x, k, n, condition, scene = campaign(rng, **effects)
            t = time.perf_counter()
            f = fit_crossing(x, k, n, TARGET, DOMAIN, condition, scene=scene, band=False)
            got["vdc fit_crossing"].append((f.low, f.high, time.perf_counter() - t))
            t = time.perf_counter()
            if "run" in args.blocks.split(","):
                got["psignifit, a block per run"].append(
                    (*psignifit_interval(x, k, n), time.perf_counter() - t)
                )
            xc = np.unique(x)
            kc = np.array([k[x == c].sum() for c in xc])
            nc = np.array([n[x == c].sum() for c in xc])
            t = time.perf_counter()
            if "condition" not in args.blocks.split(","):
                continue
            got["psignifit, a block per condition"].append(
                (*psignifit_interval(xc, kc, nc), time.perf_counter() - t)
            )
        for name, rows in got.items():
            if not rows:
                continue
            a = np.array(rows)
            ok = np.isfinite(a[:, 0]) & np.isfinite(a[:, 1])
            cover = np.mean((a[ok, 0] <= population) & (population <= a[ok, 1]))
            median = np.mean((a[ok, 0] <= TRUTH) & (TRUTH <= a[ok, 1]))
            print(
                f"{truth:14s} {name:34s} coverage {cover:.3f} of {ok.sum()} bounded "
                f"(median scene's {median:.3f}), median width "
                f"{np.median(a[ok, 1] - a[ok, 0]):.2f} deg/s, {np.median(a[:, 2]):.2f} s per fit",
                flush=True,
            )


if __name__ == "__main__":
    main()
