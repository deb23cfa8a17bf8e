"""kernels.claim_limbs (the compiled ring claim of claim_grazing_limbs) against a plain-Python
reference of the numpy form's meaning: per ring, each curved region in order takes the free
valid pixels 4-adjacent to it that its model explains within k_sigma x sigma x |cos|."""

import math

import numpy as np
import pytest

from rangeseg_o3d.kernels import claim_limbs
from rangeseg_o3d.kernels.kinds import CYLINDER, PARAM_SLOTS, SPHERE


def _joins(kind, prm, point, origin, bound_sigma):
    # the limb test of one pixel, in plain Python (scalar math, the primitives' formulas)
    x, y, z = point
    rx, ry, rz = x - origin[0], y - origin[1], z - origin[2]
    length = max(math.sqrt(rx * rx + ry * ry + rz * rz), 1e-12)
    ux, uy, uz = rx / length, ry / length, rz / length
    if kind == CYLINDER:
        dx, dy, dz = x - prm[3], y - prm[4], z - prm[5]
        along = dx * prm[0] + dy * prm[1] + dz * prm[2]
        nx, ny, nz = dx - along * prm[0], dy - along * prm[1], dz - along * prm[2]
        radius = prm[6]
    else:
        nx, ny, nz = x - prm[0], y - prm[1], z - prm[2]
        radius = prm[3]
    norm = math.sqrt(nx * nx + ny * ny + nz * nz)
    cosine = abs((nx / norm) * ux + (ny / norm) * uy + (nz / norm) * uz) if norm > 0 else 0.0
    return abs(norm - radius) <= bound_sigma * cosine


def _reference(labels, valid, xyz, sigma, origins, order, kinds, params, k_sigma, rings):
    # the numpy form's loop (refinement.recover._claim_grazing_limbs_numpy), pixel by pixel
    out = labels.copy()
    h, w = labels.shape
    active = list(range(len(order)))
    for _ in range(rings):
        grew = []
        for t in active:
            k = order[t]
            beside = [(r, c) for r in range(h) for c in range(w)
                      if out[r, c] == 0 and valid[r, c]
                      and any(0 <= r + dr < h and 0 <= c + dc < w and out[r + dr, c + dc] == k
                              for dr, dc in ((-1, 0), (1, 0), (0, -1), (0, 1)))]
            took = [(r, c) for r, c in beside
                    if _joins(kinds[t], params[t], xyz[r * w + c], origins[r], k_sigma * sigma[r * w + c])]
            for r, c in took:
                out[r, c] = k
            if took:
                grew.append(t)
        active = grew
        if not active:
            break
    return out


def _scene(seed, h=9, w=12):
    # two cylinders and a sphere (labels 2, 5, 3, claiming in the order 5, 2, 3), plane label 1,
    # free pixels between them; points near each label's surface (or a random one's for free
    # pixels) by 0-3 range sigmas along their rays, so that the tests go both ways
    rng = np.random.default_rng(seed)
    labels = rng.choice(np.array([0, 0, 0, 1, 2, 3, 5], np.int32), size=(h, w))
    valid = rng.random((h, w)) > 0.1
    origins = rng.normal(0.0, 0.05, (h, 3))
    order = np.array([5, 2, 3], np.int64)
    kinds = np.array([CYLINDER, CYLINDER, SPHERE], np.int64)
    params = np.zeros((3, PARAM_SLOTS))
    a = rng.normal(size=3)
    params[0, :7] = [*(a / np.linalg.norm(a)), 0.1, 0.2, 3.0, 0.3]
    params[1, :7] = [0.0, 1.0, 0.0, -0.2, 0.0, 2.5, 0.2]
    params[2, :4] = [0.3, -0.1, 2.8, 0.25]
    sigma = rng.uniform(0.005, 0.02, h * w)
    xyz = np.empty((h * w, 3))
    for i in range(h * w):
        t = rng.integers(3)
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        if kinds[t] == CYLINDER:
            axis, point, radius = params[t, :3], params[t, 3:6], params[t, 6]
            direction -= (direction @ axis) * axis
            direction /= np.linalg.norm(direction)
            surface = point + rng.uniform(-0.3, 0.3) * axis + radius * direction
        else:
            surface = params[t, :3] + params[t, 3] * direction
        ray = surface - origins[i // w]
        ray /= np.linalg.norm(ray)
        xyz[i] = surface + rng.uniform(-3.0, 3.0) * sigma[i] * ray
    return labels, valid, xyz, sigma, origins, order, kinds, params


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("rings", [1, 3])
def test_claim_limbs_matches_the_plain_python_rings(seed, rings):
    labels, valid, xyz, sigma, origins, order, kinds, params = _scene(seed)
    out, unsure = claim_limbs(labels, valid, xyz, sigma, origins, order, kinds, params, 3.0, rings, 1e-12)
    expected = _reference(labels, valid, xyz, sigma, origins, order, kinds, params, 3.0, rings)
    assert not unsure
    assert np.array_equal(out, expected)
    assert out.dtype == labels.dtype
    changed = out != labels
    assert (labels[changed] == 0).all() and valid[changed].all()  # free valid pixels only
    assert set(np.unique(out[changed]).tolist()) <= {2, 3, 5}  # to curved regions only


def test_claim_limbs_rings_and_order_on_a_strip():
    # one row: region 7 (a sphere of radius 1 about the origin... seen from 2 m away along z)
    # at column 0, free pixels after it all on the sphere: ring r takes column r only; a pixel
    # beside two regions goes to the first in ``order`` that explains it
    w = 6
    labels = np.array([[7, 0, 0, 0, 0, 0]], np.int32)
    valid = np.ones((1, w), bool)
    origins = np.array([[0.0, 0.0, -2.0]])
    angles = np.radians(np.arange(w) * 5.0)
    xyz = np.stack([np.sin(angles), np.zeros(w), -np.cos(angles)], axis=1)  # on the unit sphere, facing the origin
    sigma = np.full(w, 0.01)
    order = np.array([7], np.int64)
    kinds = np.array([SPHERE], np.int64)
    params = np.zeros((1, PARAM_SLOTS))
    params[0, 3] = 1.0
    for rings, taken in [(1, 2), (2, 3), (3, 4), (10, 6)]:
        out, unsure = claim_limbs(labels, valid, xyz, sigma, origins, order, kinds, params, 3.0, rings, 1e-12)
        assert not unsure
        assert out[0].tolist() == [7] * taken + [0] * (w - taken)
    # an invalid pixel stops the rings; a pixel off the sphere by 4 sigma along its ray stays free
    valid2 = valid.copy()
    valid2[0, 3] = False
    out, _ = claim_limbs(labels, valid2, xyz, sigma, origins, order, kinds, params, 3.0, 10, 1e-12)
    assert out[0].tolist() == [7, 7, 7, 0, 0, 0]
    far = xyz.copy()
    ray = far[2] - origins[0]
    far[2] += 0.04 * ray / np.linalg.norm(ray)
    out, _ = claim_limbs(labels, valid, far, sigma, origins, order, kinds, params, 3.0, 10, 1e-12)
    assert out[0].tolist() == [7, 7, 0, 0, 0, 0]
    # two spheres both explaining the pixel between them: the first in order takes it
    two = np.array([[7, 0, 9]], np.int32)
    both = np.zeros((2, PARAM_SLOTS))
    both[:, 3] = 1.0
    for first in (7, 9):
        order2 = np.array([first, 16 - first], np.int64)
        out, _ = claim_limbs(two, np.ones((1, 3), bool), xyz[:3], sigma[:3], origins, order2,
                             np.array([SPHERE, SPHERE], np.int64), both, 3.0, 3, 1e-12)
        assert out[0].tolist() == [7, first, 9]


def test_claim_limbs_flags_a_test_within_rounding_of_its_bound():
    # a distance exactly at its bound is unsure (numpy's rounding could answer either way)
    labels = np.array([[4, 0]], np.int32)
    origins = np.zeros((1, 3))
    xyz = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.03]])  # head-on: cos 1, distance 0.03
    params = np.zeros((1, PARAM_SLOTS))
    params[0, 3] = 1.0
    args = (labels, np.ones((1, 2), bool), xyz)
    out, unsure = claim_limbs(*args, np.array([0.01, 0.01]), origins, np.array([4], np.int64),
                              np.array([SPHERE], np.int64), params, 3.0, 3, 1e-12)
    assert unsure
    out, unsure = claim_limbs(*args, np.array([0.011, 0.011]), origins, np.array([4], np.int64),
                              np.array([SPHERE], np.int64), params, 3.0, 3, 1e-12)
    assert not unsure and out[0].tolist() == [4, 4]
