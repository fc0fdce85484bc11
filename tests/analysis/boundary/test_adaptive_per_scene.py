"""The per-scene adaptive design (``--design adaptive --per-scene``): runs placed on each
scene's own TF axis, a first crossing and a 95 % interval per scene, a row per (value, scene) in
``boundary.parquet``; driven by simulated detectors of known per-scene boundary (no recording:
the design's loop and files with ``run_grid`` replaced)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
import scipy.special

from analysis.boundary.settings import BoundarySettings
from analysis.experiments.collision.adaptive import (
    DesignSettings,
    DesignSpace,
    ProfileMap,
    adaptive_boundary,
    design_runs_per_scene,
    first_failure,
)
from tests.helpers import assert_one_line_error
from tests.in_process import run_in_process
from vdc.executors import QUIET

TARGET = 0.9
# the default grid's measured profile (docs/findings/boundary.md): wall TF (Hz) -> deg/s per scene
PROFILE = {
    "grating": ([0.0, 1.0, 3.0], [6.7, 12.0, 28.5]),
    "natural": ([0.0, 1.0, 3.0], [10.9, 13.0, 18.5]),
}
TRUTH_DPS = {"grating": 10.0, "natural": 16.0}  # each scene its own crossing


def success(scene: str, tf_hz: float, dip: bool = False) -> float:
    """A simulated detector's success on ``scene`` at ``tf_hz``: a logistic fall through 90 %
    at the scene's ``TRUTH_DPS`` (its profile), 0.8 log-odds per deg/s; with ``dip`` the
    grating recovers (95 %) above 2.2 Hz, as LGMD+ at T_ffi 45 does."""
    if dip and scene == "grating" and tf_hz > 2.2:
        return 0.95
    x = float(np.interp(tf_hz, *PROFILE[scene]))
    return float(scipy.special.expit(scipy.special.logit(TARGET) - 0.8 * (x - TRUTH_DPS[scene])))


def simulated(rng: np.random.Generator, placed: list[dict], dip: bool = False) -> list[dict]:
    out = []
    for p in placed:
        n = int(rng.integers(150, 300))  # a 10-min run's approaches (the grid's 100-440)
        k = int(rng.binomial(n, success(p["scene"], p["tf_hz"], dip)))
        out.append(p | {"avoidances": k, "crashes": n - k})
    return out


def test_each_scene_gets_its_own_runs_and_interval_around_its_own_crossing() -> None:
    rng = np.random.default_rng(5)
    profile = ProfileMap({k: (np.array(a), np.array(b)) for k, (a, b) in PROFILE.items()})
    rows, fits = design_runs_per_scene(
        DesignSpace([45.0], ["grating", "natural"], profile, (0.0, 3.0)),
        lambda placed: simulated(rng, placed, dip=True),
        DesignSettings(target=TARGET, budget=16, precision_dps=0.5, batch=2, seed=1),  # 0.5: many
    )
    assert set(fits) == {(45.0, "grating"), (45.0, "natural")}
    assert len(rows) <= 16 and len({r["seed"] for r in rows}) == len(rows)
    for scene, truth in TRUTH_DPS.items():
        mine = [r for r in rows if r["scene"] == scene]
        assert len(mine) >= 3  # the first batch: the range's ends and middle
        # later runs go along this scene's axis, near its own crossing (not the other's)
        later = [r["complexity_dps"] for r in mine if r["batch"] > 0]
        assert later and abs(np.median(later) - truth) < 3.0
        fit = fits[(45.0, scene)]
        # one draw: a 95 % interval misses 1 in 20 (its coverage over 200 repeats:
        # test_boundary_coverage.py); here, that it places this scene's own crossing, the
        # other's being 6 deg/s away: within one width of the interval
        assert fit.state == "within", scene
        assert fit.low - fit.width <= truth <= fit.high + fit.width, (scene, fit.low, fit.high)
    # the two intervals are each scene's own: disjoint (10 and 16 deg/s apart by 6)
    g, n = fits[(45.0, "grating")], fits[(45.0, "natural")]
    assert g.high < n.low
    # the grating recovers above 2.2 Hz; the boundary is still the first crossing, and no run
    # after the first batch went past the first clearly failing one
    assert all(r["tf_hz"] <= 2.2 for r in rows if r["scene"] == "grating" and r["batch"] > 0)


def test_a_scene_failing_from_its_least_complex_point_is_below_and_stops() -> None:
    assert first_failure([5.0, 9.0], [95, 20], [100, 100], TARGET) == 9.0
    assert math.isinf(first_failure([5.0], [100], [100], TARGET))  # all successes: none fails
    profile = ProfileMap({k: (np.array(a), np.array(b)) for k, (a, b) in PROFILE.items()})

    def natural_blind(placed: list[dict]) -> list[dict]:  # the natural wall fails everywhere
        natural, grating = {"avoidances": 30, "crashes": 70}, {"avoidances": 200, "crashes": 2}
        return [p | (natural if p["scene"] == "natural" else grating) for p in placed]

    rows, fits = design_runs_per_scene(
        DesignSpace([12.0], ["grating", "natural"], profile, (0.0, 3.0)),
        natural_blind,
        DesignSettings(target=TARGET, budget=8, precision_dps=2.0, batch=2, seed=1),
    )
    assert fits[(12.0, "natural")].state == "below"
    assert fits[(12.0, "natural")].high == PROFILE["natural"][1][0]
    assert sum(r["scene"] == "natural" for r in rows) == 3  # stopped after its first batch
    assert fits[(12.0, "grating")].state == "beyond"


def fake_run_grid(rng: np.random.Generator):
    """``run_grid`` without recording: profiling rows from ``PROFILE``, closed-loop rows from
    the simulated detector (the columns the statistics read)."""

    def run_grid(items: list, kind: str, *_: Any) -> pl.DataFrame:
        rows = []
        for cols in (it.columns for it in items):
            if kind == "profile":
                dps = float(np.interp(cols["tf_hz"], *PROFILE[cols["scene"]]))
                rows.append(cols | {"profile_dps": dps})
                continue
            (row,) = simulated(rng, [cols])
            rows.append(
                row
                | {
                    "avoidances_per_30min": 3.0 * row["avoidances"],
                    "crashes_per_30min": 3.0 * row["crashes"],
                    "false_alarms_per_30min": 0.0,
                    "dtc_median_m": 0.2,
                }
            )
        return pl.DataFrame(rows)

    return run_grid


def test_the_files_have_a_row_per_value_and_scene(tmp_path: Path) -> None:
    s = BoundarySettings(
        design="adaptive",
        per_scene=True,
        values="12,45",
        budget=10,
        no_fit=True,
        no_predictors=True,
    )
    res = adaptive_boundary(s, tmp_path, fake_run_grid(np.random.default_rng(2)), QUIET)
    bounds = pl.read_parquet(tmp_path / "boundary.parquet")
    assert sorted(zip(bounds["t_ffi"], bounds["scene"], strict=True)) == [
        (12.0, "grating"),
        (12.0, "natural"),
        (45.0, "grating"),
        (45.0, "natural"),
    ]
    runs = pl.read_parquet(tmp_path / "boundary_runs.parquet")
    profiles = pl.read_parquet(tmp_path / "boundary_profiles.parquet")
    assert runs.height <= 20
    for r in bounds.iter_rows(named=True):
        mine = runs.filter((pl.col("t_ffi") == r["t_ffi"]) & (pl.col("scene") == r["scene"]))
        assert r["fit_runs"] <= mine.height and mine.height >= 3
        if r["fit_state"] == "within":  # Hz through this scene's own measured profile
            prof = profiles.filter(pl.col("scene") == r["scene"]).sort("tf_hz")
            expect = np.interp(r["boundary_dps"], prof["profile_dps"], prof["tf_hz"])
            # the inverse map is tabulated on a 4001-point grid over 21 ranges: 0.016 Hz steps
            assert abs(r["boundary_tf_hz"] - expect) < 0.02
    md = (tmp_path / "boundary.md").read_text()
    assert "| t_ffi | scene | state |" in md and "--per-scene" in md
    assert any(line.startswith("- t_ffi = 45, natural: ") for line in md.splitlines())
    assert (tmp_path / "boundary.png").stat().st_size > 10_000
    assert any(", grating: " in line for line in res.report())
    # each scene's boundary is exploratory and says its n: its runs, its interval's unit
    assert "**Exploratory**" in md
    for r in bounds.iter_rows(named=True):
        note = f"(exploratory: this scene's {r['fit_runs']} runs alone)"
        assert any(
            line.startswith(f"- t_ffi = {r['t_ffi']:g}, {r['scene']}: ") and line.endswith(note)
            for line in md.splitlines()
        )
        assert any(f", {r['scene']}: " in line and note in line for line in res.report())
        assert r["unit"] in ("condition", "run") and r["n_units"] >= 1  # one scene: not "scene"
        assert f"| {r['fit_runs']} | {r['n_units']} {r['unit']}" in md


def test_per_scene_without_the_adaptive_design_is_one_line(tmp_path: Path) -> None:
    proc = run_in_process("analysis.cli", "boundary", "--per-scene", "--out", str(tmp_path))
    assert_one_line_error(proc, "--per-scene is for --design adaptive")
