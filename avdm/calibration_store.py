"""The AVDM's decoding calibrations (a, b): shipped ones, and fits for any other camera.

``calibrations.json`` is produced by ``vdc-analyse calibrate ... --update-defaults`` and holds
one entry per camera geometry (frame rate, degrees per pixel) with the fit quality and the grid
it used. A camera without a shipped entry is fitted on first use and the fit is cached in the
user's cache folder (the one file outside the package that ``avdm`` reads or writes, with its
lock file: processes that need the same fit at once wait for the one fitting it).
"""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
import hashlib
import json
import math
import os
from collections.abc import Callable, Iterator
from functools import cache
from importlib import resources
from pathlib import Path
from typing import Any

from threadpoolctl import threadpool_limits

from avdm.avdm_model import AvdmParams
from avdm.calibration import (
    CLUTTER_SEEDS,
    fit_decoding,
    fit_multiscale,
    valid_periods_px,
    valid_tfs_hz,
)
from avdm.file_lock import exclusive
from avdm.version import __version__

CALIBRATION_FILE = "calibrations.json"


@dataclasses.dataclass(frozen=True)
class FitNote:
    """What a calibration fit is doing, for the caller to show (``avdm`` prints nothing).

    ``stage``: ``"fitting"`` (a fit starts: ``total`` stimuli to measure), ``"step"`` (one
    stimulus measured) or ``"cached"`` (the fit is done and written to ``cache_file``; empty
    when the cache folder cannot be written)."""

    stage: str
    model: str  # avdm or avdm-natural
    fps: float  # Hz
    deg_per_px: float
    size_hw: tuple[int, int]  # the raster the fit runs on, px
    total: int = 0
    cache_file: str = ""

    def camera(self) -> str:
        """``33 Hz, 0.7071 deg/px, 99x72 px`` (W x H, as every size vdc prints)."""
        h, w = self.size_hw
        return f"{self.fps:g} Hz, {self.deg_per_px:.4g} deg/px, {w}x{h} px"


_REPORT: contextvars.ContextVar[Callable[[FitNote], None] | None] = contextvars.ContextVar(
    "vdc_fit_report", default=None
)


@contextlib.contextmanager
def fit_progress(report: Callable[[FitNote], None] | None) -> Iterator[None]:
    """Within the block, every calibration fit (however deep in ``make_model`` it starts)
    tells ``report`` what it fits, each step and where it cached the result: a fit takes
    seconds to minutes, and the caller decides how to show it (a bar, a log line). Nested, both
    the outer and the inner ``report`` hear every note."""
    outer = _REPORT.get()
    if outer is not None and report is not None:
        inner = report

        def report(note: FitNote) -> None:
            outer(note)
            inner(note)

    token = _REPORT.set(report if report is not None else outer)
    try:
        yield
    finally:
        _REPORT.reset(token)


@cache
def shipped_calibrations() -> tuple[dict[str, Any], ...]:
    """All shipped calibration entries (read once)."""
    text = resources.files("avdm").joinpath(CALIBRATION_FILE).read_text(encoding="utf-8")
    return tuple(json.loads(text)["calibrations"])


# Parameters that never change a calibration fit: the decoding constants themselves, the camera
# (keyed separately, to 1e-9), the texture row (the calibration gratings are uniform down
# every column, so every row sees the same pattern) and the preferred direction (the gratings
# drift in it, so a mirrored model meets mirrored stimuli: the same fit).
NOT_DECODING_DYNAMICS = frozenset({"a", "b", "fps", "deg_per_px", "texture_row", "direction"})


def dynamics(params: Any) -> dict[str, Any]:
    """The parameters of ``params`` (a params object or its flat dict) that change the model's
    dynamics, hence its calibration: every field but those in ``NOT_DECODING_DYNAMICS``."""
    values = params if isinstance(params, dict) else params.to_dict()
    return {k: v for k, v in values.items() if k not in NOT_DECODING_DYNAMICS}


def lookup_calibration(fps: float, deg_per_px: float, params: Any = None) -> dict[str, Any] | None:
    """The shipped entry whose fps and deg/px match (to 1e-6 relative) and, if ``params`` is
    given, whose model dynamics equal those of ``params``; or None."""
    want = None if params is None else dynamics(params)
    for entry in shipped_calibrations():
        if math.isclose(entry["fps"], fps, rel_tol=1e-6) and math.isclose(
            entry["deg_per_px"], deg_per_px, rel_tol=1e-6
        ):
            have = dynamics(entry["model_params"])
            if want is None or (entry.get("model", "avdm") == "avdm" and have == want):
                return entry
    return None


# -- fits for any camera, cached per user ----------------------------------------------------
#
# Policy: a camera's frame rate and angular resolution are used as given, never snapped to a
# "nominal" neighbour: 29.97 Hz (30000/1001) and 30 Hz get fits of their own (their decoding
# constants differ by ~0.25 %). An avdm-natural fit takes about 8 s of a core
# (docs/guides/video.md);
# callers show its progress through fit_progress. The fit uses the default AVDM on 72-px-high
# frames 99 px wide (the robot camera's raster, which the valid band of periods
# was designed for): the decoding constants depend on frame rate and degrees per pixel, not on
# the frame's size. The key holds everything that changes the fit, so a stale entry is never
# used: fps and deg/px (to 1e-9), the raster, the grating contrasts and the vdc version.

CAL_SIZE = (72, 99)  # (H, W) of the calibration gratings
CAL_CONTRASTS = (0.5, 1.0)


def cache_dir() -> Path:
    """``$VDC_CACHE_DIR``, else ``$XDG_CACHE_HOME/vdc``, else ``~/.cache/vdc``."""
    if os.environ.get("VDC_CACHE_DIR"):
        return Path(os.environ["VDC_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "vdc"


def decoding_key(fps: float, deg_per_px: float, params: Any = None) -> dict[str, Any]:
    kind = "avdm" if params is None or isinstance(params, AvdmParams) else "avdm-multiscale"
    key: dict[str, Any] = {
        "fps": float(f"{fps:.9g}"),
        "deg_per_px": float(f"{deg_per_px:.9g}"),
        "size_hw": list(CAL_SIZE) if kind == "avdm" else [params.height_px, params.width_px],  # type: ignore[union-attr]
        "model": kind,
        "vdc_version": __version__,
    }
    if key["model"] == "avdm":
        key["contrasts"] = list(CAL_CONTRASTS)
    if params is not None:
        key["dynamics"] = dynamics(params)
    return key


def cache_path(key: dict[str, Any], stem: str) -> Path:
    """Where a calibration under ``key`` is cached: ``stem`` (the model and rate, for people)
    and a digest of the whole key."""
    digest = hashlib.sha1(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]
    return cache_dir() / "calibrations" / f"{stem}-{digest}.json"


def read_cached(path: Path, key: dict[str, Any]) -> dict[str, Any] | None:
    """The entry cached at ``path`` if it was made under ``key``; None if absent, unreadable
    or another key's (then it is fitted again)."""
    try:
        entry = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return entry if isinstance(entry, dict) and entry.get("key") == key else None


def write_cached(path: Path, entry: dict[str, Any]) -> str:
    """Cache ``entry`` at ``path`` atomically (a partial file, then renamed: a reader never
    sees half an entry); the path written, or "" when it cannot be (that only costs a fit
    next time)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f"{path.name}.{os.getpid()}.partial")
        tmp.write_text(json.dumps(entry, indent=2) + "\n", encoding="utf-8")
        tmp.replace(path)
    except OSError:
        return ""
    return str(path)


def calibration_for(
    fps: float,
    deg_per_px: float,
    progress: Callable[[], None] | None = None,
    params: Any = None,
) -> dict[str, Any]:
    """The decoding calibration for this camera and these model dynamics: shipped, cached, or
    fitted now and cached.

    ``params`` (an ``AvdmParams`` or ``AvdmMultiScaleParams``; default: the default AVDM)
    says which model and which dynamics: a variant that changes ``beta``, ``tw``, thresholds
    or any other parameter but the decoding constants gets a fit of its own, so its output is
    honest deg/s. The entry carries ``a``, ``b``, the fit's quality (``r2``,
    ``rms_rel_error``, ``max_rel_error``, ``n_points``) and ``source``: ``shipped``, ``cache``
    or ``fitted``. ``progress`` is called once per stimulus of a new fit."""

    if params is None:
        params = AvdmParams(fps=fps, deg_per_px=deg_per_px)
    params = params.replace(fps=fps, deg_per_px=deg_per_px, a=None, b=None)
    multiscale = not isinstance(params, AvdmParams)
    if not multiscale:  # the row does not change the fit; the calibration raster is 72 rows
        params = params.replace(texture_row=AvdmParams.texture_row)
        shipped = lookup_calibration(fps, deg_per_px, params)
        if shipped is not None:
            return {**shipped, "source": "shipped"}
    key = decoding_key(fps, deg_per_px, params)
    path = cache_path(key, f"{key['model']}-{key['fps']:g}Hz")
    cached = read_cached(path, key)
    if cached is not None:
        return {**cached, "source": "cache", "cache_file": str(path)}
    with contextlib.suppress(OSError):  # an unwritable cache folder: fitted unlocked
        path.parent.mkdir(parents=True, exist_ok=True)
    # processes that need the same new calibration at once (a pool's workers on clips of one
    # camera) fit it once: the others wait here, then read what it cached
    with exclusive(path.with_name(path.name + ".lock")):
        cached = read_cached(path, key)
        if cached is not None:
            return {**cached, "source": "cache", "cache_file": str(path)}
        return _fit_and_cache(params, key, path, fps, deg_per_px, multiscale, progress)


def _fit_and_cache(
    params: Any,
    key: dict[str, Any],
    path: Path,
    fps: float,
    deg_per_px: float,
    multiscale: bool,
    progress: Callable[[], None] | None,
) -> dict[str, Any]:
    report = _REPORT.get()
    if multiscale:
        size = (params.height_px, params.width_px)  # its scales depend on the raster
        total = 2 * len(CLUTTER_SEEDS) * 10  # two passes over the seeds x 10 speeds
    else:
        size = CAL_SIZE
        total = len(valid_periods_px(size[1])) * len(valid_tfs_hz(fps)) * len(CAL_CONTRASTS)
    name = "avdm-natural" if multiscale else "avdm"
    note = FitNote("fitting", name, fps, deg_per_px, size, total)
    step = progress
    if report is not None:
        report(note)
        stepped = dataclasses.replace(note, stage="step")

        def step() -> None:
            report(stepped)
            if progress is not None:
                progress()

    # one BLAS thread: the pans' matrix products are small (~64 x 231 x 307), and OpenBLAS's
    # default threads spin while they wait; an avdm-natural fit at 25 Hz, 85 px took 68 s of
    # CPU with them and 6.7 s with one, the same constants (a sum's order only)
    with threadpool_limits(limits=1, user_api="blas"):
        if multiscale:
            fit = fit_multiscale(params, size=size, progress=step)
        else:
            fit = fit_decoding(params, size=size, contrasts=CAL_CONTRASTS, progress=step)
    entry = {"key": key, **key, **fit.to_dict()}
    written = write_cached(path, entry)
    if report is not None:
        report(dataclasses.replace(note, stage="cached", cache_file=written))
    return {**entry, "source": "fitted", "cache_file": written}
