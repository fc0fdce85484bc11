"""Rendering the robot's camera (Numba) and the overhead view (OpenCV) in the simulated arena.

The on-board camera is a horizontal pinhole at ``height_m`` above the floor. Each image column
is covered by ``supersample`` sub-column rays in the horizontal plane; each ray meets a wall at
horizontal distance D and wall coordinate s. On that column the wall spans image rows from
``v_top = −(H_wall − h_cam)·L/D`` to ``v_bottom = h_cam·L/D`` (v measured down from the image
centre, L the ray's focal distance), the dim room shows above and the floor (dark, with the white
light ring) below. Pixel values are the exact area average over the sub-columns of the wall, room
and floor coverage (gratings), so a static wall seen from a still robot gives identical frames
and moving stripes do not flicker; natural-scene walls are looked up in the LED panorama at 4
sub-columns × 2 sub-rows per pixel. The floor is sampled 4× per pixel row along the column's
centre ray.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from avdm.jit import kernel
from capture.config import ArenaConfig, CameraConfig, WallConfig
from capture.tracker import CORNER_IDS, ROBOT_ID, MarkerLayout, draw_marker
from vdc.arena_geometry import ray_to_wall
from vdc.errors import UserError

TEXTURE_SUBCOLS = 4
TEXTURE_SUBROWS = 2
FLOOR_SUBROWS = 4


@kernel(nogil=True, inline="always")
def _floor_value(x, y, dx, dy, rho, hx, hy, ring_lo, ring_hi, floor_level, ring_level):
    px = x + rho * dx
    py = y + rho * dy
    g = min(hx - abs(px), hy - abs(py))  # distance to the nearest wall
    return ring_level if ring_lo <= g <= ring_hi else floor_level


@kernel(nogil=True, inline="always")
def _overlap(a0, a1, b0, b1):
    return max(0.0, min(a1, b1) - max(a0, b0))


@kernel(nogil=True, inline="always")
def _centre_ray(j, w, f, hd, x, y, hx, hy, cam_h):
    """Column ``j``'s centre ray: its direction (dx, dy), its length in the image plane per
    unit depth (px) and the image row where the wall meets the floor along it (px below the
    horizon)."""
    uc = j + 0.5 - w / 2.0
    lc = math.sqrt(f * f + uc * uc)
    phc = hd + math.atan2(-uc, f)
    dxc = math.cos(phc)
    dyc = math.sin(phc)
    dc, _ = ray_to_wall(x, y, dxc, dyc, hx, hy)
    dc = max(dc, 1e-6)
    return dxc, dyc, lc, cam_h * lc / dc


@kernel(nogil=True)
def _column_floor(x, y, dxc, dyc, lc, vb_c, r0, geom, cam_h):
    """Mean floor intensity over FLOOR_SUBROWS samples of pixel row [r0, r0+1] (centre ray)."""
    hx, hy = geom[0], geom[1]
    acc = 0.0
    for q in range(FLOOR_SUBROWS):
        v = max(r0 + (q + 0.5) / FLOOR_SUBROWS, vb_c + 1e-9)
        rho = cam_h * lc / v
        acc += _floor_value(x, y, dxc, dyc, rho, hx, hy, geom[3], geom[4], geom[5], geom[6])
    return acc / FLOOR_SUBROWS


@kernel(nogil=True)
def render_grating_frames(poses, offsets, geom, cam, grating, out):
    """Render frames of a grating wall.

    poses (N, 3) f64: x_m, y_m, heading_rad; offsets (N,) f64: drift of the pattern along s (m);
    geom: hx, hy, wall_h, ring_lo, ring_hi, floor, ring, room; cam: focal_px, cam_h, supersample;
    grating: period_m, mean, amplitude; out (N, H, W) uint8.
    """
    n_frames, h, w = out.shape
    f = cam[0]
    cam_h = cam[1]
    n_sub = int(cam[2])
    hx, hy, wall_h, room = geom[0], geom[1], geom[2], geom[7]
    period, mean, amp = grating[0], grating[1], grating[2]
    sub_i = np.empty(n_sub)
    sub_vt = np.empty(n_sub)
    sub_vb = np.empty(n_sub)
    two_pi = 2.0 * math.pi
    for n in range(n_frames):
        x, y, hd = poses[n, 0], poses[n, 1], poses[n, 2]
        off = offsets[n]
        for j in range(w):
            vt_min = 1e30
            vt_max = -1e30
            vb_min = 1e30
            vb_max = -1e30
            i_sum = 0.0
            for k in range(n_sub):
                u = j + (k + 0.5) / n_sub - w / 2.0
                lk = math.sqrt(f * f + u * u)
                phi = hd + math.atan2(-u, f)
                d, s = ray_to_wall(x, y, math.cos(phi), math.sin(phi), hx, hy)
                d = max(d, 1e-6)  # a camera touching the wall divides by nothing
                val = mean + amp * math.sin(two_pi * (s - off) / period)
                vt = -(wall_h - cam_h) * lk / d
                vb = cam_h * lk / d
                sub_i[k] = val
                sub_vt[k] = vt
                sub_vb[k] = vb
                i_sum += val
                vt_min = min(vt_min, vt)
                vt_max = max(vt_max, vt)
                vb_min = min(vb_min, vb)
                vb_max = max(vb_max, vb)
            i_mean = i_sum / n_sub
            dxc, dyc, lc, vb_c = _centre_ray(j, w, f, hd, x, y, hx, hy, cam_h)
            for i in range(h):
                r0 = i - h / 2.0
                r1 = r0 + 1.0
                if r1 <= vt_min:
                    val = room
                elif r0 >= vt_max and r1 <= vb_min:
                    val = i_mean
                elif r0 >= vb_max:
                    val = _column_floor(x, y, dxc, dyc, lc, vb_c, r0, geom, cam_h)
                else:  # an edge row: exact coverage per sub-column
                    fl = _column_floor(x, y, dxc, dyc, lc, vb_c, r0, geom, cam_h)
                    acc = 0.0
                    for k in range(n_sub):
                        acc += room * _overlap(r0, r1, -1e30, sub_vt[k])
                        acc += sub_i[k] * _overlap(r0, r1, sub_vt[k], sub_vb[k])
                        acc += fl * _overlap(r0, r1, sub_vb[k], 1e30)
                    val = acc / n_sub
                out[n, i, j] = np.uint8(min(max(val, 0.0), 1.0) * 255.0 + 0.5)


@kernel(nogil=True)
def render_texture_frames(poses, offsets, geom, cam, texture, perimeter, out):
    """Render frames of a wall showing ``texture`` (Ht, Wt) f32 intensities on [0, 1], the
    panorama spanning the whole perimeter, drifted by ``offsets`` (m) along s."""
    n_frames, h, w = out.shape
    f = cam[0]
    cam_h = cam[1]
    hx, hy, wall_h, room = geom[0], geom[1], geom[2], geom[7]
    ht, wt = texture.shape
    sub_d = np.empty(TEXTURE_SUBCOLS)
    sub_l = np.empty(TEXTURE_SUBCOLS)
    sub_c = np.empty(TEXTURE_SUBCOLS)
    n_samples = TEXTURE_SUBCOLS * TEXTURE_SUBROWS
    for n in range(n_frames):
        x, y, hd = poses[n, 0], poses[n, 1], poses[n, 2]
        off = offsets[n]
        for j in range(w):
            for k in range(TEXTURE_SUBCOLS):
                u = j + (k + 0.5) / TEXTURE_SUBCOLS - w / 2.0
                sub_l[k] = math.sqrt(f * f + u * u)
                phi = hd + math.atan2(-u, f)
                d, s = ray_to_wall(x, y, math.cos(phi), math.sin(phi), hx, hy)
                d = max(d, 1e-6)  # a camera touching the wall divides by nothing
                sub_d[k] = d
                sub_c[k] = ((s - off) % perimeter) / perimeter * wt
            dxc, dyc, lc, vb_c = _centre_ray(j, w, f, hd, x, y, hx, hy, cam_h)
            for i in range(h):
                acc = 0.0
                for q in range(TEXTURE_SUBROWS):
                    v = i - h / 2.0 + (q + 0.5) / TEXTURE_SUBROWS
                    for k in range(TEXTURE_SUBCOLS):
                        z = cam_h - v * sub_d[k] / sub_l[k]
                        if z > wall_h:
                            acc += room
                        elif z >= 0.0:
                            row = min(int((wall_h - z) / wall_h * ht), ht - 1)
                            c = sub_c[k] - 0.5
                            c0 = math.floor(c)
                            frac = c - c0
                            a = texture[row, c0 % wt]
                            b = texture[row, (c0 + 1) % wt]
                            acc += a + frac * (b - a)
                        else:
                            vv = max(v, vb_c + 1e-9)
                            acc += _floor_value(
                                x,
                                y,
                                dxc,
                                dyc,
                                cam_h * lc / vv,
                                hx,
                                hy,
                                geom[3],
                                geom[4],
                                geom[5],
                                geom[6],
                            )
                val = acc / n_samples
                out[n, i, j] = np.uint8(min(max(val, 0.0), 1.0) * 255.0 + 0.5)


class CameraRenderer:
    """Renders batches of on-board frames for given poses and wall drift offsets."""

    def __init__(
        self,
        arena: ArenaConfig,
        wall: WallConfig,
        camera: CameraConfig,
        texture: np.ndarray | None = None,
    ) -> None:
        self.camera = camera
        hx, hy = arena.half_extent
        self._geom = np.array(
            [
                hx,
                hy,
                arena.wall_height_m,
                arena.ring_inset_m,
                arena.ring_inner_m,
                arena.floor_level,
                arena.ring_level if arena.ring_enabled else arena.floor_level,
                arena.room_level,
            ],
            dtype=np.float64,
        )
        self._cam = np.array([camera.focal_px, camera.height_m, camera.supersample], np.float64)
        self._perimeter = arena.perimeter_m
        mean = 1.0 / (1.0 + wall.contrast)  # peak-normalised: the brightest LED is 1
        self._grating = np.array([wall.period_m, mean, mean * wall.contrast], np.float64)
        self._texture = None
        if wall.scene == "natural":
            if texture is None:
                raise UserError("a natural-scene wall needs its texture.")
            z = np.asarray(texture, dtype=np.float64)
            self._texture = np.ascontiguousarray(mean * (1.0 + wall.contrast * z), np.float32)

    def render(self, poses: np.ndarray, offsets_m: np.ndarray) -> np.ndarray:
        """poses (N, 3) [x_m, y_m, heading_rad], offsets_m (N,) → frames (N, H, W) uint8."""
        poses = np.ascontiguousarray(poses, dtype=np.float64)
        offsets = np.ascontiguousarray(offsets_m, dtype=np.float64)
        out = np.empty((len(poses), self.camera.height_px, self.camera.width_px), np.uint8)
        if self._texture is None:
            render_grating_frames(poses, offsets, self._geom, self._cam, self._grating, out)
        else:
            render_texture_frames(
                poses, offsets, self._geom, self._cam, self._texture, self._perimeter, out
            )
        return out


class OverheadRenderer:
    """Top-down view of the arena (floor, light ring, walls) with the robot drawn on it:
    a disc, a heading tick and a bright marker dot, as the overhead tracker would see it.
    Image x runs along arena +x; image rows run along arena −y (north up)."""

    def __init__(
        self, arena: ArenaConfig, robot_radius_m: float, px_per_m: float, markers: bool = False
    ) -> None:
        self.arena = arena
        self.px_per_m = px_per_m
        self.radius_m = robot_radius_m
        self.markers = markers
        hx, hy = arena.half_extent
        self.layout = MarkerLayout(half_extent=(hx, hy))
        margin = 0.1 if markers else 0.05
        self.width = round((2 * hx + 2 * margin) * px_per_m)
        self.height = round((2 * hy + 2 * margin) * px_per_m)
        self._margin = margin
        base = np.full((self.height, self.width), 30, np.uint8)  # the room around the arena
        floor_val = round(arena.floor_level * 255)
        ring_val = round(arena.ring_level * 255) if arena.ring_enabled else floor_val
        cv2.rectangle(base, self.to_px(-hx, hy), self.to_px(hx, -hy), floor_val, -1)
        cv2.rectangle(
            base,
            self.to_px(-hx + arena.ring_inset_m, hy - arena.ring_inset_m),
            self.to_px(hx - arena.ring_inset_m, -hy + arena.ring_inset_m),
            ring_val,
            -1,
        )
        ri = arena.ring_inner_m
        cv2.rectangle(
            base, self.to_px(-hx + ri, hy - ri), self.to_px(hx - ri, -hy + ri), floor_val, -1
        )
        cv2.rectangle(base, self.to_px(-hx, hy), self.to_px(hx, -hy), 200, 2)  # walls
        if markers:  # ArUco corner markers for the tracker's calibration
            for marker_id, (cx, cy) in zip(CORNER_IDS, self.layout.corner_centres(), strict=True):
                px, py = self._to_px_f(cx, cy)
                draw_marker(base, marker_id, (px, py), self.layout.corner_size_m * px_per_m, 0.0)
        self._base = base

    def to_px(self, x: float, y: float) -> tuple[int, int]:
        hx, hy = self.arena.half_extent
        return (
            round((x + hx + self._margin) * self.px_per_m),
            round((hy + self._margin - y) * self.px_per_m),
        )

    def _to_px_f(self, x: float, y: float) -> tuple[float, float]:
        """Sub-pixel image coordinates (pixel centres at integers) of arena point (x, y)."""
        hx, hy = self.arena.half_extent
        m = self._margin
        return (x + hx + m) * self.px_per_m - 0.5, (hy + m - y) * self.px_per_m - 0.5

    def render(self, pose: np.ndarray) -> np.ndarray:
        """One overhead frame (H, W) uint8 for pose [x_m, y_m, heading_rad]."""
        img = self._base.copy()
        x, y, hd = (float(v) for v in pose)
        if self.markers:  # the robot's marker, x axis along its heading, on a dark disc
            c = self._to_px_f(x, y)
            cv2.circle(
                img,
                (round(c[0]), round(c[1])),
                round(self.radius_m * self.px_per_m),
                60,
                -1,
                lineType=cv2.LINE_AA,
            )
            draw_marker(img, ROBOT_ID, c, self.layout.robot_size_m * self.px_per_m, hd)
            return img
        c = self.to_px(x, y)
        r = max(2, round(self.radius_m * self.px_per_m))
        cv2.circle(img, c, r, 90, -1, lineType=cv2.LINE_AA)
        tip = self.to_px(x + self.radius_m * math.cos(hd), y + self.radius_m * math.sin(hd))
        cv2.line(img, c, tip, 255, 2, lineType=cv2.LINE_AA)
        cv2.circle(img, c, max(1, r // 3), 255, -1, lineType=cv2.LINE_AA)
        return img
