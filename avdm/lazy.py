"""The one lazy loader of vdc's package faces (PEP 562): a package's ``__init__`` names its
public API and the module that defines each name, and a name is imported on first use.

``avdm``, ``import vdc`` (the facade) and each command package of ``analysis`` (through
``vdc.lazy``) use it: an ``__init__`` then costs nothing, and the modules inside a package may
import one another without going through its face (no cycles). It lives in ``avdm`` because
``avdm`` imports nothing of the project; standard library only.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from typing import Any


def lazy_face(
    package: str,
    names: Mapping[str, str],
    renamed: Mapping[str, str] | None = None,
    modules: Mapping[str, str] | None = None,
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """``__getattr__`` and ``__dir__`` for ``package``, whose public ``names`` map to the
    modules that define them (``{"TablesSettings": "analysis.recordings.recompute"}``).
    ``renamed``: public name -> its name in that module, where they differ; ``modules``: public
    names that are modules themselves (``{"catalog": "vdc.catalog"}``). A name, once loaded,
    is a plain attribute of the package; any other name is an AttributeError."""
    namespace = importlib.import_module(package).__dict__
    renamed = dict(renamed or {})
    modules = dict(modules or {})

    def __getattr__(name: str) -> Any:
        if name in modules:
            value = importlib.import_module(modules[name])
        elif name in names:
            value = getattr(importlib.import_module(names[name]), renamed.get(name, name))
        else:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        namespace[name] = value  # once loaded, a plain attribute
        return value

    def __dir__() -> list[str]:
        return sorted({*namespace, *names, *modules})

    return __getattr__, __dir__
