"""The paper's three-phase collision protocol, plus the complexity-adaptive detector.

Phases (one closed-loop recording each, ``minutes`` long, same seed):

1. ``tf0``: static walls;
2. ``tf3``: walls drifting at 3 Hz, same detector;
3. ``tf3-adjusted``: 3 Hz with the adjusted detection threshold (``adjusted`` overrides);
4. ``tf3-adaptive`` and ``tf0-adaptive`` (beyond the paper): the detector's FFI threshold
   follows the on-board AVDM profile, no hand tuning.

Phases run as parallel ``vdc-capture`` processes; a phase whose recording already exists with
the same configuration (same recording id) and completed is reused.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path

from analysis.rrd_reader import Recording, RecordingError


@dataclasses.dataclass(frozen=True)
class Phase:
    key: str
    tf_hz: float
    detector: str
    adaptive: bool = False


def study_phases(detector: str, adjusted: str) -> list[Phase]:
    sep = "," if ":" in detector else ":"
    tuned = f"{detector}{sep}{adjusted}" if adjusted else detector
    return [
        Phase("tf0", 0.0, detector),
        Phase("tf3", 3.0, detector),
        Phase("tf3-adjusted", 3.0, tuned),
        Phase("tf3-adaptive", 3.0, detector, adaptive=True),
        Phase("tf0-adaptive", 0.0, detector, adaptive=True),
    ]


def capture_args(phase: Phase, minutes: float, seed: int, out: Path) -> list[str]:
    args = [
        "sim",
        "--behaviour",
        "collision",
        "--model",
        phase.detector,
        "--tf-hz",
        f"{phase.tf_hz:g}",
        "--minutes",
        f"{minutes:g}",
        "--seed",
        str(seed),
        "--phase",
        phase.key,
        "--out",
        str(out),
        "--force",
        "--quiet",
    ]
    return [*args, "--adaptive"] if phase.adaptive else args


def expected_recording_id(args: list[str]) -> str:
    """The recording id the capture command would give (a function of its configuration)."""
    from capture.cli import build_parser, sim_config_from_args

    return sim_config_from_args(build_parser().parse_args(args)).run_id()


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


def run_captures(
    items: list[tuple[str, list[str], Path]],
    jobs: int,
    log: Callable[[str], None],
) -> dict[str, Path]:
    """Run ``vdc-capture`` for every (key, args, output) in parallel processes, reusing a
    recording that is already there with the same configuration; key → path."""
    todo, paths = [], {}
    for key, args, out in items:
        out.parent.mkdir(parents=True, exist_ok=True)
        paths[key] = out
        if is_done(out, expected_recording_id(args)):
            log(f"  {key}: reusing {out}")
        else:
            todo.append((key, args))

    def one(item: tuple[str, list[str]]) -> tuple[str, float]:
        key, args = item
        t0 = time.perf_counter()
        proc = subprocess.run(
            [sys.executable, "-m", "capture", *args], capture_output=True, text=True
        )
        if proc.returncode != 0:
            raise RuntimeError(f"capture of {key} failed: {proc.stderr.strip()}")
        return key, time.perf_counter() - t0

    with ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
        futures = [pool.submit(one, item) for item in todo]
        for done, fut in enumerate(as_completed(futures), 1):
            key, secs = fut.result()
            log(f"  [{done}/{len(todo)}] {key} recorded in {secs:.0f} s")
    return paths


def phase_items(
    phases: list[Phase], minutes: float, seed: int, folder: Path
) -> list[tuple[str, list[str], Path]]:
    return [
        (
            ph.key,
            capture_args(ph, minutes, seed, folder / f"{ph.key}.rrd"),
            folder / f"{ph.key}.rrd",
        )
        for ph in phases
    ]


def run_phases(
    phases: list[Phase],
    minutes: float,
    seed: int,
    folder: Path,
    jobs: int,
    log: Callable[[str], None],
) -> dict[str, Path]:
    """Record every phase (in parallel processes), reusing finished ones; phase key → path."""
    return run_captures(phase_items(phases, minutes, seed, folder), jobs, log)
