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

from ._common import DEGENERATE_RATIO

__all__ = ["PlaneTable", "planes_from_moments", "region_moments", "quadric_gains"]


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


def region_moments(xyz_flat: np.ndarray, labels_flat: np.ndarray, n: int | None = None) -> np.ndarray:
    """(n, 10) moments (count, sums, sums of products) of the points of each label 1..n-1."""
    from ..kernels import label_moments

    labels_flat = np.ascontiguousarray(labels_flat, dtype=np.int32)
    if n is None:
        n = int(labels_flat.max(initial=0)) + 1
    return label_moments(np.ascontiguousarray(xyz_flat, dtype=np.float64), labels_flat, int(n))


def planes_from_moments(moments: np.ndarray) -> PlaneTable:
    """Least-squares planes (Hesse form, ``d >= 0``) of every row of an (K, 10) moments array."""
    moments = np.asarray(moments, dtype=np.float64)
    if moments.ndim != 2 or moments.shape[1] != 10:
        raise ValueError(f"moments must have shape (K, 10); got {moments.shape}")
    count = moments[:, 0]
    safe = np.maximum(count, 1.0)
    centroid = moments[:, 1:4] / safe[:, None]
    sxx, sxy, sxz, syy, syz, szz = (moments[:, i] / safe for i in range(4, 10))
    cx, cy, cz = centroid.T
    cov = np.empty((len(moments), 3, 3))
    cov[:, 0, 0] = sxx - cx * cx
    cov[:, 0, 1] = cov[:, 1, 0] = sxy - cx * cy
    cov[:, 0, 2] = cov[:, 2, 0] = sxz - cx * cz
    cov[:, 1, 1] = syy - cy * cy
    cov[:, 1, 2] = cov[:, 2, 1] = syz - cy * cz
    cov[:, 2, 2] = szz - cz * cz
    eigvals, eigvecs = np.linalg.eigh(cov)
    eigvals = np.maximum(eigvals, 0.0)
    normal = eigvecs[:, :, 0]
    d = np.einsum("ij,ij->i", normal, centroid)
    # Hesse form as fit_plane's orient_normal: d >= 0; through the origin, the largest
    # normal component positive.
    scale = np.abs(centroid).max(axis=1) + np.sqrt(eigvals.sum(axis=1))
    through = np.abs(d) <= 1e-12 * np.maximum(scale, 1e-300)
    largest = normal[np.arange(len(normal)), np.argmax(np.abs(normal), axis=1)]
    flip = np.where(through, largest < 0, d < 0)
    normal = np.where(flip[:, None], -normal, normal)
    d = np.where(through, 0.0, np.abs(d))
    ok = (count >= 3) & (eigvals[:, 2] > 0) & (eigvals[:, 1] > DEGENERATE_RATIO**2 * eigvals[:, 2])
    frame = np.swapaxes(eigvecs, 1, 2).copy()
    frame[:, 0] = normal
    return PlaneTable(count=count, centroid=centroid, normal=normal, d=d,
                      rms=np.sqrt(eigvals[:, 0]), eigvals=eigvals, frame=frame, ok=ok)


def quadric_gains(xyz_flat: np.ndarray, labels_flat: np.ndarray, planes: PlaneTable,
                  active: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(gain, roundness)`` per label of a quadratic height field over each plane.

    The batched form of :func:`rangeseg_o3d.fitting.classify.quadric_shape`: ``gain`` is
    plane rms / quadric rms (about 1 when flat, inf when the quadric is exact and the
    plane is not), ``roundness`` the ratio of the principal curvatures (0 cylinder, 1
    sphere). Rows not ``active`` (or whose equations are singular) get ``(1.0, 0.5)``.
    """
    from ..kernels import quadric_sums

    k = len(planes.count)
    gain = np.ones(k)
    roundness = np.full(k, 0.5)
    active = np.asarray(active, bool) & planes.ok
    if not active.any():
        return gain, roundness
    spread = np.sqrt(planes.eigvals[:, 1] + planes.eigvals[:, 2])
    inv_spread = np.where(spread > 0, 1.0 / np.where(spread > 0, spread, 1.0), 1.0)
    sums = quadric_sums(np.ascontiguousarray(xyz_flat, dtype=np.float64),
                        np.ascontiguousarray(labels_flat, dtype=np.int32),
                        planes.centroid, np.ascontiguousarray(planes.frame[:, 1]),
                        np.ascontiguousarray(planes.frame[:, 2]), planes.normal, inv_spread, active)
    rows = np.flatnonzero(active)
    ata = np.zeros((rows.size, 6, 6))
    iu = np.triu_indices(6)
    ata[:, iu[0], iu[1]] = sums[rows, :21]
    ata[:, iu[1], iu[0]] = sums[rows, :21]
    atb = sums[rows, 21:27]
    hh = sums[rows, 27]
    n = planes.count[rows]
    # points on a conic (a single row of a scan) leave no quadric height field to compare
    solvable = np.linalg.cond(ata) < 1e12
    coef = np.zeros((rows.size, 6))
    if solvable.any():
        coef[solvable] = np.linalg.solve(ata[solvable], atb[solvable][..., None])[..., 0]
    # ||h - A c||^2 = h.h - 2 c.A^T h + c^T A^T A c
    quad_ss = hh - 2 * np.einsum("ij,ij->i", coef, atb) + np.einsum("ij,ijk,ik->i", coef, ata, coef)
    quad_ms = np.maximum(quad_ss, 0.0) / n
    plane_ms = hh / n
    with np.errstate(divide="ignore", invalid="ignore"):
        g = np.where(quad_ms > 0, np.sqrt(plane_ms / quad_ms), np.where(plane_ms > 0, np.inf, 1.0))
    a, b, c = coef[:, 0], coef[:, 1], coef[:, 2]
    # eigenvalues of [[2a, b], [b, 2c]]
    mean, diff = a + c, np.sqrt((a - c) ** 2 + b * b)
    k1, k2 = np.abs(mean + diff), np.abs(mean - diff)
    big, small = np.maximum(k1, k2), np.minimum(k1, k2)
    with np.errstate(divide="ignore", invalid="ignore"):
        rnd = np.where(big > 0, small / big, 0.5)
    gain[rows] = np.where(solvable, g, 1.0)
    roundness[rows] = np.where(solvable, rnd, 0.5)
    return gain, roundness
