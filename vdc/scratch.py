"""``out=None`` writes nothing: a command whose work needs a folder (resumable parts, a pool's
outputs) does it in a temporary one, removed before the function returns (the README's
promise for every command function). The result keeps its tables (polars DataFrames, in
memory) and lists no files."""

from __future__ import annotations

import dataclasses
import functools
import inspect
import tempfile
from collections.abc import Callable
from typing import Any, TypeVar

F = TypeVar("F", bound=Callable[..., Any])


def no_files_without_out(function: F) -> F:
    """Wrap a command function with an ``out`` argument: ``out=None`` runs it in a temporary
    folder (``vdc-<name>-*`` in the system's temporary folder) that is removed when it returns,
    and the result's ``paths`` is emptied (nothing written remains)."""
    signature = inspect.signature(function)
    prefix = f"vdc-{function.__name__.replace('_', '-')}-"

    @functools.wraps(function)
    def run(*args: Any, **kwargs: Any) -> Any:
        bound = signature.bind(*args, **kwargs)
        if "out" not in bound.arguments or bound.arguments["out"] is not None:
            return function(*args, **kwargs)
        with tempfile.TemporaryDirectory(prefix=prefix) as tmp:
            bound.arguments["out"] = tmp
            result = function(*bound.args, **bound.kwargs)
        if dataclasses.is_dataclass(result) and hasattr(result, "paths"):
            return dataclasses.replace(result, paths=[])
        return result

    return run  # type: ignore[return-value]
