"""The README's "In Python" examples run exactly as written (in a fresh folder), and every shell
and Python block of the README and the guides runs as written from a clone's root."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import polars as pl
import pytest

from tests.figures import assert_figure, figure_env, saved_figures
from tests.helpers import ROOT
from tests.readme_blocks import Block, blocks, make_input, runnable


def _python_blocks() -> list[str]:
    readme = (ROOT / "README.md").read_text()
    section = readme[readme.index("## In Python") : readme.index("## Units and conventions")]
    return re.findall(r"```python\n(.*?)```", section, re.S)


def test_the_notebook_example_runs_and_gives_its_tables_and_figures(tmp_path: Path) -> None:
    blocks = _python_blocks()
    assert len(blocks) == 2
    record = tmp_path / "figures.jsonl"
    proc = subprocess.run(
        [sys.executable, "-c", blocks[0]], cwd=tmp_path, capture_output=True, text=True,
        timeout=300, env=figure_env(record),
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "1320 frames" in proc.stdout  # 40 s at 33 Hz
    assert (tmp_path / "recordings" / "nb.rrd").exists()
    figures = saved_figures(record)
    assert_figure(tmp_path / "profile_tf3.png", figures, title="responses > ", labels=("frames",))
    assert_figure(
        tmp_path / "results" / "nb-compare" / "compare.png", figures, title="distributions",
        labels=("density",),
    )  # fmt: skip
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
    readme = (ROOT / "README.md").read_text()
    section = readme[readme.index("## Your own detector") : readme.index("## Guides")]
    (block,) = re.findall(r"```python\n(.*?)```", section, re.S)
    assert block == (ROOT / "examples" / "looming.py").read_text()


# -- every block of the README and the guides (tests/readme_blocks.py says how they are run) --

_BLOCKS = blocks()


def _cases() -> list:
    cases = []
    for b in _BLOCKS:
        cases.append(pytest.param(b, None, id=b.name))
        cases += [pytest.param(b, line, id=f"{b.name}:{line[0][:40]}") for line in runnable(b)[1]]
    return cases


@pytest.fixture(scope="module")
def clone_root(tmp_path_factory) -> Path:
    """A clone's root as a user has it after the install: the examples and tests beside them, the
    package installed (here: importable from the repo, which the blocks never name)."""
    root = tmp_path_factory.mktemp("clone")
    shutil.copytree(ROOT / "examples", root / "examples")
    # the guides' write-ups render their collections with the tests' own generator
    # (`from tests.footage_clips import ...`, run from the clone's root)
    (root / "tests").symlink_to(ROOT / "tests", target_is_directory=True)
    return root


def _env(root: Path) -> dict[str, str]:
    # the package as installed: the repo on PYTHONPATH stands in for `pip install -e .`
    # (the clone's own examples/ are the copy in `root`, found from the current folder)
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "MPLBACKEND": "Agg"}
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    return env


@pytest.mark.parametrize(("block", "skipped_line"), _cases())
def test_every_block_runs_as_written(block: Block, skipped_line, clone_root: Path) -> None:
    """Each shell and Python block of README.md and docs/*.md, from a clone's root, in order
    (a block may read what an earlier one wrote); what cannot run here is reported skipped,
    by name and reason."""
    if skipped_line is not None:
        pytest.skip(f"{block.name} `{skipped_line[0]}`: {skipped_line[1]}")
    if block.mark("skip"):
        pytest.skip(f"{block.name}: {block.mark('skip')[0]}")
    if block.mark("covered"):
        (where,) = block.mark("covered")
        path, _, name = where.partition("::")
        assert f"def {name}(" in (ROOT / path).read_text(), where  # the test exists
        return
    for spec in block.mark("files"):
        for name in (n.strip() for n in spec.split(",")):
            if not (clone_root / name.rstrip("/")).exists():
                make_input(clone_root, name)
    text, _ = runnable(block)
    if block.lang == "bash":
        cmd = ["bash", "-euo", "pipefail", "-c", text]
    else:
        script = clone_root / f"block_{block.file.replace('/', '_')}_{block.line}.py"
        script.write_text(text)
        cmd = [sys.executable, script.name]  # a plain script, as a user would save it
    proc = subprocess.run(cmd, cwd=clone_root, env=_env(clone_root), capture_output=True,
                          text=True, timeout=900)  # fmt: skip
    assert proc.returncode == 0, (
        f"{block.name}:\n{text}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    )
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]


def test_every_block_is_found_and_every_mark_is_known() -> None:
    """The extraction sees the blocks (a changed fence would silently test nothing), and a
    misspelt mark fails instead of being ignored."""
    names = {b.name.split(":")[0] for b in _BLOCKS}
    assert {"README.md", "docs/boundary.md", "docs/video.md", "docs/catalog.md"} <= names
    assert sum(b.lang == "python" for b in _BLOCKS) >= 7
    for b in _BLOCKS:
        for key, _ in b.marks:
            assert key in {"skip", "skip-line", "quick", "covered", "files"}, (b.name, key)
