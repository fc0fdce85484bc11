"""vdc's capture side: everything that produces a recording (simulated arena and robot, the
Colias serial link, the overhead tracker, and the Rerun recorder that alone knows the entity
paths and the blueprint)."""

# stop, naming it, if ``import vdc`` would find another folder named vdc (beside the user's
# script, say). vdc/shadow.py is run by its path beside this package, not imported: the layers
# below the facade do not import it, and a folder named vdc ahead on the path hides vdc.shadow too
import runpy as _runpy
from pathlib import Path as _Path

_runpy.run_path(str(_Path(__file__).resolve().parent.parent / "vdc" / "shadow.py"))[
    "refuse_if_shadowed"
]()
