"""AVDM, the angular velocity decoding model (Wang, Fu et al.), fast path.

Layer by layer (see ``avdm.reference`` for the same model written plainly, and
docs/architecture.md for the sources):

1. retina: ``P(t) = sign · (I(t) − I(t − lag))``, a one-frame temporal difference by default;
2. lamina: ``ON = [P]+``, ``OFF = [−P]+``;
3. medulla: imbalanced delay-and-correlate detectors between pixels ``s`` apart,
   ``E = Q_A(t−d)·Q_B(t) − β·Q_A(t)·Q_B(t−d)`` along every row, for each channel;
4. lobula: ``R(t)`` = mean of the detectors with ``E > θ_E`` (denominator ``1 + count``), or
   the mean of ``[E]+`` over all detectors (``pooling="all_mean"``);
5. temporal mean of ``R`` over the last ``Tw`` frames → ``R̄``;
6. texture pathway: one image row is binarised at ``(min+max)/2`` of a frame (refreshed every
   ``Tw`` frames), transitions are counted and averaged over ``Tw`` frames: ``λ̂ = 2W / n̄`` px
   (``floor(2W/10)`` if ``n̄ ≤ 1``);
7. contrast ``C`` = Michelson contrast of the frame that set the texture threshold;
8. decoding: ``ω̂ = a · λ̂^b · (1+C)/(2C) · √R̄`` deg/s (mean of the ON and OFF decodings by
   default).

Valid range: drifting gratings and the arena's walls inside the calibration band (≥ 2 periods
across, ≥ 4 px per period, TF ≤ fps/4) within 22 % (the shipped fits' worst cell). On natural
footage at 25–30 fps the reading is not a speed (``benchmarks/bench_avdm_truth.py``: at 10 deg/s
80 % of readings within 0.25–2× the truth; above about 1 px per frame it falls, median 0.13× at
160 deg/s on the robot raster) and it differs by direction; use ``avdm-natural`` there. The
``omega_valid`` output marks frames whose estimated TF exceeds fps/4 or whose estimated motion
exceeds 1 px per frame.

Intensity scale: every threshold is defined on intensities in [0, 1]. ``uint8`` frames are
divided by 255; float frames are taken as already on [0, 1].

Choices where the sources are silent or would break the paper's sweep (docs/method/models.md):

* ``theta_e = 1e-6`` rather than the released code's 0.001. At 300 Hz a 1 Hz grating changes a
  pixel by at most ~1 % of full scale per frame, so products of one-frame changes are ~1e-4 and a
  0.001 threshold silences the whole low-TF band (the dead zone of avdm.md §9.8). The smallest
  non-zero detector output two one-level 8-bit changes can give is β·(1/255)² ≈ 3.8e-6, so
  1e-6 keeps every real 8-bit change and discards only float round-off. ``avdm-unity`` restores
  0.001.
* Frames before the first are taken equal to the first (no onset flash); detector and texture
  histories before the first frame count as zero (the warm-up of the released code).
"""

from __future__ import annotations

import dataclasses
import math
from typing import ClassVar

import numpy as np

from avdm.base import FrameStream, Output, Params
from avdm.errors import ParameterError
from avdm.jit import kernel

CHANNELS = ("on", "off", "on_off_mean")
POOLINGS = ("active_mean", "all_mean")
# Michelson contrast below this counts as a uniform image: the decoding is undefined there.
MIN_CONTRAST = 1e-6
# The valid regime of the one-frame decoding (sin(π·TF/fps) ≈ π·TF/fps within ~10 %): an
# estimated TF up to fps/4 (the calibration's band) and motion up to 1 px per frame, beyond
# which natural texture decorrelates between neighbouring detectors (docs/guides/video.md).
VALID_TF_FRACTION = 0.25
VALID_PX_PER_FRAME = 1.0


@dataclasses.dataclass(frozen=True)
class AvdmParams(Params):
    """Parameters of the AVDM. Units in brackets; intensities on the [0, 1] scale.

    ``a`` and ``b`` default to ``None``: the shipped least-squares calibration for this
    ``fps``/``deg_per_px`` is filled in when a model is built (``avdm.registry.make_model``).
    """

    fps: float = 300.0  # frame rate [Hz]
    deg_per_px: float = 3.6  # horizontal angle of one pixel [deg]
    beta: float = 0.25  # null-arm weight of the correlator
    tw: int = 10  # temporal window [frames]
    delay: int = 1  # correlator delay [frames]
    sd: int = 1  # correlator neighbour distance [px]
    theta_e: float = 1e-6  # pooling threshold on E [intensity²]
    channel: str = "on_off_mean"  # on | off | on_off_mean
    pooling: str = "active_mean"  # active_mean | all_mean
    photoreceptor_lag: int = 1  # P(t) = sign·(I(t) − I(t−lag)) [frames]
    photoreceptor_sign: int = 1  # −1 with lag 9 reproduces the released Unity code
    direction: int = 1  # preferred direction: +1 toward +x (column index), −1 toward −x
    texture_row: int = 2  # image row the texture pathway counts transitions on
    contrast_term: bool = True  # apply the (1+C)/(2C) factor
    a: float | None = None  # decoding gain [deg/s per px^b per intensity]
    b: float | None = None  # decoding exponent of λ̂

    def __post_init__(self) -> None:
        def bad(name: str, why: str) -> ValueError:
            return ValueError(f"avdm parameter {name}={getattr(self, name)!r}: {why}")

        self.check_ranges("avdm", positive=("fps", "deg_per_px"))
        if not (math.isfinite(self.beta) and 0.0 <= self.beta <= 1.0):
            raise bad("beta", "must be between 0 and 1")
        if not (math.isfinite(self.theta_e) and self.theta_e >= 0):
            raise bad("theta_e", "must be >= 0")
        self.check_ranges(
            "avdm",
            integers=(
                ("tw", 1, 10_000),
                ("delay", 1, 1_000),
                ("sd", 1, 1_000),
                ("photoreceptor_lag", 1, 1_000),
                ("texture_row", 0, 100_000),
            ),
        )
        for name in ("photoreceptor_sign", "direction"):
            if getattr(self, name) not in (1, -1):
                raise bad(name, "must be 1 or -1")
        if self.channel not in CHANNELS:
            raise bad("channel", f"must be one of {', '.join(CHANNELS)}")
        if self.pooling not in POOLINGS:
            raise bad("pooling", f"must be one of {', '.join(POOLINGS)}")
        if self.a is not None and not (math.isfinite(self.a) and self.a > 0):
            raise bad("a", "must be a positive number")
        if self.b is not None and not math.isfinite(self.b):
            raise bad("b", "must be a finite number")


AVDM_OUTPUTS: tuple[Output, ...] = (
    Output("omega_dps", "deg/s", "decoded angular velocity ω̂"),
    Output("lambda_px", "px", "texture pathway's spatial period estimate λ̂"),
    Output("motion", "intensity", "√R̄ of the channels in use (mean of ON and OFF by default)"),
    Output("contrast", "1", "Michelson contrast C of the frame that set the texture threshold"),
    Output("rbar_on", "intensity²", "temporal mean R̄ of the pooled ON detectors"),
    Output("rbar_off", "intensity²", "temporal mean R̄ of the pooled OFF detectors"),
    Output(
        "omega_valid",
        "1",
        "1 where the estimated temporal frequency ω̂/(λ̂·deg/px) stays under fps/4 and the "
        "estimated motion under 1 px per frame (the decoding's linear regime), after warm-up",
    ),
)
OUTPUT_NAMES = tuple(o.name for o in AVDM_OUTPUTS)
LAYER_OUTPUT_NAMES = OUTPUT_NAMES[:6]  # what the layers compute; omega_valid derives from them

_CHANNEL_CODE = {"on": 0, "off": 1, "on_off_mean": 2}

# Reassociation lets LLVM vectorise the pooled sums; run() and step() share this one compiled
# kernel, so they still produce the same floats. No nnan/ninf: inputs are checked instead.
_FASTMATH = {"reassoc", "contract", "nsz"}


@kernel(fastmath=_FASTMATH, nogil=True)
def _avdm_kernel(frames, cfg, icfg, hist, qhist, valid, rbuf, nbuf, held, counter, out):
    """Advance the AVDM state over ``frames`` (T, H, W) and write outputs into ``out`` (T, 6).

    Pixels are handled as flat rows of N = H·W values so the two hot loops are long and
    vectorise; a detector whose neighbour would wrap to the next image row has ``valid = 0``.

    cfg (float64): scale, beta, theta_e, a, b
    icfg (int64): sign, direction, sd, texture_row, tw, contrast_term, channel, all_mean
    hist (L, N) f32: ring of past intensities; qhist (d+1, 2, N) f32: ring of ON/OFF outputs;
    valid (N − sd,) f32: 1 for detectors within a row; rbuf (2, tw) f64: R of ON/OFF;
    nbuf (tw,) f64: transition counts; held (2,) f64: texture threshold and contrast;
    counter (1,) i64: frames seen so far.
    """
    n_frames, h, w = frames.shape
    n_px = h * w
    lag = hist.shape[0]
    n_q = qhist.shape[0]  # delay + 1 slots
    dly = n_q - 1
    scale = cfg[0]
    scale32 = np.float32(scale)
    beta = np.float32(cfg[1])
    theta = np.float32(cfg[2])
    a = cfg[3]
    b = cfg[4]
    sign = np.float32(icfg[0])
    sd = icfg[2]
    oa = 0 if icfg[1] > 0 else sd  # arm A (delayed in the preferred term)
    ob = sd - oa  # arm B
    n_c = n_px - sd  # correlators, including the masked row-wrapping ones
    row = icfg[3]
    tw = icfg[4]
    contrast_term = icfg[5]
    channel = icfg[6]
    all_mean = icfg[7]
    if all_mean:
        theta = np.float32(0.0)
    n_det = h * (w - sd)
    zero = np.float32(0.0)
    for i in range(n_frames):
        t = counter[0] + i
        frame = frames[i].reshape(n_px)
        hk = hist[t % lag]
        if t == 0:  # history before the first frame = the first frame: no onset flash
            for slot in range(lag):
                for x in range(n_px):
                    hist[slot, x] = np.float32(frame[x]) * scale32
        ws = t % n_q  # slot written now: ON/OFF at t
        rs = (t - dly) % n_q  # slot read: ON/OFF at t − d
        on_now = qhist[ws, 0]
        off_now = qhist[ws, 1]
        for x in range(n_px):  # retina and lamina
            v = np.float32(frame[x]) * scale32
            p = sign * (v - hk[x])
            hk[x] = v
            on_now[x] = p if p > zero else zero
            off_now[x] = -p if p < zero else zero
        # medulla and lobula: pre-shifted views keep the loop free of index offsets (vectorises)
        a_now_on = qhist[ws, 0, oa : oa + n_c]
        b_now_on = qhist[ws, 0, ob : ob + n_c]
        a_old_on = qhist[rs, 0, oa : oa + n_c]
        b_old_on = qhist[rs, 0, ob : ob + n_c]
        a_now_off = qhist[ws, 1, oa : oa + n_c]
        b_now_off = qhist[ws, 1, ob : ob + n_c]
        a_old_off = qhist[rs, 1, oa : oa + n_c]
        b_old_off = qhist[rs, 1, ob : ob + n_c]
        s_on = zero
        c_on = zero
        s_off = zero
        c_off = zero
        for x in range(n_c):
            e_on = a_old_on[x] * b_now_on[x] - beta * a_now_on[x] * b_old_on[x]
            e_off = a_old_off[x] * b_now_off[x] - beta * a_now_off[x] * b_old_off[x]
            # mask-multiply rather than branch, so the loop vectorises
            m_on = np.float32(e_on > theta) * valid[x]
            m_off = np.float32(e_off > theta) * valid[x]
            s_on += e_on * m_on
            c_on += m_on
            s_off += e_off * m_off
            c_off += m_off
        slot = t % tw
        if all_mean:
            rbuf[0, slot] = np.float64(s_on) / n_det
            rbuf[1, slot] = np.float64(s_off) / n_det
        else:
            rbuf[0, slot] = np.float64(s_on) / (1.0 + np.float64(c_on))
            rbuf[1, slot] = np.float64(s_off) / (1.0 + np.float64(c_off))

        # texture pathway and contrast, in float64 (one row, and one frame every tw frames)
        if t % tw == 0:
            lo = np.float64(frame[0]) * scale
            hi = lo
            for x in range(n_px):
                v64 = np.float64(frame[x]) * scale
                lo = min(lo, v64)
                hi = max(hi, v64)
            held[0] = (lo + hi) / 2.0
            held[1] = (hi - lo) / (hi + lo) if hi + lo > 0.0 else 0.0
        thr = held[0]
        n_tr = 0
        base = row * w
        prev = np.float64(frame[base]) * scale > thr
        for x in range(1, w):
            cur = np.float64(frame[base + x]) * scale > thr
            if cur != prev:
                n_tr += 1
            prev = cur
        nbuf[slot] = n_tr

        r_on = 0.0
        r_off = 0.0
        n_sum = 0.0
        for q in range(tw):
            r_on += rbuf[0, q]
            r_off += rbuf[1, q]
            n_sum += nbuf[q]
        r_on /= tw
        r_off /= tw
        n_bar = n_sum / tw
        lam = 2.0 * w / n_bar if n_bar > 1.0 else np.float64((2 * w) // 10)
        m_on = math.sqrt(r_on) if r_on > 0.0 else 0.0
        m_off = math.sqrt(r_off) if r_off > 0.0 else 0.0
        if channel == 0:
            motion = m_on
        elif channel == 1:
            motion = m_off
        else:
            motion = 0.5 * (m_on + m_off)
        c = held[1]
        if c < MIN_CONTRAST:
            omega = 0.0
        else:
            gain = a * lam**b
            if contrast_term:
                gain *= (1.0 + c) / (2.0 * c)
            omega = gain * motion
        out[i, 0] = omega
        out[i, 1] = lam
        out[i, 2] = motion
        out[i, 3] = c
        out[i, 4] = r_on
        out[i, 5] = r_off
    counter[0] += n_frames


class Avdm(FrameStream):
    """The AVDM as a stateful model (fast Numba path).

    >>> from avdm.registry import make_model
    >>> m = make_model("avdm")                      # 300 Hz, 3.6 deg/px, shipped (a, b)
    >>> out = m.run(frames)                         # frames: (T, H, W) uint8 or float in [0, 1]
    >>> out["omega_dps"].shape                      # (T,) deg/s

    ``step(frame)`` (H, W) returns one float per output; ``run`` equals repeated ``step``
    bit for bit, and continues from the state the previous call left.
    """

    outputs: ClassVar[tuple[Output, ...]] = AVDM_OUTPUTS
    output_names: ClassVar[tuple[str, ...]] = OUTPUT_NAMES
    min_width: ClassVar[int] = 2

    def __init__(self, params: AvdmParams, name: str = "avdm") -> None:
        if params.a is None or params.b is None:
            raise ParameterError(
                "avdm needs decoding constants a and b: build it with avdm.registry.make_model "
                "(which fills in the shipped calibration) or pass a=...,b=..."
            )
        self.name = name
        self.params = params
        self._cfg = np.array(
            [0.0, params.beta, params.theta_e, params.a, params.b], dtype=np.float64
        )
        self._icfg = np.array(
            [
                params.photoreceptor_sign,
                params.direction,
                params.sd,
                params.texture_row,
                params.tw,
                int(params.contrast_term),
                _CHANNEL_CODE[params.channel],
                int(params.pooling == "all_mean"),
            ],
            dtype=np.int64,
        )
        self.reset()

    def _allocate(self, h: int, w: int, dtype: np.dtype) -> None:
        p = self.params
        if p.texture_row >= h:
            raise ParameterError(
                f"frames have {h} rows but avdm texture_row={p.texture_row}: "
                f"use frames with more rows or set texture_row below {h}."
            )
        if w <= p.sd:
            raise ParameterError(f"frames of width {w} px are too narrow for sd={p.sd}.")
        self._hist = np.zeros((p.photoreceptor_lag, h * w), dtype=np.float32)
        self._qhist = np.zeros((p.delay + 1, 2, h * w), dtype=np.float32)
        valid = np.ones((h, w), dtype=np.float32)
        valid[:, w - p.sd :] = 0.0  # detectors whose neighbour lies in the next row
        self._valid = np.ascontiguousarray(valid.reshape(-1)[: h * w - p.sd])
        self._rbuf = np.zeros((2, p.tw), dtype=np.float64)
        self._nbuf = np.zeros(p.tw, dtype=np.float64)
        self._held = np.zeros(2, dtype=np.float64)
        self._cfg[0] = 1.0 / 255.0 if dtype == np.uint8 else 1.0

    def _kernel(self, frames: np.ndarray) -> np.ndarray:
        seen = int(self._counter[0])
        k_out = np.empty((frames.shape[0], 6), dtype=np.float64)
        _avdm_kernel(
            frames,
            self._cfg,
            self._icfg,
            self._hist,
            self._qhist,
            self._valid,
            self._rbuf,
            self._nbuf,
            self._held,
            self._counter,
            k_out,
        )
        out = np.empty((frames.shape[0], len(AVDM_OUTPUTS)), dtype=np.float64)
        out[:, :6] = k_out
        out[:, 6] = self._omega_valid(k_out, seen)
        return out

    def _omega_valid(self, out: np.ndarray, seen: int) -> np.ndarray:
        """The ``omega_valid`` column for rows of ``out`` whose first frame is ``seen``."""
        p = self.params
        omega, lam, contrast = out[:, 0], out[:, 1], out[:, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            tf_hz = omega / (lam * p.deg_per_px)
        px_per_frame = omega / (p.fps * p.deg_per_px)
        warm = np.arange(seen, seen + len(out)) + 1 >= p.tw
        ok = (
            warm
            & (contrast >= MIN_CONTRAST)
            & (tf_hz <= VALID_TF_FRACTION * p.fps)
            & (px_per_frame <= VALID_PX_PER_FRAME)
        )
        return ok.astype(np.float64)
