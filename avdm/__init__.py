"""vdc's vision models and stimuli: pure NumPy/Numba, no file, serial or Rerun I/O.

* ``avdm.Avdm`` / ``avdm.AvdmParams``: the angular velocity decoding model (fast path);
* ``avdm.reference.AvdmReference``: the same model written plainly (test oracle);
* ``avdm.avdm_multiscale.AvdmMultiScale`` (variant ``avdm-natural``): the AVDM for real
  footage, valid 1–300 deg/s at 25–30 fps; ``avdm.reference_multiscale`` is its oracle;
* ``avdm.registry``: named variants and ``name:key=value`` overrides (``make_model``);
* ``avdm.stimuli``: drifting gratings, natural scenes and a camera panning across a photograph;
* ``avdm.calibration``: least-squares fit of the decoding constants (a, b).

The names below load on first use (PEP 562): importing one module of the package, such as
``avdm.jit`` (which every Numba kernel in vdc needs), no longer loads the registry and with it
polars. A pool's fork server imports the kernels, and a library that starts threads at import,
as polars does, must not be loaded there (``vdc/warm.py``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from avdm.lazy import lazy_face

if TYPE_CHECKING:  # what the names are, for type checkers and IDEs
    from avdm.avdm_model import AVDM_OUTPUTS, Avdm, AvdmParams
    from avdm.base import Model, Output, Params
    from avdm.registry import canonical_name, make_model, make_params, parse_model_spec
    from avdm.version import __version__

_API = {
    "AVDM_OUTPUTS": "avdm.avdm_model",
    "Avdm": "avdm.avdm_model",
    "AvdmParams": "avdm.avdm_model",
    "Model": "avdm.base",
    "Output": "avdm.base",
    "Params": "avdm.base",
    "__version__": "avdm.version",
    "canonical_name": "avdm.registry",
    "make_model": "avdm.registry",
    "make_params": "avdm.registry",
    "parse_model_spec": "avdm.registry",
}

__all__ = [
    "AVDM_OUTPUTS",
    "Avdm",
    "AvdmParams",
    "Model",
    "Output",
    "Params",
    "__version__",
    "canonical_name",
    "make_model",
    "make_params",
    "parse_model_spec",
]


__getattr__, __dir__ = lazy_face(__name__, _API)
