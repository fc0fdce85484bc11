"""A learnt policy: one parameter of a model set, as it runs, from the scene's profiled complexity.

The policy is a small table a person can read and edit (CSV, ``# key: value`` lines on top)::

    # vdc policy
    # param: t_ffi
    # profile_model: avdm
    # window_s: 60
    # statistic: median
    complexity_dps,t_ffi,success_rate,avoidances_per_30min,conditions
    14.8,12,0.97,210.3,grating-tf0
    35.2,30,0.93,240.1,grating-tf3

Online, the complexity is the running ``statistic`` (median, default, or mean) of the profile
model's ``omega_dps`` (deg/s) over the last ``window_s`` seconds of frames (the frames before the
current one; at the start, the frames so far), the measure the capture can compute anywhere (the
median is barely moved by the robot's own turns, brief spikes of ω̂); the parameter is
interpolated linearly between the rows' ``complexity_dps`` and held at the end rows' values beyond
them. Columns after
the parameter are the evidence the row was chosen on (kept for the reader, not used).

``--model SPEC:policy=FILE`` (any model whose parameter can change while it runs) builds a
:class:`PolicyModel`; it adds the outputs ``policy_value`` and ``policy_complexity_dps``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from avdm.base import Output, run_by_steps
from avdm.errors import ParameterError

COMPLEXITY_COLUMN = "complexity_dps"
STATISTICS = ("median", "mean")
HEADER = "vdc policy"

if TYPE_CHECKING:
    import polars as pl

# polars is imported where a policy's table is read or written, not here: the model registry
# imports this module, so every capture did, and polars costs a process about 0.3 s of CPU at
# import and starts its thread pool, for a table a capture without a policy never touches.


@dataclasses.dataclass(frozen=True)
class Policy:
    """A parameter as a piecewise-linear function of the online complexity."""

    param: str  # the model's parameter it sets (e.g. t_ffi)
    complexity_dps: tuple[float, ...]  # increasing
    values: tuple[float, ...]  # the parameter at each complexity, interpolated between them
    window_s: float = 60.0  # the running window over the profile model's output, s
    profile_model: str = "avdm"  # the model whose omega_dps is the online complexity
    # the conditions table the policy was fitted from (boundary's), if any
    evidence: pl.DataFrame | None = dataclasses.field(default=None, compare=False)
    statistic: str = "median"  # of the profile model's omega_dps over the window

    def __post_init__(self) -> None:
        x, y = np.asarray(self.complexity_dps, float), np.asarray(self.values, float)
        if len(x) == 0 or len(x) != len(y):
            raise ParameterError("a policy needs at least one row of complexity and value.")
        if not (np.isfinite(x).all() and np.isfinite(y).all()):
            raise ParameterError("a policy's complexities and values must be finite numbers.")
        if len(x) > 1 and not (np.diff(x) > 0).all():
            raise ParameterError("a policy's complexity_dps must increase from row to row.")
        if self.statistic not in STATISTICS:
            raise ParameterError(f"a policy's statistic must be one of {', '.join(STATISTICS)}.")
        if not (math.isfinite(self.window_s) and self.window_s > 0):
            raise ParameterError(f"a policy's window_s must be > 0 s, got {self.window_s}.")

    def value(self, complexity_dps: float) -> float:
        """The parameter at this complexity (deg/s)."""
        return float(np.interp(complexity_dps, self.complexity_dps, self.values))

    def table(self) -> pl.DataFrame:
        """The rows as written: complexity, the parameter, then the evidence columns."""
        import polars as pl  # lazy: start-up (a capture imports this module: see above)

        df = pl.DataFrame(
            {COMPLEXITY_COLUMN: list(self.complexity_dps), self.param: list(self.values)}
        )
        if self.evidence is not None:
            extra = self.evidence.drop([c for c in df.columns if c in self.evidence.columns])
            df = pl.concat([df, extra], how="horizontal")
        return df

    def save(self, path: str | Path) -> Path:
        """Write the policy file (CSV with its settings on ``#`` lines)."""
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        head = (
            f"# {HEADER}\n# param: {self.param}\n# profile_model: {self.profile_model}\n"
            f"# window_s: {self.window_s:g}\n# statistic: {self.statistic}\n"
        )
        tmp = path.with_suffix(path.suffix + ".partial")
        tmp.write_text(head + self.table().write_csv(), encoding="utf-8")
        tmp.replace(path)
        return path


def load_policy(path: str | Path) -> Policy:
    """Read a policy file; ValueError in one line naming the file and what is wrong."""
    import polars as pl  # lazy: start-up (a capture imports this module: see above)

    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ParameterError(f"policy file {str(path)!r}: {exc.strerror or exc}") from None
    meta: dict[str, str] = {}
    lines = text.splitlines()
    for line in lines:
        if line.startswith("#"):
            key, _, value = line[1:].partition(":")
            if value:
                meta[key.strip()] = value.strip()
    where = f"policy file {str(path)!r}"
    if "param" not in meta:
        raise ParameterError(f"{where} has no '# param: NAME' line (is it a vdc policy?).")
    body = "\n".join(ln for ln in lines if not ln.startswith("#"))
    try:
        df = pl.read_csv(body.encode(), infer_schema_length=None)
    except Exception as exc:  # polars' many parse errors: one line for the user
        raise ParameterError(f"{where} is not a readable CSV table: {exc}") from None
    param = meta["param"]
    missing = [c for c in (COMPLEXITY_COLUMN, param) if c not in df.columns]
    if missing:
        raise ParameterError(f"{where} has no column {', '.join(missing)}.")
    try:
        df = df.with_columns(pl.col(COMPLEXITY_COLUMN, param).cast(pl.Float64)).sort(
            COMPLEXITY_COLUMN
        )
        return Policy(
            param,
            tuple(df[COMPLEXITY_COLUMN].to_list()),
            tuple(df[param].to_list()),
            float(meta.get("window_s", 60.0)),
            meta.get("profile_model", "avdm"),
            df.drop(COMPLEXITY_COLUMN, param),
            meta.get("statistic", "median"),
        )
    except (ValueError, pl.exceptions.PolarsError) as exc:
        raise ParameterError(f"{where}: {exc}") from None


class PolicyModel:
    """A model whose parameter ``policy.param`` follows the policy as frames arrive.

    ``run`` equals repeated ``step`` bit for bit (it is repeated ``step``)."""

    def __init__(
        self, inner: Any, policy: Policy, profiler: Any, context: Mapping[str, Any]
    ) -> None:
        if "fps" not in context:
            raise ParameterError("a policy needs the camera's frame rate (fps) to size its window.")
        if not callable(getattr(inner, "set_param", None)):
            raise ParameterError(f"{inner.name}: its parameters cannot change while it runs.")
        self.inner = inner
        self.policy = policy
        self.name = inner.name
        self.params = inner.params
        self.profiler = profiler  # policy.profile_model, built for the same camera
        if "omega_dps" not in {o.name for o in self.profiler.outputs}:
            raise ParameterError(f"policy profile model {policy.profile_model!r} has no omega_dps.")
        self.outputs = (
            *inner.outputs,
            Output("policy_value", "", f"{policy.param} set by the policy"),
            Output("policy_complexity_dps", "deg/s", "the policy's running AVDM statistic"),
        )
        self._names = tuple(o.name for o in self.outputs)
        self._ring = np.zeros(max(1, round(policy.window_s * float(context["fps"]))))
        self.set_param(policy.param, policy.value(0.0))  # a name it cannot change fails now
        self.reset()

    def set_param(self, name: str, value: float) -> None:
        self.inner.set_param(name, value)

    def reset(self) -> None:
        self.inner.reset()
        self.profiler.reset()
        self._ring[:] = 0.0
        self._sum = 0.0
        self._seen = 0
        self.value = self.policy.value(0.0)

    def _complexity(self) -> float:
        window = len(self._ring)
        if self.policy.statistic == "mean":
            return self._sum / min(max(self._seen, 1), window)
        if self._seen == 0:
            return 0.0
        return float(np.median(self._ring[: min(self._seen, window)]))

    def step(self, frame: np.ndarray) -> dict[str, float]:
        window = len(self._ring)
        complexity = self._complexity()
        self.value = self.policy.value(complexity)
        self.inner.set_param(self.policy.param, self.value)
        out = dict(self.inner.step(frame))
        omega = float(self.profiler.step(frame)["omega_dps"])
        slot = self._seen % window
        self._sum += omega - self._ring[slot]
        self._ring[slot] = omega
        self._seen += 1
        out["policy_value"] = self.value
        out["policy_complexity_dps"] = complexity
        return out

    def run(self, frames: np.ndarray) -> dict[str, np.ndarray]:
        return run_by_steps(self.step, frames, self._names)
