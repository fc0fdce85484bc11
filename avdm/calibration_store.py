"""The shipped decoding calibrations (a, b) of the AVDM, read from ``calibrations.json``.

The file is produced by ``vdc-analyse calibrate ... --update-defaults`` and holds one entry per
camera geometry (frame rate, degrees per pixel) with the fit quality and the grid it used.
"""

from __future__ import annotations

import json
import math
from functools import cache
from importlib import resources
from typing import Any

CALIBRATION_FILE = "calibrations.json"


@cache
def shipped_calibrations() -> tuple[dict[str, Any], ...]:
    """All shipped calibration entries (read once)."""
    text = resources.files("avdm").joinpath(CALIBRATION_FILE).read_text(encoding="utf-8")
    return tuple(json.loads(text)["calibrations"])


def lookup_calibration(fps: float, deg_per_px: float) -> dict[str, Any] | None:
    """The shipped entry whose fps and deg/px match (to 1e-6 relative), or None."""
    for entry in shipped_calibrations():
        if math.isclose(entry["fps"], fps, rel_tol=1e-6) and math.isclose(
            entry["deg_per_px"], deg_per_px, rel_tol=1e-6
        ):
            return entry
    return None
