"""Parameters, outputs and shared helpers of the LGMD collision detectors.

``LgmdPlusParams``: LGMD+ released defaults (lgmd_colias.md §2.3; GA-evolved "genes" marked).
``LgmdColiasParams``: the Colias firmware "LGMD-Plus" port (§3).
Times are in milliseconds as in the sources; the frame interval is ``1000 // fps`` (integer, as
the released code computes it: 30 ms at the robot's 33 Hz).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from avdm.base import Output, Params
from avdm.errors import ParameterError

LGMD_OUTPUTS: tuple[Output, ...] = (
    Output("spike_rate_hz", "spikes/s", "spike frequency over the last n_ts frames"),
    Output("alert", "1", "collision alert (1) or not (0)"),
    Output("spikes", "spikes", "spikes fired in this frame"),
    Output("mp", "1", "LGMD membrane potential (sum of the G layer)"),
    Output("smp", "1", "sigmoid membrane potential"),
    Output("sfa", "1", "spike-frequency-adapted potential"),
    Output("ffi", "levels/px", "feed-forward inhibition (mean |photoreceptor| change)"),
)
LGMD_OUTPUT_NAMES = tuple(o.name for o in LGMD_OUTPUTS)


def frame_interval_ms(fps: float) -> int:
    """The released code's integer frame interval, 1000 // fps milliseconds."""
    return int(1000 // fps)


def lowpass_alpha(dt_ms: float, tau_ms: float) -> float:
    """Coefficient α = Δt / (Δt + τ) of a first-order low-pass."""
    return dt_ms / (dt_ms + tau_ms)


def bias_matrix(h: int, w: int, std_w: float, w_min: float) -> np.ndarray:
    """LGMD+ local inhibition weights (H, W): ``max(1 − B, W_min)`` with B a Gaussian over the
    view scaled to ±3σ (less inhibition in the centre of view)."""
    cr, cc = h // 2, w // 2
    u = (np.arange(h) - cr) / max(cr, 1)
    v = (np.arange(w) - cc) / max(cc, 1)
    sigma_h = std_w * h / w
    b = np.exp(-4.5 * (u[:, None] ** 2 + v[None, :] ** 2)) / (2 * math.pi * sigma_h * std_w)
    return np.maximum(1.0 - b, w_min)


def _check_params(
    obj: Params,
    positive: tuple[str, ...],
    non_negative: tuple[str, ...],
    integers: tuple[tuple[str, int, int], ...],
) -> None:
    """Raise ParameterError naming the first field out of its range (shared by both
    detectors)."""
    obj.check_ranges("lgmd", positive=positive)
    fps = obj.fps  # type: ignore[attr-defined]
    if frame_interval_ms(fps) < 1:
        raise ParameterError(f"lgmd parameter fps={fps!r}: must be at most 1000.")
    for name in non_negative:
        v = getattr(obj, name)
        if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
            raise ParameterError(f"lgmd parameter {name}={v!r}: must be a number >= 0.")
    obj.check_ranges("lgmd", integers=integers)


@dataclasses.dataclass(frozen=True)
class LgmdPlusParams(Params):
    """LGMD+ (Fu et al. 2020) with the released defaults."""

    fps: float = 33.0
    blur_truncate: bool = True  # truncate each blur term toward 0 (released code)
    tau_ffi_ms: float = 10.0
    t_ffi: float = 12.0  # gene
    w_base: float = 0.6190473  # gene
    tau_g_ms: float = 10.0
    delta_c: float = 0.5
    clip_point: float = 0.1
    dc: float = 0.1
    tau_e_ms: float = 10.0  # gene: delays 10/20/30 ms for centre/nearest/diagonal
    std_w: float = 0.5307723  # gene
    w_min: float = 0.1
    w_on: float = 2.0
    w_off: float = 1.0
    w_onoff: float = 0.0
    c_w: float = 4.0
    c_de: float = 0.5
    t_de: float = 18.0  # gene
    c_sig: float = 0.6  # gene
    tau_hp_ms: float = 783.0  # gene
    t_sfa: float = 0.003
    k_sp: float = 10.0
    t_sp: float = 0.68  # gene
    n_ts: int = 10
    t_sr: float = 56.0  # gene: collision threshold on the spike rate, spikes/s

    def __post_init__(self) -> None:
        _check_params(
            self,
            positive=(
                "fps",
                "tau_ffi_ms",
                "t_ffi",
                "tau_g_ms",
                "tau_e_ms",
                "std_w",
                "c_w",
                "c_sig",
                "tau_hp_ms",
                "k_sp",
            ),
            non_negative=(
                "w_base",
                "delta_c",
                "clip_point",
                "dc",
                "w_min",
                "w_on",
                "w_off",
                "w_onoff",
                "c_de",
                "t_de",
                "t_sfa",
                "t_sp",
                "t_sr",
            ),
            integers=(("n_ts", 1, 1000),),
        )
        if not 0 <= self.dc < 1:
            raise ParameterError(f"lgmd parameter dc={self.dc!r}: must be below 1.")


@dataclasses.dataclass(frozen=True)
class LgmdColiasParams(Params):
    """The Colias firmware "LGMD-Plus" port (integer layers, OFF-biased, 15-px border)."""

    fps: float = 33.0
    t_pm: float = 20.0
    tau_pm_ms: float = 90.0
    w_on_base: float = 1.0
    w_off_base: float = 0.5
    tau_on_ms: float = 15.0  # ON inhibition delays 15/30/45 ms
    tau_off_ms: float = 60.0  # OFF inhibition delays 60/120/180 ms
    o1: float = 0.5  # ON weight in S
    o2: float = 1.0  # OFF weight in S
    delta_c: float = 0.01
    c_w: float = 4.0
    cde_tde: float = 35.0
    border: int = 15
    k_spi: float = 0.5
    tau_sfa_ms: float = 500.0
    t_sfa: float = 0.003
    a4: float = 4.0
    t_spi: float = 0.64
    n_alert: int = 4  # alert when the consecutive spike count reaches this
    n_ts: int = 10  # window of the reported spike rate (not used by the decision)

    def __post_init__(self) -> None:
        _check_params(
            self,
            positive=(
                "fps",
                "t_pm",
                "tau_pm_ms",
                "tau_on_ms",
                "tau_off_ms",
                "c_w",
                "k_spi",
                "tau_sfa_ms",
                "a4",
            ),
            non_negative=(
                "w_on_base",
                "w_off_base",
                "o1",
                "o2",
                "delta_c",
                "cde_tde",
                "t_sfa",
                "t_spi",
            ),
            integers=(("border", 0, 1000), ("n_alert", 1, 1000), ("n_ts", 1, 1000)),
        )
