"""``vdc-analyse collision`` and ``collision-study``."""

from __future__ import annotations

from pathlib import Path

import polars as pl

from tests.figures import assert_figure, figure_env, saved_figures
from tests.helpers import assert_one_line_error
from tests.in_process import run_in_process


def test_collision_study_end_to_end_and_reuse(tmp_path: Path) -> None:
    out = tmp_path / "study"
    args = ("--minutes", "0.4", "--out", str(out), "--jobs", "2", "--seeds", "2")
    record = tmp_path / "figures.jsonl"
    proc = run_in_process("analysis", "collision-study", *args, env=figure_env(record))
    assert proc.returncode == 0, proc.stderr
    summary = pl.read_parquet(out / "collision_summary.parquet")
    phases = ["tf0", "tf3", "tf3-adjusted", "tf3-adaptive", "tf0-adaptive"]
    assert summary["phase"].to_list() == [p for p in phases for _ in (1, 2)]
    assert summary["seed"].to_list() == [1, 2] * 5
    events = pl.read_parquet(out / "collision_events.parquet")
    for r in summary.iter_rows(named=True):
        ev = events.filter(pl.col("recording_id") == r["recording_id"])
        a = ev.filter(pl.col("kind") == "avoidance").height
        c = ev.filter(pl.col("kind") == "crash").height
        assert (r["avoidances"], r["crashes"]) == (a, c)
        if a + c:
            assert r["success_rate"] == a / (a + c)
        far = ev.filter((pl.col("kind") == "avoidance") & (pl.col("dtc_m") >= 0.30)).height
        assert r["false_alarms"] == far
    assert (summary.filter(pl.col("phase") == "tf3")["paper_avoidances"] == 432).all()
    adjusted = summary.filter(pl.col("phase") == "tf3-adjusted")["detector"]
    assert adjusted.str.ends_with("t_ffi=30.0").all()
    # ego-motion: avoidances triggered while the robot was still turning are counted
    frames_turning = summary["turning_share"]
    assert ((frames_turning > 0) & (frames_turning < 1)).all()
    assert (summary["avoidances_while_turning"] <= summary["avoidances"]).all()
    # across seeds: the mean and its interval per phase
    stats = pl.read_parquet(out / "collision_phases.parquet")
    assert stats["phase"].to_list() == phases and (stats["seeds"] == 2).all()
    tf0 = summary.filter(pl.col("phase") == "tf0")
    row = stats.row(0, named=True)
    assert row["avoidances_per_30min"] == tf0["avoidances_per_30min"].mean()
    assert row["avoidances_per_30min_low"] <= row["avoidances_per_30min"]
    assert 0.0 <= row["success_rate_low"] <= row["success_rate_high"] <= 1.0
    md = (out / "collision_study.md").read_text()
    assert "| tf0 |" in md and "229" in md and "| tf0 | 1 |" in md  # per phase, then per run
    assert (out / "collision.rrd").exists()
    figures = saved_figures(record)
    assert_figure(
        out / "collision_study.png", figures, title="events per phase", labels=("success rate (%)",)
    )
    # one run: three arena maps (with their colour bars) under the run's numbers
    assert_figure(
        out / "collision_tf0_seed1.png", figures, title="tf0: ", labels=("x (m)",), min_axes=3
    )
    again = run_in_process("analysis", "collision-study", *args)
    assert again.returncode == 0, again.stderr
    assert again.stderr.count("reusing") == 10
    assert pl.read_parquet(out / "collision_summary.parquet").equals(summary)


def test_collision_refuses_a_profile_recording(recordings, tmp_path: Path) -> None:
    proc = run_in_process("analysis", "collision", str(recordings["tf3_a"]), "--out", str(tmp_path))
    assert_one_line_error(proc, "not a collision-mode recording")


def test_collision_study_bad_detector(tmp_path: Path) -> None:
    proc = run_in_process(
        "analysis", "collision-study", "--detector", "nope", "--out", str(tmp_path)
    )
    assert_one_line_error(proc, "unknown model")
    proc = run_in_process(
        "analysis", "collision-study", "--adjusted", "t_ffi=x", "--out", str(tmp_path)
    )
    assert_one_line_error(proc, "expected a number")
