"""Registry of segmenters and fitters, open to third-party plugins.

Built-ins are listed by import path so that importing the package stays cheap;
third parties add theirs through ``importlib.metadata`` entry points in the groups
``rangeseg_o3d.segmenters`` and ``rangeseg_o3d.fitters``. An entry point must load
to a :class:`Plugin` (or a zero-argument callable returning one). A plugin that
fails to load is skipped with a warning, never a crash. Entry points are discovered and
loaded once per process, on the first look-up that needs them; a name is resolved in a
fixed order (registered in code, built-in, entry point), and an entry point whose name is
taken is warned about, naming both, and not used.

Contracts
---------
segmenter ``run(cloud: OrganizedCloud, *, sensor: Sensor, **params) -> Segmentation``
fitter    ``run(points: (N, 3) ndarray, **params) -> Plane | Sphere | Cylinder | FitFailure``

``params`` are the fields of the plugin's pydantic ``config`` model. A segmenter that
declares a ``sensor`` keyword receives the run's :class:`~rangeseg_o3d.sensor.Sensor`
(noise model, grid); a fitter whose keywords follow from the sensor provides
``bind_sensor``.
"""

from __future__ import annotations

import functools
import importlib
import inspect
import logging
import typing
import warnings
from dataclasses import dataclass
from importlib.metadata import EntryPoint, entry_points
from typing import Callable, Iterable

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, create_model

from .result import Segmentation  # the segmenters' answer; here for the plugins that import it from here

__all__ = [
    "Plugin",
    "Segmentation",
    "params_model",
    "defaults_of",
    "register",
    "get",
    "available",
    "load_entry_points",
    "installed_entry_points",
    "GROUPS",
]

log = logging.getLogger(__name__)

GROUPS = {"segmenter": "rangeseg_o3d.segmenters", "fitter": "rangeseg_o3d.fitters"}


class StrictParams(BaseModel):
    """The default base of :func:`params_model`: unknown keys are an error, values frozen."""

    model_config = ConfigDict(extra="forbid", frozen=True)


def params_model(function: Callable, fields: dict, *, name: str, doc: str | None = None,
                 base: type[BaseModel] = StrictParams) -> type[BaseModel]:
    """A plugin's parameter model read off its function, so that each default is written once.

    Every keyword of ``function`` named in ``fields`` with a dict of pydantic constraints
    (``{"window": dict(ge=3, le=15), "seed": {}}``) becomes a field with the signature's
    annotation and default and those constraints. A name given a ``(type, Field(default,
    ...))`` pair instead is a field the function does not take (a setting the plugin's
    ``bind_sensor`` turns into keywords). Fields keep the order of ``fields``; ``base``
    carries the model's config and its validators.
    """
    signature = inspect.signature(function)
    hints = typing.get_type_hints(function)
    model_fields = {}
    for key, spec in fields.items():
        if isinstance(spec, tuple):
            model_fields[key] = spec
            continue
        parameter = signature.parameters.get(key)
        if parameter is None or parameter.default is inspect.Parameter.empty:
            raise ValueError(f"{function.__qualname__} has no keyword {key!r} with a default")
        model_fields[key] = (hints.get(key, typing.Any), Field(parameter.default, **spec))
    doc = doc or f"Parameters of :func:`{function.__qualname__}` (defaults: its signature's)."
    return create_model(name, __base__=base, __module__=function.__module__, __doc__=doc, **model_fields)


def defaults_of(source: Callable):
    """Decorator: the keyword-only parameters the decorated function declares without a
    default take ``source``'s defaults, so that a plugin's hooks share the defaults of its
    ``run`` written once. A name ``source`` has no default for is an error at import."""
    defaults = {key: p.default for key, p in inspect.signature(source).parameters.items()
                if p.default is not inspect.Parameter.empty}

    def apply(function: Callable) -> Callable:
        wanted = [key for key, p in inspect.signature(function).parameters.items()
                  if p.kind is inspect.Parameter.KEYWORD_ONLY and p.default is inspect.Parameter.empty]
        missing = [key for key in wanted if key not in defaults]
        if missing:
            raise ValueError(f"{function.__qualname__}: {source.__qualname__} has no default for {missing}")
        function.__kwdefaults__ = {**(function.__kwdefaults__ or {}), **{key: defaults[key] for key in wanted}}
        return function

    return apply


@dataclass(frozen=True)
class Plugin:
    """A named segmenter or fitter: its parameter model and the function that runs it."""

    name: str
    config: type[BaseModel]
    run: Callable
    description: str = ""
    refit: Callable | None = None
    """Optional, fitters only: ``refit(points, model, **params)`` fits a model of ``model``'s
    kind (used after a region grew or merged); without it the pipeline calls ``run`` again."""
    fit_batch: Callable | None = None
    """Optional, fitters only: ``fit_batch(xyz (N, 3), labels (N,), **params) -> {label: model}``
    settles at once the regions it can (e.g. every plane, from label-wise moments); the
    others go through ``run`` one by one."""
    refit_moments: Callable | None = None
    """Optional, fitters only: ``refit_moments(moments (K, 10), models, **params) -> list``
    refits from label-wise moments (see :mod:`rangeseg_o3d.fitting.batch_planes`): a model or
    FitFailure per row, or None where the kind needs the points (the pipeline then calls
    ``refit``)."""
    bind_sensor: Callable | None = None
    """Optional, fitters only: ``bind_sensor(params, sensor) -> dict`` turns the validated
    parameters into the keywords of ``run``, ``refit``, ``fit_batch`` and ``refit_moments``
    for a :class:`~rangeseg_o3d.sensor.Sensor`, once per pipeline (thresholds that grow
    with the sensor's noise)."""
    trimmed: Callable | None = None
    """Optional, fitters only: ``trimmed(xyz, pool, *, sigma, min_inliers, max_rms, fit_max_points,
    **params) -> (model, inliers)``: :func:`rangeseg_o3d.fitting.robust.trimmed_fit` of
    ``xyz[pool]`` (``min_points=min_inliers``) judged by ``run`` on at most ``fit_max_points`` points, models over
    ``max_rms`` refused, all in one call (the refinement's splits run it often). Called with
    ``starts=True`` only when the fitter's ``trimmed_fit(..., starts=True)`` (local starts) is wanted."""


_BUILTIN: dict[str, dict[str, str]] = {
    "segmenter": {
        "residual_edges": "rangeseg_o3d.segmenters.residual_edges:PLUGIN",
        "region_growing": "rangeseg_o3d.segmenters.region_growing:PLUGIN",
        "o3d_planar_patches": "rangeseg_o3d.segmenters.open3d_planes:PLANAR_PATCHES",
        "o3d_ransac_planes": "rangeseg_o3d.segmenters.open3d_planes:RANSAC_PLANES",
    },
    "fitter": {
        "primitives": "rangeseg_o3d.fitting.classify:PLUGIN",
    },
}
_REGISTERED: dict[str, dict[str, Plugin]] = {"segmenter": {}, "fitter": {}}  # by register()
_FROM_ENTRY_POINTS: dict[str, dict[str, tuple[str, Plugin]]] = {"segmenter": {}, "fitter": {}}
_ENTRY_POINTS_LOADED: set[str] = set()


def _check_kind(kind: str) -> None:
    if kind not in GROUPS:
        raise ValueError(f"kind must be one of {sorted(GROUPS)}; got {kind!r}")


def register(kind: str, plugin: Plugin, *, overwrite: bool = False) -> None:
    """Register ``plugin`` as a ``kind`` ('segmenter' or 'fitter').

    A registered plugin comes before a built-in or an entry point of the same name;
    replacing an existing name (a built-in included) needs ``overwrite=True``.
    """
    _check_kind(kind)
    if not isinstance(plugin, Plugin):
        raise TypeError(f"plugin must be a Plugin; got {type(plugin).__name__}")
    if not overwrite and (plugin.name in _REGISTERED[kind] or plugin.name in _BUILTIN[kind]):
        raise ValueError(f"a {kind} named {plugin.name!r} is already registered")
    _REGISTERED[kind][plugin.name] = plugin


@functools.lru_cache(maxsize=None)
def installed_entry_points(kind: str) -> tuple[EntryPoint, ...]:
    """The entry points installed in ``kind``'s group, discovered once per process (cached)."""
    _check_kind(kind)
    return tuple(entry_points(group=GROUPS[kind]))


def _load_plugin(ep: EntryPoint) -> Plugin:
    obj = ep.load()
    plugin = obj if isinstance(obj, Plugin) else obj()
    if not isinstance(plugin, Plugin):
        raise TypeError(f"loaded {type(plugin).__name__}, expected Plugin")
    return plugin


def _shadowed(kind: str, plugin: Plugin, ep: EntryPoint) -> str | None:
    """Why an entry point's plugin is not used under its name (None: it is)."""
    name = plugin.name
    if name in _BUILTIN[kind]:
        return f"shadows the built-in {kind} {name!r} ({_BUILTIN[kind][name]}); the built-in is used"
    if name in _REGISTERED[kind]:
        return f"shadows the {kind} {name!r} registered in code; that one is used"
    earlier = _FROM_ENTRY_POINTS[kind].get(name)
    if earlier is not None and earlier[0] != ep.value:
        return f"has the name of the {kind} plugin {name!r} from {earlier[0]}; that one (found first) is used"
    return None


def load_entry_points(kind: str, eps: Iterable[EntryPoint] | None = None) -> list[str]:
    """Load the plugins advertised in ``kind``'s entry-point group; returns the names they add.

    ``eps`` replaces the installed entry points (tests build EntryPoint objects directly).
    A plugin that fails to load, or whose name is taken (a built-in, a plugin registered
    in code, an earlier entry point), is skipped with a warning naming both: which plugin
    :func:`get` returns never depends on the order of calls.
    """
    _check_kind(kind)
    if eps is None:
        eps = installed_entry_points(kind)
    names = []
    for ep in eps:
        try:
            plugin = _load_plugin(ep)
        except Exception as exc:  # a broken third-party plugin must not break us
            warnings.warn(f"{kind} plugin {ep.name!r} ({ep.value}) failed to load and is skipped: {exc}",
                          RuntimeWarning, stacklevel=2)
            continue
        reason = _shadowed(kind, plugin, ep)
        if reason is not None:
            warnings.warn(f"{kind} plugin {plugin.name!r} from entry point {ep.value} {reason}",
                          RuntimeWarning, stacklevel=2)
            continue
        _FROM_ENTRY_POINTS[kind][plugin.name] = (ep.value, plugin)
        names.append(plugin.name)
    return names


def _ensure_entry_points(kind: str) -> None:
    if kind not in _ENTRY_POINTS_LOADED:
        _ENTRY_POINTS_LOADED.add(kind)
        load_entry_points(kind)


def available(kind: str) -> list[str]:
    """Sorted names of every ``kind`` known: built-ins, registered and entry points."""
    _check_kind(kind)
    _ensure_entry_points(kind)
    return sorted(set(_BUILTIN[kind]) | set(_REGISTERED[kind]) | set(_FROM_ENTRY_POINTS[kind]))


def get(kind: str, name: str) -> Plugin:
    """The plugin called ``name``; ValueError listing the known names if there is none.

    Looked up in a fixed order: registered in code, built-in, installed entry points
    (discovered and loaded once, on the first look-up that needs them).
    """
    _check_kind(kind)
    if name in _REGISTERED[kind]:
        return _REGISTERED[kind][name]
    if name in _BUILTIN[kind]:
        module, attr = _BUILTIN[kind][name].split(":")
        return getattr(importlib.import_module(module), attr)
    _ensure_entry_points(kind)
    if name in _FROM_ENTRY_POINTS[kind]:
        return _FROM_ENTRY_POINTS[kind][name][1]
    raise ValueError(f"unknown {kind} {name!r}; known: {', '.join(available(kind))}")
