"""polish._curved_over_refused_plane: a pipe whose plane and cylinder the fitter's decision both refuses
(spinning_32x1024 seeds 709 scan 3 and 719 scan 0) gets the cylinder within the range noise that resolves
its curvature; a wall under that noise does not."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.config import load_config
from rangeseg_o3d.fitting import fit_plane
from rangeseg_o3d.fitting.primitives import Cylinder, Plane
from rangeseg_o3d.refinement.context import Context
from rangeseg_o3d.refinement.polish import _curved_over_refused_plane, _curved_planes, polish_models

STEP = 0.35  # degrees between neighbouring rays, as a 1024-column spinning lidar's columns
H = W = 48


def _rays() -> np.ndarray:
    """(H, W, 3) unit rays from the origin ``STEP`` degrees apart, the grid's middle on the z axis."""
    focal = 1.0 / np.tan(np.radians(STEP))
    v, u = np.mgrid[0:H, 0:W].astype(float)
    rays = np.dstack([(u - (W - 1) / 2) / focal, (v - (H - 1) / 2) / focal, np.ones((H, W))])
    return rays / np.linalg.norm(rays, axis=2, keepdims=True)


def _pipe_under_noise(radius: float, distance: float, seed: int = 0, sigma: float = 0.03):
    """An upright pipe of ``radius`` whose axis is ``distance`` away before a wall 6 m away, seen
    on 22 rows (26-47) at ``STEP`` under a range noise ``sigma`` (the spinning_32x1024 row's 30 mm),
    its returns region 1: ``(context, labels)``."""
    rng = np.random.default_rng(seed)
    rays = _rays()
    ranges, labels = 6.0 / rays[..., 2], np.zeros((H, W), np.int32)
    across, depth = rays[..., 0], rays[..., 2]
    a, b = across ** 2 + depth ** 2, -distance * depth
    disc = b * b - a * (distance ** 2 - radius ** 2)
    near = (-b - np.sqrt(np.maximum(disc, 0.0))) / a
    columns = np.flatnonzero(disc[30] > 0)
    ranges[26:, columns[0]:columns[-1] + 1] = near[26:, columns[0]:columns[-1] + 1]
    labels[26:, columns[0]:columns[-1] + 1] = 1
    xyz = rays * (ranges + rng.normal(0.0, sigma, ranges.shape))[..., None]
    fitter = rs.Pipeline(load_config("spinning_lidar", overrides={"sensor.sigma0": sigma})).fitter
    return Context(rs.OrganizedCloud(xyz), fitter, np.full((H, W), sigma), 10), labels


@pytest.mark.parametrize("radius, distance", [(0.15, 3.5), (0.12, 4.6)])
def test_a_pipe_whose_plane_and_cylinder_the_decision_refuses_gets_its_cylinder(radius, distance):
    # spinning_32x1024 seeds 709 scan 3 and 719 scan 0: 0.15 m at 3.5 m and 0.12 m at 4.6 m
    ctx, labels = _pipe_under_noise(radius, distance)
    idx = np.flatnonzero(labels.ravel())
    plane = fit_plane(ctx.xyz[idx])
    # the premise: the decision refuses the plane (over its threshold) and the cylinder (a gain
    # under curvature_gain), so the region would keep its plane
    refused = ctx.fitter.fit(ctx.fitter.points(ctx.xyz, idx), resolve_bends=1.0)
    assert not refused and "is not 1.5x" in refused.reason
    assert _curved_planes(ctx, labels, {1: plane}, 1.0, grazing_flat=True) == {}  # (without the rule)
    model = _curved_over_refused_plane(ctx, idx, {"resolve_bends": 1.0})
    assert isinstance(model, Cylinder) and model.rms < 0.03 < plane.rms
    assert model.radius == pytest.approx(radius, abs=0.03)
    assert abs(model.axis[1]) > 0.99
    assert _curved_planes(ctx, labels, {1: plane}, 1.0, grazing_flat=True, refused_planes=True)[1].kind == "cylinder"
    polished = polish_models(ctx, labels, {1: plane}, resolve_bends=1.0, along_rays=True)[1]
    assert isinstance(polished, Cylinder) and polished.radius == pytest.approx(radius, abs=0.03)


def test_a_wall_under_the_same_noise_gets_no_curved_model():
    ctx, labels = _pipe_under_noise(0.12, 4.6)
    flat = fit_plane(ctx.xyz[labels.ravel() == 0])  # the wall's returns: their plane is accepted
    idx = np.flatnonzero(labels.ravel() == 0)
    assert isinstance(ctx.fitter.fit(ctx.fitter.points(ctx.xyz, idx), resolve_bends=1.0), Plane)
    assert _curved_over_refused_plane(ctx, idx, {"resolve_bends": 1.0}) is None
    assert flat.rms < 0.035
