"""Output a person can read: axes within their quantity's range, titles inside the figure, one
clip's page showing that clip over time in units, sizes written W x H, and a report that gives
its numbers first, says when its verdicts are provisional and explains its symbols first."""

from __future__ import annotations

import base64
import math
from pathlib import Path

import numpy as np
import polars as pl

from tests.figures import recording_figures


def test_the_boundary_figures_speed_axes_start_at_zero(tmp_path: Path) -> None:
    """A condition's complexity interval and the boundary's interval reaching below 0 (a
    Student's t interval on few seeds can) drew the axis to -5 deg/s; complexity is a speed."""
    from analysis.boundary.plot import plot_boundary

    conditions = pl.DataFrame(
        {
            "t_ffi": [12.0, 12.0],
            "condition": ["grating-tf0", "grating-tf3"],
            "complexity_dps": [2.0, 30.0],
            "complexity_low": [-5.0, 25.0],
            "complexity_high": [9.0, 35.0],
            "success_rate": [0.98, 0.5],
            "success_low": [0.9, 0.4],
            "success_high": [1.0, 0.6],
            "avoidances_per_30min": [500.0, 300.0],
            "avoidances_per_30min_low": [400.0, 200.0],
            "avoidances_per_30min_high": [600.0, 400.0],
        }
    )
    bounds = pl.DataFrame(
        {
            "t_ffi": [12.0],
            "where": ["within"],
            "boundary_dps": [10.0],
            "boundary_low_dps": [-4.0],
            "boundary_high_dps": [20.0],
        }
    )
    with recording_figures() as saved:
        plot_boundary(conditions, bounds, "t_ffi", 0.9, tmp_path / "b.png", "test boundary")
    (fig,) = saved
    for ax in fig["axes"]:
        assert ax["xlim"][0] >= 0, ax  # no speed below 0 on the axis
        assert ax["xlim"][1] > 30  # the data still shown whole
    assert fig["clipped"] == []


def test_the_predictors_title_fits_a_one_panel_figure(tmp_path: Path) -> None:
    """One statistic: a 6-inch figure, whose suptitle with a plug-in detector's module path ran
    past both edges."""
    from analysis.predictors.report import STATS, plot_predictors

    stat = next(iter(STATS))
    table = pl.DataFrame(
        {
            "measure": ["avdm", "ti_p910"],
            "statistic": [stat, stat],
            "value": [0.1, 0.1],
            "estimate": [0.6, 0.7],
            "ci_low": [0.5, 0.6],
            "ci_high": [0.7, 0.8],
        }
    )
    title = "examples.looming:Looming: which measure predicts failure (arena, 30 profiling runs)"
    with recording_figures() as saved:
        plot_predictors(table, tmp_path / "p.png", title)
    (fig,) = saved
    assert fig["clipped"] == [], fig["clipped"]
    assert " ".join(fig["suptitle"].split()) == title  # wrapped, not cut


def test_one_clips_page_shows_that_clip_over_time_in_units(tmp_path: Path) -> None:
    from analysis.complexity.command import ComplexitySettings, complexity
    from tests.helpers import write_pan
    from vdc.recording import COMPLEXITY_UNITS as UNITS

    # the robot camera's field of view (its raster, 99x72, once resampled): a calibration vdc
    # ships, no fit to wait for (libx264 wants even sides)
    clip = write_pan(tmp_path / "clip.mp4", 98, 72, 12)
    with recording_figures() as saved:
        res = complexity([str(clip)], ComplexitySettings(fov_deg=70.0), tmp_path / "out")
    rid = res.clips["recording_id"][0]
    own = tmp_path / "out" / f"complexity_{rid}.png"
    page = (tmp_path / "out" / "complexity.html").read_text()
    # the page embeds the clip's own figure, not the collection's (one bar, one-point scatters)
    assert base64.b64encode(own.read_bytes()).decode() in page
    collection = tmp_path / "out" / "complexity_collection.png"
    assert base64.b64encode(collection.read_bytes()).decode() not in page
    assert f"Complexity of {rid}" in page
    (fig,) = [f for f in saved if f["name"] == own.name]
    panels = [a for a in fig["axes"] if a["ylabel"]]
    metrics = [m for m in UNITS if m in res.table.columns]
    assert len(metrics) >= 4
    for m in metrics:  # a panel per metric, its unit in its label, on the clip's time axis
        (ax,) = [a for a in panels if a["ylabel"].split("\n")[0] == m]
        assert f"({UNITS[m]})" in ax["ylabel"]
        assert ax["ylim"][0] >= 0 and ax["xlim"][0] >= 0
    assert not any("normalised" in a["title"] or "percentile" in a["ylabel"] for a in fig["axes"])
    assert fig["clipped"] == []
    # its recording too: each metric as measured (it was divided by its 99th percentile, with
    # no unit), its series named with its unit, on the clip's frames
    import rerun as rr

    from analysis.recordings.reader import Recording

    rrd = tmp_path / "out" / f"complexity_{rid}.rrd"
    signals = Recording(rrd).signals()
    store = rr.chunk.RrdReader(str(rrd)).store()
    for m in metrics:
        frame, _t, values = signals[f"/complexity/{m}"]
        assert frame.tolist() == res.table["frame"].to_list()
        measured = res.table[m].cast(pl.Float64).fill_null(math.nan).to_numpy()
        assert np.array_equal(values[:, 0], measured, equal_nan=True), m
        (names,) = [
            ch.to_record_batch().column("SeriesLines:names").to_pylist()[0]
            for ch in store.stream().filter(content=f"/complexity/{m}")
            if "SeriesLines:names" in ch.to_record_batch().schema.names
        ]
        assert names == [f"{m} ({UNITS[m]})"]


def test_the_viewer_gives_each_unit_a_pane() -> None:
    """A video's blueprint shows the complexity series a pane per unit: deg/s beside P.910 or
    bits/pixel on one axis would flatten all but the largest."""
    from vdc.blueprints import complexity_panes
    from vdc.recording import COMPLEXITY_UNITS as UNITS

    panes = complexity_panes().contents
    shown = [str(c) for pane in panes for c in pane.contents]  # type: ignore[union-attr]
    assert len(panes) == len(set(UNITS.values()))
    for pane in panes:
        units = {UNITS[str(c).rsplit("/", 1)[-1]] for c in pane.contents}  # type: ignore[union-attr]
        assert len(units) == 1 and pane.name.endswith(f"({units.pop()})")
    assert sorted(shown) == sorted(f"/complexity/{m}" for m in UNITS)


def test_sizes_are_written_width_by_height() -> None:
    """The robot camera's raster (72 high, 99 wide) was printed 72x99 in the calibration lines,
    where the README and every other size say W x H."""
    from avdm.calibration_store import FitNote

    note = FitNote("fitting", "avdm", 33.0, 70 / 99, (72, 99))
    assert note.camera().endswith(", 99x72 px")


def test_a_quick_reports_verdicts_are_provisional_and_the_full_ones_not() -> None:
    from analysis.experiments.paper.plan import ReproduceSettings
    from analysis.experiments.paper.report import provisional_note

    quick = provisional_note(ReproduceSettings.make(True))
    assert quick.startswith("Provisional: these verdicts come from a quick run")
    assert quick.endswith(".")
    assert provisional_note(ReproduceSettings.make(False)) == ""


def test_a_claims_row_gives_its_deciding_numbers_and_marks_the_excluded() -> None:
    from analysis.experiments.paper.claims import EXCLUDED, Claim, Quantity
    from analysis.experiments.paper.report import claim_numbers

    nan = math.nan
    c = Claim(
        "c",
        "p",
        "m",
        "holds",
        quantities=[
            Quantity("sf_upc=10", "spearman_rho_vs_tf", 0.8294, nan, nan, 1, "ρ > 0.5"),
            Quantity("sf_upc=50", "spearman_rho_vs_tf", 0.7127, nan, nan, 1, EXCLUDED),
            Quantity(
                "TF 3 Hz", "mean · avdm · straight", 27.76, 23.75, 31.77, 3, "rise with TF: x"
            ),
            Quantity(
                "TF 3 Hz", "mean · avdm · all", 35.4, 27.8, 43.0, 3, "rise with TF (supporting)"
            ),
        ],
    )
    text = claim_numbers(c)
    assert "ρ along TF: SF 10 upc: 0.829, SF 50 upc: excluded" in text
    assert "mean ω̂ driving straight (deg/s): TF 3 Hz: 27.8 [23.8, 31.8]" in text
    assert "35.4" not in text  # a supporting reading decides nothing: below, not here
