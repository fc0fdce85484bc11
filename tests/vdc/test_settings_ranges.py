"""Every command's numeric settings are held to one range, declared with the field
(:mod:`vdc.settings`): a settings object built from Python refuses a value outside it (NaN
included) in one line naming the class, the field and the range, and the field's flag refuses
the same value. Before, ``DatasetSettings(repeat_tol=nan)`` was taken (no frame was then a
repeat) while ``--repeat-tol nan`` was refused, and ``DatasetSettings(fov_deg=-5)`` was taken
and every episode then failed naming its video."""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import math
import typing
from collections.abc import Iterator

import pytest

import vdc
from analysis.experiments.collision.looming_footage import LoomingFootageSettings
from tests.helpers import assert_one_line_error
from tests.in_process import run_in_process
from vdc.cli_support import _parser_type, parse_size
from vdc.errors import UserError
from vdc.settings import Range, Settings, SettingsRangeError, _field_types, field_range


def _settings_classes() -> list[type]:
    """The settings of every command of both command lines, and the classes they build on."""
    from analysis import cli as analysis_cli
    from capture import cli as capture_cli
    from vdc.cli_support import load_settings_class

    for cli in (analysis_cli, capture_cli):
        for command in cli.COMMANDS.values():
            if command.settings:
                load_settings_class(command.settings)

    def below(cls: type) -> Iterator[type]:
        for sub in cls.__subclasses__():
            yield sub
            yield from below(sub)

    return sorted(set(below(Settings)), key=lambda c: (c.__module__, c.__name__))


def _outside(rng: Range, integer: bool) -> list[float]:
    """Values just outside ``rng`` (and NaN and infinity for a float field)."""
    step = 1 if integer else 0.5
    bad: list[float] = [] if integer else [math.nan, math.inf]
    if rng.lo is not None:
        bad.append(rng.lo if rng.lo_open else rng.lo - step)
    if rng.hi is not None:
        bad.append(rng.hi if rng.hi_open else rng.hi + step)
    return [int(b) if integer and math.isfinite(b) else float(b) for b in bad]


def _inside(rng: Range, integer: bool) -> float:
    lo = rng.lo if rng.lo is not None else 0
    value = lo + 1 if rng.lo_open or integer else lo
    if rng.hi is not None:
        value = min(value, (lo + rng.hi) / 2)
    return int(value) if integer else float(value)


def _is_int(cls: type, name: str) -> bool:
    tp = _field_types(cls)[name]
    return tp is int or int in typing.get_args(tp) or typing.get_args(tp)[:1] == (int,)


def _required(cls: type) -> dict:
    """Values for the fields without a default (a source, a port, a policy file...)."""
    given = {}
    for f in dataclasses.fields(cls):
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
            rng = field_range(f)
            given[f.name] = _inside(rng, _is_int(cls, f.name)) if rng else "x"
    return given


# each field on the class that declares it (an inherited field is the same declaration)
CASES = [
    pytest.param(cls, f, id=f"{cls.__name__}.{f.name}")
    for cls in _settings_classes()
    for f in dataclasses.fields(cls)
    if f.name in inspect.get_annotations(cls) and field_range(f) is not None
]


def test_every_command_declares_ranges() -> None:
    """The table covers the commands' numeric fields (not one command's alone)."""
    classes = {c.values[0].__name__ for c in CASES}
    for name in (
        "DatasetSettings",
        "ComplexitySettings",
        "LoomingFootageSettings",
        "BoundarySettings",
        "SimSettings",
        "VideoSettings",
        "ExecutorSettings",
        "SweepSettings",
        "SummarySettings",
        "ProfileSettings",
    ):
        assert name in classes, name
    numeric_without = [
        f"{cls.__name__}.{f.name}"
        for cls in _settings_classes()
        for f in dataclasses.fields(cls)
        if str(_field_types(cls).get(f.name)).startswith(("<class 'int'>", "<class 'float'>"))
        and field_range(f) is None
        and f.name not in ("port", "web_port")  # the catalog's ports: another task's
    ]
    assert numeric_without == [], numeric_without


@pytest.mark.parametrize(("cls", "field"), CASES)
def test_a_value_outside_the_declared_range_is_refused_when_built_and_by_its_flag(
    cls: type, field: dataclasses.Field
) -> None:
    rng = field_range(field)
    integer = _is_int(cls, field.name)
    is_tuple = str(field.type).startswith("tuple")
    base = _required(cls)
    for bad in _outside(rng, integer):
        value = (bad, bad) if is_tuple else bad
        with pytest.raises(SettingsRangeError) as err:
            cls(**{**base, field.name: value})
        message = str(err.value)
        assert f"{cls.__name__}.{field.name}" in message and rng.wanted(integer) in message, message
        assert "\n" not in message
        flag = field.metadata.get("flag")
        if flag is not None and not flag.positional:  # the command line: the same range
            parse = _parser_type(field, flag)
            text = f"{bad},{bad}" if is_tuple else str(bad)
            if flag.type is parse_size:  # WIDTHxHEIGHT
                text = f"{bad}x{bad}"
            with pytest.raises(argparse.ArgumentTypeError):
                parse(text)


@pytest.mark.parametrize(
    ("make", "needles"),
    [
        (lambda: vdc.DatasetSettings(repeat_tol=math.nan), ["repeat_tol", ">= 0", "nan"]),
        (lambda: vdc.DatasetSettings(fov_deg=-5), ["fov_deg", "[1, 360]", "-5"]),
        (lambda: vdc.ComplexitySettings(repeat_tol=-1), ["repeat_tol", ">= 0"]),
        (lambda: vdc.BoundarySettings(values=(12.0, math.inf)), ["values", "finite"]),
        (lambda: vdc.ExecutorSettings(jobs=0), ["jobs", ">= 1"]),
    ],
)
def test_the_reported_cases_are_refused_in_one_line(make, needles: list[str]) -> None:
    with pytest.raises(ValueError) as err:  # a UserError: one line at the command line
        make()
    assert isinstance(err.value, UserError)
    for needle in needles:
        assert needle in str(err.value), (needle, str(err.value))


def test_values_inside_the_ranges_are_taken() -> None:  # the control: the bounds are not tight
    assert vdc.DatasetSettings(repeat_tol=0.0, fov_deg=1.0, max_repeats=0).fov_deg == 1.0
    assert LoomingFootageSettings(clips=1).clips == 1


def test_looming_footage_refuses_no_clips_in_one_line(tmp_path) -> None:
    proc = run_in_process(
        "analysis", "looming-footage", "--clips", "0", "--out", str(tmp_path / "o")
    )
    assert_one_line_error(proc, "--clips", ">= 1")
    assert not (tmp_path / "o").exists()
    with pytest.raises(SettingsRangeError, match=r"LoomingFootageSettings\.clips"):
        LoomingFootageSettings(clips=0)
