"""vdc's offline analysis: everything that consumes recordings and stimuli.

Tables, profiles, comparisons, batch analysis and the paper's experiments
(``analysis.experiments``), written as Parquet through ``vdc.parquet_io``; the command line is
``vdc-analyse`` (``analysis.cli``).
"""

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
