"""The power study's plans (docs/findings/power_plan.md and its amendment,
docs/findings/power_plan_amendment.md): each version's arena grid, footage collection and
detectors at their planned values, named by version in :data:`PLANS`; :data:`QUICK` and
:data:`QUICK_AMENDED` exercise every step in about a minute of CPU (not findings)."""

from __future__ import annotations

import dataclasses

from analysis.boundary.scenes import PHOTOS


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
    name: str = "2026-11"  # the plan's version: docs/findings/power_plan.md (2026-11) or its
    # amendment (2026-12, docs/findings/power_plan_amendment.md)
    collection: str = "2026-11"  # looming-footage --collection: the footage's photographs
    # the amendment: each value confirmed on the first seed of every arena condition, and on a
    # pilot of ``pilot_clips`` clips of the collection's seed ``pilot_seed`` (outside the
    # study's clips), and moved one step (``steps``: detector -> (value when fewer than
    # MOVE_BELOW fail, value when more than MOVE_ABOVE fail)) when outside 20-60 %
    confirm: bool = False
    pilot_clips: int = 0
    pilot_seed: int = 1
    steps: tuple[tuple[str, str, float, float], ...] = ()  # (source, detector, fewer, more)
    # studies that cannot inform by construction, named before the runs: run for the record,
    # left out of the verdicts and of Holm's correction over the studies
    uninformative: tuple[tuple[str, str, str], ...] = ()  # (source, detector, why)
    min_ttc_s: float = 0.5  # a later first alert is a miss (docs/findings/power_plan.md)
    # an alert earlier than this before contact is early: the object enters 1.5-3 s before
    # contact (analysis.experiments.collision.looming_footage.ENTER_S), so one earlier than 3 s
    # comes before any hazard is in view
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
# docs/findings/power_plan_amendment.md (2026-12-07): 23 scenes (21 package photographs and
# the two procedural generators, one scene each) x 3 TFs, 483 clips over 21 photographs.
PHOTO_SCENES = tuple(f"photo-{p}" for p in PHOTOS)
LGMD_FOOTAGE_CANNOT_INFORM = (
    "cannot inform by construction: LGMD+ misses almost every collision clip and rejects "
    "every near miss, so its failures are the collision clips, and whether a clip collides "
    "is drawn independently of its scene: no measure of the scene can predict it"
)
AMENDED = dataclasses.replace(
    FULL,
    name="2026-12",
    scenes=("grating", "natural", *PHOTO_SCENES),
    tf_draws=3,
    clips=483,  # 23 per photograph
    collection="2026-12",
    confirm=True,
    pilot_clips=40,
    steps=(
        ("arena", "lgmd-plus-arena", 8.0, 20.0),  # the plan's 12 -> 20 when too many fail
        ("arena", "flow-ttc", 0.4, 0.8),  # the plan's 0.6 -> 0.4 / 0.8
        ("footage", "examples.looming:Looming", 0.04, 0.01),
        ("footage", "flow-ttc", 0.7, 1.5),  # too many failing: misses, so alert earlier
    ),
    uninformative=(("footage", "lgmd-plus", LGMD_FOOTAGE_CANNOT_INFORM),),
)
MOVE_BELOW, MOVE_ABOVE = 0.20, 0.60  # the plan's band for the first-seed confirmation
QUICK_AMENDED = dataclasses.replace(
    AMENDED,
    scenes=("natural", "photo-grass", "photo-hopper"),
    tf_draws=1,
    seeds=1,
    minutes=0.25,
    clips=4,
    clip_seconds=4.0,
    clip_size=(96, 72),
    pilot_clips=2,
)
PLANS = {"2026-11": FULL, "2026-12": AMENDED}
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


def plan_of(name: str, quick: bool = False) -> StudyPlan:
    """The plan of version ``name`` (:data:`PLANS`), or its quick run."""
    if quick:
        return QUICK_AMENDED if name == "2026-12" else QUICK
    return PLANS[name]
