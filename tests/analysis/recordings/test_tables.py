"""``vdc-analyse tables``: the table contract, idempotence, exact recomputation, bad files."""

from __future__ import annotations

import signal
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from analysis.recordings.reader import Recording
from capture.recorder import Recorder
from tests.helpers import assert_one_line_error, start_long_capture
from tests.in_process import run_in_process
from vdc.arena_geometry import distance_to_wall_along
from vdc.parquet_io import read_metadata
from vdc.recording import partial_path

# the frames table's contract, column by column (docs/architecture.md)
FRAMES_COLUMNS = (
    "recording_id frame t_s x_m y_m heading_rad wall_tf_hz wall_gap_m repeat dropped_before "
    "robot_omega_dps turning"
).split()
EVENTS_COLUMNS = ["recording_id", "frame", "t_s", "kind", "x_m", "y_m", "heading_rad", "dtc_m"]
SUMMARY_COLUMNS = [
    "recording_id",
    "model",
    "scene",
    "period_m",
    "seed",
    "source",
    "wall_tf_hz",
    "motion",
    "output",
    "n_frames",
    "mean",
    "p50",
    "p95",
    "max",
    "frac_over_100",
]


def tables(out: Path, *recs: Path, extra: tuple[str, ...] = ()) -> dict[str, pl.DataFrame]:
    proc = run_in_process("analysis", "tables", *map(str, recs), "--out", str(out), *extra)
    assert proc.returncode == 0, proc.stderr
    return {
        n: pl.read_parquet(out / f"{n}.parquet")
        for n in ("frames", "model_outputs", "events", "summary")
    }


def test_tables_follow_the_contract(recordings, tmp_path: Path) -> None:
    t = tables(tmp_path / "t", recordings["phases"], recordings["tf3_a"])
    frames, outputs, events, summary = (
        t[k] for k in ("frames", "model_outputs", "events", "summary")
    )
    assert frames.columns[: len(FRAMES_COLUMNS)] == FRAMES_COLUMNS
    assert events.columns[: len(EVENTS_COLUMNS)] == EVENTS_COLUMNS
    assert summary.columns[: len(SUMMARY_COLUMNS)] == SUMMARY_COLUMNS
    assert outputs.columns[:4] == ["recording_id", "model", "frame", "t_s"]
    assert {"omega_dps", "lambda_px", "motion", "contrast"} <= set(outputs.columns)
    phases = Recording(recordings["phases"])
    ph = frames.filter(pl.col("recording_id") == phases.recording_id)
    assert ph.height == 1320 and ph["frame"].to_list() == list(range(1320))
    assert (ph.filter(pl.col("t_s") < 20)["wall_tf_hz"] == 0).all()
    assert (ph.filter(pl.col("t_s") >= 20)["wall_tf_hz"] == 3).all()
    # one summary row per wall TF phase, statistics recomputable from model_outputs
    rows = summary.filter(pl.col("recording_id") == phases.recording_id)
    assert rows["wall_tf_hz"].to_list() == [0.0, 3.0]
    mo = outputs.filter(pl.col("recording_id") == phases.recording_id).join(
        ph.select("frame", "wall_tf_hz"), on="frame"
    )
    tf3 = mo.filter((pl.col("wall_tf_hz") == 3) & (pl.col("frame") >= 20))["omega_dps"]
    r3 = rows.filter(pl.col("wall_tf_hz") == 3).row(0, named=True)
    assert r3["n_frames"] == tf3.len()
    # numpy's and polars' float64 means sum in different orders: ~1e-15 apart (approx: 1e-6)
    assert r3["mean"] == pytest.approx(tf3.mean())
    assert r3["frac_over_100"] == pytest.approx((tf3 > 100).mean())
    assert r3["scene"] == "grating" and r3["seed"] == 1 and r3["source"] == "simulation"
    # events: ring turns with their distance to collision along the heading
    assert (events["kind"] == "ring_turn").all() and events.height > 0
    hx, hy = 0.7, 0.4
    expected = distance_to_wall_along(
        events["x_m"].to_numpy(), events["y_m"].to_numpy(), events["heading_rad"].to_numpy(), hx, hy
    )
    np.testing.assert_allclose(events["dtc_m"].to_numpy(), expected - 0.021)  # D_ray − radius
    # the ring is 0.04–0.09 m from the walls: turns start before the robot gets close,
    # at up to a few tens of cm along an oblique heading
    assert (events["dtc_m"] > 0.03).all() and (events["dtc_m"] < 0.8).all()
    meta = read_metadata(tmp_path / "t" / "summary.parquet")
    assert meta["params"][phases.recording_id]["avdm"]["fps"] == 33.0
    assert meta["settings"]["threshold_dps"] == 100.0
    assert {"numpy", "rerun-sdk", "polars"} <= set(meta["versions"])


def test_rerunning_writes_identical_tables(recordings, tmp_path: Path) -> None:
    a = tables(tmp_path / "a", recordings["tf3_a"], recordings["phases"])
    b = tables(tmp_path / "b", recordings["phases"], recordings["tf3_a"])  # order does not matter
    for name in a:
        assert a[name].equals(b[name]), name
        assert read_metadata(tmp_path / "a" / f"{name}.parquet") == read_metadata(
            tmp_path / "b" / f"{name}.parquet"
        )


def test_recomputed_online_model_equals_the_logged_outputs(recordings, tmp_path: Path) -> None:
    logged = tables(tmp_path / "logged", recordings["phases"])["model_outputs"]
    recomputed = tables(
        tmp_path / "re", recordings["phases"], extra=("--model", "avdm", "--model", "avdm-on")
    )["model_outputs"]
    again = recomputed.filter(pl.col("model") == "avdm")
    for col in ("omega_dps", "lambda_px", "motion", "contrast", "rbar_on", "rbar_off"):
        assert np.array_equal(again[col].to_numpy(), logged[col].to_numpy()), col
    assert set(recomputed["model"]) == {"avdm", "avdm-on"}


def test_a_capture_killed_with_sigkill_is_analysed(tmp_path: Path) -> None:
    out = tmp_path / "killed.rrd"
    proc = start_long_capture(out, min_bytes=3_000_000)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    assert not out.exists()  # a killed capture never takes the final name...
    out = partial_path(out)  # ...its frames are in the partial file, readable as it is
    res = run_in_process("analysis", "tables", str(out), "--out", str(tmp_path / "t"))
    assert res.returncode == 0, res.stderr
    assert "note:" in res.stderr and ("no footer" in res.stderr or "truncated" in res.stderr)
    frames = pl.read_parquet(tmp_path / "t" / "frames.parquet")
    assert frames.height > 1000
    assert frames["frame"].to_list() == list(range(frames.height))  # no gap before the cut
    res = run_in_process(
        "analysis", "tables", str(out), "--model", "avdm", "--out", str(tmp_path / "r")
    )
    assert res.returncode == 0, res.stderr


def test_a_truncated_copy_keeps_its_complete_part(recordings, tmp_path: Path) -> None:
    data = recordings["phases"].read_bytes()  # two capture batches: 1000 + 320 frames
    cut = tmp_path / "cut.rrd"
    cut.write_bytes(data[: len(data) * 3 // 4])  # inside the second batch
    # small chunks (logged outputs) may lie after the cut: recompute from the frames that survive
    res = run_in_process(
        "analysis", "tables", str(cut), "--model", "avdm", "--out", str(tmp_path / "t")
    )
    assert res.returncode == 0, res.stderr
    assert "truncated" in res.stderr
    outputs = pl.read_parquet(tmp_path / "t" / "model_outputs.parquet")
    assert outputs.height >= 1000
    assert outputs["frame"].to_list() == list(range(outputs.height))


def test_bad_files_give_one_line_and_exit_2(recordings, tmp_path: Path) -> None:
    random_bytes = tmp_path / "random.rrd"
    random_bytes.write_bytes(np.random.default_rng(0).bytes(5000))
    tiny = tmp_path / "tiny.rrd"
    tiny.write_bytes(recordings["tf3_a"].read_bytes()[:10])
    text = tmp_path / "notes.txt"
    text.write_text("hello")
    empty = tmp_path / "empty.rrd"
    empty.write_bytes(b"")
    empty_dir = tmp_path / "nothing_here"
    empty_dir.mkdir()
    no_frames = tmp_path / "no_frames.rrd"
    rec = Recorder(no_frames, "no-frames")
    rec.send_properties(  # what analysis needs besides the frames: nothing is assumed
        {
            "arena": {"length_m": 1.4, "width_m": 0.8},
            "camera": {"fps": 33.0, "width_px": 99, "height_px": 72, "hfov_deg": 70.0},
        }
    )
    rec.log_poses(np.arange(5), np.arange(5) / 33, np.zeros((5, 3)))
    rec.close(frames=5, stop_reason="finished", complete=True)
    cases = [
        (random_bytes, ("not a Rerun recording",)),
        (tiny, ("damaged",)),
        (text, ("not a Rerun recording",)),
        (empty, ("is empty",)),
        (empty_dir, ("no .rrd recordings",)),  # a folder is searched (vdc.folders)
        (tmp_path / "missing.rrd", ("no such file or folder",)),
    ]
    for path, needles in cases:
        assert_one_line_error(
            run_in_process("analysis", "tables", str(path), "--out", str(tmp_path / "o")), *needles
        )
    # a recording without camera frames: fine for logged tables, refused for recomputation
    assert_one_line_error(
        run_in_process("analysis", "tables", str(no_frames), "--out", str(tmp_path / "o")),
        "no logged model outputs",
        "--model",
    )
    assert_one_line_error(
        run_in_process(
            "analysis", "tables", str(no_frames), "--model", "avdm", "--out", str(tmp_path / "o")
        ),
        "holds no camera frames",
    )
    assert_one_line_error(
        run_in_process(
            "analysis",
            "tables",
            str(recordings["tf3_a"]),
            "--model",
            "nope",
            "--out",
            str(tmp_path / "o"),
        ),
        "unknown model",
    )
    assert not (tmp_path / "o").exists()


def test_outputs_cut_unevenly_by_a_crash_keep_every_frame_they_reached(tmp_path: Path) -> None:
    """A capture killed mid-write can leave one output of the last frames logged and another
    not; the frames table and the logged outputs keep every frame (missing values null)."""
    from analysis.recordings.loading import load_recording

    path = tmp_path / "uneven.rrd"
    rec = Recorder(path, "uneven")
    rec.send_properties({"model": {"name": "avdm"}, "arena": {"length_m": 1.4, "width_m": 0.8}})
    f = np.arange(12)
    rec.log_poses(f, f / 33, np.zeros((12, 3)))
    rec.log_model_outputs(
        "avdm", f[:10], f[:10] / 33, {"omega_dps": np.ones(10), "motion": np.ones(10)}
    )
    rec.log_model_outputs("avdm", f[10:], f[10:] / 33, {"omega_dps": np.full(2, 2.0)})
    rec.close(frames=12, stop_reason="finished", complete=True)
    logged = load_recording(path).logged["avdm"]
    assert logged["frame"].to_list() == list(range(12))
    assert logged["omega_dps"].to_list() == [1.0] * 10 + [2.0, 2.0]
    assert logged["motion"].null_count() == 2


def test_every_model_a_collision_run_logged_is_in_model_outputs(tmp_path: Path) -> None:
    """The detector and its controller, logged online on every frame, land in the tables
    without --model, one ``model`` each, equal to what the recording holds."""
    rec = tmp_path / "col.rrd"
    proc = run_in_process(
        "capture",
        "sim",
        "--behaviour",
        "collision",
        "--minutes",
        "0.05",
        "--model",
        "lgmd-plus-arena",
        "--out",
        str(rec),
        "--quiet",
    )
    assert proc.returncode == 0, proc.stderr
    proc = run_in_process("analysis", "tables", str(rec), "--out", str(tmp_path / "t"))
    assert proc.returncode == 0, proc.stderr
    mo = pl.read_parquet(tmp_path / "t" / "model_outputs.parquet")
    models = set(mo["model"].unique())
    assert {"avdm", "lgmd-plus-arena", "controller"} <= models, models
    lgmd = mo.filter(pl.col("model") == "lgmd-plus-arena")
    logged = Recording(rec).model_outputs("lgmd-plus-arena", ["alert"])
    np.testing.assert_array_equal(lgmd.sort("frame")["alert"].to_numpy(), logged["alert"])
    meta = read_metadata(tmp_path / "t" / "model_outputs.parquet")
    assert "lgmd-plus-arena" in next(iter(meta["params"].values()))


def test_frames_the_tracker_missed_keep_their_rows() -> None:
    """A real robot's overhead tracker may miss frames (its first ones on a busy host): the
    frames table, which every table joins on, keeps them with null poses. Built from poses
    alone it dropped them, and `tables --model` lost their recomputed outputs (CI, load 10)."""
    import numpy as np

    from analysis.recordings.loading import from_signals
    from vdc.recording import POSE, model_path

    frame = np.arange(10)
    t_s = frame / 33.0
    posed = np.array([2, 3, 5, 6, 7, 8, 9])  # frames 0, 1 and 4 met no overhead image
    pose = np.column_stack([posed * 0.01, np.zeros(len(posed)), np.zeros(len(posed))])
    sig = {
        POSE: (posed, t_s[posed], pose),
        model_path("avdm", "omega_dps"): (frame, t_s, np.ones((10, 1))),
    }
    props = {"model": {"name": "avdm"}, "arena": {"length_m": 1.0, "width_m": 1.0}}
    frames, logged, _ = from_signals(sig, props, "rid")
    assert frames["frame"].to_list() == list(range(10))
    assert frames["t_s"].to_list() == t_s.tolist()
    assert frames["x_m"].is_null().to_list() == [k not in posed for k in range(10)]
    assert frames.filter(pl.col("frame") == 5)["x_m"].item() == 0.05
    assert logged["avdm"].height == 10
