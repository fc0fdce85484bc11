"""The arena's one ray-to-wall function against a plain ray march (no shared formula)."""

import math

import numpy as np

from vdc.arena_geometry import distance_ahead, distance_to_wall_along, ray_to_wall


def _march(x: float, y: float, heading: float, hx: float, hy: float) -> float:
    """Step along the ray in 0.1 mm until it leaves the rectangle: the distance to ±0.1 mm."""
    step, d = 1e-4, 0.0
    c, s = math.cos(heading), math.sin(heading)
    while abs(x + d * c) <= hx and abs(y + d * s) <= hy:
        d += step
    return d


def test_the_distance_matches_a_ray_march_and_s_runs_round_the_perimeter() -> None:
    rng = np.random.default_rng(3)
    hx, hy = 0.7, 0.4
    for _ in range(60):
        x, y = rng.uniform(-hx + 0.01, hx - 0.01), rng.uniform(-hy + 0.01, hy - 0.01)
        h = rng.uniform(-math.pi, math.pi)
        d, s = ray_to_wall(x, y, math.cos(h), math.sin(h), hx, hy)
        assert abs(d - _march(x, y, h, hx, hy)) < 2e-4  # the march's own step, twice
        assert distance_ahead(x, y, h, hx, hy) == d
        assert 0.0 <= s <= 4 * (hx + hy)
        # s starts at the (−hx, −hy) corner and runs counter-clockwise along the bottom wall
        px, py = x + d * math.cos(h), y + d * math.sin(h)
        if abs(py + hy) < 1e-9:
            assert s == np.float64(px + hx) or abs(s - (px + hx)) < 1e-9
    out = distance_to_wall_along(np.array([0.0, np.nan]), np.array([0.0, 0.0]), np.zeros(2), hx, hy)
    assert out[0] == hx and np.isnan(out[1])
