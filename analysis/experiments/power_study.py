"""``vdc-analyse power-study``: the pre-registered plan of docs/findings/power_plan.md, run from
nothing.

One command runs exactly the plan (:data:`FULL`) and writes its answer:

1. **the arena**: for each arena detector at its planned value, the boundary campaign of
   ``vdc-analyse boundary`` over the plan's scenes and drawn wall TFs, with every complexity
   measure of the profiling runs (its predictors): ``OUT/arena/<detector>/``. All detectors
   share one ``OUT/arena/recordings`` folder (each detector's folder links to it), so the
   profiling runs, which do not depend on the detector, are recorded once;
2. **the footage**: the looming collection over real photographs (``vdc-analyse
   looming-footage``) into ``OUT/footage/clips``, then footage mode of ``boundary`` for each
   footage detector: ``OUT/footage/<detector>/``; the clips' complexity is measured once and
   its finished parts linked into the next detector's folder;
3. **the answer** (:mod:`analysis.experiments.power_answer`): ``primary.parquet`` (the AVDM
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

from analysis.boundary.command import BoundarySettings
from analysis.experiments.boundary_campaign import boundary, finished_row, grid_items
from analysis.experiments.captures import profiling_items
from analysis.experiments.looming_footage import LoomingFootageSettings, looming_footage
from analysis.experiments.power_answer import write_answer
from analysis.experiments.predictor_runs import EVERY
from vdc.cli_support import option
from vdc.errors import UserError
from vdc.executors import QUIET, ExecutorSettings, Feedback, one_pool
from vdc.parquet_io import WroteFiles
from vdc.scratch import no_files_without_out


@dataclasses.dataclass(frozen=True)
class StudyPlan:
    """One version of the plan (docs/findings/power_plan.md): the arena grid, the footage collection
    and each detector at its planned value (detector spec, parameter, value)."""

    scenes: tuple[str, ...]
    tf_draws: int  # wall TFs per scene, one per stratum of tf_range
    tf_range: str  # Hz, LO:HI
    seeds: int  # runs per condition
    minutes: float  # each arena run's length
    arena_detectors: tuple[tuple[str, str, float], ...]
    clips: int
    clip_seconds: float
    clip_size: tuple[int, int]  # (width, height) px of the rendered clips
    footage_detectors: tuple[tuple[str, str, float], ...]
    min_ttc_s: float = 0.5  # a later first alert is a miss (docs/findings/power_plan.md)
    # an alert earlier than this before contact is early: the object enters 1.5-3 s before
    # contact (analysis.experiments.looming_footage.ENTER_S), so one earlier than 3 s comes
    # before any hazard is in view
    alert_window_s: float = 3.0

    def conditions(self) -> int:
        return len(self.scenes) * self.tf_draws

    def arena_runs(self) -> int:
        """Closed-loop runs of every arena detector plus the shared profiling runs."""
        return self.conditions() * self.seeds * (len(self.arena_detectors) + 1)


FULL = StudyPlan(
    scenes=(
        *("grating", "grating-p0.05", "grating-p0.2", "grating-c0.3", "natural"),
        *("photo-astronaut", "photo-grass", "photo-brick"),
    ),
    tf_draws=6,
    tf_range="0:4",
    seeds=3,
    minutes=3.0,
    arena_detectors=(("lgmd-plus-arena", "t_ffi", 12.0), ("flow-ttc", "tau_alert_s", 0.6)),
    clips=480,
    clip_seconds=6.0,
    clip_size=(160, 120),
    footage_detectors=(
        ("lgmd-plus", "t_sr", 28.0),
        ("examples.looming:Looming", "threshold", 0.02),
        ("flow-ttc", "tau_alert_s", 1.0),
    ),
)
QUICK = dataclasses.replace(
    FULL,
    scenes=("grating", "natural", "photo-grass"),
    tf_draws=1,
    seeds=1,
    minutes=0.25,  # 15 s: the robot meets a wall about 9 s in, then every few seconds
    clips=4,
    clip_seconds=4.0,  # the shortest clip the generator makes
    # a little over the detectors' working raster at 60 deg (85 x 64): their input is alike,
    # the native-resolution measures (SI/TI, codecs, flow) cost a third
    clip_size=(96, 72),
)


@dataclasses.dataclass(frozen=True)
class PowerStudySettings(ExecutorSettings):
    """``vdc-analyse power-study``: the plan of docs/findings/power_plan.md, or its quick
    version."""

    quick: bool = option(
        False,
        "the reduced version (3 conditions, 1 seed of 15-s runs, 4 clips): checks every step "
        "in about a minute; its verdicts are not findings",
    )

    def plan(self) -> StudyPlan:
        return QUICK if self.quick else FULL


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
        return [*head, first.replace("**", ""), f"wrote {self.paths[-1]} and beside it"]


def _done(marker: Path, key: dict[str, Any]) -> str | None:
    """The status a finished step wrote into ``marker`` (``study.json``) when it ran with this
    ``key`` (what its outcome depends on), else None."""
    if not marker.exists():
        return None
    done = json.loads(marker.read_text())
    return done["status"] if done.get("key") == json.loads(json.dumps(key)) else None


def _mark(marker: Path, key: dict[str, Any], status: str) -> None:
    marker.parent.mkdir(parents=True, exist_ok=True)
    tmp = marker.with_suffix(".partial")
    tmp.write_text(json.dumps({"key": key, "status": status}))
    tmp.replace(marker)


def _outcome_key(settings: Any) -> dict[str, Any]:
    """A step's settings without where it runs (the executor fields change no outcome)."""
    executor = {f.name for f in dataclasses.fields(ExecutorSettings)}
    return {k: v for k, v in dataclasses.asdict(settings).items() if k not in executor}


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
        detector=detector, param=param, values=(value,), scenes=plan.scenes,
        tf_draws=plan.tf_draws, tf_range=plan.tf_range, seeds=plan.seeds, minutes=plan.minutes,
        no_fit=True, **_executor(s),
    )  # fmt: skip
    row = _row("arena", detector, param, value, folder, plan.conditions() * plan.seeds)
    key, marker = _outcome_key(bs), folder / "study.json"
    status = _done(marker, key)
    if status is not None and _all_finished(bs, folder):  # its tables are these runs' already
        feedback.log(f"arena study of {detector}: every run finished and analysed: reused")
        return row | {"status": status}
    try:
        res = boundary(bs, folder, feedback)
    except UserError as e:  # no evidence: recorded as the study's outcome, the others go on
        _mark(marker, key, f"no evidence: {e}")
        return row | {"status": f"no evidence: {e}"} | _recounted(folder, start)
    _mark(marker, key, "ran")
    profiles = pl.read_parquet(folder / "boundary_profiles.parquet")
    fresh = int((~res.runs["reused"]).sum()) + int((~profiles["reused"]).sum())
    return row | {"status": "ran", "recomputed": fresh}


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
        "value": value,
        "folder": str(folder),
        "units": units,
        "status": "",
        "recomputed": 0,
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
) -> dict[str, Any]:
    """One footage detector's boundary on the collection into ``out/footage/<detector>``;
    skipped when ``study.json`` there says it finished with these settings and these labels."""
    plan = s.plan()
    detector, param, value = spec
    folder = out / "footage" / _slug(detector)
    bs = BoundarySettings(
        detector=detector, param=param, values=(value,), labels=str(labels), fov_deg=fov_deg,
        min_ttc_s=plan.min_ttc_s, alert_window_s=plan.alert_window_s, **_executor(s),
    )  # fmt: skip
    row = _row("footage", detector, param, value, folder, plan.clips)
    digest = hashlib.sha256(labels.read_bytes()).hexdigest()  # rewritten, unchanged, each run
    key, marker = {"settings": _outcome_key(bs), "labels": digest}, folder / "study.json"
    status = _done(marker, key)
    if status is not None:
        feedback.log(f"footage study of {detector}: reused ({status[:60]})")
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
        f"x {len(plan.footage_detectors)} detector(s)"
    )
    rows = [arena_study(s, spec, out, feedback, start) for spec in plan.arena_detectors]
    w, h = plan.clip_size
    clips = LoomingFootageSettings(
        clips=plan.clips, seconds=plan.clip_seconds, width_px=w, height_px=h
    )
    folder = out / "footage" / "clips"
    labels = folder / "labels.csv"
    row = _row("footage", "looming-footage", "clips", plan.clips, folder, plan.clips)
    # the generator renders every clip again to label it: a finished collection is kept whole
    key = dataclasses.asdict(clips)
    if _done(folder / "study.json", key) and labels.exists():
        feedback.log(f"looming-footage: the {plan.clips} clips in {folder} reused")
        rows.append(row | {"status": "rendered"})
    else:
        made = looming_footage(clips, folder, feedback)
        _mark(folder / "study.json", key, "rendered")
        rows.append(row | {"status": "rendered", "recomputed": plan.clips - made.reused})
    for spec in plan.footage_detectors:
        rows.append(footage_study(s, spec, labels, clips.hfov_deg, out, feedback))
    studies = pl.DataFrame(rows)
    primary, paths, answer = write_answer(studies, out, quick=s.quick, plan=plan)
    return PowerStudyResult(studies, primary, paths, answer, s.quick)
