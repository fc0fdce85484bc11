"""How often the dataset command's lag interval covers a known delay.

    python benchmarks/bench_lag_interval.py [--repeats 300]

Simulated arm strokes and a camera that sees them late (``analysis.dataset.synthetic.
lag_signals``: 3 % of its frames lost), at several frame rates, episode lengths, noise levels
and delays; each episode's 95 % interval (``analysis.dataset.lag.lag_of``) either holds the
true delay or not. Printed: the coverage with its binomial 95 % interval, the median width, and
the estimate's bias and spread. The same episodes also get the moving-block bootstrap interval
the jackknife replaced (200 resamples of 1.5-s blocks of the aligned frames, percentile),
measured beside it on the first ``--bootstrap`` episodes of each case.
"""

from __future__ import annotations

import argparse
import math

import numpy as np
from scipy.stats import binomtest

from analysis.dataset.lag import lag_of, lag_peaks
from analysis.dataset.synthetic import lag_signals

CASES = [  # (fps, seconds, noise share of the peak speed, delay ms)
    (30.0, 10.0, 0.05, 110), (30.0, 10.0, 0.15, 0), (30.0, 10.0, 0.15, 110),
    (30.0, 10.0, 0.3, 250), (30.0, 3.0, 0.1, 110), (30.0, 5.0, 0.3, 110),
    (15.0, 8.0, 0.1, 110), (60.0, 10.0, 0.3, 33), (30.0, 30.0, 0.15, 110),
]  # fmt: skip


BOOTSTRAP_BLOCK_S = 1.5  # the replaced interval's blocks: one stroke of an arm


def bootstrap_interval(state: np.ndarray, camera: np.ndarray, fps: float, seed: int) -> tuple:
    """The replaced interval, as it was: a percentile moving-block bootstrap of the aligned
    frames (200 resamples of BOOTSTRAP_BLOCK_S blocks), the estimate kept inside."""
    peak, m = lag_peaks(state, camera, fps)
    lag = peak(np.arange(m))[0]
    rng = np.random.default_rng(seed)
    block = min(max(2, round(BOOTSTRAP_BLOCK_S * fps)), m)
    starts = np.arange(0, m - block + 1)
    boots = []
    for _ in range(200):
        pick = rng.choice(starts, size=math.ceil(m / block))
        boots.append(peak((pick[:, None] + np.arange(block)[None, :]).ravel()[:m])[0])
    lo, hi = np.percentile(boots, [2.5, 97.5])
    return min(lo, lag), max(hi, lag)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=300)
    ap.add_argument(
        "--bootstrap",
        type=int,
        default=40,
        help="episodes per case for the replaced bootstrap interval (200 lag_of calls each)",
    )
    args = ap.parse_args()
    print(
        f"{'fps':>4} {'s':>4} {'noise':>5} {'lag ms':>6} | {'jackknife':>24} {'width ms':>8} "
        f"{'bias':>6} {'sd':>5} | {'bootstrap':>9}"
    )
    for fps, seconds, noise, lag_ms in CASES:
        rng = np.random.default_rng(1)
        hit, widths, errs, boot_hit, boot_n = [], [], [], 0, 0
        for rep in range(args.repeats):
            state, camera = lag_signals(rng, fps, seconds, lag_ms / 1000, noise)
            camera[rng.random(len(camera)) < 0.03] = np.nan  # lost frames
            r = lag_of(state, camera, fps)
            if r["lag_ms"] is None:
                continue
            hit.append(r["lag_low_ms"] <= lag_ms <= r["lag_high_ms"])
            widths.append(r["lag_high_ms"] - r["lag_low_ms"])
            errs.append(r["lag_ms"] - lag_ms)
            if rep < args.bootstrap:
                lo, hi = bootstrap_interval(state, camera, fps, rep)
                boot_hit += lo <= lag_ms <= hi
                boot_n += 1
        k, n = int(np.sum(hit)), len(hit)
        ci = binomtest(k, n).proportion_ci()
        print(
            f"{fps:4.0f} {seconds:4.0f} {noise:5.2f} {lag_ms:6d} | {k / n:6.3f} of {n:3d} "
            f"[{ci.low:.3f}, {ci.high:.3f}] {np.median(widths):8.0f} {np.mean(errs):+6.1f} "
            f"{np.std(errs):5.1f} | {boot_hit / max(boot_n, 1):5.2f} of {boot_n}"
        )


if __name__ == "__main__":
    main()
