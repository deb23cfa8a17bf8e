"""Input checks and small numeric helpers shared by the plane, sphere and cylinder fits."""

from __future__ import annotations

import numpy as np

from .models import FitFailure

# Relative size below which a spread is treated as exactly zero. Centred float64 data
# keeps ~1e-16 relative precision and float32 input ~1e-7 of the coordinates, so a
# thickness below 1e-6 of the extent is numerical noise, never a real dimension.
DEGENERATE_RATIO = 1e-6


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


def flatness_failure(eigvals: np.ndarray, kind: str) -> FitFailure | None:
    """FitFailure when the points are collinear or coplanar (a curved surface needs 3-D spread)."""
    largest = eigvals[2]
    if largest <= 0.0 or eigvals[1] <= (DEGENERATE_RATIO**2) * largest:
        return FitFailure(kind, "points are coincident or collinear")
    if eigvals[0] <= (DEGENERATE_RATIO**2) * largest:
        return FitFailure(kind, "points are coplanar: no curvature to fit")
    return None


def check_tolerance(value, name: str) -> float | None:
    """Validate an optional positive tolerance keyword."""
    if value is None:
        return None
    value = float(value)
    if not np.isfinite(value) or value <= 0:
        raise ValueError(f"{name} must be a positive number or None; got {value!r}")
    return value


# A radius above this many times the rms spread of the points means a cap of under
# ~0.1 deg: the points are flat, and Levenberg-Marquardt would chase r -> infinity.
RADIUS_LIMIT = 1e3


class Prepared:
    """Validated input of a fit: points, centred/scaled copy and scatter eigenvalues, or the failure."""

    __slots__ = ("points", "inlier_distance", "failure", "n_bad", "centroid", "scale", "q", "eigvals",
                 "eigvecs")

    def __init__(self, points, kind: str, minimum: int, inlier_distance, curved: bool):
        from ._compiled import prepare_points

        self.points = np.ascontiguousarray(as_points(points))
        (self.n_bad, self.centroid, self.scale, self.q, self.eigvals,
         self.eigvecs) = prepare_points(self.points)
        self._check(kind, minimum, inlier_distance, curved)

    def _check(self, kind: str, minimum: int, inlier_distance, curved: bool) -> None:
        self.inlier_distance = check_tolerance(inlier_distance, "inlier_distance")
        n = len(self.points)
        if n < minimum:
            self.failure = FitFailure(kind, f"a {kind} fit needs at least {minimum} points; got {n}")
        elif self.n_bad:
            self.failure = FitFailure(kind, f"{self.n_bad} of {n} points are NaN or infinite; "
                                            "drop invalid points before fitting")
        else:
            self.failure = flatness_failure(self.eigvals, kind) if curved else None

    def specialise(self, kind: str, minimum: int, inlier_distance, curved: bool) -> "Prepared":
        """The same prepared points for another model kind (its own checks and inlier distance).

        Lets the plane -> cylinder -> sphere decision centre, scale and decompose the
        points once instead of once per model.
        """
        other = object.__new__(Prepared)
        for name in Prepared.__slots__:
            setattr(other, name, getattr(self, name))
        other._check(kind, minimum, inlier_distance, curved)
        return other


def refinement_failure(kind: str, converged: bool, max_iterations: int, params, radius: float) -> FitFailure | None:
    """FitFailure when Levenberg-Marquardt did not converge or left non-finite/negative values."""
    if np.isfinite(radius) and radius > RADIUS_LIMIT:
        return FitFailure(kind, f"radius grew beyond {RADIUS_LIMIT:g}x the patch size: the points are nearly flat")
    if not converged:
        return FitFailure(kind, f"geometric refinement did not converge in {max_iterations} iterations")
    if not (np.all(np.isfinite(params)) and np.isfinite(radius)) or radius <= 0:
        return FitFailure(kind, "geometric refinement diverged")
    return None


def curvature_failure(prep: Prepared, kind: str, radius: float, arc: float, rms: float) -> FitFailure | None:
    """FitFailure when a curved model does not explain the points better than a plane.

    Two tests, in the scaled units of ``prep``: the rms must be below the plane's (the
    smallest scatter eigenvalue gives it for free), and the sagitta
    ``r (1 - cos(arc / 2))`` (arc capped at pi) -- how far the surface bends away from a
    plane across the patch -- must exceed the rms, else the curvature is noise and the
    curved model would be a false fitting.
    """
    scale = prep.scale
    plane_rms = float(np.sqrt(max(prep.eigvals[0], 0.0) / len(prep.q)))
    if rms >= plane_rms:
        return FitFailure(
            kind, f"rms {rms * scale:.3g} is no better than a plane's {plane_rms * scale:.3g}"
        )
    sagitta = radius * (1.0 - np.cos(min(arc, np.pi) / 2.0))
    if sagitta > rms:
        return None
    return FitFailure(
        kind,
        f"curvature not significant: sagitta {sagitta * scale:.3g} <= rms {rms * scale:.3g} "
        f"(radius {radius * scale:.3g}); a plane explains the points as well",
    )
