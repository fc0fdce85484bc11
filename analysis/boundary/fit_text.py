"""What a fitted boundary says in words: one line per fit for the terminal and the report,
the notes on what the interval took as its unit, and the report's section
(:func:`fit_section`). The fit itself is :mod:`analysis.boundary.fit`."""

from __future__ import annotations

import math
from typing import Any

import polars as pl

from analysis.boundary.fit import UNDETERMINED


def describe_fit(row: dict[str, Any]) -> str:
    """The fitted boundary as a phrase: "9.1 deg/s [7.9, 10.4] (wall TF 0.42 Hz [0.2, 0.7])",
    "beyond the design's range (95 %: > 28.6 deg/s)" or "undetermined: more seeds or runs
    needed (95 %: > 6.0 deg/s)"."""
    state = row["fit_state"]
    dps = _span(row["boundary_dps_low"], row["boundary_dps_high"], "deg/s", 1)
    tf = _span(row.get("boundary_tf_low", math.nan), row.get("boundary_tf_high", math.nan), "Hz", 2)
    if state == "within":
        text = f"{row['boundary_dps']:.1f} deg/s [{dps}]"
        if _finite(row.get("boundary_tf_hz")):
            text += f" (wall TF {row['boundary_tf_hz']:.2f} Hz [{tf}])"
        return text
    interval_text = f"95 %: {dps}" + (f"; wall TF {tf}" if tf else "")
    if state == "beyond":
        return f"beyond the design's range ({interval_text})"
    if state == "below":
        return f"below the design's least complex point ({interval_text})"
    return f"{UNDETERMINED} ({interval_text})"


def _finite(v: Any) -> bool:
    return v is not None and isinstance(v, float | int) and math.isfinite(v)


def _span(low: Any, high: Any, unit: str, digits: int) -> str:
    if _finite(low) and low < 0 and unit != "Hz":  # a speed (deg/s) is not negative
        low = 0.0
    lo_ok, hi_ok = _finite(low), _finite(high)
    if hi_ok and high <= 0 and not lo_ok and unit != "Hz":
        return f"fails even at 0 {unit}"
    if lo_ok and hi_ok:
        return f"{low:.{digits}f}, {high:.{digits}f} {unit}"
    if lo_ok:
        return f"> {low:.{digits}f} {unit}"
    if hi_ok:
        return f"< {high:.{digits}f} {unit}"
    return "unbounded" if unit == "deg/s" else ""


def describe_fitted(row: dict[str, Any]) -> str:
    """A boundary row with the fitted columns: the fitted phrase (:func:`describe_fit`) and,
    for a grid (or footage's groups of clips), the conditions it lies between."""
    text = describe_fit(row)
    if row.get("design") not in ("grid", "groups"):
        return text
    where = row.get("where")
    if where == "within":
        grid = (
            f"between the conditions at {row['boundary_low_dps']:.1f} and "
            f"{row['boundary_high_dps']:.1f} deg/s"
        )
    elif where == "below":
        grid = "the least complex condition already fails"
    else:
        grid = "no condition fails at 95 %"
    return f"{text}; {row['design']}: {grid}"


def describe_boundary(row: dict[str, Any]) -> str:
    """One boundary as a phrase: "31.2 deg/s (between 20.5 and 35.0)"; a row with the fitted
    columns (``analysis.boundary.fit``) as the fitted boundary with its 95 % interval; never a
    number that is not one (a phrase with "nan" in it is no verdict)."""
    if "fit_state" in row:
        return describe_fitted(row)
    needed = {"beyond": ["boundary_low_dps"], "below": ["boundary_high_dps"]}.get(
        row["where"], ["boundary_dps", "boundary_low_dps", "boundary_high_dps"]
    )
    if not all(_finite(row.get(k)) for k in needed):
        return "not placed: the complexity of its conditions could not be measured"
    if row["where"] == "beyond":
        return f"beyond the grid (> {row['boundary_low_dps']:.1f} deg/s)"
    if row["where"] == "below":
        return f"at or below the least complex condition (<= {row['boundary_high_dps']:.1f} deg/s)"
    return (
        f"{row['boundary_dps']:.1f} deg/s (between {row['boundary_low_dps']:.1f} and "
        f"{row['boundary_high_dps']:.1f})"
    )


FIT_NOTE = (
    "The boundary is where a monotone logistic curve of success against complexity, fitted "
    "to every run (binomial counts), crosses the target; its 95 % interval is the "
    "profile-likelihood interval, widened by what varies: over 2 or more scenes, the scene is "
    "the unit (conditions of one scene share its departure from the curve): the spread of the "
    "crossing with each scene left out, never less than the conditions' overdispersion, with "
    "F quantiles on scenes − 1 degrees of freedom (2 scenes: 1, so a wide interval); within "
    "one scene, the conditions' overdispersion on conditions − 2. Its ends are interpolated "
    "(`analysis/boundary/fit.py`); the table's *unit* says which, with their number. "
    "*Undetermined*: the runs cannot place it (the interval is unbounded); *beyond the "
    "design's range* only where success is above the target at 95 % confidence everywhere on it."
)


PER_SCENE_NOTE = (
    " Per scene (`--per-scene`): each scene's runs alone, up to its first clearly failing run "
    "(the boundary is the *first* crossing along that scene's TF axis), wall TF through that "
    "scene's profile. **Exploratory**: each row is one scene's boundary, from its own runs "
    "(the n in the table), its interval over its own conditions; it says nothing of another "
    "scene's, and many rows read together are many looks."
)


def exploratory_note(row: dict[str, Any]) -> str:
    """For a ``--per-scene`` row (one scene's boundary): " (exploratory: this scene's 7 runs
    alone)"; "" for any other row."""
    if not row.get("scene") or "fit_runs" not in row:
        return ""
    return f" (exploratory: this scene's {row['fit_runs']} runs alone)"


def _unit_cell(r: dict[str, Any]) -> str:
    """The interval's unit and how many: "2 scenes", "6 conditions" (— for older tables)."""
    if not r.get("unit") or r.get("n_units") is None:
        return "—"
    return f"{r['n_units']} {r['unit']}{'s' if r['n_units'] != 1 else ''}"


def fit_section(bounds: pl.DataFrame, by: str) -> list[str]:
    """``boundary.md``'s table of the fitted boundaries (deg/s and wall TF, 95 %)."""
    if "fit_state" not in bounds.columns:
        return []
    scene = "scene" in bounds.columns  # --per-scene: a row per (value, scene)

    def scene_cell(r: dict[str, Any]) -> str:
        return f" {r['scene']} |" if scene else ""

    head = (
        f"| {by} |{' scene |' if scene else ''} state | boundary (deg/s) | 95 % | wall TF (Hz) "
        "| 95 % | runs | unit |"
    )
    lines = [FIT_NOTE + (PER_SCENE_NOTE if scene else ""), "", head]
    lines.append("|---|---|---|---|---|---|---|---|" + ("---|" if scene else ""))
    for r in bounds.iter_rows(named=True):
        dps = _span(r["boundary_dps_low"], r["boundary_dps_high"], "", 1).strip() or "—"
        tf = _span(r["boundary_tf_low"], r["boundary_tf_high"], "", 2).strip() or "—"
        # a point estimate only where the interval is bounded: an undetermined boundary's
        # best fit can lie anywhere along a flat likelihood, even past the design's range
        placed = r["fit_state"] == "within"
        point = f"{r['boundary_dps']:.1f}" if placed and _finite(r["boundary_dps"]) else "—"
        tf_point = f"{r['boundary_tf_hz']:.2f}" if placed and _finite(r["boundary_tf_hz"]) else "—"
        lines.append(
            f"| {r[by]:g} |{scene_cell(r)} {r['fit_state']} | {point} | {dps} | {tf_point} | "
            f"{tf} | {r['fit_runs']} | {_unit_cell(r)} |"
        )
    return [*lines, ""]
