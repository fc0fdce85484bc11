"""``vdc-analyse adaptation``: a learnt policy tested where it was not learnt.

The policy (``policy.csv`` from ``vdc-analyse boundary``, a grid or an adaptive campaign) sets
the detector's parameter from the on-board AVDM's running mean as the robot drives. It is run
in closed loop on held-out conditions (wall TFs and scenes the fit did not have, and a TF
schedule that changes in the middle of a run) beside three controllers:

* ``fixed``: the detector as it is (its default parameters);
* ``hand``: the paper's hand-adjusted threshold (``--hand``, e.g. ``t_ffi=30``);
* ``adaptive``: vdc's hand-made complexity-adaptive rule, T_ffi = max(T_ffi0, gain × mean ω̂)
  (lgmd-plus kinds only);
* ``policy``: the detector with ``policy=FILE``.

Every controller sees the same seeds (the same starting poses and turn draws), so differences
are paired by seed. Per condition and controller: success, avoidances and crashes per 30 min
with 95 % intervals; per condition and comparison (policy against each other controller): the
paired differences with 95 % intervals and a verdict computed from them:

* **better**: the policy keeps the target (mean success ≥ target) and the other does not; or
  both keep it and the policy avoids less (the difference's interval is above 0); or neither
  keeps it and the policy succeeds more (that difference's interval is above 0);
* **worse**: the mirror image;
* **no difference**: neither, at 95 %.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl
from matplotlib.figure import Figure

from analysis.boundary.report_tables import interval, markdown_table
from analysis.boundary.settings import condition_name, name_list, number_list
from analysis.boundary.statistics import condition_complexity, condition_statistics
from analysis.experiments.captures import RunItem, check_detectors
from analysis.experiments.collision.adaptive import in_fitted_range
from analysis.experiments.collision.boundary_campaign import run_grid
from analysis.stats import mean_ci
from avdm.policy import load_policy
from avdm.registry import add_overrides, parse_model_spec
from capture.config import CollisionConfig, parse_schedule
from capture.sim import SimSettings
from vdc.cli_support import option
from vdc.errors import UserError
from vdc.executors import QUIET, ExecutorSettings, Feedback, one_pool
from vdc.parquet_io import WroteFiles, table_set, write_tables
from vdc.scratch import no_files_without_out
from vdc.settings import AT_LEAST_0, AT_LEAST_1, POSITIVE, between

CONTROLLERS = ("fixed", "hand", "adaptive", "policy")
BETTER, WORSE, SAME = "better", "worse", "no difference"


@dataclasses.dataclass(frozen=True)
class AdaptationSettings(ExecutorSettings):
    """``vdc-analyse adaptation``: the policy, the held-out conditions, the controllers it is
    compared with."""

    policy: str | None = option(
        None, "the policy file (policy.csv of vdc-analyse boundary)", metavar="FILE", required=True
    )
    detector: str = option("lgmd-plus-arena", "the detector the policy was fitted for")
    tf: tuple[float, ...] = option(
        (2.0,), "held-out wall TFs, Hz, comma-separated", range=AT_LEAST_0
    )
    scenes: tuple[str, ...] = option(
        ("grating", "natural"), "a scene of the held-out TFs (repeat the flag for several)"
    )
    schedule: str = option(
        "0:5m,3:5m",
        "a TF schedule that changes mid-run (grating walls), TF:DURATION,...; by default "
        "{default}; empty: none",
    )
    hand: str = option("t_ffi=30", "the paper's hand-adjusted threshold: detector overrides")
    adaptive_gain: float = option(1.0, "the hand-made adaptive rule's gain", range=POSITIVE)
    seed: int = option(101, "first random seed (other than the grid's)", range=AT_LEAST_0)
    seeds: int = option(5, "runs per condition and controller", range=AT_LEAST_1)
    minutes: float = option(10.0, "length of each run at a constant TF", range=POSITIVE)
    target: float = option(
        0.9, "the success rate to keep", range=between(0, 1, lo_open=True, hi_open=True)
    )
    false_alarm_m: float = option(0.30, "false-alarm distance, m", range=POSITIVE)

    def __post_init__(self) -> None:
        super().__post_init__()

        if not self.policy:
            raise UserError("give the policy to test: --policy FILE (from vdc-analyse boundary).")
        load_policy(self.policy)  # a bad policy file fails before anything runs
        parse_model_spec(self.policy_spec())
        parse_model_spec(self.hand_spec())
        self.conditions()

    def policy_spec(self) -> str:
        return add_overrides(self.detector, f"policy={Path(self.policy).resolve()}")

    def hand_spec(self) -> str:
        return add_overrides(self.detector, self.hand) if self.hand else self.detector

    def adaptive_allowed(self) -> bool:
        return CollisionConfig(detector=self.detector).base_detector == "lgmd-plus"

    def conditions(self) -> list[tuple[str, str, float | None, str | None]]:
        """(condition, scene, TF, schedule) of every held-out condition."""
        out: list[tuple[str, str, float | None, str | None]] = [
            (condition_name(scene, tf), scene, tf, None)
            for scene in name_list(self.scenes, "scenes", ("grating", "natural"))
            for tf in number_list(self.tf, "tf")
        ]
        if self.schedule:
            parse_schedule(self.schedule)
            out.append(
                (
                    "grating-schedule",
                    "grating",
                    None,
                    self.schedule,
                )
            )
        if not out:
            raise UserError("no held-out condition: give --tf and --scenes or --schedule.")
        return out


def adaptation_items(s: AdaptationSettings, folder: Path) -> list[RunItem]:
    """One closed-loop run per (condition, controller, seed)."""

    controllers = [c for c in CONTROLLERS if c != "adaptive" or s.adaptive_allowed()]
    specs = {
        "fixed": s.detector,
        "hand": s.hand_spec(),
        "adaptive": s.detector,
        "policy": s.policy_spec(),
    }
    items = []
    for cond, scene, tf, schedule in s.conditions():
        for ctrl in controllers:
            for seed in range(s.seed, s.seed + s.seeds):
                settings = SimSettings(
                    behaviour="collision",
                    model=specs[ctrl],
                    scene=scene,
                    tf_hz=tf if tf is not None else 0.0,
                    tf_schedule=schedule,
                    minutes=None if schedule else s.minutes,
                    seed=seed,
                    phase=f"{cond}-{ctrl}",
                    adaptive=ctrl == "adaptive",
                    adaptive_gain=s.adaptive_gain,
                )
                cols = {"condition": cond, "controller": ctrl, "seed": seed}
                path = folder / cond / ctrl / f"seed{seed}.rrd"
                items.append(RunItem(f"{cond}-{ctrl}-seed{seed}", settings, path, cols))
    return items


def compare_to(runs: pl.DataFrame, cond: str, other: str, target: float) -> dict[str, Any]:
    """The policy against ``other`` on one condition, paired by seed (see the module)."""
    g = runs.filter(pl.col("condition") == cond)
    a = g.filter(pl.col("controller") == "policy").select(
        "seed", "success_rate", "avoidances_per_30min"
    )
    b = g.filter(pl.col("controller") == other).select(
        "seed", "success_rate", "avoidances_per_30min"
    )
    pair = a.join(b, on="seed", suffix="_other")
    d_s = mean_ci((pair["success_rate"] - pair["success_rate_other"]).to_numpy())
    d_a = mean_ci((pair["avoidances_per_30min_other"] - pair["avoidances_per_30min"]).to_numpy())
    keeps_p = float(np.nanmean(pair["success_rate"].to_numpy())) >= target
    keeps_o = float(np.nanmean(pair["success_rate_other"].to_numpy())) >= target
    fewer = math.isfinite(d_a.low) and d_a.low > 0
    more = math.isfinite(d_a.high) and d_a.high < 0
    safer = math.isfinite(d_s.low) and d_s.low > 0
    riskier = math.isfinite(d_s.high) and d_s.high < 0
    if keeps_p != keeps_o:  # one keeps the target and the other does not
        verdict = BETTER if keeps_p else WORSE
    elif keeps_p:  # both keep it: fewer avoidances (turns) is better
        verdict = BETTER if fewer else WORSE if more else SAME
    else:  # neither keeps it: more success is better
        verdict = BETTER if safer else WORSE if riskier else SAME
    return {
        "condition": cond,
        "against": other,
        "seeds": pair.height,
        "success_diff": d_s.mean,
        "success_diff_low": d_s.low,
        "success_diff_high": d_s.high,
        "avoidances_saved_per_30min": d_a.mean,
        "avoidances_saved_per_30min_low": d_a.low,
        "avoidances_saved_per_30min_high": d_a.high,
        "policy_keeps_target": keeps_p,
        "other_keeps_target": keeps_o,
        "verdict": verdict,
    }


@dataclasses.dataclass
class AdaptationResult(WroteFiles):
    runs: pl.DataFrame  # one row per (condition, controller, seed)
    conditions: pl.DataFrame  # per condition and controller, with 95 % intervals
    comparisons: pl.DataFrame  # the policy against each controller, per condition
    verdict: str  # one sentence, computed from the comparisons
    notices: list[str]
    paths: list[Path]
    markdown: str

    def report(self) -> list[str]:
        """What the command line prints: the report, the verdict, the files."""
        wanted = ("adaptation.md", "adaptation.png")
        wrote = ", ".join(str(p) for p in self.paths if p.name in wanted)
        return [self.markdown, f"verdict: {self.verdict}", f"wrote {wrote}"]


@no_files_without_out
@one_pool()  # its stages share one pool of workers
def adaptation(
    s: AdaptationSettings, out: str | Path | None, feedback: Feedback = QUIET
) -> AdaptationResult:
    """Run the held-out conditions with every controller; write ``adaptation.md``,
    ``adaptation.png`` and the Parquet tables into ``out``."""

    out = Path(out)
    policy = load_policy(s.policy)
    fitted = set()
    if policy.evidence is not None and "condition" in policy.evidence.columns:
        fitted = set(policy.evidence["condition"].to_list())

    notices = [
        f"{cond} was in the policy's fit: it is not held out"
        for cond, scene, tf, _ in s.conditions()
        if cond in fitted or in_fitted_range(scene, tf, fitted)  # a grid's or a TF range's
    ]
    for n in notices:
        feedback.log(f"note: {n}")
    items = adaptation_items(s, out / "recordings")

    check_detectors(it.settings.to_config() for it in items)  # one line before any run
    feedback.log(f"adaptation: {len(s.conditions())} held-out condition(s), {len(items)} run(s).")
    runs = run_grid(items, "collision", s, s.false_alarm_m, feedback)
    complexity = condition_complexity(runs, "online_dps")
    conditions = condition_statistics(runs, complexity, ["condition", "controller"])
    others = [c for c in runs["controller"].unique(maintain_order=True) if c != "policy"]
    comparisons = pl.DataFrame(
        [compare_to(runs, cond, other, s.target) for cond, *_ in s.conditions() for other in others]
    )
    verdict = overall_verdict(conditions, comparisons, s.target)
    named = {
        "adaptation_runs": runs,
        "adaptation_conditions": conditions,
        "adaptation_comparisons": comparisons,
    }
    with table_set(out) as stage:
        paths = write_tables(stage, named, {"settings": dataclasses.asdict(s)})
        paths.append(plot_adaptation(conditions, s.target, stage / "adaptation.png"))
        md = adaptation_report(s, conditions, comparisons, verdict, notices)
        (stage / "adaptation.md").write_text(md, encoding="utf-8")
        paths.append(stage / "adaptation.md")
    paths = [out / p.name for p in paths]
    return AdaptationResult(runs, conditions, comparisons, verdict, notices, paths, md)


def overall_verdict(conditions: pl.DataFrame, comparisons: pl.DataFrame, target: float) -> str:
    """One sentence from the numbers: where the policy keeps the target, and how its
    comparisons came out."""
    pol = conditions.filter(pl.col("controller") == "policy")
    keeps = pol.filter(pl.col("success_rate") >= target).height
    sure = pol.filter(pl.col("success_low") >= target).height
    parts = [
        f"the policy keeps success >= {100 * target:g} % on {keeps} of {pol.height} held-out "
        f"condition(s) ({sure} at 95 % confidence)"
    ]
    for (other,), g in comparisons.group_by("against", maintain_order=True):
        counts = {v: g.filter(pl.col("verdict") == v).height for v in (BETTER, WORSE, SAME)}
        parts.append(
            f"against {other}: better on {counts[BETTER]}, worse on {counts[WORSE]}, no "
            f"difference at 95 % on {counts[SAME]}"
        )
    return "; ".join(parts) + "."


def plot_adaptation(conditions: pl.DataFrame, target: float, path: Path) -> Path:
    """Success and avoidances per 30 min per held-out condition, one bar per controller, 95 %
    intervals as error bars."""
    conds = conditions["condition"].unique(maintain_order=True).to_list()
    ctrls = [c for c in CONTROLLERS if c in set(conditions["controller"].to_list())]
    fig = Figure(figsize=(13, 5), layout="constrained")
    axes = fig.subplots(1, 2)
    width = 0.8 / len(ctrls)
    x = np.arange(len(conds))
    for ax, (name, scale, label) in zip(
        axes,
        (("success", 100.0, "success (%)"), ("avoidances_per_30min", 1.0, "avoidances per 30 min")),
        strict=True,
    ):
        for i, ctrl in enumerate(ctrls):
            g = conditions.filter(pl.col("controller") == ctrl)
            by = {r["condition"]: r for r in g.iter_rows(named=True)}
            mean_key = "success_rate" if name == "success" else name
            m = np.array([by[c][mean_key] * scale if c in by else np.nan for c in conds])
            lo = np.array([by[c][f"{name}_low"] * scale if c in by else np.nan for c in conds])
            hi = np.array([by[c][f"{name}_high"] * scale if c in by else np.nan for c in conds])
            err = np.nan_to_num(np.clip(np.vstack([m - lo, hi - m]), 0, None))
            ax.bar(
                x + (i - (len(ctrls) - 1) / 2) * width,
                m,
                width,
                yerr=err,
                capsize=3,
                label=ctrl,
                color=f"C{i}",
            )
        ax.set_xticks(x, conds, rotation=10)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3, axis="y")
        ax.legend(fontsize=8)
    axes[0].axhline(100 * target, color="k", ls=":", lw=1)
    axes[0].set_ylim(0, 105)
    fig.suptitle("held-out conditions: the learnt policy against the other controllers")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    return path


def adaptation_report(
    s: AdaptationSettings,
    conditions: pl.DataFrame,
    comparisons: pl.DataFrame,
    verdict: str,
    notices: list[str],
) -> str:
    """``adaptation.md``."""
    lines = [
        "# The learnt policy on conditions it was not fitted on\n",
        f"Policy `{s.policy}` on {s.detector}; controllers: fixed (as is), hand ({s.hand}), "
        f"adaptive (gain {s.adaptive_gain:g}), policy. {s.seeds} seed(s) from {s.seed}; "
        f"{s.minutes:g}-min runs (the schedule: its own length). Target success "
        f"{100 * s.target:g} %. Intervals are 95 % across seeds, differences paired by seed.\n",
        f"**Verdict:** {verdict}\n",
        *(f"> Note: {n}\n" for n in notices),
        "![held-out conditions](adaptation.png)\n",
        "## Per condition and controller\n",
    ]
    table = pl.DataFrame(
        [
            {
                "condition": r["condition"],
                "controller": r["controller"],
                "seeds": r["seeds"],
                "online complexity (deg/s)": interval(r, "complexity"),
                "success (%)": interval(r, "success", 100.0),
                "avoidances / 30 min": interval(r, "avoidances_per_30min"),
                "crashes / 30 min": interval(r, "crashes_per_30min"),
            }
            for r in conditions.iter_rows(named=True)
        ]
    )
    lines += [markdown_table(table, table.columns), "## The policy against each controller\n"]
    table = pl.DataFrame(
        [
            {
                "condition": r["condition"],
                "against": r["against"],
                "success difference (points)": interval(r, "success_diff", 100.0),
                "avoidances saved / 30 min": interval(r, "avoidances_saved_per_30min"),
                "verdict": r["verdict"],
            }
            for r in comparisons.iter_rows(named=True)
        ]
    )
    lines.append(markdown_table(table, table.columns))
    return "\n".join(lines) + "\n"
