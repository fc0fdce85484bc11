"""LGMD collision detectors, fast path (Numba): LGMD+ and the Colias firmware port.

The layer-by-layer NumPy versions are in ``avdm.lgmd_reference`` (the test oracles); these
kernels compute the same arithmetic in the same order on edge-padded float64 buffers so that the
3×3 stencils need no branches. ``run`` equals repeated ``step`` bit for bit (one kernel), and a
recording can be processed in chunks.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np

from avdm.base import Output, check_frames
from avdm.errors import ParameterError
from avdm.jit import kernel
from avdm.lgmd_params import (
    LGMD_OUTPUT_NAMES,
    LGMD_OUTPUTS,
    LgmdColiasParams,
    LgmdPlusParams,
    bias_matrix,
    frame_interval_ms,
    lowpass_alpha,
)
from avdm.lgmd_reference import GAUSS_CENTRE, GAUSS_CORNER, GAUSS_EDGE

_N_OUT = len(LGMD_OUTPUTS)


@kernel(nogil=True, inline="always")
def _replicate_edges(a):
    """Fill the 1-px frame of a padded (H+2, W+2) buffer with its nearest interior values."""
    hp, wp = a.shape
    for y in range(1, hp - 1):
        a[y, 0] = a[y, 1]
        a[y, wp - 1] = a[y, wp - 2]
    for x in range(wp):
        a[0, x] = a[1, x]
        a[hp - 1, x] = a[hp - 2, x]


@kernel(nogil=True, inline="always")
def _levels(frames, i, y, x, is_u8):
    if is_u8:
        return np.float64(frames[i, y, x])
    v = min(max(np.float64(frames[i, y, x]), 0.0), 1.0) * 255.0
    return np.float64(np.rint(v))


@kernel(nogil=True)
def _lgmd_plus_kernel(frames, is_u8, cfg, wloc, lum_prev, bufs, g_prev, scal, spikes_ring, out):
    """Advance LGMD+ over frames (T, H, W).

    cfg: dt, alpha_f, t_ffi, w_base, tau_g, delta_c, clip, dc, a_e0, a_e1, a_e2, w_on, w_off,
    w_onoff, c_w, c_de, t_de, c_sig, h_sfa, t_sfa, k_sp, t_sp, t_sr, blur_truncate.
    bufs (6, H+2, W+2): P, ON now, ON prev, OFF now, OFF prev, S (padded).
    scal: f, smp, sfa, started, counter.
    """
    n, h, w = frames.shape
    dt, alpha_f, t_ffi, w_base, tau_g, delta_c = cfg[0], cfg[1], cfg[2], cfg[3], cfg[4], cfg[5]
    clip, dc, a0, a1, a2 = cfg[6], cfg[7], cfg[8], cfg[9], cfg[10]
    w_on, w_off, w_onoff, c_w, c_de, t_de = cfg[11], cfg[12], cfg[13], cfg[14], cfg[15], cfg[16]
    c_sig, h_sfa, t_sfa, k_sp, t_sp, t_sr = cfg[17], cfg[18], cfg[19], cfg[20], cfg[21], cfg[22]
    truncate = cfg[23] > 0.5
    alphas = (a0, a1, a2)
    gauss = (GAUSS_CENTRE, GAUSS_EDGE, GAUSS_CORNER)
    n_ts = spikes_ring.shape[0]
    pp = bufs[0]
    sp = bufs[5]
    ce = np.empty((h, w))
    for i in range(n):
        on_now, on_prev = bufs[1], bufs[2]
        off_now, off_prev = bufs[3], bufs[4]
        if scal[3] == 0.0:  # before the first frame: the same frame, all layers at 0
            for y in range(h):
                for x in range(w):
                    lum_prev[y, x] = _levels(frames, i, y, x, is_u8)
            scal[3] = 1.0
        abs_sum = 0.0
        for y in range(h):  # 1. photoreceptors
            for x in range(w):
                v = _levels(frames, i, y, x, is_u8)
                p = v - lum_prev[y, x]
                lum_prev[y, x] = v
                pp[y + 1, x + 1] = p
                abs_sum += abs(p)
        _replicate_edges(pp)
        f = alpha_f * (abs_sum / (h * w)) + (1.0 - alpha_f) * scal[0]  # 3. FFI
        scal[0] = f
        sigma = 1.0 - f / t_ffi  # 4.
        if sigma < 0.0:
            sigma = delta_c
        alpha_g = dt / (dt + tau_g * sigma)
        beta = max(f / t_ffi, w_base)  # 5.
        for y in range(h):  # 2. blur and 6. ON/OFF with DC residue
            for x in range(w):
                acc = 0.0
                for di in range(-1, 2):
                    for dj in range(-1, 2):
                        k = abs(di) + abs(dj)
                        term = gauss[k] * pp[y + 1 + di, x + 1 + dj]
                        acc += np.trunc(term) if truncate else term
                on_now[y + 1, x + 1] = (acc if acc >= clip else 0.0) + dc * on_prev[y + 1, x + 1]
                off_now[y + 1, x + 1] = (abs(acc) if acc < clip else 0.0) + dc * off_prev[
                    y + 1, x + 1
                ]
        _replicate_edges(on_now)
        _replicate_edges(off_now)
        for y in range(h):  # 7. delayed inhibition, 8. bias, 9. summation
            for x in range(w):
                i_on = 0.0
                i_off = 0.0
                for di in range(-1, 2):
                    for dj in range(-1, 2):
                        k = abs(di) + abs(dj)
                        wk = 1.0 if k == 0 else (0.25 if k == 1 else 0.125)
                        ak = alphas[k]
                        yy = y + 1 + di
                        xx = x + 1 + dj
                        i_on += wk * (ak * on_now[yy, xx] + (1.0 - ak) * on_prev[yy, xx])
                        i_off += wk * (ak * off_now[yy, xx] + (1.0 - ak) * off_prev[yy, xx])
                inh = wloc[y, x] * beta
                s_on = max(on_now[y + 1, x + 1] - inh * i_on, 0.0)
                s_off = max(off_now[y + 1, x + 1] - inh * i_off, 0.0)
                sp[y + 1, x + 1] = w_on * s_on + w_off * s_off + w_onoff * s_on * s_off
        _replicate_edges(sp)
        ce_max = 0.0
        for y in range(h):  # 10. grouping
            for x in range(w):
                acc = 0.0
                for di in range(-1, 2):
                    for dj in range(-1, 2):
                        acc += sp[y + 1 + di, x + 1 + dj]
                c = acc / 9.0
                ce[y, x] = c
                ce_max = max(ce_max, abs(c))
        omega = delta_c + ce_max / c_w
        mp = 0.0
        for y in range(h):
            for x in range(w):
                gt = sp[y + 1, x + 1] * ce[y, x] / omega
                if gt * c_de < t_de:
                    gt = 0.0
                g = alpha_g * gt + (1.0 - alpha_g) * g_prev[y, x]
                g_prev[y, x] = g
                mp += g
        smp = 1.0 / (1.0 + math.exp(-mp / (h * w * c_sig)))  # 11.
        d = smp - scal[1]  # 12.
        sfa = max(0.5, h_sfa * (scal[2] + d)) if d <= t_sfa else max(0.5, h_sfa * smp)
        scal[1] = smp
        scal[2] = sfa
        spikes = math.floor(math.exp(k_sp * (sfa - t_sp)))  # 13.
        slot = int(scal[4]) % n_ts
        spikes_ring[slot] = spikes
        total = 0
        for q in range(n_ts):
            total += spikes_ring[q]
        rate = 1000.0 * total / (n_ts * dt)  # 14.
        out[i, 0] = rate
        out[i, 1] = 1.0 if rate >= t_sr else 0.0
        out[i, 2] = spikes
        out[i, 3] = mp
        out[i, 4] = smp
        out[i, 5] = sfa
        out[i, 6] = f
        scal[4] += 1.0
        on_prev[:, :] = on_now  # the current ON/OFF become the previous ones
        off_prev[:, :] = off_now


@kernel(nogil=True)
def _lgmd_colias_kernel(frames, is_u8, cfg, lum_prev, bufs, scal, spikes_ring, out):
    """Advance the Colias firmware port over frames (T, H, W).

    cfg: dt, a2, t_pm, w_on_base, w_off_base, on alphas ×3, off alphas ×3, o1, o2, delta_c,
    c_w, cde_tde, k_spi, h_sfa, t_sfa, a4, t_spi, n_alert, border.
    bufs (5, H+2, W+2): ON now, ON prev, OFF now, OFF prev, S (padded).
    scal: f_raw_prev, smp, sfa, started, counter, consecutive spike count.
    """
    n, h, w = frames.shape
    dt, a2, t_pm, w_on_base, w_off_base = cfg[0], cfg[1], cfg[2], cfg[3], cfg[4]
    a_on = (cfg[5], cfg[6], cfg[7])
    a_off = (cfg[8], cfg[9], cfg[10])
    o1, o2, delta_c, c_w, cde_tde = cfg[11], cfg[12], cfg[13], cfg[14], cfg[15]
    k_spi, h_sfa, t_sfa, a4, t_spi = cfg[16], cfg[17], cfg[18], cfg[19], cfg[20]
    n_alert = cfg[21]
    b = int(cfg[22])
    w_on_k = (2.0, 0.5, 0.25)
    w_off_k = (1.0, 0.25, 0.125)
    n_ts = spikes_ring.shape[0]
    sp = bufs[4]
    ce = np.empty((h, w))
    for i in range(n):
        on_now, on_prev = bufs[0], bufs[1]
        off_now, off_prev = bufs[2], bufs[3]
        if scal[3] == 0.0:
            for y in range(h):
                for x in range(w):
                    lum_prev[y, x] = _levels(frames, i, y, x, is_u8)
            scal[3] = 1.0
        abs_sum = 0.0
        for y in range(h):  # 1. P = clip(floor(ΔY / 2)), 3. ON/OFF
            for x in range(w):
                v = _levels(frames, i, y, x, is_u8)
                p = min(max(math.floor((v - lum_prev[y, x]) / 2.0), -127.0), 127.0)
                lum_prev[y, x] = v
                abs_sum += abs(p)
                on_now[y + 1, x + 1] = p if p >= 0.0 else 0.0
                off_now[y + 1, x + 1] = -p if p < 0.0 else 0.0
        _replicate_edges(on_now)
        _replicate_edges(off_now)
        f_raw = abs_sum / (h * w)  # 2.
        f = a2 * f_raw + (1.0 - a2) * scal[0]
        scal[0] = f_raw
        w1 = max(f / t_pm, w_on_base)
        w2 = max(f / t_pm, w_off_base)
        for y in range(h):  # 4. inhibition (each term truncated), 5. S
            for x in range(w):
                i_on = 0.0
                i_off = 0.0
                for di in range(-1, 2):
                    for dj in range(-1, 2):
                        k = abs(di) + abs(dj)
                        yy = y + 1 + di
                        xx = x + 1 + dj
                        i_on += np.trunc(
                            w_on_k[k]
                            * (a_on[k] * on_now[yy, xx] + (1.0 - a_on[k]) * on_prev[yy, xx])
                        )
                        i_off += np.trunc(
                            w_off_k[k]
                            * (a_off[k] * off_now[yy, xx] + (1.0 - a_off[k]) * off_prev[yy, xx])
                        )
                i_on = math.floor(i_on)
                i_off = math.floor(i_off)
                s = math.floor(
                    o1 * max(on_now[y + 1, x + 1] - w1 * i_on, 0.0)
                    + o2 * max(off_now[y + 1, x + 1] - w2 * i_off, 0.0)
                )
                sp[y + 1, x + 1] = min(s, 255.0)
        _replicate_edges(sp)
        ce_max = 0.0
        for y in range(h):  # 6. grouping
            for x in range(w):
                acc = 0.0
                for di in range(-1, 2):
                    for dj in range(-1, 2):
                        acc += sp[y + 1 + di, x + 1 + dj]
                c = math.floor(acc / 9.0)
                ce[y, x] = c
                ce_max = max(ce_max, c)
        scale = delta_c + ce_max / c_w
        mp = 0.0
        for y in range(b, h - b):  # 7. only the region inside the border counts
            for x in range(b, w - b):
                g = min(math.floor(sp[y + 1, x + 1] * ce[y, x] / scale), 255.0)
                if g >= cde_tde:
                    mp += g
        n_cells = (h - 2 * b) * (w - 2 * b)
        smp = 1.0 / (1.0 + math.exp(-mp / (n_cells * k_spi)))  # 8.
        d = smp - scal[1]
        sfa = max(0.5, h_sfa * (scal[2] + d)) if d <= t_sfa else max(0.5, h_sfa * smp)
        scal[1] = smp
        scal[2] = sfa
        spikes = math.floor(math.exp(a4 * (sfa - t_spi)))
        alert = 0.0  # 9.
        if spikes > 0:
            scal[5] += spikes
            if scal[5] >= n_alert:
                alert = 1.0
                scal[5] = 0.0
        else:
            scal[5] = 0.0
        slot = int(scal[4]) % n_ts
        spikes_ring[slot] = spikes
        total = 0
        for q in range(n_ts):
            total += spikes_ring[q]
        out[i, 0] = 1000.0 * total / (n_ts * dt)
        out[i, 1] = alert
        out[i, 2] = spikes
        out[i, 3] = mp
        out[i, 4] = smp
        out[i, 5] = sfa
        out[i, 6] = f
        scal[4] += 1.0
        on_prev[:, :] = on_now
        off_prev[:, :] = off_now


class _LgmdBase:
    outputs: ClassVar[tuple[Output, ...]] = LGMD_OUTPUTS
    _n_bufs = 0
    _n_scal = 0

    def __init__(self, params, name: str) -> None:
        self.name = name
        self.params = params
        self.reset()

    def reset(self) -> None:
        """Forget all history; the next frame is treated as the first."""
        self._shape: tuple[int, int] | None = None
        self._is_u8: bool | None = None

    # parameters that may change while the model runs (a policy's doing): name → index in _cfg
    live_params: ClassVar[dict[str, int]] = {}

    def set_param(self, name: str, value: float) -> None:
        """Change parameter ``name`` from the next frame on, keeping all state (``params`` keep
        the value the model was built with). Only ``live_params`` can change."""
        if name not in self.live_params:
            raise ParameterError(
                f"{self.name}: parameter {name!r} cannot change while it runs (these can: "
                f"{', '.join(self.live_params)})."
            )
        if not (math.isfinite(value) and value > 0):
            raise ParameterError(f"{name} must be a positive number, got {value}.")
        self._cfg[self.live_params[name]] = float(value)

    def _allocate(self, h: int, w: int) -> None:
        self._shape = (h, w)
        self._lum = np.zeros((h, w))
        self._bufs = np.zeros((self._n_bufs, h + 2, w + 2))
        self._scal = np.zeros(self._n_scal)
        self._ring = np.zeros(self.params.n_ts, dtype=np.int64)

    def _advance(self, frames: np.ndarray) -> np.ndarray:
        _, h, w = frames.shape
        is_u8 = frames.dtype == np.uint8
        if self._shape is None:
            self._allocate(h, w)
            self._is_u8 = is_u8
        elif (h, w) != self._shape:
            raise ParameterError(
                f"frame shape changed from {self._shape[1]}x{self._shape[0]} to {w}x{h} px (WxH); "
                "call reset() first."
            )
        elif is_u8 != self._is_u8:
            raise ParameterError("frame dtype changed between uint8 and float; call reset() first.")
        out = np.empty((frames.shape[0], _N_OUT))
        self._kernel(frames, is_u8, out)
        return out

    def _kernel(self, frames: np.ndarray, is_u8: bool, out: np.ndarray) -> None:
        raise NotImplementedError

    def run(self, frames: np.ndarray) -> dict[str, np.ndarray]:
        """Process frames (T, H, W), uint8 or float on [0, 1]; ``{output: (T,) float64}``."""
        out = self._advance(check_frames(frames, min_h=3, min_w=3))
        return {n: np.ascontiguousarray(out[:, c]) for c, n in enumerate(LGMD_OUTPUT_NAMES)}

    def step(self, frame: np.ndarray) -> dict[str, float]:
        """Process one frame (H, W); ``{output: float}``."""
        arr = np.asarray(frame)
        if arr.ndim != 2:
            raise ParameterError(
                f"a frame must have shape (H, W), got an array of shape {arr.shape}."
            )
        row = self._advance(check_frames(arr[None], min_h=3, min_w=3))[0]
        return {n: float(row[c]) for c, n in enumerate(LGMD_OUTPUT_NAMES)}


class LgmdPlus(_LgmdBase):
    """LGMD+ (Fu et al. 2020, released defaults); outputs ``LGMD_OUTPUTS``."""

    _n_bufs = 6
    _n_scal = 5
    live_params: ClassVar[dict[str, int]] = {"t_ffi": 2, "t_sr": 22}

    def __init__(self, params: LgmdPlusParams, name: str = "lgmd-plus") -> None:
        p = params
        dt = frame_interval_ms(p.fps)
        self._cfg = np.array(
            [
                dt,
                lowpass_alpha(dt, p.tau_ffi_ms),
                p.t_ffi,
                p.w_base,
                p.tau_g_ms,
                p.delta_c,
                p.clip_point,
                p.dc,
                *(lowpass_alpha(dt, p.tau_e_ms * k) for k in (1, 2, 3)),
                p.w_on,
                p.w_off,
                p.w_onoff,
                p.c_w,
                p.c_de,
                p.t_de,
                p.c_sig,
                p.tau_hp_ms / (p.tau_hp_ms + dt),
                p.t_sfa,
                p.k_sp,
                p.t_sp,
                p.t_sr,
                1.0 if p.blur_truncate else 0.0,
            ],
            dtype=np.float64,
        )
        super().__init__(params, name)

    def _allocate(self, h: int, w: int) -> None:
        super()._allocate(h, w)
        p = self.params
        self._wloc = bias_matrix(h, w, p.std_w, p.w_min)
        self._g = np.zeros((h, w))

    def set_t_ffi(self, t_ffi: float) -> None:
        """Change the FFI threshold T_ffi from the next frame on (closed-loop adaptation; the
        ``params`` keep the value the model was built with)."""
        self.set_param("t_ffi", t_ffi)

    def _kernel(self, frames: np.ndarray, is_u8: bool, out: np.ndarray) -> None:
        _lgmd_plus_kernel(
            frames,
            is_u8,
            self._cfg,
            self._wloc,
            self._lum,
            self._bufs,
            self._g,
            self._scal,
            self._ring,
            out,
        )


class LgmdColias(_LgmdBase):
    """The Colias-IV firmware "LGMD-Plus" port; outputs ``LGMD_OUTPUTS``."""

    _n_bufs = 5
    _n_scal = 6
    live_params: ClassVar[dict[str, int]] = {"t_pm": 2, "n_alert": 21}

    def __init__(self, params: LgmdColiasParams, name: str = "lgmd-colias") -> None:
        p = params
        dt = frame_interval_ms(p.fps)
        self._cfg = np.array(
            [
                dt,
                lowpass_alpha(dt, p.tau_pm_ms),
                p.t_pm,
                p.w_on_base,
                p.w_off_base,
                *(lowpass_alpha(dt, p.tau_on_ms * k) for k in (1, 2, 3)),
                *(lowpass_alpha(dt, p.tau_off_ms * k) for k in (1, 2, 3)),
                p.o1,
                p.o2,
                p.delta_c,
                p.c_w,
                p.cde_tde,
                p.k_spi,
                p.tau_sfa_ms / (p.tau_sfa_ms + dt),
                p.t_sfa,
                p.a4,
                p.t_spi,
                p.n_alert,
                p.border,
            ],
            dtype=np.float64,
        )
        super().__init__(params, name)

    def _advance(self, frames: np.ndarray) -> np.ndarray:
        _, h, w = frames.shape
        b = self.params.border
        if h <= 2 * b or w <= 2 * b:
            raise ParameterError(
                f"frames of {w}x{h} px (WxH) leave nothing inside the "
                f"lgmd-colias border={b}: use larger frames or a smaller border."
            )
        return super()._advance(frames)

    def _kernel(self, frames: np.ndarray, is_u8: bool, out: np.ndarray) -> None:
        _lgmd_colias_kernel(
            frames, is_u8, self._cfg, self._lum, self._bufs, self._scal, self._ring, out
        )
