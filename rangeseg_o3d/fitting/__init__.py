"""Least-squares plane, sphere and cylinder fits and the Fig. 2 primitive classifier.

The plain fits take an ``(N, 3)`` array and return a frozen model or a falsy
:class:`FitFailure`; they import numpy only. :func:`fit_primitive` (the "primitives"
fitter plugin) lives in :mod:`.classify`, which also imports pydantic for its config
model; it is loaded on first use so that importing the plain fits stays light.
"""

from .cylinder import fit_cylinder
from .primitives import Cylinder, FitFailure, Plane, Sphere
from .plane import fit_plane
from .sphere import fit_sphere

__all__ = [
    "fit_plane",
    "fit_sphere",
    "fit_cylinder",
    "fit_primitive",
    "Plane",
    "Sphere",
    "Cylinder",
    "FitFailure",
]


def __getattr__(name):
    # fit_primitive pulls in pydantic (through its config model): load it on demand
    if name == "fit_primitive":
        from .classify import fit_primitive

        return fit_primitive
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
