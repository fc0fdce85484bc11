"""``vdc-analyse looming-footage``: a labelled collection of looming clips over real photographs.

Every clip is rendered by :func:`avdm.looming.render_looming` (the geometry is documented
there) and encoded as H.264 (libx264, yuv420p, CRF 18, through PyAV), so detectors and
complexity measures see a real codec's frames. Each clip draws its own conditions from one
seeded generator, so clip ``k`` is the same clip whatever ``--clips`` is:

* **background**: one of the photographs scikit-image ships (``BACKGROUNDS``), panned by a
  camera yaw drawn uniformly from ``[-rotation_max_dps, rotation_max_dps]`` deg/s;
* **object**: a disc of another photograph (``OBJECTS``), of radius over approach speed
  ``rv_s`` drawn log-uniformly from ``[rv_min_s, rv_max_s]``; a **collision** (on the axis)
  or, with probability ``near_miss_share``, a **near miss** passing ``miss_radii`` (uniform
  3-8) object radii to the side;
* it **enters** the scene ``enter_s`` (uniform 1.5-3 s) before it would reach the camera;
* **contrast** uniform on ``[contrast_min, 1]``, **light level** log-uniform on
  ``[light_min, 1]`` (a dusk or night scene), Gaussian **sensor noise** of ``noise_sd``
  uniform on ``[0, noise_max]`` grey levels.

The object reaches the camera's plane at the clip's last frame. ``labels.csv`` (the labelled-
footage format of ``vdc-analyse boundary --labels``, docs/guides/boundary.md) has per clip:

* ``clip``, ``label`` (``collision`` or ``near-miss``), ``collision_frame`` (the last frame
  for a collision, empty for a near miss);
* ``hazard_onset_frame``: the first frame the object is drawn (its image radius reaches 1 px
  with its centre in view; empty for a near miss that never comes into view); measures of the
  scene are taken before it;
* ``scene``: the background photograph, which the clips over it share (the unit the
  predictors' intervals are over: ``vdc-analyse boundary --labels``);
* every drawn condition, with units: ``background``, ``object``, ``rotation_dps``, ``rv_s``,
  ``miss_radii``, ``contrast``, ``light``, ``noise_sd``, ``enter_s``, ``fps``, ``hfov_deg``.

A re-run reuses the clips already written (each is encoded to a ``.partial.mp4`` and renamed
when complete, so a killed run leaves no half clip under a final name).
"""

from __future__ import annotations

import dataclasses
import math
from fractions import Fraction
from pathlib import Path

import av
import matplotlib
import numpy as np
import polars as pl

from avdm.looming import render_looming
from vdc.cli_support import option
from vdc.errors import UserError
from vdc.executors import QUIET, Feedback
from vdc.settings import AT_LEAST_0, AT_LEAST_1, FRACTION, MAX_SIDE_PX, POSITIVE, Settings, between

# photographs scikit-image ships in its package (no download): busy and plain, indoor and out
BACKGROUNDS = ("astronaut", "camera", "brick", "grass", "gravel", "coffee", "rocket", "page")
OBJECTS = ("chelsea", "coins", "horse", "moon", "immunohistochemistry")
# The amended plan's collection (docs/findings/power_plan_amendment.md): 21 photographs as the
# scenes, each a real photograph a PyPI package ships as a file (scikit-image's data folder,
# matplotlib's sample_data; nothing downloaded). Left out: chessboard, color, logo, phantom
# (drawn, not photographed), horse (a silhouette), motorcycle_right (the left one's stereo
# twin: the same scene), lfw_subset (25 px faces). File per name (photo_file: in which package).
PHOTOS_2026_12 = {
    "astronaut": "astronaut.png",
    "camera": "camera.png",
    "brick": "brick.png",
    "grass": "grass.png",
    "gravel": "gravel.png",
    "coffee": "coffee.png",
    "rocket": "rocket.jpg",
    "page": "page.png",
    "hubble_deep_field": "hubble_deep_field.jpg",
    "retina": "retina.jpg",
    "cell": "cell.png",
    "microaneurysms": "microaneurysms.png",
    "motorcycle_left": "motorcycle_left.png",
    "text": "text.png",
    "clock_motion": "clock_motion.png",
    "chelsea": "chelsea.png",
    "coins": "coins.png",
    "moon": "moon.png",
    "ihc": "ihc.png",
    "grace_hopper": "grace_hopper.jpg",
    "Minduka_Present_Blue_Pack": "Minduka_Present_Blue_Pack.png",
}
MATPLOTLIB_PHOTO_FILES = ("grace_hopper", "Minduka_Present_Blue_Pack")
# the looming objects of the amended collection: never the clip's own background
OBJECTS_2026_12 = ("chelsea", "coins", "horse", "moon", "ihc")
COLLECTIONS = ("2026-11", "2026-12")
# the object enters the scene this long before it would reach the camera (s): the frames
# before are the scene alone, what its complexity is measured on
ENTER_S = (1.5, 3.0)


@dataclasses.dataclass(frozen=True)
class LoomingFootageSettings(Settings):
    """``vdc-analyse looming-footage``: how many clips, their raster and the condition ranges."""

    clips: int = option(
        200, "clips to render (clip k is the same whatever the count)", range=AT_LEAST_1
    )
    seed: int = option(0, "the collection's seed", range=AT_LEAST_0)
    width_px: int = option(160, "frame width, px", range=between(16, MAX_SIDE_PX))
    height_px: int = option(120, "frame height, px", range=between(16, MAX_SIDE_PX))
    fps: float = option(25.0, "frame rate, Hz", range=between(0, 10_000, lo_open=True))
    hfov_deg: float = option(
        60.0, "horizontal field of view, deg", range=between(0, 170, lo_open=True, hi_open=True)
    )
    seconds: float = option(6.0, "clip length, s (the object arrives at the end)", range=POSITIVE)
    near_miss_share: float = option(0.3, "share of clips that are near misses", range=FRACTION)
    rotation_max_dps: float = option(30.0, "camera yaw drawn from +-this, deg/s", range=AT_LEAST_0)
    rv_min_s: float = option(0.08, "object radius over approach speed, lowest, s", range=POSITIVE)
    rv_max_s: float = option(0.3, "object radius over approach speed, highest, s", range=POSITIVE)
    contrast_min: float = option(
        0.2, "lowest contrast (1 = the photographs' own)", range=between(0, 1, lo_open=True)
    )
    light_min: float = option(
        0.1, "lowest light level (1 = daylight)", range=between(0, 1, lo_open=True)
    )
    noise_max: float = option(8.0, "highest sensor noise, grey levels (SD)", range=AT_LEAST_0)
    collection: str = option(
        "2026-11",
        "the photographs: 2026-11 (8 of scikit-image's, each clip's drawn) or 2026-12 (the "
        "amended plan's 21, clip k over photograph k mod 21, the object never its background)",
        choices=COLLECTIONS,
    )

    def __post_init__(self) -> None:
        if self.rv_min_s > self.rv_max_s:
            raise UserError("--rv-min-s must not exceed --rv-max-s.")
        if self.seconds < ENTER_S[1] + 1:
            raise UserError(
                f"--seconds {self.seconds:g} is too short: at least {ENTER_S[1] + 1:g} s (the "
                f"scene alone for 1 s before the object enters up to {ENTER_S[1]:g} s ahead)."
            )

    @property
    def n_frames(self) -> int:
        return round(self.seconds * self.fps)


@dataclasses.dataclass(frozen=True)
class LoomingFootageResult:
    labels: pl.DataFrame  # one row per clip (the columns of labels.csv)
    files: tuple[Path, ...]  # every file written, labels.csv last
    reused: int  # clips found complete from an earlier run

    def report(self) -> list[str]:
        """Lines for the command line: what was written."""
        counts = self.labels["label"].value_counts().sort("label").iter_rows()
        made = ", ".join(f"{n} {label}" for label, n in counts)
        return [
            f"{self.labels.height} clips ({made}; {self.reused} reused from an earlier run)",
            f"wrote {self.files[-1]}",
        ]


def draw_conditions(settings: LoomingFootageSettings, k: int) -> dict[str, float | str]:
    """Clip ``k``'s conditions, from its own generator (seed, k)."""
    s = settings
    rng = np.random.default_rng([s.seed, k])
    miss = rng.random() < s.near_miss_share
    if s.collection == "2026-11":
        background = BACKGROUNDS[int(rng.integers(len(BACKGROUNDS)))]
        obj = OBJECTS[int(rng.integers(len(OBJECTS)))]
    else:  # every photograph the same number of clips; the rest of the draws as before
        names = tuple(PHOTOS_2026_12)
        background = names[k % len(names)]
        others = tuple(o for o in OBJECTS_2026_12 if o != background)
        obj = others[int(rng.integers(len(others)))]
    return {
        "background": background,
        "object": obj,
        "rotation_dps": float(rng.uniform(-s.rotation_max_dps, s.rotation_max_dps)),
        "rv_s": float(math.exp(rng.uniform(math.log(s.rv_min_s), math.log(s.rv_max_s)))),
        "miss_radii": float(rng.uniform(3.0, 8.0)) if miss else 0.0,
        "contrast": float(rng.uniform(s.contrast_min, 1.0)),
        "light": float(math.exp(rng.uniform(math.log(s.light_min), 0.0))),
        "noise_sd": float(rng.uniform(0.0, s.noise_max)),
        "enter_s": float(rng.uniform(ENTER_S[0], ENTER_S[1])),
    }


def _photo(name: str) -> np.ndarray:
    try:
        from skimage import data, io  # lazy: optional extra (test: scikit-image)
    except ImportError:
        raise ValueError(
            "looming-footage renders over scikit-image's photographs: pip install scikit-image"
        ) from None
    if hasattr(data, name):  # scikit-image's own loader (the 2026-11 collection's, as before)
        return getattr(data, name)()
    return io.imread(photo_file(name))


def photo_file(name: str) -> Path:
    """The file of one of the amended collection's photographs (a package's own file)."""
    if name in MATPLOTLIB_PHOTO_FILES:
        folder = Path(matplotlib.get_data_path()) / "sample_data"
    else:
        from skimage import data  # lazy: optional extra (test: scikit-image)

        folder = Path(data.__file__).parent
    path = folder / PHOTOS_2026_12[name]
    if not path.is_file():
        raise UserError(f"photograph {name!r} is not installed at {path}.")
    return path


def encode_h264(path: Path, frames: np.ndarray, fps: float) -> None:
    """Grey frames (T, H, W) uint8 as H.264 (libx264, yuv420p, CRF 18, no B-frames), written
    to ``path`` via ``<stem>.partial.mp4`` and a rename."""
    partial = path.with_name(path.stem + ".partial.mp4")
    with av.open(str(partial), "w") as out:
        stream = out.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001))
        stream.width, stream.height = frames.shape[2], frames.shape[1]
        stream.pix_fmt = "yuv420p"
        stream.options = {"crf": "18", "bf": "0"}
        for f in frames:
            out.mux(stream.encode(av.VideoFrame.from_ndarray(f, format="gray")))
        out.mux(stream.encode())  # flush the encoder
    partial.replace(path)


def looming_footage(
    settings: LoomingFootageSettings, out: str | Path, feedback: Feedback = QUIET
) -> LoomingFootageResult:
    """Render and encode ``settings.clips`` clips into ``out`` with their ``labels.csv``."""
    s = settings
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    n = s.n_frames
    rows, files, reused = [], [], 0
    feedback.log(
        f"looming-footage: {s.clips} clips of {n} frames ({s.width_px}x{s.height_px} px) "
        f"into {out}."
    )
    feedback.expect(s.clips)
    for k in range(s.clips):
        c = draw_conditions(s, k)
        collision = c["miss_radii"] == 0.0
        name = f"clip{k:04d}-{'collision' if collision else 'near-miss'}.mp4"
        clip = render_looming(
            _photo(str(c["background"])),
            _photo(str(c["object"])),
            size=(s.height_px, s.width_px),
            fps=s.fps,
            hfov_deg=s.hfov_deg,
            n_frames=n,
            contact_frame=n - 1,
            rv_s=float(c["rv_s"]),
            miss_radii=float(c["miss_radii"]),
            rotation_dps=float(c["rotation_dps"]),
            contrast=float(c["contrast"]),
            light=float(c["light"]),
            noise_sd=float(c["noise_sd"]),
            seed=s.seed * 100_003 + k,
            enter_frame=n - 1 - round(float(c["enter_s"]) * s.fps),
        )
        path = out / name
        if path.is_file():
            reused += 1
        else:
            encode_h264(path, clip.frames, s.fps)
        files.append(path)
        rows.append(
            {
                "clip": name,
                "label": "collision" if collision else "near-miss",
                "collision_frame": n - 1 if collision else None,
                "hazard_onset_frame": clip.hazard_onset_frame,
                # the photograph is what clips share: the predictors' unit (issue 57)
                "scene": c["background"],
                **c,
                "fps": s.fps,
                "hfov_deg": s.hfov_deg,
            }
        )
        feedback.progress(1)
    labels = pl.DataFrame(
        rows, schema_overrides={"collision_frame": pl.Int64, "hazard_onset_frame": pl.Int64}
    )
    table = out / "labels.csv"
    partial = out / "labels.partial.csv"
    labels.write_csv(partial)
    partial.replace(table)
    return LoomingFootageResult(labels, (*files, table), reused)
