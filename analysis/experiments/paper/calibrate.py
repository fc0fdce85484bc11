"""Saving, plotting and shipping AVDM decoding calibrations (the fit is in avdm.calibration)."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np
from matplotlib.figure import Figure

from avdm.avdm_model import AvdmParams
from avdm.base import Params
from avdm.calibration import CalibrationResult, fit_decoding, valid_periods_px, valid_tfs_hz
from avdm.calibration_store import CALIBRATION_FILE
from avdm.registry import canonical_name, make_params
from vdc.cli_support import option, parse_size
from vdc.errors import UserError
from vdc.parquet_io import WroteFiles
from vdc.provenance import package_versions
from vdc.settings import POSITIVE, SIDE_PX, Settings, between


def calibration_entry(
    result: CalibrationResult, name: str, model: str, params: Params
) -> dict[str, Any]:
    """The JSON entry stored for a calibration: constants, quality, grid and provenance."""
    cells = result.cells
    entry: dict[str, Any] = {"name": name, "model": model, **result.to_dict()}
    entry["grid"] = {
        "periods_px": sorted({round(c.period_px, 6) for c in cells}),
        "tfs_hz": sorted({round(c.tf_hz, 6) for c in cells}),
        "contrasts": sorted({c.contrast for c in cells}),
        "stimulus": "drifting sine gratings, peak-normalised, uint8, point-sampled",
    }
    entry["model_params"] = {k: v for k, v in params.to_dict().items() if k not in ("a", "b")}
    entry["vdc_version"] = package_versions()["vdc"]
    return entry


def write_calibration(
    result: CalibrationResult, path: Path, name: str, model: str, params: Params
) -> dict[str, Any]:
    """Write the calibration entry as JSON to ``path``; returns the entry."""
    entry = calibration_entry(result, name, model, params)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(entry, indent=2) + "\n", encoding="utf-8")
    return entry


def update_shipped(entry: dict[str, Any]) -> Path:
    """Replace (or add) the shipped entry with the same fps and deg/px in calibrations.json."""
    path = Path(str(resources.files("avdm").joinpath(CALIBRATION_FILE)))
    data = json.loads(path.read_text(encoding="utf-8"))
    keep = [
        e
        for e in data["calibrations"]
        if not (
            np.isclose(e["fps"], entry["fps"], rtol=1e-6)
            and np.isclose(e["deg_per_px"], entry["deg_per_px"], rtol=1e-6)
        )
    ]
    data["calibrations"] = sorted([*keep, entry], key=lambda e: -e["fps"])
    path.write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")
    return path


def plot_calibration(result: CalibrationResult, path: Path) -> Path:
    """Decoded against true angular velocity for every grating cell, log-log."""
    fig = Figure(figsize=(6.5, 5.5), layout="constrained")
    ax = fig.subplots()
    cells = result.cells
    truth = np.array([c.omega_true_dps for c in cells])
    est = np.array([result.a * c.lambda_px**result.b * c.gain_term for c in cells])
    periods = np.array([c.period_px for c in cells])
    contrast = np.array([c.contrast for c in cells])
    for cval, marker in zip(sorted(set(contrast)), "os^dv", strict=False):
        m = contrast == cval
        sc = ax.scatter(
            truth[m],
            np.clip(est[m], 1e-3, None),
            c=periods[m],
            cmap="viridis",
            norm=matplotlib.colors.LogNorm(),
            marker=marker,
            s=22,
            label=f"contrast {cval:g}",
        )
    lo, hi = truth.min() / 1.5, truth.max() * 1.5
    ax.plot([lo, hi], [lo, hi], "k--", lw=1, label="ω̂ = ω")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("true angular velocity ω (deg/s)")
    ax.set_ylabel("decoded ω̂ (deg/s)")
    fig.colorbar(sc, ax=ax, label="grating period (px)")
    ax.set_title(
        f"{result.fps:g} Hz, {result.deg_per_px:.3g} deg/px, {result.width}x{result.height} px\n"
        f"a = {result.a:.4g}, b = {result.b:.4g}, RMS error {100 * result.rms_rel_error:.1f} %"
    )
    ax.legend(fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return path


@dataclasses.dataclass(frozen=True)
class CalibrateSettings(Settings):
    """``vdc-analyse calibrate``: the geometry to fit (a, b) for and the gratings used."""

    fps: float = option(300.0, "frame rate, Hz", range=POSITIVE)
    size: tuple[int, int] = option(  # (H, W) px
        (100, 100), "frame WIDTHxHEIGHT px", type=parse_size, range=SIDE_PX
    )
    deg_per_px: float | None = option(
        None,
        "degrees per pixel (default: 360/width, the offline-stimulus convention)",
        range=POSITIVE,
    )
    model: str = option("avdm", "AVDM variant to calibrate")
    contrasts: tuple[float, ...] = option(
        (0.5, 1.0),
        "grating contrasts to include",
        "--contrast",
        range=between(0, 1, lo_open=True),
    )
    name: str | None = option(None, "name of this calibration (default: from fps and size)")
    update_defaults: bool = option(
        False,
        "also store the fit as the shipped default for this fps and deg/px (edits "
        "avdm/calibrations.json in an editable install)",
    )

    @property
    def resolved_deg_per_px(self) -> float:
        return self.deg_per_px if self.deg_per_px is not None else 360.0 / self.size[1]

    @property
    def resolved_name(self) -> str:
        return self.name or f"fps{self.fps:g}-{self.size[1]}x{self.size[0]}"

    def base_params(self) -> Params:
        """The model's params with a = b = 1 (the fit's starting point)."""
        sep = ":" if ":" not in self.model else ","
        params = make_params(
            f"{self.model}{sep}a=1,b=1", fps=self.fps, deg_per_px=self.resolved_deg_per_px
        )
        if not isinstance(params, AvdmParams):
            raise UserError(
                f"calibrate fits the grating-calibrated AVDM (avdm and its variants); "
                f"{self.model.split(':')[0]} is fitted on clutter automatically for each camera "
                "on first use (avdm.calibration.fit_multiscale)."
            )
        return params

    def n_cells(self) -> int:
        w = self.size[1]
        return len(valid_periods_px(w)) * len(valid_tfs_hz(self.fps)) * len(self.contrasts)


# Below this log-log R² a fit does not describe the model (the shipped fits reach 0.99): it
# is written for inspection but never offered for use or stored as a default.
MIN_CALIBRATION_R2 = 0.9


@dataclasses.dataclass
class CalibrateResult(WroteFiles):
    fit: CalibrationResult
    entry: dict[str, Any]  # what calibration.json holds
    paths: list[Path]

    @property
    def usable(self) -> bool:
        return bool(self.fit.r2 >= MIN_CALIBRATION_R2)

    def report(self, s: CalibrateSettings) -> list[str]:
        """The fit and how to use it, as lines for people (its quality first)."""
        fit, (h, w) = self.fit, s.size
        lines = [
            f"calibration {s.resolved_name}: fps={s.fps:g} Hz, {s.resolved_deg_per_px:.6g} "
            f"deg/px, {w}x{h} px",
            f"  a = {fit.a:.6g}   b = {fit.b:.6g}",
            f"  log-log R^2 = {fit.r2:.4f}; over {fit.n_points} valid cells the decoded omega "
            f"is off by {100 * fit.rms_rel_error:.1f} % RMS, {100 * fit.max_rel_error:.1f} % "
            "at worst",
            f"  wrote {self.files.calibration_json} and {self.files.calibration_png}",
        ]
        if self.usable:
            lines.append(
                f"  use it as: --model {s.model.split(':')[0]}:a={fit.a:.6g},b={fit.b:.6g}"
            )
        if self.usable and s.update_defaults:
            lines.append(f"  updated the shipped defaults in {self.files.calibrations}")
        return lines


def calibrate(
    settings: CalibrateSettings = CalibrateSettings(),
    out: str | Path | None = None,
    *,
    progress: Callable[[], None] | None = None,
) -> CalibrateResult:
    """``vdc-analyse calibrate``: least-squares fit of ω = a·λ^b·(1+C)/(2C)·√R̄ on the valid
    band of drifting gratings. With ``out``: ``calibration.json`` and ``calibration.png``;
    ``update_defaults`` also stores it in the shipped ``avdm/calibrations.json``."""
    base = settings.base_params()
    h, w = settings.size
    fit = fit_decoding(base, size=(h, w), contrasts=settings.contrasts, progress=progress)  # type: ignore[arg-type]
    name, model = settings.resolved_name, canonical_name(settings.model)
    entry = calibration_entry(fit, name, model, base)
    paths: list[Path] = []
    if out is not None:
        out = Path(out)
        write_calibration(fit, out / "calibration.json", name, model, base)
        paths += [out / "calibration.json", plot_calibration(fit, out / "calibration.png")]
    result = CalibrateResult(fit, entry, paths)
    if settings.update_defaults and result.usable:
        paths.append(update_shipped(entry))
    return result
