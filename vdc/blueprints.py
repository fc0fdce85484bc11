"""vdc's blueprints: how the viewer lays out a recording (the entity paths are
``vdc.recording``'s). The capture sends one with every recording; the catalog registers the
arena's as its dataset's default, so a segment opens the same way as its file."""

from __future__ import annotations

from collections.abc import Sequence

import rerun.blueprint as rrb

from avdm.base import Output, primary_output_name
from vdc.recording import (
    ARENA,
    CAMERA,
    COMPLEXITY_ROOT,
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
                rrb.TimeSeriesView(
                    name="baselines, normalised (vdc-analyse complexity)", origin=COMPLEXITY_ROOT
                ),
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
