"""vdc's vision models and stimuli: pure NumPy/Numba, no file, serial or Rerun I/O.

* ``avdm.Avdm`` / ``avdm.AvdmParams``: the angular velocity decoding model (fast path);
* ``avdm.reference.AvdmReference``: the same model written plainly (test oracle);
* ``avdm.avdm_multiscale.AvdmMultiScale`` (variant ``avdm-natural``): the AVDM for real
  footage, valid 1–300 deg/s at 25–30 fps; ``avdm.reference_multiscale`` is its oracle;
* ``avdm.registry``: named variants and ``name:key=value`` overrides (``make_model``);
* ``avdm.stimuli``: drifting gratings, natural scenes and a camera panning across a photograph;
* ``avdm.calibration``: least-squares fit of the decoding constants (a, b).
"""

from avdm.avdm_model import AVDM_OUTPUTS, Avdm, AvdmParams
from avdm.base import Model, Output, Params
from avdm.registry import canonical_name, make_model, make_params, parse_model_spec
from avdm.version import __version__

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
