"""The arena's geometry, written once: where a ray from a point inside the rectangular arena
meets its wall. The renderer (every camera column), the closed loop (distance ahead, per frame)
and the tables (an event's distance to the wall) all ask this one question."""

from __future__ import annotations

import math

import numpy as np

from avdm.jit import kernel

_BIG = 1e30  # "never": a ray parallel to a pair of walls


@kernel(nogil=True, inline="always")
def ray_to_wall(
    x: float, y: float, dx: float, dy: float, hx: float, hy: float
) -> tuple[float, float]:
    """Horizontal distance (m) from (x, y) along the unit direction (dx, dy) to the wall of the
    rectangle [−hx, hx] × [−hy, hy], and the wall coordinate s (m, counter-clockwise from the
    (−hx, −hy) corner) where it lands. From inside the arena the distance is finite."""
    tx = (hx - x) / dx if dx > 1e-12 else ((-hx - x) / dx if dx < -1e-12 else _BIG)
    ty = (hy - y) / dy if dy > 1e-12 else ((-hy - y) / dy if dy < -1e-12 else _BIG)
    if tx < ty:
        d = tx
        yh = y + d * dy
        s = 2 * hx + (yh + hy) if dx > 0 else 4 * hx + 2 * hy + (hy - yh)
    else:
        d = ty
        xh = x + d * dx
        s = xh + hx if dy < 0 else 2 * hx + 2 * hy + (hx - xh)
    return d, s


def distance_ahead(x: float, y: float, heading_rad: float, hx: float, hy: float) -> float:
    """Distance (m) from (x, y) along ``heading_rad`` to the arena's wall."""
    return ray_to_wall(x, y, math.cos(heading_rad), math.sin(heading_rad), hx, hy)[0]


@kernel(nogil=True)
def _distances(x, y, heading, hx, hy, out):  # pragma: no cover - compiled
    for i in range(x.shape[0]):
        if math.isnan(x[i]) or math.isnan(y[i]) or math.isnan(heading[i]):
            out[i] = math.nan
        else:
            out[i] = ray_to_wall(x[i], y[i], math.cos(heading[i]), math.sin(heading[i]), hx, hy)[0]


def distance_to_wall_along(
    x: np.ndarray, y: np.ndarray, heading_rad: np.ndarray, hx: float, hy: float
) -> np.ndarray:
    """(N,) float64 distances (m) from each (x, y) along ``heading_rad`` to the wall; NaN where
    any input is NaN."""
    x, y, h = (np.ascontiguousarray(a, dtype=np.float64) for a in (x, y, heading_rad))
    out = np.empty(x.shape[0], dtype=np.float64)
    _distances(x, y, h, float(hx), float(hy), out)
    return out
