"""``vdc-analyse profile`` and ``vdc-analyse compare``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl
import pytest
import rerun as rr

from analysis.recordings.reader import Recording
from tests.figures import assert_figure, figure_env, saved_figures
from tests.helpers import assert_one_line_error
from tests.in_process import run_in_process


def entities(path: Path) -> set[str]:
    return {ch.entity_path for ch in rr.chunk.RrdReader(str(path)).store().stream()}


def test_profile_per_recording_segment(recordings, tmp_path: Path) -> None:
    out = tmp_path / "p"
    record = tmp_path / "figures.jsonl"
    proc = run_in_process(
        "analysis",
        "profile",
        str(recordings["phases"]),
        "--out",
        str(out),
        "--threshold",
        "80",
        "--bin-dps",
        "10",
        env=figure_env(record),
    )
    assert proc.returncode == 0, proc.stderr
    summary = pl.read_parquet(out / "profile_summary.parquet")
    assert summary["wall_tf_hz"].to_list() == [0.0, 3.0]  # one profile per TF phase
    pngs = sorted(out.glob("profile_*.png"))
    assert len(pngs) == 2
    figures = saved_figures(record)
    for png in pngs:  # each segment: circles, histogram of responses > 80, arena map
        assert_figure(png, figures, title="responses > 80", labels=("frames", "x (m)"), min_axes=3)
    # every axis says its unit (issue 43): the bars' share and the responses in deg/s
    overview = assert_figure(out / "profiles.png", figures, title="'AVDM > 80' per segment")
    labels = {ax["ylabel"] for ax in overview["axes"]} | {ax["xlabel"] for ax in overview["axes"]}
    assert "% of frames with response > 80 deg/s" in labels, labels
    assert {"response (deg/s)", "density (per deg/s)"} <= labels, labels
    assert (summary["threshold_dps"] == 80).all()
    # the profile's own statistics agree with the tables'
    t = run_in_process(
        "analysis",
        "tables",
        str(recordings["phases"]),
        "--out",
        str(tmp_path / "t"),
        "--threshold",
        "80",
    )
    assert t.returncode == 0
    tab = pl.read_parquet(tmp_path / "t" / "summary.parquet").sort("wall_tf_hz")
    np.testing.assert_allclose(summary["frac_over_threshold"], tab["frac_over_threshold"])
    np.testing.assert_allclose(summary["near_wall_mean"], tab["near_wall_mean"])
    ents = entities(out / "profiles.rrd")
    seg = summary["segment"][1]
    for leaf in ("circles", "histogram", "heatmap", "arena"):
        assert f"/profile/{seg}/{leaf}" in ents
    assert rr.chunk.RrdReader(str(out / "profiles.rrd")).blueprints()
    assert "circles" not in proc.stderr


def test_profile_pools_recordings_by_condition(recordings, tmp_path: Path) -> None:
    out = tmp_path / "c"
    tf3 = [str(recordings["tf3_a"]), str(recordings["tf3_b"])]
    proc = run_in_process("analysis", "profile", *tf3, "--by", "condition", "--out", str(out))
    assert proc.returncode == 0, proc.stderr
    summary = pl.read_parquet(out / "profile_summary.parquet")
    assert summary.height == 1
    row = summary.row(0, named=True)
    assert row["recordings"] == 2 and row["wall_tf_hz"] == 3.0
    assert row["n_frames"] == 2 * (792 - 20)
    # the pooled share as an estimate over the recordings (seeds), from each run's own tables
    shares = []
    for k, rec in enumerate(tf3):
        t = run_in_process("analysis", "tables", rec, "--out", str(tmp_path / f"t{k}"))
        assert t.returncode == 0, t.stderr
        out_k = pl.read_parquet(tmp_path / f"t{k}" / "model_outputs.parquet")
        frames_k = pl.read_parquet(tmp_path / f"t{k}" / "frames.parquet").select("frame")
        # the frames the frames table has (as the profile joins), after the warm-up
        omega = out_k.join(frames_k, on="frame").filter(pl.col("frame") >= 20)["omega_dps"]
        shares.append(float((omega.to_numpy() > row["threshold_dps"]).mean()))
    mean = float(np.mean(shares))
    half = 12.706204736174698 * float(np.std(shares, ddof=1)) / np.sqrt(2)  # t(0.975, 1 df)
    # the same float64 arithmetic on the same frames; 1e-9 allows only the order of a sum
    assert row["frac_over_threshold_by_recording"] == pytest.approx(mean, abs=1e-9)
    assert row["frac_over_threshold_ci_low"] == pytest.approx(max(0.0, mean - half), abs=1e-9)
    assert row["frac_over_threshold_ci_high"] == pytest.approx(min(1.0, mean + half), abs=1e-9)
    assert shares[0] != shares[1]  # two seeds differ: the interval has a width to check


def test_compare_runs_variants_on_identical_frames(recordings, tmp_path: Path) -> None:
    out = tmp_path / "cmp"
    rec = recordings["tf3_a"]
    record = tmp_path / "figures.jsonl"
    models = ["--model", "avdm", "--model", "avdm-on", "--model", "avdm:beta=0.5"]
    proc = run_in_process(
        "analysis", "compare", str(rec), *models, "--out", str(out), env=figure_env(record)
    )
    assert proc.returncode == 0, proc.stderr
    stats = pl.read_parquet(out / "compare_summary.parquet")
    assert stats["model"].to_list() == ["avdm", "avdm-on", "avdm:beta=0.5"]
    assert set(stats.columns) >= {"mean", "p95", "frac_over_threshold", "near_wall_centre_ratio"}
    corr = pl.read_parquet(out / "compare_correlations.parquet")
    assert corr.height == 3 and (corr["pearson"].abs() <= 1).all()
    assert corr.filter(pl.col("model_b") == "avdm-on")["pearson"][0] > 0.9
    assert_figure(
        out / "compare.png",
        saved_figures(record),
        title="the busiest minute",
        labels=("time (s)", "density (per deg/s)", "response (deg/s)"),
        min_axes=3,
    )
    # the variants file opens alongside the source: same recording id, /model_variants/...
    source = Recording(rec)
    (entry,) = rr.chunk.RrdReader(str(out / "variants.rrd")).recordings()
    assert entry.recording_id == source.recording_id and entry.application_id == "vdc"
    ents = entities(out / "variants.rrd")
    assert {
        "/model_variants/avdm/omega_dps",
        "/model_variants/avdm-on/omega_dps",
        "/model_variants/avdm_beta_0.5/omega_dps",
    } <= ents
    variant = Recording(out / "variants.rrd").scalars("/model_variants/avdm/omega_dps")
    logged = source.model_outputs("avdm", ["omega_dps"])
    assert np.array_equal(variant[2][:, 0], logged["omega_dps"])  # identical frames, same floats
    assert f"rerun {rec}" in proc.stdout


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["compare", "REC", "--model", "avdm"], "at least two"),
        (["compare", "REC", "--model", "avdm", "--model", "avdm"], "given twice"),
        (["compare", "REC", "--model", "avdm", "--model", "zzz"], "unknown model"),
        (["profile", "REC", "--cell-m", "3"], "--cell-m"),
        (["profile", "REC", "--by", "moon"], "invalid choice"),
        (["profile", "REC", "--threshold", "-5"], "positive number"),
    ],
)
def test_bad_options_give_one_line(recordings, tmp_path: Path, args, needle) -> None:
    args = [str(recordings["tf3_a"]) if a == "REC" else a for a in args]
    assert_one_line_error(run_in_process("analysis", *args, "--out", str(tmp_path / "o")), needle)


@pytest.mark.parametrize(
    ("model", "output", "unit"),
    [
        ("avdm", "omega_dps", "deg/s"),
        ("avdm-natural", "omega_dps", "deg/s"),
        # decoded as the released code does: the registry calls it relative units, not deg/s
        ("avdm-released-units", "omega_dps", "relative units"),
        ("avdm:a=100,b=1,contrast_term=false", "omega_dps", "relative units"),
        ("lgmd-plus", "spike_rate_hz", "Hz"),
    ],
)
def test_a_profile_axis_names_the_unit_of_its_model(model: str, output: str, unit: str) -> None:
    from analysis.profile import response_unit

    assert response_unit(model, output) == unit
