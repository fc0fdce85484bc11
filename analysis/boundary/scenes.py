"""The arena's wall scenes by name, for a boundary campaign over many scenes.

* ``grating``: the default grating (0.1 m period, contrast 1); ``grating-p<period_m>`` and/or
  ``-c<contrast>`` set its period (its spatial frequency: 1 / period cycles per metre of wall)
  and its Michelson contrast, e.g. ``grating-p0.05-c0.3``;
* ``natural``: seeded 1/f clutter (``-c<contrast>`` too);
* ``photo-<name>``: one of the photographs scikit-image (or matplotlib) ships in its package
  (``PHOTOS``), shown on the walls as a natural scene, e.g. ``photo-astronaut``; ``-c`` too.

A scene's name is its folder and condition name (``<scene>-tf<TF>``), so it is kept short and
path-safe. :func:`scene_fields` gives the ``vdc-capture sim`` settings it stands for.
"""

from __future__ import annotations

import re
import zlib
from pathlib import Path

import matplotlib
import numpy as np

from vdc.errors import UserError

# scikit-image's photographs shipped as files (nothing downloaded): file name per scene name
PHOTOS = {
    "astronaut": "astronaut.png",
    "brick": "brick.png",
    "camera": "camera.png",
    "coffee": "coffee.png",
    "grass": "grass.png",
    "gravel": "gravel.png",
    "rocket": "rocket.jpg",
    "page": "page.png",
    # the amended plan's (docs/findings/power_plan_amendment.md): every real photograph the
    # installed packages ship, short names (a scene name is a folder name)
    "hubble": "hubble_deep_field.jpg",
    "retina": "retina.jpg",
    "cell": "cell.png",
    "microaneurysms": "microaneurysms.png",
    "motorcycle": "motorcycle_left.png",
    "text": "text.png",
    "clock": "clock_motion.png",
    "chelsea": "chelsea.png",
    "coins": "coins.png",
    "moon": "moon.png",
    "ihc": "ihc.png",
    "hopper": "grace_hopper.jpg",  # matplotlib's sample_data
    "minduka": "Minduka_Present_Blue_Pack.png",  # matplotlib's sample_data
}
MATPLOTLIB_PHOTOS = ("hopper", "minduka")
_NAME = re.compile(
    r"^(?P<kind>grating|natural|photo-(?P<photo>[a-z]+))"
    r"(?:-p(?P<period>\d+(?:\.\d+)?))?(?:-c(?P<contrast>\d+(?:\.\d+)?))?$"
)
HELP = "grating[-p<period_m>][-c<contrast>], natural[-c<contrast>], photo-<name>[-c<contrast>]"


def scene_fields(name: str) -> dict[str, object]:
    """``{scene, period_m, contrast, image}`` of ``vdc-capture sim`` for the scene ``name``.

    ValueError in one line for a name that is not a scene, a period or contrast out of range,
    or a photograph vdc does not know."""
    m = _NAME.match(name)
    if m is None:
        raise UserError(f"unknown arena scene {name!r}: expected {HELP}.")
    kind = "grating" if m["kind"] == "grating" else "natural"
    if m["period"] is not None and kind != "grating":
        raise UserError(f"arena scene {name!r}: only a grating has a period (-p).")
    period = float(m["period"]) if m["period"] is not None else 0.1
    contrast = float(m["contrast"]) if m["contrast"] is not None else 1.0
    if not 0.002 <= period <= 10:
        raise UserError(f"arena scene {name!r}: period {period:g} m is not in 0.002-10 m.")
    if not 0 < contrast <= 1:
        raise UserError(f"arena scene {name!r}: contrast {contrast:g} is not in (0, 1].")
    image = None
    if m["photo"] is not None:
        image = str(photo_path(m["photo"]))
    return {"scene": kind, "period_m": period, "contrast": contrast, "image": image}


def photo_path(photo: str) -> Path:
    """The file of scikit-image's photograph ``photo`` (ValueError when unknown or absent)."""
    if photo not in PHOTOS:
        raise UserError(
            f"unknown photograph {photo!r} for an arena scene: known are {', '.join(PHOTOS)}."
        )
    try:
        import skimage.data  # lazy: optional extra (test: scikit-image)
    except ImportError:
        raise UserError(
            "photo-* arena scenes show scikit-image's photographs: pip install scikit-image"
        ) from None
    folder = Path(skimage.data.__file__).parent
    if photo in MATPLOTLIB_PHOTOS:
        folder = Path(matplotlib.get_data_path()) / "sample_data"
    path = folder / PHOTOS[photo]
    if not path.is_file():
        raise UserError(f"scikit-image's photograph {PHOTOS[photo]} is not installed at {path}.")
    return path


def check_scenes(names: list[str]) -> list[str]:
    """``names`` when every one is a scene (see :func:`scene_fields`); ValueError otherwise."""
    if not names:
        raise UserError(f"--scenes is empty: expected some of {HELP}.")
    if len(set(names)) != len(names):
        raise UserError(f"--scenes repeats a scene: {', '.join(names)}")
    for n in names:
        scene_fields(n)
    return names


def draw_tfs(seed: int, scene: str, n: int, bounds: tuple[float, float]) -> list[float]:
    """``n`` wall TFs (Hz) for ``scene``: one uniform draw in each of ``n`` equal strata of
    ``bounds`` (LO, HI), rounded to 0.01 Hz (a folder name), from the scene's own generator
    (seed, CRC-32 of its name): adding or reordering scenes moves no scene's TFs."""
    lo, hi = bounds
    rng = np.random.default_rng([seed, zlib.crc32(scene.encode())])
    draws = lo + (np.arange(n) + rng.random(n)) * (hi - lo) / n
    return sorted({round(float(v), 2) for v in draws})
