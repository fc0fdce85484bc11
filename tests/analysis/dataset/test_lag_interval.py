"""The dataset command's lag interval covers a known delay about 95 % of the time (issue 46:
"the lag interval's coverage"): simulated arm strokes seen by a camera a known time late
(``analysis.dataset.synthetic.lag_signals``), with lost frames, on a long and on the shortest
measurable episode. ``benchmarks/bench_lag_interval.py`` measures more cases, beside the
moving-block bootstrap this interval replaced (57-92 % there)."""

from __future__ import annotations

import numpy as np
import pytest

from analysis.dataset.lag import LAG_SEARCH_S, lag_of
from analysis.dataset.synthetic import lag_signals

EPISODES = 200


@pytest.mark.parametrize(("seconds", "lag_ms"), [(10.0, 110), (3.0, 33)])
def test_the_lag_interval_covers_a_known_delay(seconds: float, lag_ms: int) -> None:
    rng = np.random.default_rng(11)
    held, measured = 0, 0
    for _ in range(EPISODES):
        state, camera = lag_signals(rng, 30.0, seconds, lag_ms / 1000, noise=0.15)
        camera[rng.random(len(camera)) < 0.03] = np.nan  # lost frames
        r = lag_of(state, camera, 30.0)
        if r["lag_ms"] is None:
            continue
        measured += 1
        assert -LAG_SEARCH_S * 1000 <= r["lag_low_ms"] <= r["lag_ms"] <= r["lag_high_ms"]
        assert r["lag_high_ms"] <= LAG_SEARCH_S * 1000
        held += r["lag_low_ms"] <= lag_ms <= r["lag_high_ms"]
    assert measured >= 0.95 * EPISODES  # strokes this clear are measurable
    # 95 % nominal; with 200 episodes the binomial sd is 1.5 points, so 0.90-0.99 is over
    # three of them either side (measured: 0.94 and 0.96; the bootstrap it replaced: 0.83, 0.57)
    assert 0.90 <= held / measured <= 0.99, held / measured
