"""How true is an angular-velocity reading? Real photographs panned at known speeds.

The protocol (``benchmarks/bench_avdm_truth.py`` runs it whole; the tests run one cell):

* a real photograph that ships inside scikit-image is a panorama; a virtual camera with a
  70° field of view sees part of it (``avdm.stimuli.panned_image``: exact sub-pixel Fourier
  shifts, area-averaged pixels) and turns at a known speed, in either direction;
* the frames are made at a *video pitch* (320 px across 70°, 0.22 deg/px) and optionally go
  through H.264 (libx264, CRF 23, the codec's default quality); the *robot pitch* (99 px,
  0.71 deg/px) is the video frames area-resized as ``vdc-capture video`` resizes them;
* each registered model (``TRUTH_VARIANTS``: ``avdm``, ``avdm-natural`` and the Hassenstein–
  Reichardt correlator ``hrc``) and three of OpenCV's optic flows (``FLOW_READERS``: DIS, as
  ``complexity``'s ``flow_dps`` computes it; Farnebäck; pyramidal Lucas–Kanade on a grid of
  points) read the speed; a flow reads the mean |horizontal flow| in deg/s; a cell's reading is
  the mean after the warm-up.

``summarise_truth`` then gives, per reader: the median absolute relative error per speed, the
share of frames a model flagged valid (``omega_valid``), the worst direction asymmetry and
Spearman's ρ between reading and truth per image.
"""

from __future__ import annotations

import dataclasses
import io
import math
from collections.abc import Callable, Sequence
from fractions import Fraction
from functools import lru_cache
from itertools import pairwise
from pathlib import Path

import cv2
import numpy as np
import polars as pl
from matplotlib.figure import Figure

from analysis.stats import spearman
from avdm.registry import make_model
from avdm.stimuli import panned_image
from vdc.errors import UserError
from vdc.recording import camera_model_context

FOV_DEG = 70.0
TRUTH_VIEW_FRACTION = 0.65  # the camera sees this share of the photograph's width
VIDEO_SIZE = (232, 320)  # (H, W): 0.22 deg/px, a small video's pitch at 70°
ROBOT_SIZE = (72, 99)  # the robot camera's raster, 0.71 deg/px
SPEEDS_DPS = (1.0, 2.0, 5.0, 10.0, 20.0, 40.0, 80.0, 160.0, 300.0)
IMAGES = ("camera", "astronaut", "coffee", "chelsea", "rocket", "brick", "grass", "gravel")
TRUTH_VARIANTS = ("avdm", "avdm-natural", "hrc")
FLOW_READERS = ("dis", "farneback", "lk")


@lru_cache(maxsize=len(IMAGES))
def photograph(name: str) -> np.ndarray:
    """A photograph that ships inside scikit-image, as 8-bit luma (H, W) float64.

    Needs scikit-image (the ``test`` extra); nothing is downloaded: only images inside the
    package's own data folder are used. Remembered (read-only): the protocol reads each many
    times."""
    try:
        from skimage import data  # lazy: optional extra
    except ImportError:  # pragma: no cover - the test extra installs it
        raise UserError(
            "the validation photographs need scikit-image: pip install scikit-image"
        ) from None
    img = getattr(data, name)()
    if img.ndim == 3:  # BT.601 luma, as a video decoder's gray conversion gives
        img = img[..., :3] @ np.array([0.299, 0.587, 0.114])
    out = np.asarray(img, dtype=np.float64)
    out.flags.writeable = False
    return out


def h264_roundtrip(frames: np.ndarray, fps: float, crf: int = 23) -> np.ndarray:
    """Encode grey frames (T, H, W) uint8 as H.264 (yuv420p, libx264) in memory and decode
    them back to luma: what a real clip's frames look like after the codec."""

    import av  # lazy: start-up

    buf = io.BytesIO()
    with av.open(buf, "w", format="matroska") as out:
        stream = out.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001))
        stream.width, stream.height = frames.shape[2], frames.shape[1]
        stream.pix_fmt = "yuv420p"
        stream.options = {"crf": str(crf)}
        for f in frames:
            frame = av.VideoFrame.from_ndarray(np.stack([f] * 3, axis=-1), format="rgb24")
            for packet in stream.encode(frame):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)
    buf.seek(0)
    with av.open(buf) as inp:
        return np.stack([fr.to_ndarray(format="gray") for fr in inp.decode(video=0)])


@dataclasses.dataclass(frozen=True)
class Cell:
    """One condition of the protocol."""

    image: str
    omega_true_dps: float
    direction: int  # +1 or -1
    fps: float
    pitch: str  # "robot" or "video"
    codec: str  # "none" or "h264"


# the protocol measures each pan at two pitches, raw and through H.264: one pan serves all four
# (the 18 speeds and directions of an image and frame rate, ~60 MB at the video pitch)
@lru_cache(maxsize=2 * len(SPEEDS_DPS))
def _pan(image: str, omega_dps: float, direction: int, fps: float, n_frames: int) -> np.ndarray:
    frames = panned_image(
        photograph(image),
        size=VIDEO_SIZE,
        fov_deg=FOV_DEG,
        image_deg=FOV_DEG / TRUTH_VIEW_FRACTION,
        fps=fps,
        omega_dps=omega_dps,
        n_frames=n_frames,
        direction=direction,
    )
    frames.flags.writeable = False
    return frames


def cell_frames(cell: Cell, n_frames: int = 45) -> np.ndarray:
    """The frames (T, H, W) uint8 a model sees in ``cell``."""
    frames = _pan(cell.image, cell.omega_true_dps, cell.direction, cell.fps, n_frames).copy()
    if cell.codec == "h264":
        frames = h264_roundtrip(frames, cell.fps)
    if cell.pitch == "robot":
        h, w = ROBOT_SIZE
        frames = np.stack([cv2.resize(f, (w, h), interpolation=cv2.INTER_AREA) for f in frames])
    return frames


def dis_speed_dps(frames: np.ndarray, fps: float, deg_per_px: float) -> np.ndarray:
    """Mean |horizontal DIS flow| (OpenCV, preset medium, as ``complexity``'s ``flow_dps``) per
    frame pair, deg/s: (T−1,)."""
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    px = [float(np.abs(dis.calc(a, b, None)[..., 0]).mean()) for a, b in pairwise(frames)]
    return np.asarray(px) * deg_per_px * fps


# OpenCV's documented example parameters (the dense optical flow tutorial): pyramid scale 0.5,
# 3 levels, 15 px window, 3 iterations, 5 px polynomial neighbourhood, σ 1.2
FARNEBACK = {
    "pyr_scale": 0.5,
    "levels": 3,
    "winsize": 15,
    "iterations": 3,
    "poly_n": 5,
    "poly_sigma": 1.2,
    "flags": 0,
}


def farneback_speed_dps(frames: np.ndarray, fps: float, deg_per_px: float) -> np.ndarray:
    """Mean |horizontal Farnebäck flow| (``cv2.calcOpticalFlowFarneback``, ``FARNEBACK``) per
    frame pair, deg/s, read as DIS is: (T−1,)."""
    px = [
        float(np.abs(cv2.calcOpticalFlowFarneback(a, b, None, **FARNEBACK)[..., 0]).mean())
        for a, b in pairwise(frames)
    ]
    return np.asarray(px) * deg_per_px * fps


def lk_grid(h: int, w: int) -> np.ndarray:
    """The points Lucas–Kanade tracks: a grid about 40 points across (every ``max(4, W/40)``
    px, at least 10 px from the border), (N, 1, 2) float32 (x, y)."""
    step = max(4, round(w / 40))
    xs = np.arange(min(10, w // 4), w - min(10, w // 4), step)
    ys = np.arange(min(10, h // 4), h - min(10, h // 4), step)
    gx, gy = np.meshgrid(xs, ys)
    return np.stack([gx.ravel(), gy.ravel()], axis=-1).astype(np.float32)[:, None, :]


def lk_speed_dps(frames: np.ndarray, fps: float, deg_per_px: float) -> np.ndarray:
    """Mean |horizontal displacement| of the grid points pyramidal Lucas–Kanade
    (``cv2.calcOpticalFlowPyrLK``, OpenCV's defaults: 21×21 window, 3 pyramid levels) tracks
    from each frame to the next, over the points it reports found, deg/s: (T−1,). A pair
    where it finds none reads 0."""
    pts = lk_grid(*frames.shape[1:])
    px = []
    for a, b in pairwise(frames):
        moved, status, _ = cv2.calcOpticalFlowPyrLK(a, b, pts, None)
        ok = status.ravel() == 1
        px.append(float(np.abs(moved[ok, 0, 0] - pts[ok, 0, 0]).mean()) if ok.any() else 0.0)
    return np.asarray(px) * deg_per_px * fps


FLOW_SPEED = {"dis": dis_speed_dps, "farneback": farneback_speed_dps, "lk": lk_speed_dps}


def measure_truth_cell(
    cell: Cell,
    variants: Sequence[str] = TRUTH_VARIANTS,
    n_frames: int = 45,
    warm: int = 20,
    flows: Sequence[str] = FLOW_READERS,
) -> list[dict]:
    """Rows (one per reader: each variant and each optic flow of ``flows``) with the mean and
    spread of the reading after ``warm`` frames and, for the models with ``omega_valid``, the
    share of frames flagged valid (NaN for the flows, which flag nothing)."""
    frames = cell_frames(cell, n_frames)
    h, w = frames.shape[1:]
    ctx = camera_model_context(w, h, cell.fps, FOV_DEG)
    base = dataclasses.asdict(cell)
    rows = []
    for spec in variants:
        out = make_model(spec, **ctx).run(frames)
        r = out["omega_dps"][warm:]
        valid = out.get("omega_valid")
        rows.append(
            {
                **base,
                "reader": spec,
                "omega_dps": float(r.mean()),
                "omega_sd_dps": float(r.std()),
                "valid_share": float(valid[warm:].mean()) if valid is not None else math.nan,
            }
        )
    for flow in flows:
        d = FLOW_SPEED[flow](frames, cell.fps, float(ctx["deg_per_px"]))[warm - 1 :]
        rows.append(
            {
                **base,
                "reader": flow,
                "omega_dps": float(d.mean()),
                "omega_sd_dps": float(d.std()),
                "valid_share": math.nan,
            }
        )
    return rows


def protocol_cells(
    images: Sequence[str] = IMAGES,
    speeds: Sequence[float] = SPEEDS_DPS,
    fps: Sequence[float] = (25.0, 30.0),
    pitches: Sequence[str] = ("robot", "video"),
    codecs: Sequence[str] = ("none", "h264"),
) -> list[Cell]:
    # the pitches and codecs of one pan next to each other: its frames are made once
    return [
        Cell(i, float(v), d, float(f), p, c)
        for i in images
        for f in fps
        for v in speeds
        for d in (1, -1)
        for p in pitches
        for c in codecs
    ]


def run_protocol(
    cells: Sequence[Cell],
    variants: Sequence[str] = TRUTH_VARIANTS,
    progress: Callable[[], None] | None = None,
) -> pl.DataFrame:
    """Every cell measured: one row per (cell, reader)."""
    rows = []
    for c in cells:
        rows.extend(measure_truth_cell(c, variants))
        if progress is not None:
            progress()
    return pl.DataFrame(rows)


def summarise_truth(table: pl.DataFrame) -> tuple[pl.DataFrame, pl.DataFrame]:
    """(per reader and speed: median and max |relative error| over images, directions, fps,
    pitches and codecs, and the mean share of frames flagged valid (NaN for a reader without
    a flag); per reader: worst direction asymmetry over 2–300 deg/s, and the smallest
    Spearman ρ over (image, fps, pitch, codec) groups)."""

    t = table.with_columns(
        ((pl.col("omega_dps") - pl.col("omega_true_dps")).abs() / pl.col("omega_true_dps")).alias(
            "abs_rel_error"
        )
    )
    per_speed = (
        t.group_by("reader", "omega_true_dps")
        .agg(
            pl.col("abs_rel_error").median().alias("median_abs_rel_error"),
            pl.col("abs_rel_error").max().alias("max_abs_rel_error"),
            pl.col("valid_share").mean().alias("valid_share"),
        )
        .sort("reader", "omega_true_dps")
    )
    keys = ["reader", "image", "fps", "pitch", "codec", "omega_true_dps"]
    pos = t.filter(pl.col("direction") == 1).select(*keys, pl.col("omega_dps").alias("plus"))
    neg = t.filter(pl.col("direction") == -1).select(*keys, pl.col("omega_dps").alias("minus"))
    pair = pos.join(neg, on=keys).filter(pl.col("omega_true_dps") >= 2.0)
    pair = pair.with_columns(
        (
            (pl.col("plus") - pl.col("minus")).abs()
            / ((pl.col("plus") + pl.col("minus")) / 2).clip(lower_bound=1e-9)
        ).alias("asymmetry")
    )
    groups = []
    for (reader, image, fps, pitch, codec), g in t.group_by(
        "reader", "image", "fps", "pitch", "codec"
    ):
        rho = spearman(g["omega_true_dps"].to_numpy(), g["omega_dps"].to_numpy())
        groups.append(
            {
                "reader": reader,
                "image": image,
                "fps": fps,
                "pitch": pitch,
                "codec": codec,
                "spearman": rho,
            }
        )
    rho_t = pl.DataFrame(groups)
    per_reader = (
        pair.group_by("reader")
        .agg(
            pl.col("asymmetry").max().alias("worst_asymmetry"),
            pl.col("asymmetry").median().alias("median_asymmetry"),
            (pl.col("asymmetry") <= 0.10).mean().alias("share_asymmetry_le_0_10"),
        )
        .join(
            rho_t.group_by("reader").agg(
                pl.col("spearman").min().alias("min_spearman"),
                (pl.col("spearman") >= 0.95).mean().alias("share_spearman_ge_0_95"),
            ),
            on="reader",
        )
        .join(
            per_speed.filter(pl.col("omega_true_dps") >= 2.0)
            .group_by("reader")
            .agg(pl.col("median_abs_rel_error").max().alias("worst_median_error_2_300")),
            on="reader",
        )
        .sort("reader")
    )
    return per_speed, per_reader


def plot_truth(table: pl.DataFrame, path: str | Path) -> Path:
    """Reading against truth (log-log), each reader's median and 10–90 % band over images,
    directions, fps, pitches and codecs; the ±25 % band around the truth shaded."""

    fig = Figure(figsize=(7.5, 5.5), layout="constrained")
    ax = fig.add_subplot()
    v = np.array(sorted(table["omega_true_dps"].unique().to_list()))
    ax.fill_between(v, v * 0.75, v * 1.25, color="0.85", label="truth ±25 %")
    ax.plot(v, v, color="k", lw=1)
    for reader, g in sorted(table.group_by("reader"), key=lambda x: str(x[0][0])):
        stats = (
            g.group_by("omega_true_dps")
            .agg(
                pl.col("omega_dps").median().alias("med"),
                pl.col("omega_dps").quantile(0.1).alias("lo"),
                pl.col("omega_dps").quantile(0.9).alias("hi"),
            )
            .sort("omega_true_dps")
        )
        x = stats["omega_true_dps"].to_numpy()
        (line,) = ax.plot(x, stats["med"].to_numpy(), marker="o", label=str(reader[0]))
        ax.fill_between(
            x, stats["lo"].to_numpy(), stats["hi"].to_numpy(), color=line.get_color(), alpha=0.2
        )
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("true angular speed (deg/s)")
    ax.set_ylabel("reading (deg/s): median and 10-90 % over cells")
    fps = "/".join(f"{f:g}" for f in sorted(table["fps"].unique().to_list()))
    codecs = set(table["codec"].unique().to_list())
    codec = "±H.264" if codecs == {"none", "h264"} else ("H.264" if codecs == {"h264"} else "raw")
    n_img, n_pitch = table["image"].n_unique(), table["pitch"].n_unique()
    ax.set_title(
        f"{n_img} real photographs panned at known speeds ({fps} fps, {n_pitch} pitches, {codec})"
    )
    ax.legend()
    ax.grid(alpha=0.3, which="both")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    return path
