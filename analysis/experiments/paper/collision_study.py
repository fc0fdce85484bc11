"""The paper's three-phase collision protocol, plus the complexity-adaptive detector.

Phases (one closed-loop recording per seed, ``minutes`` long; seeds ``seed`` .. ``seed + seeds
- 1``, the same seeds in every phase):

1. ``tf0``: static walls;
2. ``tf3``: walls drifting at 3 Hz, same detector;
3. ``tf3-adjusted``: 3 Hz with the adjusted detection threshold (``adjusted`` overrides);
4. ``tf3-adaptive`` and ``tf0-adaptive`` (beyond the paper): the detector's FFI threshold
   follows the on-board AVDM profile, no hand tuning.

Phases run in parallel processes; a phase whose recording already exists with the same
configuration (same recording id) and completed is reused.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

import polars as pl

from analysis.collision import CollisionSettings, collision
from analysis.experiments.captures import CaptureItem, check_detectors, run_captures
from avdm.registry import add_overrides, parse_model_spec
from capture.sim import SimSettings
from vdc.cli_support import option
from vdc.executors import ExecutorSettings, one_pool
from vdc.parquet_io import WroteFiles
from vdc.scratch import no_files_without_out
from vdc.settings import AT_LEAST_0, AT_LEAST_1, POSITIVE

SEEDS_HELP = (  # --seeds of the campaigns (collision-study, reproduce)
    "runs per condition, seeds --seed, --seed+1, ...: every figure is given as a mean with its "
    "95 % interval across them"
)
PAPER_NOTE = (
    "Paper: 229, 432 and 233 avoidances in three 30-min phases (TF 0, TF 3, TF 3 with the "
    "adjusted threshold), success > 90 % in each."
)


@dataclasses.dataclass(frozen=True)
class Phase:
    key: str
    tf_hz: float
    detector: str
    adaptive: bool = False


def study_phases(detector: str, adjusted: str) -> list[Phase]:
    tuned = add_overrides(detector, adjusted) if adjusted else detector
    return [
        Phase("tf0", 0.0, detector),
        Phase("tf3", 3.0, detector),
        Phase("tf3-adjusted", 3.0, tuned),
        Phase("tf3-adaptive", 3.0, detector, adaptive=True),
        Phase("tf0-adaptive", 0.0, detector, adaptive=True),
    ]


def phase_settings(phase: Phase, minutes: float, seed: int) -> SimSettings:
    """The closed-loop simulated run of one phase."""
    return SimSettings(
        behaviour="collision",
        model=phase.detector,
        tf_hz=phase.tf_hz,
        minutes=minutes,
        seed=seed,
        phase=phase.key,
        adaptive=phase.adaptive,
    )


def seed_list(first: int, count: int) -> list[int]:
    """The seeds of a campaign: ``first``, ``first + 1``, ... (``count`` of them)."""
    return list(range(first, first + count))


def phase_items(
    phases: list[Phase], minutes: float, seeds: list[int], folder: Path
) -> list[CaptureItem]:
    """One capture per (phase, seed): key ``<phase>-seed<n>``, file ``seed<n>/<phase>.rrd``."""
    return [
        (
            f"{ph.key}-seed{seed}",
            phase_settings(ph, minutes, seed),
            folder / f"seed{seed}" / f"{ph.key}.rrd",
        )
        for seed in seeds
        for ph in phases
    ]


def run_phases(
    phases: list[Phase],
    minutes: float,
    seeds: list[int],
    folder: Path,
    executor: ExecutorSettings,
    log: Callable[[str], None],
) -> dict[str, Path]:
    """Record every (phase, seed) on the executor, reusing finished ones; key → path."""
    return run_captures(phase_items(phases, minutes, seeds, folder), executor, log)


@dataclasses.dataclass(frozen=True)
class CollisionStudySettings(ExecutorSettings):
    """``vdc-analyse collision-study``: phase length, detector, the adjusted phase's overrides;
    the runs go to the executor (``executor``, ``jobs``, ``scheduler``)."""

    minutes: float = option(
        30.0, "length of each phase (default: {default}, the paper's)", range=POSITIVE
    )
    detector: str = option(
        "lgmd-plus-arena",
        "collision detector (default: {default}; lgmd-plus = released parameters, which never "
        "alert on this arena's static walls)",
    )
    adjusted: str = option("t_ffi=30", "detector overrides of the 'adjusted threshold' phase")
    seed: int = option(1, "first random seed", range=AT_LEAST_0)
    seeds: int = option(5, SEEDS_HELP, range=AT_LEAST_1)
    false_alarm_m: float = option(0.30, "false-alarm distance, m", range=POSITIVE)

    def __post_init__(self) -> None:
        super().__post_init__()
        parse_model_spec(self.detector)  # a bad detector fails before anything runs
        if self.adjusted:
            parse_model_spec(add_overrides(self.detector, self.adjusted))
        CollisionSettings(false_alarm_m=self.false_alarm_m)


@dataclasses.dataclass
class CollisionStudyResult(WroteFiles):
    summary: pl.DataFrame  # one row per (phase, seed)
    phases: pl.DataFrame  # one row per phase: means and 95 % intervals across seeds
    markdown: str  # the per-phase and per-run tables beside the paper's numbers
    recordings: dict[str, Path]  # phase key -> recording
    paths: list[Path]


@no_files_without_out
@one_pool()  # its stages share one pool of workers
def collision_study(
    settings: CollisionStudySettings,
    out: str | Path | None,
    *,
    log: Callable[[str], None] | None = None,
    notice: Callable[[str], None] | None = None,
) -> CollisionStudyResult:
    """Record the phases into ``out/recordings`` (reusing finished ones), analyse them into
    ``out`` and write ``collision_study.md`` with the paper's numbers beside ours."""
    out = Path(out)
    say = log or (lambda _m: None)
    phases = study_phases(settings.detector, settings.adjusted)
    # every phase's detector, once, before a word or a run (one line if one cannot be one)
    check_detectors(phase_settings(p, settings.minutes, settings.seed).to_config() for p in phases)
    say(
        f"collision study: {len(phases)} phases x {settings.seeds} seed(s) of "
        f"{settings.minutes:g} min, detector {settings.detector}, adjusted threshold "
        f"{settings.adjusted or '(none)'}."
    )
    seeds = seed_list(settings.seed, settings.seeds)
    recs = run_phases(phases, settings.minutes, seeds, out / "recordings", settings, say)
    res = collision(
        [str(p) for p in recs.values()],
        CollisionSettings(false_alarm_m=settings.false_alarm_m),
        out,
        notice=notice,
    )
    table = res.markdown()
    md = out / "collision_study.md"
    md.write_text(
        "# Collision study\n\nPer phase: mean [95 % interval] across seeds; then every run.\n\n"
        + table
        + "\n\n"
        + PAPER_NOTE
        + "\n",
        encoding="utf-8",
    )
    return CollisionStudyResult(res.summary, res.phases, table, recs, [*res.paths, md])
