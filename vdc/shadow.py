"""A folder or file named like one of vdc's packages, ahead of it on Python's path, hides it.

``python script.py`` puts the script's folder first on ``sys.path``, so a ``vdc/`` folder (or
``vdc.py``) beside the script is what ``import vdc`` finds; the real package then never runs, and
the user sees ``AttributeError: module 'vdc' has no attribute 'record_sim'``. A folder without
``__init__.py`` is a namespace package: ``__file__`` is None and ``__path__`` points at the
folder. The other packages (``capture``, ``analysis``) and the console scripts can look at what
``import vdc`` finds and say where it came from.

Plain standard library, no ``vdc`` import: ``capture`` and ``analysis`` run this file by its path
beside them (``runpy.run_path``) and call ``refuse_if_shadowed``, which works even when
``import vdc`` finds the wrong thing.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

OWN_PACKAGES = ("vdc", "avdm", "capture", "analysis")
# vdc, avdm, capture and analysis are installed side by side (pyproject's packages.find)
ROOT = Path(__file__).resolve().parent.parent


def where(module: ModuleType) -> str:
    """Where ``module`` was loaded from: its file, or a namespace package's folder(s)."""
    file = getattr(module, "__file__", None)
    if file:
        return str(Path(file).parent if Path(file).name == "__init__.py" else file)
    folders = [str(p) for p in getattr(module, "__path__", [])]
    return ", ".join(folders) or "(nowhere on disk)"


def is_ours(name: str, module: ModuleType) -> bool:
    """Whether ``module`` (imported as ``name``) is vdc's own package, beside this one."""
    file = getattr(module, "__file__", None)
    return file is not None and Path(file).resolve() == ROOT / name / "__init__.py"


def message(name: str, found: str) -> str:
    """The one line that names the impostor and says what to do."""
    return (
        f"'import {name}' found {found}, not vdc's package {ROOT / name}: a folder or file named "
        f"{name!r} earlier on Python's path (beside your script, or in the current folder) hides "
        "it; rename it, or run from another folder"
    )


def shadowed(names: tuple[str, ...] = OWN_PACKAGES) -> str | None:
    """The message for the first of ``names`` that an import would take from elsewhere (whether
    imported already or only found), else None. Imports nothing."""
    for name in names:
        module = sys.modules.get(name)
        if module is not None:
            if not is_ours(name, module):
                return message(name, where(module))
            continue
        spec = importlib.util.find_spec(name)
        if spec is None:
            continue
        origin = spec.origin if spec.has_location else None
        if origin is None or Path(origin).resolve() != ROOT / name / "__init__.py":
            found = origin or ", ".join(spec.submodule_search_locations or []) or "(nowhere)"
            if origin and Path(origin).name == "__init__.py":
                found = str(Path(origin).parent)
            return message(name, found)
    return None


def refuse_if_shadowed(names: tuple[str, ...] = ("vdc",)) -> None:
    """Stop at once, naming it, if ``import`` of one of ``names`` would find another folder or
    file (beside the user's script, say): otherwise the first ``vdc.`` name fails with
    ``module 'vdc' has no attribute ...``. Raises ImportError with the one-line message."""
    for name in names:
        problem = shadowed((name,))
        if problem is not None:
            raise ImportError(problem, name=name)
