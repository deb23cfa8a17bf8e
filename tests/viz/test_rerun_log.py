"""log_scan and the per-stage loggers: record to an .rrd, read it back, check every entity."""

from __future__ import annotations

import numpy as np
import pytest

import rerun as rr  # a core dependency: its absence is a failure, not a skip

from rangeseg_o3d import OrganizedCloud, Result
from rangeseg_o3d.pipeline import Pipeline
from rangeseg_o3d.synthetic.lms200 import simulate_lms200
from rangeseg_o3d.synthetic.suite import default_scene
from rangeseg_o3d.viz import rerun_log
from rangeseg_o3d.viz.rerun_log import log_scan, log_timings

from viz_scan import (
    CYLINDER_LABEL,
    CYLINDER_RADIUS,
    H,
    PLANE_LABEL,
    SPHERE_CENTER,
    SPHERE_LABEL,
    SPHERE_RADIUS,
    W,
    column_values,
    columns,
    make_scan,
    read_rrd,
)


def _record(tmp_path, scans, **kwargs):
    """Log ``scans`` [(cloud, result), ...] at indices 0.. into an .rrd and read it back."""
    path = tmp_path / "scans.rrd"
    rec = rr.RecordingStream("rangeseg_test", recording_id="test")
    rec.save(path)
    for index, (cloud, result) in enumerate(scans):
        log_scan(rec, cloud, result, scan_index=index, log_static=index == 0, **kwargs)
    rec.flush()
    rec.disconnect()
    return read_rrd(path)


@pytest.fixture
def recorded(tmp_path, scan):
    return scan, _record(tmp_path, [scan])


def test_every_entity_has_its_archetype(recorded):
    _, entities = recorded
    expected = {
        "/scan/range": "DepthImage:buffer",
        "/scan/residual": "Image:buffer",
        "/scan/closed": "Image:buffer",
        "/scan/edges": "Image:buffer",
        "/scan/labels": "SegmentationImage:buffer",
        "/world/points": "Points3D:positions",
        f"/world/features/{PLANE_LABEL}": "LineStrips3D:strips",
        f"/world/features/{CYLINDER_LABEL}": "Cylinders3D:centers",
        f"/world/features/{SPHERE_LABEL}": "Ellipsoids3D:centers",
        "/timings/total": "Scalars:scalars",
        "/timings/residual": "Scalars:scalars",
    }
    for entity, column in expected.items():
        assert entity in entities, f"{entity} missing; have {sorted(entities)}"
        assert column in columns(entities[entity]), f"{entity} lacks {column}"
    assert "AnnotationContext:context" in columns(entities["/scan/labels"])


@pytest.mark.parametrize(
    "entity, archetype", [("/scan/range", "DepthImage"), ("/scan/residual", "Image"),
                          ("/scan/edges", "Image"), ("/scan/labels", "SegmentationImage")]
)
def test_images_have_the_grid_shape(recorded, entity, archetype):
    _, entities = recorded
    (fmt,) = column_values(entities[entity], f"{archetype}:format")
    assert (fmt[0]["height"], fmt[0]["width"]) == (H, W)


def test_range_is_metres_with_invalid_as_zero(recorded):
    (cloud, _), entities = recorded
    (meter,) = column_values(entities["/scan/range"], "DepthImage:meter")
    assert meter == [1.0]
    (buffer,) = column_values(entities["/scan/range"], "DepthImage:buffer")
    ranges = np.frombuffer(bytes(buffer[0]), dtype=np.float32).reshape(H, W)
    expected = cloud.range_image()
    valid = np.isfinite(expected) & (expected > 0)
    np.testing.assert_allclose(ranges[valid], expected[valid], rtol=1e-6)
    assert np.all(ranges[~valid] == 0)


def test_points_are_the_valid_pixels_with_row_col_and_region(recorded):
    (cloud, result), entities = recorded
    batches = entities["/world/points"]
    (positions,) = column_values(batches, "Points3D:positions")
    (rows,) = column_values(batches, "GridIndex:row")
    (cols,) = column_values(batches, "GridIndex:col")
    (class_ids,) = column_values(batches, "Points3D:class_ids")
    (colors,) = column_values(batches, "Points3D:colors")
    assert len(positions) == len(rows) == len(cols) == len(class_ids) == len(colors) == cloud.n_valid
    rows, cols = np.array(rows), np.array(cols)
    assert cloud.valid[rows, cols].all()
    np.testing.assert_allclose(np.array(positions), cloud.xyz[rows, cols], atol=1e-5)
    np.testing.assert_array_equal(class_ids, result.labels[rows, cols])


def test_annotation_context_names_each_region(recorded):
    _, entities = recorded
    (context,) = column_values(entities["/scan/labels"], "AnnotationContext:context")
    names = {c["class_id"]: c["class_description"]["info"]["label"] for c in context[0]}
    assert names == {
        0: "no region",
        1: "plane 1",
        2: "cylinder 2 r=0.25 m",
        3: "sphere 3 r=0.30 m",
        4: "unfitted 4",
    }


def test_one_entity_per_feature_with_fitted_geometry(recorded):
    (cloud, result), entities = recorded
    features = sorted(e for e in entities if e.startswith("/world/features/"))
    assert features == [f"/world/features/{f.label}" for f in result.features]

    cyl = entities[f"/world/features/{CYLINDER_LABEL}"]
    (center,) = column_values(cyl, "Cylinders3D:centers")
    (length,) = column_values(cyl, "Cylinders3D:lengths")
    (radius,) = column_values(cyl, "Cylinders3D:radii")
    (quat,) = column_values(cyl, "Cylinders3D:quaternions")
    # Inliers span x in [0, 2.9] on the axis y = 2, z = 0.5.
    np.testing.assert_allclose(center[0], [1.45, 2.0, 0.5], atol=1e-5)
    assert length == pytest.approx([2.9], abs=1e-5)
    assert radius == pytest.approx([CYLINDER_RADIUS])
    x, y, z, w = quat[0]
    # The quaternion turns the cylinder's +z onto the fitted axis (+x).
    rot_z = np.array([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)])
    np.testing.assert_allclose(rot_z, [1, 0, 0], atol=1e-6)

    sph = entities[f"/world/features/{SPHERE_LABEL}"]
    (center,) = column_values(sph, "Ellipsoids3D:centers")
    (half,) = column_values(sph, "Ellipsoids3D:half_sizes")
    np.testing.assert_allclose(center[0], SPHERE_CENTER, atol=1e-6)
    np.testing.assert_allclose(half[0], [SPHERE_RADIUS] * 3, atol=1e-6)

    plane = entities[f"/world/features/{PLANE_LABEL}"]
    (strips,) = column_values(plane, "LineStrips3D:strips")
    outline = np.array(strips[0])
    np.testing.assert_allclose(outline[0], outline[-1])  # closed
    np.testing.assert_allclose(outline[:, 2], 0.0, atol=1e-6)  # on z = 0
    # The plane's pixels: x in [0, 2.9] for y in [0, 0.6], x in [0.5, 2.9] at y = 0.7.
    corners = {(0.0, 0.0), (2.9, 0.0), (2.9, 0.7), (0.5, 0.7), (0.0, 0.6)}
    assert {tuple(np.round(p[:2], 4)) for p in outline} == corners
    assert len(outline) == len(corners) + 1
    (kind,) = column_values(plane, "Feature:kind")
    assert kind == ["plane"]


def test_timings_are_logged_in_milliseconds(recorded):
    (_, result), entities = recorded
    for stage, seconds in result.timings.items():
        (value,) = column_values(entities[f"/timings/{stage}"], "Scalars:scalars")
        assert value == pytest.approx([seconds * 1e3])


def test_sequence_of_scans_one_step_each_and_stale_data_cleared(tmp_path):
    first = make_scan()
    cloud, result = make_scan(with_stages=False)
    fewer = Result(result.labels, result.features[:1], result.unfitted, {"total": 0.5}, {})
    entities = _record(tmp_path, [first, (cloud, fewer)])
    scan_steps = sorted(
        v for batch in entities["/world/points"] for v in batch.column("scan").to_pylist()
    )
    assert scan_steps == [0, 1]
    # Scan 1 has no residual: its entity is cleared at step 1 instead of showing scan 0's.
    residual = entities["/scan/residual"]
    assert column_values(residual, "Image:buffer") and len(column_values(residual, "Image:buffer")) == 1
    cleared = [
        step
        for batch in residual
        if "Clear:is_recursive" in batch.schema.names
        for step, flag in zip(batch.column("scan").to_pylist(), batch.column("Clear:is_recursive").to_pylist())
        if flag is not None
    ]
    assert cleared == [1]
    # world/features is cleared recursively at each scan before the new features are logged.
    flags = column_values(entities["/world/features"], "Clear:is_recursive")
    assert flags == [[True], [True]]


def test_static_context_for_nodding_and_pinhole(tmp_path):
    ranges = np.full((5, 7), 2.0)
    nodding = OrganizedCloud.from_ranges(ranges, np.linspace(0.5, 2.5, 7), np.linspace(-0.3, 0.3, 5))
    empty = Result(np.zeros((5, 7), np.int32), [])
    entities = _record(tmp_path, [(nodding, empty)])
    sensor = entities["/world/sensor"]
    assert "LineStrips3D:strips" in columns(sensor)
    assert all("scan" not in batch.schema.names for batch in sensor)  # static
    (strips,) = column_values(sensor, "LineStrips3D:strips")
    assert len(strips) == 5  # the field-of-view outline and four corner rays
    assert "ViewCoordinates:xyz" in columns(entities["/world"])
    assert "TextDocument:text" in columns(entities["/legend"])
    (positions,) = column_values(entities["/world/points"], "Points3D:positions")
    assert len(positions) == 35

    depth = np.full((4, 6), 1.5)
    pinhole = OrganizedCloud.from_depth(depth, 5.0, 5.0, 3.0, 2.0)
    entities = _record(tmp_path, [(pinhole, Result(np.zeros((4, 6), np.int32), []))])
    (resolution,) = column_values(entities["/world/sensor"], "Pinhole:resolution")
    assert resolution == [[6.0, 4.0]]


def test_all_nan_cloud_logs_zero_points(tmp_path):
    cloud = OrganizedCloud(np.full((3, 4, 3), np.nan))
    entities = _record(tmp_path, [(cloud, Result(np.zeros((3, 4), np.int32), []))])
    (positions,) = column_values(entities["/world/points"], "Points3D:positions")
    assert positions == []
    assert not [e for e in entities if e.startswith("/world/features/")]


def test_bad_input_is_rejected_before_anything_is_logged(tmp_path, scan):
    cloud, result = scan
    rec = rr.RecordingStream("rangeseg_test")
    rec.memory_recording()
    wrong = Result(result.labels[:, :-1], result.features)
    with pytest.raises(ValueError, match=r"labels must have shape \(20, 30\)"):
        log_scan(rec, cloud, wrong, scan_index=0)
    with pytest.raises(ValueError, match="stage image 'edges'"):
        log_scan(rec, cloud, Result(result.labels, [], stages={"edges": np.zeros(3)}), scan_index=0)
    with pytest.raises(ValueError, match="scan_index"):
        log_scan(rec, cloud, result, scan_index=-1)
    with pytest.raises(ValueError, match="labels must lie in"):
        log_scan(rec, cloud, Result(result.labels - 1, []), scan_index=0)
    with pytest.raises(TypeError, match="cloud must be an OrganizedCloud"):
        log_scan(rec, cloud.xyz, result, scan_index=0)
    with pytest.raises(TypeError, match="result must be"):
        log_scan(rec, cloud, result.labels, scan_index=0)
    with pytest.raises(TypeError, match="recording must be"):
        log_scan("rec.rrd", cloud, result, scan_index=0)


def test_no_recording_is_a_no_op(scan):
    cloud, result = scan
    assert log_scan(None, cloud, result, scan_index=0) is None
    assert rerun_log.log_points(None, cloud, result.labels) == 0
    assert rerun_log.log_features(None, cloud, result) == []


def test_nonfinite_timings_are_skipped(tmp_path):
    rec = rr.RecordingStream("rangeseg_test")
    rec.memory_recording()
    logged = log_timings(rec, {"good": 0.1, "nan": float("nan"), "neg": -1.0, "odd name/x": 0.2})
    assert logged == ["timings/good", "timings/odd_name_x"]


def test_static_context_is_logged_once_per_recording(tmp_path):
    cloud = OrganizedCloud.from_ranges(np.full((5, 7), 2.0), np.linspace(0.5, 2.5, 7), np.linspace(-0.3, 0.3, 5))
    result = Result(np.zeros((5, 7), np.int32), [])
    path = tmp_path / "static.rrd"
    rec = rr.RecordingStream("rangeseg_test")
    rec.save(path)
    for index in range(3):  # the pipeline calls log_scan with the default log_static=True
        log_scan(rec, cloud, result, scan_index=index)
    rec.flush()
    rec.disconnect()
    entities = read_rrd(path)
    assert len(column_values(entities["/legend"], "TextDocument:text")) == 1
    assert len(column_values(entities["/world/sensor"], "LineStrips3D:strips")) == 1
    assert len(column_values(entities["/world/points"], "Points3D:positions")) == 3


def test_pipeline_run_with_a_recording_logs_every_stage(tmp_path):
    cloud = simulate_lms200(default_scene(), seed=0).cloud
    path = tmp_path / "pipeline.rrd"
    rec = rr.RecordingStream("rangeseg_test")
    rec.save(path)
    result = Pipeline("lms200").run(cloud, recording=rec, scan_index=2)
    rec.flush()
    rec.disconnect()
    entities = read_rrd(path)
    for stage in ("range", "residual", "closed", "edges", "labels"):
        assert f"/scan/{stage}" in entities
    (positions,) = column_values(entities["/world/points"], "Points3D:positions")
    assert len(positions) == cloud.n_valid
    features = [e for e in entities if e.startswith("/world/features/")]
    assert sorted(features) == sorted(f"/world/features/{f.label}" for f in result.features)
    assert {f"/timings/{stage}" for stage in result.timings} <= set(entities)
    steps = {v for batch in entities["/scan/labels"] for v in batch.column("scan").to_pylist()}
    assert steps == {2}


# -- issue 15 item 6: blueprint, view coordinates, poses, feature parameters, light mode ----

@pytest.fixture(scope="module")
def pipeline_scan():
    import rangeseg_o3d as rs
    from rangeseg_o3d.synthetic.lms200 import simulate_lms200
    from rangeseg_o3d.synthetic.suite import default_scene

    cloud = simulate_lms200(default_scene(), seed=0).cloud
    return cloud, rs.Pipeline("lms200").run(cloud)


def test_blueprint_is_sent_with_the_recording(tmp_path, scan):
    from rerun.chunk import RrdReader

    _record(tmp_path, [scan])
    assert [entry.kind for entry in RrdReader(tmp_path / "scans.rrd").blueprints()] == ["blueprint"]
    blueprint = rerun_log.default_blueprint()
    assert isinstance(blueprint, rr.blueprint.Blueprint)


def test_features_carry_parameters_sigmas_patch_and_boundary(tmp_path, pipeline_scan):
    cloud, result = pipeline_scan
    entities = _record(tmp_path, [pipeline_scan])
    plane = next(f for f in result.features if f.kind == "plane")
    record = entities[f"/world/features/{plane.label}"]
    (normal,) = column_values(record, "Feature:normal")
    np.testing.assert_allclose(normal, plane.normal)
    (sigma,) = column_values(record, "Feature:sigma")
    np.testing.assert_allclose(sigma, np.sqrt(np.diag(plane.covariance)))
    (area,) = column_values(record, "Feature:area")
    assert area == pytest.approx([plane.area])
    (strips,) = column_values(record, "LineStrips3D:strips")
    rings = [ring for piece in plane.geometry.pieces for ring in piece if len(ring) >= 2]
    assert len(strips) == len(rings)  # the traced boundary rings, not a convex hull
    np.testing.assert_allclose(np.array(strips[0])[:-1], rings[0], atol=1e-5)
    cylinder = next(f for f in result.features if f.kind == "cylinder")
    (length,) = column_values(entities[f"/world/features/{cylinder.label}"], "Cylinders3D:lengths")
    assert length == pytest.approx([cylinder.height], rel=1e-5)


def test_pose_is_the_world_transform_and_estimated_pinhole_gives_view_coordinates(tmp_path):
    depth = np.full((12, 16), 2.0)
    camera = OrganizedCloud.from_depth(depth, 20.0, 20.0, 7.5, 5.5)
    pose = np.eye(4)
    pose[:3, 3] = [1.0, 2.0, 3.0]
    # as a PCD would give it: the points, no geometry, a VIEWPOINT pose
    posed = OrganizedCloud(camera.xyz, pose=pose)
    plain = OrganizedCloud(camera.xyz)
    empty = Result(np.zeros((12, 16), np.int32), [])
    entities = _record(tmp_path, [(posed, empty)])
    (translation,) = column_values(entities["/world"], "Transform3D:translation")
    np.testing.assert_allclose(np.ravel(translation), [1.0, 2.0, 3.0])
    assert "ViewCoordinates:xyz" in columns(entities["/world"])
    assert "/world/sensor" in entities  # the estimated pinhole is drawn
    entities = _record(tmp_path, [(plain, empty)])
    assert "ViewCoordinates:xyz" in columns(entities["/"])  # the 3-D view's root, upright


def test_light_mode_leaves_out_the_intermediate_images(tmp_path, pipeline_scan):
    full = _record(tmp_path, [pipeline_scan])
    size_full = (tmp_path / "scans.rrd").stat().st_size
    light = _record(tmp_path, [pipeline_scan], light=True)
    size_light = (tmp_path / "scans.rrd").stat().st_size
    assert "Image:buffer" in columns(full["/scan/residual"])
    assert "Image:buffer" not in columns(light.get("/scan/residual", []))
    assert "DepthImage:buffer" in columns(light["/scan/range"])
    assert size_light < size_full
