"""How often the held-out balanced accuracy's interval covers a known truth.

    python benchmarks/bench_loco_interval.py [--repeats 300] [--boot 500]

Conditions drawn from a known population (``analysis.predictors.synthetic``: a measure
x ~ N(0, 1), failure with probability logistic(-1 + beta x)), from beta = 0 (a measure unrelated
to failure) to beta = 30 (the classes all but separate), on 12, 24 and 48 conditions; the truth
is the balanced accuracy on new conditions of a threshold fitted on N - 1 of them
(``loco_truth``). Each draw gets vdc's interval (``loco_interval``: the union of a bootstrap
over conditions, each held out with all its copies, and a Beta posterior of the held-out counts)
and, beside it, the plain reference: that Beta posterior alone (Jeffreys prior; Brodersen et al.
2010), which ignores that the held-out predictions share their thresholds. Printed: coverage
with its binomial 95 % interval, and the mean width.
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.stats import binomtest

from analysis.predictors.held_out import loco_interval, loco_threshold, posterior_interval
from analysis.predictors.synthetic import conditions, loco_truth

ALPHA_LOGIT = -1.0  # about a third of the conditions fail at beta = 0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=300, help="draws per case")
    ap.add_argument("--boot", type=int, default=500, help="resamples per interval")
    args = ap.parse_args()
    rng = np.random.default_rng(20261127)
    print("  N  beta  truth  draws   vdc coverage [95 %]   width   Beta posterior [95 %]   width")
    for n in (12, 24, 48):
        for beta in (0.0, 1.0, 3.0, 30.0):
            truth = loco_truth(n, beta, ALPHA_LOGIT, rng)
            hits = {"vdc": 0, "beta": 0}
            width = {"vdc": [], "beta": []}
            k = 0
            while k < args.repeats:
                x, fails = conditions(n, beta, ALPHA_LOGIT, rng)
                if min(fails.sum(), (~fails).sum()) < 2:  # refused, as in the report
                    continue
                k += 1
                assert np.isfinite(loco_threshold(x, fails))
                for name, (lo, hi) in (
                    ("vdc", loco_interval(x, fails, rng, args.boot)),
                    ("beta", posterior_interval(x, fails, rng)),
                ):
                    hits[name] += lo <= truth <= hi
                    width[name].append(hi - lo)
            cells = []
            for name in ("vdc", "beta"):
                ci = binomtest(hits[name], k).proportion_ci()
                share, mean_width = hits[name] / k, np.mean(width[name])
                cells.append(f"{share:6.1%} [{ci.low:.1%}, {ci.high:.1%}]  {mean_width:.2f}")
            row = f"{n:3d} {beta:5.1f}  {truth:.3f}  {k:5d}   {cells[0]}     {cells[1]}"
            print(row, flush=True)


if __name__ == "__main__":
    main()
