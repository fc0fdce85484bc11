"""The Python guide's examples (docs/guides/python.md) and the plug-in of
docs/guides/your_detector.md run exactly as written (in a fresh folder), and every shell and
Python block of the README runs as written from a clone's root."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import polars as pl
import pytest

from tests.figures import assert_figure, figure_env, saved_figures
from tests.helpers import ROOT
from tests.readme_blocks import (
    GUIDE_TESTS,
    GUIDES,
    Block,
    blocks,
    clone_root_fixture,
    guide_cases,
    run_block,
)


def _python_blocks() -> list[str]:
    guide = (ROOT / "docs" / "guides" / "python.md").read_text()
    section = guide[guide.index("## The notebook API") : guide.index("## Units and conventions")]
    return re.findall(r"```python\n(.*?)```", section, re.S)


def test_the_notebook_example_runs_and_gives_its_tables_and_figures(tmp_path: Path) -> None:
    blocks = _python_blocks()
    assert len(blocks) == 2
    record = tmp_path / "figures.jsonl"
    proc = subprocess.run(
        [sys.executable, "-c", blocks[0]],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
        env=figure_env(record),
    )
    assert proc.returncode == 0, proc.stderr
    assert "1320 frames" in proc.stdout  # 40 s at 33 Hz
    assert (tmp_path / "recordings" / "nb.rrd").exists()
    figures = saved_figures(record)
    assert_figure(tmp_path / "profile_tf3.png", figures, title="responses > ", labels=("frames",))
    assert_figure(
        tmp_path / "results" / "nb-compare" / "compare.png",
        figures,
        title="distributions",
        labels=("density",),
    )
    folder = tmp_path / "results" / "nb-compare"
    written = {p.name for p in folder.iterdir() if not p.name.startswith(".")}
    assert (folder / ".vdc-outputs.json").exists()  # the manifest: what vdc wrote there
    assert written == {
        "compare_summary.parquet",
        "compare_correlations.parquet",
        "compare.png",
        "variants.rrd",
    }
    stats = pl.read_parquet(tmp_path / "results" / "nb-compare" / "compare_summary.parquet")
    assert stats["model"].to_list() == ["avdm", "avdm-on"]
    assert not (tmp_path / "results" / "tables").exists()  # out=None wrote nothing


def test_the_model_example_runs() -> None:
    proc = subprocess.run(
        [sys.executable, "-c", _python_blocks()[1]], capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    assert 160 < float(proc.stdout.split()[-1]) < 200  # ≈ 180 deg/s, as the comment says


def test_the_readme_plugin_is_the_example_the_tests_use() -> None:
    guide = (ROOT / "docs" / "guides" / "your_detector.md").read_text()
    (block,) = re.findall(r"```python\n(.*?)```", guide, re.S)
    assert block == (ROOT / "examples" / "looming.py").read_text()


# -- every block of the README (the guides' blocks: tests/test_guide_*.py, one file per guide
#    or group of guides, so that the suite's workers share them out; tests/readme_blocks.py)

_BLOCKS = blocks()
clone_root = clone_root_fixture()


@pytest.mark.parametrize(("block", "skipped_line"), guide_cases(__file__))
def test_every_block_runs_as_written(block: Block, skipped_line, clone_root: Path) -> None:
    """Each shell and Python block of README.md, from a clone's root, in order (a block may
    read what an earlier one wrote); what cannot run here is reported skipped, by name and
    reason."""
    run_block(block, skipped_line, clone_root)


def test_every_block_is_found_and_every_mark_is_known() -> None:
    """The extraction sees the blocks (a changed fence would silently test nothing), and a
    misspelt mark fails instead of being ignored."""
    names = {b.name.split(":")[0] for b in _BLOCKS}
    assert {
        "README.md",
        "docs/guides/boundary.md",
        "docs/guides/video.md",
        "docs/guides/catalog.md",
        "docs/guides/python.md",
        "docs/findings/predictors.md",
    } <= names
    assert sum(b.lang == "python" for b in _BLOCKS) >= 7
    for b in _BLOCKS:
        for key, _ in b.marks:
            assert key in {"skip", "skip-line", "quick", "covered", "same", "files"}, (b.name, key)
    # every guide's blocks are run by exactly one test file (none left out by the split)
    groups = [g for _, g in GUIDE_TESTS]
    assert sorted(g for group in groups for g in group) == sorted(GUIDES)
    for path, _ in GUIDE_TESTS:
        assert "guide_cases(__file__)" in (ROOT / path).read_text() or (
            "guide_tests(__file__)" in (ROOT / path).read_text()
        ), path
