"""A multi-scale AVDM for real footage (variant ``avdm-natural``).

Why: the paper's AVDM (``avdm``) decodes temporal frequency from one-frame differences, which
holds only while the image moves well under one pixel per frame at the scale of its texture
(``sin(π·TF/fps) ≈ π·TF/fps``). Natural texture at a video camera's pitch and 25–30 fps leaves
that regime above about 1–2 px per frame, and the reading then falls as the speed rises. The
paper measured at 300 Hz offline and with slowly drifting walls on the robot.

What this variant keeps from the AVDM, and what it changes, layer by layer:

1. retina: the frame is low-passed (5-tap binomial, σ = 1 px: it spreads 8-bit quantisation
   steps so slow motion is not a sparse train of one-level jumps) and decomposed into spatial
   scales: a Gaussian pyramid (each scale low-passed against aliasing, then halved) while the
   scale stays at least ``min_width_px`` wide, then undecimated scales whose correlators span
   2, 4, 8... samples (à trous). Scale k samples the scene every ``f_k · deg_per_px`` degrees,
   with ``f_k = 2^k``: like ommatidia of wider acceptance and spacing. Enough scales are built
   that ``max_dps`` moves at most ``v_high`` samples per frame at the coarsest one;
2. lamina: one-frame differences split into ON = [P]+ and OFF = [−P]+, as in the AVDM;
3. medulla: delay-and-correlate detectors between samples one spacing apart, as in the AVDM
   (one-frame delay), but **both mirror-image detectors are summed**, so the reading does not
   depend on the direction of motion. The AVDM's null-arm weight β then only scales the sum
   by (1 − β) and cancels in the decoding below, so it is not a parameter here;
4. lobula: the mean of the detectors over the whole field (the AVDM's ``all_mean`` pooling:
   on natural scenes the share of "active" detectors depends on the picture), then the
   temporal mean over ``tw`` frames → R̄_k;
5. texture pathway: instead of counting threshold crossings on one row (λ̂) and dividing by
   the frame's Michelson contrast, the pooled spatial contrast between the same pairs of
   samples over the whole field, S̄_k = 2·mean((I(x+s) − I(x))²) over ``tw`` frames. For a
   grating of period λ and amplitude A this is ∝ (A·π·s/λ)², so 1/√S̄ plays the role of
   λ̂·(1+C)/(2C) in the AVDM's decoding, estimated on every row and every scale;
6. decoding, per scale: ``ω̂_k = a · (√(R̄_k/S̄_k) · f_k · deg_per_px · fps)^b`` deg/s, with
   (a, b) fitted by least squares on camera pans over 1/f clutter, per camera and raster
   (``avdm.calibration.fit_multiscale``; the scales depend on the frame size);
7. scale choice, coarse to fine: start at the coarsest scale that has texture (RMS spatial
   contrast ≥ ``min_texture`` 8-bit levels and ≥ ``min_texture_ratio`` of the finer scales'
   largest: a picture without coarse structure leaves a coarse scale only noise), then
   move to each finer scale while the current
   estimate moves less than ``v_low`` of its samples per frame there, blending linearly up to
   ``v_high``: the finest scale still inside the correlators' linear range wins (more samples,
   less noise), and a fine scale that is too slow to follow the motion is never trusted.

Valid range (``benchmarks/bench_avdm_truth.py``: 8 real photographs panned at 1–300 deg/s in
both directions, 25 and 30 fps, the robot camera's pitch and a video pitch, raw and through
H.264; 1,152 cells): median error ≤ 10 % at every speed from 1 to 300 deg/s, Spearman ρ ≥ 0.995
against the truth on 7 of the 8 pictures, directions within 10 % on 99 % of cells; 34,000
frames/s on 99×72 on one core (14.6× OpenCV's DIS flow). It fails on texture without coarse
structure (a regular brick wall) moving more than about half its period per frame, which is
ambiguous for any one-frame correlator. ``omega_valid`` is 0 during the warm-up, on frames
without texture at any scale, and when the estimate moves more than one sample per frame at the
coarsest usable scale.

Intensity scale: uint8 frames are divided by 255; float frames are taken as on [0, 1].
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import numpy as np

from avdm.base import FrameStream, Output, Params
from avdm.errors import ParameterError
from avdm.jit import kernel

MULTISCALE_OUTPUTS: tuple[Output, ...] = (
    Output("omega_dps", "deg/s", "decoded angular velocity ω̂ (finest trusted scale)"),
    Output("scale_deg", "deg", "sampling base of the finest scale used (f_k · deg/px)"),
    Output("shift_samples", "1", "estimated motion per frame in samples of that scale"),
    Output("motion", "intensity", "√R̄ of that scale (ON and OFF, both directions)"),
    Output("texture", "intensity", "√S̄ of that scale: pooled spatial contrast"),
    Output("omega_valid", "1", "1 where the reading is inside the model's valid regime"),
)
MULTISCALE_OUTPUT_NAMES = tuple(o.name for o in MULTISCALE_OUTPUTS)


@dataclasses.dataclass(frozen=True)
class AvdmMultiScaleParams(Params):
    """Parameters of the multi-scale AVDM. Units in brackets; intensities on [0, 1].

    ``a`` and ``b`` default to ``None``: a least-squares calibration for this camera and these
    dynamics is filled in when the model is built (``avdm.registry.make_model``)."""

    fps: float = 30.0  # frame rate [Hz]
    deg_per_px: float = 70.0 / 99.0  # horizontal angle of one pixel [deg]
    # the raster: the scales (pyramid, then à trous) and so the calibration depend on it
    width_px: int = 99
    height_px: int = 72
    tw: int = 10  # temporal window of R̄ and S̄ [frames]
    max_dps: float = 300.0  # fastest motion the coarsest scale must follow [deg/s]
    min_width_px: int = 24  # the pyramid halves a scale while it stays this wide [px]
    v_low: float = 0.35  # below this shift per frame [samples] a finer scale is trusted fully
    v_high: float = 0.7  # above it a scale is not trusted [samples per frame]
    min_texture: float = 1.0  # a scale needs this RMS spatial contrast [8-bit levels]
    # ... and this share of the largest RMS contrast of the finer scales: a texture with no
    # coarse structure (bricks, a fine grating) leaves coarse scales with only codec noise
    min_texture_ratio: float = 0.2
    a: float | None = None  # decoding gain
    b: float | None = None  # decoding exponent

    def __post_init__(self) -> None:
        def bad(name: str, why: str) -> ValueError:
            return ValueError(f"avdm-natural parameter {name}={getattr(self, name)!r}: {why}")

        self.check_ranges(
            "avdm-natural",
            positive=("fps", "deg_per_px", "max_dps", "min_texture", "min_texture_ratio"),
            integers=(
                ("width_px", 4, 100_000),
                ("height_px", 1, 100_000),
                ("tw", 1, 10_000),
                ("min_width_px", 4, 100_000),
            ),
        )
        if not (0 < self.v_low < self.v_high <= 4.0):
            raise ParameterError(
                f"avdm-natural parameters v_low={self.v_low}, v_high={self.v_high}: "
                "need 0 < v_low < v_high <= 4."
            )
        if self.a is not None and not (math.isfinite(self.a) and self.a > 0):
            raise bad("a", "must be a positive number")
        if self.b is not None and not (math.isfinite(self.b) and self.b > 0):
            raise bad("b", "must be a positive number")

    def n_scales(self) -> int:
        """Scales needed so ``max_dps`` moves at most ``v_high`` samples per frame at the
        coarsest: ``f = 2^(n−1) ≥ max_dps / (fps · deg_per_px · v_high)``."""
        need = self.max_dps / (self.fps * self.deg_per_px * self.v_high)
        return max(1, math.ceil(math.log2(max(need, 1.0))) + 1)


def scale_geometry(p: AvdmMultiScaleParams, h: int, w: int) -> np.ndarray:
    """One row per scale: height, width, offset into the flat buffers, correlator spacing
    (samples), filter hole, decimate (0/1), factor f_k (level-0 px per spacing). int64 (K, 7).

    Scale 0 is the frame low-passed in place; each next scale is the previous one low-passed
    and halved while the result stays ``min_width_px`` wide, else low-passed with holes of the
    current spacing and correlated at twice that spacing."""
    rows = [(h, w, 0, 1, 1, 0, 1)]
    off = h * w
    for _ in range(p.n_scales() - 1):
        ph, pw, _, sp, _, _, f = rows[-1]
        if sp == 1 and (pw + 1) // 2 >= p.min_width_px:
            nh, nw, hole, dec, nsp = (ph + 1) // 2, (pw + 1) // 2, 1, 1, 1
        else:
            nh, nw, hole, dec, nsp = ph, pw, sp, 0, sp * 2
        if nsp >= nw:  # the spacing would leave no detector: stop here
            break
        rows.append((nh, nw, off, nsp, hole, dec, f * 2))
        off += nh * nw
    return np.array(rows, dtype=np.int64)


_FASTMATH = {"reassoc", "contract", "nsz"}
# A reading is valid while the coarsest usable scale moves at most one sample per frame: the
# one-frame correlators' limit (the faithful avdm's flag uses the same 1 px per frame).
VALID_SHIFT = 1.0


@kernel(nogil=True, inline="always")
def _reflect(i, n):
    # BORDER_REFLECT_101 (OpenCV's default): ... 2 1 | 0 1 2 ... n-1 | n-2 ...
    if n == 1:
        return 0
    while i < 0 or i >= n:
        if i < 0:
            i = -i
        if i >= n:
            i = 2 * n - 2 - i
    return i


@kernel(nogil=True, fastmath=_FASTMATH)
def _binomial(src, sh, sw, dst, dh, dw, hole, dec, tmp):
    """5-tap binomial (1 4 6 4 1)/16 low-pass with ``hole`` spacing, then keep every 2nd sample
    if ``dec``; src (sh·sw) → dst (dh·dw), both flat; tmp holds sh·dw."""
    step = 2 if dec else 1
    h2 = 2 * hole
    # interior outputs, whose taps all fall inside the row: no border arithmetic (vectorises)
    j_lo = min(dw, (h2 + step - 1) // step)
    j_hi = max(j_lo, min(dw, (sw - 1 - h2) // step + 1))
    c6 = np.float32(6.0 / 16.0)
    c4 = np.float32(4.0 / 16.0)
    c1 = np.float32(1.0 / 16.0)
    for y in range(sh):
        r = y * sw
        o = y * dw
        if step == 1:  # unit stride: a loop LLVM vectorises
            a0 = src[r + j_lo : r + j_hi]
            am1 = src[r + j_lo - hole : r + j_hi - hole]
            ap1 = src[r + j_lo + hole : r + j_hi + hole]
            am2 = src[r + j_lo - h2 : r + j_hi - h2]
            ap2 = src[r + j_lo + h2 : r + j_hi + h2]
            t_row = tmp[o + j_lo : o + j_hi]
            for j in range(j_hi - j_lo):
                t_row[j] = c6 * a0[j] + c4 * (am1[j] + ap1[j]) + c1 * (am2[j] + ap2[j])
        else:
            for j in range(j_lo, j_hi):
                x = r + 2 * j
                tmp[o + j] = (
                    c6 * src[x]
                    + c4 * (src[x - hole] + src[x + hole])
                    + c1 * (src[x - h2] + src[x + h2])
                )
        for j in range(dw):
            if j_lo <= j < j_hi:
                continue  # done above
            x = j * step
            tmp[o + j] = (
                c6 * src[r + x]
                + c4 * (src[r + _reflect(x - hole, sw)] + src[r + _reflect(x + hole, sw)])
                + c1 * (src[r + _reflect(x - h2, sw)] + src[r + _reflect(x + h2, sw)])
            )
    for i in range(dh):
        y = i * step
        r0 = y * dw
        rm1 = _reflect(y - hole, sh) * dw
        rp1 = _reflect(y + hole, sh) * dw
        rm2 = _reflect(y - 2 * hole, sh) * dw
        rp2 = _reflect(y + 2 * hole, sh) * dw
        b0, bm1, bp1 = tmp[r0 : r0 + dw], tmp[rm1 : rm1 + dw], tmp[rp1 : rp1 + dw]
        bm2, bp2 = tmp[rm2 : rm2 + dw], tmp[rp2 : rp2 + dw]
        d_row = dst[i * dw : i * dw + dw]
        for j in range(dw):
            d_row[j] = c6 * b0[j] + c4 * (bm1[j] + bp1[j]) + c1 * (bm2[j] + bp2[j])


@kernel(nogil=True, fastmath=_FASTMATH)
def _multiscale_kernel(frames, cfg, geo, lev, prev, qon, qoff, tmp, rbuf, sbuf, counter, out):
    """Advance the model over ``frames`` (T, H, W); write (T, 6) outputs.

    cfg (f64): scale, a, b, fps, deg_per_px, v_low, v_high, min_texture (8-bit levels), tw,
    min_texture_ratio
    geo (K, 7) i64: see ``scale_geometry``; lev/prev/qon/qoff: flat f32 buffers of all scales;
    rbuf/sbuf (K, tw) f64 rings; counter (1,) i64 frames seen."""
    n_frames, h, w = frames.shape
    n_px = h * w
    n_sc = geo.shape[0]
    scale = np.float32(cfg[0])
    a, b, fps, dpp = cfg[1], cfg[2], cfg[3], cfg[4]
    v_low, v_high = cfg[5], cfg[6]
    floor = (cfg[7] / 255.0) ** 2 * 2.0  # S̄ of a field whose RMS contrast is min_texture
    tw = int(cfg[8])
    rel2 = cfg[9] * cfg[9]  # min_texture_ratio, on S̄ (a squared contrast)
    usable = np.zeros(geo.shape[0], dtype=np.bool_)
    raw = np.empty(n_px, dtype=np.float32)
    row_on = np.empty(w, dtype=np.float32)
    row_off = np.empty(w, dtype=np.float32)
    om = np.empty(n_sc, dtype=np.float64)
    ratio = np.empty(n_sc, dtype=np.float64)
    rb = np.empty(n_sc, dtype=np.float64)
    sb = np.empty(n_sc, dtype=np.float64)
    zero = np.float32(0.0)
    for i in range(n_frames):
        t = counter[0] + i
        fr = frames[i].reshape(n_px)
        for x in range(n_px):
            raw[x] = np.float32(fr[x]) * scale
        _binomial(raw, h, w, lev, h, w, 1, 0, tmp)
        for k in range(1, n_sc):
            ph, pw, po = geo[k - 1, 0], geo[k - 1, 1], geo[k - 1, 2]
            kh, kw, ko = geo[k, 0], geo[k, 1], geo[k, 2]
            src, dst = lev[po : po + ph * pw], lev[ko : ko + kh * kw]
            _binomial(src, ph, pw, dst, kh, kw, geo[k, 4], geo[k, 5], tmp)
        if t == 0:  # history before the first frame = the first frame: no onset flash
            for x in range(lev.shape[0]):
                prev[x] = lev[x]
        slot = t % tw
        for k in range(n_sc):
            kh, kw, ko, s = geo[k, 0], geo[k, 1], geo[k, 2], geo[k, 3]
            e_sum = 0.0
            d_sum = 0.0
            for y in range(kh):
                r = ko + y * kw
                # retina/lamina at this row: ON/OFF now; the previous ON/OFF are in qon/qoff
                cur = lev[r : r + kw]
                old = prev[r : r + kw]
                for x in range(kw):
                    p = cur[x] - old[x]
                    row_on[x] = p if p > zero else zero
                    row_off[x] = -p if p < zero else zero
                n_c = kw - s
                on_a, on_b = row_on[:n_c], row_on[s:kw]
                off_a, off_b = row_off[:n_c], row_off[s:kw]
                qon_a, qon_b = qon[r : r + n_c], qon[r + s : r + kw]
                qoff_a, qoff_b = qoff[r : r + n_c], qoff[r + s : r + kw]
                l_a, l_b = cur[:n_c], cur[s:kw]
                acc_e = zero
                acc_d = zero
                for x in range(n_c):
                    # both mirror-image delay-and-correlate detectors, ON and OFF
                    acc_e += on_a[x] * qon_b[x] + on_b[x] * qon_a[x]
                    acc_e += off_a[x] * qoff_b[x] + off_b[x] * qoff_a[x]
                    d = l_b[x] - l_a[x]
                    acc_d += d * d
                e_sum += acc_e
                d_sum += acc_d
                q_on = qon[r : r + kw]
                q_off = qoff[r : r + kw]
                for x in range(kw):
                    q_on[x] = row_on[x]
                    q_off[x] = row_off[x]
            n_det = kh * (kw - s)
            rbuf[k, slot] = e_sum / n_det
            sbuf[k, slot] = 2.0 * d_sum / n_det
        for x in range(lev.shape[0]):
            prev[x] = lev[x]

        # decoding per scale, then the coarse-to-fine choice
        for k in range(n_sc):
            r_m = 0.0
            s_m = 0.0
            for q in range(tw):
                r_m += rbuf[k, q]
                s_m += sbuf[k, q]
            r_m /= tw
            s_m /= tw
            rb[k] = r_m
            sb[k] = s_m
            ratio[k] = math.sqrt(r_m / s_m) if s_m > 0.0 and r_m > 0.0 else 0.0
            nu = ratio[k] * geo[k, 6] * dpp * fps
            om[k] = a * nu**b if nu > 0.0 else 0.0
        finest_max = 0.0
        top = -1
        for k in range(n_sc):
            usable[k] = sb[k] >= floor and sb[k] >= rel2 * finest_max
            finest_max = max(finest_max, sb[k])
            if usable[k]:
                top = k
        valid = 1.0 if t + 1 >= tw else 0.0
        if top < 0:  # no texture anywhere: nothing to measure
            out[i, 0] = 0.0
            out[i, 1] = geo[0, 6] * dpp
            out[i, 2] = 0.0
            out[i, 3] = math.sqrt(rb[0])
            out[i, 4] = math.sqrt(sb[0])
            out[i, 5] = 0.0
            continue
        est = om[top]
        used = top
        if est / (geo[top, 6] * dpp * fps) > VALID_SHIFT:
            valid = 0.0  # faster than the coarsest scale can follow
        for k in range(top - 1, -1, -1):
            if not usable[k]:
                continue
            shift = est / (geo[k, 6] * dpp * fps)
            wgt = (v_high - shift) / (v_high - v_low)
            if wgt <= 0.0:
                break
            if wgt > 1.0:
                wgt = 1.0
            est = wgt * om[k] + (1.0 - wgt) * est
            used = k
        out[i, 0] = est
        out[i, 1] = geo[used, 6] * dpp
        out[i, 2] = est / (geo[used, 6] * dpp * fps)
        out[i, 3] = math.sqrt(rb[used])
        out[i, 4] = math.sqrt(sb[used])
        out[i, 5] = valid
    counter[0] += n_frames


class AvdmMultiScale(FrameStream):
    """The multi-scale AVDM as a stateful model (see the module for the layers).

    >>> from avdm.registry import make_model
    >>> m = make_model("avdm-natural", fps=30.0, deg_per_px=70 / 99)
    >>> m.run(frames)["omega_dps"]          # frames (T, H, W) uint8 or float on [0, 1] → (T,)

    ``run`` equals repeated ``step`` bit for bit and continues from the previous call's state.
    """

    outputs: ClassVar[tuple[Output, ...]] = MULTISCALE_OUTPUTS
    output_names: ClassVar[tuple[str, ...]] = MULTISCALE_OUTPUT_NAMES
    min_width: ClassVar[int] = 4

    def __init__(self, params: AvdmMultiScaleParams, name: str = "avdm-natural") -> None:
        if params.a is None or params.b is None:
            raise ParameterError(
                "avdm-natural needs decoding constants a and b: build it with "
                "avdm.registry.make_model (which fits them) or pass a=...,b=..."
            )
        self.name = name
        self.params = params
        self.reset()

    def _allocate(self, h: int, w: int, dtype: np.dtype) -> None:
        p = self.params
        if (h, w) != (p.height_px, p.width_px):
            raise ParameterError(
                f"frames of {w}x{h} px (WxH) but this avdm-natural is calibrated for "
                f"{p.width_px}x{p.height_px}: build it for the frames' raster, e.g. "
                "make_model(spec, **vdc.recording.camera_model_context(W, H, fps, fov))."
            )
        self._geo = scale_geometry(p, h, w)
        total = int(self._geo[-1, 2] + self._geo[-1, 0] * self._geo[-1, 1])
        self._lev = np.zeros(total, dtype=np.float32)
        self._prev = np.zeros(total, dtype=np.float32)
        self._qon = np.zeros(total, dtype=np.float32)
        self._qoff = np.zeros(total, dtype=np.float32)
        self._tmp = np.zeros(max(h * w, 2 * w), dtype=np.float32)
        k = len(self._geo)
        self._rbuf = np.zeros((k, p.tw), dtype=np.float64)
        self._sbuf = np.zeros((k, p.tw), dtype=np.float64)
        self._cfg = np.array(
            [
                1.0 / 255.0 if dtype == np.uint8 else 1.0,
                p.a,
                p.b,
                p.fps,
                p.deg_per_px,
                p.v_low,
                p.v_high,
                p.min_texture,
                p.tw,
                p.min_texture_ratio,
            ],
            dtype=np.float64,
        )

    def _kernel(self, frames: np.ndarray) -> np.ndarray:
        out = np.empty((frames.shape[0], len(MULTISCALE_OUTPUTS)), dtype=np.float64)
        _multiscale_kernel(
            frames,
            self._cfg,
            self._geo,
            self._lev,
            self._prev,
            self._qon,
            self._qoff,
            self._tmp,
            self._rbuf,
            self._sbuf,
            self._counter,
            out,
        )
        return out
