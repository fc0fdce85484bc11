"""How long the pre-registered plan (docs/findings/power_plan.md, ``vdc-analyse power-study``)
takes:
an estimate on 2 local cores and on a Dask cluster of N workers, from measured per-unit times.

Run: ``python benchmarks/bench_power_plan.py [--plan 2026-12] [--minutes 0.25] [--workers 8,32]``
(``--plan``: the amended plan, the default, or the first, 2026-11). Measures, in
this process, after one warm-up run (compile caches, calibrations):

* one closed-loop arena run of each arena detector and one profiling run with every
  complexity measure of the predictors, each ``--minutes`` long (default: the quick plan's
  length), recorded and measured as the campaign's task does it
  (``boundary_campaign.record_and_measure``);
* one footage clip of the plan's length rendered and encoded; its complexity (the
  ``complexity`` command on one clip, one worker: its pool start-up included); each footage
  detector judging it (``clip_task``) and the predictors' pass over it (``clip_frames_task``).

The estimate: each stage of the plan (the arena detectors' campaigns one after the other, the
shared profiling runs, the clips rendered in one process, then each footage detector's
complexity, clip and predictor passes) takes ceil(its tasks / workers) × its unit's time, an
arena run's time scaled from ``--minutes`` to the plan's 3 minutes in proportion (the run's
start-up included: a slight over-estimate). It is an estimate, not a measurement of the plan:
it leaves out the statistics and figures at the end (seconds) and assumes the machine gives
each worker a core. The plain reference, measured in the same run: one arena run (LGMD+)
recorded alone with ``record_sim``, nothing measured.
"""

from __future__ import annotations

import argparse
import math
import os
import tempfile
import time
from pathlib import Path

from analysis.boundary.footage import clip_task
from analysis.boundary.footage_predictors import clip_frames_task
from analysis.boundary.settings import BoundarySettings
from analysis.complexity.command import ComplexitySettings, complexity
from analysis.experiments.captures import profiling_items
from analysis.experiments.collision.boundary_campaign import grid_items, record_and_measure
from analysis.experiments.collision.looming_footage import LoomingFootageSettings, looming_footage
from analysis.experiments.power.plans import PLANS
from capture.run import REPLACE_OUTPUT
from capture.sim import record_sim

CPU: list[float] = []  # each timed call's CPU seconds in this process, in order


def timed(fn, *args) -> float:
    """Wall seconds of ``fn(*args)``; its CPU seconds in this process appended to CPU."""
    t0, c0 = time.perf_counter(), time.process_time()
    fn(*args)
    CPU.append(time.process_time() - c0)
    return time.perf_counter() - t0


def arena_unit(tmp: Path, detector: str, param: str, value: float, minutes: float) -> float:
    s = BoundarySettings(
        detector=detector,
        param=param,
        values=(value,),
        scenes=("natural",),
        tf=(1.0,),
        seeds=1,
        minutes=minutes,
    )
    it = grid_items(s, tmp / detector)[0]
    it.path.parent.mkdir(parents=True, exist_ok=True)
    return timed(record_and_measure, it.key, it.settings, str(it.path), "collision", 0.3)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=0.25, help="measured run length")
    ap.add_argument("--workers", default="8,32", help="Dask cluster sizes, comma-separated")
    ap.add_argument("--plan", default="2026-12", choices=tuple(PLANS), help="the plan's version")
    args = ap.parse_args()
    plan = PLANS[args.plan]
    scale = plan.minutes / args.minutes
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        warm = BoundarySettings(
            scenes=("natural",), tf=(1.0,), values=(12.0,), seeds=1, minutes=0.05
        )
        one = grid_items(warm, tmp / "warm")[0]
        record_sim(one.settings, one.path)  # warm-up: compile caches, calibrations
        ref = BoundarySettings(
            scenes=("natural",), tf=(1.0,), values=(12.0,), seeds=1, minutes=args.minutes
        )
        r = grid_items(ref, tmp / "ref")[0]
        reference = timed(record_sim, r.settings, r.path, REPLACE_OUTPUT)

        unit = {d: arena_unit(tmp, d, p, v, args.minutes) for d, p, v in plan.arena_detectors}
        prof = profiling_items(ref, tmp / "prof")[0]
        prof.path.parent.mkdir(parents=True, exist_ok=True)
        profile_s = timed(
            record_and_measure, prof.key, prof.settings, str(prof.path), "profile", 0.0, 8
        )

        w, h = plan.clip_size
        cs = LoomingFootageSettings(clips=1, seconds=plan.clip_seconds, width_px=w, height_px=h)
        render_s = timed(looming_footage, cs, tmp / "clips")
        clip = str(next((tmp / "clips").glob("clip*.mp4")))
        cx = ComplexitySettings(fov_deg=cs.hfov_deg, metrics="all", jobs=1)
        complexity_s = timed(complexity, [clip], cx, tmp / "cx")
        det_s, frames_s = {}, {}
        for d, p, v in plan.footage_detectors:
            spec = f"{d}:{p}={v:g}"
            det_s[d] = timed(clip_task, clip, spec, None, cs.hfov_deg, plan.alert_window_s, 0.5)
            frames_s[d] = timed(clip_frames_task, clip, {f"{v:g}": spec}, cs.hfov_deg)

    # wall and CPU seconds of each unit, in the order measured (CPU: this process only; the
    # complexity command's work is in its pool's worker, so its wall time stands for both)
    names = ["reference", *unit, "profile", "render", "complexity"]
    names += [f"{k} {d}" for d in det_s for k in ("judged", "predictors")]
    walls = [reference, *unit.values(), profile_s, render_s, complexity_s]
    walls += [x for d in det_s for x in (det_s[d], frames_s[d])]
    k = names.index("complexity")
    cpus = [*CPU[:k], complexity_s, *CPU[k + 1 :]]
    runs = plan.conditions() * plan.seeds
    print(
        f"plan: {plan.conditions()} conditions x {plan.seeds} seeds x "
        f"{len(plan.arena_detectors)} arena detectors + {runs} profiling runs = "
        f"{plan.arena_runs()} runs of {plan.minutes:g} min; {plan.clips} clips x "
        f"{len(plan.footage_detectors)} footage detectors"
    )
    print(f"load average while measuring: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print(
        f"reference: one arena run (lgmd-plus-arena, {args.minutes:g} min) recorded alone "
        f"with record_sim: {reference:.1f} s ({cpus[0]:.1f} s of CPU)"
    )
    for name, w, c in zip(names[1:], walls[1:], cpus[1:], strict=True):
        per = f" per {args.minutes:g}-min run" if name in unit or name == "profile" else ""
        print(f"  {name}: {w:.2f} s ({c:.2f} s of CPU){per}")

    def estimate(workers: int, secs: list[float]) -> float:
        t = dict(zip(names, secs, strict=True))

        def stage(tasks: int, unit_s: float) -> float:
            return math.ceil(tasks / workers) * unit_s

        total = sum(stage(runs, t[d] * scale) for d in unit)
        total += stage(runs, t["profile"] * scale)
        total += plan.clips * t["render"]  # rendered in the command's own process
        total += stage(plan.clips, t["complexity"])  # measured once, shared by the detectors
        total += sum(stage(plan.clips, t[f"judged {d}"] + t[f"predictors {d}"]) for d in det_s)
        if plan.confirm:  # the footage pilot: its clips rendered, each detector judging them
            total += plan.pilot_clips * (t["render"] + sum(t[f"judged {d}"] for d in det_s))
        return total

    def moved(workers: int, secs: list[float]) -> float:
        """The worst case of the confirmation: every arena value moved, its first seed run
        again at the new value (unmoved, the first seed is the study's own, reused)."""
        t = dict(zip(names, secs, strict=True))
        if not plan.confirm:
            return 0.0
        return sum(math.ceil(plan.conditions() / workers) * t[d] * scale for d in unit)

    print(
        "estimate of the full plan (not a measurement; see the docstring), from the wall "
        "times at this load / from the CPU times (cores to itself):"
    )
    sizes = [("2 local cores", 2)] + [
        (f"Dask cluster of {n} workers", n) for n in (int(w) for w in args.workers.split(","))
    ]
    for label, n in sizes:
        print(f"  {label}: {estimate(n, walls) / 3600:.1f} h / {estimate(n, cpus) / 3600:.1f} h"
              + (f"; every arena value moved: + {moved(n, walls) / 3600:.1f} h / "
                 f"{moved(n, cpus) / 3600:.1f} h" if plan.confirm else ""))  # fmt: skip


if __name__ == "__main__":
    main()
