"""Results out: Open3D geometries, labels PNG, PLY of points and meshes, JSON and back."""

import json

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.io.export import (
    load_result,
    mesh_arrays,
    read_labels_png,
    result_to_open3d,
    write_labels_png,
    write_ply,
    write_result_json,
)

o3d = pytest.importorskip("open3d")


@pytest.fixture(scope="module")
def scan():
    from rangeseg_o3d.synthetic.lms200 import simulate_lms200
    from rangeseg_o3d.synthetic.suite import default_scene

    cloud = simulate_lms200(default_scene(), seed=1).cloud
    return cloud, rs.Pipeline("lms200").run(cloud)


def test_to_open3d_tensor_points_carry_labels_and_colours(scan):
    cloud, result = scan
    geometries = result.to_open3d(cloud)
    assert len(geometries) == 1 + len(result.features)
    points = geometries[0]
    assert isinstance(points, o3d.t.geometry.PointCloud)
    labels = points.point["labels"].numpy()[:, 0]
    rows, cols = points.point["row"].numpy()[:, 0], points.point["col"].numpy()[:, 0]
    np.testing.assert_array_equal(labels, result.labels[rows, cols])
    colors = points.point.colors.numpy()
    # one colour per label, different between two features
    first, second = result.features[0].label, result.features[1].label
    assert np.ptp(colors[labels == first], axis=0).max() == 0
    assert not np.array_equal(colors[labels == first][0], colors[labels == second][0])
    assert all(isinstance(g, o3d.t.geometry.TriangleMesh) for g in geometries[1:])


def test_meshes_sit_on_their_surfaces(scan):
    cloud, result = scan
    meshes = result.to_open3d(cloud, legacy=True)[1:]
    for feat, mesh in zip(result.features, meshes):
        assert isinstance(mesh, o3d.geometry.TriangleMesh)
        vertices = np.asarray(mesh.vertices)
        assert len(mesh.triangles) > 0
        # every vertex on the model (the plane's boundary lies on it by construction;
        # tubes and spheres are built at the fitted radius)
        assert np.abs(feat.model.distances(vertices)).max() < 1e-9
        if feat.kind == "plane":
            # the triangulated patch has the boundary polygons' area
            assert mesh.get_surface_area() == pytest.approx(feat.area, rel=1e-6)
        if feat.kind == "cylinder":
            axial = (vertices - feat.point) @ feat.axis
            span = (feat.segment - feat.point) @ feat.axis
            np.testing.assert_allclose([axial.min(), axial.max()], sorted(span), atol=1e-9)


def test_plane_mesh_keeps_its_hole():
    rows, cols = np.mgrid[0:40, 0:40].astype(float)
    xyz = np.stack([cols * 0.01, rows * 0.01, np.full((40, 40), 1.0)], axis=-1)
    labels = np.zeros((40, 40), np.int32)
    labels[5:35, 5:35] = 1
    labels[15:25, 15:25] = 0
    cloud = rs.OrganizedCloud(xyz)
    plane = rs.Plane(normal=(0, 0, 1), d=1.0, rms=0.0, inliers=0)
    from rangeseg_o3d.patches import PatchSource

    result = rs.Result(labels, [rs.Feature(1, plane, int(labels.sum()), source=PatchSource(xyz, labels))])
    vertices, triangles = mesh_arrays(result.features[0])
    centres = vertices[triangles].mean(axis=1)
    inside_hole = (np.abs(centres[:, 0] - 0.195) < 0.04) & (np.abs(centres[:, 1] - 0.195) < 0.04)
    assert not inside_hole.any()
    mesh = result.to_open3d(cloud, legacy=True)[1]
    assert mesh.get_surface_area() == pytest.approx(result.features[0].area, rel=1e-9)


def test_labels_png_round_trip(tmp_path, scan):
    _, result = scan
    path = write_labels_png(result.labels, tmp_path / "labels.png")
    back = read_labels_png(path)
    assert back.dtype == np.int32
    np.testing.assert_array_equal(back, result.labels)
    big = np.array([[0, 65535]], np.int32)
    np.testing.assert_array_equal(read_labels_png(write_labels_png(big, tmp_path / "big.png")), big)


@pytest.mark.parametrize("labels, name, message", [
    (np.array([[70000]]), "a.png", "0..65535"),
    (np.array([[-1]]), "a.png", "0..65535"),
    (np.zeros((2, 2, 2), int), "a.png", "2-D integer"),
    (np.zeros((2, 2)), "a.png", "2-D integer"),
    (np.zeros((2, 2), int), "a.jpg", "must be a .png"),
])
def test_labels_png_refuses_what_it_cannot_store(tmp_path, labels, name, message):
    with pytest.raises(ValueError, match=message):
        write_labels_png(labels, tmp_path / name)


def test_read_labels_png_refuses_colour_images(tmp_path):
    import cv2

    cv2.imwrite(str(tmp_path / "rgb.png"), np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(ValueError, match="single-channel"):
        read_labels_png(tmp_path / "rgb.png")


def test_ply_holds_points_and_meshes_that_open3d_reads(tmp_path, scan):
    cloud, result = scan
    path = write_ply(tmp_path / "scan.ply", result, cloud)
    meshes = [mesh_arrays(f) for f in result.features]
    n_mesh_vertices = sum(len(v) for v, _ in meshes)
    n_triangles = sum(len(t) for _, t in meshes)
    mesh = o3d.io.read_triangle_mesh(str(path))
    assert len(mesh.vertices) == cloud.n_valid + n_mesh_vertices
    assert len(mesh.triangles) == n_triangles
    points = o3d.t.io.read_point_cloud(str(path))
    labels = points.point["label"].numpy()[:, 0]
    np.testing.assert_array_equal(labels[:cloud.n_valid], result.labels[cloud.valid])
    np.testing.assert_allclose(points.point.positions.numpy()[:cloud.n_valid],
                               cloud.xyz[cloud.valid], atol=1e-5)  # float32 storage
    for feat in result.features:  # each mesh's vertices carry its label
        assert (labels[cloud.n_valid:] == feat.label).any()


def test_ply_refuses_a_cloud_of_another_shape(tmp_path, scan):
    cloud, result = scan
    with pytest.raises(ValueError, match="pass the cloud the result was computed from"):
        write_ply(tmp_path / "x.ply", result, cloud.crop(rows=slice(0, 10)))
    with pytest.raises(ValueError, match="must end in .ply"):
        write_ply(tmp_path / "x.obj", result, cloud)
    with pytest.raises(TypeError, match="must be an OrganizedCloud"):
        result_to_open3d(result, cloud.xyz)


def test_json_and_labels_png_load_back_as_a_result(tmp_path, scan):
    _, result = scan
    write_result_json(result, tmp_path / "r.json", input="scan.npz")
    write_labels_png(result.labels, tmp_path / "r.png")
    stored = json.loads((tmp_path / "r.json").read_text())
    assert stored["input"] == "scan.npz" and "plane_convention" in stored
    back = load_result(tmp_path / "r.json", tmp_path / "r.png")
    np.testing.assert_array_equal(back.labels, result.labels)
    assert [f.to_dict() for f in back.features] == [f.to_dict() for f in result.features]


def test_load_result_reports_bad_files(tmp_path):
    (tmp_path / "a.json").write_text("{not json")
    with pytest.raises(ValueError, match="not a JSON file"):
        load_result(tmp_path / "a.json")
    (tmp_path / "b.json").write_text(json.dumps({"shape": [2, 2], "features": [{"kind": "plane"}]}))
    with pytest.raises(ValueError, match="not a rangeseg_o3d result record"):
        load_result(tmp_path / "b.json")
    with pytest.raises(FileNotFoundError):
        load_result(tmp_path / "missing.json")


def test_readme_open3d_round_trip_in_five_lines(tmp_path):
    """The README's five lines (drawing aside) on an organized PCD Open3D reads."""
    from rangeseg_o3d.synthetic.depth_camera import simulate_depth_camera
    from rangeseg_o3d.synthetic.suite import rgbd_scenes

    path = simulate_depth_camera(rgbd_scenes()[1][1], seed=0).cloud.save(tmp_path / "frame.pcd")
    cloud = rs.OrganizedCloud.from_open3d(o3d.t.io.read_point_cloud(str(path)))  # grid recovered
    result = rs.Pipeline("rgbd_vga").run(cloud)
    geometries = result.to_open3d(cloud, legacy=True)
    result.write_ply(tmp_path / "features.ply", cloud)
    assert cloud.shape == (480, 640) and len(result.features) >= 3
    assert all(isinstance(g, (o3d.geometry.PointCloud, o3d.geometry.TriangleMesh)) for g in geometries)
    assert len(o3d.io.read_triangle_mesh(str(tmp_path / "features.ply")).triangles) > 0
