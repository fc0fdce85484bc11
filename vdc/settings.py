"""The allowed ranges of settings fields, declared once with the field and checked when the
settings are built.

A numeric field states its range in its metadata (``option(0.5, "...", range=AT_LEAST_0)``;
``dataclasses.field(metadata={RANGE: between(1, 100)})`` for a field without a flag). The
command lines' parsers read the same :class:`Range` (``vdc.cli_support``), and
:func:`check_ranges` holds a dataclass built from Python to it, so ``--repeat-tol nan`` and
``DatasetSettings(repeat_tol=float("nan"))`` are refused alike, in one line naming the field
and the range. This module knows nothing of argparse: the settings layer stands apart from the
command lines.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import os
import sys
import types
import typing
from pathlib import PurePath
from typing import Any

from vdc.errors import UserError

RANGE = "range"  # the metadata key of a field's Range


class SettingsRangeError(UserError):
    """A settings field given a value outside its range (NaN and infinities included): one
    line naming the class, the field and the range; a ``ValueError`` to Python."""


@dataclasses.dataclass(frozen=True)
class Range:
    """The values a numeric field may take: finite numbers from ``lo`` to ``hi`` (None: no
    bound on that side), each bound included unless ``lo_open``/``hi_open``. A tuple field's
    range holds for each of its items; None (a field left unset) is never judged."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False

    def __contains__(self, value: object) -> bool:
        if not isinstance(value, numbers.Real) or isinstance(value, bool):
            return False
        v = float(value)
        if not math.isfinite(v):
            return False
        if self.lo is not None and (v <= self.lo if self.lo_open else v < self.lo):
            return False
        return self.hi is None or (v < self.hi if self.hi_open else v <= self.hi)

    def describe(self) -> str:
        """The range in words: ``> 0``, ``>= 1``, ``in [0, 1]``, ``in (0, 170)``, ``finite``."""
        if self.lo is None and self.hi is None:
            return "finite"
        if self.hi is None:
            return f"{'>' if self.lo_open else '>='} {self.lo:g}"
        if self.lo is None:
            return f"{'<' if self.hi_open else '<='} {self.hi:g}"
        left, right = "(" if self.lo_open else "[", ")" if self.hi_open else "]"
        return f"in {left}{self.lo:g}, {self.hi:g}{right}"

    def wanted(self, integer: bool = False) -> str:
        """What a value must be, as words: ``a number > 0``, ``an integer >= 1``, ``a finite
        number``."""
        kind = "an integer" if integer else "a number"
        if self.lo is None and self.hi is None:
            return "an integer" if integer else "a finite number"
        if self.lo == 0 and self.hi is None:
            if self.lo_open:
                return f"a positive {kind.split()[-1]}"
            if integer:
                return "a non-negative integer"
        return f"{kind} {self.describe()}"


FINITE = Range()
POSITIVE = Range(0, lo_open=True)
AT_LEAST_0 = Range(0)
AT_LEAST_1 = Range(1)
FRACTION = Range(0, 1)  # a share or a probability
MAX_SIDE_PX = 4096  # stimuli are held in memory: 4096² is ~16 MB a frame
SIDE_PX = Range(1, MAX_SIDE_PX)  # a frame's side, px


def at_least(lo: float) -> Range:
    return Range(lo)


def between(lo: float, hi: float, lo_open: bool = False, hi_open: bool = False) -> Range:
    return Range(lo, hi, lo_open, hi_open)


def field_range(field: dataclasses.Field) -> Range | None:
    """The range a field declares, or None."""
    return field.metadata.get(RANGE)


def out_of_range(value: Any, rng: Range) -> Any:
    """The first item of ``value`` (a number, or a tuple of numbers) outside ``rng``, or None
    when all are inside. Items that are not numbers are left to the type check."""
    items = value if isinstance(value, tuple | list) else (value,)
    for item in items:
        if isinstance(item, numbers.Real) and not isinstance(item, bool) and item not in rng:
            return item
    return None


def check_ranges(settings: Any) -> None:
    """Refuse (:class:`SettingsRangeError`) a settings dataclass whose field lies outside the
    range its declaration states. A float field without a declared range must still be
    finite, as its flag requires."""
    for f in dataclasses.fields(settings):
        value = getattr(settings, f.name)
        if value is None:
            continue
        rng = field_range(f)
        if rng is None:
            if not (isinstance(value, float) and not math.isfinite(value)):
                continue
            rng = FINITE
        bad = out_of_range(value, rng)
        if bad is not None:
            integer = isinstance(bad, numbers.Integral)
            raise SettingsRangeError(
                f"{type(settings).__name__}.{f.name} must be {rng.wanted(integer)}, got {bad!r}"
            )


# dataclasses.field(metadata=API_ONLY): a settings field without a flag (set from Python only,
# or through another flag); the layout test holds every other field to a flag of its name
API_ONLY = {"api_only": True}


class SettingsTypeError(UserError, TypeError):
    """A settings field given a value of another type: a ``TypeError`` to Python, a one-line
    error (exit status 2) to the command lines, naming the class and the field."""


def _field_types(cls: type) -> dict[str, Any]:
    """``{field: type}`` of a settings dataclass from its annotations (strings under ``from
    __future__ import annotations``), evaluated in the class's module; a field whose
    annotation cannot be evaluated is left out (not checked)."""
    cached = cls.__dict__.get("_vdc_field_types")
    if cached is not None:
        return cached
    found: dict[str, Any] = {}
    for klass in reversed(cls.__mro__):
        scope = vars(sys.modules.get(klass.__module__, sys))
        for name, ann in vars(klass).get("__annotations__", {}).items():
            try:
                found[name] = eval(ann, dict(scope)) if isinstance(ann, str) else ann
            except Exception:  # a name only known to type checkers: not checked
                found.pop(name, None)
    cls._vdc_field_types = found  # type: ignore[attr-defined]
    return found


_NO = object()  # "does not conform"


def _conform(value: Any, tp: Any) -> Any:
    """``value`` as a field of type ``tp`` takes it (an int for a float is a float, a Path for a
    text a str, a list for a tuple a tuple), or ``_NO``. Types it cannot judge pass."""
    origin = typing.get_origin(tp)
    if tp is Any or isinstance(tp, typing.TypeVar):
        return value
    if origin in (typing.Union, types.UnionType):
        for member in typing.get_args(tp):
            got = _conform(value, member)
            if got is not _NO:
                return got
        return _NO
    if tp is type(None):
        return value if value is None else _NO
    if origin is typing.Literal:
        return value if value in typing.get_args(tp) else _NO
    if tp is bool:
        return value if isinstance(value, bool) else _NO
    if tp is int:
        ok = isinstance(value, numbers.Integral) and not isinstance(value, bool)
        return int(value) if ok else _NO
    if tp is float:
        ok = isinstance(value, numbers.Real) and not isinstance(value, bool)
        return float(value) if ok else _NO
    if tp is str:
        if isinstance(value, str):
            return value
        return os.fspath(value) if isinstance(value, os.PathLike) else _NO
    if isinstance(tp, type) and issubclass(tp, PurePath):
        return tp(value) if isinstance(value, (str, os.PathLike)) else _NO
    if tp is tuple or origin is tuple:
        if isinstance(value, str):  # a comma-separated list, as its flag takes it: the class's
            return value  # own check parses it ("12,30" -> (12.0, 30.0)) and names what is wrong
        return tuple(value) if isinstance(value, (tuple, list)) else _NO
    if isinstance(origin, type):
        return value if isinstance(value, origin) else _NO
    if isinstance(tp, type) and tp.__module__ != "typing":
        return value if isinstance(value, tp) else _NO
    return value  # a Callable, a Protocol, ...: not judged here


def _type_name(tp: Any) -> str:
    names = {
        bool: "true or false",
        int: "an integer",
        float: "a number",
        str: "text",
        type(None): "None",
    }
    return names.get(tp, getattr(tp, "__name__", None) or str(tp).replace("typing.", ""))


def check_field_types(settings: Any) -> None:
    """Refuse (:class:`SettingsTypeError`, one line naming the field) a settings dataclass
    whose fields hold values of other types than their annotations say, and normalise the
    harmless differences (an int for a float, a Path for a str, a list for a tuple)."""
    cls = type(settings)
    types_ = _field_types(cls)
    for f in dataclasses.fields(settings):
        if f.name not in types_:
            continue
        value = getattr(settings, f.name)
        got = _conform(value, types_[f.name])
        if got is _NO:
            tp = types_[f.name]
            members = typing.get_args(tp) if typing.get_origin(tp) is not None else ()
            want = " or ".join(_type_name(m) for m in members) if members else _type_name(tp)
            if typing.get_origin(tp) in (tuple, list):
                want = _type_name(typing.get_origin(tp))
            raise SettingsTypeError(
                f"{cls.__name__}.{f.name} must be {want}, got {value!r} ({type(value).__name__})"
            )
        if got is not value:
            object.__setattr__(settings, f.name, got)


class Settings:
    """The base of every command's settings dataclass: a value of another type than a field's
    annotation or outside its declared range (:mod:`vdc.settings`) is refused when the settings
    are built, in one line naming the field (``ComplexitySettings(fov_deg="60")``), rather
    than failing deep inside a run.

    A subclass's own ``__post_init__`` (its range checks) runs after the type check, with no
    call to make: :meth:`__init_subclass__` wraps it."""

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        own = cls.__dict__.get("__post_init__")
        if own is None or getattr(own, "_checks_types", False):
            return

        def post_init(self: Any, *args: Any) -> None:
            check_field_types(self)
            check_ranges(self)
            own(self, *args)

        post_init._checks_types = True  # type: ignore[attr-defined]
        post_init.__doc__ = own.__doc__
        cls.__post_init__ = post_init  # type: ignore[attr-defined]

    def __post_init__(self) -> None:
        check_field_types(self)
        check_ranges(self)
