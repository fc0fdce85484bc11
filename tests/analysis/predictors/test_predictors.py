"""The predictor statistics (:mod:`analysis.predictors.statistics`) against constructed truth: a
measure
built to predict the failures perfectly gets ρ 1 and AUROC 1; one built to carry no
information gets intervals that cover 0 and 0.5; a measure that ranks clips but not moments is
told apart from one that tracks the moments."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest
import scipy.stats

from analysis.predictors.arena import arena_predictors
from analysis.predictors.held_out import loco_threshold
from analysis.predictors.report import STATS, plot_predictors, predictors_report
from analysis.predictors.statistics import (
    auroc,
    finite_spearman,
    footage_predictors,
)
from tests.figures import assert_figure, recording_figures
from tests.helpers import no_frames


def _get(table: pl.DataFrame, measure: str, statistic: str, value: float = 1.0) -> dict:
    r = table.filter(
        (pl.col("measure") == measure)
        & (pl.col("statistic") == statistic)
        & (pl.col("value") == value)
    )
    assert r.height == 1, (measure, statistic)
    return r.row(0, named=True)


def test_auroc_is_mann_whitney_u_and_spearman_is_scipys() -> None:
    rng = np.random.default_rng(0)
    x = rng.normal(size=40).round(1)  # rounded: ties count half
    y = rng.random(40) < 0.4
    u = scipy.stats.mannwhitneyu(x[y], x[~y]).statistic
    assert auroc(x, y) == pytest.approx(u / (y.sum() * (~y).sum()), abs=1e-12)
    z = rng.normal(size=40)
    assert finite_spearman(x, z) == pytest.approx(scipy.stats.spearmanr(x, z).statistic, abs=1e-12)
    assert np.isnan(auroc(x, np.zeros(40, bool)))  # one class: undefined, not 0.5


def test_loco_threshold_holds_out_each_condition() -> None:
    x = np.array([1.0, 2.0, 3.0, 10.0, 11.0, 12.0])
    fails = x > 5
    assert loco_threshold(x, fails) == 1.0  # a wide gap: every held-out unit on its side
    # reversed: no threshold beats calling everything alike, which is chance
    assert loco_threshold(-x, fails) == 0.5
    assert np.isnan(loco_threshold(x, np.ones(6, bool)))  # nothing passes: undefined


def _arena(n_conditions: int, seed: int = 7) -> pl.DataFrame:
    """``n_conditions`` x 5 seeds; failure rates spread from 2 % to 60 % with a gap at the
    80 % target; ``avdm`` is the failure rate itself (plus small noise per seed), ``ti_p910``
    pure noise, the same in every condition."""
    rng = np.random.default_rng(seed)
    half = n_conditions // 2
    fail = np.r_[np.linspace(0.02, 0.11, half), np.linspace(0.45, 0.6, n_conditions - half)]
    runs, measures = [], []
    for c, f in enumerate(fail):
        for s in range(5):
            k = rng.binomial(400, 1 - f)
            runs.append(
                {"condition": f"c{c}", "t_ffi": 1.0, "seed": s, "avoidances": k, "crashes": 400 - k}
            )
            measures.append(
                {
                    "condition": f"c{c}",
                    "seed": s,
                    "avdm": f + rng.normal(0, 0.002),
                    "ti_p910": rng.normal(),
                    "si_p910": rng.normal(),
                }
            )
    return arena_predictors(pl.DataFrame(runs), pl.DataFrame(measures), "t_ffi", 0.8)


@pytest.fixture(scope="module")
def arena() -> pl.DataFrame:
    return _arena(8)


def test_a_perfect_measure_gets_rho_1_and_a_shuffled_one_an_interval_around_0(arena) -> None:
    assert set(arena.columns) >= {
        "measure",
        "value",
        "statistic",
        "estimate",
        "ci_low",
        "ci_high",
        "n",
        "n_failing",
        "unit",
        "p_value",
        "p_holm",
        "role",
        "survives",
        "verdict",
    }
    assert set(arena["unit"]) == {"condition"}  # every row names its unit
    good = _get(arena, "avdm", "rho_failure")
    assert good["estimate"] == 1.0 and good["ci_low"] > 0.5 and good["n"] == 8
    assert good["p_value"] == pytest.approx(1 / 40320)  # exact: 1 ordering of 8! is as good
    assert _get(arena, "avdm", "loco_balanced_accuracy")["estimate"] == 1.0
    noise = _get(arena, "ti_p910", "rho_failure")
    assert noise["ci_low"] < 0 < noise["ci_high"]
    assert noise["ci_high"] - noise["ci_low"] > 0.5  # 8 conditions: wide, as it is
    # 8 conditions are below the power calculation's 24: an estimate, no verdict
    paired = _get(arena, "ti_p910", "paired_rho_failure_vs_avdm")
    assert paired["role"] == "primary" and paired["estimate"] > 0
    assert paired["verdict"] == "8 conditions: too few to judge (24 needed)"
    assert paired["survives"] is None
    # SI/TI alone know nothing; adding the perfect measure lowers the held-out loss
    gain = _get(arena, "si_p910+ti_p910+avdm", "cv_logloss_gain_vs_si_p910+ti_p910")
    assert gain["estimate"] > 0


def test_with_enough_conditions_the_primary_comparison_is_judged_and_the_rest_holm() -> None:
    table = _arena(30)
    primary = table.filter(pl.col("role") == "primary")
    assert primary.height == 1  # one comparison named in advance: the AVDM against P.910 TI
    p = primary.row(0, named=True)
    assert (p["measure"], p["statistic"]) == ("ti_p910", "paired_rho_failure_vs_avdm")
    assert p["verdict"] == "better" and p["survives"] is True and p["n"] == 30
    second = table.filter(pl.col("role") == "secondary")
    assert second.height > 2
    judged = second.filter(pl.col("p_holm").is_not_null())
    assert (judged["p_holm"] >= judged["p_value"] - 1e-15).all()  # Holm only ever raises p
    # a verdict other than "no difference shown" only where the corrected p survives
    claims = judged.filter(pl.col("verdict").is_in(["better", "worse"]))
    assert claims.height and (claims["p_holm"] < 0.05).all() and claims["survives"].all()


def test_leave_one_condition_out_refuses_with_one_failing_condition() -> None:
    """One failing condition: held out, it leaves no failure to fit a threshold on, and a
    perfect predictor would score 0.5; the statistic is refused instead."""
    rng = np.random.default_rng(2)
    runs = [
        {
            "condition": f"c{c}",
            "t_ffi": 1.0,
            "seed": 0,
            "avoidances": 100 if c else 10,
            "crashes": 0 if c else 90,
        }
        for c in range(6)
    ]
    measures = [
        {
            "condition": f"c{c}",
            "seed": 0,
            "avdm": -float(c),
            "ti_p910": rng.normal(),
            "si_p910": rng.normal(),
        }
        for c in range(6)
    ]
    t = arena_predictors(pl.DataFrame(runs), pl.DataFrame(measures), "t_ffi", 0.8)
    loco = _get(t, "avdm", "loco_balanced_accuracy")
    assert loco["estimate"] is None and loco["n_failing"] == 1
    assert (
        loco_threshold(np.array([-0.0, -1, -2, -3]), np.array([True, False, False, False])) == 0.5
    )


@pytest.fixture(scope="module")
def footage() -> pl.DataFrame:
    """40 clips, 12 wrong. Per clip, ``avdm`` is high exactly on the wrong clips; ``si_p910``
    is noise. Per frame (100 frames a clip), ``ti_p910`` rises exactly on the frames the
    detector alerts on; ``mafd`` is a clip-level constant that is higher where a clip alerts
    more (it ranks clips, not moments)."""
    rng = np.random.default_rng(3)
    n = 40
    wrong = np.zeros(n, bool)
    wrong[:12] = True
    clips = pl.DataFrame(
        {
            "clip": [f"k{i}" for i in range(n)],
            "threshold": 1.0,
            "correct": ~wrong,
            "avdm": np.where(wrong, 5.0, 1.0) + rng.random(n),
            "si_p910": rng.normal(size=n),
            "ti_p910": rng.normal(size=n),
            "mafd": rng.normal(size=n),
        }
    )
    frames = []
    for i in range(n):
        rate = 0.05 + 0.4 * i / n
        alert = rng.random(100) < rate
        frames.append(
            pl.DataFrame(
                {
                    "clip": f"k{i}",
                    "threshold": 1.0,
                    "frame": np.arange(100),
                    "positive": alert,
                    "keep": True,
                    "ti_p910": alert * 2.0 + rng.random(100),
                    "mafd": np.full(100, rate),
                    "si_p910": rng.normal(size=100),
                }
            )
        )
    return footage_predictors(clips, pl.concat(frames), "threshold")


def test_footage_auroc_perfect_shuffled_and_within_clip(footage, tmp_path) -> None:
    good = _get(footage, "avdm", "clip_auroc")
    # separated: the interval keeps its width (a percentile bootstrap collapsed to [1, 1])
    assert good["estimate"] == 1.0 and 0.85 < good["ci_low"] < 1.0 and good["n"] == 40
    assert good["unit"] == "clip" and good["n_failing"] == 12
    # frames clustered in their clips: the clips are what the interval clusters on
    pooled = _get(footage, "ti_p910", "frame_auroc_pooled")
    assert pooled["unit"] == "clip" and pooled["n_units"] == 40
    noise = _get(footage, "si_p910", "clip_auroc")
    assert noise["ci_low"] < 0.5 < noise["ci_high"]
    tracks = _get(footage, "ti_p910", "frame_auroc_within_clip")
    assert tracks["estimate"] == 1.0
    assert _get(footage, "ti_p910", "frame_auroc_pooled")["estimate"] == 1.0
    ranks_clips = _get(footage, "mafd", "frame_auroc_pooled")
    assert ranks_clips["ci_low"] > 0.6  # clips that alert more rank higher, pooled
    within = _get(footage, "mafd", "frame_auroc_within_clip")
    assert within["estimate"] == 0.5  # a constant within each clip: ties, no information
    frame_noise = _get(footage, "si_p910", "frame_auroc_pooled")
    assert frame_noise["ci_low"] < 0.5 < frame_noise["ci_high"]
    with recording_figures() as saved:
        png = plot_predictors(footage, tmp_path / "p.png", "test predictors")
    assert_figure(png, saved, title="test predictors", labels=("95 % interval",), min_axes=2)
    md = predictors_report(footage, "threshold", "footage")
    assert "1.00 [1.00, 1.00]" not in md
    assert "12 failing clips (the smaller class): too few to judge (46 of each class needed)" in md


def test_the_arena_grid_gains_its_predictors_from_cached_measures(tmp_path) -> None:
    """A tiny grid (3 drifts, one value, 2 seeds of 0.3 min) end to end: every measure of every
    profiling run, cached beside it, and the table recomputed from the cache alone; measured
    in the grid's own pool (by the worker that recorded the run), the same bytes as measured
    afterwards. On every 4th frame pair (--measure-every 4), which the recomputation keeps."""
    import vdc

    s = vdc.BoundarySettings(
        tf="0,1,3",
        scenes="grating",
        values="30",
        seeds=2,
        minutes=0.3,
        jobs=2,
        no_fit=True,
        measure_every=4,
    )
    with recording_figures() as saved:
        res = vdc.boundary(s, tmp_path)
    pred = pl.read_parquet(tmp_path / "predictors.parquet")
    measures = pl.read_parquet(tmp_path / "predictor_measures.parquet")
    assert measures.height == 3 * 2  # one row per profiling run
    assert (measures["every"] == 4).all()
    # a quarter of the straight frames after the warm-up, give or take a frame per straight
    # stretch (turns break them)
    share = measures["sampled_frames"] / measures["frames"]
    assert ((share > 0.2) & (share < 0.3)).all(), share.to_list()
    from analysis.predictors.statistics import MEASURES

    for m in MEASURES:  # every measure measured, on the camera's raster
        assert measures[m].is_finite().all(), m
        assert pred.filter(pl.col("measure") == m).height, m
    by = measures.group_by("condition").agg(pl.col("avdm", "flow_dps", "ti_p910").mean())
    c = {r["condition"]: r for r in by.iter_rows(named=True)}
    for m in ("avdm", "flow_dps", "ti_p910"):  # the wall's drift is what motion measures read
        assert c["grating-tf3"][m] > c["grating-tf0"][m], m
    if pred["estimate"].is_not_null().any():
        assert_figure(tmp_path / "predictors.png", saved, labels=("95 % interval",))
    else:  # runs this short may all succeed alike: the figure says so, never a blank panel
        fig = next(d for d in saved if d["name"] == "predictors.png")
        assert all("no estimate" in ax["title"] for ax in fig["axes"]), fig
    assert "## Which measure predicts where it breaks" in res.markdown
    caches = sorted((tmp_path / "recordings" / "profile").rglob("*.measures.json"))
    assert len(caches) == 6
    (tmp_path / "predictors.parquet").unlink()  # an older grid: computed from the caches
    again = vdc.predictors(tmp_path)
    assert again.measures["reused"].all()
    assert again.predictors.sort("measure", "statistic").equals(pred.sort("measure", "statistic"))
    assert vdc.predictors(res).predictors.height == pred.height
    # measured by the workers that recorded the runs == measured afterwards, bit for bit (the
    # JSON floats round-trip exactly): the same numbers from either pool, nothing re-tuned
    in_pool = {c: c.read_text() for c in caches}
    for c in caches:
        c.unlink()
    (tmp_path / "predictors.parquet").unlink()
    after = vdc.predictors(tmp_path)
    assert not after.measures["reused"].any()  # measured afresh, in a second pool
    assert {c: c.read_text() for c in caches} == in_pool
    assert after.predictors.sort("measure", "statistic").equals(pred.sort("measure", "statistic"))


def test_footage_keeps_every_measure_per_frame(tmp_path) -> None:
    """The guides' OpenCV looming detector on rendered clips: the per-frame table and the
    clip and frame statistics for every measure."""
    import vdc
    from tests.footage_clips import looming_boundary_settings, write_collection

    labels = write_collection(tmp_path / "clips", drifts=(0.0, 4.0), seeds=(1, 2))
    # a clip with the object and one without over the same drifting texture share their
    # background: their scene (4 scenes of 2 clips)
    table = pl.read_csv(labels)
    table.with_columns(pl.col("clip").str.extract(r"-(drift.*)\.mp4$").alias("scene")).write_csv(
        labels
    )
    s = looming_boundary_settings(labels)
    vdc.boundary(s, tmp_path / "out")
    res = vdc.predictors(tmp_path / "out")
    clips = pl.read_parquet(tmp_path / "out" / "boundary_clips.parquet")
    assert clips["scene"].n_unique() == 4
    # every statistic is over the 4 scenes the 8 clips share (too few for any verdict)
    assert set(res.predictors["unit"]) == {"scene"}
    assert set(res.predictors["n_units"]) <= {0, 1, 2, 3, 4}
    verdicts = res.predictors.filter(pl.col("role").is_not_null())["verdict"]
    assert all("too few to judge" in v for v in verdicts), verdicts.to_list()
    frames = res.measures
    assert frames["clip"].n_unique() == 8
    assert {"avdm", "avdm_natural", "ti_p910", "flow_dps", "positive", "keep"} <= set(
        frames.columns
    )
    looming = frames.filter(pl.col("clip").str.starts_with("loom"))
    assert not looming.filter(pl.col("frame") >= 99 - 50)["keep"].any()  # the window is left out
    stats = set(res.predictors["statistic"])
    assert {"clip_auroc", "frame_auroc_pooled", "frame_auroc_within_clip"} <= stats
    # the report names each statistic in words (since 40d33c2), not by its column name
    assert f"### {STATS['clip_auroc']} (intervals over " in res.markdown
    # the still clips' paper AVDM is 0, a number: the combined models with it are fitted
    assert "si_p910+ti_p910+avdm" in set(res.predictors["measure"])


@pytest.mark.parametrize("shape", [(3, 72, 99), (2, 71, 100)])
def test_codec_frames_are_ffmpegs_grey_to_yuv420p(shape) -> None:
    """The H.264 size (codec_bpp) is of 4:2:0 frames built directly from the grey frames: they
    are, byte for byte, FFmpeg's own conversion (odd sizes padded by their edge), so the
    faster path measures the same stream."""
    import av

    from analysis.experiments.collision.predictor_runs import yuv420_planes

    frames = np.random.default_rng(1).integers(0, 256, shape, dtype=np.uint8)
    frames[0, 0, :2] = (0, 255)  # both ends of the range
    ours = yuv420_planes(frames)
    for grey, planes in zip(frames, ours, strict=True):
        even = np.pad(grey, ((0, shape[1] % 2), (0, shape[2] % 2)), mode="edge")
        ffmpeg = av.VideoFrame.from_ndarray(even, format="gray").reformat(format="yuv420p")
        np.testing.assert_array_equal(planes, ffmpeg.to_ndarray())


def test_frame_classes_leave_out_the_start_up_and_the_window() -> None:
    """A busy clip alerts from its third frame on: its only quiet frames are the start-up,
    where the AVDM is still rising from 0; with the start-up left out, no quiet frame is left
    to make a within-clip AUROC of 1 from that artefact."""
    from analysis.boundary.footage_predictors import frame_classes

    frames = np.arange(100)
    alert = (frames >= 2).astype(float)
    positive, keep = frame_classes(frames, alert, None, 25, warmup_frames=60)
    assert not keep[:60].any() and keep[60:].all()
    assert positive[keep].all()  # nothing quiet to compare with: the statistic has no pair
    positive, keep = frame_classes(frames, alert, 99, 25, warmup_frames=60)
    assert np.flatnonzero(keep).tolist() == list(range(60, 74))
    positive, keep = frame_classes(frames, alert, 99, 25)  # no start-up given: as before
    assert keep[:74].all() and not keep[74:].any() and not positive[:2].any()
    # the object is drawn from frame 50 on, well before the window: the scene ends there
    positive, keep = frame_classes(frames, alert, 99, 25, hazard_onset_frame=50)
    assert np.flatnonzero(keep).tolist() == list(range(50))
    # a near miss (no collision) drawn from frame 40: its frames from then on are not scene
    positive, keep = frame_classes(frames, alert, None, 25, hazard_onset_frame=40)
    assert np.flatnonzero(keep).tolist() == list(range(40))


def test_failure_modes_with_opposite_signs_are_scored_apart() -> None:
    """Misses on dark, plain scenes (a LOW measure) and false alarms on busy ones (HIGH): one
    class "wrong" mixes them to about chance; scored apart, each is found with its sign."""
    rng = np.random.default_rng(4)
    kinds = ["miss"] * 10 + ["hit"] * 20 + ["false_alarm"] * 10 + ["quiet"] * 20
    level = {"miss": -2.0, "hit": 0.0, "false_alarm": 2.0, "quiet": 0.0}
    clips = pl.DataFrame(
        {
            "clip": [f"k{i}" for i in range(len(kinds))],
            "threshold": 1.0,
            "correct": [k in ("hit", "quiet") for k in kinds],
            "failure": kinds,
            "si_p910": [level[k] + rng.normal(0, 0.3) for k in kinds],
        }
    )
    frames = no_frames("si_p910")
    t = footage_predictors(clips, frames, "threshold")
    mixed = _get(t, "si_p910", "clip_auroc")
    assert mixed["ci_low"] < 0.5 < mixed["ci_high"]  # one class: the signs cancel
    miss = _get(t, "si_p910", "clip_auroc_miss")
    fa = _get(t, "si_p910", "clip_auroc_false_alarm")
    assert miss["estimate"] < 0.1 and miss["n"] == 30 and miss["n_failing"] == 10
    assert fa["estimate"] > 0.9 and fa["n"] == 30
