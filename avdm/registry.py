"""Named model variants and ``name:key=value,...`` overrides.

A variant is a model kind plus parameter overrides. Users add their own on the command line:
``--model avdm:beta=0.5,tw=6``. Every model is built through ``make_model`` so that analysis
and capture treat them alike.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from avdm.avdm_model import Avdm, AvdmParams
from avdm.avdm_multiscale import AvdmMultiScale, AvdmMultiScaleParams
from avdm.base import PRIMARY_OUTPUT as PRIMARY_OUTPUT_NAME
from avdm.base import Model, Params, require_alert
from avdm.calibration_store import calibration_for
from avdm.errors import ParameterError
from avdm.flow_ttc import FlowTtc, FlowTtcParams
from avdm.hrc import Hrc, HrcParams
from avdm.hrc_calibration import hrc_calibration
from avdm.lgmd import LgmdColias, LgmdPlus
from avdm.lgmd_params import LgmdColiasParams, LgmdPlusParams
from avdm.plugins import (
    PluginParams,
    build_plugin,
    entry_point_models,
    factory_parameters,
    is_reference,
    load_factory,
)
from avdm.policy import PolicyModel, load_policy


@dataclasses.dataclass(frozen=True)
class Kind:
    """A model family: its params class and how to build a model from params."""

    params_cls: type[Params]
    build: Callable[[Params, str], Model]
    # fills parameters that depend on the camera (e.g. the decoding calibration); may raise
    complete: Callable[[Params], Params]


@dataclasses.dataclass(frozen=True)
class Variant:
    kind: str
    overrides: Mapping[str, Any]
    description: str


def _complete_avdm(params: Params) -> Params:
    assert isinstance(params, AvdmParams | AvdmMultiScaleParams)
    if params.a is not None and params.b is not None:
        return params
    # shipped, else cached, else fitted now: once per camera and per set of dynamics
    # (a variant with another beta or tw gets a fit of its own; see calibration_store)
    cal = calibration_for(params.fps, params.deg_per_px, params=params)
    return params.replace(
        a=params.a if params.a is not None else cal["a"],
        b=params.b if params.b is not None else cal["b"],
    )


def _complete_hrc(params: Params) -> Params:
    assert isinstance(params, HrcParams)
    if None not in (params.r_peak, params.v_peak_dps, params.knee, params.change_max):
        return params
    # the response curve measured on 1/f clutter for this camera and these dynamics: once,
    # then cached (avdm.hrc_calibration); what the user fixed wins

    cal = hrc_calibration(params)
    return params.replace(
        **{k: cal[k] if getattr(params, k) is None else getattr(params, k) for k in _HRC_CURVE}
    )


_HRC_CURVE = ("r_peak", "v_peak_dps", "knee", "change_max")


def _as_is(params: Params) -> Params:
    return params


KINDS: dict[str, Kind] = {
    "avdm": Kind(AvdmParams, lambda p, n: Avdm(p, n), _complete_avdm),  # type: ignore[arg-type]
    "avdm-multiscale": Kind(
        AvdmMultiScaleParams,
        lambda p, n: AvdmMultiScale(p, n),  # type: ignore[arg-type]
        _complete_avdm,
    ),
    "hrc": Kind(HrcParams, lambda p, n: Hrc(p, n), _complete_hrc),  # type: ignore[arg-type]
    "lgmd-plus": Kind(LgmdPlusParams, lambda p, n: LgmdPlus(p, n), _as_is),  # type: ignore[arg-type]
    "lgmd-colias": Kind(LgmdColiasParams, lambda p, n: LgmdColias(p, n), _as_is),  # type: ignore[arg-type]
    "flow-ttc": Kind(FlowTtcParams, lambda p, n: FlowTtc(p, n), _as_is),  # type: ignore[arg-type]
}

VARIANTS: dict[str, Variant] = {
    "avdm": Variant("avdm", {}, "AVDM, ON and OFF channels averaged (default)"),
    "avdm-on": Variant("avdm", {"channel": "on"}, "AVDM, ON channel only (tunnel-centring code)"),
    "avdm-off": Variant("avdm", {"channel": "off"}, "AVDM, OFF channel only"),
    "avdm-allmean": Variant(
        "avdm", {"pooling": "all_mean"}, "AVDM pooling the mean of [E]+ over all detectors"
    ),
    "avdm-unity": Variant(
        "avdm",
        {"photoreceptor_lag": 9, "photoreceptor_sign": -1, "theta_e": 0.001},
        "AVDM as the released Unity code runs it: I(t-9) - I(t) photoreceptor, theta_e = 0.001",
    ),
    "avdm-released-units": Variant(
        "avdm",
        {"a": 100.0, "b": 1.0, "contrast_term": False},
        "AVDM decoded as the released code does, 100·λ̂·√R̄ with no contrast term: relative "
        "units, not deg/s, the units the paper's 'AVDM > 100' counts were set in",
    ),
    "avdm-natural": Variant(
        "avdm-multiscale",
        {},
        "AVDM for real footage: multi-scale, direction-symmetric correlators, texture pooled "
        "over the field; valid 1-300 deg/s at 25-30 fps (default for video and complexity)",
    ),
    "hrc": Variant(
        "hrc",
        {},
        "Hassenstein-Reichardt correlator, fly-style, contrast-normalised: tuned to temporal "
        "frequency; reads deg/s only below its calibrated peak (about 25 deg/s at 25-30 fps)",
    ),
    "lgmd-plus": Variant("lgmd-plus", {}, "LGMD+ collision detector, released defaults"),
    "lgmd-plus-arena": Variant(
        "lgmd-plus",
        {"blur_truncate": False, "t_de": 5.0, "w_base": 0.3},
        "LGMD+ retuned for the arena's 99x72 camera: alerts on static walls too",
    ),
    "lgmd-colias": Variant(
        "lgmd-colias", {}, "LGMD+ as ported to the Colias-IV firmware (integer, OFF-biased)"
    ),
    "flow-ttc": Variant(
        "flow-ttc",
        {},
        "optic-flow time-to-contact detector (Farneback flow; tau = 2 / divergence): alerts "
        "below tau_alert_s = 1 s; no frame differences",
    ),
}

_SPEC_RE = re.compile(r"^(?P<name>[A-Za-z0-9_\-]+)(?::(?P<over>.*))?$")
_TRUE = {"1", "true", "yes", "on"}
_FALSE = {"0", "false", "no", "off"}


def _parse_value(key: str, raw: str, typ: type) -> Any:
    raw = raw.strip()
    if raw == "":
        raise ParameterError(f"model override {key}= has no value.")
    if typ is bool:
        low = raw.lower()
        if low in _TRUE:
            return True
        if low in _FALSE:
            return False
        raise ParameterError(f"model override {key}={raw!r}: expected true or false.")
    if typ is int:
        try:
            return int(raw)
        except ValueError:
            raise ParameterError(f"model override {key}={raw!r}: expected an integer.") from None
    if typ is float:
        try:
            return float(raw)
        except ValueError:
            raise ParameterError(f"model override {key}={raw!r}: expected a number.") from None
    return raw


# a key every model takes: the file of a learnt policy that sets one of its parameters from the
# scene's profiled complexity as it runs (avdm.policy)
POLICY_KEY = "policy"


def _split_spec(spec: str) -> tuple[str, str | None, str | None]:
    """``(name, plug-in reference or None, override text or None)`` of a spec."""
    if not isinstance(spec, str) or not spec.strip():
        raise ParameterError("empty model spec: expected a name such as 'avdm' or 'avdm:beta=0.5'.")
    text = spec.strip()
    parts = text.split(":", 2)
    named = parts[0] in VARIANTS or parts[0] in entry_point_models()
    if not named and len(parts) >= 2 and "=" not in parts[1] and is_reference(":".join(parts[:2])):
        ref = f"{parts[0]}:{parts[1]}"
        return ref, ref, parts[2] if len(parts) == 3 else None
    m = _SPEC_RE.match(text)
    if m is None:
        raise ParameterError(
            f"malformed model spec {spec!r}: expected name, name:key=value,... or "
            "package.module:factory[:key=value,...]."
        )
    name = m.group("name")
    if name in VARIANTS:
        return name, None, m.group("over")
    installed = entry_point_models()
    if name in installed:
        return name, installed[name], m.group("over")
    known = sorted(VARIANTS) + sorted(installed)
    raise ParameterError(
        f"unknown model {name!r}: known models are {', '.join(known)} (or a plug-in, "
        "package.module:factory)."
    )


def _param_types(name: str, ref: str | None) -> tuple[dict[str, type], bool]:
    """The parameters a spec may override, with their types, and whether others are taken."""
    if ref is None:
        return KINDS[VARIANTS[name].kind].params_cls.field_types(), False
    return factory_parameters(load_factory(ref))


def parse_model_spec(spec: str) -> tuple[str, dict[str, Any]]:
    """Split ``"name:key=value,key=value"`` (or ``"package.module:factory:key=value"``) into the
    model's name and typed overrides.

    Raises ``ValueError`` naming the problem: unknown variant or plug-in, unknown parameter, a
    value of the wrong type, or a malformed spec.
    """
    name, ref, over = _split_spec(spec)
    types, open_kw = _param_types(name, ref)
    overrides: dict[str, Any] = {}
    if over is not None:
        if not over.strip():
            raise ParameterError(f"model spec {spec!r} has ':' but no key=value overrides.")
        for item in over.split(","):
            if "=" not in item:
                raise ParameterError(
                    f"model override {item.strip()!r} in {spec!r} is not key=value."
                )
            key, raw = (s.strip() for s in item.split("=", 1))
            if key == POLICY_KEY:
                overrides[key] = _parse_value(key, raw, str)
                continue
            if key not in types and not open_kw:
                raise ParameterError(
                    f"unknown parameter {key!r} for model {name!r}: "
                    f"known parameters are {', '.join(types) or '(none)'}."
                )
            overrides[key] = _parse_value(key, raw, types.get(key, float))
    return name, overrides


def is_plugin(spec: str) -> bool:
    """``spec`` names a model from outside vdc (a factory or an installed entry point)."""
    return _split_spec(spec)[1] is not None


def add_overrides(spec: str, overrides: str) -> str:
    """``spec`` with ``overrides`` (``"key=value,..."``) added to its own: after ``:`` for a
    bare name or factory, after ``,`` where the spec has overrides already."""
    plain = ":" not in spec or (is_plugin(spec) and spec.count(":") == 1)
    return f"{spec}{':' if plain else ','}{overrides}"


def canonical_name(spec: str) -> str:
    """The spec as it is stored in tables: ``name`` or ``name:k=v,...`` with keys sorted."""
    name, overrides = parse_model_spec(spec)
    if not overrides:
        return name
    return name + ":" + ",".join(f"{k}={overrides[k]}" for k in sorted(overrides))


def same_model(a: str, b: str, **context: Any) -> bool:
    """Whether specs ``a`` and ``b`` build the same model on the camera ``context``: the same
    kind (or plug-in factory) with equal resolved parameters and the same policy, however
    they are spelt (``avdm:beta=0.25`` is ``avdm``, whose ``beta`` is 0.25). False when
    either cannot be built."""
    try:
        if canonical_name(a) == canonical_name(b):
            return True
        (na, oa), (nb, ob) = parse_model_spec(a), parse_model_spec(b)
        if oa.get(POLICY_KEY) != ob.get(POLICY_KEY) or _split_spec(a)[1] != _split_spec(b)[1]:
            return False
        if _split_spec(a)[1] is None and VARIANTS[na].kind != VARIANTS[nb].kind:
            return False
        pa, pb = make_params(a, **context), make_params(b, **context)
    except (ValueError, KeyError, TypeError):
        return False
    return type(pa) is type(pb) and pa == pb


def make_params(spec: str, **context: Any) -> Params:
    """Fully resolved params for ``spec``.

    ``context`` carries camera facts the caller knows (``fps``, ``deg_per_px``); they apply
    before the variant's and the user's overrides, which win. A plug-in's params are the
    keyword arguments its factory would be called with.
    """
    name, overrides = parse_model_spec(spec)
    overrides.pop(POLICY_KEY, None)
    _, ref, _ = _split_spec(spec)
    if ref is not None:
        types, _ = factory_parameters(load_factory(ref))
        return PluginParams({**{k: v for k, v in context.items() if k in types}, **overrides})  # type: ignore[return-value]
    variant = VARIANTS[name]
    kind = KINDS[variant.kind]
    fields = kind.params_cls.field_types()
    values = {k: v for k, v in context.items() if k in fields}
    values.update(variant.overrides)
    values.update(overrides)
    params = kind.params_cls(**values)  # validates in __post_init__
    return kind.complete(params)


def make_model(spec: str, **context: Any) -> Model:
    """Build the model named by ``spec`` (e.g. ``"avdm"``, ``"avdm-on"``, ``"avdm:beta=0.5"``,
    ``"mypackage.detectors:make_detector:threshold=0.2"``, ``"lgmd-plus:policy=policy.csv"``)."""
    name, overrides = parse_model_spec(spec)
    policy = overrides.pop(POLICY_KEY, None)
    _, ref, _ = _split_spec(spec)
    full = canonical_name(spec)
    if ref is not None:
        model: Model = build_plugin(ref, full, overrides, context)  # type: ignore[assignment]
    else:
        params = make_params(spec, **context)
        model = KINDS[VARIANTS[name].kind].build(params, full)
    if policy is None:
        return model

    plan = load_policy(policy)
    profiler = make_model(plan.profile_model, **context)
    return PolicyModel(model, plan, profiler, context)  # type: ignore[return-value]


# the families whose models decode an angular velocity (output ``omega_dps``); the others are
# collision detectors (spike rate, membrane potential)
ANGULAR_VELOCITY_KINDS = ("avdm", "avdm-multiscale", "hrc")


def require_angular_velocity(spec: str, what: str) -> None:
    """ValueError, in one line, when ``spec`` is not a model with ``omega_dps`` (``what``: the
    command that needs one, e.g. ``"sweep"``)."""
    name, _ = parse_model_spec(spec)
    if name not in VARIANTS:  # a plug-in: it must say it decodes an angular velocity
        model = make_model(spec)
        if PRIMARY_OUTPUT_NAME in {o.name for o in model.outputs}:
            return
    if name not in VARIANTS or VARIANTS[name].kind not in ANGULAR_VELOCITY_KINDS:
        avdms = sorted(n for n, v in VARIANTS.items() if v.kind in ANGULAR_VELOCITY_KINDS)
        raise ParameterError(
            f"{what} needs a model's angular velocity (omega_dps); {name} is a collision "
            f"detector without one: give an angular-velocity model ({', '.join(avdms)})."
        )


def describe_models() -> str:
    """One line per registered variant and installed plug-in, for ``--help`` texts."""
    lines = [f"  {n:<20} {v.description}" for n, v in sorted(VARIANTS.items())]
    lines += [f"  {n:<20} plug-in {ref}" for n, ref in sorted(entry_point_models().items())]
    own = "a model of your own (docs/method/models.md#your-own-model)"
    lines.append(f"  {'module:factory':<20} {own}")
    return "\n".join(lines)


def check_detector(
    spec: str, context: Mapping[str, Any], shape: tuple[int, int], *, alert: bool = True
) -> Model:
    """The one check of a detector, before any run that takes it: build ``spec`` with the
    camera ``context`` (what ``make_model`` is given), require an ``alert`` output
    (:func:`avdm.base.require_alert`), and step a fresh instance on one mid-grey ``shape``
    (H, W) uint8 frame, the raster it will be given: it must return ``alert`` as a finite
    number or a bool. ValueError in one line naming the detector otherwise (a plug-in that
    fails to build, has no ``step``, returns other keys or a NaN alert, or raises on a
    frame). ``alert=False``: any model (``batch``/``tables --model``), whose step must return
    each output it declares. Returns the model built (stepped once: its name, outputs and
    parameters describe the run; build a fresh one to run it)."""
    model = make_model(spec, **context)
    if alert:
        require_alert(model)
    h, w = shape
    what = "detector" if alert else "model"
    try:
        out = model.step(np.full((h, w), 128, dtype=np.uint8))
    except Exception as exc:  # the user's code: one line
        first = str(exc).splitlines()[0] if str(exc) else ""
        why = first if isinstance(exc, ValueError) else f"{type(exc).__name__}: {first}"
        raise ParameterError(
            f"{what} {model.name!r} cannot run on a {w}x{h} frame (WxH): {why}"
        ) from None
    names = [o.name for o in model.outputs] if not alert else ["alert"]
    lacking = [n for n in names if not isinstance(out, Mapping) or n not in out]
    if lacking and not alert:
        raise ParameterError(
            f"model {model.name!r}: step() on a {w}x{h} frame (WxH) returned no "
            f"{', '.join(lacking)} (it declares {', '.join(names)})."
        )
    if not alert:
        return model
    value = out["alert"] if not lacking else None
    finite = isinstance(value, bool | np.bool_) or (
        isinstance(value, int | float | np.integer | np.floating) and np.isfinite(value)
    )
    if not finite:
        raise ParameterError(
            f"detector {model.name!r} returned alert={value!r} on a {w}x{h} frame (WxH): it "
            "must be a finite number (1 = collision ahead, 0 = not) or a bool."
        )
    return model
