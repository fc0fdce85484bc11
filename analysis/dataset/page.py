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

# the episodes' table: (column, header with its unit, decimals; None: text). The page fits a
# 1,280-px window: the measures a flag reads, rounded to what they can tell
EPISODE_COLUMNS = (
    ("episode_index", "episode", 0),
    ("camera", "camera", None),
    ("flags", "flags", None),
    ("frames_decoded", "frames", 0),
    ("dropped", "dropped, frames", 0),
    ("drift_end_ms", "drift at end, ms", 1),
    ("frozen_longest_s", "frozen run, s", 2),
    ("idle_head_s", "idle head, s", 2),
    ("idle_tail_s", "idle tail, s", 2),
    ("lag_ms", "lag, ms [95 % interval]", 0),
    ("shift_px", "shift, px", 1),
    ("shift_within_px", "shift within, px", 1),
    ("shift_frame", "at frame", 0),
    ("blurred_share", "blurred, share", 2),
    ("underexposed_share", "dark, share", 2),
    ("overexposed_share", "bright, share", 2),
    ("ti_p910_mean", "TI (P.910), mean", 1),
    ("omega_dps_mean", "ω, deg/s", 1),
)


def number(v: Any, decimals: int) -> str:
    """``v`` rounded to ``decimals`` (no ``-0``; "-" for none or NaN)."""
    if v is None or (isinstance(v, float) and v != v):
        return "-"
    r = round(float(v), decimals)
    return f"{0.0 if r == 0 else r:.{decimals}f}"


def _cell(r: dict[str, Any], col: str, decimals: int | None) -> str:
    v = r.get(col)
    if col == "camera":  # LeRobot's keys share a long prefix: the page shows the rest
        return html.escape(str(v).removeprefix("observation.images."))
    if col == "lag_ms":
        if v is None:  # why there is none: the note's first words
            note = str(r.get("lag_note") or "-").split(":")[0]
            return html.escape(note)
        return (
            f"{number(v, 0)} [{number(r.get('lag_low_ms'), 0)}, {number(r.get('lag_high_ms'), 0)}]"
        )
    if decimals is None:
        return html.escape("-" if v is None else str(v))
    return number(v, decimals)


# the figure: one panel per measure, episodes along x, flagged episodes in red
PANELS = (
    ("drift_end_ms", "drift at the end, ms"),
    ("dropped", "dropped frames"),
    ("frozen_longest_s", "longest frozen run, s"),
    ("idle_head_s", "idle head, s"),
    ("lag_ms", "lag behind the state, ms"),
    ("shift_px", "camera shift, px"),
    ("blurred_share", "share of frames blurred"),
    ("overexposed_share", "share over-exposed"),
    ("ti_p910_mean", "TI (P.910), mean"),
)


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
    red where the episode carries the panel's flag (its evidence past the threshold, dashed:
    an estimate whose interval does not clear it stays grey)."""
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
        flag = by_col[key][1] if key in by_col else None
        over = np.array([flag in f.split(",") for f in e["flags"]], bool)
        ax.bar(x, np.nan_to_num(v), color=np.where(over, "#c0392b", "#7f8c8d"))
        if col == "lag_ms" and "lag_low_ms" in e.columns:
            lo = e["lag_low_ms"].cast(pl.Float64).fill_null(np.nan).to_numpy()
            hi = e["lag_high_ms"].cast(pl.Float64).fill_null(np.nan).to_numpy()
            ax.errorbar(
                x,
                np.nan_to_num(v),
                yerr=[np.nan_to_num(v - lo), np.nan_to_num(hi - v)],
                fmt="none",
                ecolor="k",
                lw=0.8,
            )
        if key in by_col:
            thr, name = by_col[key]
            ax.axhline(thr, ls="--", color="k", lw=0.8, label=f"{name} threshold")
            if col in ("drift_end_ms", "lag_ms"):
                ax.axhline(-thr, ls="--", color="k", lw=0.8)
            ax.legend(fontsize=7, loc="upper right")
        ax.set_title(title, fontsize=10)
        ax.set_xticks(x, [str(i) for i in e["episode_index"]], fontsize=7)
        ax.set_xlabel("episode", fontsize=8)
    fig.suptitle("Each episode's measures (red: flagged, its evidence past the threshold, dashed)")
    fig.savefig(path, dpi=90)
    return path


def write_page(
    path: Path,
    ds: Dataset,
    eps: pl.DataFrame,
    frames: pl.DataFrame,
    problems: list[Problem],
    cameras: tuple[str, ...] = (),
) -> Path:
    """Write ``path`` (see the module); ``eps`` worst first; ``cameras``: a line per camera,
    the kind it was taken for (fixed, or moving with the robot) and why."""
    fig = plot_measures(eps, path.with_suffix(".png"))
    figure = base64.b64encode(fig.read_bytes()).decode()
    fig.unlink()
    cols = [c for c in EPISODE_COLUMNS if c[0] in eps.columns]
    head = "".join(f"<th>{html.escape(h)}</th>" for _, h, _ in cols)
    body = "".join(
        f"<tr{' class=flag' if r['flags'] else ''}>"
        + "".join(f"<td>{_cell(r, c, d)}</td>" for c, _, d in cols)
        + "</tr>"
        for r in eps.iter_rows(named=True)
    )
    kinds = "".join(f"<li>{html.escape(c)}</li>" for c in cameras)
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
<style>body{{font-family:sans-serif;max-width:1260px}}
table{{border-collapse:collapse;font-size:11px}} td{{text-align:right}}
td,th{{border:1px solid #ccc;padding:2px 4px}} th{{font-weight:normal;background:#eee}}
tr.flag{{background:#fbe3e0}} img{{max-width:100%}}</style></head><body>
<h1>{html.escape(str(ds.root))}</h1>
<p>LeRobot {html.escape(ds.version)}, {len(ds.episodes)} episode(s), {len(ds.cameras)} camera(s),
measured at {rates} fps (info.json states {ds.fps:g}): {n_flag} episode × camera flagged,
{len(problems)} problem(s).</p>
{f"<h2>Problems (unreadable or inconsistent)</h2><ul>{bad}</ul>" if bad else ""}
{f"<h2>Cameras</h2><ul>{kinds}</ul>" if kinds else ""}
<h2>Episodes, worst first</h2><table><tr>{head}</tr>{body}</table>
<h2>Across the dataset</h2><img src="data:image/png;base64,{figure}">
<h2>Flagged episodes</h2>{"".join(strips) or "<p>none</p>"}
<h2>Flags</h2><table><tr><th>flag</th><th>when</th><th>meaning</th></tr>{rules}</table>
</body></html>"""
    path.write_text(page)
    return path
