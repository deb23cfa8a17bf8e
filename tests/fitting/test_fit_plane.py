import numpy as np
import pytest

from rangeseg_o3d.fitting import FitFailure, Plane, fit_plane


@pytest.mark.parametrize(
    "normal, d",
    [((0, 0, 1), 2.0), ((1, 0, 0), 0.5), ((0, 1, 0), 3.0), ((1, -2, 0.5), 1.7), ((-1, -1, -1), 4.0)],
)
def test_recovers_noise_free_plane_exactly(synth, normal, d):
    rng = np.random.default_rng(0)
    pts = synth.plane(rng, normal, d)
    plane = fit_plane(pts)
    true_n = np.asarray(normal, float) / np.linalg.norm(normal)
    # noise-free points: what is left is rounding at the coordinates' scale
    tolerance = 1000 * np.finfo(float).eps * np.abs(pts).max()
    # Hesse form: d >= 0, so the normal may be the negated truth only if d was negative
    assert isinstance(plane, Plane)
    assert plane.d >= 0
    assert np.allclose(plane.normal * np.sign(plane.normal @ true_n), true_n, rtol=0, atol=tolerance)
    assert plane.d == pytest.approx(d, abs=tolerance)
    assert plane.rms < tolerance
    assert plane.inliers == len(pts)


def test_noisy_plane_within_tolerance(synth):
    rng = np.random.default_rng(1)
    pts = synth.plane(rng, (0.2, 0.3, 1.0), 2.5, n=500, size=1.0, noise=0.005)
    plane = fit_plane(pts)
    true_n = np.array([0.2, 0.3, 1.0]) / np.linalg.norm([0.2, 0.3, 1.0])
    # normal error ~ noise / (extent * sqrt(N)); 0.1 deg is a wide margin
    assert synth.angle_deg(plane.normal, true_n) < 0.1
    assert plane.d == pytest.approx(2.5, abs=0.002)
    assert plane.rms == pytest.approx(0.005, rel=0.15)


def test_normal_orientation_hesse_form():
    # plane z = -2 seen from the origin: normal must point away from origin, d = 2
    pts = np.array([[0, 0, -2], [1, 0, -2], [0, 1, -2], [1, 1, -2.0]])
    plane = fit_plane(pts)
    assert plane.normal.tolist() == pytest.approx([0, 0, -1])
    assert plane.d == pytest.approx(2.0)
    assert np.allclose(plane.distances(pts), 0)


def test_plane_through_origin_has_positive_largest_component():
    pts = np.array([[1, 0, 0], [0, 1, 0], [1, 1, 0], [2, 3, 0.0]])
    plane = fit_plane(pts)
    assert plane.d == 0.0
    assert plane.normal.tolist() == pytest.approx([0, 0, 1])


def test_inlier_distance_counts_points_near_the_plane():
    rng = np.random.default_rng(2)
    pts = np.c_[rng.uniform(0, 1, (100, 2)), np.zeros(100)]
    pts[:5, 2] = 0.5  # five outliers
    plane = fit_plane(pts, inlier_distance=0.1)
    assert plane.inliers == 95
    assert fit_plane(pts).inliers == 100


def test_float32_far_from_origin_keeps_precision(synth):
    rng = np.random.default_rng(3)
    center = np.array([7380.86, -8350.60, 4324.23])
    pts = (center + synth.plane(rng, (0.3, 0.5, 0.8), 0.0, size=1.0)).astype(np.float32)
    plane = fit_plane(pts)
    true_n = np.array([0.3, 0.5, 0.8]) / np.linalg.norm([0.3, 0.5, 0.8])
    # float32 resolution there is ~5e-4 m over a 1 m patch: ~0.01 deg expected
    assert synth.angle_deg(plane.normal, true_n) < 0.05


@pytest.mark.parametrize("n", [0, 1, 2])
def test_too_few_points_fail(n):
    result = fit_plane(np.zeros((n, 3)))
    assert isinstance(result, FitFailure) and not result
    assert "at least 3" in result.reason


def test_empty_list_fails_not_raises():
    assert not fit_plane([])


@pytest.mark.parametrize(
    "pts, word",
    [
        (np.array([[0, 0, 0], [1, 1, 1], [2, 2, 2], [3, 3, 3.0]]), "collinear"),
        (np.ones((5, 3)), "coincident"),
        (np.full((5, 3), np.nan), "NaN"),
        (np.array([[0, 0, 0], [1, 0, 0], [0, 1, np.inf]]), "infinite"),
    ],
)
def test_degenerate_inputs_fail_with_reason(pts, word):
    result = fit_plane(pts)
    assert not result
    assert word in result.reason
    assert result.kind == "plane"


def test_bad_shape_and_type_raise():
    with pytest.raises(ValueError, match=r"shape \(N, 3\); got \(10, 2\)"):
        fit_plane(np.zeros((10, 2)))
    with pytest.raises(ValueError, match="shape"):
        fit_plane(np.zeros((2, 3, 3)))
    with pytest.raises(TypeError):
        fit_plane("points")
    with pytest.raises(ValueError, match="inlier_distance"):
        fit_plane(np.eye(3), inlier_distance=-1)
