"""The one table of model kinds, shared by the compiled kernels and the Python code.

A model table (see :func:`rangeseg_o3d.fitting.region_fitter.model_table`) gives each label a kind and
a row of ``PARAM_SLOTS`` parameters:

=========  =====  ==========================================
kind       value  parameters
=========  =====  ==========================================
NONE       0      none: the label has no model, kernels skip it
PLANE      1      ``(nx, ny, nz, d)``: ``n . p = d``
SPHERE     2      ``(cx, cy, cz, r)``
CYLINDER   3      ``(ax, ay, az, px, py, pz, r)``: unit axis through p
=========  =====  ==========================================

The plane -> cylinder -> sphere decision (:mod:`rangeseg_o3d.fitting._decide`) answers
with the same values. numba reads module-level ints as compile-time constants, so the
kernels use the plain ints below; Python code may use :class:`ModelKind`, whose members
compare equal to them. This module imports nothing but the standard library.
"""

from __future__ import annotations

from enum import IntEnum

__all__ = ["ModelKind", "NONE", "PLANE", "SPHERE", "CYLINDER", "PARAM_SLOTS", "kind_of"]


class ModelKind(IntEnum):
    """Kind of a fitted model, as stored in a model table and returned by the decision."""

    NONE = 0
    PLANE = 1
    SPHERE = 2
    CYLINDER = 3

    @property
    def label(self) -> str:
        """The name models carry as ``kind`` ("plane", "sphere", "cylinder"; "none")."""
        return self.name.lower()


NONE = int(ModelKind.NONE)
PLANE = int(ModelKind.PLANE)
SPHERE = int(ModelKind.SPHERE)
CYLINDER = int(ModelKind.CYLINDER)

PARAM_SLOTS = 7
"""Parameters per row of a model table (a cylinder's seven; planes and spheres use four)."""


def kind_of(name: str) -> ModelKind:
    """The ModelKind of a model's ``kind`` string; ValueError for an unknown one.

    >>> kind_of("cylinder")
    <ModelKind.CYLINDER: 3>
    """
    try:
        return ModelKind[str(name).upper()]
    except KeyError:
        known = ", ".join(k.label for k in ModelKind if k)
        raise ValueError(f"model kind must be one of {known}; got {name!r}") from None
