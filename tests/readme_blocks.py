"""The shell and Python blocks of the README and the guides, as a test runs them.

A block runs as written, from a clone's root (a copy of its ``examples/``; the package
installed, not the folder on the path), unless the HTML comments just above its fence (one
``<!-- readme-test: KEY: VALUE -->`` per line, invisible on GitHub) say otherwise:

* ``skip: REASON``: the whole block needs what a test cannot have (a robot, a display, a
  cluster, an install); it is reported skipped with that reason.
* ``skip-line: TEXT => REASON``: the lines containing ``TEXT`` are left out, each reported
  skipped with its reason (a robot's port, a viewer window).
* ``quick: OLD => NEW``: ``OLD`` replaced by ``NEW`` before it runs (short runs; the guides
  say which durations are quick).
* ``covered: TEST``: run by that test, which checks what it prints and writes.
* ``same: TEXT => GUIDE``: the lines containing ``TEXT`` are, once both blocks' ``quick``
  substitutions are made, the very command a block of ``GUIDE`` runs (the same words, spaces
  and comments aside); they are left out here, and each one's case checks that ``GUIDE`` runs
  it (not skipped, covered or left out there). The same command twice in one suite asserts
  nothing new (exit 0, no traceback) and costs its whole run again.
* ``files: NAME, ...``: inputs the block's text names, made first (see ``make_input``).
"""

from __future__ import annotations

import dataclasses
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.helpers import ROOT

GUIDES = (
    "README.md",
    *sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / "docs").rglob("*.md")),
)
# Which test file runs which guides' blocks. The suite's workers take whole files
# (``--dist loadfile``), so the longest guides get a file each and the workers share them
# out; a block may read what an earlier block of its own guide wrote, never another's.
_OWN_FILE = {
    "tests/test_readme_python.py": ("README.md",),
    "tests/test_guide_boundary.py": ("docs/guides/boundary.md", "docs/findings/predictors.md"),
    "tests/test_guide_video.py": ("docs/guides/video.md",),
    "tests/test_guide_commands.py": ("docs/guides/commands.md",),
}
GUIDE_TESTS: tuple[tuple[str, tuple[str, ...]], ...] = (
    *_OWN_FILE.items(),
    (
        "tests/test_guides.py",
        tuple(g for g in GUIDES if all(g not in own for own in _OWN_FILE.values())),
    ),
)
GUIDE_TESTS_BY_FILE = dict(GUIDE_TESTS)
_FENCE = re.compile(r"^```(bash|python)\n(.*?)^```$", re.S | re.M)
_MARK = re.compile(r"<!-- readme-test: ([a-z-]+): (.*?) -->")


@dataclasses.dataclass(frozen=True)
class Block:
    file: str  # relative to the repo root
    line: int  # the fence's line, 1-based
    lang: str  # bash | python
    text: str
    marks: tuple[tuple[str, str], ...]

    @property
    def name(self) -> str:
        return f"{self.file}:{self.line}"

    def mark(self, key: str) -> list[str]:
        return [v for k, v in self.marks if k == key]


def blocks() -> list[Block]:
    """Every ``bash`` and ``python`` block of the README and of docs/ (its sub-folders too:
    guides/, method/, findings/), in order."""
    found = []
    for file in GUIDES:
        text = (ROOT / file).read_text()
        for m in _FENCE.finditer(text):
            before = text[: m.start()].splitlines()
            marks = []
            while before and _MARK.fullmatch(before[-1].strip()):
                marks.insert(0, _MARK.fullmatch(before.pop().strip()).groups())  # type: ignore[union-attr]
            line = text.count("\n", 0, m.start()) + 1
            found.append(Block(file, line, m.group(1), m.group(2), tuple(marks)))
    return found


def runnable(block: Block) -> tuple[str, list[tuple[str, str]]]:
    """The text to run (quick substitutions made, skipped lines left out) and the skipped
    lines with their reasons. A shell command continued with ``\\`` counts as one line."""
    text = block.text
    for sub in block.mark("quick"):
        old, _, new = sub.partition(" => ")
        assert old in text, f"{block.name}: quick {old!r} is not in the block"
        text = text.replace(old, new)
    skips = [tuple(s.split(" => ", 1)) for s in block.mark("skip-line")]
    skips += [(t, f"{SAME}{g}") for t, _, g in (s.partition(" => ") for s in block.mark("same"))]
    if block.lang != "bash" or not skips:
        return text, []
    kept, skipped = [], []
    for cmd in commands(text):
        reason = next((r for t, r in skips if t in cmd), None)
        if reason is None:
            kept.append(cmd)
        else:
            skipped.append((cmd.split("#")[0].strip(), reason))
    for t, _ in skips:
        assert any(t in c for c in commands(text)), f"{block.name}: {t!r} matches no line"
    return "\n".join(kept), skipped


SAME = "run by "  # the reason of a line a ``same`` mark leaves out, before the guide's name


def commands(text: str) -> list[str]:
    """A shell block's commands, one per item (a line continued with ``\\`` is one)."""
    return re.split(r"(?<!\\)\n", text)


def command_words(cmd: str) -> str:
    """A command as its words: continuations joined, the comment and extra spaces dropped."""
    return " ".join(cmd.replace("\\\n", " ").split("#")[0].split())


def assert_run_elsewhere(block: Block, cmd: str, guide: str) -> None:
    """``cmd`` (a line ``block``'s ``same`` mark leaves out) is run as is by a block of
    ``guide``: one that runs (no ``skip``, no ``covered``) and keeps that line."""
    want = command_words(cmd)
    for other in blocks():
        if other.file != guide or other.lang != "bash" or other.name == block.name:
            continue
        if other.mark("skip") or other.mark("covered"):
            continue
        if want in {command_words(c) for c in commands(runnable(other)[0])}:
            return
    raise AssertionError(f"{block.name}: `{want}` is run by no block of {guide}")


def make_input(root: Path, name: str) -> None:
    """An input a block names, made under ``root``: ``clip.mp4`` (a real photograph panned
    5 px per frame, H.264, 2 s), ``footage/`` (two such clips), ``my_scene.png`` (a real
    photograph), ``clips/labels.csv`` (labelled looming clips, tests/footage_clips.py),
    ``recordings/`` (two short simulated runs, natural and grating walls, seed 1)."""
    from tests.helpers import write_pan

    if name == "clip.mp4":
        write_pan(root / name, 160, 120, 50)
    elif name == "footage/":
        (root / "footage").mkdir()
        for k, step in enumerate((3, 6)):
            write_pan(root / "footage" / f"pan{k}.mp4", 160, 120, 50, step_px=step)
    elif name == "my_scene.png":
        import cv2
        from skimage import data

        cv2.imwrite(str(root / name), np.ascontiguousarray(data.coffee()[:, :, ::-1]))
    elif name == "recordings/":  # two short simulated runs, one over each kind of wall
        for scene in ("natural", "grating"):
            cmd = ["vdc-capture", "sim", "--scene", scene, "--tf-hz", "3", "--minutes", "0.05"]
            subprocess.run([*cmd, "--seed", "1", "--quiet"], cwd=root, env=_env(), check=True)
    elif name == "clips/labels.csv":
        from tests.footage_clips import write_collection

        write_collection(root / "clips", (0, 2), (1,))
    else:
        raise AssertionError(f"no maker for the input {name!r}")


def guide_cases(test_file: str) -> list:
    """pytest params ``(block, skipped_line)`` for every block of the guides ``test_file`` (a
    test module's ``__file__``) runs, per ``GUIDE_TESTS``: the block itself, then one skipped
    case per line its marks leave out."""
    files = GUIDE_TESTS_BY_FILE[Path(test_file).resolve().relative_to(ROOT).as_posix()]
    cases = []
    for b in (b for b in blocks() if b.file in files):
        cases.append(pytest.param(b, None, id=b.name))
        cases += [pytest.param(b, line, id=f"{b.name}:{line[0][:40]}") for line in runnable(b)[1]]
    return cases


def guide_tests(test_file: str) -> tuple:
    """``(clone_root, test_every_block_runs_as_written)`` for a test module (its ``__file__``)
    that runs the blocks of its guides (``GUIDE_TESTS``), each from a clone's root, in order:
    a block may read what an earlier one of the same guide wrote."""

    @pytest.mark.parametrize(("block", "skipped_line"), guide_cases(test_file))
    def test_every_block_runs_as_written(block: Block, skipped_line, clone_root: Path) -> None:
        run_block(block, skipped_line, clone_root)

    return clone_root_fixture(), test_every_block_runs_as_written


def clone_root_fixture():
    """A module fixture: a clone's root as a user has it after the install."""

    @pytest.fixture(scope="module")
    def clone_root(tmp_path_factory) -> Path:
        """The examples and tests beside them, the package installed (here: importable from
        the repo, which the blocks never name)."""
        root = tmp_path_factory.mktemp("clone")
        shutil.copytree(ROOT / "examples", root / "examples")
        # the guides' write-ups render their collections with the tests' own generator
        # (`from tests.footage_clips import ...`, run from the clone's root)
        (root / "tests").symlink_to(ROOT / "tests", target_is_directory=True)
        return root

    return clone_root


def _env() -> dict[str, str]:
    # the package as installed: the repo on PYTHONPATH stands in for `pip install -e .`
    # (the clone's own examples/ are the copy in the clone, found from the current folder)
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "MPLBACKEND": "Agg"}
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    return env


def run_block(block: Block, skipped_line: tuple[str, str] | None, clone_root: Path) -> None:
    """Run one block as written from ``clone_root`` (or report it skipped, by name and
    reason); fails on a non-zero exit or a traceback."""
    if skipped_line is not None and skipped_line[1].startswith(SAME):
        assert_run_elsewhere(block, skipped_line[0], skipped_line[1].removeprefix(SAME))
        return  # run there, as it is written here
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
    proc = subprocess.run(
        cmd, cwd=clone_root, env=_env(), capture_output=True, text=True, timeout=900
    )
    assert proc.returncode == 0, (
        f"{block.name}:\n{text}\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    )
    assert "Traceback" not in proc.stderr, proc.stderr[-3000:]
