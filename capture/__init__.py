"""vdc's capture side: everything that produces a recording (simulated arena and robot, the
Colias serial link, the overhead tracker, and the Rerun recorder that alone knows the entity
paths and the blueprint)."""

# what ``import vdc`` would find, checked without importing it (the layers below the facade do
# not import it); the check is loaded by its path beside this package, since a folder named
# vdc ahead of it on the path hides vdc.shadow too
import importlib.util as _importlib_util
from pathlib import Path as _Path


def _check_vdc() -> None:
    """Stop at once, naming it, if ``import vdc`` would find another folder or file named
    ``vdc`` (beside the user's script, say): otherwise the first ``vdc.`` name fails with
    ``module 'vdc' has no attribute ...``."""
    spec = _importlib_util.spec_from_file_location(
        "_vdc_shadow_check", _Path(__file__).resolve().parent.parent / "vdc" / "shadow.py"
    )
    shadow = _importlib_util.module_from_spec(spec)
    spec.loader.exec_module(shadow)
    problem = shadow.shadowed(("vdc",))
    if problem is not None:
        raise ImportError(problem, name="vdc")


_check_vdc()
