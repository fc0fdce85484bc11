"""The amended plan's answer as committed (docs/findings/power-2026-12/): its answer.md, its
primary table and its counts hold to the run and clip tables committed beside them, so a number
in the README can be traced to the units that made it."""

from __future__ import annotations

import json
from pathlib import Path

import polars as pl
import pytest

from analysis.experiments.power.answer import primary_row
from analysis.experiments.power.findings import FINDINGS, answer_text
from analysis.experiments.power.units import arena_units

ROOT = Path(__file__).resolve().parents[4]  # tests/analysis/experiments/power/ to the root
COMMITTED = ROOT / FINDINGS


def _studies() -> list[tuple[dict, Path]]:
    """Each study that ran, with its folder inside the committed findings."""
    studies = pl.read_parquet(COMMITTED / "studies.parquet")
    return [
        (st, COMMITTED / st["source"] / Path(st["folder"]).name)
        for st in studies.iter_rows(named=True)
        if st["status"] == "ran"
    ]


def test_the_committed_answer_md_is_the_one_its_tables_give() -> None:
    """answer.md is rebuilt from the committed tables by this code: a changed wording or table
    fails here until `python -m analysis.experiments.power.findings` rewrites it."""
    assert (COMMITTED / "answer.md").read_text(encoding="utf-8") == answer_text(COMMITTED)


def test_the_committed_run_met_the_amended_plans_size() -> None:
    """The amendment's minimum: at least 20 arena scenes and 20 background photographs, the
    full plan (not --quick), with the code that made it named."""
    made = json.loads((COMMITTED / "made_by.json").read_text())
    assert made["quick"] is False and made["plan"] == "2026-12"
    assert len(made["commit"]) == 40 and made["code_key"]["code"]
    arena = [f for st, f in _studies() if st["source"] == "arena"]
    assert arena and all(
        pl.read_parquet(f / "boundary_runs.parquet")["scene"].n_unique() >= 20 for f in arena
    )
    labels = pl.read_csv(COMMITTED / "footage/clips/labels.csv")
    assert labels["background"].n_unique() >= 20 and labels.height >= 480


def test_each_studys_counts_are_its_committed_units() -> None:
    """n, n_failing and the scenes of each primary row are counted again from the committed run
    (arena: conditions from boundary_runs and predictor_measures) or clip tables (footage: the
    failure mode of each clip, its photograph from labels.csv)."""
    primary = pl.read_parquet(COMMITTED / "primary.parquet")
    labels = pl.read_csv(COMMITTED / "footage/clips/labels.csv").select("clip", "scene")
    checked = 0
    for st, folder in _studies():
        if st["detector"] == "looming-footage":  # the clips themselves, no detector
            continue
        row = primary.filter(
            (pl.col("source") == st["source"]) & (pl.col("detector") == st["detector"])
        ).row(0, named=True)
        if st["source"] == "arena":
            units = arena_units(folder)
            failing = int(units["failing"].sum())
        else:
            units = pl.read_parquet(folder / "boundary_clips.parquet").join(labels, on="clip")
            assert set(units["failure"]) <= {"hit", "quiet", "miss", "early", "false_alarm"}
            failing = units.filter(~pl.col("correct")).height
            # a clip fails by a named mode, and only then
            assert (
                units.filter(~pl.col("correct"))["failure"]
                .is_in(["miss", "early", "false_alarm"])
                .all()
            )
        assert (row["n"], row["n_failing"], row["n_correct"]) == (
            units.height,
            failing,
            units.height - failing,
        ), st["detector"]
        assert row["n_units"] == units["scene"].n_unique() and row["unit"] == "scene"
        checked += 1
    assert checked == 5


@pytest.mark.parametrize("source", ["arena", "footage"])
def test_the_primary_rows_come_from_the_committed_statistics(source: str) -> None:
    """Each primary row is read again from its study's committed predictors.parquet by this
    code: the same estimates, intervals, p and verdict (read, not refitted: exact)."""
    primary = pl.read_parquet(COMMITTED / "primary.parquet")
    for st, folder in _studies():
        if st["source"] != source or st["detector"] == "looming-footage":
            continue
        again = primary_row(st, pl.read_parquet(folder / "predictors.parquet"))
        row = primary.filter(
            (pl.col("source") == source) & (pl.col("detector") == st["detector"])
        ).row(0, named=True)
        assert {k: row[k] for k in again} == again, st["detector"]


def test_refreshing_the_committed_findings_changes_no_text(tmp_path: Path) -> None:
    """`python -m analysis.experiments.power.findings` (refresh) on a copy of the committed
    findings and docs rewrites nothing: they are what the tables give; and after a table
    changes it rewrites answer.md and both docs."""
    import shutil

    from analysis.experiments.power.findings import refresh

    folder = tmp_path / "docs/findings/power-2026-12"
    shutil.copytree(COMMITTED, folder)
    docs = []
    for doc in ("README.md", "docs/findings/index.md"):
        (tmp_path / doc).parent.mkdir(parents=True, exist_ok=True)
        docs.append(Path(shutil.copy(ROOT / doc, tmp_path / doc)))
    assert refresh(folder, tuple(docs)) == []
    assert (folder / "per_scene.png").stat().st_size > 10_000  # drawn again
    primary = pl.read_parquet(folder / "primary.parquet")
    primary.with_columns(pl.lit(0.2).alias("p_holm_across")).write_parquet(
        folder / "primary.parquet"
    )
    assert refresh(folder, tuple(docs)) == [folder / "answer.md", *docs]
