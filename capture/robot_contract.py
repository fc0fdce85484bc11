"""What a robot announced, held against what it sends: the checks behind the handshake.

A robot's ANNOUNCE (``capture.serial_protocol.Announcement``) is its word on the model it runs,
the model's outputs and its camera. The host takes it only when the camera is sane and the
model is the one asked for, compared by its parameters (``avdm:beta=0.25`` is ``avdm``); then
every FRAME is held to it: the announced (or, for older firmware, the assumed) raster, the
model's number of outputs, no infinite value. A fault in the first frame refuses the robot
before any file is written; a fault later ends the run after the frames before it
(``capture.robot_capture``). Each check says what is wrong in one line.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from avdm.base import Model
from avdm.registry import canonical_name, make_model, same_model
from capture.serial_protocol import Announcement, FramePacket
from vdc.errors import UserError


def accepted_model(a: Announcement, asked: str) -> Model:
    """The host's model for the robot's announcement ``a`` (built on the announced camera) when
    the robot runs the model ``asked`` for, with its outputs in the same order and units;
    ValueError in one line when the camera is not sane or the model differs."""
    want = canonical_name(asked)
    robot_outputs = [f"{n} [{u}]" for n, u in a.outputs]
    problem = a.problem()
    if problem is not None:
        raise UserError(f"the robot announces {problem}: its firmware sends a broken camera.")
    # by parameters, not spelling: a robot running avdm:beta=0.25 runs avdm (beta 0.25)
    if not same_model(a.model, want, **a.model_context()):
        raise UserError(
            f"the robot runs {a.model} (outputs {', '.join(robot_outputs) or 'none'}), not "
            f"--model {asked}: give --model {a.model}, or load {want} on the robot."
        )
    try:
        host = make_model(want, **a.model_context())
    except ValueError as exc:
        raise UserError(f"the robot's announced camera does not fit {want}: {exc}") from None
    host_outputs = [f"{o.name} [{o.unit}]" for o in host.outputs]
    if robot_outputs != host_outputs:
        raise UserError(
            f"the robot's {a.model} sends {len(robot_outputs)} outputs "
            f"({', '.join(robot_outputs) or 'none'}) but {want} has {len(host_outputs)} "
            f"({', '.join(host_outputs)}): the robot's firmware and vdc disagree on the model."
        )
    return host


def frame_problem(
    pkt: FramePacket,
    context: Mapping[str, float | int],
    model_name: str,
    output_names: Sequence[str],
) -> str | None:
    """Why ``pkt`` is not a frame of the camera ``context`` (``width_px``, ``height_px``) and
    of the model ``model_name`` with ``output_names``, in a few words, or None: its size
    (sent even when the image is decimated away), its number of outputs, infinite values."""
    want = (int(context["width_px"]), int(context["height_px"]))
    if (pkt.width, pkt.height) != want:
        return (
            f"frame {pkt.index} is {pkt.width}x{pkt.height} px, the camera {want[0]}x{want[1]} px"
        )
    if len(pkt.outputs) != len(output_names):
        return (
            f"frame {pkt.index} carries {len(pkt.outputs)} outputs, "
            f"{model_name} has {len(output_names)}"
        )
    bad = [n for n, v in zip(output_names, pkt.outputs, strict=True) if math.isinf(v)]
    if bad:
        return f"frame {pkt.index} has infinite {', '.join(bad)}"
    return None


def announcement_change(
    a: Announcement,
    started: Announcement | None,
    asked: str,
    model_name: str,
    context: Mapping[str, float | int],
) -> str | None:
    """Why a mid-run ANNOUNCE ``a`` ends a run that ``started`` with that announcement (None:
    unannounced, on the assumed camera ``context``) running ``model_name``, in one line; None
    when ``a`` repeats it (a robot announces after every START, so after a reconnection)."""
    if started is not None and a == started:
        return None
    if started is None and a.problem() is None:
        # an unannounced start, announced now: the model asked for on the camera assumed?
        if same_model(a.model, asked, **a.model_context()) and a.model_context() == dict(context):
            return None
    return (
        f"mid-run the robot announces {a.model} on a {a.width_px}x{a.height_px} camera at "
        f"{a.fps:g} Hz, not the {model_name} on a {context['width_px']}x{context['height_px']} "
        f"camera at {context['fps']:g} Hz it started with"
    )
