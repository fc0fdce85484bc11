"""Simulated runs recorded in parallel processes, reused when already there.

Each run is a :class:`capture.sim.SimSettings` and an output path. A recording already at
that path with the same configuration (the recording id is a function of it) and complete is
reused; the others are recorded as tasks on an executor (``vdc.executors``: a local pool
of fresh processes, or a Dask cluster), so a campaign of many long runs spreads over a cluster.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

from analysis.boundary.scenes import scene_fields
from analysis.boundary.settings import condition_name, with_override
from analysis.recordings.reader import Recording, RecordingError
from avdm.registry import check_detector
from capture.run import REPLACE_OUTPUT
from capture.sim import SimSettings, record_sim
from vdc.executors import (
    QUIET,
    ExecutorSettings,
    Feedback,
    TaskOutcome,
    TasksFailed,
    failure_report,
    run_tasks,
)

# (key, settings, output path) of one run
CaptureItem = tuple[str, SimSettings, Path]


def capture_is_done(path: Path, recording_id: str) -> bool:
    """A finished recording of exactly this configuration is already there."""
    if not path.exists():
        return False
    try:
        rec = Recording(path)
        end = rec.properties().get("run_end", {})
    except RecordingError:
        return False
    return rec.recording_id == recording_id and bool(end.get("complete"))


def check_detectors(configs: Iterable[Any]) -> None:
    """Every collision run's detector (each distinct one once: spec and camera), built and
    stepped on one frame of the camera's raster (:func:`avdm.registry.check_detector`), before any
    run: a detector that cannot be one is a ValueError in one line, not one failure per run.
    ``configs``: :class:`capture.config.SimConfig` items."""

    seen = set()
    for config in configs:
        if config.behaviour != "collision":
            continue
        cam = config.camera
        spec, ctx = config.collision.detector_spec(), cam.model_context()
        shape = (cam.height_px, cam.width_px)
        key = (spec, shape, tuple(sorted(ctx.items())))
        if key not in seen:
            seen.add(key)
            check_detector(spec, ctx, shape)


def _record(key: str, settings: SimSettings, out: str) -> dict:
    """One run, as an executor task (module-level, small arguments, small result)."""
    t0 = time.perf_counter()
    record_sim(settings, out, REPLACE_OUTPUT)  # a partial file of a killed run is replaced
    return {"key": key, "seconds": time.perf_counter() - t0}


def run_captures(
    items: Sequence[CaptureItem],
    executor: ExecutorSettings,
    log: Callable[[str], None],
    feedback: Feedback = QUIET,
) -> dict[str, Path]:
    """Record every (key, settings, output) not already there on ``executor``; key → path;
    ``feedback`` counts the runs to record (``expect``) and those finished (``progress``).

    A failed run does not stop the others: they finish and are kept, then
    :class:`TasksFailed` names the failed ones (a re-run records only those)."""
    todo, paths = [], {}
    check_detectors(settings.to_config() for _, settings, _ in items)
    for key, settings, out in items:
        run_id = settings.to_config().run_id()  # a bad configuration fails before any process
        out.parent.mkdir(parents=True, exist_ok=True)
        paths[key] = out
        if capture_is_done(out, run_id):
            log(f"  {key}: reusing {out}.")
        else:
            todo.append((key, (key, settings, str(out))))
    if not todo:
        return paths
    log(f"recording {len(todo)} run(s) on {executor.where()}.")
    finished = 0
    feedback.expect(len(todo))

    def done(outcome: TaskOutcome) -> None:
        nonlocal finished
        finished += 1
        feedback.progress(1)
        if outcome.error is None:
            secs = outcome.result["seconds"] if outcome.result else float("nan")
            log(f"  [{finished}/{len(todo)}] {outcome.key} recorded in {secs:.0f} s.")
        else:
            log(f"  [{finished}/{len(todo)}] {outcome.key} FAILED: {outcome.error}")

    outcomes = run_tasks(
        _record,
        todo,
        executor.executor_settings(),
        done,
        log,
        shared_paths=[items[0][2].parent],
    )
    report = failure_report(outcomes, "simulated run")
    if report:
        raise TasksFailed(report)
    return paths


@dataclasses.dataclass(frozen=True)
class RunItem:
    """One simulated run of a campaign: its ``key`` (unique in the campaign), the
    ``capture.sim.SimSettings`` it records with, the recording's ``path`` and the ``columns``
    its row of the runs table starts with."""

    key: str
    settings: SimSettings
    path: Path
    columns: dict[str, Any]


def profiling_items(s: Any, folder: Path) -> list[RunItem]:
    """A boundary campaign's profiling runs (``s``: its ``BoundarySettings``): one (as
    ``reproduce`` profiles: ring turns, no detector) per (scene, TF, seed)."""

    items = []
    for scene, tf in s.conditions():
        cond = condition_name(scene, tf)
        for seed in range(s.seed, s.seed + s.seeds):
            settings = SimSettings(
                **scene_fields(scene),
                tf_hz=tf,
                minutes=s.minutes,
                seed=seed,
                model=s.profile_model,
            )
            cols = {"condition": cond, "scene": scene, "tf_hz": tf, "seed": seed}
            path = folder / "profile" / cond / f"seed{seed}.rrd"
            items.append(RunItem(f"profile-{cond}-seed{seed}", settings, path, cols))
    return items


def collision_run_item(
    s: Any, scene: str, tf_hz: float, value: float, seed: int, folder: Path, cols: dict[str, Any]
) -> RunItem:
    """One closed-loop run of a boundary campaign (``s``: its ``BoundarySettings``) at the
    detector's ``value``, as the grid and the
    adaptive design both record it (so either reuses the other's finished runs)."""

    cond = condition_name(scene, tf_hz)
    tag = f"{s.param}{value:g}"
    settings = SimSettings(
        behaviour="collision",
        model=with_override(s.detector, s.param, value),
        **scene_fields(scene),
        tf_hz=tf_hz,
        minutes=s.minutes,
        seed=seed,
        phase=f"{cond}-{tag}",
        profile_model=s.profile_model,
    )
    key = f"{cond}-{tag}-seed{seed}"
    return RunItem(
        key, settings, folder / cond / tag / f"seed{seed}.rrd", {"condition": cond} | cols
    )
