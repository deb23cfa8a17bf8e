"""Input checks and small numeric helpers shared by the plane, sphere and cylinder fits."""

from __future__ import annotations

import numpy as np

from . import _codes as d
from ._codes import FLAT, RADIUS_LIMIT
from .primitives import FitFailure


def as_points(points, name: str = "points") -> np.ndarray:
    """Return ``points`` as a float64 ``(N, 3)`` array; TypeError/ValueError otherwise."""
    if isinstance(points, (str, bytes)) or points is None:
        raise TypeError(f"{name} must be an (N, 3) array of numbers; got {type(points).__name__}")
    try:
        arr = np.asarray(points, dtype=float)
    except (TypeError, ValueError) as exc:
        raise TypeError(
            f"{name} must be an (N, 3) array of numbers; got {type(points).__name__}"
        ) from exc
    if arr.ndim == 1 and arr.size == 0:
        arr = arr.reshape(0, 3)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{name} must have shape (N, 3); got {arr.shape}")
    return arr


def check_tolerance(value, name: str) -> float | None:
    """Validate an optional positive tolerance keyword."""
    if value is None:
        return None
    value = float(value)
    if not np.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a positive number or None; got {value!r}")
    return value


def input_failure(kind: str, n: int, n_bad: int, minimum: int) -> FitFailure | None:
    """FitFailure for too few points or NaN/infinite ones, else None."""
    if n < minimum:
        return FitFailure(kind, f"a {kind} fit needs at least {minimum} points; got {n}")
    if n_bad:
        return FitFailure(kind, f"{n_bad} of {n} points are NaN or infinite; drop invalid points before fitting")
    return None


class Prepared:
    """Validated input of a fit: points, centred/scaled copy and scatter eigenvalues, or the failure."""

    __slots__ = ("points", "inlier_distance", "failure", "n_bad", "centroid", "scale", "q", "eigvals",
                 "eigvecs")

    def __init__(self, points, kind: str, minimum: int, inlier_distance):
        from ._compiled import prepare_points

        self.points = np.ascontiguousarray(as_points(points))
        (self.n_bad, self.centroid, self.scale, self.q, self.eigvals,
         self.eigvecs) = prepare_points(self.points)
        self._check(kind, minimum, inlier_distance)

    def _check(self, kind: str, minimum: int, inlier_distance) -> None:
        self.inlier_distance = check_tolerance(inlier_distance, "inlier_distance")
        self.failure = input_failure(kind, len(self.points), self.n_bad, minimum)

    def specialise(self, kind: str, minimum: int, inlier_distance) -> "Prepared":
        """The same prepared points for another model kind (its own checks and inlier distance).

        Lets the plane -> cylinder -> sphere decision centre, scale and decompose the
        points once instead of once per model.
        """
        other = object.__new__(Prepared)
        for name in Prepared.__slots__:
            setattr(other, name, getattr(self, name))
        other._check(kind, minimum, inlier_distance)
        return other

    @property
    def eigen_rms(self) -> float:
        """The best plane's rms from the smallest scatter eigenvalue, in the points' units."""
        return self.scale * float(np.sqrt(max(self.eigvals[0], 0.0) / len(self.q)))


def refusal(kind: str, code: int, result=None, *, scale: float = 1.0, plane_rms: float = float("nan"),
            n: int = 0, minimum: int = 0, max_iterations: int = 0, tolerance: float = float("nan"),
            max_radius: float = float("nan"), min_arc: float = float("nan"),
            curvature_gain: float = float("nan")) -> str:
    """Why a curved model was refused, from a code of :mod:`rangeseg_o3d.fitting._decide`.

    ``result`` is the model's row (scaled frame, times ``scale`` for metres);
    ``plane_rms`` the plane's rms it was compared with (metres). Codes up to ``FLAT`` are
    the fit's own failures, the others the decision's thresholds.
    """
    if code == d.TOO_FEW:
        return f"a {kind} fit needs at least {minimum} points; got {n}"
    if code == d.COLLINEAR:
        return "points are coincident or collinear"
    if code == d.COPLANAR:
        return "points are coplanar: no curvature to fit"
    if code == d.SINGULAR:
        return "the algebraic sphere system is singular (coplanar points)"
    if code == d.RUNAWAY:
        return f"radius grew beyond {RADIUS_LIMIT:g}x the patch size: the points are nearly flat"
    if code == d.NOT_CONVERGED:
        return f"geometric refinement did not converge in {max_iterations} iterations"
    if code == d.DIVERGED:
        return "geometric refinement diverged"
    rms, radius, arc = result[d.RMS] * scale, result[d.RADIUS] * scale, result[d.ARC]
    if code == d.NO_BETTER:
        return f"rms {rms:.3g} is no better than a plane's {plane_rms:.3g}"
    if code == d.FLAT:
        sagitta = radius * (1.0 - np.cos(min(arc, np.pi) / 2.0))
        return (f"curvature not significant: sagitta {sagitta:.3g} <= rms {rms:.3g} "
                f"(radius {radius:.3g}); a plane explains the points as well")
    if code == d.RMS_OVER:
        return f"{kind} rms {rms:.3g} > {tolerance:.3g}"
    if code == d.RADIUS_OVER:
        return f"{kind} radius {radius:.3g} > max_radius {max_radius:.3g}"
    if code == d.ARC_UNDER:
        return f"{kind} arc {np.degrees(arc):.0f} deg < min_arc_deg {np.degrees(min_arc):.0f}"
    if code == d.GAIN_UNDER:
        return f"{kind} rms {rms:.3g} is not {curvature_gain:g}x below the plane's {plane_rms:.3g}"
    raise ValueError(f"unknown refusal code {code}")


def decision_reason(kind: str, code: int, result, *, eigen_rms: float, plane_rms: float,
                    **numbers) -> str:
    """:func:`refusal` as the decision words it: the fit's own failures prefixed by the kind.

    The fit's curvature test compares with the plane rms from the smallest eigenvalue
    (``eigen_rms``), the decision's gain test with the plane's own (``plane_rms``).
    """
    if code <= FLAT:
        return f"{kind}: {refusal(kind, code, result, plane_rms=eigen_rms, **numbers)}"
    return refusal(kind, code, result, plane_rms=plane_rms, **numbers)
