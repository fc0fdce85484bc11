"""A fly-style Hassenstein–Reichardt correlator with a contrast-normalising front end (``hrc``).

What it is for: the speed-meter leaderboard (``benchmarks/bench_avdm_truth.py``) holds the
AVDM variants against the classic insect motion detector. The Hassenstein–Reichardt correlator
(HRC; Hassenstein & Reichardt 1956; review Borst & Egelhaaf 1989) multiplies the signal of one
photoreceptor, delayed by a low-pass filter, with the undelayed signal of its neighbour and
subtracts the mirror-image product. Its mean response to a drifting sine grating of temporal
frequency TF, period λ and contrast C is ``∝ C² · sin(2π·Δφ/λ) · TFτ/(1+(2π·TF·τ)²)`` (for a
first-order low-pass of time constant τ): **tuned to temporal frequency, not to velocity**. It
peaks at TF = 1/(2πτ) whatever the period, and a faster pattern beyond the peak gives a
*smaller* response. Dror, O'Carroll & Laughlin (2001, JOSA A 18:241, "Accuracy of velocity
estimation by Reichardt correlators") showed that on natural images, whose spectra are alike,
the mean response still maps to velocity below the peak, more reliably with the prefiltering,
contrast normalisation and integration insect eyes have. This model is that reading, honestly
calibrated, with its range stated; the AVDM (honeybee-inspired) is the alternative that
decodes speed rather than temporal frequency.

Layer by layer (intensities on [0, 1]; uint8 frames are divided by 255):

1. optics: each ommatidium sees the frame through a Gaussian acceptance function of full
   width at half maximum Δρ = ``acceptance_ratio`` · Δφ; ommatidia lie on a square lattice
   Δφ = ``spacing_deg`` apart (rounded to whole pixels, at least 1), centred on the frame;
2. lamina, contrast-normalising front end: lateral inhibition removes the mean of the
   ``(2·surround+1)²`` lattice neighbourhood (c = L − S, no DC), then divisive normalisation
   by the local RMS contrast of the ``(2·norm_radius+1)²`` neighbourhood,
   ``n = c / √(mean(c²) + σ₀²)`` with σ₀ = ``noise_floor`` 8-bit levels: the input to the
   correlator no longer depends on the picture's contrast or brightness;
3. medulla, the HRC: a first-order low-pass of time constant ``tau_ms`` (discretised exactly
   for frames held one frame period: D(t) = β·D(t−1) + (1−β)·n(t−1), β = e^(−1/(fps·τ))) and
   the opponent product between horizontal neighbours,
   ``r = D_A·n_B − n_A·D_B`` (B one spacing toward +x of A), positive for image motion toward
   +x (increasing column index);
4. lobula, a wide-field tangential cell: the mean of r over every detector, then the mean
   over the last ``tw`` frames → R̄ (``response``, normalised contrast², signed);
5. decoding: a response-to-speed curve measured on camera pans over 1/f clutter at this
   camera's fps and pitch (``avdm.hrc_calibration``; never on the validation photographs),
   ``R(v) = r_peak · (2·x^k / (1 + x^(2k)))^(1/k)`` with x = v / ``v_peak_dps`` and k =
   ``knee``: linear at slow speeds, peak r_peak at v_peak, falling as 1/v beyond. |R̄| is
   inverted on the rising branch, ``x = (ρ^k / (1 + √(1 − ρ^(2k))))^(1/k)`` with ρ =
   |R̄|/r_peak (held at x = 1 where ρ ≥ 1); ``omega_dps`` = x·v_peak, the speed whatever the
   direction (like ``avdm-natural``), ``omega_signed_dps`` carries R̄'s sign.

What it reads, and its valid range: a speed only below v_peak, which is set by τ and Δφ, not
by the scene (about 25 deg/s at 25–30 fps with the defaults; the calibration stores it). A
faster scene gives the response of a slower one (and beyond about half a spacing per frame,
aliased correlations of either sign): the correlator cannot tell which side of its peak it is
on, so a reading is never more than v_peak. The flag therefore adds a non-directional pathway,
the frame-to-frame change of the normalised signal C̄ = mean((n(t) − n(t−1))²) over ``tw``
frames (``change``), which keeps rising with speed where R̄ falls. ``omega_valid`` is 1 after
the ``tw``-frame warm-up on frames with texture (RMS lateral-inhibition contrast ≥ σ₀) whose
response stays under ``valid_fraction`` (0.9) of r_peak (about 0.6·v_peak with the fitted
knee; nearer the peak the inversion's slope diverges) and whose change C̄ stays under
``change_max``, the clutter's C̄ at v_peak (past the peak). A picture with more fine structure
than 1/f clutter changes faster at the same speed, so the flag can also drop below v_peak.
Measured (``benchmarks/bench_avdm_truth.py --quick``: 3 photographs, 1–300 deg/s both ways,
25/30 fps, two pitches; docs/guides/video.md): v_peak 23–27 deg/s; every frame of 1–20 deg/s
flagged valid, 11 % at 40 deg/s, none at 80–300; the valid cells read 0.53–0.87× the truth
(10–90 %; the photographs have less fine structure than the clutter); past the peak 0.23× at
40 deg/s, ≤ 0.03× from 80 deg/s. Valid range: 1–20 deg/s at 25–30 fps, reading 10–50 % low.

Defaults from the fly and bee literature: Δφ = 1.5° (hoverfly and honeybee frontal eyes,
1–2°), Δρ/Δφ = 1, τ = 35 ms (the delay filter of blowfly HRC models); tw = 10 frames as the
AVDM's temporal mean. ``run`` equals repeated ``step`` bit for bit and continues from the
current state.
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import numpy as np

from avdm.avdm_multiscale import _reflect
from avdm.base import FrameStream, Output, Params
from avdm.errors import ParameterError
from avdm.jit import kernel

HRC_OUTPUTS: tuple[Output, ...] = (
    Output("omega_dps", "deg/s", "speed read from |R̄| on the calibrated rising branch"),
    Output("omega_signed_dps", "deg/s", "the same with R̄'s sign: + = image motion toward +x"),
    Output("response", "1", "R̄: pooled opponent correlator output (normalised contrast²)"),
    Output("contrast", "intensity", "RMS contrast after lateral inhibition, before normalising"),
    Output("change", "1", "C̄: mean squared frame-to-frame change of the normalised signal"),
    Output("omega_valid", "1", "1 where the reading is inside the model's valid range"),
)
HRC_OUTPUT_NAMES = tuple(o.name for o in HRC_OUTPUTS)
FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))


@dataclasses.dataclass(frozen=True)
class HrcParams(Params):
    """Parameters of the HRC. Units in brackets; intensities on [0, 1].

    ``r_peak``, ``v_peak_dps`` and ``knee`` default to ``None``: the response curve measured
    for this camera and these dynamics is filled in when the model is built
    (``avdm.registry.make_model``; ``avdm.hrc_calibration``)."""

    fps: float = 30.0  # frame rate [Hz]
    deg_per_px: float = 70.0 / 99.0  # horizontal angle of one pixel [deg]
    spacing_deg: float = 1.5  # interommatidial angle Δφ [deg] (rounded to whole px)
    acceptance_ratio: float = 1.0  # acceptance angle Δρ (Gaussian FWHM) over Δφ
    tau_ms: float = 35.0  # time constant of the delay low-pass [ms]
    surround: int = 1  # lateral inhibition: radius of the subtracted mean [ommatidia]
    norm_radius: int = 2  # contrast normalisation: radius of the RMS pool [ommatidia]
    noise_floor: float = 2.0  # σ₀ of the divisive normalisation [8-bit levels]
    tw: int = 10  # temporal mean of the pooled response [frames]
    valid_fraction: float = 0.9  # |R̄|/r_peak up to which a reading is valid
    r_peak: float | None = None  # calibrated peak response [normalised contrast²]
    v_peak_dps: float | None = None  # speed of the peak response [deg/s]
    knee: float | None = None  # sharpness of the response curve's knee
    change_max: float | None = None  # C̄ of the calibration clutter at v_peak [normalised²]

    def __post_init__(self) -> None:
        def bad(name: str, why: str) -> ValueError:
            return ValueError(f"hrc parameter {name}={getattr(self, name)!r}: {why}")

        self.check_ranges(
            "hrc", positive=("fps", "deg_per_px", "spacing_deg", "acceptance_ratio", "tau_ms")
        )
        if not (math.isfinite(self.noise_floor) and self.noise_floor >= 0):
            raise bad("noise_floor", "must be >= 0")
        ranges = (("surround", 1, 50), ("norm_radius", 1, 50), ("tw", 1, 10_000))
        self.check_ranges("hrc", integers=ranges)
        if not (0 < self.valid_fraction <= 1):
            raise bad("valid_fraction", "must be in (0, 1]")
        for name in ("r_peak", "v_peak_dps", "knee", "change_max"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and v > 0):
                raise bad(name, "must be a positive number")

    def spacing_px(self) -> int:
        """Δφ in whole pixels of this camera (at least 1)."""
        return max(1, round(self.spacing_deg / self.deg_per_px))

    def beta(self) -> float:
        """The delay low-pass's per-frame decay e^(−1/(fps·τ))."""
        return math.exp(-1000.0 / (self.fps * self.tau_ms))


def lattice(n_px: int, spacing: int) -> np.ndarray:
    """Pixel positions (int64) of ommatidia ``spacing`` px apart, centred on ``n_px`` px."""
    n = (n_px - 1) // spacing + 1
    off = ((n_px - 1) - (n - 1) * spacing) // 2
    return off + spacing * np.arange(n, dtype=np.int64)


def acceptance_weights(p: HrcParams) -> np.ndarray:
    """The Gaussian acceptance function sampled on pixels, normalised, (2r+1,) float64."""
    sigma = p.acceptance_ratio * p.spacing_deg / p.deg_per_px / FWHM_PER_SIGMA
    radius = max(1, math.ceil(3.0 * sigma))
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    w = np.exp(-0.5 * (x / sigma) ** 2)
    return w / w.sum()


def response_curve(v_dps: np.ndarray, r_peak: float, v_peak_dps: float, knee: float) -> np.ndarray:
    """The calibrated mean response at speed ``v_dps``: r_peak·(2x^k/(1+x^(2k)))^(1/k)."""
    x = np.asarray(v_dps, dtype=np.float64) / v_peak_dps
    xk = x**knee
    return r_peak * (2.0 * xk / (1.0 + xk * xk)) ** (1.0 / knee)


@kernel(nogil=True)
def _box_mean(src, dst, radius):
    """Mean over the (2r+1)² neighbourhood of each element of ``src`` (ny, nx), reflecting at
    the edges (BORDER_REFLECT_101); into ``dst``."""
    ny, nx = src.shape
    norm = 1.0 / ((2 * radius + 1) * (2 * radius + 1))
    for i in range(ny):
        for j in range(nx):
            acc = 0.0
            for di in range(-radius, radius + 1):
                ii = _reflect(i + di, ny)
                for dj in range(-radius, radius + 1):
                    acc += src[ii, _reflect(j + dj, nx)]
            dst[i, j] = acc * norm


@kernel(nogil=True)
def _hrc_kernel(
    frames,
    cfg,
    icfg,
    rows,
    cols,
    wts,
    tmp,
    lum,
    sur,
    con,
    var,
    nrm,
    dly,
    prv,
    rbuf,
    cbuf,
    counter,
    out,
):
    """Advance the HRC over ``frames`` (T, H, W); write (T, 6) outputs.

    cfg (f64): scale, beta, sigma0² (intensity²), r_peak, v_peak_dps, knee, valid_fraction,
    change_max; icfg (i64): surround, norm_radius, tw; rows/cols: lattice positions; wts:
    acceptance weights; tmp (H, nx), lum/sur/con/var/nrm/dly/prv (ny, nx) f64 buffers (dly: the
    delay filters' state, prv: the previous normalised frame); rbuf/cbuf (tw,) rings of the
    pooled response and change; counter (1,) frames seen."""
    n_frames, h, w = frames.shape
    ny, nx = rows.shape[0], cols.shape[0]
    scale, beta, s02 = cfg[0], cfg[1], cfg[2]
    r_peak, v_peak, knee, vfrac, cmax = cfg[3], cfg[4], cfg[5], cfg[6], cfg[7]
    surround, nrad, tw = icfg[0], icfg[1], icfg[2]
    rad = (wts.shape[0] - 1) // 2
    n_det = ny * (nx - 1)
    for t_i in range(n_frames):
        t = counter[0] + t_i
        fr = frames[t_i]
        # 1. optics: Gaussian acceptance, sampled at the lattice (separable)
        for y in range(h):
            for j in range(nx):
                acc = 0.0
                for k in range(-rad, rad + 1):
                    acc += wts[k + rad] * fr[y, _reflect(cols[j] + k, w)]
                tmp[y, j] = acc * scale
        for i in range(ny):
            for j in range(nx):
                acc = 0.0
                for k in range(-rad, rad + 1):
                    acc += wts[k + rad] * tmp[_reflect(rows[i] + k, h), j]
                lum[i, j] = acc
        # 2. lamina: lateral inhibition, then divisive contrast normalisation
        _box_mean(lum, sur, surround)
        sum_c2 = 0.0
        for i in range(ny):
            for j in range(nx):
                c = lum[i, j] - sur[i, j]
                con[i, j] = c * c
                sum_c2 += c * c
        _box_mean(con, var, nrad)
        for i in range(ny):
            for j in range(nx):
                nrm[i, j] = (lum[i, j] - sur[i, j]) / math.sqrt(var[i, j] + s02)
        if t == 0:  # the delay filters start at the first frame: no onset flash
            for i in range(ny):
                for j in range(nx):
                    dly[i, j] = nrm[i, j]
                    prv[i, j] = nrm[i, j]
        # 3. the correlators (delayed A × B − A × delayed B), 4. pooled over the field
        r = 0.0
        for i in range(ny):
            for j in range(nx - 1):
                r += dly[i, j] * nrm[i, j + 1] - nrm[i, j] * dly[i, j + 1]
        chg = 0.0
        for i in range(ny):
            for j in range(nx):
                d = nrm[i, j] - prv[i, j]
                chg += d * d
                prv[i, j] = nrm[i, j]
                dly[i, j] = beta * dly[i, j] + (1.0 - beta) * nrm[i, j]
        rbuf[t % tw] = r / n_det if n_det > 0 else 0.0
        cbuf[t % tw] = chg / (ny * nx)
        rbar = 0.0
        cbar = 0.0
        for q in range(tw):
            rbar += rbuf[q]
            cbar += cbuf[q]
        rbar /= tw
        cbar /= tw
        # 5. decoding on the calibrated rising branch
        rho = abs(rbar) / r_peak
        if rho >= 1.0:
            x = 1.0
        elif rho > 0.0:
            rk = rho**knee
            x = (rk / (1.0 + math.sqrt(1.0 - rk * rk))) ** (1.0 / knee)
        else:
            x = 0.0
        omega = x * v_peak
        rms_c = math.sqrt(sum_c2 / (ny * nx))
        textured = rms_c * rms_c >= s02
        valid = t + 1 >= tw and textured and rho <= vfrac and cbar <= cmax
        out[t_i, 0] = omega
        out[t_i, 1] = omega if rbar >= 0.0 else -omega
        out[t_i, 2] = rbar
        out[t_i, 3] = rms_c
        out[t_i, 4] = cbar
        out[t_i, 5] = 1.0 if valid else 0.0
    counter[0] += n_frames


class Hrc(FrameStream):
    """The contrast-normalised Hassenstein–Reichardt correlator as a stateful model (see the
    module for the layers, what it reads and its valid range).

    >>> from avdm.registry import make_model
    >>> m = make_model("hrc", fps=30.0, deg_per_px=70 / 99)
    >>> m.run(frames)["omega_dps"]          # frames (T, H, W) uint8 or float on [0, 1] → (T,)
    """

    outputs: ClassVar[tuple[Output, ...]] = HRC_OUTPUTS
    output_names: ClassVar[tuple[str, ...]] = HRC_OUTPUT_NAMES
    min_width: ClassVar[int] = 2

    def __init__(self, params: HrcParams, name: str = "hrc") -> None:
        if None in (params.r_peak, params.v_peak_dps, params.knee, params.change_max):
            raise ParameterError(
                "hrc needs its response curve (r_peak, v_peak_dps, knee, change_max): build "
                "it with avdm.registry.make_model (which measures it) or pass all four."
            )
        self.name = name
        self.params = params
        self.reset()

    def _allocate(self, h: int, w: int, dtype: np.dtype) -> None:
        p = self.params
        s = p.spacing_px()
        self._rows, self._cols = lattice(h, s), lattice(w, s)
        if len(self._cols) < 2:
            raise ParameterError(
                f"frames {w} px wide hold fewer than 2 ommatidia {s} px apart: the hrc needs "
                f"a wider frame or a smaller spacing_deg (now {p.spacing_deg})."
            )
        ny, nx = len(self._rows), len(self._cols)
        self._wts = acceptance_weights(p)
        self._tmp = np.zeros((h, nx), dtype=np.float64)
        self._bufs = [np.zeros((ny, nx), dtype=np.float64) for _ in range(7)]
        self._rbuf = np.zeros(p.tw, dtype=np.float64)
        self._cbuf = np.zeros(p.tw, dtype=np.float64)
        sigma0 = p.noise_floor / 255.0
        self._cfg = np.array(
            [
                1.0 / 255.0 if dtype == np.uint8 else 1.0,
                p.beta(),
                sigma0 * sigma0,
                p.r_peak,
                p.v_peak_dps,
                p.knee,
                p.valid_fraction,
                p.change_max,
            ],
            dtype=np.float64,
        )
        self._icfg = np.array([p.surround, p.norm_radius, p.tw], dtype=np.int64)

    def _kernel(self, frames: np.ndarray) -> np.ndarray:
        out = np.empty((frames.shape[0], len(HRC_OUTPUTS)), dtype=np.float64)
        _hrc_kernel(
            frames,
            self._cfg,
            self._icfg,
            self._rows,
            self._cols,
            self._wts,
            self._tmp,
            *self._bufs,
            self._rbuf,
            self._cbuf,
            self._counter,
            out,
        )
        return out
