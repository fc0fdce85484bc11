"""The Python API as the README shows it: a single path where a list is expected, ``out=None``
writing nothing, and settings that refuse a value of the wrong type when they are built."""

from __future__ import annotations

import importlib
import os
from pathlib import Path

import polars as pl
import pytest

import vdc
from analysis.cli import COMMANDS as ANALYSE
from capture.cli import COMMANDS as CAPTURE
from vdc.settings import Settings, SettingsTypeError


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("api")
    rec = vdc.record_sim(vdc.SimSettings(tf_hz=3.0, minutes=0.1), folder / "x.rrd")
    return rec.path


def _files(folder: Path) -> set[Path]:
    return {p for p in folder.rglob("*")}


def test_a_single_path_works_where_a_list_is_expected(
    recording: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    listed = vdc.tables([recording]).summary
    # a Path (not iterable: a TypeError before) and a str (iterated letter by letter before:
    # "/abs/x.rrd" walked the file system from "/"; relative here, so the old code fails fast)
    monkeypatch.chdir(recording.parent)
    for single in (recording, recording.name):
        assert vdc.tables(single).summary.equals(listed), single
    clips = vdc.complexity(recording.name, out=tmp_path / "c").clips
    assert clips.height == 1 and clips["recording_id"][0] == listed["recording_id"][0]


def test_complexity_with_out_none_writes_nothing_and_returns_the_tables(
    recording: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    before = _files(recording.parent)
    temp = Path(os.environ.get("TMPDIR", "/tmp"))
    temp_before = {p.name for p in temp.glob("vdc-complexity-*")}
    res = vdc.complexity([recording], out=None)
    assert res.paths == [] and not list(tmp_path.iterdir())  # not even results/complexity
    assert _files(recording.parent) == before
    assert {p.name for p in temp.glob("vdc-complexity-*")} == temp_before  # removed after
    # the tables are those a written run gives
    written = vdc.complexity([recording], out=tmp_path / "w")
    assert res.table.equals(written.table) and res.clips.height == 1
    assert pl.read_parquet(tmp_path / "w" / "complexity.parquet").equals(res.table)


@pytest.mark.parametrize(
    ("make", "needle"),
    [
        (lambda: vdc.ComplexitySettings(fov_deg="60"), "ComplexitySettings.fov_deg must be"),
        (lambda: vdc.SimSettings(minutes="3"), "SimSettings.minutes must be a number"),
        (lambda: vdc.TablesSettings(threshold_dps=True), "TablesSettings.threshold_dps must be"),
        (lambda: vdc.ExecutorSettings(jobs=2.5), "ExecutorSettings.jobs must be an integer"),
        (lambda: vdc.SimSettings(seed="1"), "SimSettings.seed must be an integer"),
    ],
)
def test_settings_reject_a_wrong_type_when_built_in_one_line(make, needle: str) -> None:
    with pytest.raises(TypeError) as err:  # a TypeError to Python, a UserError to the CLIs
        make()
    assert isinstance(err.value, SettingsTypeError)
    message = str(err.value)
    assert needle in message and "\n" not in message, message


def test_settings_take_what_is_harmless_as_the_field_type() -> None:
    s = vdc.ComplexitySettings(fov_deg=60)  # an int for a float
    assert s.fov_deg == 60.0 and isinstance(s.fov_deg, float)
    sim = vdc.SimSettings(tf_hz=3)
    assert isinstance(sim.tf_hz, float)


def test_every_commands_settings_class_checks_its_types() -> None:
    for commands in (ANALYSE, CAPTURE):
        for name, cmd in commands.items():
            if not cmd.settings:
                continue
            module, cls = cmd.settings.split(":")
            assert issubclass(getattr(importlib.import_module(module), cls), Settings), name


def test_dataset_with_out_none_writes_nothing_and_returns_the_tables(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The README: ``out=None`` writes nothing, for every command function (dataset was a
    TypeError from ``Path(None)``)."""
    from analysis.dataset.synthetic import write_dataset

    root = tmp_path / "ds"
    write_dataset(root, episodes=2, codec="libx264", seconds=(1.0, 1.0), shape=(48, 64))
    work = tmp_path / "cwd"
    work.mkdir()
    monkeypatch.chdir(work)
    before = _files(root)
    settings = vdc.DatasetSettings(jobs=1, recordings=False, page=False)
    res = vdc.dataset(root, settings, out=None)
    assert res.paths == [] and not list(work.iterdir())  # not even results/dataset
    assert _files(root) == before
    assert res.episodes.height == 2 and set(res.episodes["episode_index"]) == {0, 1}


def test_complexity_of_nothing_says_so_in_one_line() -> None:
    with pytest.raises(vdc.errors.UserError, match="no sources"):
        vdc.complexity([], out=None)  # was an IndexError


def test_every_command_function_takes_out_none() -> None:
    """The README: ``out=None`` writes nothing, for every command function (most of them
    took ``out`` as a required path and failed deep inside on ``Path(None)``)."""
    import inspect

    for name in vdc.__all__:
        function = getattr(vdc, name)
        if name == "summarise":  # its out is its input, the batch's folder: None is refused
            continue
        if inspect.isfunction(function) and "out" in inspect.signature(function).parameters:
            annotation = str(inspect.signature(function).parameters["out"].annotation)
            assert "None" in annotation, (name, annotation)


def test_batch_with_out_none_writes_nothing_and_returns_the_tables(
    recording: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    before = _files(recording.parent)
    res = vdc.batch([recording], vdc.BatchSettings(models=("avdm",), jobs=1), out=None)
    assert res.paths == [] and not list(tmp_path.iterdir())
    assert _files(recording.parent) == before
    written = vdc.batch([recording], vdc.BatchSettings(models=("avdm",), jobs=1), tmp_path / "w")
    assert res.tables["summary"].equals(written.tables["summary"])
    assert res.tables["summary"].height > 0
    with pytest.raises(vdc.errors.UserError, match="summarise reads the folder"):
        vdc.summarise(None)
