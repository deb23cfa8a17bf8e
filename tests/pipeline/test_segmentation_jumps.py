"""The depth-jump mask passes from the segmenter to the refinement as a typed field."""

import numpy as np
import pytest
from pydantic import BaseModel

import rangeseg_o3d as rs
from rangeseg_o3d import registry
from rangeseg_o3d.segmenters.residual_edges import segment_residual_edges
from rangeseg_o3d.synthetic.lms200 import simulate_lms200
from rangeseg_o3d.synthetic.suite import default_scene


def _step_cloud():
    # a wall at 2 m whose right half stands 1 m further back: one column of depth jumps
    rows, cols = 20, 30
    xyz = np.zeros((rows, cols, 3))
    xyz[..., 0], xyz[..., 1] = np.meshgrid(np.linspace(-0.5, 0.5, cols), np.linspace(-0.3, 0.3, rows))
    xyz[..., 2] = np.where(np.arange(cols) < cols // 2, 2.0, 3.0)[None, :]
    return rs.OrganizedCloud(xyz)


def test_residual_edges_reports_its_jumps():
    sensor = rs.Pipeline("lms200").sensor
    seg = segment_residual_edges(_step_cloud(), sensor=sensor)
    assert seg.jumps is not None and seg.jumps.dtype == bool
    assert np.array_equal(seg.jumps, seg.stages["jumps"])  # the same image, for the viewer
    # the step is between columns 14 and 15: the jumps lie there and nowhere else
    assert set(np.flatnonzero(seg.jumps.any(axis=0))) <= {14, 15}
    assert seg.jumps[:, 14:16].any(axis=1).all()


def test_wrapped_segmentation_keeps_the_jumps_on_the_grid():
    scan = simulate_lms200(default_scene(), seed=0)
    sensor = rs.Pipeline("spinning_lidar").sensor
    seg = segment_residual_edges(scan.cloud, sensor=sensor)
    assert seg.jumps.shape == scan.cloud.shape and seg.jumps.any()


class _NoParams(BaseModel):
    pass


def _bad_jumps(cloud):
    return rs.Segmentation(labels=np.where(cloud.valid, 1, 0).astype(np.int32),
                           jumps=np.zeros((2, 2), bool))


def test_malformed_jumps_from_a_plugin_are_an_error():
    registry.register("segmenter", rs.Plugin("bad_jumps_test", _NoParams, _bad_jumps), overwrite=True)
    pipeline = rs.Pipeline({"segmenter": {"name": "bad_jumps_test", "params": {}}})
    with pytest.raises(ValueError, match=r"jumps of shape \(2, 2\); expected \(20, 30\)"):
        pipeline.run(_step_cloud())


def _narrow_face_cloud():
    # a 0.5-deg grid (12 x 16): a front face at 2 m, a face three grid columns wide seen
    # 8 deg from grazing (columns 4-6, column 4 its corner with the front face; each step
    # ~7 % of the range, over the derived jump ratio of 6 x 0.5 deg = 5.2 %), then a wall
    # 1.2 m behind it (columns 7-15)
    angle, step = np.radians(8.0), np.radians(0.5)
    face = 2.0 / (1.0 - np.arange(1, 3) * step / np.tan(angle))
    line = np.concatenate([np.full(5, 2.0), face, np.full(9, face[-1] + 1.2)])
    az, el = np.meshgrid((np.arange(16) - 8) * step, (np.arange(12) - 6) * step)
    rays = np.dstack([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)])
    return rs.OrganizedCloud(rays * line[None, :, None])


def test_a_laser_keeps_a_narrow_face_near_grazing_whole_and_a_camera_does_not():
    from rangeseg_o3d.sensor import NoiseModel, Sensor

    cloud = _narrow_face_cloud()
    grid = dict(row_spacing_deg=0.5, column_spacing_deg=0.5)
    laser = Sensor(noise=NoiseModel(sigma0=0.005), **grid)
    camera = Sensor(noise=NoiseModel(sigma0=0.001, sigma_quadratic=1.425e-3), **grid)
    assert laser.laser_returns and not camera.laser_returns
    seen = segment_residual_edges(cloud, sensor=laser).jumps
    # the laser's single returns: the face's two steps continue each other beyond the noise,
    # so neither is a jump; the wall behind it still is, in every row
    assert not seen[:, :7].any() and seen[:, 7].all() and seen.sum() == 12
    # a camera's (its steps continued on both sides only): each step of the face is a jump
    cut = segment_residual_edges(cloud, sensor=camera).jumps
    assert cut[:, 5].all() and cut[:, 6].all() and cut[:, 7].all() and cut.sum() == 36
