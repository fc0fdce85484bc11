"""``vdc-analyse boundary`` in the arena and ``vdc-analyse adaptation``: a small grid run on a
real process pool, the boundary and the policy found from it, the policy tested in closed loop
on conditions it was not fitted on, and bad input."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from analysis.boundary.settings import OWN_COLUMNS, BoundarySettings
from analysis.boundary.statistics import find_boundary
from analysis.experiments.collision.adaptation import AdaptationSettings, adaptation
from analysis.experiments.collision.boundary_campaign import boundary
from analysis.recordings.reader import Recording
from avdm.policy import load_policy
from tests.figures import assert_figure, recording_figures
from tests.helpers import assert_one_line_error, flags, write_video
from tests.in_process import run_in_process
from vdc.executors import Feedback

# LGMD+ (arena tuning) at its released T_ffi = 12 is blinded by a 3 Hz drift (it crashes);
# at T_ffi = 30, the paper's adjusted threshold, it is not (tests/capture/test_collision_mode)
GRID = BoundarySettings(
    tf="0,3", scenes="grating", values="12,30", seeds=3, minutes=1.5, jobs=2, no_predictors=True
)  # the predictors: tests/analysis/predictors/test_predictors.py


@pytest.fixture(scope="module")
def grid(tmp_path_factory) -> tuple[Path, object, list[dict]]:
    out = tmp_path_factory.mktemp("boundary")
    with recording_figures() as figures:
        return out, boundary(GRID, out), figures


def test_the_arena_tables_hold_no_column_outside_the_reserved_set(grid) -> None:
    """What the --param check keeps free (OWN_COLUMNS) is every column arena mode writes
    beside the swept parameter: a parameter of any other name cannot collide (footage mode's
    tables: test_inputs_at_the_door.py)."""
    _, res, _ = grid
    written = [p for p in res.paths if p.suffix == ".parquet"]
    assert any(p.name == "boundary_runs.parquet" for p in written)
    for path in written:
        extra = set(pl.read_parquet_schema(path)) - OWN_COLUMNS - {GRID.param}
        assert not extra, (path.name, extra)


def test_the_grid_profiles_each_condition_and_measures_each_run(grid) -> None:
    out, res, figures = grid
    assert res.runs.height == 2 * 2 * 3  # conditions x values x seeds
    assert set(res.runs["condition"]) == {"grating-tf0", "grating-tf3"}
    profiles = pl.read_parquet(out / "boundary_profiles.parquet")
    assert profiles.height == 2 * 3  # one profiling run per condition and seed
    cond = res.conditions.sort("t_ffi", "complexity_dps")
    c = {r["condition"]: r["complexity_dps"] for r in cond.iter_rows(named=True)}
    assert c["grating-tf3"] > c["grating-tf0"] + 5  # the drift is what the AVDM profiles
    for r in cond.iter_rows(named=True):  # every number with its 95 % interval
        assert r["success_low"] <= r["success_rate"] <= r["success_high"]
        assert r["seeds"] == 3
    assert_figure(out / "boundary.png", figures, title="success", labels=("success (%)",))
    assert "## The boundary" in (out / "boundary.md").read_text()


def test_the_boundary_lies_where_the_released_threshold_is_blinded(grid) -> None:
    _, res, _ = grid
    b = {r["t_ffi"]: r for r in res.boundaries.iter_rows(named=True)}
    c = {r["condition"]: r["complexity_dps"] for r in res.conditions.iter_rows(named=True)}
    assert b[12.0]["where"] == "within"  # falls below 90 % at 95 % confidence at TF 3
    assert b[12.0]["boundary_low_dps"] == pytest.approx(c["grating-tf0"])
    assert b[12.0]["boundary_high_dps"] == pytest.approx(c["grating-tf3"])
    assert b[30.0]["where"] == "beyond"  # the adjusted threshold holds over the whole grid


def test_the_policy_is_fitted_from_the_grid_and_written_as_a_table(grid) -> None:
    out, _, _ = grid
    policy = load_policy(out / "policy.csv")
    assert policy.param == "t_ffi"
    assert set(policy.evidence["condition"]) == {"grating-tf0", "grating-tf3"}
    # the most complex condition needs the adjusted threshold: 12 does not keep the target
    assert policy.values[-1] == 30.0
    assert policy.value(1e6) == 30.0


def test_a_rerun_reuses_every_run(grid, tmp_path: Path) -> None:
    out, res, _ = grid
    lines: list[str] = []
    again = boundary(GRID, out, Feedback(log=lines.append))
    assert again.runs["reused"].all()
    # the log says each stage between the plan and the results (a pipe shows no bar)
    stages = [ln.split(":")[0] for ln in lines if ln.startswith("stage ")]
    assert stages == ["stage 1/3", "stage 2/3", "stage 3/3"], lines
    assert (
        lines[0].startswith("boundary of lgmd-plus-arena") and "12 closed-loop run(s)" in lines[1]
    )
    assert again.conditions.equals(res.conditions)


def test_the_policy_is_tested_on_held_out_conditions_running_online(grid) -> None:
    """The policy fitted on TF 0 and 3 keeps the target on TF 2 and on a 0 -> 3 Hz schedule,
    as docs/findings/boundary.md states for its held-out conditions (there 5 seeds of 10 min; here
    2 seeds of 1 min), and where the released threshold is blinded (TF 2) it is better."""
    out, _, _ = grid
    s = AdaptationSettings(
        policy=str(out / "policy.csv"),
        tf="2",
        scenes="grating",
        schedule="0:40s,3:40s",
        seeds=2,
        minutes=1.0,
        jobs=2,
    )
    with recording_figures() as figures:
        res = adaptation(s, out / "held-out")
    assert set(res.runs["controller"]) == {"fixed", "hand", "adaptive", "policy"}
    assert set(res.runs["condition"]) == {"grating-tf2", "grating-schedule"}
    assert res.notices == []  # TF 2 and the schedule were not in the fit
    assert res.comparisons.height == 2 * 3
    assert set(res.comparisons["verdict"]) <= {"better", "worse", "no difference"}
    # the held-out claim: the policy keeps success >= 90 % on every held-out condition...
    policy_rows = res.conditions.filter(pl.col("controller") == "policy")
    assert (policy_rows["success_rate"] >= 0.9).all(), policy_rows
    kept = "the policy keeps success >= 90 % on 2 of 2 held-out"
    assert res.verdict.startswith(kept), res.verdict
    # ...and beats the detector as released where a drift blinds it
    beats = res.comparisons.filter(
        (pl.col("condition") == "grating-tf2") & (pl.col("against") == "fixed")
    )
    assert beats["verdict"].to_list() == ["better"], beats
    # the policy ran on board: the T_ffi it set is logged and follows the policy's rows
    rec = out / "held-out" / "recordings" / "grating-schedule" / "policy" / "seed101.rrd"
    signals = Recording(rec).signals()
    t_ffi = signals["/model/controller/t_ffi"][2][:, 0]
    (set_by,) = [v[2][:, 0] for k, v in signals.items() if k.endswith("/policy_value")]
    np.testing.assert_array_equal(t_ffi, set_by)
    policy = load_policy(out / "policy.csv")
    assert min(policy.values) - 1e-9 <= t_ffi.min() and t_ffi.max() <= max(policy.values) + 1e-9
    assert_figure(
        out / "held-out" / "adaptation.png",
        figures,
        title="held-out conditions",
        labels=("success (%)", "avoidances per 30 min"),
        min_axes=2,
    )


def test_find_boundary_brackets_the_crossing() -> None:
    b = find_boundary([10, 20, 30], [1.0, 0.95, 0.2], [1.0, 1.0, 0.5], 0.9)
    assert b["where"] == "within" and (b["boundary_low_dps"], b["boundary_high_dps"]) == (20, 30)
    assert 20 < b["boundary_dps"] < 30
    assert find_boundary([10, 20], [0.5, 0.4], [0.6, 0.5], 0.9)["where"] == "below"
    beyond = find_boundary([10, 20], [1.0, 0.95], [1.0, 1.0], 0.9)
    assert beyond["where"] == "beyond" and math.isinf(beyond["boundary_high_dps"])


@pytest.mark.parametrize(
    ("args", "needles"),
    [
        (["--detector", "nosuch_pkg.detectors:make"], ["no module named 'nosuch_pkg.detectors'"]),
        (
            ["--detector", "tests.toy_detector:broken", "--labels", "{labels}", "--fov-deg", "60"],
            ["failed to build", "RuntimeError"],
        ),
        (
            [
                *flags(
                    "--detector tests.toy_detector:NoAlert --param gain --values 1 --fov-deg 60",
                    labels="{labels}",
                ),
            ],
            ["has no 'alert' output"],
        ),
        (["--values", "12,abc"], ["--values"]),
        (["--param", "colour"], ["unknown parameter 'colour'"]),
        (["--measure-every", "0"], ["--measure-every: expected an integer >= 1"]),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path: Path, args: list[str], needles) -> None:
    write_video(tmp_path / "clip.mp4", np.full((5, 48, 64), 128, np.uint8), 25.0)
    labels = tmp_path / "labels.csv"
    labels.write_text("clip,label,collision_frame\nclip.mp4,background,\n")
    args = [a.replace("{labels}", str(labels)) for a in args]
    proc = run_in_process("analysis.cli", "boundary", *args, "--out", str(tmp_path / "o"))
    assert_one_line_error(proc, *needles)


def test_a_bad_policy_for_adaptation_is_one_line(tmp_path: Path) -> None:
    bad = tmp_path / "policy.csv"
    bad.write_text("complexity_dps,t_ffi\n1,2\n")
    proc = run_in_process(
        "analysis.cli", "adaptation", "--policy", str(bad), "--out", str(tmp_path)
    )
    assert_one_line_error(proc, "policy.csv", "# param: NAME")
