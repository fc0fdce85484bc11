"""Collision study metrics and figures (paper Fig. 8; definitions of lgmd_colias.md §9).

* avoidance = an LGMD alert that triggered a turn; crash = the robot touched a wall;
* success rate = avoidances / (avoidances + crashes);
* distance to collision at an avoidance: from the robot's body along its heading to the wall;
* false alarm = an avoidance with distance to collision ≥ ``false_alarm_m`` (0.30 m, §9);
* density maps: 2D histograms in 0.02 m bins (occupancy = share of frames), lightly smoothed;
* ego-motion: the share of frames in which the robot turns (its avoidance turns included) and
  the avoidances triggered while it was still turning (the detector seeing its own rotation);
* across seeds (several recordings of one phase): mean and 95 % interval per phase
  (``phase_statistics``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from collections.abc import Callable, Sequence
from pathlib import Path

import matplotlib
import numpy as np
import polars as pl
import rerun as rr
import rerun.blueprint as rrb
from matplotlib.figure import Figure

from analysis.recordings.analysis_rrd import log_arena_outline, open_tabbed_rrd, view_3d
from analysis.recordings.ego_motion import turning_before
from analysis.recordings.loading import LoadedRecording, Notices, load_recording
from analysis.recordings.recompute import DistinctRecordings, SummarySettings, events_table
from analysis.recordings.segments import safe_key
from analysis.stats import Estimate, mean_ci, share_ci
from vdc.cli_support import option
from vdc.errors import UserError
from vdc.folders import path_list
from vdc.parquet_io import WroteFiles, table_set, write_parquet
from vdc.settings import POSITIVE, Settings, between

# what the paper reports for its three phases (30 min each) [BRIEF]
PAPER = {
    "tf0": {"paper_avoidances": 229, "paper_success": "> 90 %"},
    "tf3": {"paper_avoidances": 432, "paper_success": "> 90 %"},
    "tf3-adjusted": {"paper_avoidances": 233, "paper_success": "> 90 %"},
}
COLLISION_ROOT = "/collision"


@dataclasses.dataclass(frozen=True)
class CollisionSettings(Settings):
    """``vdc-analyse collision``: what counts as a false alarm, and the density maps' bins."""

    false_alarm_m: float = option(
        0.30, "avoidance with the wall farther ahead than this = false alarm, m", range=POSITIVE
    )
    bin_m: float = option(0.02, "density-map bin, m (0.005-0.2)", range=between(0.005, 0.2))


def require_collision_recording(loaded: LoadedRecording) -> None:
    """Raise ValueError unless the recording comes from collision mode."""
    run = loaded.props.get("run", {})
    if run.get("behaviour") != "collision" or "detector" not in loaded.props:
        raise UserError(
            f"{str(loaded.rec.path)!r} is not a collision-mode recording (record one with "
            "`vdc-capture sim --behaviour collision`): it has no avoidance/crash events to study."
        )


def phase_key(loaded: LoadedRecording) -> str:
    """A short condition key: tf0, tf3, tf3-adjusted, tf3-adaptive, ..."""
    col = loaded.props.get("collision", {})
    label = str(col.get("phase") or "")
    if label:
        return safe_key(label)
    tfs = loaded.frames["wall_tf_hz"].unique().sort().to_list()
    key = "tf" + "-".join(f"{t:g}" for t in tfs)
    return key + ("-adaptive" if col.get("adaptive") else "")


def collision_metrics(loaded: LoadedRecording, s: CollisionSettings) -> tuple[dict, pl.DataFrame]:
    """One summary row for a collision recording, and its events table."""
    require_collision_recording(loaded)
    ev = events_table(loaded)
    avoid = ev.filter(pl.col("kind") == "avoidance")
    crash = ev.filter(pl.col("kind") == "crash")
    n_a, n_c = avoid.height, crash.height
    minutes = loaded.frames.height / float(loaded.props["camera"]["fps"]) / 60.0
    dtc = avoid["dtc_m"].to_numpy()
    col = loaded.props.get("collision", {})
    key = phase_key(loaded)
    # avoidances while the robot was already turning before the alert (poses before it only;
    # the per-frame turning flag would also see the turn the avoidance itself starts)
    fr = loaded.frames
    index = {f: i for i, f in enumerate(fr["frame"].to_list())}
    at = np.array([index.get(f, -1) for f in avoid["frame"].to_list()], dtype=np.int64)
    avoid_turning = turning_before(
        fr["t_s"].to_numpy(),
        fr["heading_rad"].fill_null(float("nan")).to_numpy(),
        at,
        SummarySettings.turn_threshold_dps,  # the tables' turn threshold (30 deg/s)
    )
    row = {
        "recording_id": loaded.recording_id,
        "phase": key,
        "seed": loaded.props.get("run", {}).get("seed"),
        "detector": loaded.props["detector"]["name"],
        "wall_tf_hz": float(loaded.frames["wall_tf_hz"].median()),
        "adaptive": bool(col.get("adaptive", False)),
        "minutes": minutes,
        "avoidances": n_a,
        "crashes": n_c,
        "success_rate": n_a / (n_a + n_c) if n_a + n_c else float("nan"),
        "false_alarms": int((dtc >= s.false_alarm_m).sum()),
        "false_alarms_per_30min": (
            int((dtc >= s.false_alarm_m).sum()) * 30.0 / minutes if minutes else float("nan")
        ),
        "dtc_mean_m": float(dtc.mean()) if n_a else float("nan"),
        "dtc_median_m": float(np.median(dtc)) if n_a else float("nan"),
        "avoidances_per_30min": n_a * 30.0 / minutes if minutes else float("nan"),
        "crashes_per_30min": n_c * 30.0 / minutes if minutes else float("nan"),
        "turning_share": float(loaded.frames["turning"].fill_null(False).mean() or 0.0),
        "avoidances_while_turning": int(avoid_turning.sum()),
        **PAPER.get(key, {"paper_avoidances": None, "paper_success": None}),
    }
    return row, ev


def _smooth(a: np.ndarray) -> np.ndarray:
    """3×3 binomial smoothing (≈ Gaussian σ ≈ 0.7 bin) with zero padding."""
    k = np.array([1.0, 2.0, 1.0]) / 4.0
    p = np.pad(a, 1)
    rows = k[0] * p[:-2] + k[1] * p[1:-1] + k[2] * p[2:]
    return k[0] * rows[:, :-2] + k[1] * rows[:, 1:-1] + k[2] * rows[:, 2:]


def density(x: np.ndarray, y: np.ndarray, hx: float, hy: float, bin_m: float) -> np.ndarray:
    """Share of samples per bin (ny, nx), smoothed; rows run along +y."""
    xe = np.linspace(-hx, hx, max(1, round(2 * hx / bin_m)) + 1)
    ye = np.linspace(-hy, hy, max(1, round(2 * hy / bin_m)) + 1)
    counts, _, _ = np.histogram2d(y, x, bins=(ye, xe))
    total = counts.sum()
    return _smooth(counts / total) if total else counts


def plot_recording(
    loaded: LoadedRecording, row: dict, ev: pl.DataFrame, s: CollisionSettings, path: Path
) -> Path:
    """Trajectory occupancy, avoidance and crash density maps (paper Fig. 8) for one run."""
    hx, hy = loaded.arena_half_extent()
    f = loaded.frames
    maps = [
        ("trajectory occupancy", f["x_m"].to_numpy(), f["y_m"].to_numpy(), "viridis", None),
        (f"avoidances ({row['avoidances']})", *_xy(ev, "avoidance"), "Blues", "C0"),
        (f"crashes ({row['crashes']})", *_xy(ev, "crash"), "Reds", "C3"),
    ]
    fig = Figure(figsize=(17, 4.6), layout="constrained")
    axes = fig.subplots(1, 3)
    for ax, (title, x, y, cmap, dot) in zip(axes, maps, strict=True):
        d = density(x, y, hx, hy, s.bin_m)
        im = ax.imshow(d, origin="lower", extent=(-hx, hx, -hy, hy), cmap=cmap, aspect="equal")
        if dot is not None and len(x):
            ax.scatter(x, y, s=6, c=dot, edgecolors="k", linewidths=0.2)
        ax.set_title(title)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        fig.colorbar(im, ax=ax, shrink=0.8, label="share per 2 cm bin")
    sr = row["success_rate"]
    fig.suptitle(
        f"{row['phase']}: {row['detector']}, TF {row['wall_tf_hz']:g} Hz, "
        f"{row['minutes']:.1f} min - success {100 * sr:.1f} %, false alarms "
        f"{row['false_alarms']}, median distance to collision "
        f"{100 * row['dtc_median_m']:.1f} cm"
    )
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    return path


def _xy(ev: pl.DataFrame, kind: str) -> tuple[np.ndarray, np.ndarray]:
    e = ev.filter(pl.col("kind") == kind)
    return e["x_m"].to_numpy(), e["y_m"].to_numpy()


PHASE_ORDER = ["tf0", "tf3", "tf3-adjusted", "tf3-adaptive", "tf0-adaptive"]


def _phase_rank(phase: str) -> tuple[int, str]:
    return (PHASE_ORDER.index(phase) if phase in PHASE_ORDER else len(PHASE_ORDER), phase)


# every count is a rate per 30 min (the paper's run length), whatever the runs' length
PHASE_STATISTICS = (
    "avoidances_per_30min",
    "crashes_per_30min",
    "success_rate",
    "false_alarms_per_30min",
)


def phase_statistics(summary: pl.DataFrame) -> pl.DataFrame:
    """One row per phase from the per-recording ``summary`` (one recording per seed): the
    number of seeds, and for avoidances, crashes and false alarms per 30 min and success rate
    the mean with its 95 % interval (``<name>``, ``<name>_low``, ``<name>_high``; counts are
    clipped at 0, NaN bounds with one seed). The success rate's interval also covers the
    exact binomial interval of the pooled avoidances and crashes (``stats.share_ci``)."""
    rows = []
    for phase in sorted(summary["phase"].unique().to_list(), key=_phase_rank):
        g = summary.filter(pl.col("phase") == phase)
        row = {
            "phase": phase,
            "detector": g["detector"][0],
            "wall_tf_hz": float(g["wall_tf_hz"][0]),
            "seeds": g.height,
            "minutes": float(g["minutes"].mean()),
        }
        for name in PHASE_STATISTICS:
            if name == "success_rate":
                n = g["avoidances"] + g["crashes"]
                est = share_ci(g["avoidances"].to_numpy(), n.to_numpy())
            else:
                est = mean_ci(g[name].cast(pl.Float64).to_numpy(), bounds=(0.0, math.inf))
            row |= {name: est.mean, f"{name}_low": est.low, f"{name}_high": est.high}
        row |= PAPER.get(phase, {"paper_avoidances": None, "paper_success": None})
        rows.append(row)
    return pl.DataFrame(rows)


def plot_study(summary: pl.DataFrame, path: Path) -> Path:
    """Avoidances and crashes per 30 min and success rate per phase, beside the paper's: the
    mean across seeds with its 95 % interval as error bars, each seed as a dot."""
    phases = phase_statistics(summary)
    fig = Figure(figsize=(14, 5), layout="constrained")
    (ax_n, ax_s) = fig.subplots(1, 2)
    labels = phases["phase"].to_list()
    x = np.arange(len(labels))

    def bars(ax, dx: float, name: str, color: str, label: str, scale: float = 1.0) -> None:
        mean = phases[name].to_numpy() * scale
        err = np.vstack(
            [
                mean - phases[f"{name}_low"].to_numpy() * scale,
                phases[f"{name}_high"].to_numpy() * scale - mean,
            ]
        )
        ax.bar(x + dx, mean, 0.27, color=color, label=label)
        if np.isfinite(err).any():
            ax.errorbar(x + dx, mean, yerr=np.nan_to_num(err), fmt="none", ecolor="k", capsize=3)
        for i, phase in enumerate(labels):
            seeds = summary.filter(pl.col("phase") == phase)[name].to_numpy() * scale
            ax.scatter(np.full(len(seeds), i + dx), seeds, s=10, c="k", zorder=3)

    n_seeds = ", ".join(sorted({str(n) for n in phases["seeds"].to_list()}))
    bars(ax_n, -0.27, "avoidances_per_30min", "C0", "avoidances (ours, per 30 min)")
    bars(ax_n, 0.0, "crashes_per_30min", "C3", "crashes (ours, per 30 min)")
    paper = [v if v is not None else np.nan for v in phases["paper_avoidances"].to_list()]
    ax_n.bar(x + 0.27, paper, 0.27, color="0.6", label="avoidances (paper)")
    ax_n.set_xticks(x, labels, rotation=15)
    ax_n.legend(fontsize=8)
    ax_n.set_title(f"events per phase: mean of {n_seeds} seed(s), 95 % interval, seeds as dots")
    bars(ax_s, 0.0, "success_rate", "C2", "success rate (ours)", scale=100.0)
    ax_s.axhline(90, color="k", ls="--", lw=1, label="paper: > 90 % in every phase")
    ax_s.set_xticks(x, labels, rotation=15)
    ax_s.set_ylim(0, 105)
    ax_s.set_ylabel("success rate (%)")
    ax_s.legend(fontsize=8)
    ax_s.set_title("avoidances / (avoidances + crashes)")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    return path


def write_collision_rrd(
    items: list[tuple[LoadedRecording, dict, pl.DataFrame]],
    s: CollisionSettings,
    path: Path,
    recording_id: str,
) -> Path:
    """Avoidance and crash positions (Points3D) over an occupancy map, a tab per recording."""
    tabs = []
    for loaded, row, _ in items:
        base = f"{COLLISION_ROOT}/{safe_key(row['phase'] + '_' + loaded.recording_id[-8:])}"
        points = f"{row['phase']}: avoidances (blue), crashes (red)"
        tabs.append(
            rrb.Horizontal(
                view_3d(points, base, "avoidances", "crashes", "arena"),
                rrb.Spatial2DView(name="trajectory occupancy", origin=f"{base}/occupancy"),
                name=row["phase"],
            )
        )
    rec = open_tabbed_rrd(path, recording_id, tabs)
    for loaded, row, ev in items:
        base = f"{COLLISION_ROOT}/{safe_key(row['phase'] + '_' + loaded.recording_id[-8:])}"
        hx, hy = loaded.arena_half_extent()
        log_arena_outline(rec, f"{base}/arena", hx, hy)
        for kind, color in (("avoidance", (40, 140, 255)), ("crash", (255, 50, 50))):
            x, y = _xy(ev, kind)
            rec.log(
                f"{base}/{kind}s",
                rr.Points3D(np.column_stack([x, y, np.zeros_like(x)]), radii=0.008, colors=[color]),
                static=True,
            )
        occ = density(
            loaded.frames["x_m"].to_numpy(), loaded.frames["y_m"].to_numpy(), hx, hy, s.bin_m
        )
        top = occ.max() if occ.size and occ.max() > 0 else 1.0
        rgb = (matplotlib.colormaps["viridis"](occ / top)[:, :, :3] * 255).astype(np.uint8)
        rec.log(f"{base}/occupancy", rr.Image(np.ascontiguousarray(rgb[::-1])), static=True)
    rec.flush()
    rec.disconnect()
    return path


@dataclasses.dataclass
class CollisionResult(WroteFiles):
    """Per-recording (phase) metrics, every avoidance and crash, and the files written."""

    summary: pl.DataFrame
    events: pl.DataFrame
    paths: list[Path]
    notices: list[str]

    @property
    def phases(self) -> pl.DataFrame:
        """One row per phase: means and 95 % intervals across its recordings (seeds)."""
        return phase_statistics(self.summary)

    def markdown(self) -> str:
        """The per-phase table across seeds, then the per-recording table."""
        return phase_table_markdown(self.phases) + "\n\n" + collision_table_markdown(self.summary)


def collision(
    recordings: str | Path | Sequence[str | Path],
    settings: CollisionSettings = CollisionSettings(),
    out: str | Path | None = None,
    *,
    notice: Callable[[str], None] | None = None,
    progress: Callable[[int], None] | None = None,
) -> CollisionResult:
    """``vdc-analyse collision`` (Fig. 8): metrics of closed-loop recordings, ordered by
    phase. With ``out``: ``collision_summary.parquet``, ``collision_events.parquet``, a PNG
    per recording, ``collision_study.png`` and ``collision.rrd``. ``progress(1)`` after each
    recording's metrics."""

    items, notes = [], Notices(notice)
    distinct = DistinctRecordings()
    for path in path_list(recordings):  # a single path given as a str: a list of one
        loaded = load_recording(path)
        distinct.add(loaded.recording_id, path)
        notes.of(loaded)
        row, ev = collision_metrics(loaded, settings)
        items.append((loaded, row, ev))
        if progress is not None:
            progress(1)
    items.sort(key=lambda it: (_phase_rank(it[1]["phase"]), it[1]["seed"] or 0, it[0].recording_id))
    summary = pl.DataFrame([row for _, row, _ in items])
    events = pl.concat([ev for _, _, ev in items])
    paths: list[Path] = []
    if out is not None:
        out = Path(out)
        meta = {
            "settings": {"false_alarm_m": settings.false_alarm_m, "bin_m": settings.bin_m},
            "recordings": [row["recording_id"] for _, row, _ in items],
        }
        with table_set(out) as stage:  # published whole: never a mix of two runs
            paths.append(write_parquet(summary, stage / "collision_summary.parquet", meta))
            paths.append(write_parquet(events, stage / "collision_events.parquet", meta))
            paths.append(
                write_parquet(phase_statistics(summary), stage / "collision_phases.parquet", meta)
            )
            per_phase = summary["phase"].value_counts()
            several = set(per_phase.filter(pl.col("count") > 1)["phase"].to_list())
            for loaded, row, ev in items:
                name = row["phase"] + (f"_seed{row['seed']}" if row["phase"] in several else "")
                png = stage / f"collision_{safe_key(name)}.png"
                paths.append(plot_recording(loaded, row, ev, settings, png))
            paths.append(plot_study(summary, stage / "collision_study.png"))
            rid = "collision-" + hashlib.sha1("|".join(meta["recordings"]).encode()).hexdigest()[:8]
            paths.append(write_collision_rrd(items, settings, stage / "collision.rrd", rid))
        paths = [out / p.name for p in paths]
    return CollisionResult(summary, events, paths, list(notes))


def collision_table_markdown(summary: pl.DataFrame) -> str:
    """The per-recording table beside the paper's numbers, as Markdown."""
    lines = [
        "| phase | seed | detector | TF (Hz) | minutes | avoidances | per 30 min | crashes | "
        "success | false alarms | median dist. to collision | avoidances while turning | "
        "paper avoidances | paper success |",
        "|" + "---|" * 14,
    ]
    for r in summary.iter_rows(named=True):
        lines.append(
            f"| {r['phase']} | {r['seed'] if r['seed'] is not None else '-'} | {r['detector']} | "
            f"{r['wall_tf_hz']:g} | {r['minutes']:.1f} | "
            f"{r['avoidances']} | {r['avoidances_per_30min']:.0f} | {r['crashes']} | "
            f"{100 * r['success_rate']:.1f} % | {r['false_alarms']} | "
            f"{100 * r['dtc_median_m']:.1f} cm | {r['avoidances_while_turning']} | "
            f"{r['paper_avoidances'] or '-'} | {r['paper_success'] or '-'} |"
        )
    return "\n".join(lines)


def phase_estimate(row: dict, name: str) -> Estimate:
    """One statistic of a :func:`phase_statistics` row as an :class:`Estimate`."""
    return Estimate(row[name], row[f"{name}_low"], row[f"{name}_high"], row["seeds"])


def _est(r: dict, name: str, fmt: str, scale: float = 1.0) -> str:
    e = phase_estimate(r, name)
    if not math.isfinite(e.low):
        return fmt.format(e.mean * scale)  # one seed: the value alone
    return e.text(fmt, scale)


def phase_table_markdown(phases: pl.DataFrame) -> str:
    """The per-phase table across seeds (mean [95 % interval]) beside the paper's numbers."""
    lines = [
        "| phase | detector | TF (Hz) | seeds | avoidances per 30 min | crashes per 30 min | "
        "success (%) | false alarms per 30 min | paper avoidances | paper success |",
        "|" + "---|" * 10,
    ]
    for r in phases.iter_rows(named=True):
        lines.append(
            f"| {r['phase']} | {r['detector']} | {r['wall_tf_hz']:g} | {r['seeds']} | "
            f"{_est(r, 'avoidances_per_30min', '{:.0f}')} | "
            f"{_est(r, 'crashes_per_30min', '{:.1f}')} | "
            f"{_est(r, 'success_rate', '{:.1f}', 100.0)} | "
            f"{_est(r, 'false_alarms_per_30min', '{:.1f}')} | "
            f"{r['paper_avoidances'] or '-'} | {r['paper_success'] or '-'} |"
        )
    return "\n".join(lines)
