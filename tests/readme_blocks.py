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
* ``files: NAME, ...``: inputs the block's text names, made first (see ``make_input``).
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np

from tests.helpers import ROOT

GUIDES = ("README.md", *sorted(f"docs/{p.name}" for p in (ROOT / "docs").glob("*.md")))
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
    """Every ``bash`` and ``python`` block of the README and of docs/*.md, in order."""
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
    if block.lang != "bash" or not skips:
        return text, []
    commands = re.split(r"(?<!\\)\n", text)
    kept, skipped = [], []
    for cmd in commands:
        reason = next((r for t, r in skips if t in cmd), None)
        if reason is None:
            kept.append(cmd)
        else:
            skipped.append((cmd.split("#")[0].strip(), reason))
    for t, _ in skips:
        assert any(t in c for c, _ in skipped), f"{block.name}: skip-line {t!r} matches nothing"
    return "\n".join(kept), skipped


def make_input(root: Path, name: str) -> None:
    """An input a block names, made under ``root``: ``clip.mp4`` (a real photograph panned
    5 px per frame, H.264, 2 s), ``footage/`` (two such clips), ``my_scene.png`` (a real
    photograph), ``clips/labels.csv`` (labelled looming clips, tests/footage_clips.py)."""
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
    elif name == "clips/labels.csv":
        from tests.footage_clips import write_collection

        write_collection(root / "clips", (0, 2), (1,))
    else:
        raise AssertionError(f"no maker for the input {name!r}")
