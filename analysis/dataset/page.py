"""``dataset.html``: the episodes worst first, a strip of thumbnails around each flagged
episode's flagged frame, and the measures across the dataset as one figure; self-contained
(the images inline)."""

from __future__ import annotations

import base64
import html
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import polars as pl
from matplotlib.figure import Figure

from analysis.dataset.flags import FLAGS, first_flags
from analysis.dataset.layout import Dataset, Problem
from analysis.dataset.window import WindowReader
from vdc.sources import open_reader

STRIP_HALF = 4  # frames either side of the flagged one
THUMB_WIDTH = 128  # px

EPISODE_COLUMNS = (
    "episode_index", "camera", "flags", "frames_decoded", "length", "fps", "dropped",
    "drift_start_ms", "drift_end_ms", "frozen_longest_s", "idle_head_s", "idle_tail_s",
    "lag_ms", "lag_low_ms", "lag_high_ms", "shift_px", "shift_within_px", "blurred_share",
    "underexposed_share", "overexposed_share", "ti_p910_mean", "omega_dps_mean",
)  # fmt: skip
# the figure: one panel per measure, episodes along x, flagged episodes in red
PANELS = (
    ("drift_end_ms", "drift at the end, ms"), ("dropped", "dropped frames"),
    ("frozen_longest_s", "longest frozen run, s"), ("idle_head_s", "idle head, s"),
    ("lag_ms", "lag behind the state, ms"), ("shift_px", "camera shift, px"),
    ("blurred_share", "share of frames blurred"), ("overexposed_share", "share over-exposed"),
    ("ti_p910_mean", "TI (P.910), mean"),
)  # fmt: skip


def _png(img: np.ndarray) -> str:
    ok, buf = cv2.imencode(".png", img)
    return base64.b64encode(buf.tobytes()).decode() if ok else ""


def thumbnails(ds: Dataset, episode: int, camera: str, frame: int) -> np.ndarray | None:
    """(h, k × w) uint8 grey: the frames ``frame`` ± STRIP_HALF of the episode's camera side
    by side, the flagged one framed in white (decoded again: only flagged episodes)."""
    video = next((v for v in ds.videos if v.episode == episode and v.camera == camera), None)
    if video is None:
        return None
    try:
        reader = (
            WindowReader(video.path, video.from_s, video.to_s, ds.rate(camera))
            if video.kind == "video"
            else open_reader(video.path, ds.rate(camera))
        )
    except ValueError:
        return None
    lo, hi = frame - STRIP_HALF, frame + STRIP_HALF
    tiles = []
    try:
        for i, fr in enumerate(reader.frames()):
            if i > hi:
                break
            if i >= lo:
                h, w = fr.luma.shape
                t = cv2.resize(fr.luma, (THUMB_WIDTH, round(h * THUMB_WIDTH / w)))
                if i == frame:
                    t = cv2.rectangle(t.copy(), (0, 0), (t.shape[1] - 1, t.shape[0] - 1), 255, 2)
                tiles.append(t)
    finally:
        reader.close()
    return cv2.hconcat(tiles) if tiles else None


def plot_measures(eps: pl.DataFrame, path: Path) -> Path:
    """The measures across the dataset: a panel per measure, one bar per episode × camera,
    red where it reaches the panel's flag threshold (a dashed line)."""
    by_col = {f.column: (f.threshold, name) for name, f in FLAGS.items()}
    e = eps.sort("episode_index", "camera")
    x = np.arange(len(e))
    # fixed margins, not a constrained layout: that measures every label's extent in a draw
    # of its own, half the figure's 0.65 s of CPU, paid by every run however small
    fig = Figure(figsize=(12, 8))
    axes = fig.subplots(3, 3)
    fig.subplots_adjust(left=0.05, right=0.99, bottom=0.06, top=0.92, wspace=0.22, hspace=0.45)
    for ax, (col, title) in zip(axes.ravel(), PANELS, strict=True):
        if col not in e.columns:
            ax.set_visible(False)
            continue
        v = e[col].cast(pl.Float64).fill_null(np.nan).to_numpy()
        key = "drift_abs_ms" if col == "drift_end_ms" else "lag_abs_ms" if col == "lag_ms" else col
        thr = by_col[key][0] if key in by_col else np.inf
        over = np.abs(np.nan_to_num(v)) >= thr
        ax.bar(x, np.nan_to_num(v), color=np.where(over, "#c0392b", "#7f8c8d"))
        if col == "lag_ms":
            lo = e["lag_low_ms"].cast(pl.Float64).fill_null(np.nan).to_numpy()
            hi = e["lag_high_ms"].cast(pl.Float64).fill_null(np.nan).to_numpy()
            ax.errorbar(x, np.nan_to_num(v), yerr=[np.nan_to_num(v - lo), np.nan_to_num(hi - v)],
                        fmt="none", ecolor="k", lw=0.8)  # fmt: skip
        if key in by_col:
            thr, name = by_col[key]
            ax.axhline(thr, ls="--", color="k", lw=0.8, label=f"{name} threshold")
            if col in ("drift_end_ms", "lag_ms"):
                ax.axhline(-thr, ls="--", color="k", lw=0.8)
            ax.legend(fontsize=7, loc="upper right")
        ax.set_title(title, fontsize=10)
        ax.set_xticks(x, [str(i) for i in e["episode_index"]], fontsize=7)
        ax.set_xlabel("episode", fontsize=8)
    fig.suptitle("Each episode's measures (red: at or past the flag's threshold, dashed)")
    fig.savefig(path, dpi=90)
    return path


def write_page(
    path: Path, ds: Dataset, eps: pl.DataFrame, frames: pl.DataFrame, problems: list[Problem]
) -> Path:
    """Write ``path`` (see the module); ``eps`` worst first."""
    fig = plot_measures(eps, path.with_suffix(".png"))
    figure = base64.b64encode(fig.read_bytes()).decode()
    fig.unlink()
    cols = [c for c in EPISODE_COLUMNS if c in eps.columns]

    def cell(v: Any) -> str:
        if isinstance(v, float):
            return "-" if v != v else f"{v:.3g}"
        return html.escape("-" if v is None else str(v))

    head = "".join(f"<th>{html.escape(c)}</th>" for c in cols)
    body = "".join(
        f"<tr{' class=flag' if r['flags'] else ''}>"
        + "".join(f"<td>{cell(r[c])}</td>" for c in cols)
        + "</tr>"
        for r in eps.iter_rows(named=True)
    )
    strips = []
    marks = first_flags(eps, frames)
    for r in eps.filter(pl.col("flag_count") > 0).iter_rows(named=True):
        key = (r["episode_index"], r["camera"])
        flag, frame = marks[key]
        strip = thumbnails(ds, *key, frame)
        img = f'<img src="data:image/png;base64,{_png(strip)}">' if strip is not None else ""
        strips.append(
            f"<h3>episode {key[0]}, {html.escape(key[1])}: {html.escape(r['flags'])}</h3>"
            f"<p>frames {max(0, frame - STRIP_HALF)}-{frame + STRIP_HALF}, frame {frame} framed "
            f"({html.escape(flag)}: {html.escape(FLAGS[flag][3])})</p>{img}"
        )
    rules = "".join(
        f"<tr><td>{n}</td><td>{f.evidence} &ge; {f.threshold:g} {f.unit}</td>"
        f"<td>{html.escape(f.meaning)}</td></tr>"
        for n, f in FLAGS.items()
    )
    bad = "".join(f"<li>{html.escape(p.line())}</li>" for p in problems)
    rates = ", ".join(f"{r:.4g}" for r in sorted({ds.rate(c) for c in ds.cameras}))
    n_flag = eps.filter(pl.col("flag_count") > 0).height
    page = f"""<!doctype html><html><head><meta charset="utf-8"><title>vdc dataset</title>
<style>body{{font-family:sans-serif}} table{{border-collapse:collapse;font-size:12px}}
td,th{{border:1px solid #ccc;padding:2px 5px}} tr.flag{{background:#fbe3e0}}</style></head><body>
<h1>{html.escape(str(ds.root))}</h1>
<p>LeRobot {html.escape(ds.version)}, {len(ds.episodes)} episode(s), {len(ds.cameras)} camera(s),
measured at {rates} fps (info.json states {ds.fps:g}): {n_flag} episode × camera flagged,
{len(problems)} problem(s).</p>
{f"<h2>Problems (unreadable or inconsistent)</h2><ul>{bad}</ul>" if bad else ""}
<h2>Episodes, worst first</h2><table><tr>{head}</tr>{body}</table>
<h2>Across the dataset</h2><img src="data:image/png;base64,{figure}" style="max-width:100%">
<h2>Flagged episodes</h2>{"".join(strips) or "<p>none</p>"}
<h2>Flags</h2><table><tr><th>flag</th><th>when</th><th>meaning</th></tr>{rules}</table>
</body></html>"""
    path.write_text(page)
    return path
