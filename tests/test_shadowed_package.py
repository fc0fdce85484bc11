"""A folder named ``vdc`` beside a user's script hides the package (issue 43, item 7): what the
user then runs names that folder instead of failing with ``module 'vdc' has no attribute ...``.

Each case is a real ``python script.py`` in a temporary folder, as a user runs it: Python puts
the script's folder first on its path, which is what makes the folder win."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.helpers import ROOT, assert_one_line_error


def _run_script(
    folder: Path, source: str, *, pythonpath: bool = True
) -> subprocess.CompletedProcess:
    (folder / "script.py").write_text(source)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    if pythonpath:  # this checkout, as the suite runs it (the shared venv may point elsewhere)
        env["PYTHONPATH"] = str(ROOT)
    return subprocess.run(
        [sys.executable, "script.py"],
        cwd=folder,
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
    )


@pytest.mark.parametrize(
    "statement", ["from capture.sim import SimSettings", "import analysis.complexity"]
)
def test_a_vdc_folder_with_init_beside_the_script_is_named(tmp_path: Path, statement: str) -> None:
    (tmp_path / "vdc").mkdir()
    (tmp_path / "vdc" / "__init__.py").write_text("# the user's own vdc\n")
    proc = _run_script(tmp_path, f"{statement}\n")
    assert proc.returncode != 0
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("ImportError: 'import vdc' found "), proc.stderr
    assert str(tmp_path / "vdc") in last and str(ROOT / "vdc") in last, last
    assert "rename it" in last


# setuptools' own editable finder (what ``pip install -e .`` installs when it does not just put
# the project folder on the path): it comes after Python's path finder, so a namespace ``vdc/``
# (no __init__.py) beside the script wins ``import vdc``, while ``vdc.launch`` etc. still load
# from the project. The repository itself is taken off the path, so only the finder knows it.
_EDITABLE = """
import sys, types
from pathlib import Path
from setuptools.command.editable_wheel import _finder_template

root = {root!r}
sys.path[:] = [p for p in sys.path if not (Path(p or ".") / "vdc" / "__init__.py").exists()
               or Path(p or ".").resolve() == Path.cwd().resolve()]
finder = types.ModuleType("editable_finder")
mapping = {{name: str(Path(root, name)) for name in ("vdc", "avdm", "capture", "analysis")}}
exec(_finder_template("visual-dynamic-complexity", mapping, {{}}), finder.__dict__)
finder.install()
"""


def test_a_namespace_vdc_folder_is_named_by_the_console_script(tmp_path: Path) -> None:
    (tmp_path / "vdc").mkdir()  # no __init__.py: a namespace package
    proc = _run_script(
        tmp_path,
        _EDITABLE.format(root=str(ROOT))
        + "import vdc\nassert vdc.__file__ is None, vdc.__path__  # the folder did win\n"
        + "sys.argv = ['vdc-analyse', '--help']\n"
        + "from vdc.launch import analyse\nsys.exit(analyse())\n",
        pythonpath=False,
    )
    assert_one_line_error(proc, "vdc-analyse: 'import vdc' found", str(tmp_path / "vdc"))
    assert "usage" not in proc.stdout


def test_a_namespace_vdc_folder_is_named_by_capture(tmp_path: Path) -> None:
    (tmp_path / "vdc").mkdir()
    proc = _run_script(
        tmp_path,
        _EDITABLE.format(root=str(ROOT)) + "from capture.sim import SimSettings\n",
        pythonpath=False,
    )
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("ImportError: 'import vdc' found "), proc.stderr
    assert str(tmp_path / "vdc") in last, last


def test_without_a_shadow_the_console_script_runs(tmp_path: Path) -> None:
    # the check must not refuse the real package (run from an empty folder, same set-up)
    proc = _run_script(
        tmp_path,
        _EDITABLE.format(root=str(ROOT))
        + "sys.argv = ['vdc-analyse', '--help']\n"
        + "from vdc.launch import analyse\nsys.exit(analyse())\n",
        pythonpath=False,
    )
    assert proc.returncode == 0, proc.stderr
    assert "usage: vdc-analyse" in proc.stdout
