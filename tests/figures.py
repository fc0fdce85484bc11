"""What a figure the library saved shows, for tests: its titles and axis labels (recorded from
the matplotlib Figure as it is saved) and its pixels (read back from the PNG).

In the test's own process, :func:`recording_figures` records every ``Figure.savefig``; in a
command the test runs, :func:`figure_env` does the same through ``tests/figure_probe``'s
``sitecustomize`` (processes the command starts inherit it), and :func:`saved_figures` reads
what it recorded. :func:`assert_figure` then checks one PNG against its record."""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

PROBE = Path(__file__).resolve().parent / "figure_probe"
ENV = "VDC_TEST_FIGURES"


def describe(fig, path: object) -> dict:
    """The texts of a matplotlib Figure saved to ``path``: its suptitle and, per axes, the title
    (centre, left and right joined), the x/y (and z) labels, how many data artists (lines,
    collections, patches, images) it draws and whether it is a colour bar."""
    sup = getattr(fig, "_suptitle", None)
    axes = []
    for ax in fig.get_axes():
        titles = [ax.get_title(loc) for loc in ("center", "left", "right")]
        axes.append(
            {
                "title": " ".join(t for t in titles if t),
                "xlabel": ax.get_xlabel(),
                "ylabel": ax.get_ylabel(),
                "zlabel": ax.get_zlabel() if hasattr(ax, "get_zlabel") else "",
                "artists": len(ax.lines) + len(ax.collections) + len(ax.patches) + len(ax.images),
                "colorbar": hasattr(ax, "_colorbar"),  # a colour bar's axes (matplotlib sets it)
                "xlim": [float(x) for x in ax.get_xlim()],
                "ylim": [float(y) for y in ax.get_ylim()],
            }
        )
    return {
        "name": Path(os.fsdecode(path)).name if isinstance(path, str | os.PathLike) else "",
        "suptitle": sup.get_text() if sup is not None else "",
        "axes": axes,
        "clipped": clipped_texts(fig),
    }


def clipped_texts(fig) -> list[str]:
    """The suptitle, titles and axis labels that reach beyond the figure's edges (as drawn: a
    saved figure has a renderer). 1 px of slack: antialiasing, not clipping."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    # a Figure() made without pyplot has a bare canvas: measure on Agg, as it was saved
    canvas = fig.canvas if hasattr(fig.canvas, "get_renderer") else FigureCanvasAgg(fig)
    renderer = canvas.get_renderer()
    box = fig.bbox
    texts = [getattr(fig, "_suptitle", None)]
    for ax in fig.get_axes():
        texts += [ax.title, ax._left_title, ax._right_title, ax.xaxis.label, ax.yaxis.label]
    out = []
    for t in texts:
        if t is None or not t.get_text() or not t.get_visible():
            continue
        e = t.get_window_extent(renderer)
        if e.x0 < box.x0 - 1 or e.x1 > box.x1 + 1 or e.y0 < box.y0 - 1 or e.y1 > box.y1 + 1:
            out.append(t.get_text())
    return out


def _install(record) -> object:
    """Wrap ``Figure.savefig`` so that every save is described to ``record``; returns the
    original method."""
    from matplotlib.figure import Figure

    original = Figure.savefig

    def savefig(self, fname, *args, **kwargs):
        out = original(self, fname, *args, **kwargs)
        record(describe(self, fname))
        return out

    Figure.savefig = savefig
    return original


@contextmanager
def recording_figures() -> Iterator[list[dict]]:
    """Within the block, every Figure this process saves is described (:func:`describe`) in
    the list yielded, in the order saved."""
    from matplotlib.figure import Figure

    saved: list[dict] = []
    original = _install(saved.append)
    try:
        yield saved
    finally:
        Figure.savefig = original


def figure_env(record: Path, env: dict[str, str] | None = None) -> dict[str, str]:
    """An environment under which a Python command (and the processes it starts) appends a
    description of every Figure it saves to ``record`` (JSON lines)."""
    env = dict(os.environ if env is None else env)
    env[ENV] = str(record)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(PROBE), env.get("PYTHONPATH")) if p)
    return env


def saved_figures(record: Path) -> list[dict]:
    """The descriptions a command run under :func:`figure_env` wrote, in the order saved."""
    if not record.exists():
        return []
    return [json.loads(line) for line in record.read_text().splitlines() if line.strip()]


def install_from_env() -> None:
    """Record to the file ``$VDC_TEST_FIGURES`` names (called by the probe's sitecustomize)."""
    record = os.environ.get(ENV)
    if not record:
        return

    def append(info: dict) -> None:
        with open(record, "a", encoding="utf-8") as f:  # one short line: appends do not mix
            f.write(json.dumps(info) + "\n")

    _install(append)


def assert_figure(
    png: Path,
    saved: list[dict],
    *,
    title: str = "",
    labels: tuple[str, ...] = (),
    min_axes: int = 1,
    min_coloured: float = 0.0005,
) -> dict:
    """``png`` is a real, drawn figure, and says what it shows:

    * its pixels are not blank: grey levels vary (std > 0.05 on 0-1; a blank figure has 0),
      and more than ``min_coloured`` of them are coloured (max - min of RGB > 0.2). Axes,
      ticks and texts are black and grey: an empty frame with its labels and title has no
      coloured pixel (grey std 0.085), the figures of a quick reproduction have 0.9-23 %, a
      5-s clip's time series and histogram 0.16 %;
    * it was saved from a Figure (found by file name in ``saved``) with at least ``min_axes``
      axes that draw data (colour bars aside), each with a y label or a title (its x axis
      may be categories, named by their tick labels);
    * it has a title; ``title`` is in its suptitle or an axes' title, and each of ``labels``
      in some axes' x, y or z label.

    Returns the figure's description (:func:`describe`)."""
    from matplotlib.image import imread

    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", png
    rgb = imread(png)[..., :3]
    grey = rgb.mean(axis=-1)
    assert grey.std() > 0.05, f"{png.name} is blank (grey std {grey.std():.4f})"
    coloured = float((rgb.max(axis=-1) - rgb.min(axis=-1) > 0.2).mean())
    assert coloured > min_coloured, f"{png.name} draws no data: {coloured:.2%} coloured pixels"
    found = [f for f in saved if f["name"] == png.name]
    assert found, f"no Figure was saved as {png.name}: saved {[f['name'] for f in saved]}"
    fig = found[-1]
    drawn = [ax for ax in fig["axes"] if ax["artists"] > 0 and not ax["colorbar"]]
    assert len(drawn) >= min_axes, f"{png.name}: {len(drawn)} axes draw data, {fig['axes']}"
    for ax in drawn:
        named = ax["ylabel"] or ax["title"]  # x may be categories, named by their ticks
        assert named, f"{png.name}: an axes with data says not what it shows: {ax}"
    titles = [fig["suptitle"], *(ax["title"] for ax in fig["axes"])]
    assert any(t.strip() for t in titles), f"{png.name} has no title"
    assert title in " | ".join(titles), f"{png.name}: {title!r} not in the titles {titles}"
    texts = " | ".join(ax[k] for ax in fig["axes"] for k in ("xlabel", "ylabel", "zlabel"))
    for label in labels:
        assert label in texts, f"{png.name}: {label!r} not in the axis labels {texts!r}"
    return fig
