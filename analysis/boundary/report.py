"""The report of an arena boundary campaign: ``boundary.md`` (:func:`arena_report`: the
design, the boundary per value, performance per condition, the learnt policy)."""

from __future__ import annotations

import math
from typing import Any

import polars as pl

from analysis.boundary.fit_text import describe_boundary, exploratory_note, fit_section
from analysis.boundary.report_tables import interval, markdown_table
from analysis.boundary.settings import BoundarySettings, number_list
from avdm.policy import Policy


def _join(values: Any) -> str:
    return ", ".join(f"{v:g}" for v in number_list(values, "values", minimum=-math.inf))


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
