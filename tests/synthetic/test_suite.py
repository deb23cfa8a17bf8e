"""Benchmark suites: size, variety, determinism, regions large enough to score."""

import numpy as np
import pytest

from rangeseg_o3d.synthetic.suite import default_scene, lms200_suite, rgbd_suite


@pytest.fixture(scope="module")
def suite():
    return lms200_suite(seed=0)


def test_default_scene_has_every_kind_in_view():
    from rangeseg_o3d.synthetic.lms200 import simulate_lms200

    scan = simulate_lms200(default_scene(), seed=0)
    counts = np.bincount(scan.truth_ids.ravel())
    big = {k: m.kind for k, m in scan.truth.items() if counts[k] >= 60}
    assert set(big.values()) == {"plane", "cylinder", "sphere"}
    assert sum(1 for k in big.values() if k == "cylinder") >= 2
    assert len(big) >= 9


def test_lms200_suite_is_varied_and_scorable(suite):
    assert len(suite) >= 8
    assert len({name for name, _ in suite}) == len(suite)
    radii = []
    axes = []
    for name, scan in suite:
        assert scan.cloud.shape == (70, 131), name
        counts = np.bincount(scan.truth_ids.ravel())
        sizes = np.array([counts[k] for k in scan.truth])
        # Regions big enough to score dominate the scan.
        assert sizes[sizes >= 60].sum() > 0.95 * sizes.sum(), name
        for k, model in scan.truth.items():
            if counts[k] >= 60 and model.kind in ("sphere", "cylinder"):
                radii.append(model.radius)
            if counts[k] >= 60 and model.kind == "cylinder":
                axes.append(np.abs(model.axis))
    assert min(radii) <= 0.15 and max(radii) >= 0.5
    axes = np.array(axes)
    for direction in np.eye(3):  # cylinders along x, y and z
        assert np.any(np.abs(axes @ direction) > 0.99)
    assert np.any(np.max(axes, axis=1) < 0.9)  # and tilted ones
    ranges = np.concatenate([s.cloud.ranges[s.truth_ids > 0] for _, s in suite])
    assert np.nanmin(ranges) < 1.2 and np.nanmax(ranges) > 7.0


def test_lms200_suite_deterministic(suite):
    again = lms200_suite(seed=0)
    for (n1, a), (n2, b) in zip(suite, again):
        assert n1 == n2
        assert np.array_equal(a.cloud.xyz, b.cloud.xyz, equal_nan=True)
        assert np.array_equal(a.truth_ids, b.truth_ids)


def test_rgbd_suite():
    scans = rgbd_suite(seed=0)
    assert len(scans) >= 3
    kinds = set()
    for name, scan in scans:
        assert scan.cloud.shape == (480, 640), name
        assert scan.cloud.n_valid > 0.8 * 640 * 480, name
        kinds |= {m.kind for m in scan.truth.values()}
    assert kinds == {"plane", "cylinder", "sphere"}
