"""Models from outside vdc: ``package.module:factory`` specs and the ``vdc.models`` entry points.

A plug-in is a **factory**: any callable that takes keyword arguments (its parameters) and
returns an object with

* ``outputs``: the output names and units, as :class:`avdm.base.Output` items, ``(name, unit)``
  pairs or a ``{name: unit}`` mapping;
* ``step(frame)``: one ``(H, W)`` frame (uint8 0–255, or float 0–1) → ``{output: float}``;
* optionally ``run(frames)`` (``(T, H, W)`` → ``{output: (T,) array}``; else ``step`` per frame),
  ``reset()`` and ``set_param(name, value)`` (a parameter changed while it runs, used by a
  policy; else the attribute of that name is set).

A detector that drives the robot's avoidance in the closed loop has an output named ``alert``
(1 = collision ahead, 0 = not).

Two ways to name one on the command line:

* ``--model mypackage.detectors:make_detector`` or ``...:make_detector:threshold=0.2`` (the
  module is imported from ``sys.path``, then from the current folder, which is not added to
  ``sys.path``: the process's imports stay as they were);
* an installed package's entry point in the ``vdc.models`` group
  (``[project.entry-points."vdc.models"] looming = "mypackage.detectors:make_detector"``), then
  ``--model looming:threshold=0.2``.

Parameters are the factory's keyword arguments: ``key=value`` overrides are parsed into the type
of the argument's annotation or default (int, float, bool, str), an unknown key is an error, and
the camera facts the caller knows (``fps``, ``deg_per_px``, ...) are passed to the arguments
of those names.
"""

from __future__ import annotations

import functools
import importlib
import importlib.machinery
import importlib.util
import inspect
import os
import re
import sys
from collections.abc import Callable, Mapping
from importlib.metadata import entry_points
from typing import Any

import numpy as np

from avdm.base import FRAME_TABLE_COLUMNS, Output, check_frames
from avdm.errors import ParameterError, PluginError

ENTRY_POINT_GROUP = "vdc.models"
_REF_RE = re.compile(r"^(?P<module>[A-Za-z_][\w.]*):(?P<factory>[A-Za-z_][\w.]*)$")


def is_reference(text: str) -> bool:
    """``text`` names a factory as ``module:attribute`` (not a variant's ``name:k=v``)."""
    return _REF_RE.match(text) is not None


@functools.lru_cache(maxsize=1)
def entry_point_models() -> dict[str, str]:
    """Installed plug-ins: entry-point name → ``module:factory`` (group ``vdc.models``)."""
    return {ep.name: ep.value.replace(" ", "") for ep in entry_points(group=ENTRY_POINT_GROUP)}


def _from_current_folder(module: str) -> Any:
    """``module`` found in the current folder (a plug-in beside the user's data, as ``python -m``
    would find it), loaded without adding the folder to ``sys.path`` for the whole process: only
    its top-level package or module is looked up there; its submodules follow its own path.
    A plain folder (no ``__init__.py``, such as the clone's ``examples/``) is a namespace package
    there, as ``python -m`` from that folder would take it. None if the current folder has no
    ``module`` (the top-level name found there is forgotten again)."""
    top = module.partition(".")[0]
    if top in sys.modules:
        return None  # the plain import already knew ``top`` and found no ``module`` under it
    spec = importlib.machinery.PathFinder.find_spec(top, [os.getcwd()])
    if spec is None or (spec.loader is None and spec.submodule_search_locations is None):
        return None
    # a namespace spec has no loader: module_from_spec gives it the namespace loader and its
    # __path__ (the folder), whose exec_module does nothing
    loaded = importlib.util.module_from_spec(spec)
    sys.modules[top] = loaded
    try:
        if spec.loader is not None:
            spec.loader.exec_module(loaded)
        return importlib.import_module(module)
    except ModuleNotFoundError as exc:
        _forget(top)
        if exc.name is not None and module.startswith(exc.name):
            return None  # a folder of that name, without the module asked for
        raise
    except BaseException:
        _forget(top)
        raise


def _forget(top: str) -> None:
    """Drop a top-level name loaded from the current folder, and its submodules."""
    for name in [n for n in sys.modules if n == top or n.startswith(top + ".")]:
        del sys.modules[name]


class _Missing(Exception):
    """The module is neither importable nor in the current folder."""


def _import_here_or_beside(module: str) -> Any:
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name is None or not module.startswith(exc.name):
            raise  # the plug-in itself imports something that is not installed
        found = _from_current_folder(module)
        if found is None:
            raise _Missing from None
        return found


def _import_module(module: str, ref: str) -> Any:
    try:
        return _import_here_or_beside(module)
    except _Missing:
        raise ParameterError(
            f"model plug-in {ref!r}: no module named {module!r} (install its package, or run "
            "from the folder that holds it, or add that folder to PYTHONPATH)."
        ) from None
    except Exception as exc:  # the user's module: say what broke, in one line
        raise ParameterError(
            f"model plug-in {ref!r}: importing {module!r} failed: {type(exc).__name__}: {exc}"
        ) from None


@functools.lru_cache(maxsize=64)
def load_factory(ref: str) -> Callable[..., Any]:
    """The callable named by ``module:attribute`` (ValueError in one line if it is not there)."""
    m = _REF_RE.match(ref)
    if m is None:
        raise ParameterError(f"model plug-in {ref!r} is not of the form package.module:factory.")
    obj: Any = _import_module(m.group("module"), ref)
    for part in m.group("factory").split("."):
        if not hasattr(obj, part):
            raise ParameterError(
                f"model plug-in {ref!r}: module {m.group('module')!r} has no "
                f"{m.group('factory')!r}."
            )
        obj = getattr(obj, part)
    if not callable(obj):
        raise ParameterError(f"model plug-in {ref!r}: {m.group('factory')!r} is not callable.")
    return obj


def _annotation_type(p: inspect.Parameter) -> type:
    ann = p.annotation
    text = ann if isinstance(ann, str) else getattr(ann, "__name__", "")
    text = str(text).replace(" ", "")
    for name, typ in (("bool", bool), ("int", int), ("float", float), ("str", str)):
        if text == name or text.startswith(name + "|"):
            return typ
    default = p.default
    if isinstance(default, bool | int | float | str):
        return type(default)
    return str


def factory_parameters(factory: Callable[..., Any]) -> tuple[dict[str, type], bool]:
    """The factory's keyword parameters with their types, and whether it takes ``**kwargs``."""
    try:
        sig = inspect.signature(factory)
    except (TypeError, ValueError):
        return {}, True
    types, open_kw = {}, False
    for p in sig.parameters.values():
        if p.kind is p.VAR_KEYWORD:
            open_kw = True
        elif p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY):
            types[p.name] = _annotation_type(p)
    return types, open_kw


class PluginParams:
    """The parameters a plug-in was built with (stored in recordings and tables)."""

    def __init__(self, values: Mapping[str, Any]) -> None:
        self._values = dict(values)

    def to_dict(self) -> dict[str, Any]:
        return dict(self._values)

    def __getattr__(self, name: str) -> Any:
        try:
            return self.__dict__["_values"][name]
        except KeyError:
            raise AttributeError(name) from None

    def __repr__(self) -> str:
        return f"PluginParams({self._values!r})"


def _outputs(raw: Any, ref: str) -> tuple[Output, ...]:
    if isinstance(raw, Mapping):
        items = [Output(str(k), str(v), "") for k, v in raw.items()]
    else:
        items = []
        for o in raw or ():
            if isinstance(o, Output):
                items.append(o)
            elif isinstance(o, tuple | list) and len(o) in (2, 3):
                items.append(Output(str(o[0]), str(o[1]), str(o[2]) if len(o) == 3 else ""))
            else:
                raise ParameterError(f"model plug-in {ref!r}: output {o!r} is not (name, unit).")
    if not items:
        raise ParameterError(f"model plug-in {ref!r}: its model declares no outputs.")
    taken = [o.name for o in items if o.name in FRAME_TABLE_COLUMNS]
    if taken:
        raise ParameterError(
            f"model plug-in {ref!r}: its output {taken[0]!r} has the name of vdc's own column "
            f"{taken[0]!r} of the per-frame tables ({', '.join(FRAME_TABLE_COLUMNS)} are "
            "taken): rename the output."
        )
    return tuple(items)


class PluginModel:
    """A plug-in's model behind vdc's :class:`avdm.base.Model` interface."""

    def __init__(self, inner: Any, name: str, params: Mapping[str, Any], ref: str) -> None:
        if not callable(getattr(inner, "step", None)):
            raise ParameterError(f"model plug-in {ref!r}: the factory's result has no step(frame).")
        self.inner = inner
        self.name = name
        self.params = PluginParams(params)
        self.outputs = _outputs(getattr(inner, "outputs", None), ref)
        self._names = tuple(o.name for o in self.outputs)
        self._ref = ref

    def reset(self) -> None:
        if callable(getattr(self.inner, "reset", None)):
            self.inner.reset()

    def step(self, frame: np.ndarray) -> dict[str, float]:
        arr = np.asarray(frame)
        if arr.ndim != 2:
            raise ParameterError(
                f"a frame must have shape (H, W), got an array of shape {arr.shape}."
            )
        try:
            out = self.inner.step(check_frames(arr[None])[0])
        except Exception as exc:  # the user's code: one line naming it, no traceback
            raise PluginError(self._ref, exc, offset=0) from None
        missing = [n for n in self._names if n not in out]
        if missing:
            raise ParameterError(
                f"model plug-in {self._ref!r}: step() returned no {', '.join(missing)} "
                f"(it declares outputs {', '.join(self._names)})."
            )
        return {n: float(out[n]) for n in self._names}

    def run(self, frames: np.ndarray) -> dict[str, np.ndarray]:
        if callable(getattr(self.inner, "run", None)):
            try:
                out = self.inner.run(check_frames(frames))
            except Exception as exc:  # somewhere in these frames
                raise PluginError(self._ref, exc) from None
            return {n: np.asarray(out[n], dtype=np.float64) for n in self._names}
        rows = []
        for i, frame in enumerate(check_frames(frames)):
            try:
                rows.append(self.step(frame))
            except PluginError as exc:
                exc.offset = i  # the frame's place in this call's frames
                raise
        return {n: np.array([r[n] for r in rows], dtype=np.float64) for n in self._names}

    def set_param(self, name: str, value: float) -> None:
        """Change a parameter while the model runs (a policy's doing)."""
        if callable(getattr(self.inner, "set_param", None)):
            self.inner.set_param(name, value)
        elif hasattr(self.inner, name):
            setattr(self.inner, name, value)
        else:
            raise ParameterError(
                f"model plug-in {self._ref!r} has no parameter {name!r} to change while it runs "
                "(give its model that attribute or a set_param(name, value) method)."
            )


def build_plugin(
    ref: str, name: str, overrides: Mapping[str, Any], context: Mapping[str, Any]
) -> PluginModel:
    """Call the factory ``ref`` with the context it accepts and ``overrides``; wrap the result.

    A factory that raises is a ValueError naming the plug-in and the error, in one line."""
    factory = load_factory(ref)
    types, open_kw = factory_parameters(factory)
    kwargs = {k: v for k, v in context.items() if k in types or open_kw}
    kwargs.update(overrides)
    try:
        inner = factory(**kwargs)
    except Exception as exc:  # the user's code: report it in one line
        detail = str(exc).splitlines()[0] if str(exc) else ""
        raise ParameterError(
            f"model plug-in {ref!r} failed to build with {kwargs or 'no parameters'}: "
            f"{type(exc).__name__}: {detail}"
        ) from None
    return PluginModel(inner, name, kwargs, ref)
