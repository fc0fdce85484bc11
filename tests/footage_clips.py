"""Labelled clips the tests render themselves: a dark object looming (on a collision course)
over a drifting textured background, with the frame of collision known, and background-only
clips with nothing colliding; encoded as H.264 files with a labels table."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import polars as pl

from analysis.boundary.settings import BoundarySettings
from tests.helpers import write_video

SIZE = (120, 160)  # H, W
FPS = 25.0
COLLISION_FRAME = 99  # the object reaches the camera here (4 s in); the clip ends with it
LOOM_K_PX = 60.0  # the object's image radius is LOOM_K_PX / frames-to-collision


CONTRAST = 30.0  # the texture's standard deviation, grey levels (before clipping to 70-190)


def texture(seed: int, width: int, contrast: float = CONTRAST) -> np.ndarray:
    """A smooth random texture (H, width) uint8 of standard deviation ``contrast`` grey levels
    about 130, clipped to 70-190 (never as dark as the object)."""
    rng = np.random.default_rng(seed)
    noise = rng.normal(size=(SIZE[0], width)).astype(np.float32)
    smooth = cv2.GaussianBlur(noise, (0, 0), 3.0)
    smooth = (smooth - smooth.mean()) / (smooth.std() + 1e-9)
    return np.clip(130 + contrast * smooth, 70, 190).astype(np.uint8)


def render_clip(
    drift_px: float, looming: bool, seed: int, contrast: float = CONTRAST
) -> np.ndarray:
    """Frames (T, H, W) uint8: the texture drifting ``drift_px`` px per frame to the left and,
    if ``looming``, a dark disc at the centre whose radius grows as 1 / time to collision."""
    h, w = SIZE
    n = COLLISION_FRAME + 1
    tex = texture(seed, w + int(np.ceil(abs(drift_px) * n)) + 2, contrast)
    yy, xx = np.mgrid[0:h, 0:w]
    r2 = (yy - h / 2 + 0.5) ** 2 + (xx - w / 2 + 0.5) ** 2
    frames = np.empty((n, h, w), np.uint8)
    for t in range(n):
        shift = drift_px * t
        i = int(shift)
        frac = shift - i
        f = (1 - frac) * tex[:, i : i + w] + frac * tex[:, i + 1 : i + 1 + w]
        if looming:
            radius = LOOM_K_PX / max(COLLISION_FRAME - t, 0.5)
            f = np.where(r2 <= radius**2, 20.0, f)
        frames[t] = np.rint(f).astype(np.uint8)
    return frames


def write_collection(
    folder: Path,
    drifts: tuple[float, ...] = (0.0, 1.5, 5.0),
    seeds: tuple[int, ...] = (1, 2),
    contrasts: tuple[float, ...] = (CONTRAST,),
) -> Path:
    """Render and encode every (drift, contrast, looming or not, seed) clip into ``folder``;
    write and return its labels table (``labels.csv``). A contrast other than the default is
    in the clip's name (``-c<contrast>``)."""
    folder.mkdir(parents=True, exist_ok=True)
    rows = []
    for drift in drifts:
        for contrast in contrasts:
            tag = "" if contrast == CONTRAST else f"-c{contrast:g}"
            for looming in (True, False):
                for seed in seeds:
                    name = f"{'loom' if looming else 'bg'}-drift{drift:g}{tag}-s{seed}.mp4"
                    frames = render_clip(drift, looming, seed, contrast)
                    write_video(folder / name, frames, FPS)
                    rows.append(
                        {
                            "clip": name,
                            "label": "looming" if looming else "background",
                            "collision_frame": COLLISION_FRAME if looming else None,
                        }
                    )
    path = folder / "labels.csv"
    pl.DataFrame(rows, schema_overrides={"collision_frame": pl.Int64}).write_csv(path)
    return path


def looming_boundary_settings(labels: Path, **overrides: Any) -> BoundarySettings:
    """Footage mode on a collection's ``labels`` with the guides' OpenCV looming detector at
    threshold 0.05 (a 60° field of view, one job); ``overrides`` replace any of these."""
    fields = {"labels": str(labels), "fov_deg": 60.0, "detector": "examples.looming:Looming"}
    fields |= {"param": "threshold", "values": "0.05", "jobs": 1}
    return BoundarySettings(**(fields | overrides))
