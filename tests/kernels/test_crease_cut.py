"""rangeseg_o3d.kernels.crease_cut (crease_planes._crease_cut in one compiled pass) against
the numpy form it replaced (_crease_cut_numpy below): the same cut, the same values
within their rounding (sums added point after point, Newton's smallest eigenvalues,
against numpy's pairwise sums and LAPACK)."""

import numpy as np
import pytest

import rangeseg_o3d.crease_planes as cp
from rangeseg_o3d.fitting.primitives import Cylinder


def _box_corner(seed, n=900, noise=1e-3, bend_deg=90.0):
    # two faces meeting at a crease along the z axis (bend_deg between them), seen as a
    # cylinder of radius 0.3 whose axis runs along the crease 0.3 behind it
    rng = np.random.default_rng(seed)
    half = np.radians(bend_deg) / 2
    t = rng.uniform(0.0, 0.4, n)
    z = rng.uniform(-0.2, 0.2, n)
    side = rng.random(n) < 0.5
    direction = np.where(side[:, None], [np.cos(half), np.sin(half)], [np.cos(half), -np.sin(half)])
    xy = direction * t[:, None]
    points = np.column_stack([xy, z]) + rng.normal(0.0, noise, (n, 3))
    cylinder = Cylinder(np.array([0.0, 0.0, 1.0]), np.array([-0.3, 0.0, 0.0]), 0.45, rms=0.0, inliers=n)
    return points, cylinder


def _true_cylinder(seed, n=700, noise=1e-3):
    rng = np.random.default_rng(seed)
    angle = rng.uniform(-1.0, 1.0, n)
    z = rng.uniform(-0.3, 0.3, n)
    r = 0.2 + rng.normal(0.0, noise, n)
    axis = np.array([0.1, 0.2, 1.0]) / np.linalg.norm([0.1, 0.2, 1.0])
    e1 = np.cross(axis, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    point = np.array([0.5, -0.2, 3.0])
    points = point + np.outer(r * np.cos(angle), e1) + np.outer(r * np.sin(angle), e2) + np.outer(z, axis)
    return points, Cylinder(axis, point, 0.2, rms=0.0, inliers=n)


@pytest.mark.parametrize("seed", range(5))
def test_crease_cut_compiled_agrees_with_numpy_at_a_box_corner(seed):
    from rangeseg_o3d.crease_planes import _crease_cut

    rng = np.random.default_rng(seed)
    points, cylinder = _box_corner(seed, n=int(rng.integers(200, 1500)), bend_deg=float(rng.uniform(60, 150)))
    got, want = _crease_cut(points, cylinder, 20), _crease_cut_numpy(points, cylinder, 20)
    assert got is not None and want is not None
    angle, reference, rms, by_factor = got
    assert angle == pytest.approx(want[0], abs=1e-12)
    assert np.allclose(reference, want[1], rtol=0, atol=1e-14)
    assert rms == pytest.approx(want[2], rel=1e-9)
    assert by_factor == want[3]
    # values: the cut lies at the crease (the reference points between the two faces, along
    # +x: angle ~0), the two planes fit within a few noises, the cylinder far worse
    assert abs(angle) < 0.05
    assert np.allclose(reference, [1.0, 0.0, 0.0], atol=0.05)
    assert 0.5e-3 < rms < 2e-3 and by_factor
    # each side of the cut is one face
    far = np.arctan2(points @ np.cross([0.0, 0.0, 1.0], reference), (points + [0.3, 0.0, 0.0]) @ reference) > angle
    assert (far == (points[:, 1] > 0)).mean() > 0.98 or (far == (points[:, 1] < 0)).mean() > 0.98


@pytest.mark.parametrize("seed", range(3))
def test_crease_cut_of_a_true_cylinder_is_not_by_the_factor(seed):
    from rangeseg_o3d.crease_planes import _crease_cut

    points, cylinder = _true_cylinder(seed)
    got, want = _crease_cut(points, cylinder, 20), _crease_cut_numpy(points, cylinder, 20)
    assert (got is None) == (want is None)
    if got is not None:
        assert got[0] == pytest.approx(want[0], abs=1e-12)
        assert got[2] == pytest.approx(want[2], rel=1e-9)
        assert not got[3] and not want[3]


def test_crease_cut_too_few_points_or_no_reference():
    from rangeseg_o3d.crease_planes import _crease_cut

    points, cylinder = _box_corner(0, n=100)
    assert _crease_cut(points, cylinder, 60) is None and _crease_cut_numpy(points, cylinder, 60) is None
    # points all on the axis: no offset from it, no reference direction
    on_axis = np.column_stack([np.full(50, -0.3), np.zeros(50), np.linspace(-1, 1, 50)])
    assert _crease_cut(on_axis, cylinder, 5) is None and _crease_cut_numpy(on_axis, cylinder, 5) is None


def _crease_cut_numpy(points: np.ndarray, cylinder, min_side: int):
    """crease_planes._crease_cut in numpy: the form its compiled pass replaced, kept here as its reference."""
    n = len(points)
    if n < 2 * min_side:
        return None
    # the offsets from the axis once: the angles and the cylinder's distances reuse them
    radial = cp._radial(points, cylinder)
    reference = radial.mean(axis=0)
    if not np.linalg.norm(reference) > 0:
        return None
    reference /= np.linalg.norm(reference)
    angles = cp._radial_angles(radial, cylinder, reference)
    order = np.argsort(angles)
    ordered = points[order] - points.mean(axis=0)
    # every cut's two sides' scatter matrices from cumulative moments (one sort, no refits)
    firsts = np.cumsum(ordered, axis=0)
    seconds = np.cumsum(ordered[:, :, None] * ordered[:, None, :], axis=0)
    # each side cp.CREASE_SIDE_SHARE of the pixels too: a strip along the axis is a line,
    # which any plane through it fits
    side = max(min_side, int(np.ceil(cp.CREASE_SIDE_SHARE * n)))
    if n < 2 * side:
        return None
    sizes = np.unique(np.linspace(side, n - side, cp.CREASE_CUTS).astype(np.int64))
    # both sides of every cut in one call (each scatter matrix's eigenvalues are its own)
    both = _least_squares(np.concatenate([firsts[sizes - 1], firsts[-1] - firsts[sizes - 1]]),
                          np.concatenate([seconds[sizes - 1], seconds[-1] - seconds[sizes - 1]]),
                          np.concatenate([sizes, n - sizes]))
    left, right = both[:sizes.size], both[sizes.size:]
    best = int(np.argmin(left + right))
    planes_squares = max(float(left[best] + right[best]), 0.0)
    cylinder_squares = float(np.sum((np.linalg.norm(radial, axis=1) - cylinder.radius) ** 2))  # its distances
    if not cylinder_squares > planes_squares:
        return None
    size = int(sizes[best])
    return (0.5 * float(angles[order[size - 1]] + angles[order[size]]), reference, np.sqrt(planes_squares / n),
            bool(cylinder_squares > cp.CREASE_RMS_FACTOR ** 2 * planes_squares))


def _least_squares(firsts: np.ndarray, seconds: np.ndarray, counts: np.ndarray) -> np.ndarray:
    # the least-squares plane's sum of squared distances of each set of points, from their
    # sums and sums of outer products: the smallest eigenvalue of their scatter matrix
    counts = counts.astype(np.float64)
    scatter = seconds - firsts[:, :, None] * firsts[:, None, :] / counts[:, None, None]
    return np.linalg.eigvalsh(scatter)[:, 0]
