"""Capture from the simulated rig over ptys: exact rows, faults, resets, silence, continuous nodding."""

import time

import numpy as np
import pytest

from rangeseg_o3d import OrganizedCloud
from rangeseg_o3d.acquisition import CaptureConfig, DeviceTimeout, simulated_capture
from rangeseg_o3d.acquisition.capture import capture_stop_and_go
from rangeseg_o3d.acquisition.lms2xx import beam_angles
from rangeseg_o3d.acquisition.sim.rig import SimulatedRig

from acquisition_helpers import MOUNT, WALL_X, rig_devices, scans_in_sweep, wall_ranges


def config(rows=4, **extra):
    data = {"schedule": {"rows": rows, "start": -0.3, "stop": 0.2}, "mount": {"offset": MOUNT}}
    for key, value in extra.items():
        data.setdefault(key, {}).update(value) if isinstance(value, dict) else data.__setitem__(key, value)
    return CaptureConfig.model_validate(data)


def expected_ranges(cloud, tilt_sign=1.0):
    """What the wall gives at the cloud's actual tilts, in the LMS's mm quantisation."""
    beams = beam_angles(180, 100)
    rows = [wall_ranges(t, beams, tilt_sign=tilt_sign) for t in cloud.geometry.tilt_angles]
    r = np.vstack(rows)
    return np.where(np.isfinite(r) & (r <= 8.183), np.round(r * 1000) * 0.001, np.nan)


def test_fault_free_capture_is_exact(wall):
    cfg = config()
    cloud = simulated_capture(cfg, row_ranges=wall, noise=0.0)
    assert cloud.shape == (4, 181)
    np.testing.assert_allclose(cloud.geometry.tilt_angles, cfg.schedule.angles(), atol=1e-6)  # float32 of targets
    np.testing.assert_array_equal(cloud.ranges, expected_ranges(cloud))
    assert np.nanmax(np.abs(cloud.xyz[..., 0] - WALL_X)) < 1e-3  # points on the wall, mm quantisation
    assert np.all(np.diff(cloud.timestamps) > 0)
    np.testing.assert_allclose(cloud.geometry.mount_offset, MOUNT)


@pytest.mark.parametrize("baud, tilt_sign", [(9600, -1), (500000, 1)])
def test_baud_rates_and_tilt_sign(baud, tilt_sign):
    def row(tilt, beams):
        return wall_ranges(tilt, beams, tilt_sign=tilt_sign)

    cfg = config(rows=2, lms={"baudrate": baud}, mount={"tilt_sign": tilt_sign})
    cloud = simulated_capture(cfg, row_ranges=row, noise=0.0)
    assert cloud.geometry.tilt_sign == tilt_sign
    np.testing.assert_array_equal(cloud.ranges, expected_ranges(cloud, tilt_sign))


@pytest.mark.parametrize("seed", [1, 2])
def test_one_percent_byte_faults_every_row_correct(wall, seed):
    cfg = config(rows=3)
    clean = simulated_capture(cfg, row_ranges=wall, noise=0.005, seed=seed)
    faulty = simulated_capture(cfg, faults=0.01, row_ranges=wall, noise=0.005, seed=seed)
    np.testing.assert_array_equal(faulty.geometry.tilt_angles, clean.geometry.tilt_angles)
    np.testing.assert_array_equal(faulty.ranges, clean.ranges)


def test_nak_and_reset_mid_capture(wall):
    cfg = config(rows=4)
    rig_options = {"lms_options": {"nak_rate": 0.3, "reset_after_scans": 5}}
    cloud = simulated_capture(cfg, row_ranges=wall, noise=0.0, rig_options=rig_options)
    np.testing.assert_array_equal(cloud.ranges, expected_ranges(cloud))


def test_reset_seen_at_9600_is_detected_as_power_on(wall):
    cfg = config(rows=3, lms={"baudrate": 9600})
    rig_options = {"lms_options": {"reset_after_scans": 3}}
    cloud = simulated_capture(cfg, row_ranges=wall, noise=0.0, rig_options=rig_options)
    np.testing.assert_array_equal(cloud.ranges, expected_ranges(cloud))


def test_unplugged_lms_keeps_captured_rows(wall, tmp_path):
    partial_path = tmp_path / "scan.partial.npz"
    cfg = config(rows=5, partial_path=partial_path, lms={"timeout": 0.3})
    rig_options = {"lms_options": {"silent_after_scans": 5}}  # two scans per row: rows 0 and 1 complete
    with pytest.raises(DeviceTimeout) as info:
        simulated_capture(cfg, row_ranges=wall, noise=0.0, rig_options=rig_options)
    err = info.value
    assert err.port.startswith("/dev/pts/") and err.port in str(err)
    assert err.partial.n_rows == 2
    saved = OrganizedCloud.load(partial_path)
    assert saved.shape == (2, 181)
    np.testing.assert_array_equal(saved.ranges, err.partial.to_cloud().ranges)


def test_silent_tilt_unit_times_out(wall):
    with pytest.raises(DeviceTimeout, match="PowerCube") as info:
        simulated_capture(config(rows=2), row_ranges=wall, rig_options={"tilt_options": {"silent": True}})
    assert info.value.partial.n_rows == 0


def test_ctrl_c_during_a_move_halts_the_tilt_unit_and_saves_the_rows_so_far(wall, tmp_path):
    class InterruptedSecondMove:
        waits = 0

        def __init__(self, inner):
            self.inner = inner

        def __getattr__(self, name):
            return getattr(self.inner, name)

        def wait_until_stopped(self, timeout):
            self.waits += 1
            if self.waits == 2:  # row 1's move: -0.3 -> 0.2 rad, 1.5 s of device time
                raise KeyboardInterrupt
            return self.inner.wait_until_stopped(timeout)

    cfg = config(rows=3, partial_path=tmp_path / "scan.partial.npz")
    time_scale = 0.5
    with SimulatedRig(row_ranges=wall, time_scale=time_scale, noise=0.0, mount_offset=MOUNT) as rig:
        with rig_devices(rig, cfg, time_scale) as (sim, lms, tilt), pytest.raises(KeyboardInterrupt) as info:
            capture_stop_and_go(lms, InterruptedSecondMove(tilt), sim)
        stopped_at = rig.cube.position()
        time.sleep(0.1)  # a unit left moving would be 0.05 rad further on by now
        assert rig.cube.halted and not rig.cube.moving_at(rig.clock.now())
        assert -0.3 < rig.cube.position() == stopped_at < 0.15  # halted on its way to row 1's 0.2 rad
    assert info.value.partial.n_rows == 1
    assert OrganizedCloud.load(tmp_path / "scan.partial.npz").shape == (1, 181)


def test_continuous_nodding(wall):
    cfg = config(mode="continuous", continuous_velocity=0.5)
    cloud = simulated_capture(cfg, row_ranges=wall, noise=0.0, time_scale=0.5)
    tilts = cloud.geometry.tilt_angles
    # every scan streamed during the sweep is a row (test_continuous_capture: also on a slow host)
    in_sweep = np.count_nonzero((tilts > -0.3 + 1e-3) & (tilts < 0.2 - 1e-3))
    assert abs(in_sweep - scans_in_sweep(-0.3, 0.2, 0.5)) <= 2, (in_sweep, scans_in_sweep(-0.3, 0.2, 0.5))
    assert np.all(np.diff(tilts) >= -1e-4) and -0.3 - 1e-3 <= tilts[0] and tilts[-1] <= 0.2 + 1e-3
    assert np.all(np.diff(cloud.timestamps) >= 0)  # scans read in one chunk share its arrival time
    # tilt interpolated at each scan's time: points stay near the wall (1 cm at 3 m ~ 3 mrad of tilt error)
    assert np.nanmedian(np.abs(cloud.xyz[..., 0] - WALL_X)) < 0.05


def test_default_scene_capture_then_segmentation():
    cfg = CaptureConfig.model_validate({"schedule": {"rows": 12}})
    cloud = simulated_capture(cfg)
    assert cloud.shape == (12, 181) and cloud.n_valid > 0.5 * cloud.xyz[..., 0].size
    from rangeseg_o3d import Pipeline, load_config

    result = Pipeline(load_config("lms200")).run(cloud)
    assert result.labels.shape == (12, 181) and result.labels.max() >= 1
