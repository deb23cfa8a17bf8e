"""The merge's pair filters in Python floats give numpy's answers: planes_into_curved's
turned-planes filter and the adjacency carried through a merge's look-up."""

import numpy as np
import pytest

from rangeseg_o3d.fitting.primitives import Cylinder, Plane
from rangeseg_o3d.refinement.context import SCREEN_SLACK
from rangeseg_o3d.refinement.merge import (_beyond_from_origin, _convex_pairs, _mapped_adjacency,
                                          _turned_plane_pairs)

MAX_ANGLE_DEG = 12.0
TURNED = float(np.cos(np.radians(MAX_ANGLE_DEG)))


def _numpy_turned_pairs(fits, adjacency, turned):
    # the filter's numpy form (planes_into_curved before the Python-float screen)
    return [(a, b) for a, b in adjacency
            if isinstance(fits.get(a), Plane) and isinstance(fits.get(b), Plane)
            and abs(float(fits[a].normal @ fits[b].normal)) < turned]


def _rotated(normal, angle_deg, rng):
    # ``normal`` turned by ``angle_deg`` about a random axis across it
    across = np.cross(normal, rng.normal(size=3))
    across /= np.linalg.norm(across)
    angle = np.radians(angle_deg)
    return np.cos(angle) * normal + np.sin(angle) * across


def _scene(rng, labels=40, scale=1.0):
    """Models by label (planes, a few at the angle limit or a rounding off it, a few
    cylinders, one plane with a NaN normal, some labels with no model) and every pair of
    labels as the adjacency."""
    fits, base = {}, None
    for k in range(1, labels + 1):
        draw = rng.random()
        if draw < 0.1:
            continue  # a label without a model
        if draw < 0.2:
            fits[k] = Cylinder(axis=rng.normal(size=3), point=rng.normal(size=3), radius=0.1, rms=0.01, inliers=50)
            continue
        if base is None or draw < 0.4:
            base = rng.normal(size=3)
            base /= np.linalg.norm(base)
            normal = base
        elif draw < 0.7:  # at the limit, within a rounding or a margin of it
            normal = _rotated(base, MAX_ANGLE_DEG + rng.choice([0.0, 1e-13, -1e-13, 1e-8, -1e-8]), rng)
        else:
            normal = _rotated(base, rng.uniform(0.0, 30.0), rng)
        if draw > 0.97:
            normal = np.array([np.nan, 0.0, 1.0])
        fits[k] = Plane(normal=scale * normal, d=1.0, rms=0.01, inliers=50)
    adjacency = {(a, b) for a in range(1, labels + 1) for b in range(a + 1, labels + 1)}
    return fits, adjacency


@pytest.mark.parametrize("seed", range(12))
@pytest.mark.parametrize("scale", [1.0, 1.0 + 1e-12, 3.0])
def test_turned_plane_pairs_are_numpys_on_many_scenes(seed, scale):
    rng = np.random.default_rng(seed)
    fits, adjacency = _scene(rng, scale=scale)
    expected = _numpy_turned_pairs(fits, adjacency, TURNED * scale * scale)
    assert _turned_plane_pairs(fits, adjacency, TURNED * scale * scale) == expected
    assert expected  # the scenes hold turned pairs, and pairs that are not
    assert len(expected) < sum(isinstance(fits.get(a), Plane) and isinstance(fits.get(b), Plane)
                               for a, b in adjacency)


def test_turned_plane_pairs_near_the_limit_are_asked_of_numpy():
    # pairs whose Python sum lies within the margin of the limit: numpy's product decides,
    # on either side of it
    rng = np.random.default_rng(5)
    near, both_sides = 0, set()
    for _ in range(200):
        fits, adjacency = _scene(rng, labels=12)
        for a, b in adjacency:
            if isinstance(fits.get(a), Plane) and isinstance(fits.get(b), Plane):
                u, v = fits[a].normal.tolist(), fits[b].normal.tolist()
                dot = abs(u[0] * v[0] + u[1] * v[1] + u[2] * v[2])
                if abs(dot - TURNED) <= SCREEN_SLACK:
                    near += 1
                    both_sides.add(bool(abs(float(fits[a].normal @ fits[b].normal)) < TURNED))
        assert _turned_plane_pairs(fits, adjacency, TURNED) == _numpy_turned_pairs(fits, adjacency, TURNED)
    assert near > 20 and both_sides == {True, False}


def test_turned_plane_pairs_of_no_planes_or_no_pairs_are_none():
    plane = Plane(normal=[0.0, 0.0, 1.0], d=1.0, rms=0.01, inliers=10)
    turned = Plane(normal=[0.0, 1.0, 0.0], d=1.0, rms=0.01, inliers=10)
    assert _turned_plane_pairs({1: plane, 2: turned}, set(), TURNED) == []
    assert _turned_plane_pairs({1: plane}, {(1, 2)}, TURNED) == []
    assert _turned_plane_pairs({1: plane, 2: turned}, {(1, 2)}, TURNED) == [(1, 2)]
    assert _turned_plane_pairs({1: plane, 2: plane}, {(1, 2)}, TURNED) == []


def _numpy_mapped(adjacency, lut):
    # the merge's adjacency after a look-up, as the steps computed it before
    mapped = ((int(lut[a]), int(lut[b])) for a, b in adjacency)
    return {(min(a, b), max(a, b)) for a, b in mapped if a != b}


@pytest.mark.parametrize("seed", range(20))
def test_mapped_adjacency_is_the_look_ups_pairs(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 60))
    pairs = rng.integers(1, n, size=(int(rng.integers(0, 200)), 2))
    adjacency = {(int(a), int(b)) for a, b in pairs if a != b}
    if seed % 2:  # either order of a pair, as a caller may give
        adjacency = {(a, b) if a < b else (b, a) for a, b in adjacency}
    lut = np.arange(n, dtype=np.int32)
    for _ in range(int(rng.integers(0, n))):  # unions: a label goes to another's root
        a, b = rng.integers(1, n, size=2)
        lut[lut == lut[b]] = lut[a]
    out = _mapped_adjacency(adjacency, lut)
    assert out == _numpy_mapped(adjacency, lut)
    assert all(type(a) is int and type(b) is int and a < b for a, b in out)


def test_mapped_adjacency_of_the_identity_keeps_the_pairs_ordered():
    lut = np.arange(6, dtype=np.int32)
    assert _mapped_adjacency({(1, 2), (4, 3), (5, 5)}, lut) == {(1, 2), (3, 4)}
    assert _mapped_adjacency(set(), lut) == set()


def _convex(first, second, first_centre, second_centre):
    # the convexity test in numpy (planes_into_curved's before the Python-float sums): each
    # region's centre beyond the other's plane, away from the origin
    return _beyond_from_origin(first, second_centre) and _beyond_from_origin(second, first_centre)


def _convex_scene(rng, labels=30):
    """Planes and region centres: random ones, centres on another's plane (a side of 0 or a
    rounding), planes through the origin, a NaN centre, and labels with no centre."""
    fits, centres = {}, {}
    for k in range(1, labels + 1):
        normal = rng.normal(size=3)
        normal /= np.linalg.norm(normal)
        d = 0.0 if rng.random() < 0.1 else float(rng.uniform(-3.0, 3.0))
        fits[k] = Plane(normal=normal, d=d, rms=0.01, inliers=50)
        draw = rng.random()
        if draw < 0.1:
            continue  # no pixels: no centre
        centre = rng.normal(size=3) * 3.0
        if draw < 0.5 and k > 1:  # on the previous plane, to its rounding
            other = fits[k - 1]
            centre = centre - (centre @ other.normal - other.d) * other.normal
            centre = centre + rng.choice([0.0, 1e-15, -1e-15, 1e-10]) * other.normal
        if draw > 0.95:
            centre = np.array([np.nan, 1.0, 1.0])
        centres[k] = centre
    pairs = [(a, b) for a in range(1, labels + 1) for b in range(a + 1, labels + 1)]
    rng.shuffle(pairs)
    return fits, centres, [tuple(map(int, pair)) for pair in pairs]


@pytest.mark.parametrize("seed", range(15))
def test_convex_pairs_are_the_numpy_tests_on_many_scenes(seed):
    rng = np.random.default_rng(seed)
    fits, centres, pairs = _convex_scene(rng)
    expected = [(a, b) for a, b in pairs if a in centres and b in centres
                and _convex(fits[a], fits[b], centres[a], centres[b])]
    assert _convex_pairs(fits, centres, pairs) == expected
    assert 0 < len(expected) < len(pairs)


def test_convex_pairs_leave_a_side_within_the_rounding_to_numpy():
    # a centre on the other's plane: the Python side is within the margin, numpy decides
    normal = np.array([0.6, 0.0, 0.8])
    plane = Plane(normal=normal, d=2.0, rms=0.01, inliers=50)
    other = Plane(normal=[0.0, 1.0, 0.0], d=1.0, rms=0.01, inliers=50)
    on_plane = np.array([1.0, 5.0, 1.75])  # 0.6 + 1.4 = 2.0
    beyond = np.array([0.0, 2.0, 4.0])  # side 1.2 > 0, and beyond the other's plane
    side = float(normal @ on_plane - 2.0)
    assert abs(side) <= SCREEN_SLACK * 4.0
    fits = {1: plane, 2: other}
    for centre in (on_plane, on_plane + 1e-15, on_plane - 1e-15):
        centres = {1: beyond, 2: centre}
        assert _convex_pairs(fits, centres, [(1, 2)]) == ([(1, 2)] if _convex(plane, other, beyond, centre) else [])
    assert _convex_pairs(fits, {1: np.array([0.0, 0.5, 0.0]), 2: beyond}, [(1, 2)]) == []
