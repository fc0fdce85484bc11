"""``vdc-analyse collision`` and ``collision-study``."""

from __future__ import annotations

from pathlib import Path

import polars as pl

from tests.helpers import assert_one_line_error, run_cli


def test_collision_study_end_to_end_and_reuse(tmp_path: Path) -> None:
    out = tmp_path / "study"
    proc = run_cli(
        "analysis", "collision-study", "--minutes", "0.5", "--out", str(out), "--jobs", "2"
    )
    assert proc.returncode == 0, proc.stderr
    summary = pl.read_parquet(out / "collision_summary.parquet")
    assert summary["phase"].to_list() == [
        "tf0",
        "tf3",
        "tf3-adjusted",
        "tf3-adaptive",
        "tf0-adaptive",
    ]
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
    paper = summary.filter(pl.col("phase") == "tf3")["paper_avoidances"].item()
    assert paper == 432
    assert (
        summary.filter(pl.col("phase") == "tf3-adjusted")["detector"].item().endswith("t_ffi=30.0")
    )
    md = (out / "collision_study.md").read_text()
    assert "| tf0 |" in md and "229" in md
    for name in ("collision_study.png", "collision_tf0.png", "collision.rrd"):
        assert (out / name).exists(), name
    again = run_cli("analysis", "collision-study", "--minutes", "0.5", "--out", str(out))
    assert again.returncode == 0, again.stderr
    assert again.stderr.count("reusing") == 5
    assert pl.read_parquet(out / "collision_summary.parquet").equals(summary)


def test_collision_refuses_a_profile_recording(recordings, tmp_path: Path) -> None:
    proc = run_cli("analysis", "collision", str(recordings["tf3_a"]), "--out", str(tmp_path))
    assert_one_line_error(proc, "not a collision-mode recording")


def test_collision_study_bad_detector(tmp_path: Path) -> None:
    proc = run_cli("analysis", "collision-study", "--detector", "nope", "--out", str(tmp_path))
    assert_one_line_error(proc, "unknown model")
    proc = run_cli("analysis", "collision-study", "--adjusted", "t_ffi=x", "--out", str(tmp_path))
    assert_one_line_error(proc, "expected a number")
