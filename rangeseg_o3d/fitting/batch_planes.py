"""Planes of many regions at once from label-wise moments.

A least-squares plane needs only the count, the sum and the sum of outer products of
its points; these add up when regions merge. So every region of a label image is
fitted from one pass over the pixels (:func:`rangeseg_o3d.kernels.label_moments`), and
the plane of a union of regions is the plane of the summed moments, without touching a
point again.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import kernels  # the package: its names load on first use (no compiler at import)


__all__ = ["PlaneTable", "planes_from_moments", "plane_rms_from_moments", "region_moments", "quadric_gains"]


@dataclass(frozen=True)
class PlaneTable:
    """Least-squares planes of regions ``0..K-1`` (row k = label k).

    ``rms`` is the rms orthogonal distance, ``eigvals`` the ascending eigenvalues of the
    covariance (m^2), ``frame`` the eigenvectors as rows (normal, middle, largest);
    ``ok`` is False for fewer than 3 points or coincident/collinear points.
    """

    count: np.ndarray
    centroid: np.ndarray
    normal: np.ndarray
    d: np.ndarray
    rms: np.ndarray
    eigvals: np.ndarray
    frame: np.ndarray
    ok: np.ndarray


def region_moments(xyz_flat: np.ndarray, labels_flat: np.ndarray, n: int | None = None, *,
                   only=None) -> np.ndarray:
    """(n, 10) moments (count, sums, sums of products) of the points of each label 1..n-1.

    With ``only`` (labels), those labels' rows alone (the same values), the others zero:
    the other labels' pixels are read, not summed (:func:`rangeseg_o3d.kernels.member_moments`)."""
    labels_flat = np.ascontiguousarray(labels_flat, dtype=np.int32)
    if n is None:
        n = int(labels_flat.max(initial=0)) + 1
    xyz_flat = np.ascontiguousarray(xyz_flat, dtype=np.float64)
    if only is None:
        return kernels.label_moments(xyz_flat, labels_flat, int(n))
    members = np.zeros(int(n), np.bool_)
    members[[k for k in only if 0 < k < n]] = True
    return kernels.member_moments(xyz_flat, labels_flat, members)


def _moment_rows(moments) -> np.ndarray:
    moments = np.ascontiguousarray(moments, dtype=np.float64)
    if moments.ndim != 2 or moments.shape[1] != 10:
        raise ValueError(f"moments must have shape (K, 10); got {moments.shape}")
    return moments


def planes_from_moments(moments: np.ndarray) -> PlaneTable:
    """Least-squares planes (Hesse form, ``d >= 0``) of every row of an (K, 10) moments array."""
    moments = _moment_rows(moments)
    centroid, normal, d, eigvals, frame, ok = kernels.planes_from_moment_rows(moments)
    return PlaneTable(count=moments[:, 0], centroid=centroid, normal=normal, d=d,
                      rms=np.sqrt(eigvals[:, 0]), eigvals=eigvals, frame=frame, ok=ok)


def plane_rms_from_moments(moments: np.ndarray) -> np.ndarray:
    """``planes_from_moments(moments).rms``, the rms distance of each row's least-squares
    plane, without building the table (for a few rows at a time, as the merge loop's one-union
    candidates, the table is a third of the cost)."""
    return np.sqrt(kernels.planes_from_moment_rows(_moment_rows(moments))[3][:, 0])


def quadric_gains(xyz_flat: np.ndarray, labels_flat: np.ndarray, planes: PlaneTable,
                  active: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(gain, roundness)`` per label of a quadratic height field over each plane.

    The batched form of :func:`rangeseg_o3d.fitting.classify.quadric_shape`: ``gain`` is
    plane rms / quadric rms (about 1 when flat, inf when the quadric is exact and the
    plane is not), ``roundness`` the ratio of the principal curvatures (0 cylinder, 1
    sphere). Rows not ``active`` (or whose equations are singular) get ``(1.0, 0.5)``.
    """
    active = np.asarray(active, bool) & planes.ok
    if not active.any():
        return np.ones(len(planes.count)), np.full(len(planes.count), 0.5)
    spread = np.sqrt(planes.eigvals[:, 1] + planes.eigvals[:, 2])
    inv_spread = 1.0 / np.where(spread > 0, spread, 1.0)
    sums = kernels.quadric_sums(np.ascontiguousarray(xyz_flat, dtype=np.float64),
                                np.ascontiguousarray(labels_flat, dtype=np.int32),
                                planes.centroid, np.ascontiguousarray(planes.frame[:, 1]),
                                np.ascontiguousarray(planes.frame[:, 2]), planes.normal, inv_spread, active)
    return kernels.quadric_shapes(sums, planes.count, active)
