"""``vdc-capture campaign``: grid specs, one recording and one row per run, resume, failures."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import polars as pl
import pytest
from hypothesis import given
from hypothesis import strategies as st

from analysis.recordings.reader import Recording
from capture.campaign import CampaignSettings, parse_grid
from capture.sim import SimSettings
from tests.helpers import assert_one_line_error
from tests.in_process import run_in_process


def test_grid_items_take_the_sim_settings_types() -> None:
    grid = parse_grid(
        ["tf-hz=0,1.5", "seed=2..4", "behaviour=collision", "adaptive=yes,no", "threshold=none"]
    )
    assert grid == {
        "tf_hz": [0.0, 1.5],
        "seed": [2, 3, 4],
        "behaviour": ["collision"],
        "adaptive": [True, False],
        "threshold": [None],
    }
    # a TF schedule holds commas itself: schedules are separated by ';'
    assert parse_grid(["tf_schedule=0:10s,3:10s;3:20s"]) == {
        "tf_schedule": ["0:10s,3:10s", "3:20s"]
    }


def test_model_specs_keep_their_overrides_in_a_grid() -> None:
    grid = parse_grid(["model=avdm:beta=0.5,tw=6,avdm-on;avdm:tw=3", "profile_model=avdm"])
    assert grid["model"] == ["avdm:beta=0.5,tw=6", "avdm-on", "avdm:tw=3"]
    keys = [key for key, _, _ in CampaignSettings(grid=("model=avdm:beta=0.5,tw=6,avdm",)).runs()]
    assert len(keys) == 2 and not any(k.startswith("modeltw") for k in keys)


@given(
    tfs=st.lists(st.sampled_from([0.0, 0.5, 1.0, 3.0]), min_size=1, max_size=3, unique=True),
    seeds=st.lists(st.integers(0, 50), min_size=1, max_size=3, unique=True),
)
def test_runs_are_the_product_of_the_varied_items_with_distinct_keys(tfs, seeds) -> None:
    items = [f"tf_hz={','.join(map(str, tfs))}", f"seed={','.join(map(str, seeds))}", "minutes=1"]
    runs = CampaignSettings(grid=tuple(items), jobs=1).runs()
    assert len(runs) == len(tfs) * len(seeds)
    assert len({key for key, _, _ in runs}) == len(runs)
    pairs = {(s.tf_hz, s.seed) for _, _, s in runs}
    assert pairs == {(tf, seed) for tf in tfs for seed in seeds}
    for _key, values, settings in runs:
        assert settings == SimSettings(minutes=1.0, tf_hz=settings.tf_hz, seed=settings.seed)
        # only what varies names the run
        assert set(values) == {k for k, v in (("tf_hz", tfs), ("seed", seeds)) if len(v) > 1}


def _sweep(out: Path, *args: str) -> object:
    return run_in_process("capture", "campaign", *args, "--out", str(out), "--quiet", "--jobs", "2")


def test_a_collision_grid_records_every_run_once_and_resumes(tmp_path: Path) -> None:
    grid = ("behaviour=collision", "minutes=0.1", "threshold=20,60", "tf_hz=0,3")
    out = tmp_path / "campaign"
    proc = _sweep(out, *grid)
    assert proc.returncode == 0, proc.stderr
    assert "4 runs: 0 already done, 4 recorded, 0 failed" in proc.stdout
    runs = pl.read_parquet(out / "runs.parquet")
    assert runs.height == 4 and runs["complete"].all()
    assert set(zip(runs["threshold"], runs["tf_hz"], strict=True)) == {
        (20.0, 0.0),
        (20.0, 3.0),
        (60.0, 0.0),
        (60.0, 3.0),
    }
    # the settings every run shares are columns too: each row rebuilds its run's settings
    assert (runs["behaviour"] == "collision").all() and (runs["minutes"] == 0.1).all()
    assert (runs["scene"] == SimSettings().scene).all()  # a default nobody gave, stated
    for row in runs.iter_rows(named=True):
        settings = SimSettings(
            behaviour="collision", minutes=0.1, threshold=row["threshold"], tf_hz=row["tf_hz"]
        )
        fields = {f.name for f in dataclasses.fields(SimSettings)}
        assert SimSettings(**{k: row[k] for k in fields}) == settings
        rec = Recording(row["recording"])
        # the recording is the run a single `vdc-capture sim` with these settings makes
        assert rec.recording_id == row["recording_id"] == settings.to_config().run_id()
        props = rec.properties()
        assert props["run_end"]["complete"]
        assert props["collision"]["threshold"] == row["threshold"]
        assert row["events_crash"] + row["events_avoidance"] > 0  # 6 s in a 1.4 m arena
    # a re-run records nothing; a lost row is recorded again, alone; --force records all
    again = _sweep(out, *grid)
    assert "4 already done, 0 recorded" in again.stdout, again.stderr
    lost = sorted((out / "runs").glob("*.parquet"))[0]
    lost.unlink()
    again = _sweep(out, *grid)
    assert again.returncode == 0 and "3 already done, 1 recorded" in again.stdout
    assert lost.exists() and pl.read_parquet(out / "runs.parquet").height == 4
    forced = _sweep(out, *grid, "--force")
    assert forced.returncode == 0 and "0 already done, 4 recorded" in forced.stdout
    assert (
        pl.read_parquet(out / "runs.parquet").drop("wall_time_s").equals(runs.drop("wall_time_s"))
    )  # same seeds, same code, one machine: the same runs


def test_a_failing_run_is_listed_and_the_others_finish(tmp_path: Path) -> None:
    import cv2

    good = tmp_path / "scene.png"
    cv2.imwrite(str(good), (np.random.default_rng(0).random((60, 400)) * 255).astype(np.uint8))
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"not an image")
    out = tmp_path / "c"
    grid = ("scene=natural", f"image={good},{junk}", "minutes=0.05", "tf_hz=3")
    proc = _sweep(out, *grid)
    assert proc.returncode == 1
    assert "2 runs: 0 already done, 1 recorded, 1 failed" in proc.stdout
    assert "not a readable image" in proc.stderr and "Traceback" not in proc.stderr
    runs = pl.read_parquet(out / "runs.parquet")
    assert runs["image"].to_list() == [str(good)]


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["bogus=1"], "'bogus' is not a vdc-capture sim setting"),
        (["tf_hz=x"], "'x' is not a float"),
        (["seed=5..1"], "runs backwards"),
        (["tf_hz"], "expected FIELD=V1,V2"),
        (["tf_hz=1", "tf_hz=2"], "given twice"),
        (["tf_hz=-3"], "tf_hz must be a number >= 0"),
        (["tf_hz=1", "--jobs", "0"], "--jobs: expected an integer >= 1"),
        (["tf_hz=1", "--scheduler", "missing.json"], "neither tcp://"),
        (["model=avdm:beta=x"], "beta"),  # overrides are checked before any run starts
        (["model=avdm,nope"], "unknown model 'nope'"),
        (["seed=1..1000", "tf_hz=0,1,2,3,4,5,6,7,8,9,10"], "11,000 runs"),
    ],
)
def test_bad_grids_are_one_line_errors(tmp_path: Path, args: list[str], needle: str) -> None:
    # in this process (tests.in_process): the grid is refused before any run starts
    proc = run_in_process("capture", "campaign", *args, "--out", str(tmp_path / "o"))
    assert_one_line_error(proc, needle)
    assert not (tmp_path / "o").exists()  # nothing recorded


def test_the_old_name_sweep_runs_campaign_and_says_so(tmp_path: Path) -> None:
    """``vdc-capture sweep`` became ``campaign`` (``vdc-analyse sweep`` is Fig. 3's, unrelated):
    the old name still runs it, with one line on stderr saying so."""
    proc = run_in_process("capture", "sweep", "model=avdm,nope", "--out", str(tmp_path / "o"))
    lines = proc.stderr.strip().splitlines()
    assert lines[0] == "vdc-capture sweep is now vdc-capture campaign (an alias of it)"
    assert proc.returncode == 2 and len(lines) == 2, proc.stderr
    assert "unknown model 'nope'" in lines[1]
