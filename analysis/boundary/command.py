"""``vdc-analyse boundary``: where a detector breaks as the scene's dynamic complexity rises.

Arena mode runs a campaign over a grid (scene × wall TF × the detector's sensitivity parameter ×
seeds) of closed-loop collision runs on the executors (finished runs are reused), profiles every
condition with the AVDM and measures each run's collision performance (success rate, avoidances
and crashes per 30 min, distance to collision). Footage mode (:mod:`analysis.boundary.footage`)
does the same on a labelled collection of clips. Both give performance against complexity with
95 % intervals and **the boundary**: the complexity at which success falls below the target
(defined in :mod:`analysis.boundary.statistics`). A policy is fitted from the grid
(:func:`analysis.boundary.policy.fit_policy`) and written as ``policy.csv``.

The command reads, in order: :mod:`analysis.boundary.settings` (the settings),
:mod:`analysis.boundary.statistics` (per run and per condition, the boundary) and
:mod:`analysis.boundary.report` (``boundary.md``); this module holds the result and the end
every mode shares (the files written, the report published). The campaign that records the
arena's runs is :mod:`analysis.experiments.collision.boundary_campaign` (the command's entry,
:func:`boundary`), the footage mode :mod:`analysis.boundary.footage`.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import polars as pl

from analysis.boundary.fit_text import describe_boundary, exploratory_note
from analysis.boundary.plot import plot_boundary
from analysis.boundary.report import arena_report
from analysis.boundary.settings import BoundarySettings
from avdm.policy import Policy
from vdc.parquet_io import WroteFiles, write_tables


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
