"""The per-frame complexity table carries ``omega_valid`` beside ``omega_dps`` (issue 43, item 5;
docs/guides/video.md describes it): False where the AVDM variant's own regime does not hold."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl

from analysis.complexity import ComplexitySettings, complexity, complexity_of_frames
from analysis.complexity.avdm_truth import Cell, cell_frames
from tests.helpers import write_pan

FOV = 70.0  # the robot camera's field of view over cell_frames' 99 px raster


def test_omega_valid_follows_the_warm_up_and_the_texture() -> None:
    """A real photograph panned at 40 deg/s (inside avdm-natural's stated 1-300 deg/s): valid
    once the model has warmed up; a uniform grey clip (no texture at any scale, outside its
    regime): never valid, although omega_dps still has a value (0) on every frame."""
    settings = ComplexitySettings(metrics="omega_dps")
    panned = cell_frames(Cell("astronaut", 40.0, 1, 30.0, "robot", "none"), 40)
    moving = complexity_of_frames(panned, 30.0, FOV, settings=settings)
    assert moving.columns == ["frame", "t_s", "repeat", "omega_dps", "omega_valid"]
    assert moving["omega_valid"].dtype == pl.Boolean
    valid = moving["omega_valid"].to_numpy()
    assert not valid[:9].any()  # the warm-up: the temporal filters are still filling
    assert valid[12:].all()
    flat = np.full((30, 72, 99), 128, np.uint8)
    still = complexity_of_frames(flat, 30.0, FOV, settings=settings)
    assert still["omega_dps"].null_count() == 0
    assert not still["omega_valid"].any()
    # without the AVDM there is no flag either
    ti = complexity_of_frames(flat, 30.0, FOV, settings=ComplexitySettings(metrics="ti_p910"))
    assert "omega_valid" not in ti.columns


def test_the_command_writes_omega_valid_and_its_share(tmp_path: Path) -> None:
    clip = write_pan(tmp_path / "pan.mp4", 320, 240, 40, step_px=2)
    settings = ComplexitySettings(fov_deg=FOV, metrics="omega_dps,ti_p910", model="avdm-natural")
    res = complexity([clip], settings, tmp_path / "cx")
    df = pl.read_parquet(tmp_path / "cx" / "complexity.parquet")
    assert df.columns[4:7] == ["omega_dps", "ti_p910", "omega_valid"]
    assert df["omega_valid"].dtype == pl.Boolean and df["omega_valid"].null_count() == 0
    valid = df.sort("frame")["omega_valid"].to_numpy()
    assert not valid[:9].any() and valid[20:].mean() > 0.5
    clips = pl.read_parquet(tmp_path / "cx" / "clips.parquet")
    assert clips["omega_valid_share"][0] == df["omega_valid"].cast(pl.Float64).mean()
    assert "omega_valid" not in set(res.correlations["metric_a"]) | set(
        res.correlations["metric_b"]
    )
