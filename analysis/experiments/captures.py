"""Simulated runs recorded in parallel processes, reused when already there.

Each run is a :class:`capture.sim.SimSettings` and an output path. A recording already at
that path with the same configuration (the recording id is a function of it) and complete is
reused; the others are recorded by ``jobs`` worker processes (started fresh, not forked, so no
Rerun or Numba thread state is copied into them).
"""

from __future__ import annotations

import multiprocessing
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path

from analysis.rrd_reader import Recording, RecordingError
from capture.sim import SimSettings, record_sim

# (key, settings, output path) of one run
CaptureItem = tuple[str, SimSettings, Path]


def is_done(path: Path, recording_id: str) -> bool:
    """A finished recording of exactly this configuration is already there."""
    if not path.exists():
        return False
    try:
        rec = Recording(path)
        end = rec.properties().get("run_end", {})
    except RecordingError:
        return False
    return rec.recording_id == recording_id and bool(end.get("complete"))


def _record(key: str, settings: SimSettings, out: Path) -> tuple[str, float]:
    t0 = time.perf_counter()
    try:
        record_sim(settings, out, force=True)
    except Exception as exc:  # a worker's error names its run
        raise RuntimeError(f"capture of {key} failed: {exc}") from exc
    return key, time.perf_counter() - t0


def run_captures(
    items: Sequence[CaptureItem], jobs: int, log: Callable[[str], None]
) -> dict[str, Path]:
    """Record every (key, settings, output) not already there; key → path."""
    todo, paths = [], {}
    for key, settings, out in items:
        run_id = settings.to_config().run_id()  # a bad configuration fails before any process
        out.parent.mkdir(parents=True, exist_ok=True)
        paths[key] = out
        if is_done(out, run_id):
            log(f"  {key}: reusing {out}")
        else:
            todo.append((key, settings, out))
    if not todo:
        return paths
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=max(1, min(jobs, len(todo))), mp_context=ctx) as pool:
        futures = [pool.submit(_record, *item) for item in todo]
        for done, fut in enumerate(as_completed(futures), 1):
            key, secs = fut.result()
            log(f"  [{done}/{len(todo)}] {key} recorded in {secs:.0f} s")
    return paths
