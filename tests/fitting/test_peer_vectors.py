"""Our least-squares fitters against the numbers in PCL's and Open3D's own tests
(../shared/data/peer_vectors/*.json; each test skips when its file is absent).
open3d_segment_plane_fragment.json is not used: its data (Open3D's fragment.pcd) is
downloaded by Open3D's tests and is not in the shared data, so no test can run it here.

Where a case contains outliers we either drop the outliers the file lists (sphere
RANSAC) or run a simple robust re-fit: least squares on all points, then repeatedly
on the points within the peer's RANSAC threshold until the inlier set stops changing
(sac_plane_test).
"""

import json

import numpy as np
import pytest

from rangeseg_o3d.fitting import Cylinder, FitFailure, fit_cylinder, fit_plane, fit_sphere


def load(shared_data, name):
    path = shared_data / "peer_vectors" / f"{name}.json"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    return json.loads(path.read_text())


def read_ascii_pcd(path):
    """Fields and (N, k) data of an ascii PCD (header lines until DATA)."""
    lines = path.read_text().splitlines()
    header = {}
    for i, line in enumerate(lines):
        key, _, value = line.partition(" ")
        header[key] = value
        if key == "DATA":
            assert value.strip() == "ascii"
            return header["FIELDS"].split(), np.loadtxt(lines[i + 1 :], ndmin=2)
    raise ValueError(f"{path}: no DATA line")


def robust_plane(points, threshold, max_rounds=50):
    """Least squares, then least squares on the points within ``threshold``, until stable."""
    keep = np.ones(len(points), bool)
    for _ in range(max_rounds):
        plane = fit_plane(points[keep])
        new_keep = np.abs(plane.distances(points)) < threshold
        if np.array_equal(new_keep, keep):
            return plane, keep
        keep = new_keep
    raise AssertionError("robust plane re-fit did not settle")


def test_pcl_sphere_ransac_without_listed_outliers(shared_data):
    case = load(shared_data, "pcl_sphere_ransac")
    pts = np.delete(np.array(case["points"]), case["outlier_indices"], axis=0)
    s = fit_sphere(pts, inlier_distance=case["ransac_threshold"])
    assert s.inliers == case["expected_inlier_count"]
    assert np.allclose(s.center / s.radius, case["expected_center_over_radius"], atol=case["tolerance"])


def test_pcl_normal_sphere_ransac(shared_data):
    case = load(shared_data, "pcl_normal_sphere_ransac")
    s = fit_sphere(np.array(case["points"]), inlier_distance=case["ransac_threshold"])
    assert s.inliers == case["expected_inlier_count"]
    assert np.allclose(s.center, case["expected_center"], atol=case["tolerance"])
    assert s.radius == pytest.approx(case["expected_radius"], abs=case["tolerance"])


@pytest.mark.parametrize("with_normals", [False, True])
def test_pcl_cylinder_ransac(shared_data, with_normals):
    case = load(shared_data, "pcl_cylinder_ransac")
    expected = case["expected"]
    pts = np.array(case["points"])
    c = fit_cylinder(pts, np.array(case["normals"]) if with_normals else None)
    assert isinstance(c, Cylinder), c
    # the axis is parallel to z: the axis point's x, y are the coefficients PCL checks
    assert c.axis @ [0, 0, 1] == pytest.approx(1.0, abs=1e-6)
    assert c.point[0] == pytest.approx(expected["coeff[0]"], abs=expected["tolerance"])
    assert c.point[1] == pytest.approx(expected["coeff[1]"], abs=expected["tolerance"])
    assert c.radius == pytest.approx(expected["coeff[6] (radius)"], abs=expected["tolerance"])
    # every point is an inlier of the geometric fit (PCL's 0.02 for point 0 is its normal-angle term)
    assert np.abs(c.distances(pts)).max() < 1e-3
    assert fit_cylinder(pts, inlier_distance=0.021).inliers == expected["inliers"]


def test_pcl_cylinder_two_point_cases_are_below_our_minimum(shared_data):
    # PCL builds a model from 2 points + normals; a least-squares fit needs at least 5
    case = load(shared_data, "pcl_cylinder_two_point_minimal")
    for sample in case["cases"]:
        result = fit_cylinder(np.array(sample["points"], float), np.array(sample["normals"], float))
        assert isinstance(result, FitFailure) and "at least 5" in result.reason


def test_pcl_cylinder_projection_matches_our_distances(shared_data):
    case = load(shared_data, "pcl_cylinder_project_points")
    px, py, pz, dx, dy, dz, r = case["model_coefficients"]
    model = Cylinder(axis=np.array([dx, dy, dz]) / np.linalg.norm([dx, dy, dz]), point=[px, py, pz], radius=r, rms=0.0, inliers=0)
    pts = np.array(case["input_points"])[case["inlier_indices"]]
    projected = np.array(case["projected_truth_for_inliers"])
    # projecting moves each point by exactly its orthogonal distance, onto the surface
    assert np.allclose(np.abs(model.distances(pts)), np.linalg.norm(pts - projected, axis=1), atol=case["tolerance"])
    assert np.allclose(model.distances(projected), 0.0, atol=case["tolerance"])


@pytest.mark.parametrize("with_normals", [False, True])
def test_pcl_cylinder_radius_accuracy(shared_data, with_normals):
    spec = load(shared_data, "pcl_cylinder_radius_accuracy_spec")
    gen = spec["generator"]
    std, n, runs = 0.05, gen["num_points"], gen["num_runs"]
    center, radius = np.array(gen["center"]), gen["radius"]
    rng = np.random.default_rng(20240611)
    errors = []
    for _ in range(runs):
        angle = rng.uniform(0, 2 * np.pi, n)
        radial = np.stack([np.cos(angle), np.sin(angle), np.zeros(n)], axis=1)
        r = radius + np.clip(rng.normal(0, std, n), -3 * std, 3 * std)
        pts = center + r[:, None] * radial + np.outer(rng.uniform(0, 1, n), [0, 0, 1])
        normals = radial + np.clip(rng.normal(0, std, (n, 3)), -3 * std, 3 * std)
        c = fit_cylinder(pts, normals if with_normals else None, inlier_distance=3.5 * std)
        assert c.inliers == n
        errors.append(c.radius - radius)
    rmse = float(np.sqrt(np.mean(np.square(errors))))
    assert rmse <= 1.3 * std / np.sqrt(n)


def test_pcl_plane_far_from_origin_float32(shared_data):
    spec = load(shared_data, "pcl_plane_far_from_origin_spec")
    gen = spec["generator"]
    steps = np.arange(-0.5, 0.5 - 1e-9, 0.01)  # 100 values, as PCL's float loop
    i, j = np.meshgrid(steps, steps, indexing="ij")
    pts = (np.array(gen["center"]) + i.reshape(-1, 1) * gen["x_axis"] + j.reshape(-1, 1) * gen["y_axis"]).astype(np.float32)
    assert len(pts) == 10000
    plane = fit_plane(pts)
    expected_n = np.array(spec["expected_normal"])
    sign = np.sign(plane.normal @ expected_n)
    assert np.allclose(sign * plane.normal, expected_n, atol=spec["normal_tolerance"])
    expected_d = -expected_n @ np.array(gen["center"])  # PCL: n.p + d = 0
    assert -sign * plane.d == pytest.approx(expected_d, abs=spec["d_tolerance"])


def test_pcl_sac_plane_test_robust_refit(shared_data):
    case = load(shared_data, "pcl_plane_sac_plane_test")
    path = shared_data / "pcl" / "sac_plane_test.pcd"
    if not path.is_file():
        pytest.skip(f"{path} not found")
    fields, data = read_ascii_pcd(path)
    pts = data[:, [fields.index(k) for k in "xyz"]]
    plane, inliers = robust_plane(pts, case["ransac_threshold"])
    assert inliers.sum() > case["expected_min_inliers_exclusive"]
    # PCL: a x + b y + c z + dd = 0 with dd = -d, so (a, b, c) / dd = -normal / d
    assert np.allclose(-plane.normal / plane.d, case["expected_plane_over_d"], atol=case["tolerance"])
    positions = np.flatnonzero(inliers)
    checks = case["projection_checks"]
    for k, expected in checks["inlier_list_positions"].items():
        p = pts[positions[int(k)]]
        projected = p - plane.distances(p[None])[0] * plane.normal
        assert np.allclose(projected, expected, atol=checks["tolerance"])


def test_open3d_known_plane(shared_data):
    case = load(shared_data, "open3d_segment_plane_known")
    points = np.array(case["points_newer"])
    plane = fit_plane(points, inlier_distance=case["distance_threshold"])
    assert plane.inliers == 5
    # The points lie exactly on the plane: what is left is rounding, which grows with the
    # coordinates' magnitude (21 here) and differs between CPUs / BLAS builds. Allow 1000
    # units of rounding at the data's scale (5e-12), far below any real misfit.
    tolerance = 1000 * np.finfo(float).eps * np.abs(points).max()
    # x + y + z + 1 = 0 in Hesse form: normal -(1,1,1)/sqrt(3), d = 1/sqrt(3)
    assert np.allclose(plane.normal, -np.ones(3) / np.sqrt(3), rtol=0, atol=tolerance)
    assert plane.d == pytest.approx(1 / np.sqrt(3), abs=tolerance)
    assert plane.rms < tolerance


def test_open3d_older_points_are_collinear(shared_data):
    # the older point set is (t, t, -2t - 1): a line in the plane. RANSAC returns some plane
    # through it; the least-squares plane is undetermined and we say so.
    case = load(shared_data, "open3d_segment_plane_known")
    result = fit_plane(np.array(case["points_older"]))
    assert isinstance(result, FitFailure) and "collinear" in result.reason

