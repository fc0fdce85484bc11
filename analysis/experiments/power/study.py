"""``vdc-analyse power-study``: the pre-registered plan run from nothing: by default as amended
on 2026-12-07 (:data:`AMENDED`, docs/findings/power_plan_amendment.md), with ``--plan 2026-11``
as first fixed (:data:`FULL`, docs/findings/power_plan.md).

The amended plan confirms each detector's value before its study (the arena: on the first
seed of every condition, ``OUT/arena/<detector>/first-seed``; footage: on a pilot of clips drawn
from another seed than the study's, ``OUT/footage/pilot``) and moves it one step where 20-60 %
do not fail (:func:`move`), recording the move in the studies table (``planned_value``,
``value``, ``first_seed_failing``, ``deviation``); a study it names as unable to inform
(``cannot_inform``) runs for the record and is left out of the verdicts. Every resume key holds
vdc's version and a hash of the code that scores and measures (:func:`code_key`): where it
changed, the earlier studies are set aside (renamed, kept) and computed again
(:func:`set_aside_stale`). ``--publish-findings DIR`` copies the answer with the commit that
made it (:func:`analysis.experiments.power.findings.publish`).

One command runs exactly the plan and writes its answer:

1. **the arena**: for each arena detector at its planned value, the boundary campaign of
   ``vdc-analyse boundary`` over the plan's scenes and drawn wall TFs, with every complexity
   measure of the profiling runs (its predictors): ``OUT/arena/<detector>/``. All detectors
   share one ``OUT/arena/recordings`` folder (each detector's folder links to it), so the
   profiling runs, which do not depend on the detector, are recorded once;
2. **the footage**: the looming collection over real photographs (``vdc-analyse
   looming-footage``) into ``OUT/footage/clips``, then footage mode of ``boundary`` for each
   footage detector: ``OUT/footage/<detector>/``; the clips' complexity is measured once and
   its finished parts linked into the next detector's folder;
3. **the answer** (:mod:`analysis.experiments.power.answer`): ``primary.parquet`` (the AVDM
   against P.910 TI per detector and source, with interval, p and verdict),
   ``secondaries.parquet`` (every other comparison, Holm-corrected within its study),
   ``per_scene.parquet`` and ``per_scene.png`` (where each measure fails to rank the
   conditions, scene by scene) and ``answer.md``.

Resumable: the arena's runs are reused by the campaign itself (a finished recording of the same
configuration, and its measurements, are kept beside it, and read without starting a worker);
the clips by ``looming-footage``. A step that finished writes ``study.json`` beside its outputs,
naming what it ran with (settings without the executor; a footage study also the labels'
SHA-256): a re-run keeps such a step whole (an arena study only while every run of it is still
there), so a finished plan re-runs in seconds and computes nothing. A study that holds no
evidence (no avoidance or crash in the arena, a detector that never alerts on the clips) is
recorded as such, with the reason, and the others go on.

``--quick`` runs :data:`QUICK`: three scenes of one TF, one seed of 15-s runs, four 4-s clips.
It exercises every step in about a minute of CPU; its outputs say at the top, in words, that its
verdicts are not findings.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shutil
import time
from pathlib import Path
from typing import Any

import polars as pl

from analysis.boundary.settings import BoundarySettings
from analysis.experiments.captures import profiling_items
from analysis.experiments.collision.boundary_campaign import boundary, finished_row, grid_items
from analysis.experiments.collision.looming_footage import LoomingFootageSettings, looming_footage
from analysis.experiments.collision.predictor_runs import EVERY
from analysis.experiments.power.answer import write_answer
from analysis.experiments.power.findings import publish
from analysis.experiments.power.pilot import footage_pilot
from analysis.experiments.power.plans import (
    MOVE_ABOVE,
    MOVE_BELOW,
    PLANS,
    StudyPlan,
    plan_of,
)
from analysis.experiments.power.resume import (
    _done,
    _mark,
    _mark_json,
    _outcome_key,
    code_key,
    set_aside_stale,
)
from vdc.cli_support import option
from vdc.errors import UserError
from vdc.executors import QUIET, ExecutorSettings, Feedback, one_pool
from vdc.parquet_io import WroteFiles
from vdc.scratch import no_files_without_out


@dataclasses.dataclass(frozen=True)
class PowerStudySettings(ExecutorSettings):
    """``vdc-analyse power-study``: the amended plan (docs/findings/power_plan_amendment.md)
    or the first (``plan_version="2026-11"``, docs/findings/power_plan.md), or its quick
    version."""

    quick: bool = option(
        False,
        "the reduced version (3 conditions, 1 seed of 15-s runs, 4 clips): checks every step "
        "in about a minute; its verdicts are not findings",
    )
    plan_version: str = option(
        "2026-12",
        "which plan: 2026-12, the amended one (docs/findings/power_plan_amendment.md), or "
        "2026-11, the first (docs/findings/power_plan.md)",
        "--plan",
        choices=tuple(PLANS),
    )
    publish_findings: str = option(
        "",
        "at the end of the run, copy the answer's tables and answer.md into this "
        "folder (e.g. docs/findings/power-2026-12) with the commit of the code that made them",
        metavar="DIR",
    )

    def plan(self) -> StudyPlan:
        return plan_of(self.plan_version, self.quick)


@dataclasses.dataclass
class PowerStudyResult(WroteFiles):
    """``studies``: one row per study (source, detector, status, units run and recomputed);
    ``primary``: the primary comparison per study; ``paths``: the answer's files."""

    studies: pl.DataFrame
    primary: pl.DataFrame
    paths: list[Path]
    answer: str  # answer.md's text
    quick: bool

    @property
    def recomputed(self) -> int:
        """Runs, clips and detector passes computed by this call (0: all reused)."""
        return int(self.studies["recomputed"].sum())

    def report(self) -> list[str]:
        """What the command line prints: the answer's first paragraph, then the files."""
        first = self.answer.split("\n\n")[1 if self.quick else 0]
        head = ["QUICK RUN: its verdicts are not findings"] if self.quick else []
        more = len(self.paths) - 1  # the line was cut at "and beside it"
        return [
            *head,
            first.replace("**", ""),
            f"wrote {self.paths[-1]} and {more} more files beside it.",
        ]


def _slug(spec: str) -> str:
    return spec.replace(".", "-").replace(":", "-")


def _executor(s: ExecutorSettings) -> dict[str, Any]:
    return {"executor": s.executor, "jobs": s.jobs, "scheduler": s.scheduler}


def arena_study(
    s: PowerStudySettings,
    spec: tuple[str, str, float],
    out: Path,
    feedback: Feedback,
    start: float,
) -> dict[str, Any]:
    """One arena detector's boundary campaign into ``out/arena/<detector>`` (its recordings
    in the shared ``out/arena/recordings``); its row of the studies table."""
    plan = s.plan()
    detector, param, value = spec
    folder = out / "arena" / _slug(detector)
    folder.mkdir(parents=True, exist_ok=True)
    shared = out / "arena" / "recordings"
    shared.mkdir(parents=True, exist_ok=True)
    link = folder / "recordings"
    if not link.exists():
        os.symlink(Path("..") / "recordings", link, target_is_directory=True)
    bs = BoundarySettings(
        detector=detector,
        param=param,
        values=(value,),
        scenes=plan.scenes,
        tf_draws=plan.tf_draws,
        tf_range=plan.tf_range,
        seeds=plan.seeds,
        minutes=plan.minutes,
        no_fit=True,
        **_executor(s),
    )
    row = _row("arena", detector, param, value, folder, plan.conditions() * plan.seeds)
    if plan.confirm:  # the first seed of every condition, in its own folder, before the rest
        first = folder / "first-seed"
        first.mkdir(parents=True, exist_ok=True)
        if not (first / "recordings").exists():
            os.symlink(Path("..") / ".." / "recordings", first / "recordings", True)
        check = dataclasses.replace(bs, seeds=1)
        share, checked = _first_seed_share(check, first, feedback)
        moved = move(plan, "arena", detector, param, value, share)
        row |= {"first_seed_failing": share, "deviation": moved[1], "recomputed": checked}
        if moved[0] != value:
            value = moved[0]
            bs = dataclasses.replace(bs, values=(value,))
            row["value"] = value
            feedback.log(f"arena study of {detector}: {moved[1]}")
    key, marker = {"settings": _outcome_key(bs), **code_key()}, folder / "study.json"
    status = _done(marker, key)
    if status is not None and _all_finished(bs, folder):  # its tables are these runs' already
        feedback.log(f"arena study of {detector}: every run finished and analysed: reused.")
        return row | {"status": status}
    checked = row["recomputed"]  # the confirmation's runs
    try:
        res = boundary(bs, folder, feedback)
    except UserError as e:  # no evidence: recorded as the study's outcome, the others go on
        _mark(marker, key, f"no evidence: {e}")
        again = _recounted(folder, start)["recomputed"]
        return row | {"status": f"no evidence: {e}", "recomputed": max(again, checked)}
    _mark(marker, key, "ran")
    profiles = pl.read_parquet(folder / "boundary_profiles.parquet")
    fresh = int((~res.runs["reused"]).sum()) + int((~profiles["reused"]).sum())
    return row | {"status": "ran", "recomputed": fresh + checked}


def _first_seed_share(
    bs: BoundarySettings, folder: Path, feedback: Feedback
) -> tuple[float | None, int]:
    """(the share of the arena conditions failing on their first seed, the runs this call
    recorded for it): a condition fails when its success share is below the campaign's
    target, as the answer counts it; None where the first seed holds no evidence."""
    marker, key = folder / "study.json", {"settings": _outcome_key(bs), **code_key()}
    fresh = 0
    status = _done(marker, key)
    if status is not None and status.startswith("no evidence"):
        return None, 0
    if status is None or not (folder / "boundary_runs.parquet").exists():
        start = time.time()
        try:
            res = boundary(bs, folder, feedback)
        except UserError as e:
            _mark(marker, key, f"no evidence: {e}")
            return None, _recounted(folder, start)["recomputed"]
        _mark(marker, key, "ran")
        profiles = pl.read_parquet(folder / "boundary_profiles.parquet")
        fresh = int((~res.runs["reused"]).sum()) + int((~profiles["reused"]).sum())
    runs = pl.read_parquet(folder / "boundary_runs.parquet")
    events = pl.col("avoidances") + pl.col("crashes")
    success = (
        runs.filter(events > 0)
        .group_by("condition")
        .agg((pl.col("avoidances") / events).mean().alias("success"))
    )
    if not success.height:
        return None, fresh
    return float((success["success"] < bs.target).mean()), fresh


def move(
    plan: StudyPlan, source: str, detector: str, param: str, value: float, share: float | None
) -> tuple[float, str]:
    """The plan's rule: a value whose confirmation puts fewer than 20 % or more than 60 % of
    the units in failure moves one step (``plan.steps``), once; (the value, what was done, in
    words: the study's ``deviation``)."""
    if share is None:
        return value, f"{param} {value:g} kept unconfirmed: no evidence in the confirmation"
    steps = {(src, d): (lo, hi) for src, d, lo, hi in plan.steps}
    where = f"{100 * share:.0f} % failing in the confirmation"
    if MOVE_BELOW <= share <= MOVE_ABOVE:
        return value, ""  # confirmed: no deviation
    if (source, detector) not in steps:
        return value, f"{param} {value:g} kept: {where}, outside 20-60 %, and no step named"
    fewer, more = steps[(source, detector)]
    new = fewer if share < MOVE_BELOW else more
    return new, f"{param} moved {value:g} -> {new:g}: {where}, outside 20-60 %"


def _all_finished(bs: BoundarySettings, folder: Path) -> bool:
    """Every run of the campaign recorded and measured (read as the campaign reads them)."""
    rec = folder / "recordings"
    runs = [(it, "collision", 0) for it in grid_items(bs, rec)]
    runs += [(it, "profile", EVERY) for it in profiling_items(bs, rec)]
    return all(finished_row(it, kind, every) is not None for it, kind, every in runs)


def _recounted(folder: Path, start: float) -> dict[str, Any]:
    """A study that stopped for lack of evidence returns no runs table: its runs measured by
    this call (``start``: its time.time()) are counted by their rows' files (``.row.json``)."""
    caches = (folder / "recordings").rglob("*.row.json")
    return {"recomputed": sum(c.stat().st_mtime >= start for c in caches)}


def _row(source: str, detector: str, param: str, value: float, folder: Path, units: int) -> dict:
    return {
        "source": source,
        "detector": detector,
        "param": param,
        "planned_value": value,  # the plan's; ``value`` the one run (moved by the rule)
        "value": value,
        "folder": str(folder),
        "units": units,
        "status": "",
        "recomputed": 0,
        "first_seed_failing": None,  # the confirmation's failing share (arena: first seed)
        "deviation": "",  # what differs from the plan, in words ("" none)
        "cannot_inform": "",  # named in advance: why the study cannot inform ("" it can)
    }


def _link_parts(src: Path, dst: Path) -> None:
    """The finished complexity parts of one footage study linked into the next one's folder
    (the same clips and settings: its ``complexity`` then measures nothing again)."""
    if not src.is_dir():
        return
    dst.mkdir(parents=True, exist_ok=True)
    for part in src.iterdir():
        target = dst / part.name
        if part.is_file() and not target.exists():
            try:
                os.link(part, target)
            except OSError:  # another file system: a copy
                shutil.copy2(part, target)


def footage_study(
    s: PowerStudySettings,
    spec: tuple[str, str, float],
    labels: Path,
    fov_deg: float,
    out: Path,
    feedback: Feedback,
    pilot: dict[str, float | None] | None = None,
) -> dict[str, Any]:
    """One footage detector's boundary on the collection into ``out/footage/<detector>``;
    skipped when ``study.json`` there says it finished with these settings and these labels."""
    plan = s.plan()
    detector, param, value = spec
    folder = out / "footage" / _slug(detector)
    bs = BoundarySettings(
        detector=detector,
        param=param,
        values=(value,),
        labels=str(labels),
        fov_deg=fov_deg,
        min_ttc_s=plan.min_ttc_s,
        alert_window_s=plan.alert_window_s,
        **_executor(s),
    )
    row = _row("footage", detector, param, value, folder, plan.clips)
    if pilot is not None:  # the value confirmed on the pilot clips (outside the study's)
        share = pilot.get(detector)
        moved = move(plan, "footage", detector, param, value, share)
        row |= {"first_seed_failing": share, "deviation": moved[1]}
        if moved[0] != value:
            value = moved[0]
            bs = dataclasses.replace(bs, values=(value,))
            row["value"] = value
            feedback.log(f"footage study of {detector}: {moved[1]}")
    for src, d, why in plan.uninformative:
        if (src, d) == ("footage", detector):
            row["cannot_inform"] = why
    digest = hashlib.sha256(labels.read_bytes()).hexdigest()  # rewritten, unchanged, each run
    key = {"settings": _outcome_key(bs), "labels": digest, **code_key()}
    marker = folder / "study.json"
    status = _done(marker, key)
    if status is not None:
        feedback.log(f"footage study of {detector}: reused ({status}).")
        return row | {"status": status}
    for other in (out / "footage").iterdir():  # clips measured by an earlier detector
        _link_parts(other / "complexity" / "parts", folder / "complexity" / "parts")
    try:
        boundary(bs, folder, feedback)
        status = "ran"
    except UserError as e:
        status = f"no evidence: {e}"
    _mark(marker, key, status)
    return row | {"status": status, "recomputed": plan.clips}


@no_files_without_out
@one_pool()  # its stages share one pool of workers
def power_study(
    settings: PowerStudySettings, out: str | Path | None, feedback: Feedback = QUIET
) -> PowerStudyResult:
    """Run the plan (``settings.quick``: its reduced version) into ``out`` and write the
    answer there (see the module); finished runs, clips and footage studies are reused."""
    start = time.time()
    s = settings
    plan = s.plan()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    feedback.log(
        f"power study{' (QUICK: not findings)' if s.quick else ''}: {plan.conditions()} arena "
        f"conditions x {plan.seeds} seed(s) x {len(plan.arena_detectors)} detector(s) "
        f"+ profiling = {plan.arena_runs()} run(s) of {plan.minutes:g} min; {plan.clips} clips "
        f"x {len(plan.footage_detectors)} detector(s)."
    )
    set_aside_stale(out, code_key(), feedback)
    rows = [arena_study(s, spec, out, feedback, start) for spec in plan.arena_detectors]
    w, h = plan.clip_size
    clips = LoomingFootageSettings(
        clips=plan.clips,
        seconds=plan.clip_seconds,
        width_px=w,
        height_px=h,
        collection=plan.collection,
    )
    folder = out / "footage" / "clips"
    labels = folder / "labels.csv"
    row = _row("footage", "looming-footage", "clips", plan.clips, folder, plan.clips)
    # the generator renders every clip again to label it: a finished collection is kept whole
    key = dataclasses.asdict(clips)
    if _done(folder / "study.json", key) and labels.exists():
        feedback.log(f"looming-footage: the {plan.clips} clips in {folder} reused.")
        rows.append(row | {"status": "rendered"})
    else:
        made = looming_footage(clips, folder, feedback)
        _mark(folder / "study.json", key, "rendered")
        rows.append(row | {"status": "rendered", "recomputed": plan.clips - made.reused})
    pilot = footage_confirmation(plan, clips, out / "footage" / "pilot", feedback)
    for spec in plan.footage_detectors:
        rows.append(footage_study(s, spec, labels, clips.hfov_deg, out, feedback, pilot))
    studies = pl.DataFrame(rows, infer_schema_length=None)
    primary, paths, answer = write_answer(studies, out, quick=s.quick, plan=plan)
    if s.publish_findings:
        paths += publish(out, Path(s.publish_findings), studies, plan.name, feedback)
    return PowerStudyResult(studies, primary, paths, answer, s.quick)


def footage_confirmation(
    plan: StudyPlan, clips: LoomingFootageSettings, folder: Path, feedback: Feedback
) -> dict[str, float | None] | None:
    """The amended plan's confirmation of each footage detector's value: its failing share on
    ``plan.pilot_clips`` clips of the collection drawn from ``plan.pilot_seed`` (not the
    study's clips), by detector; None where the plan confirms nothing. Kept in
    ``folder/pilot.json`` with what it ran with (and the code), and reused."""
    if not plan.confirm or not plan.pilot_clips:
        return None
    specs = tuple(f"{d}:{p}={v:g}" for d, p, v in plan.footage_detectors)
    settings = dataclasses.replace(clips, seed=plan.pilot_seed, clips=plan.pilot_clips)
    key = {"settings": dataclasses.asdict(settings), "detectors": specs, **code_key()}
    marker = folder / "pilot.json"
    if marker.exists() and (done := json.loads(marker.read_text())).get("key") == key:
        feedback.log(f"footage pilot: {plan.pilot_clips} clips of seed {plan.pilot_seed} reused.")
        return done["shares"]
    feedback.log(
        f"footage pilot: each footage detector's value on {plan.pilot_clips} clips of seed "
        f"{plan.pilot_seed} (outside the study's clips)."
    )
    table = footage_pilot(folder, plan.pilot_clips, specs, feedback, settings)
    by_spec = dict(zip(table["detector"], table["failure_share"], strict=True))
    detectors = [d for d, _, _ in plan.footage_detectors]
    shares = {d: by_spec.get(sp) for d, sp in zip(detectors, specs, strict=True)}
    folder.mkdir(parents=True, exist_ok=True)
    _mark_json(marker, {"key": key, "shares": shares})
    return shares
