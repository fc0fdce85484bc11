"""What a resumed power study may reuse (docs/findings/power_plan_amendment.md): each finished
step's ``study.json`` names what it ran with (its settings without the executor, the labels'
SHA-256) and the code that scored and measured it (:func:`code_key`); where the code changed
since the last run, :func:`set_aside_stale` sets the studies aside and they are computed again.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from importlib.metadata import version  # vdc.__version__ (the facade: not imported here)
from pathlib import Path
from typing import Any

from vdc.executors import ExecutorSettings, Feedback

# What decides a study's outcomes and measures: the simulation and the detectors (capture,
# avdm), the clips' rendering, the complexity measures, footage mode's judging, the
# predictors' statistics and verdicts, and this plan. A study is reused only with the same
# vdc version and the same source of these (code_key); else it is set aside and recomputed.
# Files and folders of the source, relative to the folder that holds the packages (read as
# files, never imported: hashing a module is no dependency on it).
CODE_PATHS = (
    "avdm",
    "capture",
    "analysis/boundary",
    "analysis/complexity",
    "analysis/predictors",
    "analysis/experiments/captures.py",
    "analysis/experiments/collision/boundary_campaign.py",
    "analysis/experiments/collision/predictor_runs.py",
    "analysis/experiments/collision/looming_footage.py",
    "analysis/experiments/power/sizes.py",
    "analysis/experiments/power/pilot.py",
    "analysis/experiments/power/plans.py",
    "analysis/experiments/power/study.py",
    "analysis/experiments/power/answer.py",
    "analysis/experiments/power/units.py",
    "analysis/experiments/power/resume.py",
)
SOURCE_ROOT = Path(__file__).resolve().parents[3]  # holds analysis/, avdm/, capture/


def code_key(paths: tuple[str, ...] = CODE_PATHS, root: Path = SOURCE_ROOT) -> dict[str, str]:
    """``{vdc, code}``: the package version and the SHA-256 of the source at ``paths`` under
    ``root`` (a folder: every ``.py`` under it), by relative path and content."""
    digest = hashlib.sha256()
    for rel in paths:
        where = root / rel
        if not where.exists():
            raise ValueError(f"no source at {where} to hash")
        files = sorted(where.rglob("*.py")) if where.is_dir() else [where]
        for f in files:
            digest.update(f"{f.relative_to(root).as_posix()}\0".encode())
            digest.update(f.read_bytes())
    return {"vdc": version("visual-dynamic-complexity"), "code": digest.hexdigest()}


def set_aside_stale(out: Path, key: dict[str, str], feedback: Feedback) -> list[Path]:
    """Where ``out/code.json`` names other code than ``key``, its studies (``arena``,
    ``footage``) are renamed ``<name>.stale-<old code[:8]>`` (kept, not deleted) so that
    everything is computed again, and the log says so; then ``code.json`` names ``key``.
    Returns the folders set aside."""
    marker = out / "code.json"
    moved: list[Path] = []
    if marker.exists():
        old = json.loads(marker.read_text())
        if old != key:
            feedback.log(
                f"the code that scores and measures changed since the last run (vdc "
                f"{old.get('vdc')}, code {str(old.get('code'))[:12]} -> vdc {key['vdc']}, "
                f"code {key['code'][:12]}): every study is computed again."
            )
            for name in ("arena", "footage"):
                if (out / name).exists():
                    dst = out / f"{name}.stale-{str(old.get('code'))[:8]}"
                    n = 1
                    while dst.exists():
                        dst, n = out / f"{name}.stale-{str(old.get('code'))[:8]}-{n}", n + 1
                    (out / name).rename(dst)
                    feedback.log(f"  {out / name} set aside as {dst.name}.")
                    moved.append(dst)
    elif any((out / n).exists() for n in ("arena", "footage")):  # before code.json existed
        feedback.log("no code.json: the studies here predate the code key and are recomputed.")
        for name in ("arena", "footage"):
            if (out / name).exists():
                dst = out / f"{name}.stale-unknown"
                (out / name).rename(dst)
                moved.append(dst)
    _mark_json(marker, key)
    return moved


def _mark_json(path: Path, value: dict[str, Any]) -> None:
    tmp = path.with_suffix(".partial")
    tmp.write_text(json.dumps(value))
    tmp.replace(path)


def _done(marker: Path, key: dict[str, Any]) -> str | None:
    """The status a finished step wrote into ``marker`` (``study.json``) when it ran with this
    ``key`` (what its outcome depends on), else None."""
    if not marker.exists():
        return None
    done = json.loads(marker.read_text())
    return done["status"] if done.get("key") == json.loads(json.dumps(key)) else None


def _mark(marker: Path, key: dict[str, Any], status: str) -> None:
    marker.parent.mkdir(parents=True, exist_ok=True)
    tmp = marker.with_suffix(".partial")
    tmp.write_text(json.dumps({"key": key, "status": status}))
    tmp.replace(marker)


def _outcome_key(settings: Any) -> dict[str, Any]:
    """A step's settings without where it runs (the executor fields change no outcome)."""
    executor = {f.name for f in dataclasses.fields(ExecutorSettings)}
    return {k: v for k, v in dataclasses.asdict(settings).items() if k not in executor}
