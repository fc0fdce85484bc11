"""The one small interface every vision model and variant implements.

A model is built from a frozen params dataclass and keeps its own state:

* ``step(frame)`` processes one frame and returns ``{output_name: float}`` (online use);
* ``run(frames)`` processes ``frames[T, H, W]`` and returns ``{output_name: ndarray[T]}``
  (offline use). ``run`` continues from the current state, so running a recording in
  chunks gives exactly the floats of one long ``run`` or of repeated ``step`` calls;
* ``reset()`` forgets all history;
* ``outputs`` names every output and its unit.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any, ClassVar, Protocol, runtime_checkable

import numpy as np

from avdm.errors import ParameterError

# The output a model is summarised, profiled and plotted by: the angular velocity when a model
# has one, else its first output (the detectors' spike rate or membrane potential).
PRIMARY_OUTPUT = "omega_dps"


# The columns every per-frame table of model outputs carries beside the outputs themselves
# (``tables``' model_outputs.parquet, ``batch``, ``compare``, ``catalog query``): a model output
# of one of these names would overwrite the frame numbers or times, so none may have one.
FRAME_TABLE_COLUMNS = ("recording_id", "model", "frame", "t_s")


def primary_output_name(names: Sequence[str]) -> str:
    """The one rule for a model's primary output, given its output names in order."""
    names = list(names)
    if not names:
        raise ParameterError("a model with no outputs has no primary output.")
    return PRIMARY_OUTPUT if PRIMARY_OUTPUT in names else names[0]


@dataclasses.dataclass(frozen=True)
class Output:
    """One model output: its name (a column or entity name) and its unit."""

    name: str
    unit: str
    description: str


class Params:
    """Mixin for frozen params dataclasses: flat dict round trip and validation hooks."""

    def to_dict(self) -> dict[str, Any]:
        """Flat ``{field: value}`` with plain Python scalars (stored in recordings and tables)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}  # type: ignore[arg-type]

    @classmethod
    def field_types(cls) -> dict[str, type]:
        """Field name → the Python type its string overrides are parsed into."""
        out: dict[str, type] = {}
        for f in dataclasses.fields(cls):  # type: ignore[arg-type]
            t = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", str(f.type))
            t = t.replace(" ", "")
            if t in ("int",):
                out[f.name] = int
            elif t in ("float", "float|None"):
                out[f.name] = float
            elif t == "bool":
                out[f.name] = bool
            else:
                out[f.name] = str
        return out

    def check_ranges(
        self,
        model: str,
        positive: Sequence[str] = (),
        integers: Sequence[tuple[str, int, int]] = (),
    ) -> None:
        """Raise ParameterError naming the first field out of its range: each of ``positive`` a
        finite number > 0, each ``(name, lo, hi)`` of ``integers`` a whole number from lo to
        hi; ``model`` names the model in the message."""
        for name in positive:
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ParameterError(f"{model} parameter {name}={v!r}: must be a positive number.")
        for name, lo, hi in integers:
            v = getattr(self, name)
            if not (isinstance(v, int) and lo <= v <= hi):
                raise ParameterError(
                    f"{model} parameter {name}={v!r}: must be an integer from {lo} to {hi}."
                )

    def replace(self, **changes: Any) -> Params:
        """A copy with ``changes`` applied (and validated)."""
        return dataclasses.replace(self, **changes)  # type: ignore[type-var]


@runtime_checkable
class Model(Protocol):
    """What analysis and capture rely on; every model in the registry satisfies it."""

    name: str
    params: Params
    outputs: ClassVar[tuple[Output, ...]]

    def reset(self) -> None: ...

    def step(self, frame: np.ndarray) -> dict[str, float]: ...

    def run(self, frames: np.ndarray) -> dict[str, np.ndarray]: ...


def require_alert(model: Model) -> None:
    """ValueError, in one line, unless ``model`` is a detector: it has an ``alert`` output (1 =
    collision ahead), what drives the robot's avoidance and what footage is scored on."""
    if "alert" not in {o.name for o in model.outputs}:
        raise ParameterError(
            f"detector {model.name!r} has no 'alert' output (1 = collision ahead): give its "
            "model an output named alert."
        )


def alert_frames(alert: np.ndarray) -> tuple[np.ndarray, int]:
    """A detector's ``alert`` output (T,) float read as (T,) bool: the frames it alerts on
    (``alert > 0``), and how many frames its alert is NaN. A NaN is neither an alert nor its
    absence: it counts as no alert, but the caller must say how many (never silently)."""
    values = np.asarray(alert, dtype=np.float64)
    return values > 0, int(np.isnan(values).sum())


def run_by_steps(
    step: Any, frames: np.ndarray, names: tuple[str, ...], **check: int
) -> dict[str, np.ndarray]:
    """``run`` of a model that only knows ``step``: (T,) float64 per output name."""
    rows = [step(f) for f in check_frames(frames, **check)]
    return {k: np.array([r[k] for r in rows], dtype=np.float64) for k in names}


def check_frames(frames: np.ndarray, *, min_h: int = 1, min_w: int = 2) -> np.ndarray:
    """Validate a stack of frames ``(T, H, W)`` and return it C-contiguous.

    Accepts ``uint8`` (0–255) or floating point (intensity scale [0, 1]). Raises
    ``ValueError`` naming the problem for anything else: wrong rank, empty axes,
    frames too small for the model, other dtypes, NaN or infinite values.
    """
    arr = np.asarray(frames)
    if arr.ndim != 3:
        raise ParameterError(
            f"frames must have shape (T, H, W), got an array of shape {arr.shape}."
        )
    t, h, w = arr.shape
    if t == 0 or h == 0 or w == 0:
        raise ParameterError(f"frames must not be empty, got shape {arr.shape}.")
    if h < min_h or w < min_w:
        raise ParameterError(
            f"frames of {w}x{h} px (WxH) are too small: need at least {min_w}x{min_h}."
        )
    if arr.dtype == np.uint8:
        return np.ascontiguousarray(arr)
    if arr.dtype in (np.float32, np.float64):
        if not np.isfinite(arr).all():
            raise ParameterError("frames contain NaN or infinite values.")
        return np.ascontiguousarray(arr)
    if (
        arr.dtype == np.bool_
        or np.issubdtype(arr.dtype, np.integer)
        or np.issubdtype(arr.dtype, np.floating)
    ):
        raise ParameterError(
            f"frames must be uint8 (0-255) or float32/float64 (0-1), got dtype {arr.dtype}."
        )
    raise ParameterError(f"frames must be numeric images, got dtype {arr.dtype}.")


class FrameStream:
    """What the stateful kernel models share: a stream of frames of one raster and one
    intensity scale, counted; ``run`` and ``step`` on top of the subclass's ``_advance``.

    A subclass sets ``output_names`` and ``min_width`` and implements ``_allocate(h, w,
    dtype)`` (buffers for a new stream) and ``_kernel(frames) -> (T, n_outputs)``."""

    output_names: ClassVar[tuple[str, ...]] = ()
    min_width: ClassVar[int] = 2

    def reset(self) -> None:
        """Forget all history; the next frame is treated as the first."""
        self._shape: tuple[int, int] | None = None
        self._dtype: np.dtype | None = None
        self._counter = np.zeros(1, dtype=np.int64)

    @property
    def frames_seen(self) -> int:
        """Number of frames processed since construction or the last ``reset``."""
        return int(self._counter[0])

    def _allocate(self, h: int, w: int, dtype: np.dtype) -> None:  # pragma: no cover
        raise NotImplementedError

    def _kernel(self, frames: np.ndarray) -> np.ndarray:  # pragma: no cover
        raise NotImplementedError

    def _advance(self, frames: np.ndarray) -> np.ndarray:
        _, h, w = frames.shape
        if self._shape is None:
            self._allocate(h, w, frames.dtype)
            self._shape, self._dtype = (h, w), frames.dtype
        elif (h, w) != self._shape:
            raise ParameterError(
                f"frame shape changed from {self._shape[1]}x{self._shape[0]} to {w}x{h} px (WxH); "
                "call reset() first."
            )
        elif (frames.dtype == np.uint8) != (self._dtype == np.uint8):
            raise ParameterError(
                f"frame dtype changed from {self._dtype} to {frames.dtype} (intensity scale "
                "would change); call reset() first."
            )
        return self._kernel(frames)

    def run(self, frames: np.ndarray) -> dict[str, np.ndarray]:
        """Process ``frames`` (T, H, W), uint8 or float on [0, 1].

        Returns ``{output: (T,) float64}``."""
        out = self._advance(check_frames(frames, min_h=1, min_w=self.min_width))
        return {n: np.ascontiguousarray(out[:, c]) for c, n in enumerate(self.output_names)}

    def step(self, frame: np.ndarray) -> dict[str, float]:
        """Process one frame (H, W); return ``{output: float}``."""
        arr = np.asarray(frame)
        if arr.ndim != 2:
            raise ParameterError(
                f"a frame must have shape (H, W), got an array of shape {arr.shape}."
            )
        row = self._advance(check_frames(arr[None], min_h=1, min_w=self.min_width))[0]
        return {n: float(row[c]) for c, n in enumerate(self.output_names)}
