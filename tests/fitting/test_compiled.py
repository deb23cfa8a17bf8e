"""The compiled pieces of the sphere and cylinder fits against their definitions."""

import numpy as np
import pytest

from rangeseg_o3d.fitting._compiled import circle_scores, cylinder_lm, sphere_lm
from rangeseg_o3d.kernels.linalg import solve, solve_in_place


def test_solve_matches_numpy_and_reports_singular_systems():
    rng = np.random.default_rng(0)
    for n in (1, 4, 5):
        a = rng.normal(size=(n, n))
        b = rng.normal(size=n)
        x, ok = solve(a, b)
        assert ok
        np.testing.assert_allclose(x, np.linalg.solve(a, b), rtol=1e-10, atol=1e-12)
    singular = np.array([[1.0, 2.0], [2.0, 4.0]])
    assert not solve(singular, np.ones(2))[1]


def test_solve_in_place_is_solve_bit_for_bit_in_the_arrays_given():
    rng = np.random.default_rng(2)
    for n in (1, 4, 5):
        a = rng.normal(size=(n, n))
        b = rng.normal(size=n)
        m, x = a.copy(), b.copy()
        assert solve_in_place(m, x, 0.0)
        expected, ok = solve(a, b, 0.0)
        assert ok and x.tobytes() == expected.tobytes()
        assert n == 1 or not np.array_equal(m, a)  # the elimination overwrote the matrix
    near = np.array([[1.0, 2.0], [1.0, 2.0 + 1e-13]])
    for rel_tol in (0.0, 1e-12):  # exactly or numerically singular: the same answer as solve
        assert solve_in_place(near.copy(), np.ones(2), rel_tol) == solve(near, np.ones(2), rel_tol)[1]
    assert not solve_in_place(np.array([[1.0, 2.0], [2.0, 4.0]]), np.ones(2), 0.0)


def test_lm_answers_are_their_own_arrays_across_calls():
    # the fits keep their model in work buffers: an answer is not changed by a later fit
    rng = np.random.default_rng(3)
    d = rng.normal(size=(100, 3))
    first = 0.5 * d / np.linalg.norm(d, axis=1, keepdims=True)
    center, radius, _ = sphere_lm(first, np.array([0.05, 0.0, 0.0]), 0.45, 50)
    kept = center.copy()
    sphere_lm(first + 1.0, np.array([1.05, 1.0, 1.0]), 0.45, 50)
    assert center.tobytes() == kept.tobytes()
    np.testing.assert_allclose(center, 0.0, atol=1e-9)
    t = rng.uniform(0, np.pi, 120)
    pts = np.stack([0.3 * np.cos(t), 0.3 * np.sin(t), rng.uniform(-1, 1, 120)], axis=1)
    axis, point, r, converged = cylinder_lm(pts, np.array([0.02, 0.01, 1.0]), np.zeros(3), 0.25, 50)
    kept = axis.copy(), point.copy()
    cylinder_lm(pts + 2.0, np.array([0.0, 0.03, 1.0]), np.full(3, 2.0), 0.25, 50)
    assert converged == 1 and axis.tobytes() == kept[0].tobytes() and point.tobytes() == kept[1].tobytes()
    assert abs(abs(axis[2]) - 1.0) < 1e-9 and r == pytest.approx(0.3, abs=1e-9)


def test_sphere_and_cylinder_lm_reach_the_exact_surfaces_from_a_rough_start():
    rng = np.random.default_rng(1)
    d = rng.normal(size=(200, 3))
    d[:, 2] = np.abs(d[:, 2])
    sphere = 0.5 * d / np.linalg.norm(d, axis=1, keepdims=True) + [0.1, -0.2, 0.3]
    center, radius, converged = sphere_lm(sphere, np.array([0.0, 0.0, 0.0]), 0.4, 50)
    assert converged
    np.testing.assert_allclose(center, [0.1, -0.2, 0.3], atol=1e-9)
    assert radius == pytest.approx(0.5, abs=1e-9)

    t = rng.uniform(0, np.pi, 300)
    axis = np.array([1.0, 1.0, 0.2]) / np.linalg.norm([1.0, 1.0, 0.2])
    u = np.cross(axis, [0, 0, 1.0])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    along = rng.uniform(-1, 1, 300)
    pts = 0.3 * (np.cos(t)[:, None] * u + np.sin(t)[:, None] * v) + along[:, None] * axis
    start = axis + [0.05, -0.03, 0.02]
    got_axis, point, r, converged = cylinder_lm(pts, start, np.array([0.02, 0.0, 0.01]), 0.25, 50)
    assert converged and r == pytest.approx(0.3, abs=1e-9)
    assert abs(abs(got_axis @ axis) - 1) < 1e-12
    assert np.linalg.norm(point - (point @ axis) * axis) < 1e-9  # the axis through the origin
    assert abs(point @ got_axis) < 1e-9  # kept nearest the origin of the points


def test_circle_scores_are_zero_along_the_axis_of_an_exact_cylinder():
    t = np.linspace(0, 2 * np.pi, 64, endpoint=False)
    pts = np.stack([0.5 * np.cos(t), 0.5 * np.sin(t), np.tile([-1.0, 1.0], 32)], axis=1)
    pts -= pts.mean(axis=0)
    x, y, z = pts.T
    quad = np.stack([x * x, y * y, z * z, x * y, x * z, y * z], axis=1)
    dirs = np.array([[0, 0, 1.0], [1.0, 0, 0]])
    u = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    v = np.array([[0, 1.0, 0], [0, 0, 1.0]])
    w = dirs
    s = np.stack([1 - w[:, 0] ** 2, 1 - w[:, 1] ** 2, 1 - w[:, 2] ** 2,
                  -2 * w[:, 0] * w[:, 1], -2 * w[:, 0] * w[:, 2], -2 * w[:, 1] * w[:, 2]], axis=1)
    score, cx, cy, rsq = circle_scores(64.0, pts.T @ pts, pts.T @ quad, quad.T @ quad, dirs, u, v, s)
    assert score[0] == pytest.approx(0.0, abs=1e-12) and rsq[0] == pytest.approx(0.25)
    assert abs(cx[0]) < 1e-12 and abs(cy[0]) < 1e-12
    assert score[1] > 1e-3  # across the axis the projection is a rectangle, not a circle


def test_lm_gives_up_only_when_creeping_far_above_the_bound():
    # Two perpendicular planes: no sphere explains them; LM creeps towards a huge radius.
    rng = np.random.default_rng(2)
    u = rng.uniform(0, 1, (400, 2))
    left = u[:, 0] < 0.5
    crease = np.where(left[:, None], np.c_[u[:, 0], u[:, 1], np.zeros(400)],
                      np.c_[np.full(400, 0.5), u[:, 1], u[:, 0] - 0.5]) - 0.5
    start = np.array([0.0, 0.0, -0.5])
    _, _, converged = sphere_lm(crease, start, 0.6, 30, 0.01)
    assert converged == -1
    _, _, without = sphere_lm(crease, start, 0.6, 30)  # no bound: it never gives up
    assert without in (0, 1)
    # an exact sphere converges whatever the bound
    d = rng.normal(size=(200, 3))
    sphere = 0.5 * d / np.linalg.norm(d, axis=1, keepdims=True)
    assert sphere_lm(sphere, np.array([0.05, 0.0, 0.0]), 0.45, 50, 1e-6)[2] == 1


def test_a_refused_refinement_skips_the_arc_and_a_converged_one_has_it():
    from rangeseg_o3d.fitting._compiled import cylinder_refine, sphere_refine

    t = np.linspace(0.0, np.pi, 120)
    along = np.tile(np.linspace(-0.5, 0.5, 6), 20)
    arc = np.stack([0.3 * np.cos(t), 0.3 * np.sin(t), along], axis=1)
    axis, point = np.array([0.0, 0.0, 1.0]), np.zeros(3)
    *_, converged, rms, got_arc, inliers = cylinder_refine(arc, axis, point, 0.29, 30, 0.01)
    assert converged == 1 and rms < 1e-9 and inliers == 120
    assert got_arc == pytest.approx(np.pi, rel=1e-9)  # a half circle: the gap is the other half
    # a union of the arc and a far wall: Levenberg-Marquardt gives up (converged -1), the row's
    # arc is NaN (never judged for a refused model), its rms is still measured
    wall = np.stack([np.full(60, 3.0), np.linspace(-1, 1, 60), np.tile([-0.5, 0.5], 30)], axis=1)
    both = np.concatenate([arc, wall])
    *_, converged, rms, got_arc, _ = cylinder_refine(both, axis, point, 0.3, 30, 0.01, 0.001)
    assert converged == -1 and np.isnan(got_arc) and rms > 0.1
    ball = np.stack([np.cos(t) * 0.5, np.sin(t) * 0.5, np.zeros_like(t)], axis=1)
    ok, _, _, converged, _, cap, _ = sphere_refine(np.concatenate([ball, wall]), np.zeros(3), 0.5, 30, 0.01,
                                                   0.0001)
    assert ok and converged == -1 and np.isnan(cap)
    ok, _, _, converged, _, cap, _ = sphere_refine(ball + [0.0, 0.0, 1e-3], np.zeros(3), 0.5, 30, 0.01)
    assert ok and converged == 1 and np.isfinite(cap)
