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

from tests.helpers import ROOT, assert_one_line_error, run_text


def _run_script(
    folder: Path, source: str, *, pythonpath: bool = True
) -> subprocess.CompletedProcess:
    (folder / "script.py").write_text(source)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    if pythonpath:  # this checkout, as the suite runs it (the shared venv may point elsewhere)
        env["PYTHONPATH"] = str(ROOT)
    return run_text([sys.executable, "script.py"], cwd=folder, env=env, timeout=120)


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


def test_an_editable_install_beats_an_empty_vdc_folder_beside_the_script(tmp_path: Path) -> None:
    """The README's install (``pip install -e .``) for real, into a new virtual environment, of
    a copy of this project: an empty ``vdc/`` folder (a namespace package, say a folder of
    results) beside a plain script loses to the installed package, so ``vdc.record_sim`` is
    found. (A ``vdc/`` folder *with* ``__init__.py`` is a package Python must prefer before any
    vdc code runs; ``capture``, ``analysis`` and the console scripts name it, above.)"""
    # nothing of this checkout's path: pip would take its egg-info for vdc already installed
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    copy = tmp_path / "project"
    subprocess.run(["git", "clone", "-q", str(ROOT), str(copy)], check=True, timeout=120)
    # the working tree's pyproject, which the clone of the last commit may not have yet
    (copy / "pyproject.toml").write_text((ROOT / "pyproject.toml").read_text())
    # the editable wheel pip would build (PEP 660), by the build system the test extras bring,
    # so nothing is downloaded; installed without dependencies: `import vdc` loads none of them
    build = "import setuptools.build_meta as b, sys; print(b.build_editable(sys.argv[1]))"
    wheel = subprocess.run(
        [sys.executable, "-c", build, str(tmp_path / "dist")],
        cwd=copy,
        check=True,
        capture_output=True,
        text=True,
        timeout=300,
    ).stdout.split()[-1]
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    subprocess.run(
        [venv / "bin" / "pip", "install", "-q", "--no-deps", tmp_path / "dist" / wheel],
        check=True,
        capture_output=True,
        timeout=300,
        env=env,
    )
    # the dependencies: this environment's, after the project on the new one's path
    purelib = "import sysconfig; print(sysconfig.get_paths()['purelib'])"
    ours, theirs = (
        subprocess.run([py, "-c", purelib], capture_output=True, text=True).stdout.strip()
        for py in (sys.executable, venv / "bin" / "python")
    )
    (Path(theirs) / "zz_dependencies.pth").write_text(ours + "\n")
    assert list(Path(theirs).glob("__editable__.visual_dynamic_complexity-*.pth"))  # installed
    user = tmp_path / "user"
    (user / "vdc").mkdir(parents=True)
    (user / "script.py").write_text(
        "import vdc\nprint(vdc.__file__)\nprint(vdc.record_sim)\n"
        "import capture\nprint(capture.__file__)\n"
    )
    proc = run_text([venv / "bin" / "python", "script.py"], cwd=user, env=env, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    file, record_sim, capture_file = proc.stdout.splitlines()
    assert Path(file) == copy / "vdc" / "__init__.py"
    assert "record_sim" in record_sim
    assert Path(capture_file) == copy / "capture" / "__init__.py"
