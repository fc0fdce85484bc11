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
