"""Patch geometry (boundaries, areas, extents, caps), parameter covariances, JSON round trip."""

import json

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.patches import (
    PatchSource,
    cylinder_patch,
    occupied_area,
    parameter_covariance,
    plane_patch,
    sphere_patch,
    to_open3d_plane,
    trace_rings,
)

SPACING = 0.01


def _flat_grid(h=60, w=80, z=2.0):
    rows, cols = np.mgrid[0:h, 0:w].astype(float)
    return np.stack([cols * SPACING, rows * SPACING, np.full((h, w), z)], axis=-1)


def _square_with_hole(h=60, w=80):
    labels = np.zeros((h, w), np.int32)
    labels[10:50, 10:70] = 1
    labels[20:30, 30:40] = 0  # a 10 x 10 hole
    return labels


def test_plane_boundary_traces_outer_ring_and_hole_exactly():
    xyz, labels = _flat_grid(), _square_with_hole()
    plane = rs.Plane(normal=(0, 0, 1), d=2.0, rms=0.001, inliers=0)
    patch = plane_patch(PatchSource(xyz, labels), 1, plane)
    assert len(patch.boundary) == 2 and len(patch.pieces) == 1
    outer, hole = patch.boundary
    # Rings run through the centres of the region's border pixels: the outer one spans
    # pixels 10..69 x 10..49, the hole's ring the pixels around it, 29..40 x 19..30.
    np.testing.assert_allclose(outer[:, 0].min() / SPACING, 10, atol=1e-9)
    np.testing.assert_allclose(outer[:, 0].max() / SPACING, 69, atol=1e-9)
    np.testing.assert_allclose(outer[:, 1].max() / SPACING, 49, atol=1e-9)
    np.testing.assert_allclose([hole[:, 0].min() / SPACING, hole[:, 0].max() / SPACING], [29, 40], atol=1e-9)
    # The hole's ring steps diagonally at its four corners (8-connected border pixels),
    # cutting half a pixel step squared at each: 11 x 11 - 4 / 2.
    np.testing.assert_allclose(patch.area, (59 * 39 - (11 * 11 - 2)) * SPACING**2, rtol=1e-9)
    np.testing.assert_allclose(outer[:, 2], 2.0)
    # The oriented extent is about the 59 x 39 pixel-step rectangle, major axis along x
    # (the off-centre hole turns the principal axes a little).
    np.testing.assert_allclose(patch.extent, [59 * SPACING, 39 * SPACING], rtol=0.02)
    assert abs(patch.extent_axes[0, 0]) > 0.999
    np.testing.assert_allclose(patch.extent_center, [0.395, 0.295, 2.0], atol=0.005)
    # The hole pulls the centroid away from the rectangle's centre, toward +x +y.
    assert patch.centroid[0] > 0.395 and patch.centroid[1] > 0.295


def test_disjoint_pieces_are_all_kept_largest_first():
    labels = np.zeros((30, 40), np.int32)
    labels[2:8, 2:8] = 1
    labels[10:28, 10:38] = 1
    rings = trace_rings(labels == 1)
    assert len(rings) == 2
    assert rings[0][0][:, 0].min() == 10  # the large piece first (rows of (row, col) pixels)
    patch = plane_patch(PatchSource(_flat_grid(30, 40), labels), 1,
                        rs.Plane(normal=(0, 0, 1), d=2.0, rms=0.0, inliers=0))
    np.testing.assert_allclose(patch.area, (17 * 27 + 5 * 5) * SPACING**2, rtol=1e-9)


def test_tilted_noisy_plane_area_close_to_the_truth():
    # A 1 m x 0.6 m rectangle tilted 50 degrees, sampled on a 4 mm grid with 1 mm noise.
    rng = np.random.default_rng(0)
    s, t = np.mgrid[0:151, 0:251] * 0.004
    tilt = np.radians(50)
    xyz = np.stack([t, s * np.cos(tilt), 3 + s * np.sin(tilt)], axis=-1)
    normal = np.array([0.0, -np.sin(tilt), np.cos(tilt)])
    xyz = xyz + rng.normal(0, 0.001, s.shape)[..., None] * normal
    labels = np.ones(s.shape, np.int32)
    plane = rs.fit_plane(xyz.reshape(-1, 3))
    patch = plane_patch(PatchSource(xyz, labels), 1, plane)
    truth = 1.0 * 0.6
    assert abs(patch.area - truth) / truth < 0.01
    assert abs(occupied_area(xyz.reshape(-1, 3), plane) - truth) / truth < 0.1


def test_cylinder_patch_height_and_half_circle_span():
    angle = np.linspace(0.2, 0.2 + np.pi, 50)
    height = np.linspace(-0.3, 0.9, 40)
    a, h = np.meshgrid(angle, height)
    points = np.stack([0.25 * np.cos(a) + 1, 0.25 * np.sin(a), h], axis=-1).reshape(-1, 3)
    cyl = rs.Cylinder(axis=(0, 0, 1), point=(1, 0, 0), radius=0.25, rms=0.0, inliers=0)
    patch = cylinder_patch(points, cyl)
    np.testing.assert_allclose(patch.height, 1.2, rtol=1e-9)
    np.testing.assert_allclose(patch.segment[:, 2], [-0.3, 0.9], atol=1e-9)
    np.testing.assert_allclose(patch.angle_span, np.pi, rtol=1e-9)
    middle = 0.2 + np.pi / 2
    np.testing.assert_allclose(patch.arc_mid, [np.cos(middle), np.sin(middle), 0], atol=1e-9)


def test_sphere_cap_angle_and_area():
    polar = np.radians(np.linspace(0, 40, 30))
    azimuth = np.linspace(0, 2 * np.pi, 60, endpoint=False)
    p, a = np.meshgrid(polar, azimuth)
    # a cap around -x (the side a sensor at the origin would see of a sphere at +x)
    points = np.stack([-np.cos(p), np.sin(p) * np.cos(a), np.sin(p) * np.sin(a)], axis=-1).reshape(-1, 3)
    sphere = rs.Sphere(center=(3, 0, 0), radius=0.5, rms=0.0, inliers=0)
    patch = sphere_patch(np.array([3.0, 0, 0]) + 0.5 * points, sphere)
    np.testing.assert_allclose(patch.cap_axis, [-1, 0, 0], atol=1e-6)
    np.testing.assert_allclose(np.degrees(patch.cap_angle), 40, atol=1e-6)
    np.testing.assert_allclose(patch.cap_area, 2 * np.pi * 0.25 * (1 - np.cos(np.radians(40))), rtol=1e-6)


def _monte_carlo(fit, make, repeats, rng):
    params, predicted = [], []
    for _ in range(repeats):
        points = make(rng)
        model = fit(points)
        assert model
        values = np.concatenate([np.ravel(v) for v in model.params().values()])
        params.append(values)
        predicted.append(parameter_covariance(points, model))
    return np.array(params), np.mean(predicted, axis=0)


def test_plane_covariance_matches_the_scatter_of_refits():
    rng = np.random.default_rng(1)
    base = np.stack(np.meshgrid(np.linspace(-0.5, 0.5, 20), np.linspace(-0.3, 0.3, 15)), -1).reshape(-1, 2)

    def make(rng):
        return np.column_stack([base, 2 + 0.1 * base[:, 0] + rng.normal(0, 0.005, len(base))])

    params, predicted = _monte_carlo(rs.fit_plane, make, 300, rng)
    empirical = np.cov(params.T)
    # Standard deviations of the normal's tilt components and of d within 20 %.
    for k in (0, 3):
        assert np.sqrt(empirical[k, k]) == pytest.approx(np.sqrt(predicted[k, k]), rel=0.2)


def test_sphere_covariance_matches_the_scatter_of_refits():
    rng = np.random.default_rng(2)
    direction = rng.normal(size=(400, 3))
    direction[:, 0] = -np.abs(direction[:, 0]) * 3  # one side, as a sensor sees it
    direction /= np.linalg.norm(direction, axis=1)[:, None]

    def make(rng):
        return np.array([2.0, 0, 0]) + (0.3 + rng.normal(0, 0.003, 400))[:, None] * direction

    params, predicted = _monte_carlo(rs.fit_sphere, make, 200, rng)
    empirical = np.cov(params.T)
    for k in (0, 3):  # centre along the view and radius: the correlated, hard pair
        assert np.sqrt(empirical[k, k]) == pytest.approx(np.sqrt(predicted[k, k]), rel=0.25)


def test_cylinder_covariance_radius_matches_refits():
    rng = np.random.default_rng(3)
    a, h = np.meshgrid(np.linspace(np.pi / 2, 3 * np.pi / 2, 30), np.linspace(0, 1, 20))

    def make(rng):
        r = 0.2 + rng.normal(0, 0.002, a.shape)
        return np.stack([2 + r * np.cos(a), r * np.sin(a), h], -1).reshape(-1, 3)

    params, predicted = _monte_carlo(rs.fit_cylinder, make, 100, rng)
    assert np.std(params[:, 6]) == pytest.approx(np.sqrt(predicted[6, 6]), rel=0.3)


def test_degenerate_points_give_no_covariance():
    plane = rs.Plane(normal=(0, 0, 1), d=1.0, rms=0.01, inliers=0)
    assert parameter_covariance(np.zeros((2, 3)), plane) is None
    assert parameter_covariance(np.tile([0.0, 0.0, 1.0], (10, 1)), plane) is None  # one point, repeated


def test_open3d_plane_coefficients_convention():
    import open3d as o3d

    rng = np.random.default_rng(4)
    xy = rng.uniform(-1, 1, (500, 2))
    points = np.column_stack([xy, 3 - 0.5 * xy[:, 0]])
    ours = to_open3d_plane(rs.fit_plane(points))
    assert np.abs(points @ ours[:3] + ours[3]).max() < 1e-9
    assert ours[3] < 0  # our d >= 0 is Open3D's -d
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    theirs, _ = pcd.segment_plane(0.001, 3, 200)
    theirs = np.asarray(theirs) * np.sign(np.dot(theirs[:3], ours[:3]))
    np.testing.assert_allclose(theirs, ours, atol=1e-6)


# -- through the pipeline ------------------------------------------------------------

@pytest.fixture(scope="module")
def lms_result():
    from rangeseg_o3d.synthetic.lms200 import simulate_lms200
    from rangeseg_o3d.synthetic.suite import default_scene

    scan = simulate_lms200(default_scene(), seed=0)
    return scan.cloud, rs.Pipeline("lms200").run(scan.cloud)


def test_pipeline_features_carry_geometry_covariance_and_stated_inliers(lms_result):
    cloud, result = lms_result
    kinds = {f.kind for f in result.features}
    assert kinds == {"plane", "cylinder", "sphere"}
    for feat in result.features:
        assert 0 < feat.inliers <= feat.n_pixels
        cov = feat.covariance
        assert cov.shape == (len(feat.parameter_names),) * 2
        assert np.all(np.linalg.eigvalsh(cov) >= -1e-15)
        if feat.kind == "plane":
            assert feat.area > 0 and len(feat.boundary[0]) >= 3
            # boundary vertices lie on the plane
            assert np.abs(feat.boundary[0] @ feat.normal - feat.d).max() < 1e-9
        elif feat.kind == "cylinder":
            assert 0 < feat.height and 0 < feat.angle_span <= np.pi + 0.5  # seen from one side
        else:
            assert 0 < feat.cap_angle < np.pi / 2 + 0.3
    # A 5 mm sensor noise, 2 sigma: a fair share of pixels lies farther, not all are inliers.
    assert sum(f.inliers for f in result.features) < sum(f.n_pixels for f in result.features)


def test_json_round_trip_keeps_models_geometry_and_covariance(lms_result):
    _, result = lms_result
    data = json.loads(json.dumps(result.to_dict()))
    assert data["format"] == rs.result.RESULT_FORMAT
    back = rs.Result.from_dict(data, labels=result.labels)
    assert [f.kind for f in back.features] == [f.kind for f in result.features]
    for ours, theirs in zip(result.features, back.features):
        assert theirs.inliers == ours.inliers and theirs.rms == ours.rms
        for name in ours.model.params():
            np.testing.assert_array_equal(getattr(theirs, name), getattr(ours, name))
        np.testing.assert_allclose(theirs.covariance, ours.covariance)
        assert theirs.geometry.to_dict() == ours.geometry.to_dict()
    plane = next(f for f in back.features if f.kind == "plane")
    assert plane.area == next(f for f in result.features if f.label == plane.label).area
    assert back.counts() == result.counts()


@pytest.mark.parametrize("bad, message", [
    ([], "must be a dict with 'shape' and 'features'"),
    ({"shape": [2, 2]}, "must be a dict with 'shape' and 'features'"),
    ({"shape": [2, 2], "features": [{"kind": "torus"}]}, "kind must be one of"),
    ({"shape": [2, 2], "features": [{"kind": "plane", "normal": [0, 0, 1]}]}, "lacks d, label"),
])
def test_from_dict_rejects_what_is_not_a_result(bad, message):
    with pytest.raises(ValueError, match=message):
        rs.Result.from_dict(bad)


def test_from_dict_rejects_labels_of_another_shape(lms_result):
    _, result = lms_result
    with pytest.raises(ValueError, match="labels must have the stored shape"):
        rs.Result.from_dict(result.to_dict(), labels=np.zeros((3, 3), np.int32))


def test_feature_without_grid_has_no_geometry():
    feat = rs.Feature(1, rs.Plane(normal=(0, 0, 1), d=1.0, rms=0.0, inliers=5), 5)
    assert feat.geometry is None and feat.covariance is None
    with pytest.raises(AttributeError, match="no patch geometry"):
        feat.area
    assert "geometry" not in feat.to_dict()


def test_onto_plane_along_rays_keeps_each_point_on_its_ray():
    from rangeseg_o3d.fitting.primitives import Plane
    from rangeseg_o3d.patches import onto_plane_along_rays

    # a floor 1 m below the sensor seen 4-6 degrees from grazing, returns off it by 2 cm along
    # their rays: moved along the rays they land on the floor and on their rays; moved
    # orthogonally they would move ~20 cm across the floor
    plane = Plane(normal=np.array([0.0, 1.0, 0.0]), d=-1.0, rms=0.002, inliers=0)
    elevation = np.radians(np.array([-4.0, -5.0, -6.0]))
    rays = np.stack([np.zeros(3), np.sin(elevation), np.cos(elevation)], axis=1)
    on_floor = -1.0 / rays[:, 1]
    points = rays * (on_floor + np.array([0.02, -0.02, 0.02]))[:, None]
    lifted = onto_plane_along_rays(points, plane)
    np.testing.assert_allclose(lifted[:, 1], -1.0, atol=1e-12)
    np.testing.assert_allclose(lifted, rays * on_floor[:, None], atol=1e-9)
    # a point farther off than ALONG_RAY_RMS of the plane's rms (a mixed return: 30 cm along a
    # 5-degree ray would be 3.4 m) is moved orthogonally
    far = rays[:1] * (on_floor[0] - 0.3)
    np.testing.assert_allclose(onto_plane_along_rays(far, plane), far * [1.0, 0.0, 1.0] + [0.0, -1.0, 0.0])
    # a point whose ray does not meet the plane in front of the sensor is moved orthogonally
    above = np.array([[0.0, 0.5, 3.0]])
    np.testing.assert_allclose(onto_plane_along_rays(above, plane), [[0.0, -1.0, 3.0]])
