"""claim_grazing_limbs: a column's limbs and a box top's far row seen near grazing join their models;
the wall behind does not."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.fitting.primitives import Cylinder, Plane
from rangeseg_o3d.refinement.recover import claim_grazing_limbs


def _column_before_a_wall(seed):
    # a vertical column (radius 0.15 m, axis 3 m ahead) before a wall 3.6 m ahead, seen from the
    # origin by a 0.5-deg grid, 5 mm range noise along the rays; labels: the column's pixels
    # seen within 63 deg of head-on are region 1 (one limb column 84 deg from head-on, the other 68), its limbs and the wall are free
    az, el = np.meshgrid(np.radians(np.arange(-6.15, 6.0, 0.5)), np.radians(np.arange(-3.0, 3.01, 0.5)))
    rays = np.dstack([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)])
    centre, radius = np.array([0.0, 0.0, 3.0]), 0.15
    flat = rays[..., [0, 2]] / np.linalg.norm(rays[..., [0, 2]], axis=2, keepdims=True)
    along = flat @ centre[[0, 2]]
    inside = along ** 2 - (centre[[0, 2]] @ centre[[0, 2]] - radius ** 2)
    hit = inside > 0
    horizontal = np.where(hit, along - np.sqrt(np.maximum(inside, 0)), 3.6 / flat[..., 1])
    ranges = horizontal / np.linalg.norm(rays[..., [0, 2]], axis=2)
    points = rays * ranges[..., None]
    normals = points.copy()
    normals[..., 1] = 0
    normals[..., [0, 2]] -= centre[[0, 2]]
    normals /= np.linalg.norm(normals, axis=2, keepdims=True)
    cosines = np.abs(np.sum(normals * rays, axis=2))
    rng = np.random.default_rng(seed)
    points = rays * (ranges + rng.normal(0.0, 0.005, ranges.shape))[..., None]
    labels = np.where(hit & (cosines > 0.45), 1, 0).astype(np.int32)
    limbs = hit & (labels == 0)
    return points, labels, limbs, hit, centre, radius


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_claim_grazing_limbs_gives_a_column_its_limbs_and_leaves_the_wall(context, seed):
    xyz, labels, limbs, hit, centre, radius = _column_before_a_wall(seed)
    assert limbs.sum() >= 4  # the scene has limbs to claim
    cloud = rs.OrganizedCloud(xyz)
    fits = {1: Cylinder(axis=np.array([0.0, 1.0, 0.0]), point=centre, radius=radius, rms=0.005, inliers=int((labels == 1).sum()))}
    out = claim_grazing_limbs(context(cloud, sigma=np.full(labels.shape, 0.005)), labels, fits,
                              valid=cloud.valid, k_sigma=3.0)
    assert (out[labels == 1] == 1).all()  # the region keeps its pixels
    assert (out[~hit] == 0).all()  # the wall behind the limbs (0.3-0.6 m along the rays) stays free
    assert (out[limbs] == 1).mean() >= 0.9  # the limbs lie on the column within their distance noise
    assert (labels[limbs] == 0).all()  # the input is not changed


def _box_top_before_a_wall(seed):
    # a box top (y = -0.3 m, 1.8-2.3 m ahead) seen from the origin by a grid 0.7 deg apart in
    # elevation, 0.35 deg in azimuth, 1.5 cm range noise along the rays: three rows of it at
    # 8-9 deg incidence, each row a range jump of ~0.2 m; above it a wall 3 m ahead, below it
    # the box's front face (z = 1.8 m). Labels: the front face 2, the top 1 but its far row, free
    az, el = np.meshgrid(np.radians(np.arange(-8.0, 8.0, 0.35)), np.radians(np.arange(-12.0, -4.9, 0.7)))
    rays = np.dstack([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)])
    to_top = -0.3 / rays[..., 1]
    top_z = to_top * rays[..., 2]
    on_top = (top_z >= 1.8) & (top_z <= 2.3)
    front = top_z < 1.8
    ranges = np.where(on_top, to_top, np.where(front, 1.8, 3.0) / rays[..., 2])
    rng = np.random.default_rng(seed)
    points = rays * (ranges + rng.normal(0.0, 0.015, ranges.shape))[..., None]
    top_rows = np.flatnonzero(on_top.any(axis=1))
    far_row = np.zeros_like(on_top)
    far_row[top_rows.max()] = on_top[top_rows.max()]
    labels = np.where(on_top & ~far_row, 1, np.where(front, 2, 0)).astype(np.int32)
    fits = {1: Plane(normal=np.array([0.0, 1.0, 0.0]), d=-0.3, rms=0.002, inliers=int((labels == 1).sum())),
            2: Plane(normal=np.array([0.0, 0.0, 1.0]), d=1.8, rms=0.015, inliers=int((labels == 2).sum()))}
    return points, labels, fits, far_row, on_top | front, top_rows


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_claim_grazing_limbs_gives_a_box_top_its_far_row_and_leaves_the_wall(context, seed):
    xyz, labels, fits, far_row, box, top_rows = _box_top_before_a_wall(seed)
    assert top_rows.size == 3 and far_row.sum() >= 40  # a top three rows deep, its far row free
    cloud = rs.OrganizedCloud(xyz)
    out = claim_grazing_limbs(context(cloud, sigma=np.full(labels.shape, 0.015)), labels, fits,
                              valid=cloud.valid, k_sigma=3.0)
    assert np.array_equal(out[labels > 0], labels[labels > 0])  # the regions keep their pixels
    assert (out[far_row] == 1).mean() >= 0.9  # the far row lies on the top within its distance noise
    assert (out[~box] == 0).all()  # the wall behind (0.7 m on along the rays) stays free
    assert (labels[far_row] == 0).all()  # the input is not changed


def test_claim_grazing_limbs_compiled_and_numpy_forms_agree_on_planes(context, monkeypatch):
    from rangeseg_o3d.refinement import recover

    xyz, labels, fits, far_row, box, top_rows = _box_top_before_a_wall(0)
    cloud = rs.OrganizedCloud(xyz)
    ctx = context(cloud, sigma=np.full(labels.shape, 0.015))
    compiled = claim_grazing_limbs(ctx, labels, fits, valid=cloud.valid, k_sigma=3.0)
    monkeypatch.setattr(recover, "_LIMB_ROUNDING", 1e6)  # every test unsure: numpy answers
    assert np.array_equal(compiled, claim_grazing_limbs(ctx, labels, fits, valid=cloud.valid, k_sigma=3.0))
    assert (compiled != labels).sum() >= 40


def test_claim_grazing_limbs_a_plane_off_the_pixels_claims_nothing_and_bad_shapes_are_refused(context):
    xyz, labels, limbs, hit, centre, radius = _column_before_a_wall(0)
    cloud = rs.OrganizedCloud(xyz)
    fits = {1: Plane(normal=np.array([0.0, 0.0, 1.0]), d=2.85, rms=0.005, inliers=int((labels == 1).sum()))}
    ctx = context(cloud, sigma=np.full(labels.shape, 0.005))
    out = claim_grazing_limbs(ctx, labels, fits, valid=cloud.valid, k_sigma=3.0)
    assert np.array_equal(out, labels)
    with pytest.raises(ValueError, match="valid must have"):
        claim_grazing_limbs(ctx, labels, fits, valid=cloud.valid[:-1], k_sigma=3.0)
    with pytest.raises(ValueError, match=r"\(H, W\) array"):
        claim_grazing_limbs(ctx, labels.ravel(), fits, valid=cloud.valid, k_sigma=3.0)


@pytest.mark.parametrize("seed", [0, 1])
def test_claim_grazing_limbs_compiled_and_numpy_forms_agree(context, monkeypatch, seed):
    # the compiled pass (kernels.claim_limbs) and the numpy form it hands a test within rounding
    # of its bound to: forced unsure everywhere (a huge margin), the numpy form answers alike
    from rangeseg_o3d.refinement import recover

    xyz, labels, limbs, hit, centre, radius = _column_before_a_wall(seed)
    cloud = rs.OrganizedCloud(xyz)
    fits = {1: Cylinder(axis=np.array([0.0, 1.0, 0.0]), point=centre, radius=radius, rms=0.005, inliers=int((labels == 1).sum()))}
    ctx = context(cloud, sigma=np.full(labels.shape, 0.005))
    compiled = claim_grazing_limbs(ctx, labels, fits, valid=cloud.valid, k_sigma=3.0)
    asked = []
    numpy_form = recover._claim_grazing_limbs_numpy
    monkeypatch.setattr(recover, "_claim_grazing_limbs_numpy", lambda *a, **kw: asked.append(1) or numpy_form(*a, **kw))
    monkeypatch.setattr(recover, "_LIMB_ROUNDING", 1e6)
    fallback = claim_grazing_limbs(ctx, labels, fits, valid=cloud.valid, k_sigma=3.0)
    assert asked == [1]
    assert np.array_equal(compiled, fallback)
    assert (compiled != labels).sum() >= 4 and compiled.dtype == labels.dtype


def test_claim_grazing_limbs_asks_another_plugins_curved_model_itself(context):
    # a plugin's own cylinder type (no row in the kernels' model table) answers by its own
    # distances and normals, as the built-in one does
    class PluginCylinder:
        kind = "cylinder"

        def __init__(self, inner):
            self.inner = inner

        def distances(self, points):
            return self.inner.distances(points)

        def normals(self, points):
            return self.inner.normals(points)

    xyz, labels, limbs, hit, centre, radius = _column_before_a_wall(0)
    cloud = rs.OrganizedCloud(xyz)
    cylinder = Cylinder(axis=np.array([0.0, 1.0, 0.0]), point=centre, radius=radius, rms=0.005, inliers=int((labels == 1).sum()))
    ctx = context(cloud, sigma=np.full(labels.shape, 0.005))
    built_in = claim_grazing_limbs(ctx, labels, {1: cylinder}, valid=cloud.valid, k_sigma=3.0)
    plugin = claim_grazing_limbs(ctx, labels, {1: PluginCylinder(cylinder)}, valid=cloud.valid, k_sigma=3.0)
    assert np.array_equal(built_in, plugin) and (plugin != labels).sum() >= 4
