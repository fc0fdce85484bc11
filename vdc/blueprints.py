"""vdc's blueprints: how the viewer lays out a recording (the entity paths are
``vdc.recording``'s). The capture sends one with every recording; the catalog registers the
arena's as its dataset's default, so a segment opens the same way as its file."""

from __future__ import annotations

from collections.abc import Sequence

import rerun as rr
import rerun.blueprint as rrb

from avdm.base import Output, primary_output_name
from vdc.recording import (
    ARENA,
    CAMERA,
    COMPLEXITY_ROOT,
    COMPLEXITY_UNITS,
    DATASET_ROOT,
    DESCRIPTION,
    EVENTS,
    FRAME_TIMELINE,
    FRAME_TIMING,
    MODEL_ROOT,
    MODEL_VARIANTS_ROOT,
    OVERHEAD,
    POSE,
    ROBOT,
    ROBOT_BODY,
    ROBOT_HEADING,
    TIME_TIMELINE,
    WALL_TF,
    dataset_measure_path,
    dataset_video_path,
    entity_name,
    model_path,
)


def default_blueprint(
    model_name: str,
    outputs: Sequence[Output],
    extra_views: Sequence[tuple[str, Sequence[str]]] = (),
) -> rrb.Blueprint:
    """Camera, top-down arena with a 30 s pose trail, model traces, wall TF, pose, events.

    ``extra_views``: (title, entity paths) of further time-series panes, e.g. the AVDM running
    beside a collision detector."""
    main = primary_output_name([o.name for o in outputs])
    main_unit = next(o.unit for o in outputs if o.name == main)
    others = [o.name for o in outputs if o.name != main]
    trail = rrb.VisibleTimeRange(
        FRAME_TIMELINE,
        start=rrb.TimeRangeBoundary.cursor_relative(seq=-1000),
        end=rrb.TimeRangeBoundary.cursor_relative(),
    )
    top_down = rrb.EyeControls3D(
        kind=rrb.Eye3DKind.Orbital,
        position=[0.0, -0.05, 1.3],
        look_target=[0.0, 0.0, 0.0],
        eye_up=[0.0, 0.0, 1.0],
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Tabs(
                    rrb.Spatial2DView(name="robot camera", origin=CAMERA),
                    rrb.Spatial2DView(name="overhead camera", origin=OVERHEAD),
                    rrb.TextDocumentView(name="about this recording", origin=DESCRIPTION),
                ),
                rrb.Spatial3DView(
                    name="arena, top-down (30 s trail)",
                    origin="/",
                    contents=[f"{ARENA}/**", ROBOT_BODY, ROBOT_HEADING, ROBOT, f"{EVENTS}/**"],
                    time_ranges=trail,
                    eye_controls=top_down,
                    line_grid=False,
                ),
                row_shares=[1, 1.4],
            ),
            rrb.Vertical(
                rrb.Tabs(
                    rrb.Vertical(
                        rrb.TimeSeriesView(
                            name=f"{model_name} {main} ({main_unit})",
                            origin=model_path(model_name, main),
                        ),
                        rrb.TimeSeriesView(
                            name=f"{model_name} other outputs",
                            origin=f"{MODEL_ROOT}/{entity_name(model_name)}",
                            contents=[model_path(model_name, o) for o in others],
                        ),
                        row_shares=[2, 1.5],
                        name="online model",
                    ),
                    # filled when `vdc-analyse compare` output is opened with this recording
                    rrb.TimeSeriesView(
                        name="model variants (vdc-analyse compare)", origin=MODEL_VARIANTS_ROOT
                    ),
                ),
                *[
                    rrb.TimeSeriesView(name=title, origin="/", contents=list(paths))
                    for title, paths in extra_views
                ],
                rrb.TimeSeriesView(name="wall TF (Hz)", origin=WALL_TF),
                rrb.TimeSeriesView(name="pose (m, rad)", origin=POSE),
                rrb.TextLogView(name="events", origin=EVENTS),
                row_shares=[3.5, *([1.5] * len(extra_views)), 1, 1.5, 1.5],
            ),
            column_shares=[1, 1.2],
        ),
        rrb.TimePanel(timeline=FRAME_TIMELINE),
        collapse_panels=False,
    )


def complexity_panes() -> rrb.Tabs:
    """``vdc-analyse complexity``'s series of a clip, once opened beside it: a pane per unit
    (deg/s, P.910, 8-bit levels, ...), each metric as measured, never rescaled to share one."""
    by_unit: dict[str, list[str]] = {}
    for metric, unit in COMPLEXITY_UNITS.items():
        by_unit.setdefault(unit, []).append(metric)
    return rrb.Tabs(
        *[
            rrb.TimeSeriesView(
                name=f"{', '.join(metrics)} ({unit})",
                origin=COMPLEXITY_ROOT,
                contents=[f"{COMPLEXITY_ROOT}/{m}" for m in metrics],
            )
            for unit, metrics in by_unit.items()
        ],
        name="vdc-analyse complexity",
    )


def video_blueprint(model_name: str, outputs: Sequence[Output]) -> rrb.Blueprint:
    """A video recording: the frame, the AVDM trace and the baseline metrics (once
    ``vdc-analyse complexity`` output is opened beside it) on one time axis, frame timing
    (repeats, drops) and events. No arena or pose: a video has none."""
    main = primary_output_name([o.name for o in outputs])
    main_unit = next(o.unit for o in outputs if o.name == main)
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                rrb.Spatial2DView(name="camera (luma, working size)", origin=CAMERA),
                rrb.Tabs(
                    rrb.TextLogView(name="events (drops, decode errors)", origin=EVENTS),
                    rrb.TextDocumentView(name="about this recording", origin=DESCRIPTION),
                ),
                row_shares=[2, 1],
            ),
            rrb.Vertical(
                rrb.TimeSeriesView(
                    name=f"{model_name} {main} ({main_unit})", origin=model_path(model_name, main)
                ),
                complexity_panes(),
                rrb.TimeSeriesView(
                    name="frame timing: repeat, dropped before, dt (s)", origin=FRAME_TIMING
                ),
                row_shares=[2, 2, 1],
            ),
            column_shares=[1, 1.3],
        ),
        rrb.TimePanel(timeline=TIME_TIMELINE),
        collapse_panels=False,
    )


def dataset_blueprint(
    cameras: Sequence[str], flagged: tuple[str, int] | None = None
) -> rrb.Blueprint:
    """A dataset episode (``vdc-analyse dataset``): each camera's video beside its measures
    (motion, change, spatial detail, sharpness, timing; one scale a pane), the episode's
    flags and its description.
    ``flagged``: (camera, frame) the time panel opens at: a selection of half a second either
    side of that frame, played in a loop (a blueprint cannot place a paused cursor; a loop
    over the selection brings it there)."""
    videos = [rrb.Spatial2DView(name=cam, origin=dataset_video_path(cam)) for cam in cameras]
    main = cameras[0]
    measures = [
        rrb.TimeSeriesView(
            name=f"{title} ({main})",
            origin=f"{DATASET_ROOT}/{entity_name(main)}/measures",
            contents=[dataset_measure_path(main, m) for m in names],
        )
        for title, names in DATASET_PANES
    ]
    panel: dict = {"timeline": FRAME_TIMELINE}
    if flagged is not None:
        _cam, frame = flagged
        panel |= {
            "play_state": "playing",
            "loop_mode": "selection",
            "time_selection": rr.encodings.AbsoluteTimeRange(
                min=max(0, frame - FLAG_CONTEXT_FRAMES), max=frame + FLAG_CONTEXT_FRAMES
            ),
        }
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(
                *videos,
                rrb.Tabs(
                    rrb.TextLogView(name="flags", origin=EVENTS),
                    rrb.TextDocumentView(name="about this episode", origin=DESCRIPTION),
                ),
                row_shares=[*([2] * len(videos)), 1],
            ),
            rrb.Vertical(*measures),
            column_shares=[1, 1.3],
        ),
        rrb.TimePanel(**panel),
        collapse_panels=False,
    )


# frames either side of a flagged frame in the loop a flagged episode opens with (half a second
# at LeRobot's usual 30 fps: long enough to see a freeze or a jump, short enough to stay on it)
FLAG_CONTEXT_FRAMES = 15
# the measure panes of a dataset episode: (title, per-frame columns of frames.parquet)
DATASET_PANES = (
    (
        "motion: TI, mean frame difference (levels), deg/s",
        ("ti_p910", "mafd", "omega_dps", "flow_dps"),
    ),
    ("change from the frame before (grey levels)", ("change_max", "change2_max")),
    ("spatial information and mean grey (levels)", ("si_p910", "mean_grey")),
    ("sharpness (Laplacian variance)", ("sharpness",)),
    ("timing and stillness (0/1, frames)", ("repeat", "dropped_before", "frozen", "still")),
)
