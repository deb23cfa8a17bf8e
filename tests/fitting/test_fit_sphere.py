import numpy as np
import pytest

from rangeseg_o3d.fitting import FitFailure, Sphere, fit_sphere
from rangeseg_o3d.fitting.sphere import sphere_cap_angle


@pytest.mark.parametrize("radius", [0.05, 0.3, 2.0])
@pytest.mark.parametrize("cap_deg", [60, 120, 180, 360])
def test_noise_free_caps_recovered_exactly(synth, radius, cap_deg):
    rng = np.random.default_rng(int(radius * 100) + cap_deg)
    center = np.array([1.0, -2.0, 3.0])
    pts, _ = synth.sphere(rng, center, radius, n=200, cap=np.radians(cap_deg))
    s = fit_sphere(pts)
    assert isinstance(s, Sphere)
    assert np.allclose(s.center, center, atol=1e-8 * max(1, radius))
    assert s.radius == pytest.approx(radius, rel=1e-8)
    assert s.rms < 1e-9
    assert s.inliers == 200


@pytest.mark.parametrize("cap_deg", [90, 180])
def test_noisy_cap_within_tolerance(synth, cap_deg):
    # LMS200-like: 5 mm noise on a 0.25 m ball seen as a cap
    rng = np.random.default_rng(cap_deg)
    center = np.array([0.5, 0.2, 2.0])
    pts, _ = synth.sphere(rng, center, 0.25, n=400, cap=np.radians(cap_deg), noise=0.005)
    s = fit_sphere(pts)
    assert s.radius == pytest.approx(0.25, abs=0.01)
    assert np.linalg.norm(s.center - center) < 0.015
    assert s.rms == pytest.approx(0.005, rel=0.2)


def test_cap_angle_of_hemisphere(synth):
    rng = np.random.default_rng(0)
    pts, _ = synth.sphere(rng, (0, 0, 0), 1.0, n=2000, cap=np.pi)
    assert np.degrees(sphere_cap_angle(pts, np.zeros(3))) == pytest.approx(180, abs=3)


def test_inlier_distance_excludes_outlier(synth):
    rng = np.random.default_rng(1)
    # one point 0.1 m outside among 300 barely moves the fit
    pts, _ = synth.sphere(rng, (0, 0, 0), 1.0, n=300, cap=np.pi, noise=0.001)
    s = fit_sphere(np.vstack([pts, [[0, 0, -1.1]]]), inlier_distance=0.05)
    assert s.inliers == 300


@pytest.mark.parametrize("n", [0, 1, 3])
def test_too_few_points_fail(n):
    result = fit_sphere(np.arange(3 * n, dtype=float).reshape(n, 3))
    assert isinstance(result, FitFailure) and "at least 4" in result.reason


def test_exact_plane_fails_as_coplanar(synth):
    rng = np.random.default_rng(2)
    result = fit_sphere(synth.plane(rng, (0.3, 0.1, 1), 2.0))
    assert not result and "coplanar" in result.reason


@pytest.mark.parametrize("seed", range(5))
def test_noisy_plane_never_becomes_a_sphere(synth, seed):
    rng = np.random.default_rng(seed)
    pts = synth.plane(rng, (0.1, -0.2, 1), 2.0, n=300, size=1.0, noise=0.005)
    result = fit_sphere(pts)
    assert not result, f"a noisy plane gave {result}"


@pytest.mark.parametrize(
    "pts, word",
    [
        (np.array([[0, 0, 0], [1, 1, 1], [2, 2, 2], [3, 3, 3.0], [4, 4, 4]]), "collinear"),
        (np.full((6, 3), np.nan), "NaN"),
        (np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, 0, -np.inf]]), "infinite"),
    ],
)
def test_degenerate_inputs_fail(pts, word):
    result = fit_sphere(pts)
    assert not result and word in result.reason and result.kind == "sphere"


def test_bad_shape_raises():
    with pytest.raises(ValueError, match="shape"):
        fit_sphere(np.zeros((4, 4)))
