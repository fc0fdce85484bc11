"""The units a predictor table's intervals are over, and the rules of its verdicts (issue 57):
:mod:`analysis.predictors.statistics` computes the rows, this module says what they may claim.

* :class:`Units`: the scenes where the conditions or clips share them (at least two named),
  else the conditions or clips, taken as independent (:func:`table_note` says so in one line);
* :func:`judge`: no verdict below the power thresholds (:data:`MIN_CONDITIONS` conditions in
  the arena, over :data:`MIN_SCENES` scenes where they share them; :data:`MIN_SCENES` scenes
  and :data:`MIN_FAILURES` units of each class on footage),
  the primary comparison at 5 %, the rest Holm-corrected; "better" or "worse" only where the
  winner predicts failure beyond chance itself; "both against the expected sign" where both
  measures are inverted (less inverted is not better).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import polars as pl

from analysis.predictors.inference import holm
from analysis.stats import ALPHA

# Below these no comparison gets a verdict ("too few to judge"): the units that give 80 %
# power at two-sided 5 % for the effects the question is about
# (docs/findings/power_plan.md, "How many conditions and clips"). Arena: two dependent
# Spearman rho of 0.71 and 0.31 (the default
# grid's TI and AVDM) whose measures correlate 0.7 need 24 independent units (Steiger's test;
# 47 at 0.3): 24 scenes where conditions share them. Footage: an AUROC difference of 0.10
# between measures correlated 0.6 needs 46 failing clips, and as many that do not fail
# (Hanley & McNeil; 94 at 0.3), and, clips that share scenes, at least MIN_SCENES scenes: with
# fewer clusters even a clustered test over-rejects (8 scenes: 9-12 % at a nominal 5 %;
# Cameron & Miller 2015 put reliable inference at 20-50 clusters, with t on G - 1 df).
# In the arena, conditions clustered on scenes need MIN_SCENES scenes (the clustered test's
# validity, as on footage) and MIN_CONDITIONS conditions (docs/findings/
# power_plan_amendment.md): the scenes carry G m / (1 + (m - 1) ICC) independent units
# (analysis.experiments.power.sizes.design_effect), at least G, so 24 scenes were enough at any ICC;
# the amended plan's 23 scenes of 3 TFs carry the 37 its comparison needs up to ICC 0.43,
# and its answer reports the ICC it met.
MIN_CONDITIONS = 24
MIN_SCENES = 20
MIN_FAILURES = 46


@dataclasses.dataclass(frozen=True)
class Units:
    """What a table's intervals resample or cluster on: ``unit`` (``scene`` where the units
    share scenes, else ``condition`` or ``clip``, taken as independent), the cluster label of
    each unit (None: every unit its own), the units' name (``counted``: conditions, clips) and
    what :func:`table_note` says where they are taken as independent."""

    unit: str
    cluster: np.ndarray | None
    counted: str
    size: int  # the units (conditions, clips)

    def n_units(self, ok: np.ndarray | None = None) -> int:
        """The clusters (or units) among the units ``ok`` (bool, all by default)."""
        if self.cluster is None:
            return self.size if ok is None else int(ok.sum())
        return len(np.unique(self.cluster if ok is None else self.cluster[ok]))

    @property
    def clusters(self) -> int | None:
        """K for a clustered interval (None: units independent)."""
        return None if self.cluster is None else self.n_units()


def units_of(scene: Sequence[Any] | None, counted: str, size: int) -> Units:
    """The units of one table: clustered on ``scene`` (per unit) where every unit names one
    and there are at least 2; else the units (``counted``: ``conditions`` or ``clips``) taken
    as independent (:func:`table_note` says so)."""
    if scene is not None:
        labels = [None if s is None else str(s) for s in scene]
        if None not in labels and len(set(labels)) >= 2:
            return Units("scene", np.asarray(labels, str), counted, len(labels))
    return Units(counted.removesuffix("s"), None, counted, size)


def table_note(table: pl.DataFrame) -> str | None:
    """The one line a predictor table says where its units are taken as independent (its
    ``unit`` is not ``scene``: no scene named, or all units in one); None where they are
    clustered on scenes. Printed by the commands and written in the reports."""
    units = set(table["unit"].drop_nulls().to_list()) if table.height else set()
    if not units or units == {"scene"}:
        return None
    counted = "conditions" if "condition" in units else "clips"
    where = "the runs name" if counted == "conditions" else "the labels name"
    return (
        f"{counted.capitalize()} taken as independent: {where} no scene (the photograph, "
        f"place or session {counted} share), or one; where {counted} share a scene, their "
        "intervals are too narrow and their verdicts too many."
    )


# --- verdicts ----------------------------------------------------------------------------------


def chance(statistic: str) -> float:
    """A statistic's value when the measure knows nothing of failure: ρ 0, an AUROC 0.5."""
    return 0.0 if statistic.startswith("rho") else 0.5


def too_few(r: dict[str, Any], mode: str) -> str | None:
    """Why a comparison row gets no verdict for lack of units, or None: fewer independent units
    than :data:`MIN_CONDITIONS` (arena) or :data:`MIN_SCENES` (footage), or, on footage, a
    smaller class than :data:`MIN_FAILURES` (named as the smaller class)."""
    unit = r["unit"]
    need = MIN_CONDITIONS if mode == "arena" and unit != "scene" else MIN_SCENES
    short: list[tuple[str, str]] = []  # (what there is, what is needed)
    if r["n_units"] < need:
        short.append((f"{r['n_units']} {unit}{'s' if r['n_units'] != 1 else ''}", f"{need}"))
    elif mode == "arena" and unit == "scene" and (r["n"] or 0) < MIN_CONDITIONS:
        short.append((f"{r['n']} conditions", f"{MIN_CONDITIONS} conditions"))
    if mode == "footage":
        fail, ok = r["n_failing"] or 0, r["n_correct"] or 0
        smaller, k = ("failing", fail) if fail <= ok else ("correct", ok)
        if k < MIN_FAILURES:
            what = f"{k} {smaller} {r['counted']} (the smaller class)"
            short.append((what, f"{MIN_FAILURES} of each class"))
    if not short:
        return None
    if len(short) == 2:
        short[0] = (short[0][0], f"{need} {unit}s")
    have = " and ".join(h for h, _ in short)
    return f"{have}: too few to judge ({' and '.join(n for _, n in short)} needed)"


def judge(rows: list[dict[str, Any]], mode: str) -> list[dict[str, Any]]:
    """Verdicts (the module's rules): comparison rows (a ``role``) with too few units
    (:func:`too_few`) get no verdict; the primary comparison is judged at 5 %; the rest by
    Holm's adjusted p over the whole table (every value of the parameter), each saying whether
    it survives. "better" (the AVDM's statistic higher) or "worse" needs the winner to predict
    failure beyond chance itself, in the expected direction (its own interval clear of
    chance); two measures both against the expected sign are "both against the expected
    sign", never one better for being less inverted."""
    own = {(r["statistic"], r["value"], r["measure"]): r for r in rows if r["role"] is None}
    cmp = [r for r in rows if r["role"] is not None]
    for r in cmp:
        short = too_few(r, mode)
        if short:
            r["verdict"] = short
        elif not math.isfinite(r["p_value"]):
            r["verdict"] = "undetermined"
    family = [r for r in cmp if r.get("verdict") is None and r["role"] == "secondary"]
    adj = holm(np.array([r["p_value"] for r in family]))
    for r, a in zip(family, adj, strict=True):
        r["p_holm"] = float(a)
    for r in cmp:
        if r.get("verdict") is not None:
            continue
        p = r["p_value"] if r["role"] == "primary" else r["p_holm"]  # the primary: uncorrected
        r["survives"] = bool(p < ALPHA)
        r["verdict"] = _verdict(r, own)
    return rows


def _verdict(r: dict[str, Any], own: dict[tuple, dict[str, Any]]) -> str:
    """A judged comparison's verdict (see :func:`judge`)."""
    if not r["statistic"].startswith("paired_"):  # a model's gain over SI/TI: its own sign
        if not r["survives"]:
            return "no difference shown"
        return "better" if r["estimate"] > 0 else "worse"
    ref = r["statistic"].rsplit("_vs_", 1)[1]
    head = r["statistic"].removeprefix("paired_").rsplit("_vs_", 1)[0]
    mine = own.get((head, r["value"], ref))
    theirs = own.get((head, r["value"], r["measure"]))
    base = chance(head)
    if mine and theirs and mine["estimate"] < base and theirs["estimate"] < base:
        return "both against the expected sign"
    if not r["survives"]:
        return "no difference shown"
    winner = mine if r["estimate"] > 0 else theirs
    if winner is None or not (winner["ci_low"] > base):
        return "not shown: the better of the two does not predict failure beyond chance"
    return "better" if r["estimate"] > 0 else "worse"
