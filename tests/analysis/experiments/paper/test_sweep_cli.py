"""``vdc-analyse sweep`` and ``vdc-analyse calibrate`` as a user runs them."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from analysis.cli import main
from avdm.calibration_store import lookup_calibration
from tests.figures import assert_figure, figure_env, recording_figures, saved_figures
from tests.helpers import assert_one_line_error, flags, run_cli
from tests.in_process import run_in_process
from vdc.parquet_io import read_metadata

SWEEP_COLUMNS = [
    "model",
    "sf_upc",
    "tf_hz",
    "period_px",
    "omega_true_dps",
    "omega_dps",
    "lambda_px",
    "motion",
    "contrast",
]


def test_paper_sweep_writes_table_figure_and_monotonicity(out_dir: Path, capsys) -> None:
    with recording_figures() as figures:
        assert main(["sweep", "--out", str(out_dir)]) == 0
    printed = capsys.readouterr().out
    df = pl.read_parquet(out_dir / "sweep.parquet")
    assert df.columns[: len(SWEEP_COLUMNS)] == SWEEP_COLUMNS
    # the six rows and columns of paper Fig. 3
    for sf in (1.0, 10.0, 50.0):
        assert df.filter(pl.col("sf_upc") == sf).height == 16
    for tf in (1.0, 5.0, 50.0):
        assert df.filter(pl.col("tf_hz") == tf).height == 17
    np.testing.assert_allclose(df["omega_true_dps"], df["tf_hz"] * 360 / df["sf_upc"])
    np.testing.assert_allclose(df["period_px"], 100 / df["sf_upc"])
    fig = assert_figure(
        out_dir / "sweep.png",
        figures,
        title="SF = 10 upc",
        labels=("TF (Hz)", "SF (units per circle)"),
        min_axes=6,
    )
    assert "angular velocity (deg/s)" in {ax["ylabel"] for ax in fig["axes"]}
    mono = pl.read_parquet(out_dir / "monotonicity.parquet")
    assert mono.height == 6
    # the paper's claim on the well-sampled rows: rising with TF, falling with SF
    for fixed in ("sf_upc=1", "sf_upc=10"):
        assert mono.filter(pl.col("fixed") == fixed)["trend"].item() == "increasing"
    for fixed in ("tf_hz=1", "tf_hz=5", "tf_hz=50"):
        assert mono.filter(pl.col("fixed") == fixed)["rho"].item() < -0.9
    assert "rho=" in printed and "vs TF at sf_upc=10" in printed
    meta = read_metadata(out_dir / "sweep.parquet")
    assert meta["model"] == "avdm"
    assert meta["params"]["a"] == lookup_calibration(300.0, 3.6)["a"]
    assert meta["stimulus"]["fps"] == 300.0
    assert "numpy" in meta["versions"] and "vdc" in meta["versions"]


def test_grid_sweep_is_idempotent_and_honours_the_model(tmp_path: Path) -> None:
    args = [
        "sweep",
        *flags("--sf 2,10 --tf 1,5,20 --duration 0.3 --model avdm-on:beta=0.3"),
    ]
    assert main([*args, "--out", str(tmp_path / "a")]) == 0
    assert main([*args, "--out", str(tmp_path / "b")]) == 0
    a = pl.read_parquet(tmp_path / "a" / "sweep.parquet")
    b = pl.read_parquet(tmp_path / "b" / "sweep.parquet")
    assert a.height == 6 and a.equals(b)
    assert set(a["model"]) == {"avdm-on:beta=0.3"}
    assert read_metadata(tmp_path / "a" / "sweep.parquet")["params"]["channel"] == "on"


def test_sweep_runs_as_a_module(out_dir: Path) -> None:
    proc = run_cli(
        "analysis",
        "sweep",
        *flags("--sf 5,10 --tf 2,4 --duration 0.2", out=out_dir),
    )
    assert proc.returncode == 0, proc.stderr
    assert "summary:" in proc.stdout
    assert pl.read_parquet(out_dir / "sweep.parquet").height == 4


@pytest.mark.parametrize(
    ("args", "needles"),
    [
        (["sweep", "--tf", "abc"], ["--tf", "comma-separated numbers"]),
        (["sweep", "--model", "nope"], ["unknown model 'nope'"]),
        (["sweep", "--model", "avdm:beta=x"], ["beta", "expected a number"]),
        (["sweep", "--sf", "60"], ["Nyquist"]),
        (["sweep", "--tf", "0"], ["> 0 Hz"]),
        (["sweep", "--duration", "0.01"], ["warm-up"]),
        (["sweep", "--contrast", "2"], ["--contrast"]),
        (["sweep", "--size", "ten"], ["WIDTHxHEIGHT"]),
        (["sweep", "--size", "100000x100000"], ["too large"]),
        (
            ["sweep", "--model", "lgmd-plus"],
            ["omega_dps", "collision detector"],
        ),  # refused, not out of memory
        (["sweep", "--fps", "100"], ["paper layout"]),
        (["sweep", "--bogus"], ["unrecognized arguments"]),
        (["calibrate", "--fps", "-1"], ["positive number"]),
        (["calibrate", "--model", "avdm:tw=x"], ["expected an integer"]),
        (["frobnicate"], ["invalid choice"]),
    ],
)
def test_bad_input_gives_one_line_and_exit_2(args: list[str], needles: list[str], out_dir) -> None:
    # in this process (tests.in_process): the parse and checks of the command line only
    proc = (
        run_in_process("analysis", *args, "--out", str(out_dir))
        if args[0] != "frobnicate"
        else run_in_process("analysis", *args)
    )
    assert_one_line_error(proc, *needles)
    assert not (out_dir / "sweep.parquet").exists()


def test_unwritable_output_is_one_line(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    proc = run_in_process(
        "analysis", "sweep", "--sf", "5,10", "--tf", "2", "--out", str(blocker / "sub")
    )
    assert_one_line_error(proc)


def test_calibrate_prints_and_saves_the_fit(out_dir: Path) -> None:
    record = out_dir.parent / "figures.jsonl"
    proc = run_cli(
        "analysis",
        "calibrate",
        *flags("--fps 33 --size 99x72", deg_per_px=repr(70 / 99), out=out_dir),
        env=figure_env(record),
    )
    assert proc.returncode == 0, proc.stderr
    shipped = lookup_calibration(33.0, 70 / 99)
    printed = re.search(r"a = (\S+)\s+b = (\S+)", proc.stdout)
    assert printed, proc.stdout
    # compare numbers, not 6-digit strings: a fit on another CPU may round the last printed
    # digit the other way (see test_calibration.py for the 1e-5 relative tolerance)
    assert float(printed[1]) == pytest.approx(shipped["a"], rel=1e-5)
    assert float(printed[2]) == pytest.approx(shipped["b"], rel=1e-5)
    assert "--model avdm:a=" in proc.stdout
    saved = (out_dir / "calibration.json").read_text()
    assert '"r2"' in saved and '"grid"' in saved
    assert_figure(
        out_dir / "calibration.png",
        saved_figures(record),
        title="a = ",
        labels=("true angular velocity ω (deg/s)", "decoded ω̂ (deg/s)"),
    )


def test_a_poor_calibration_is_not_offered(tmp_path: Path) -> None:
    """12x4 px at 30 Hz leaves a narrow valid band: the log-log fit explains too little of it
    (R^2 about 0.67), so it is written for inspection but neither offered nor stored."""
    proc = run_in_process(
        "analysis",
        "calibrate",
        *flags("--fps 30 --size 12x4 --update-defaults", out=tmp_path),
    )
    assert proc.returncode == 1, proc.stderr
    assert "not offered for use" in proc.stderr and "use it as" not in proc.stdout
    assert "updated the shipped defaults" not in proc.stdout
    assert (tmp_path / "calibration.json").exists()


def test_complexity_refuses_a_model_without_omega_in_one_line() -> None:
    from analysis.complexity.command import ComplexitySettings

    with pytest.raises(ValueError, match="lgmd-plus is a collision detector"):
        ComplexitySettings(model="lgmd-plus")
