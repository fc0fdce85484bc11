"""The README's "In Python" examples run exactly as written (in a fresh folder)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import polars as pl

from tests.helpers import ROOT


def _python_blocks() -> list[str]:
    readme = (ROOT / "README.md").read_text()
    section = readme[readme.index("## In Python") : readme.index("## Units and conventions")]
    return re.findall(r"```python\n(.*?)```", section, re.S)


def test_the_notebook_example_runs_and_gives_its_tables_and_figures(tmp_path: Path) -> None:
    blocks = _python_blocks()
    assert len(blocks) == 2
    proc = subprocess.run(
        [sys.executable, "-c", blocks[0]], cwd=tmp_path, capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stderr
    assert "1320 frames" in proc.stdout  # 40 s at 33 Hz
    assert (tmp_path / "recordings" / "nb.rrd").exists()
    assert (tmp_path / "profile_tf3.png").read_bytes()[:4] == b"\x89PNG"
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
