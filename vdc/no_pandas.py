"""pyarrow without pandas in vdc's own processes (its commands and pool workers).

pyarrow asks whether pandas is installed the first time it converts a Python list (Rerun
does so when it logs, vdc when it reads a recording's scalars), and answers by importing it:
0.25-0.3 s of CPU in every process, where the catalog and notebook extras install pandas.
Nothing vdc runs needs it. Measured over the whole test suite: 5 % of its CPU.

:func:`arrow_without_pandas` lets pyarrow ask while pandas cannot be imported, once, right
after pyarrow itself loads: it then converts lists without looking for pandas. An explicit
use still works (``Table.to_pandas()`` imports pandas then, and pyarrow knows it from then
on). Called only where vdc owns the process (:mod:`vdc.launch`, the pool workers' start),
never by ``import vdc`` in a user's notebook, where a pandas Series given to ``pa.array``
before any such use would lose pandas' missing-value conventions.

Plain standard library until pyarrow loads: the console scripts call it before anything
heavy.

It rests on one detail pyarrow does not promise: its pandas shim tries the import once and
remembers a failure (``_PandasAPIShim._tried_importing_pandas``, ``pandas-shim.pxi``, pyarrow
26), while an explicit use tries again. vdc reads and sets none of its private attributes;
only :func:`_ask_now` relies on that behaviour, and if a new pyarrow drops it, the plain path
follows (pyarrow imports pandas on its first conversion, as without this module).
``tests/vdc/test_no_pandas.py`` fails naming the pyarrow version if it changes. Measured (pyarrow
26, Python 3.11): pyarrow's first list conversion costs 0.21-0.23 s of CPU without this
module, 0.00 s with it.
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import sys
from types import ModuleType
from typing import Any


class _NoPandas(importlib.abc.MetaPathFinder):
    """Makes ``import pandas`` fail while it is on ``sys.meta_path``."""

    def find_spec(self, name: str, path: Any = None, target: Any = None) -> None:
        if name == "pandas" or name.startswith("pandas."):
            raise ImportError("pandas is not imported here (vdc.no_pandas)")


def _ask_now(pa: ModuleType) -> None:
    """pyarrow's first look for pandas, while pandas cannot load: it remembers the answer
    (the one place that relies on pyarrow's undocumented behaviour; see the module)."""
    if "pandas" in sys.modules:  # already imported by someone: nothing to save
        return
    blocker = _NoPandas()
    sys.meta_path.insert(0, blocker)
    try:
        pa.array([0])
    except Exception:  # another pyarrow: it may look later, which only costs time
        pass
    finally:
        sys.meta_path.remove(blocker)


class _AfterPyarrow(importlib.abc.MetaPathFinder):
    """Finds ``pyarrow`` as usual, and asks for pandas once it has loaded."""

    def find_spec(self, name: str, path: Any = None, target: Any = None) -> Any:
        if name != "pyarrow":
            return None
        # a query (importlib.util.find_spec, as polars asks whether pyarrow is installed)
        # loads nothing: this finder stays until pyarrow has really loaded
        spec = importlib.machinery.PathFinder.find_spec(name, path)
        if spec is None or spec.loader is None or not hasattr(spec.loader, "exec_module"):
            return spec
        loader = spec.loader
        exec_module = loader.exec_module

        def exec_then_ask(module: ModuleType) -> None:
            exec_module(module)
            if self in sys.meta_path:
                sys.meta_path.remove(self)
            _ask_now(module)

        loader.exec_module = exec_then_ask  # type: ignore[method-assign]  # this module's own
        return spec


def arrow_without_pandas() -> None:
    """Have pyarrow decide, now or as soon as it loads, that there is no pandas to look for
    (see the module). Idempotent."""
    pa = sys.modules.get("pyarrow")
    if pa is not None:
        _ask_now(pa)
        return
    if not any(isinstance(f, _AfterPyarrow) for f in sys.meta_path):
        sys.meta_path.insert(0, _AfterPyarrow())
