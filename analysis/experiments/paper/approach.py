"""Open-loop approach (paper Fig. 4): the robot driven straight at a grating wall.

For each wall TF, ``repeats`` runs start 0.65 m from the +y wall (body 0.63 m), at a random
lateral offset and grating phase, with seeded camera noise, and drive straight at 0.08 m/s until
the body touches the wall. The AVDM runs on the camera; the table keeps every frame, the summary
the mean ± std over repeats per 2-cm distance bin.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import polars as pl
from matplotlib.figure import Figure

from avdm.registry import make_model
from capture.config import ArenaConfig, CameraConfig, RobotConfig, WallConfig
from capture.render import CameraRenderer

START_GAP_M = 0.65  # robot centre to the wall at the start


@dataclasses.dataclass(frozen=True)
class ApproachConfig:
    tfs_hz: tuple[float, ...] = (0.0, 1.0, 2.0, 3.0)
    repeats: int = 10
    period_m: float = 0.1
    noise_sd: float = 2.0  # camera noise, 8-bit levels (repeats differ in noise and offsets)
    model: str = "avdm"
    seed: int = 0
    bin_m: float = 0.02


def approach_run(cfg: ApproachConfig, tf_hz: float, repeat: int) -> pl.DataFrame:
    """One straight approach; rows: tf_hz, repeat, frame, t_s, distance_m (body to wall),
    omega_dps."""
    arena, robot, camera = ArenaConfig(), RobotConfig(), CameraConfig(noise_sd=cfg.noise_sd)
    wall = WallConfig(period_m=cfg.period_m, tf_schedule=((tf_hz, 60.0),))
    rng = np.random.default_rng([cfg.seed, repeat, round(tf_hz * 1000)])
    _, hy = arena.half_extent
    x0 = rng.uniform(-0.3, 0.3)
    phase_m = rng.uniform(0.0, cfg.period_m)
    n = int((START_GAP_M - robot.radius_m) / robot.speed_mps * camera.fps)
    t = np.arange(n) / camera.fps
    y = hy - START_GAP_M + robot.speed_mps * t
    poses = np.column_stack([np.full(n, x0), y, np.full(n, math.pi / 2)])
    offsets = phase_m + tf_hz * cfg.period_m * t
    frames = CameraRenderer(arena, wall, camera).render(poses, offsets)
    noise = rng.normal(0.0, cfg.noise_sd, frames.shape)
    frames = np.clip(np.rint(frames + noise), 0, 255).astype(np.uint8)
    out = make_model(cfg.model, **camera.model_context()).run(frames)
    return pl.DataFrame(
        {
            "tf_hz": np.full(n, tf_hz),
            "repeat": np.full(n, repeat, np.int64),
            "frame": np.arange(n, dtype=np.int64),
            "t_s": t,
            "distance_m": hy - y - robot.radius_m,
            "omega_dps": out["omega_dps"],
        }
    )


def run_approach(
    cfg: ApproachConfig, progress: Callable[[int], None] | None = None
) -> tuple[pl.DataFrame, pl.DataFrame]:
    """All runs (frames after the model's warm-up) and the per-distance-bin summary;
    ``progress`` hears of each approach as it ends."""

    def one(tf: float, r: int) -> pl.DataFrame:
        df = approach_run(cfg, tf, r)
        if progress is not None:
            progress(1)
        return df

    runs = pl.concat([one(tf, r) for tf in cfg.tfs_hz for r in range(cfg.repeats)])
    runs = runs.filter(pl.col("frame") >= 20)
    summary = (
        runs.with_columns(
            ((pl.col("distance_m") / cfg.bin_m).floor() * cfg.bin_m + cfg.bin_m / 2).alias(
                "distance_bin_m"
            )
        )
        .group_by("tf_hz", "distance_bin_m")
        .agg(
            pl.col("omega_dps").mean().alias("mean_dps"),
            pl.col("omega_dps").std().alias("std_dps"),
            pl.col("omega_dps").count().alias("n"),
        )
        .sort("tf_hz", "distance_bin_m")
    )
    return runs, summary


def plot_approach(runs: pl.DataFrame, summary: pl.DataFrame, path: Path) -> Path:
    fig = Figure(figsize=(14, 5), layout="constrained")
    (ax_t, ax_d) = fig.subplots(1, 2)
    for i, (tf,) in enumerate(runs.select("tf_hz").unique().sort("tf_hz").iter_rows()):
        g = (
            runs.filter(pl.col("tf_hz") == tf)
            .group_by("t_s")
            .agg(pl.col("omega_dps").mean().alias("m"), pl.col("omega_dps").std().alias("s"))
            .sort("t_s")
        )
        t, m, s = g["t_s"].to_numpy(), g["m"].to_numpy(), np.nan_to_num(g["s"].to_numpy())
        ax_t.plot(t, m, color=f"C{i}", label=f"TF {tf:g} Hz")
        ax_t.fill_between(t, m - s, m + s, color=f"C{i}", alpha=0.2, lw=0)
        d = summary.filter(pl.col("tf_hz") == tf)
        dm, ds = d["mean_dps"].to_numpy(), np.nan_to_num(d["std_dps"].to_numpy())
        ax_d.plot(100 * d["distance_bin_m"].to_numpy(), dm, color=f"C{i}", label=f"TF {tf:g} Hz")
        ax_d.fill_between(
            100 * d["distance_bin_m"].to_numpy(), dm - ds, dm + ds, color=f"C{i}", alpha=0.2, lw=0
        )
    n_rep = runs["repeat"].n_unique()
    ax_t.set_xlabel("time since the start (s)")
    ax_t.set_ylabel("AVDM ω̂ (deg/s), mean ± sd")
    ax_t.set_title(f"approach at 8 cm/s, {n_rep} repeats per TF")
    ax_d.set_xlabel("distance from the body to the wall (cm)")
    ax_d.set_ylabel("AVDM ω̂ (deg/s), mean ± sd")
    ax_d.invert_xaxis()
    ax_d.set_title("against distance to the wall")
    for ax in (ax_t, ax_d):
        ax.grid(alpha=0.3)
        ax.legend()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    return path
