"""An optic-flow time-to-contact detector: collision warning from the expansion of the flow field.

Unlike LGMD+ (and examples/looming.py) it is not built on frame differences. Each
frame, dense optic flow from the previous frame is measured (OpenCV's Farnebäck polynomial-
expansion flow). The field is cut into ``cells`` x ``cells`` regions; in each, an affine flow
``u = a0 + a1 x + a2 y, v = b0 + b1 x + b2 y`` is fitted by least squares, weighted by the
local image structure (squared gradient: flow is only measured where there is texture). Its
divergence ``a1 + b2`` (1/frame) is the expansion rate of that region.

An object approaching at constant speed, or a surface approached head-on, grows in the image
as ``1 / (time to contact)``: between frames ``t - 1`` and ``t`` its image scales by
``k = τ(t - 1) / τ(t) = 1 + 1/τ(t)`` (``τ`` in frames), so the flow is ``(k - 1)·x`` about
the focus of expansion and its divergence is ``2 / τ(t)``. Hence

    tau_s = 2 / (divergence · fps),

exact for a constant approach speed, taken from the most expanding region with enough texture
(the obstacle ahead, not the background). A pure camera rotation moves the image without
expanding it (divergence 0 up to lens distortion), which is what frame-difference detectors
cannot tell from a looming object. The detector alerts once ``tau_s`` has been below
``tau_alert_s`` for ``n_confirm`` frames in a row.

``run`` is repeated ``step`` (one code path), so the two agree bit for bit, and a recording can
be processed in chunks.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import cv2
import numpy as np

from avdm.base import Output, Params, check_frames, run_by_steps
from avdm.errors import ParameterError

FLOW_TTC_OUTPUTS: tuple[Output, ...] = (
    Output("tau_s", "s", "time to contact from the most expanding region (tau_max_s: none)"),
    Output("divergence_hz", "1/s", "expansion rate (flow divergence) of that region"),
    Output("alert", "1", "collision alert (1) or not (0)"),
)
FLOW_TTC_OUTPUT_NAMES = tuple(o.name for o in FLOW_TTC_OUTPUTS)


@dataclasses.dataclass(frozen=True)
class FlowTtcParams(Params):
    """Parameters of the flow time-to-contact detector (times in seconds, sizes in px)."""

    fps: float = 30.0
    tau_alert_s: float = 1.0  # alert below this time to contact
    n_confirm: int = 2  # frames in a row below tau_alert_s before the alert (noise)
    cells: int = 3  # the field is fitted in cells x cells regions
    min_texture: float = 4.0  # a region's RMS gradient (grey levels/px) to count at all
    tau_max_s: float = 60.0  # reported when nothing expands (a finite stand-in for "never")
    levels: int = 3  # Farnebäck: pyramid levels
    winsize: int = 9  # Farnebäck: averaging window (px)
    iterations: int = 3  # Farnebäck: iterations per level

    def __post_init__(self) -> None:
        self.check_ranges(
            "flow-ttc",
            positive=("fps", "tau_alert_s", "min_texture", "tau_max_s"),
            integers=(
                ("n_confirm", 1, 100),
                ("cells", 1, 16),
                ("levels", 1, 8),
                ("winsize", 3, 99),
                ("iterations", 1, 20),
            ),
        )
        if self.tau_alert_s >= self.tau_max_s:
            raise ParameterError(
                f"flow-ttc parameter tau_alert_s={self.tau_alert_s!r}: must be below "
                f"tau_max_s={self.tau_max_s!r}."
            )


def _cell_edges(n: int, margin: int, cells: int) -> np.ndarray:
    return np.linspace(margin, n - margin, cells + 1).round().astype(int)


def region_divergence(
    flow: np.ndarray, weight: np.ndarray, cells: int, min_weight: float, margin: int = 0
) -> np.ndarray:
    """Divergence (1/frame) of the weighted least-squares affine fit in each region.

    ``flow`` (H, W, 2) float32 px/frame, ``weight`` (H, W) float >= 0; the regions tile the
    raster inside a border of ``margin`` px. Returns (cells, cells) float64, NaN where a
    region's mean weight is below ``min_weight`` or its fit is singular.
    """
    h, w = weight.shape
    ys, xs = _cell_edges(h, margin, cells), _cell_edges(w, margin, cells)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    # centred per region, the normal equations stay well conditioned: x, y relative to the
    # region's centre
    cy = (ys[:-1] + ys[1:]) / 2.0
    cx = (xs[:-1] + xs[1:]) / 2.0
    row_of = np.clip(np.searchsorted(ys, np.arange(h), side="right") - 1, 0, cells - 1)
    col_of = np.clip(np.searchsorted(xs, np.arange(w), side="right") - 1, 0, cells - 1)
    x = xx - cx[col_of][None, :]
    y = yy - cy[row_of][:, None]
    wt = weight.astype(np.float64)
    u = flow[..., 0].astype(np.float64)
    v = flow[..., 1].astype(np.float64)
    terms = np.stack(
        [
            wt,
            wt * x,
            wt * y,
            wt * x * x,
            wt * x * y,
            wt * y * y,
            wt * u,
            wt * x * u,
            wt * y * u,
            wt * v,
            wt * x * v,
            wt * y * v,
        ]
    )
    sums = np.add.reduceat(np.add.reduceat(terms, ys[:-1], axis=1), xs[:-1], axis=2)
    out = np.full((cells, cells), np.nan)
    for i in range(cells):
        for j in range(cells):
            s = sums[:, i, j]
            area = (ys[i + 1] - ys[i]) * (xs[j + 1] - xs[j])
            if area < 9 or s[0] / area < min_weight:
                continue
            normal = np.array([[s[0], s[1], s[2]], [s[1], s[3], s[4]], [s[2], s[4], s[5]]])
            if np.linalg.cond(normal) > 1e8:
                continue
            cu = np.linalg.solve(normal, s[6:9])
            cv = np.linalg.solve(normal, s[9:12])
            out[i, j] = cu[1] + cv[2]  # du/dx + dv/dy
    return out


class FlowTtc:
    """Optic-flow time-to-contact detector; outputs ``FLOW_TTC_OUTPUTS`` (see the module)."""

    outputs: ClassVar[tuple[Output, ...]] = FLOW_TTC_OUTPUTS

    def __init__(self, params: FlowTtcParams, name: str = "flow-ttc") -> None:
        self.name = name
        self.params = params
        self.reset()

    def reset(self) -> None:
        """Forget all history; the next frame is treated as the first."""
        self._prev: np.ndarray | None = None
        self._is_u8: bool | None = None
        self._below = 0

    def _levels(self, frame: np.ndarray) -> np.ndarray:
        """Grey levels 0-255 as float32 (uint8 as is; float frames are on [0, 1])."""
        if frame.dtype == np.uint8:
            return frame.astype(np.float32)
        return (np.clip(frame, 0.0, 1.0) * 255.0).astype(np.float32)

    def step(self, frame: np.ndarray) -> dict[str, float]:
        """Process one frame (H, W), uint8 or float on [0, 1]; ``{output: float}``."""
        arr = np.asarray(frame)
        if arr.ndim != 2:
            raise ParameterError(
                f"a frame must have shape (H, W), got an array of shape {arr.shape}."
            )
        arr = check_frames(arr[None], min_h=3, min_w=3)[0]
        is_u8 = arr.dtype == np.uint8
        cur = self._levels(arr)
        p = self.params
        prev = self._prev
        if prev is not None and prev.shape != cur.shape:
            raise ParameterError(
                f"frame shape changed from {prev.shape[1]}x{prev.shape[0]} to "
                f"{cur.shape[1]}x{cur.shape[0]} px (WxH); call reset() first."
            )
        if prev is not None and is_u8 != self._is_u8:
            raise ParameterError("frame dtype changed between uint8 and float; call reset() first.")
        self._prev, self._is_u8 = cur, is_u8
        if prev is None:  # no motion before the first frame
            return {"tau_s": p.tau_max_s, "divergence_hz": 0.0, "alert": 0.0}
        flow = cv2.calcOpticalFlowFarneback(
            prev, cur, None, 0.5, p.levels, p.winsize, p.iterations, 5, 1.1, 0
        )
        gx = cv2.Sobel(prev, cv2.CV_32F, 1, 0, ksize=3) / 8.0  # grey levels per px
        gy = cv2.Sobel(prev, cv2.CV_32F, 0, 1, ksize=3) / 8.0
        weight = gx * gx + gy * gy
        div = region_divergence(flow, weight, p.cells, p.min_texture**2, p.winsize)
        top = float(np.nanmax(div)) if np.isfinite(div).any() else 0.0
        div_hz = max(top, 0.0) * p.fps
        tau = min(2.0 / div_hz, p.tau_max_s) if div_hz > 0 else p.tau_max_s
        self._below = self._below + 1 if tau < p.tau_alert_s else 0
        alert = 1.0 if self._below >= p.n_confirm else 0.0
        return {"tau_s": float(tau), "divergence_hz": float(div_hz), "alert": alert}

    def run(self, frames: np.ndarray) -> dict[str, np.ndarray]:
        """Process frames (T, H, W), uint8 or float on [0, 1]; ``{output: (T,) float64}``."""
        return run_by_steps(self.step, frames, FLOW_TTC_OUTPUT_NAMES, min_h=3, min_w=3)
