import numpy as np
import pytest

from rangeseg_o3d.fitting import Cylinder, FitFailure, fit_cylinder
from rangeseg_o3d.fitting.cylinder import cylinder_arc

AXES = [(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (0.3, -0.5, 0.8), (1, 1e-3, 0)]


@pytest.mark.parametrize("axis", AXES)
@pytest.mark.parametrize("arc_deg", [60, 120, 180, 360])
@pytest.mark.parametrize("with_normals", [False, True])
def test_noise_free_arcs_recovered(synth, axis, arc_deg, with_normals):
    rng = np.random.default_rng(arc_deg)
    point, radius = np.array([1.0, 2.0, -0.5]), 0.4
    pts, normals = synth.cylinder(rng, axis, point, radius, n=250, arc=np.radians(arc_deg), length=0.8)
    c = fit_cylinder(pts, normals if with_normals else None)
    assert isinstance(c, Cylinder), c
    assert synth.angle_deg(c.axis, axis) < 1e-5
    assert c.radius == pytest.approx(radius, rel=1e-7)
    assert synth.line_distance(c.point, c.axis, point) < 1e-7
    assert c.rms < 1e-8
    # axis point nearest the centroid; axis sign: largest component positive
    assert abs((pts.mean(axis=0) - c.point) @ c.axis) < 1e-9
    assert c.axis[np.argmax(np.abs(c.axis))] > 0


@pytest.mark.parametrize("radius", [0.05, 0.2, 1.0])
def test_noisy_half_cylinder_within_tolerance(synth, radius):
    # what a laser sees: about half the cylinder, 5 mm noise
    rng = np.random.default_rng(7)
    axis, point = (0.1, 0.05, 1.0), np.array([0.3, 2.0, 0.0])
    pts, _ = synth.cylinder(rng, axis, point, radius, n=400, arc=np.radians(150), length=max(4 * radius, 0.5), noise=0.005)
    c = fit_cylinder(pts)
    assert c.radius == pytest.approx(radius, abs=0.01)
    assert synth.angle_deg(c.axis, axis) < 2.0
    assert synth.line_distance(c.point, c.axis, point) < 0.012


def test_uses_normals_when_given_and_ignores_nan_rows(synth):
    rng = np.random.default_rng(3)
    pts, normals = synth.cylinder(rng, (1, 0, 0), (0, 0, 2), 0.3, n=200, arc=np.radians(90), noise=0.002)
    normals = normals * 3.0  # length must not matter
    normals[:10] = np.nan
    c = fit_cylinder(pts, normals)
    assert c.radius == pytest.approx(0.3, abs=0.01)
    assert synth.angle_deg(c.axis, (1, 0, 0)) < 1.0


def test_arc_of_quarter_cylinder(synth):
    rng = np.random.default_rng(4)
    pts, _ = synth.cylinder(rng, (0, 0, 1), (0, 0, 0), 1.0, n=1000, arc=np.pi / 2)
    assert np.degrees(cylinder_arc(pts, (0, 0, 1), np.zeros(3))) == pytest.approx(90, abs=2)


@pytest.mark.parametrize("n", [0, 1, 4])
def test_too_few_points_fail(n):
    result = fit_cylinder(np.random.default_rng(0).normal(size=(n, 3)))
    assert isinstance(result, FitFailure) and "at least 5" in result.reason


def test_exact_plane_fails_as_coplanar(synth):
    result = fit_cylinder(synth.plane(np.random.default_rng(5), (1, 0, 0), 1.0))
    assert not result and "coplanar" in result.reason


@pytest.mark.parametrize("seed", range(5))
def test_noisy_plane_never_becomes_a_cylinder(synth, seed):
    rng = np.random.default_rng(seed)
    pts = synth.plane(rng, (0.1, -0.2, 1), 2.0, n=300, size=1.0, noise=0.005)
    result = fit_cylinder(pts)
    assert not result, f"a noisy plane gave {result}"


@pytest.mark.parametrize(
    "pts, word",
    [
        (np.outer(np.arange(6.0), [1, 2, 3]), "collinear"),
        (np.full((6, 3), np.nan), "NaN"),
        (np.vstack([np.eye(3), [[1, 1, 1], [2, 0, 1], [0, 0, np.inf]]]), "infinite"),
    ],
)
def test_degenerate_inputs_fail(pts, word):
    result = fit_cylinder(pts)
    assert not result and word in result.reason and result.kind == "cylinder"


def test_bad_normals_shape_raises():
    with pytest.raises(ValueError, match="normals"):
        fit_cylinder(np.random.default_rng(0).normal(size=(10, 3)), np.zeros((9, 3)))
