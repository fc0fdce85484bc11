"""The reproduction's plan: durations, repeats, seeds and where the runs go."""

from __future__ import annotations

import dataclasses
from typing import Any, ClassVar

from analysis.experiments.paper.collision_study import SEEDS_HELP, seed_list
from vdc.cli_support import option
from vdc.executors import ExecutorSettings
from vdc.settings import AT_LEAST_0, AT_LEAST_1, POSITIVE


@dataclasses.dataclass(frozen=True)
class ReproduceSettings(ExecutorSettings):
    """``vdc-analyse reproduce``: durations and repeats. The defaults are the paper's plan;
    :meth:`quick` is the preset that finishes in minutes (a settings object always is what its
    report says: :attr:`plan_name` is read from the values, not from a flag).
    The simulated runs go to the executor (``executor``, ``jobs``, ``scheduler``)."""

    profile_minutes: float = option(
        30.0, "profiling run length, min", range=POSITIVE, shown="30; 3 with --quick"
    )
    collision_minutes: float = option(
        30.0, "collision phase length, min", range=POSITIVE, shown="30; 3 with --quick"
    )
    approach_repeats: int = option(
        10,
        "approach repeats per TF",
        "--repeats",
        range=AT_LEAST_1,
        shown="10; 3 with --quick",
    )
    sweep_duration_s: float = option(
        1.0, "seconds per sweep cell", range=POSITIVE, shown="1; 0.5 with --quick"
    )
    seed: int = option(1, "first random seed", range=AT_LEAST_0)
    seeds: int = option(5, SEEDS_HELP, range=AT_LEAST_1, shown="5; 3 with --quick")
    detector: str = option("lgmd-plus-arena", "collision detector of the study")
    adjusted: str = option("t_ffi=30", "detector overrides of the 'adjusted threshold' phase")

    QUICK: ClassVar[dict[str, Any]] = {
        "profile_minutes": 3.0,
        "collision_minutes": 3.0,
        "approach_repeats": 3,
        "sweep_duration_s": 0.5,
        "seeds": 3,
    }

    @classmethod
    def quick(cls, **overrides: Any) -> ReproduceSettings:
        """The quick preset (3-minute runs, 3 seeds), then ``overrides``."""
        return cls(**{**cls.QUICK, **{k: v for k, v in overrides.items() if v is not None}})

    @classmethod
    def make(cls, quick: bool, **kw: Any) -> ReproduceSettings:
        """The command line's: the quick preset or the paper's plan, then the given flags."""
        if quick:
            return cls.quick(**kw)
        return cls(**{k: v for k, v in kw.items() if v is not None})

    @property
    def plan_name(self) -> str:
        """``quick`` or ``full`` when the durations are a preset's, else ``custom``."""
        values = {k: getattr(self, k) for k in self.QUICK}
        if values == self.QUICK:
            return "quick"
        defaults = {f.name: f.default for f in dataclasses.fields(self) if f.name in values}
        if values == defaults:
            return "full"
        return "custom"

    @property
    def seed_list(self) -> list[int]:
        return seed_list(self.seed, self.seeds)
