"""Lazy public faces: a package whose ``__init__`` names its public API without importing it.

Each command package of ``analysis`` (and ``import vdc``) lists its public names and the module
that defines each; a name is imported on first use. A package's ``__init__`` thus costs nothing,
and the modules inside it may import one another without going through the face (no cycles).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from typing import Any


def lazy_face(
    package: str, names: dict[str, str]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """``__getattr__`` and ``__dir__`` for ``package`` whose public ``names`` map to the modules
    that define them (``{"TablesSettings": "analysis.recordings.recompute"}``)."""
    namespace = importlib.import_module(package).__dict__

    def __getattr__(name: str) -> Any:
        module = names.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(module), name)
        namespace[name] = value  # once loaded, a plain attribute
        return value

    def __dir__() -> list[str]:
        return sorted({*namespace, *names})

    return __getattr__, __dir__
