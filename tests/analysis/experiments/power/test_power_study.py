"""``vdc-analyse power-study --quick``: the pre-registered plan's reduced version end to end on
a real process pool (arena campaigns, the looming collection, footage studies, the answer), its
outputs marked as not findings, and a re-run that recomputes nothing; the per-scene measure
checked against Kendall's tau."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import polars as pl
import pyarrow.parquet as pq
import pytest
import scipy.stats

from analysis.experiments.power.answer import discordant_share, footage_units
from analysis.experiments.power.plans import AMENDED, FULL, QUICK_AMENDED
from analysis.experiments.power.study import PowerStudySettings, power_study
from tests.figures import assert_figure, recording_figures
from tests.in_process import run_in_process

QUICK = QUICK_AMENDED  # the quick run of the default (amended) plan

ANSWER = (
    "answer.md",
    "primary.parquet",
    "secondaries.parquet",
    "per_scene.parquet",
    "per_scene.png",
    "studies.parquet",
)


@pytest.fixture(scope="module")
def quick(tmp_path_factory) -> tuple[Path, object, list[dict]]:
    out = tmp_path_factory.mktemp("power-study")
    # one worker: the suite's two xdist workers already fill the two cores
    with recording_figures() as figures:
        return out, power_study(PowerStudySettings(quick=True, jobs=1), out), figures


def test_the_quick_plan_writes_the_answer_marked_as_not_findings(quick) -> None:
    out, res, figures = quick
    for name in ANSWER:
        assert (out / name).is_file(), name
    answer = (out / "answer.md").read_text()
    first, second = answer.split("\n\n")[:2]
    assert first.startswith("**Quick run") and "not findings" in first
    # every study is far below the plan's power: the answer says so in words, naming the units
    assert second.startswith("**Does the AVDM predict")
    assert "Not known: no study could be judged." in second and "Too few scenes" in second
    assert "too few to judge" in answer.split("\n\n")[2]  # each study's line says why
    assert "What these runs cannot tell" in second
    assert "QUICK RUN" in res.report()[0]
    for name in ("primary", "secondaries", "per_scene", "studies"):
        kv = pq.read_schema(out / f"{name}.parquet").metadata
        assert json.loads(kv[b"vdc.not_findings"]) is True, name
    fig = assert_figure(out / "per_scene.png", figures, title="not findings", min_axes=2)
    assert "QUICK RUN" in fig["suptitle"]


def test_each_detector_gets_its_primary_comparison(quick) -> None:
    out, _, _ = quick
    primary = pl.read_parquet(out / "primary.parquet")
    want = [("arena", d) for d, _, _ in QUICK.arena_detectors] + [
        ("footage", d) for d, _, _ in QUICK.footage_detectors
    ]
    assert list(zip(primary["source"], primary["detector"], strict=True)) == want
    arena = primary.filter(pl.col("source") == "arena")
    # 3 conditions in 3 scenes, below the 20 scenes a clustered verdict asks for: no
    # verdict, said so; the scenes are the unit
    assert arena["n"].to_list() == [QUICK.conditions()] * 2
    assert arena["unit"].to_list() == ["scene"] * 2 and arena["n_units"].to_list() == [3] * 2
    assert all(v == "3 scenes: too few to judge (20 needed)" for v in arena["verdict"])
    assert arena["statistic"].to_list() == ["rho_failure"] * 2
    # a footage study either judged its clips or says why it could not (no alert at all); LGMD+
    # is named in advance as unable to inform, and says so whatever its numbers
    for r in primary.filter(pl.col("source") == "footage").iter_rows(named=True):
        if r["detector"] == "lgmd-plus":
            assert r["verdict"].startswith("cannot inform by construction"), r
            continue
        assert "too few to judge" in r["verdict"] or r["verdict"].startswith("no evidence"), r
    # the secondaries are the studies' own comparisons, never the primary one
    sec = pl.read_parquet(out / "secondaries.parquet")
    assert sec.height and set(sec["role"]) == {"secondary"}


def test_the_arena_detectors_share_one_set_of_profiling_runs(quick) -> None:
    out, res, _ = quick
    profiles = list((out / "arena" / "recordings" / "profile").rglob("*.rrd"))
    assert len(profiles) == QUICK.conditions() * QUICK.seeds
    arena = res.studies.filter(pl.col("source") == "arena")
    # every run recorded was counted once, by the study that recorded it: the first
    # detector's confirmation recorded the profiling runs too (and a moved value its runs again)
    recorded = list((out / "arena" / "recordings").rglob("*.rrd"))
    assert int(arena["recomputed"].sum()) == len(recorded)
    assert arena["recomputed"][0] >= 2 * QUICK.conditions()
    scenes = pl.read_parquet(out / "per_scene.parquet")
    assert set(scenes["scene"]) >= {*QUICK.scenes, "across scenes"}


def test_a_rerun_recomputes_nothing(quick) -> None:
    out, res, _ = quick
    assert res.recomputed > 0
    rrd = sorted(out.rglob("*.rrd"))
    primary = pl.read_parquet(out / "primary.parquet")
    proc = run_in_process("analysis", "power-study", "--quick", "--out", str(out), "--jobs", "1")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith("QUICK RUN: its verdicts are not findings")
    studies = pl.read_parquet(out / "studies.parquet")
    assert studies["recomputed"].to_list() == [0] * studies.height
    assert sorted(out.rglob("*.rrd")) == rrd
    # every study said it was reused, and the answer is the same
    assert proc.stderr.count("reused") >= studies.height, proc.stderr
    assert pl.read_parquet(out / "primary.parquet").equals(primary)


def test_the_per_scene_measure_agrees_with_the_predictors_auroc(quick) -> None:
    out, _, _ = quick
    primary = pl.read_parquet(out / "primary.parquet")
    labels = pl.read_csv(out / "footage" / "clips" / "labels.csv")
    ran = primary.filter((pl.col("source") == "footage") & pl.col("avdm_estimate").is_not_null())
    assert ran.height
    for r in ran.iter_rows(named=True):
        units = footage_units(
            out / "footage" / r["detector"].replace(".", "-").replace(":", "-"), labels
        )
        # over failing/passing pairs, AUROC = 1 - the discordant share (ties half in both);
        # the clips' AVDM is recomputed here from the frames the predictors kept
        for m, col in (("avdm", "avdm_estimate"), ("ti_p910", "ti_estimate")):
            share = discordant_share(units[m].to_numpy(), units["failure"].to_numpy())
            assert 1 - share == pytest.approx(r[col], abs=1e-9), (r["detector"], m)


def test_the_amended_plan_is_the_documented_one() -> None:
    """docs/findings/power_plan_amendment.md: 23 scenes (21 photographs, one grating, one
    natural) x 3 TFs, 3 seeds of 3 min, 483 clips over the 21 photographs, every value
    confirmed, LGMD+ on footage named as unable to inform."""
    from analysis.boundary.scenes import scene_fields

    assert AMENDED.conditions() == 69 and AMENDED.seeds == 3 and AMENDED.minutes == 3.0
    photos = [sc for sc in AMENDED.scenes if sc.startswith("photo-")]
    assert len(photos) == 21 == len(set(photos))
    # a procedural generator is one family: at most one scene each
    assert [sc for sc in AMENDED.scenes if not sc.startswith("photo-")] == ["grating", "natural"]
    images = {scene_fields(sc)["image"] for sc in photos}
    assert len(images) == 21 and all(images)
    assert AMENDED.clips == 483 and AMENDED.collection == "2026-12" and AMENDED.confirm
    assert [d for _, d, _ in AMENDED.uninformative] == ["lgmd-plus"]
    assert AMENDED.pilot_seed != 0  # the study's clips are seed 0's
    assert PowerStudySettings().plan() is AMENDED
    assert PowerStudySettings(plan_version="2026-11").plan() is FULL


def test_the_confirmation_moves_a_value_one_step_outside_20_60() -> None:
    from analysis.experiments.power.study import move

    assert move(AMENDED, "arena", "flow-ttc", "tau_alert_s", 0.6, 0.38) == (0.6, "")
    assert move(AMENDED, "arena", "flow-ttc", "tau_alert_s", 0.6, 0.1)[0] == 0.4
    assert move(AMENDED, "arena", "flow-ttc", "tau_alert_s", 0.6, 0.7)[0] == 0.8
    # the first plan's LGMD+: 69 % of the arena conditions failing moves T_ffi 12 -> 20
    value, why = move(AMENDED, "arena", "lgmd-plus-arena", "t_ffi", 12.0, 0.69)
    assert (
        value == 20.0
        and why == "t_ffi moved 12 -> 20: 69 % failing in the confirmation, outside 20-60 %"
    )
    assert move(AMENDED, "arena", "flow-ttc", "tau_alert_s", 0.6, 0.2) == (0.6, "")  # the edge
    assert "unconfirmed" in move(AMENDED, "arena", "flow-ttc", "tau_alert_s", 0.6, None)[1]


def test_a_pilot_refuses_the_studys_own_clips(tmp_path: Path) -> None:
    from analysis.experiments.collision.looming_footage import LoomingFootageSettings
    from analysis.experiments.power.pilot import footage_pilot

    with pytest.raises(ValueError, match="must not be the study's"):
        footage_pilot(tmp_path, 2, settings=LoomingFootageSettings(seed=0))


def test_the_resume_key_holds_the_code(quick) -> None:
    out, _, _ = quick
    from analysis.experiments.power.study import code_key

    key = code_key()
    assert json.loads((out / "code.json").read_text()) == key
    for marker in (out / "footage").glob("*/study.json"):
        if marker.parent.name != "clips":
            assert json.loads(marker.read_text())["key"]["code"] == key["code"], marker
    for marker in (out / "arena").glob("*/study.json"):
        assert json.loads(marker.read_text())["key"]["code"] == key["code"], marker


def test_changed_code_sets_the_studies_aside_and_says_so(tmp_path: Path) -> None:
    """A resumed study is reused only with the code that scored it: another code hash sets
    the studies aside (kept, renamed) so that everything is computed again, and says so."""
    from analysis.experiments.power.study import code_key, set_aside_stale
    from vdc.executors import Feedback

    lines: list[str] = []
    log = Feedback(log=lines.append)
    key = code_key()
    (tmp_path / "arena" / "flow-ttc").mkdir(parents=True)
    (tmp_path / "arena" / "flow-ttc" / "study.json").write_text("{}")
    (tmp_path / "footage").mkdir()
    assert set_aside_stale(tmp_path, key, log) != []  # no code.json: older studies, recomputed
    (tmp_path / "arena").mkdir()
    assert set_aside_stale(tmp_path, key, log) == []  # the same code: kept
    assert (tmp_path / "arena").is_dir()
    # a scorer's source changed: its hash differs
    # a scorer's source changed: a copy of the sources with one scoring line edited
    from analysis.experiments.power.resume import CODE_PATHS, SOURCE_ROOT

    copy = tmp_path / "src"
    for rel in CODE_PATHS:
        src = SOURCE_ROOT / rel
        if src.is_dir():
            shutil.copytree(src, copy / rel, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            (copy / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(src, copy / rel)
    assert code_key(root=copy) == key  # the same sources: the same key
    judge = copy / "analysis" / "boundary" / "footage.py"
    judge.write_text(judge.read_text().replace("min_ttc_s", "min_ttc_s ", 1))
    changed = code_key(root=copy)
    assert changed["code"] != key["code"]
    moved = set_aside_stale(tmp_path, changed, log)
    assert [m.name for m in moved] == [f"arena.stale-{key['code'][:8]}"]
    assert not (tmp_path / "arena").exists() and moved[0].is_dir()
    assert any("changed since the last run" in line for line in lines)
    assert json.loads((tmp_path / "code.json").read_text()) == changed


def test_the_full_plan_is_the_documented_one() -> None:
    # docs/findings/power_plan.md: 8 scenes x 6 TFs = 48 conditions, 3 seeds of 3 min, 480 clips
    assert FULL.conditions() == 48 and FULL.seeds == 3 and FULL.minutes == 3.0
    assert FULL.clips == 480 and len(FULL.footage_detectors) == 3
    assert FULL.arena_runs() == 48 * 3 * 3  # two detectors and the profiling runs


def test_the_discordant_share_is_kendalls_tau_rescaled() -> None:
    rng = np.random.default_rng(3)
    x, f = rng.normal(size=12), rng.normal(size=12)
    tau = scipy.stats.kendalltau(x, f).statistic
    # without ties every pair is concordant or discordant: share = (1 - tau) / 2 (exact
    # arithmetic on 66 pairs; 1e-12 is float rounding)
    assert discordant_share(x, f) == pytest.approx((1 - tau) / 2, abs=1e-12)
    assert discordant_share(f, f) == 0.0 and discordant_share(-f, f) == 1.0
    assert discordant_share(np.zeros(4), [0, 1, 0, 1]) == 0.5  # ties count half
    assert np.isnan(discordant_share([1.0, 2.0], [0.5, 0.5]))  # no pair whose failure differs
    # across groups only: the within-group pairs (here all concordant) are left out
    group = np.array([0, 0, 1, 1])
    assert discordant_share([1, 2, 0, 0.5], [1, 2, 3, 4], group) == 1.0


def test_the_answer_says_which_verdicts_survive_holm_over_the_studies() -> None:
    """The plan judges each study's primary comparison alone at 5 %; the answer also says which
    verdicts survive Holm over the judged studies (the plan's own run: 4 verdicts, 1 stands)."""
    from analysis.experiments.power.answer import first_paragraph, with_holm_across
    from analysis.predictors.statistics import HEADLINE

    base = {
        "param": "v",
        "value": 1.0,
        "statistic": "s",
        "n": 48,
        "n_failing": 20,
        "n_correct": 28,
        "n_units": 48,
        "unit": "condition",
        "status": "ran",
        "avdm_estimate": 0.1,
        "avdm_ci_low": 0.0,
        "avdm_ci_high": 0.2,
        "ti_estimate": 0.2,
        "ti_ci_low": 0.1,
        "ti_ci_high": 0.3,
        "difference": -0.1,
        "difference_low": -0.2,
        "difference_high": 0.0,
    }
    studies = [
        ("arena", "lgmd-plus-arena", 0.0014, "worse"),
        ("arena", "flow-ttc", 0.019, "better"),
        ("footage", "lgmd-plus", 0.25, "no difference shown"),
        ("footage", "looming", 0.048, "worse"),
        ("footage", "flow-ttc", 0.013, "worse"),
        (
            "footage",
            "unjudged",
            0.001,
            "9 failing clips (the smaller class): too few to judge (46 of each class needed)",
        ),
    ]
    primary = with_holm_across(
        pl.DataFrame(
            [
                base
                | {"source": s, "detector": d, "p_value": p, "verdict": v}
                | {"statistic": HEADLINE[s]}
                for s, d, p, v in studies
            ]
        )
    )
    # Holm over the five judged: 0.0014 x 5, then 0.013 x 4 = 0.052 stops it; the unjudged none
    expected = [0.007, 0.057, 0.25, 0.096, 0.052, None]
    got = primary["p_holm_across"].to_list()
    assert got[-1] is None
    assert np.allclose(got[:-1], expected[:-1], atol=1e-12)  # exact products, one rounding
    text = first_paragraph(primary)
    assert "No: in none of the 5 studies judged does it predict them better." in text
    assert "TI predicts them better for LGMD+ in the arena." in text  # the one kept
    # the uncorrected "better" (p 0.019, Holm 0.057) and "worse" verdicts are not counted
    assert (
        "For optic-flow TTC in the arena, LGMD+ on footage, looming on footage and optic-flow "
        "TTC on footage, no difference survives Holm's correction over the studies." in text
    )
    assert "Too few scenes, or units in a class, to judge unjudged on footage" in text
    assert "48 conditions in the arena" in text and "over the 5 judged studies" in text
    # the AVDM's [0.0, 0.2]: above ρ 0 in the arena, wholly below AUROC 0.5 on footage
    assert (
        "The AVDM's own interval lies wholly against the expected sign for LGMD+ on footage, "
        "looming on footage and optic-flow TTC on footage:" in text
    )

    # a "better" that survives is a yes
    flipped = primary.with_columns(
        pl.when(pl.col("detector") == "lgmd-plus-arena")
        .then(pl.lit("better"))
        .otherwise(pl.col("verdict"))
        .alias("verdict"),
    )
    assert "Yes, in 1 of the 5 studies judged (LGMD+ in the arena)." in first_paragraph(flipped)


def test_the_docs_result_section_is_regenerated_from_published_tables(quick, tmp_path) -> None:
    """--publish-findings's copy of the answer, and a doc's generated section rebuilt from it:
    equal when the doc was written from these tables, different once a table changes."""
    from analysis.experiments.power.findings import (
        BEGIN,
        END,
        PENDING,
        STUDY_TABLES,
        answer_text,
        publish,
        result_section,
        section_in,
        update_section,
    )

    out, res, _ = quick
    dest = tmp_path / "findings" / "power-quick"
    publish(out, dest, res.studies)
    made = json.loads((dest / "made_by.json").read_text())
    assert made["quick"] is True and (len(made["commit"]) == 40 or made["commit"] == "unknown")
    assert (dest / "answer.md").read_text() == (out / "answer.md").read_text()
    # answer.md is a function of the published tables: rebuilt from them, it is the run's own
    assert answer_text(dest) == (out / "answer.md").read_text()
    for st in res.studies.filter(pl.col("status") == "ran").iter_rows(named=True):
        tables = STUDY_TABLES.get(st["source"], ())
        for name in tables:  # each study's runs or clips, with their failure modes
            assert (dest / st["source"] / Path(st["folder"]).name / name).exists(), name
    assert (dest / "footage/clips/labels.csv").exists()
    assert made["plan"] == "2026-12" and made["code_key"] == json.loads(
        (out / "code.json").read_text()
    )
    doc = tmp_path / "README.md"
    doc.write_text(f"# x\n\n{BEGIN}\n{PENDING}\n{END}\n\nafter\n")
    assert update_section(doc, dest) is True
    section = section_in(doc.read_text())
    assert section == result_section(dest, doc)  # its link to answer.md relative to the doc
    assert section.startswith("**Does the AVDM predict") and "a QUICK run: not findings" in section
    assert doc.read_text().endswith(f"{END}\n\nafter\n")
    assert update_section(doc, dest) is False
    # a committed table changed after the doc was generated: the doc no longer matches
    primary = pl.read_parquet(dest / "primary.parquet")
    primary.with_columns(pl.lit("worse").alias("verdict")).write_parquet(dest / "primary.parquet")
    assert section_in(doc.read_text()) != result_section(dest, doc)


def test_the_readme_and_the_findings_index_show_the_committed_answer() -> None:
    """The README's and the findings index's result section are the committed tables' (or,
    until the amended run is committed, say it is pending: no number is invented)."""
    from analysis.experiments.power.findings import FINDINGS, PENDING, result_section, section_in

    root = Path(__file__).resolve().parents[4]  # tests/analysis/experiments/power/ to the root
    for doc in ("README.md", "docs/findings/index.md"):
        want = result_section(root / FINDINGS, root / doc)
        if not (root / FINDINGS / "primary.parquet").exists():
            assert want == PENDING
        assert section_in((root / doc).read_text(encoding="utf-8")) == want, (
            f"{doc} differs from the committed answer: run python -m "
            "analysis.experiments.power.findings"
        )


def test_the_failures_icc_over_scenes_recovers_a_known_truth() -> None:
    """ICC(1) of a one-way ANOVA on 40 scenes of 3 units with a scene effect of variance 0.3
    (total 1): its mean over 400 simulated studies is within 0.03 of 0.3 (the mean's SE is
    about 0.006; 0.03 leaves room for the estimator's small bias at 40 groups)."""
    from analysis.experiments.power.answer import icc_oneway

    rng = np.random.default_rng(5)
    groups = np.repeat(np.arange(40), 3)
    est = [
        icc_oneway(rng.normal(0, 0.3**0.5, 40)[groups] + rng.normal(0, 0.7**0.5, 120), groups)
        for _ in range(400)
    ]
    assert np.mean(est) == pytest.approx(0.3, abs=0.03)
    assert np.isnan(icc_oneway(np.ones(3), np.array([0, 0, 0])))  # one scene: no ICC
