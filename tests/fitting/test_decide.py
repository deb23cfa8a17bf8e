"""The compiled refusal codes and the decision that uses them."""

import numpy as np
import pytest

from rangeseg_o3d.fitting import _decide as d
from rangeseg_o3d.fitting import fit_cylinder, fit_primitive, fit_sphere
from rangeseg_o3d.fitting._common import decision_reason, refusal
from rangeseg_o3d.fitting.classify import refit_primitive
from rangeseg_o3d.fitting.primitives import Cylinder, FitFailure, Sphere

WORDS = {
    d.TOO_FEW: "at least 5 points; got 3", d.COLLINEAR: "collinear", d.COPLANAR: "coplanar",
    d.SINGULAR: "singular", d.RUNAWAY: "radius grew beyond", d.NOT_CONVERGED: "did not converge in 30",
    d.DIVERGED: "diverged", d.NO_BETTER: "no better than a plane's 0.02",
    d.FLAT: "sagitta", d.RMS_OVER: "cylinder rms 0.01 > 0.005", d.RADIUS_OVER: "max_radius 5",
    d.ARC_UNDER: "arc 57 deg < min_arc_deg 30", d.GAIN_UNDER: "is not 1.5x below the plane's 0.02",
}


def test_every_code_is_worded():
    row = np.zeros(d.CURVED_SIZE)
    row[d.RMS], row[d.RADIUS], row[d.ARC] = 0.01, 2.0, 1.0
    for code, words in WORDS.items():
        text = refusal("cylinder", code, row, plane_rms=0.02, n=3, minimum=5, max_iterations=30,
                       tolerance=0.005, max_radius=5.0, min_arc=np.radians(30), curvature_gain=1.5)
        assert words in text, (code, text)
    with pytest.raises(ValueError, match="unknown refusal code 99"):
        refusal("cylinder", 99, row)


def test_decision_prefixes_the_fits_own_failures_only():
    row = np.zeros(d.CURVED_SIZE)
    row[d.RMS], row[d.RADIUS] = 0.03, 1.0
    own = decision_reason("sphere", d.NO_BETTER, row, eigen_rms=0.02, plane_rms=0.05)
    assert own == "sphere: rms 0.03 is no better than a plane's 0.02"
    judged = decision_reason("sphere", d.RMS_OVER, row, eigen_rms=0.02, plane_rms=0.05, tolerance=0.01)
    assert judged == "sphere rms 0.03 > 0.01"


def test_a_crease_is_refused_with_every_model_tried():
    rng = np.random.default_rng(3)
    u = rng.uniform(0, 1, (200, 2))
    half = u[:, 0] < 0.5
    pts = np.where(half[:, None], np.c_[u[:, 0], u[:, 1], np.zeros(200)],
                   np.c_[0.5 * np.ones(200), u[:, 1], u[:, 0] - 0.5])
    pts = pts + rng.normal(0, 0.002, pts.shape)
    result = fit_primitive(pts)
    assert isinstance(result, FitFailure) and result.kind == "primitive"
    parts = result.reason.split("; ")
    assert parts[0].startswith("plane rms ")
    assert {p.split(" ")[0].rstrip(":") for p in parts[1:]} <= {"cylinder", "sphere"}
    assert len(parts) >= 2


def test_refit_refuses_a_curved_model_on_flat_points():
    rng = np.random.default_rng(4)
    flat = np.c_[rng.uniform(0, 1, (300, 2)), 2.0 + rng.normal(0, 0.002, 300)]
    cylinder = Cylinder(axis=[0, 1, 0], point=[0.5, 0.5, 1.7], radius=0.3, rms=0.002, inliers=300)
    sphere = Sphere(center=[0.5, 0.5, 1.7], radius=0.3, rms=0.002, inliers=300)
    for model in (cylinder, sphere):
        result = refit_primitive(flat, model)
        assert isinstance(result, FitFailure) and result.kind == model.kind
        assert model.kind in result.reason


@pytest.mark.parametrize("seed", range(5))
def test_decision_agrees_with_the_single_model_fits(seed):
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    u = np.cross(axis, np.eye(3)[np.argmin(np.abs(axis))])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    angle = rng.uniform(0, 2.0, 300)
    along = rng.uniform(-0.5, 0.5, 300)
    radius, centre = rng.uniform(0.1, 0.5), rng.uniform(-3, 3, 3)
    cyl = centre + radius * (np.cos(angle)[:, None] * u + np.sin(angle)[:, None] * v) + along[:, None] * axis
    cyl += rng.normal(0, 0.001, cyl.shape)
    decided, alone = fit_primitive(cyl), fit_cylinder(cyl)
    assert decided.kind == "cylinder"
    assert decided.radius == pytest.approx(alone.radius, rel=1e-9)
    assert abs(decided.axis @ alone.axis) == pytest.approx(1.0, abs=1e-9)
    direction = rng.normal(size=(300, 3))
    direction[:, 2] = np.abs(direction[:, 2]) + 0.5  # a cap, not the whole sphere
    sph = centre + radius * direction / np.linalg.norm(direction, axis=1)[:, None]
    sph += rng.normal(0, 0.001, sph.shape)
    decided, alone = fit_primitive(sph), fit_sphere(sph)
    assert decided.kind == "sphere"
    assert np.allclose(decided.center, alone.center, atol=1e-9)
