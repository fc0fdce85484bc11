"""How every capture (sim, robot, video) starts its recording: one model description, one
description document, one order of writing.

:func:`model_sections` is the one writer of a capture's model description: the ``model``,
``model_params`` and ``model_context`` property sections (``vdc.recording.PROPERTY_SECTIONS``)
that analysis rebuilds the online model from. :func:`start_recording` opens the
:class:`~capture.recorder.Recorder`, sends the properties with that description, logs the model's
output units and a short markdown description of the recording (what was recorded, with which
model and camera, and how to analyse it) at ``vdc.recording.DESCRIPTION``. What was recorded is
the device's to say (``capture.device.DescribedDevice``: its properties and description).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from capture.device import DescribedDevice
from capture.recorder import Recorder
from vdc.provenance import machine_info, package_versions

if TYPE_CHECKING:  # the Rerun SDK loads only when a recording starts
    import rerun.blueprint as rrb

    from avdm.base import Model


def model_sections(
    model: Model, context: Mapping[str, float | int], **model_fields: Any
) -> dict[str, dict[str, Any]]:
    """The model description of a capture: ``model`` (name, output units as JSON, and
    ``model_fields`` such as ``verified`` or ``true_time``), ``model_params`` (the resolved
    parameters) and ``model_context`` (fps, deg/px, texture row, raster the model is built
    with: ``vdc.recording.camera_model_context``)."""
    return {
        "model": {
            "name": model.name,
            "outputs": json.dumps({o.name: o.unit for o in model.outputs}),
            **model_fields,
        },
        "model_params": {k: v for k, v in model.params.to_dict().items() if v is not None},
        "model_context": dict(context),
    }


def camera_line(context: Mapping[str, float | int]) -> str:
    """``99 x 72 px at 33 Hz, 0.7071 deg/px (70 deg wide), texture row 36``."""
    w, h = int(context["width_px"]), int(context["height_px"])
    dpp = float(context["deg_per_px"])
    return (
        f"{w} x {h} px at {float(context['fps']):.6g} Hz, {dpp:.4g} deg/px "
        f"({dpp * w:.4g} deg wide), texture row {int(context['texture_row'])}"
    )


def description_markdown(
    recording_id: str,
    what: str,
    model: Model,
    context: Mapping[str, float | int],
    analyse: Sequence[str],
    model_note: str = "",
) -> str:
    """The recording's description: what, model (outputs with units), camera, how to analyse.

    ``analyse`` holds ``vdc-analyse`` command lines with ``REC`` for the recording's path."""
    outputs = ", ".join(f"`{o.name}` [{o.unit}]" for o in model.outputs)
    lines = [
        f"# vdc recording `{recording_id}`",
        "",
        f"**What**: {what}",
        "",
        f"**Model**: `{model.name}`{f' ({model_note})' if model_note else ''}; "
        f"outputs {outputs}, logged per frame under `/model/`.",
        "",
        f"**Camera** (the model's `model_context`): {camera_line(context)}.",
        "",
        "**Analyse** (REC is this file):",
        "",
        *[f"    {cmd}" for cmd in analyse],
        "",
        "The recording's properties hold every setting; `docs/guides/analysis.md` explains the "
        "tables.",
    ]
    return "\n".join(lines) + "\n"


def start_recording(
    partial: Path,
    recording_id: str,
    *,
    device: DescribedDevice,
    blueprint: rrb.Blueprint,
    live_url: str | None,
    model: Model,
    context: Mapping[str, float | int],
    analyse: Sequence[str],
    sections: Mapping[str, Mapping[str, Any]] | None = None,
    model_fields: Mapping[str, Any] | None = None,
    model_note: str = "",
) -> Recorder:
    """Open the recording of a capture at ``partial`` and write what every capture writes
    first: the properties (the ``device``'s own, with ``sections`` merged in, the recording id
    in ``run``, the ``provenance`` and the model description of :func:`model_sections`), the
    model's output units and the description document (what: the device's description).
    Returns the recorder."""

    props = device.properties()
    for name, section in (sections or {}).items():
        props[name] = {**props.get(name, {}), **section}
    props["run"] = {"recording_id": recording_id, **props.get("run", {})}
    props["provenance"] = {**package_versions(), **machine_info()}
    props |= model_sections(model, context, **dict(model_fields or {}))
    recorder = Recorder(partial, recording_id, blueprint=blueprint, live_url=live_url)
    recorder.send_properties(props)
    recorder.log_model_meta(model.name, model.outputs)
    what = device.description()
    text = description_markdown(recording_id, what, model, context, analyse, model_note)
    recorder.log_description(text)
    return recorder
