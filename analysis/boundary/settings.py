"""The settings of ``vdc-analyse boundary`` (:class:`BoundarySettings`: the detector and its
sensitivity parameter, the grid, the target, footage mode's labels, the adaptive design) and the
helpers that read its flags (:func:`number_list`, :func:`name_list`) and name its conditions
(:func:`condition_name`, :func:`with_override`).

The complexity of a condition (``--complexity``):

* ``profile`` (default): the AVDM's mean response while the robot drives straight, in the
  profiling runs ``reproduce`` makes (ring turns, no detector), one per seed: a property of the
  scene alone, the same whichever detector is studied;
* ``online``: the mean of the on-board AVDM over the detector's own runs (all frames after the
  warm-up), the measure a learnt policy reads as it runs.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

from analysis.boundary.scenes import check_scenes, draw_tfs
from analysis.collision import CollisionSettings
from avdm.registry import add_overrides, parse_model_spec
from vdc.cli_support import check_below_nyquist, option
from vdc.errors import UserError
from vdc.executors import ExecutorSettings
from vdc.settings import AT_LEAST_0, AT_LEAST_1, FINITE, POSITIVE, at_least, between

TARGET_HELP = "the success rate a detector must keep (default: {default}, the paper's 90 %)"
COMPLEXITY_MEASURES = ("profile", "online")
DESIGNS = ("grid", "adaptive")


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
        raise UserError(f"--{name} must be numbers separated by commas, got {text!r}.") from None
    if not values or not all(math.isfinite(v) and v >= minimum for v in values):
        raise UserError(f"--{name} must be numbers >= {minimum:g}, comma-separated: {text!r}")
    if len(set(values)) != len(values):
        raise UserError(f"--{name} repeats a value: {text!r}")
    return values


def name_list(text: Any, name: str, allowed: Sequence[str]) -> list[str]:
    values = _items(text)
    bad = [v for v in values if v not in allowed]
    if not values or bad:
        raise UserError(f"--{name} must be some of {', '.join(allowed)}, got {text!r}.")
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
                "name (rename it in the plug-in)."
            )
        if self.design == "adaptive" and (self.complexity != "profile" or self.labels):
            raise UserError("--design adaptive is for the arena with --complexity profile.")
        if self.per_scene and self.design != "adaptive":
            raise UserError("--per-scene is for --design adaptive.")
        if self.labels is None:
            check_below_nyquist(self.tf_bounds()[1], f"--tf-range {self.tf_range}")
            self.grid_values()
            check_below_nyquist(max(number_list(self.tf, "tf")), "--tf")
            self.scene_list()
            if self.per_scene and self.budget < 2 * len(self.scene_list()):
                raise UserError("--per-scene needs --budget of at least 2 runs per scene.")

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
            raise UserError(
                f"--tf-range must be LO:HI Hz with 0 <= LO < HI, got {self.tf_range!r}."
            )
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


def condition_name(scene: str, tf_hz: float) -> str:
    return f"{scene}-tf{tf_hz:g}"
