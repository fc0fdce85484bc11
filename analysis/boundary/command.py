"""``vdc-analyse boundary``: where a detector breaks as the scene's dynamic complexity rises.

Arena mode runs a campaign over a grid (scene × wall TF × the detector's sensitivity parameter ×
seeds) of closed-loop collision runs on the executors (finished runs are reused), profiles every
condition with the AVDM and measures each run's collision performance (success rate, avoidances
and crashes per 30 min, distance to collision). Footage mode (:mod:`analysis.boundary.footage`)
does the
same on a labelled collection of clips. Both give performance against complexity with 95 %
intervals and **the boundary**: the complexity at which success falls below the target.

The boundary, per parameter value, with conditions in order of complexity: the first condition
whose success is below the target at 95 % confidence (the upper end of its interval is below
it) is the first *failing* one; the boundary lies between the condition before it and it
(``boundary_low_dps`` < boundary ≤ ``boundary_high_dps``), and the point estimate is where the
mean success crosses the target by linear interpolation inside that interval. No failing
condition: the boundary lies beyond the grid (``> boundary_low_dps``); the first condition
fails: it lies at or below the grid's least complex condition.

The complexity of a condition (``--complexity``):

* ``profile`` (default): the AVDM's mean response while the robot drives straight, in the
  profiling runs ``reproduce`` makes (ring turns, no detector), one per seed: a property of the
  scene alone, the same whichever detector is studied;
* ``online``: the mean of the on-board AVDM over the detector's own runs (all frames after the
  warm-up), the measure a learnt policy reads as it runs.

A policy is fitted from the grid (:func:`analysis.boundary.policy.fit_policy`) and written
as ``policy.csv``.

This module holds the settings, the measurements and statistics, the boundary,
the figure and the report; the campaign that records the arena's runs is
:mod:`analysis.experiments.collision.boundary_campaign` (the command's entry, :func:`boundary`), the
footage mode :mod:`analysis.boundary.footage`.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

from analysis.boundary.fit_text import describe_boundary, exploratory_note, fit_section
from analysis.boundary.plot import plot_boundary
from analysis.boundary.report_tables import interval, markdown_table
from analysis.boundary.scenes import check_scenes, draw_tfs
from analysis.collision import CollisionSettings, collision_metrics
from analysis.recordings.loading import load_recording
from analysis.stats import mean_ci, share_ci
from avdm.policy import Policy
from avdm.registry import add_overrides, parse_model_spec
from vdc.cli_support import check_below_nyquist, option
from vdc.errors import UserError
from vdc.executors import ExecutorSettings
from vdc.parquet_io import WroteFiles, write_tables
from vdc.settings import AT_LEAST_0, AT_LEAST_1, FINITE, POSITIVE, at_least, between

TARGET_HELP = "the success rate a detector must keep (default: {default}, the paper's 90 %)"
COMPLEXITY_MEASURES = ("profile", "online")
DESIGNS = ("grid", "adaptive")
ROW_VERSION = 2  # what run_row measures; a cached row of another version is measured again
WARMUP_FRAMES = 60  # the AVDM's and the running means' start-up, left out of every mean


def _with_intervals(*names: str) -> set[str]:
    return {f"{n}{end}" for n in names for end in ("", "_low", "_high")}


# vdc's own columns in the tables a boundary campaign writes (boundary*.parquet, the predictor
# tables; footage mode's clips, arena mode's runs and profiles): the parameter swept by --param
# is a column beside them, so none may share its name (a detector parameter named ``frame`` or
# ``value`` collided with one). tests/analysis/test_inputs_at_the_door.py and
# tests/analysis/boundary/test_boundary.py check that the tables written hold no column outside
# this set.
OWN_COLUMNS = frozenset(
    {"frame", "t_s", "recording_id", "model", "source", "key", "row_version", "reused", "value"}
    | {"condition", "scene", "tf_hz", "seed", "seeds", "batch", "phase", "detector", "design"}
    | {"target", "where", "bracket_dps", "boundary_low_dps", "boundary_high_dps", "fit_state"}
    | {"fit_runs", "fit_dispersion", "profile_dps", "wall_tf_hz", "adaptive", "minutes"}
    | {"avoidances", "crashes", "false_alarms", "dtc_mean_m", "turning_share", "straight_dps"}
    | {"avoidances_while_turning", "online_dps", "online_median_dps", "success_rate"}
    | {"clip", "clips", "label", "collision_frame", "hazard_onset_frame", "collision", "fps"}
    | {"frames", "alert_nan_frames", "first_alert_frame", "hit", "false_alarm", "failure"}
    | {"complexity_frames", "startup_frames_left_out", "alert", "positive", "keep", "avdm"}
    | {"avdm_natural", "measure_version", "every", "sampled_frames", "profiler", "rrd_stamp"}
    | {"measure", "statistic", "estimate", "ci_low", "ci_high", "n", "n_failing", "n_correct"}
    | {"unit", "n_units"}
    | {"p_value", "p_holm", "role", "survives", "verdict", "omega_dps", "omega_valid"}
    | {"si_p910", "ti_p910", "si_legacy", "ti_legacy", "mafd", "flow_dps", "edge_density"}
    | {"zlib_ratio", "jpeg_bpp", "codec_bpp"}
    | {"n_units"}
    | _with_intervals("boundary_dps", "boundary_tf", "success", "complexity", "hit_rate")
    | _with_intervals("avoidances_per_30min", "crashes_per_30min", "false_alarms_per_30min")
    | _with_intervals("dtc_median_m", "false_alarm_rate", "correct", "ttc_first_alert_s")
    | {"boundary_tf_hz", "complexity_dps"}
)


def _items(given: Any) -> list[str]:
    """A flag's list: a tuple of items, a comma-separated string, or both."""
    parts = [given] if isinstance(given, str | int | float) else list(given)
    return [w.strip() for p in parts for w in str(p).split(",") if w.strip()]


def number_list(text: Any, name: str, *, minimum: float = 0.0) -> list[float]:
    """``"0,1.5,3"`` or ``(0, 1.5, 3)`` → ``[0.0, 1.5, 3.0]``; ValueError naming ``--name``
    otherwise."""
    try:
        values = [float(v) for v in _items(text)]
    except ValueError:
        raise UserError(f"--{name} must be numbers separated by commas, got {text!r}") from None
    if not values or not all(math.isfinite(v) and v >= minimum for v in values):
        raise UserError(f"--{name} must be numbers >= {minimum:g}, comma-separated: {text!r}")
    if len(set(values)) != len(values):
        raise UserError(f"--{name} repeats a value: {text!r}")
    return values


def name_list(text: Any, name: str, allowed: Sequence[str]) -> list[str]:
    values = _items(text)
    bad = [v for v in values if v not in allowed]
    if not values or bad:
        raise UserError(f"--{name} must be some of {', '.join(allowed)}, got {text!r}")
    return values


def with_override(spec: str, key: str, value: float) -> str:
    """``spec`` with ``key=value`` added to its overrides."""

    return add_overrides(spec, f"{key}={value:g}")


@dataclasses.dataclass(frozen=True)
class BoundarySettings(ExecutorSettings):
    """``vdc-analyse boundary``: the detector and its sensitivity parameter, the grid, the
    target; with ``labels``, footage mode on a labelled collection instead of the arena."""

    detector: str = option(
        "lgmd-plus-arena",
        "the detector (a model with an 'alert' output: a built-in LGMD or a plug-in, "
        "package.module:factory[:key=value,...])",
    )
    param: str = option("t_ffi", "the detector's sensitivity parameter swept by the grid")
    values: tuple[float, ...] = option(
        (12.0, 20.0, 30.0, 45.0), "the parameter's values, comma-separated", range=FINITE
    )
    tf: tuple[float, ...] = option(
        (0.0, 1.0, 3.0), "arena: wall TFs, Hz, comma-separated", range=AT_LEAST_0
    )
    scenes: tuple[str, ...] = option(
        ("grating", "natural"),
        "arena: wall scenes, comma-separated (docs/guides/boundary.md#scenes)",
    )
    tf_draws: int = option(
        0,
        "arena grid: per scene, this many wall TFs drawn from --tf-range (one in each of as "
        "many equal strata, uniform in it, seeded by --seed and the scene) instead of --tf",
        range=AT_LEAST_0,
    )
    seed: int = option(1, "first random seed", range=AT_LEAST_0)
    seeds: int = option(
        5, "arena: runs per condition and value (seeds --seed, --seed+1, ...)", range=AT_LEAST_1
    )
    minutes: float = option(10.0, "arena: length of each run", range=POSITIVE)
    target: float = option(0.9, TARGET_HELP, range=between(0, 1, lo_open=True, hi_open=True))
    complexity: str = option(
        "profile",
        "arena: the complexity of a condition: profile = the AVDM's straight-driving response "
        "in profiling runs (a property of the scene); online = the on-board AVDM's mean in the "
        "detector's own runs (what a policy reads)",
        choices=COMPLEXITY_MEASURES,
    )
    false_alarm_m: float = option(
        0.30,
        "arena: an avoidance with the wall farther than this is a false alarm, m",
        range=POSITIVE,
    )
    no_fit: bool = option(False, "arena: do not fit a policy (policy.csv) from the grid")
    labels: str | None = option(
        None,
        "footage mode: a table (CSV or Parquet) of clip, label and collision_frame (empty: no "
        "collision), optionally scene (what clips share: the predictors' unit); clips relative "
        "to its folder",
        metavar="FILE",
    )
    fov_deg: float | None = option(
        None,
        "footage mode: the camera's horizontal field of view, degrees",
        range=between(1, 360),
    )
    alert_window_s: float = option(
        2.0,
        "footage mode: an alert at most this long before the collision frame is a hit, an "
        "earlier one a false alarm",
        range=POSITIVE,
    )
    min_ttc_s: float = option(
        0.5,
        "footage mode: a first alert later than this before the collision is a miss (too late "
        "to turn away), s; 0 counts an alert at the moment of impact as a hit",
        range=AT_LEAST_0,
    )
    profile_model: str = option("avdm", "arena: the AVDM variant that profiles the conditions")
    design: str = option(
        "grid",
        "arena: grid = every --tf x seed; adaptive = batches of runs along --tf-range placed "
        "where the boundary is most uncertain (analysis.experiments.collision.adaptive)",
        choices=DESIGNS,
    )
    budget: int = option(
        12, "adaptive: detector runs per parameter value at most", range=at_least(2)
    )
    tf_range: str = option("0:3", "adaptive: the wall TFs the design may visit, LO:HI Hz")
    precision: float = option(
        2.0,
        "adaptive: a value stops once its boundary's 95 % interval is narrower, deg/s",
        range=POSITIVE,
    )
    per_scene: bool = option(
        False,
        "adaptive: each scene a factor: --budget split among the scenes, each scene's runs "
        "placed along its own TF axis, a boundary (the first crossing) per scene",
    )
    groups: int | None = option(
        None,
        "footage mode: clips in N groups of similar complexity (default: up to 5 of 4)",
        range=AT_LEAST_1,
    )
    no_predictors: bool = option(
        False,
        "do not judge every complexity measure by how it predicts the failures "
        "(predictors.parquet; arena: needs --complexity profile)",
    )
    measure_every: int = option(
        8,
        "arena predictors: SI/TI, MAFD, DIS flow and zlib measured on every Nth frame pair of "
        "a profiling run (1: every pair; the error of each N: docs/method/boundary.md)",
        range=AT_LEAST_1,
    )

    def __post_init__(self) -> None:
        super().__post_init__()

        parse_model_spec(self.detector)  # a bad detector or plug-in fails before anything runs
        if self.param in OWN_COLUMNS:
            raise UserError(
                f"--param {self.param}: vdc's tables have a column {self.param!r} of their own, "
                "beside which the swept parameter is written; sweep a parameter of another "
                "name (rename it in the plug-in)"
            )
        if self.design == "adaptive" and (self.complexity != "profile" or self.labels):
            raise UserError("--design adaptive is for the arena with --complexity profile")
        if self.per_scene and self.design != "adaptive":
            raise UserError("--per-scene is for --design adaptive")
        if self.labels is None:
            check_below_nyquist(self.tf_bounds()[1], f"--tf-range {self.tf_range}")
            self.grid_values()
            check_below_nyquist(max(number_list(self.tf, "tf")), "--tf")
            self.scene_list()
            if self.per_scene and self.budget < 2 * len(self.scene_list()):
                raise UserError("--per-scene needs --budget of at least 2 runs per scene")

            CollisionSettings(false_alarm_m=self.false_alarm_m)

    def grid_values(self) -> list[float]:
        values = number_list(self.values, "values")

        for v in values:  # the parameter exists and takes these values
            parse_model_spec(with_override(self.detector, self.param, v))
        return values

    def tf_bounds(self) -> tuple[float, float]:
        """``--tf-range LO:HI`` as (LO, HI), Hz."""
        lo, _, hi = str(self.tf_range).partition(":")
        try:
            bounds = float(lo), float(hi)
        except ValueError:
            bounds = (math.nan, math.nan)
        if not (0 <= bounds[0] < bounds[1] < math.inf):
            raise UserError(f"--tf-range must be LO:HI Hz with 0 <= LO < HI, got {self.tf_range!r}")
        return bounds

    def scene_list(self) -> list[str]:
        return check_scenes(_items(self.scenes))

    def scene_tfs(self, scene: str) -> list[float]:
        """The wall TFs (Hz) of ``scene``: --tf, or --tf-draws TFs drawn from --tf-range
        (:func:`analysis.boundary.scenes.draw_tfs`)."""
        if self.tf_draws == 0:
            return number_list(self.tf, "tf")
        return draw_tfs(self.seed, scene, self.tf_draws, self.tf_bounds())

    def conditions(self) -> list[tuple[str, float]]:
        """(scene, TF) of the grid, in the order given."""
        return [(scene, tf) for scene in self.scene_list() for tf in self.scene_tfs(scene)]


def _join(values: Any) -> str:
    return ", ".join(f"{v:g}" for v in number_list(values, "values", minimum=-math.inf))


def condition_name(scene: str, tf_hz: float) -> str:
    return f"{scene}-tf{tf_hz:g}"


# --- one run measured ----------------------------------------------------------------------


def run_row(path: str | Path, kind: str, false_alarm_m: float = 0.30) -> dict[str, Any]:
    """The measurements of one recorded run. ``kind`` "collision": the collision metrics
    (``analysis.collision``) plus the on-board AVDM's mean over all frames after the warm-up
    (``online_dps``) and over straight driving (``straight_dps``); "profile": the online AVDM's
    mean over straight driving (``profile_dps``)."""

    loaded = load_recording(path)
    fr = loaded.frames.select("frame", "turning").filter(pl.col("frame") >= WARMUP_FRAMES)
    row: dict[str, Any] = {"recording_id": loaded.recording_id}
    if kind == "collision":
        metrics, _ = collision_metrics(loaded, CollisionSettings(false_alarm_m=false_alarm_m))
        row |= {k: v for k, v in metrics.items() if not k.startswith("paper_")}
        profiler = loaded.props.get("model", {}).get("name", "avdm")
    else:
        profiler = loaded.online_model or "avdm"
    omega = loaded.logged[profiler].select("frame", "omega_dps").join(fr, on="frame")
    straight = omega.filter(pl.col("turning").not_())["omega_dps"]
    if kind == "collision":
        row["online_dps"] = float(omega["omega_dps"].mean() or math.nan)
        row["online_median_dps"] = float(omega["omega_dps"].median() or math.nan)
        row["straight_dps"] = float(straight.mean()) if straight.len() else math.nan
    else:
        row["profile_dps"] = float(straight.mean()) if straight.len() else math.nan
    return row


# --- performance against complexity, and the boundary -------------------------------------


def run_statistics(runs: pl.DataFrame, by: Sequence[str]) -> pl.DataFrame:
    """One row per group of runs (``by``: e.g. condition and parameter value): the number of
    seeds, the success rate with its 95 % interval across seeds (``analysis.stats.share_ci``),
    and the means with 95 % intervals of avoidances and crashes per 30 min, false alarms per
    30 min and the median distance to collision."""
    rows = []
    for keys, g in runs.group_by(*by, maintain_order=True):
        row = dict(zip(by, keys, strict=True)) | {"seeds": g.height}
        est = share_ci(g["avoidances"].to_numpy(), (g["avoidances"] + g["crashes"]).to_numpy())
        row |= {"success_rate": est.mean, "success_low": est.low, "success_high": est.high}
        for name in (
            "avoidances_per_30min",
            "crashes_per_30min",
            "false_alarms_per_30min",
            "dtc_median_m",
        ):
            e = mean_ci(g[name].cast(pl.Float64).to_numpy(), bounds=(0.0, math.inf))
            row |= {name: e.mean, f"{name}_low": e.low, f"{name}_high": e.high}
        rows.append(row)
    return pl.DataFrame(rows)


def condition_statistics(
    runs: pl.DataFrame, complexity: pl.DataFrame, by: Sequence[str]
) -> pl.DataFrame:
    """:func:`run_statistics` per condition and parameter value (``by``), with the condition's
    complexity (from ``complexity``: condition, complexity_dps, _low, _high)."""
    return (
        run_statistics(runs, by)
        .join(complexity, on="condition", how="left")
        .sort(by[-1], "complexity_dps")
    )


def condition_complexity(rows: pl.DataFrame, column: str) -> pl.DataFrame:
    """Per condition: the mean of ``column`` across its runs with the 95 % interval."""
    out = []
    for (cond,), g in rows.group_by("condition", maintain_order=True):
        # a speed (deg/s) is not negative: the t-interval stops at 0
        e = mean_ci(g[column].cast(pl.Float64).to_numpy(), bounds=(0.0, math.inf))
        out.append(
            {
                "condition": cond,
                "complexity_dps": e.mean,
                "complexity_low": e.low,
                "complexity_high": e.high,
            }
        )
    return pl.DataFrame(out)


def find_boundary(
    complexity: Sequence[float],
    success: Sequence[float],
    success_high: Sequence[float],
    target: float,
) -> dict[str, Any]:
    """The boundary of one curve (see the module): ``boundary_dps`` (point estimate),
    ``boundary_low_dps`` < boundary ≤ ``boundary_high_dps``, and ``where``: "within" the
    grid, "beyond" its most complex condition or "below" its least complex one."""
    c = np.asarray(complexity, float)
    s = np.asarray(success, float)
    hi = np.asarray(success_high, float)
    order = np.argsort(c)
    c, s, hi = c[order], s[order], hi[order]
    # a condition with no interval (one seed) fails when its success itself is below
    failing = np.where(np.isfinite(hi), hi < target, s < target)
    if not failing.any():
        return {
            "where": "beyond",
            "boundary_dps": math.nan,
            "boundary_low_dps": float(c[-1]),
            "boundary_high_dps": math.inf,
        }
    k = int(np.argmax(failing))
    if k == 0:
        return {
            "where": "below",
            "boundary_dps": math.nan,
            "boundary_low_dps": -math.inf,
            "boundary_high_dps": float(c[0]),
        }
    c0, c1, s0, s1 = c[k - 1], c[k], s[k - 1], s[k]
    if s0 <= target or s0 == s1:
        point = c0
    else:  # where the mean success crosses the target, inside the interval
        point = c0 + (s0 - target) / (s0 - s1) * (c1 - c0)
    point = float(min(max(point, c0), c1))
    return {
        "where": "within",
        "boundary_dps": point,
        "boundary_low_dps": float(c0),
        "boundary_high_dps": float(c1),
    }


def boundaries(conditions: pl.DataFrame, by: str, target: float) -> pl.DataFrame:
    """One boundary per value of ``by`` (the parameter) from :func:`condition_statistics`."""
    rows = []
    for (value,), g in conditions.group_by(by, maintain_order=True):
        b = find_boundary(g["complexity_dps"], g["success_rate"], g["success_high"], target)
        rows.append({by: value, "target": target, **b})
    return pl.DataFrame(rows)


# --- the policy -----------------------------------------------------------------------------


# --- figures and report ---------------------------------------------------------------------


@dataclasses.dataclass
class BoundaryResult(WroteFiles):
    runs: pl.DataFrame  # one row per run (or clip, in footage mode)
    conditions: pl.DataFrame  # performance per condition and parameter value, with intervals
    boundaries: pl.DataFrame  # one row per parameter value
    policy: Policy | None
    paths: list[Path]
    markdown: str

    def report(self) -> list[str]:
        """What the command line prints: the boundary per value, then the files."""
        param = self.boundaries.columns[0]
        lines = [
            f"boundary at {param} = {r[param]:g}{', ' + r['scene'] if r.get('scene') else ''}: "
            f"{describe_boundary(r)}{exploratory_note(r)}"
            for r in self.boundaries.iter_rows(named=True)
        ]
        wanted = ("boundary.md", "boundary.png", "policy.csv")
        return [*lines, "wrote " + ", ".join(str(p) for p in self.paths if p.name in wanted)]


def published(stage: Path, out: Path, result: BoundaryResult) -> BoundaryResult:
    """The end of every boundary mode: its report last, as ``boundary.md`` into ``stage`` (the
    table set ``out``'s staging folder); ``result`` naming each file where it is published."""
    (stage / "boundary.md").write_text(result.markdown, encoding="utf-8")
    paths = [out / p.name for p in result.paths] + [out / "boundary.md"]
    return dataclasses.replace(result, paths=paths)


def write_arena_outputs(
    stage: Path,
    s: BoundarySettings,
    tables: dict[str, pl.DataFrame | None],
    policy: Any,
    title: str,
    x_label: str,
    fits: Any,
) -> tuple[list[Path], str]:
    """An arena campaign's files into ``stage`` (the grid's and the adaptive design's alike):
    ``boundary_{runs,conditions}.parquet``, ``boundary.parquet``, ``boundary_profiles.parquet``
    (``tables["profiles"]`` None: none), ``boundary.png``, ``policy.csv`` (``policy`` None:
    none); returns their paths and the report (``boundary.md``, not yet written)."""

    named = {
        "boundary_runs": tables["runs"],
        "boundary_conditions": tables["conditions"],
        "boundary": tables["bounds"],
        "boundary_profiles": tables["profiles"],
    }
    paths = write_tables(stage, named, {"settings": dataclasses.asdict(s)})
    conditions, bounds = tables["conditions"], tables["bounds"]
    paths.append(
        plot_boundary(
            conditions,
            bounds,
            s.param,
            s.target,
            stage / "boundary.png",
            title,
            x_label,
            fits=fits,
        )
    )
    if policy is not None:
        paths.append(policy.save(stage / "policy.csv"))
    return paths, arena_report(s, conditions, bounds, policy)


PER_SCENE_DESIGN = " split among the scenes, each scene placed and fitted on its own (--per-scene)"


def arena_report(
    s: BoundarySettings, conditions: pl.DataFrame, bounds: pl.DataFrame, policy: Policy | None
) -> str:
    """``boundary.md``: the boundary per value, performance per condition, the policy."""

    design = (
        f"Grid: scenes {', '.join(s.scene_list())}; wall TF {_join(s.tf)} Hz; {s.param} = "
        f"{_join(s.values)}; {s.seeds} seed(s) from {s.seed}"
        if s.design == "grid"
        else f"Adaptive design: scenes {', '.join(s.scene_list())}; wall TF {s.tf_range} Hz; "
        f"{s.param} = {_join(s.values)}; at most {s.budget} runs per value"
        f"{PER_SCENE_DESIGN if s.per_scene else ''}"
        f", stopping at a 95 % interval narrower than {s.precision:g} deg/s"
    )
    lines = [
        f"# Where {s.detector} breaks\n",
        f"{design}; {s.minutes:g}-min closed-loop runs. Target success "
        f"{100 * s.target:g} %. Complexity: {s.complexity} ({s.profile_model}). Intervals "
        "are 95 % across seeds.\n",
        "![success and energy against complexity](boundary.png)\n",
        "## The boundary\n",
        *fit_section(bounds, s.param),
    ]
    for row in bounds.iter_rows(named=True):
        scene = f", {row['scene']}" if row.get("scene") else ""  # --per-scene
        lines.append(
            f"- {s.param} = {row[s.param]:g}{scene}: {describe_boundary(row)}"
            f"{exploratory_note(row)}"  # one scene's own runs: a look, not a verdict
        )
    lines += ["", "## Performance per condition\n"]
    columns = {
        "complexity (deg/s)": ("complexity", 1.0),
        "success (%)": ("success", 100.0),
        # a success rate alone hides a detector that turns from everything
        "false alarms / 30 min": ("false_alarms_per_30min", 1.0),
        "avoidances / 30 min": ("avoidances_per_30min", 1.0),
        "crashes / 30 min": ("crashes_per_30min", 1.0),
        "median DTC (cm)": ("dtc_median_m", 100.0),
    }
    table = pl.DataFrame(
        [
            {"condition": r["condition"], s.param: r[s.param], "seeds": r["seeds"]}
            | {label: interval(r, name, scale) for label, (name, scale) in columns.items()}
            for r in conditions.iter_rows(named=True)
        ]
    )
    lines.append(markdown_table(table, table.columns))
    if policy is not None:
        lines += [
            "## The learnt policy (policy.csv)\n",
            f"{s.param} against the on-board AVDM's running {policy.statistic} over "
            f"{policy.window_s:g} s "
            f"(interpolated between rows). Use it with `--model "
            f"'{s.detector}:policy=policy.csv'`; test it on conditions it was not fitted on "
            "with `vdc-analyse adaptation`.\n",
            markdown_table(policy.table(), policy.table().columns),
        ]
    return "\n".join(lines) + "\n"
