"""``vdc-capture campaign``: a grid of simulated runs (a campaign), each one executor task.

The grid is a few ``FIELD=V1,V2,...`` items over :class:`capture.sim.SimSettings` (the
``vdc-capture sim`` flags, same names), e.g.::

    behaviour=collision model=lgmd-plus-arena minutes=30 threshold=40,56,80 tf_hz=0,1,3 seed=1..5

Items with one value apply to every run; the runs are the product of the others (here
3 x 3 x 5 = 45). Each run records ``OUT/recordings/<key>.rrd`` and then writes its row of the
runs table, ``OUT/runs/<key>.parquet``, atomically: that row is the run's "done" mark, so a
re-run after a crash, a signal or a killed worker records only the runs without one. At the
end the rows are concatenated into ``OUT/runs.parquet`` (one row per run: every setting of the
run, varied or the same for all, the recording, frames, how it ended, event counts), ready
for ``vdc-analyse collision`` or ``vdc-analyse batch OUT/recordings/*.rrd``.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import re
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import polars as pl

from avdm.registry import make_params
from capture.run import REPLACE_OUTPUT
from capture.sim import SimSettings, record_sim
from vdc.cli_support import option
from vdc.errors import UserError
from vdc.executors import QUIET, ExecutorSettings, Feedback, TaskOutcome, run_tasks
from vdc.parquet_io import WroteFiles, write_parquet
from vdc.scratch import no_files_without_out

RUNS = "runs"
RECORDINGS = "recordings"
_TRUE = {"true", "yes", "1", "on"}
_FALSE = {"false", "no", "0", "off"}


def _field_types() -> dict[str, str]:
    return {f.name: str(f.type) for f in dataclasses.fields(SimSettings)}


def _convert(field: str, kind: str, text: str) -> Any:
    """``text`` as the type SimSettings declares for ``field`` (annotations are strings)."""
    text = text.strip()
    if "None" in kind and text.lower() == "none":
        return None
    base = kind.replace("| None", "").strip()
    try:
        if base == "float":
            return float(text)
        if base == "int":
            return int(text)
        if base == "bool":
            if text.lower() in _TRUE | _FALSE:
                return text.lower() in _TRUE
            raise UserError(text)
    except ValueError:
        raise UserError(f"grid item {field}: {text!r} is not a {base}.") from None
    return text


_MODEL_FIELDS = ("model", "profile_model")
# the most runs one sweep plans; a typo such as seed=1..1000000 is refused, not started
MAX_RUNS = 10_000


def _model_specs(text: str) -> list[str]:
    """``avdm:beta=0.5,tw=6,avdm-on`` → ``["avdm:beta=0.5,tw=6", "avdm-on"]``: a comma starts a
    new variant unless what follows is one more ``key=value`` of the variant before it (the
    model spec syntax, ``name:key=value,...``); ``;`` always separates."""
    specs: list[str] = []
    for group in text.split(";"):
        for token in group.split(","):
            token = token.strip()
            if specs and "=" in token and ":" not in token and ":" in specs[-1]:
                specs[-1] += "," + token
            elif token:
                specs.append(token)
        specs.append("")  # a ';' closes the variant before it
    return [s for s in specs if s]


def _values(field: str, kind: str, text: str) -> list[Any]:
    """``1,2,3`` or, for integers, ``1..5`` (inclusive)."""
    m = re.fullmatch(r"\s*(-?\d+)\s*\.\.\s*(-?\d+)\s*", text)
    if m and kind.startswith("int"):
        lo, hi = int(m[1]), int(m[2])
        if hi < lo:
            raise UserError(f"grid item {field}={text}: the range runs backwards.")
        return list(range(lo, hi + 1))
    # a TF schedule holds commas itself: give several schedules separated by ';'
    if field == "tf_schedule":
        parts = text.split(";")
    elif field in _MODEL_FIELDS:
        parts = _model_specs(text)
    else:
        parts = text.split(",")
    values = [_convert(field, kind, v) for v in parts if v.strip()]
    if not values:
        raise UserError(f"grid item {field}= has no value.")
    return values


def parse_grid(items: Sequence[str]) -> dict[str, list[Any]]:
    """``["tf_hz=0,1,3", "seed=1..5", "minutes=3"]`` → field → values, in the given order.
    Field names are ``vdc-capture sim``'s flags (``tf-hz`` or ``tf_hz``)."""
    types = _field_types()
    grid: dict[str, list[Any]] = {}
    for item in items:
        name, sep, text = item.partition("=")
        field = name.strip().lstrip("-").replace("-", "_")
        if not sep:
            raise UserError(f"grid item {item!r}: expected FIELD=V1,V2,...")
        if field not in types:
            raise UserError(
                f"grid item {item!r}: {field!r} is not a vdc-capture sim setting "
                f"(one of {', '.join(types)})."
            )
        if field in grid:
            raise UserError(f"grid item {field} is given twice.")
        grid[field] = _values(field, types[field], text)
    if not grid:
        raise UserError("the grid is empty: give items such as tf_hz=0,1,3 seed=1..3.")
    return grid


def _token(value: Any) -> str:
    text = f"{value:g}" if isinstance(value, float) else str(value)
    return re.sub(r"[^A-Za-z0-9.+-]+", "_", text)


@dataclasses.dataclass(frozen=True)
class CampaignSettings(ExecutorSettings):
    """``vdc-capture campaign``: the grid items, ``force`` to record finished runs again, and
    where the runs go (``executor``, ``jobs``, ``scheduler``)."""

    grid: tuple[str, ...] = option(
        (), "FIELD=V1,V2,... (see above)", positional=True, metavar="GRID"
    )
    force: bool = option(False, "record finished runs again")

    def __post_init__(self) -> None:
        super().__post_init__()
        object.__setattr__(self, "grid", tuple(self.grid))
        self.runs()  # a bad grid or run fails here, before anything is recorded

    def runs(self) -> list[tuple[str, dict[str, Any], SimSettings]]:
        """(key, varied values, settings) of every run; the key names the varied values."""
        grid = parse_grid(self.grid)
        fixed = {k: v[0] for k, v in grid.items() if len(v) == 1}
        varied = {k: v for k, v in grid.items() if len(v) > 1}
        n_runs = math.prod(len(v) for v in varied.values())
        if n_runs > MAX_RUNS:
            raise UserError(
                f"the grid makes {n_runs:,} runs, more than {MAX_RUNS:,}: give fewer values "
                "(or several sweeps)."
            )
        for field in _MODEL_FIELDS:  # unknown variants or overrides fail before any run
            for spec in grid.get(field, []):
                if spec is not None:
                    make_params(spec)
        runs = []
        for combo in itertools.product(*varied.values()) if varied else [()]:
            values = dict(zip(varied, combo, strict=True))
            key = "-".join(f"{k}{_token(v)}" for k, v in values.items()) or "run"
            settings = SimSettings(**fixed, **values)
            settings.to_config().run_id()  # every value checked (ranges, combinations)
            runs.append((key, values, settings))
        return runs


@dataclasses.dataclass
class CampaignResult(WroteFiles):
    runs: pl.DataFrame  # one row per finished run
    planned: int
    skipped: int  # finished by an earlier invocation
    outcomes: list[TaskOutcome]  # this invocation's tasks
    failures: list[tuple[str, str]]  # (run key, error)
    paths: list[Path]
    elapsed_s: float


def run_path(out: Path, key: str) -> Path:
    return Path(out) / RUNS / f"{key}.parquet"


def _settings_columns(settings: SimSettings, exclude: dict[str, Any]) -> dict[str, Any]:
    """Every field of a run's settings as a column value (a tuple or mapping as its text)."""
    cols = {}
    for f in dataclasses.fields(settings):
        if f.name not in exclude:
            v = getattr(settings, f.name)
            cols[f.name] = v if v is None or isinstance(v, (bool, int, float, str)) else str(v)
    return cols


def record_run(key: str, values: dict[str, Any], settings: SimSettings, out: str) -> dict[str, Any]:
    """One run of the grid, as an executor task: record it, then write its row (the done
    mark) atomically. Module-level, small arguments, a small result."""

    rec = Path(out) / RECORDINGS / f"{key}.rrd"
    res = record_sim(settings, rec, REPLACE_OUTPUT)  # a partial file of a killed run is replaced
    row = {
        "run": key,
        **values,
        **_settings_columns(settings, exclude=values),  # the constant ones too: the table
        "recording": str(rec),  # describes its runs whole
        "recording_id": res.recording_id,
        "frames": res.frames,
        "expected_frames": res.expected_frames,
        "stop_reason": res.stop_reason,
        "complete": res.complete,
        "wall_time_s": res.wall_time_s,
        **{f"events_{k}": v for k, v in sorted(res.events.items())},
    }
    meta = {"settings": dataclasses.asdict(settings)}
    write_parquet(pl.DataFrame([row]), run_path(Path(out), key), meta)
    return {"run": key, "seconds": res.wall_time_s}


def collect_runs(out: str | Path, keys: Sequence[str]) -> pl.DataFrame:
    """The rows of the finished runs among ``keys`` under ``out``, in key order (events absent
    from a run count 0)."""
    files = [run_path(Path(out), k) for k in sorted(keys) if run_path(Path(out), k).exists()]
    if not files:
        return pl.DataFrame()
    df = pl.concat([pl.read_parquet(f) for f in files], how="diagonal_relaxed")
    events = [c for c in df.columns if c.startswith("events_")]
    return df.with_columns(pl.col(events).fill_null(0)).sort("run")


@no_files_without_out
def campaign(
    settings: CampaignSettings, out: str | Path | None, feedback: Feedback = QUIET
) -> CampaignResult:
    """Record every run of the grid that has no row yet (all with ``force``) on the executor,
    then write ``OUT/runs.parquet``. A failed run is listed and does not stop the others."""
    t0 = time.perf_counter()
    out = Path(out)
    runs = settings.runs()
    todo = [r for r in runs if settings.force or not run_path(out, r[0]).exists()]
    feedback.log(
        f"{len(runs)} runs: {len(runs) - len(todo)} already done, {len(todo)} to record on "
        f"{settings.where()}."
    )
    (out / RECORDINGS).mkdir(parents=True, exist_ok=True)
    feedback.expect(len(todo))

    def done(outcome: TaskOutcome) -> None:
        if outcome.error is not None:
            feedback.log(f"FAILED {outcome.key}: {outcome.error}")
        feedback.progress(1)

    outcomes = run_tasks(
        record_run,
        [(key, (key, values, s, str(out))) for key, values, s in todo],
        settings.executor_settings(),
        done,
        feedback.log,
        shared_paths=[out],
    )
    failures = [(o.key, o.error) for o in outcomes if o.error is not None]
    table = collect_runs(out, [r[0] for r in runs])
    paths = []
    if table.height:
        meta = {"grid": list(settings.grid)}
        paths.append(write_parquet(table, out / "runs.parquet", meta))
    return CampaignResult(
        table,
        len(runs),
        len(runs) - len(todo),
        outcomes,
        failures,
        paths,
        time.perf_counter() - t0,
    )
