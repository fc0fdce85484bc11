"""The same checks in every command that takes a folder or a detector (issue 37): ``batch`` and
``tables`` walk a folder as ``complexity`` does (``vdc.folders.scan_folder``: a dangling link and
vdc's own outputs skipped and said once), one unreadable recording never sinks the others, a
model that cannot run on a frame stops ``batch``/``tables --model`` before any run, and footage
mode without evidence says so in one line instead of a verdict."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from analysis.batch import BatchSettings, batch
from analysis.boundary.settings import BoundarySettings
from analysis.complexity.command import ComplexitySettings, complexity
from analysis.experiments.collision.boundary_campaign import boundary
from analysis.recordings.recompute import TablesSettings, tables
from capture.sim import SimSettings, record_sim
from tests.helpers import ROOT, assert_one_line_error, flags, module_on_path, write_video
from vdc.errors import UserError
from vdc.parquet_io import table_set

PLUGINS = """
class Raises:  # written for a wider camera: fails on the first frame
    outputs = (("level", "1"),)

    def __init__(self, gain: float = 1.0):
        self.gain = gain

    def step(self, frame):
        return {"level": float(frame[0, 500])}


class Silent:  # a detector that never alerts
    outputs = (("alert", "1"),)

    def __init__(self, gain: float = 1.0):
        self.gain = gain

    def step(self, frame):
        return {"alert": 0.0}
"""


@pytest.fixture(scope="module")
def plugins(tmp_path_factory) -> Iterator[Path]:
    yield from module_on_path(tmp_path_factory.mktemp("plugins"), "audit_plugins", PLUGINS)


@pytest.fixture(scope="module")
def collection(tmp_path_factory) -> Path:
    """A folder of two 3-s simulated runs (one of them cut at 60 %, its footer gone), a file
    that is no recording, a dangling link (a run moved away) and the outputs of an earlier
    ``compare`` written inside it (``variants.rrd`` in a published set)."""
    root = tmp_path_factory.mktemp("runs") / "runs"
    root.mkdir()
    record_sim(SimSettings(tf_hz=1.0, minutes=0.05, seed=1), root / "a.rrd")
    b = record_sim(SimSettings(tf_hz=3.0, minutes=0.05, seed=2), root / "b.rrd").path
    data = b.read_bytes()
    (root / "b_cut.rrd").write_bytes(data[: int(len(data) * 0.6)])  # a copy that stopped early
    b.unlink()
    (root / "junk.rrd").write_bytes(b"not a recording at all" * 10)
    (root / "lost.rrd").symlink_to(root.parent / "moved-away.rrd")
    with table_set(root / "res") as stage:  # an output folder as compare publishes one
        (stage / "variants.rrd").write_bytes((root / "a.rrd").read_bytes())
    return root


def _skip_note(notes: list[str]) -> str:
    lines = [n for n in notes if "skipped" in n]
    assert len(lines) == 1, notes  # one line per folder: how many and why
    return lines[0]


def test_tables_walks_a_folder_and_one_bad_file_leaves_the_others(collection: Path) -> None:
    notes: list[str] = []
    res = tables([collection], TablesSettings(), notice=notes.append)
    note = _skip_note(notes)
    assert "skipped 2 entries" in note and "1 dangling link" in note, note
    assert "1 output(s) vdc wrote itself" in note, note
    left = [n for n in notes if n.startswith("left out")]
    assert len(left) == 1 and "junk.rrd" in left[0], notes
    assert any("no footer" in n or "repaired" in n for n in notes), notes  # the cut copy
    assert res.summary["recording_id"].n_unique() == 2  # the intact run and the cut copy


def test_batch_walks_a_folder_as_complexity_does(collection: Path, tmp_path: Path) -> None:
    notes: list[str] = []
    res = batch([collection], BatchSettings(jobs=1), tmp_path / "b", log=notes.append)
    note = _skip_note(notes)
    assert "1 dangling link" in note and "1 output(s) vdc wrote itself" in note, note
    assert [t for t, _ in res.failures] == [f"{collection / 'junk.rrd'} avdm"], res.failures
    assert res.tables is not None and res.tables["summary"]["recording_id"].n_unique() == 2


def test_a_model_that_fails_on_a_frame_stops_batch_and_tables_first(
    plugins: Path, collection: Path, tmp_path: Path
) -> None:
    spec = "audit_plugins:Raises"
    with pytest.raises(ValueError, match=r"cannot run on a .* frame .*IndexError"):
        tables([collection / "a.rrd"], TablesSettings(models=[spec]))
    env = {**os.environ, "PYTHONPATH": f"{plugins}{os.pathsep}{ROOT}"}
    out = tmp_path / "b"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "analysis",
            "batch",
            str(collection / "a.rrd"),
            *flags("--jobs 1", model=spec, out=out),
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env=env,
        timeout=300,
    )
    assert_one_line_error(proc, "audit_plugins", "IndexError")
    assert not list(out.glob("parts/**/*.parquet"))  # nothing ran


def test_footage_without_evidence_is_one_line(plugins: Path, tmp_path: Path) -> None:
    clips = tmp_path / "clips"
    clips.mkdir()
    # one short clip (30 frames) of a scene panning right, on test_footage's raster (120x160
    # at 60 deg: the AVDM's calibration for it is fitted once per test session)
    scene = np.random.default_rng(3).integers(40, 200, size=(120, 220), dtype=np.uint8)
    pan = np.stack([np.roll(scene, 2 * t, 1)[:, :160] for t in range(30)])
    write_video(clips / "tiny.mp4", pan, 25.0)
    s = {"fov_deg": 60.0, "param": "gain", "values": "1", "jobs": 1, "alert_window_s": 0.2}
    # no clip labelled with a collision: nothing to score hits on, said before any run
    quiet = clips / "quiet.csv"
    quiet.write_text("clip,label,collision_frame\ntiny.mp4,background,\n")
    with pytest.raises(UserError, match=r"no clip in .* has a collision") as err:
        boundary(
            BoundarySettings(labels=str(quiet), detector="audit_plugins:Silent", **s),
            tmp_path / "q",
        )
    assert "nan" not in str(err.value) and not (tmp_path / "q").exists()
    # a detector that never alerts at any value: no boundary either
    labels = clips / "labels.csv"
    labels.write_text("clip,label,collision_frame\ntiny.mp4,collision,29\n")
    with pytest.raises(UserError, match="never alerted on any of the 1 clip") as err:
        boundary(
            BoundarySettings(labels=str(labels), detector="audit_plugins:Silent", **s),
            tmp_path / "s",
        )
    assert "nan" not in str(err.value) and not (tmp_path / "s" / "boundary.md").exists()


def test_the_catalog_names_a_dangling_link_and_serves_the_others(collection: Path) -> None:
    from analysis.catalog.query import query

    notes: list[str] = []
    q = query([collection], notice=notes.append)
    assert f"not registered: {collection / 'lost.rrd'}: a dangling link" in "\n".join(notes)
    assert any(n.startswith(f"not registered: {collection / 'junk.rrd'}") for n in notes), notes
    assert q["frames"]["recording_id"].n_unique() == 2  # the intact run and the cut copy


def test_complexity_measures_the_others_beside_a_file_that_is_no_recording(
    collection: Path, tmp_path: Path
) -> None:
    notes: list[str] = []
    s = ComplexitySettings(metrics="omega_dps", jobs=1)
    res = complexity([collection], s, tmp_path / "c", notice=notes.append)
    note = _skip_note(notes)
    assert "1 dangling link" in note and "1 output(s) vdc wrote itself" in note, note
    assert [src for src, _ in res.failures] == [str(collection / "junk.rrd")], res.failures
    assert res.clips.height == 2  # the intact run and the cut copy, each measured
