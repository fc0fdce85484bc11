"""The overhead tracker (OpenCV ArUco): its camera, arena calibration by homography, robot pose
per frame.

Markers (dictionary DICT_4X4_50): ids 0–3 at the arena's corners, outside the walls, centres at
``(∓(hx + inset), ∓(hy + inset))`` counter-clockwise from (−x, −y); id 10 on the robot, centred
on it, its x axis along the robot's heading. The homography maps image pixels to arena metres
(x along the long side, y along the short side); the robot's pose is its marker's centre and the
direction of its x axis through that map. A frame without the robot marker is a lost track:
no pose is invented.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import cv2
import numpy as np

from vdc.errors import UserError

DICTIONARY = cv2.aruco.DICT_4X4_50
CORNER_IDS = (0, 1, 2, 3)
ROBOT_ID = 10


@dataclasses.dataclass(frozen=True)
class MarkerLayout:
    """Where the markers are, in arena metres."""

    half_extent: tuple[float, float] = (0.7, 0.4)
    corner_inset_m: float = 0.05  # corner marker centres this far outside the walls
    corner_size_m: float = 0.05
    robot_size_m: float = 0.03

    def corner_centres(self) -> np.ndarray:
        hx, hy = self.half_extent
        d = self.corner_inset_m
        return np.array(
            [[-hx - d, -hy - d], [hx + d, -hy - d], [hx + d, hy + d], [-hx - d, hy + d]]
        )


def detector() -> cv2.aruco.ArucoDetector:
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX  # sub-pixel corners
    return cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(DICTIONARY), params)


def detect(image: np.ndarray) -> dict[int, np.ndarray]:
    """Marker id → its 4 corners (4, 2) in pixels (top-left, top-right, bottom-right, bottom-left
    of the marker's own frame)."""
    corners, ids, _ = detector().detectMarkers(image)
    if ids is None:
        return {}
    return {int(i): c.reshape(4, 2) for i, c in zip(ids.ravel(), corners, strict=True)}


def calibrate_homography(image: np.ndarray, layout: MarkerLayout) -> np.ndarray:
    """Homography (3, 3) from image pixels to arena metres, from the four corner markers.

    Raises ValueError naming the markers it could not see."""
    found = detect(image)
    missing = [i for i in CORNER_IDS if i not in found]
    if missing:
        raise UserError(f"overhead calibration: corner marker(s) {missing} not visible.")
    px = np.array([found[i].mean(axis=0) for i in CORNER_IDS], dtype=np.float64)
    h, _ = cv2.findHomography(px, layout.corner_centres(), 0)
    if h is None:
        raise UserError("overhead calibration: the corner markers give no homography.")
    return h


def save_calibration(h: np.ndarray, path: Path) -> None:
    path.write_text(json.dumps({"homography_px_to_m": h.tolist()}), encoding="utf-8")


def load_calibration(path: Path) -> np.ndarray:
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
        h = np.array(data["homography_px_to_m"], dtype=np.float64)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise UserError(f"cannot read the tracker calibration {str(path)!r}: {exc}") from None
    if h.shape != (3, 3):
        raise UserError(f"tracker calibration {str(path)!r} is not a 3x3 homography.")
    return h


def to_arena(h: np.ndarray, px: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) → arena metres (N, 2)."""
    return cv2.perspectiveTransform(px.reshape(-1, 1, 2).astype(np.float64), h).reshape(-1, 2)


def robot_pose(image: np.ndarray, h: np.ndarray) -> tuple[float, float, float] | None:
    """(x_m, y_m, heading_rad) of the robot marker, or None if it is not visible."""
    found = detect(image)
    if ROBOT_ID not in found:
        return None
    world = to_arena(h, found[ROBOT_ID])
    centre = world.mean(axis=0)
    # the marker's x axis from all four edges: the two along x, and the two along y turned by
    # −90° (corners: top-left, top-right, bottom-right, bottom-left; arena y points up)
    tl, tr, br, bl = world
    up = (tl - bl) + (tr - br)
    axis = (tr - tl) + (br - bl) + np.array([up[1], -up[0]])
    return float(centre[0]), float(centre[1]), math.atan2(axis[1], axis[0])


def draw_marker(
    canvas: np.ndarray,
    marker_id: int,
    centre_px: tuple[float, float],
    size_px: float,
    angle_rad: float,
    flip_y: bool = True,
) -> None:
    """Paint an ArUco marker (with a white quiet zone) into a grey image, rotated by
    ``angle_rad`` counter-clockwise in arena terms (image y points down when ``flip_y``)."""
    cells = 6  # 4×4 data + border
    res = 16  # source pixels per cell
    src = cv2.aruco.generateImageMarker(
        cv2.aruco.getPredefinedDictionary(DICTIONARY), marker_id, cells * res
    )
    quiet = np.full((cells * res + 2 * res, cells * res + 2 * res), 255, np.uint8)
    quiet[res:-res, res:-res] = src
    n = quiet.shape[0]
    scale = size_px * (cells + 2) / cells / n
    a = -angle_rad if flip_y else angle_rad
    m = cv2.getRotationMatrix2D((n / 2, n / 2), math.degrees(-a), scale)
    m[0, 2] += centre_px[0] - n / 2
    m[1, 2] += centre_px[1] - n / 2
    h, w = canvas.shape
    warped = cv2.warpAffine(quiet, m, (w, h), flags=cv2.INTER_AREA, borderValue=0)
    mask = (
        cv2.warpAffine(
            np.full_like(quiet, 255), m, (w, h), flags=cv2.INTER_AREA, borderValue=0
        ).astype(np.float32)
        / 255.0
    )
    canvas[:] = np.rint(canvas * (1 - mask) + warped * mask).astype(np.uint8)


def open_camera(source: str) -> cv2.VideoCapture:
    """Open a camera index or a video / image-sequence path; ValueError if it gives no frame."""
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)  # end of file is normal
    if source.isdigit():
        cap = cv2.VideoCapture(int(source))
    else:
        is_pattern = "%" in source
        if not is_pattern and not Path(source).exists():
            raise UserError(f"overhead camera {source!r}: no such file or camera index.")
        cap = cv2.VideoCapture(source, cv2.CAP_IMAGES if is_pattern else cv2.CAP_ANY)
    if not cap.isOpened():
        raise UserError(f"overhead camera {source!r} cannot be opened.")
    return cap
