"""The split step: a region that no single model explains comes back as all its surfaces."""

import numpy as np

import rangeseg_o3d as rs
from rangeseg_o3d.fitting.primitives import FitFailure
from rangeseg_o3d.refinement import refine_regions


def _folded_strip(noise: float, seed: int = 0):
    """Three planes meeting at two 45-degree creases, seen as one 60 x 90 grid."""
    v, u = np.mgrid[0:60, 0:90].astype(float)
    x, y = u * 0.02, v * 0.02
    # heights: flat, rising at 45 deg, then falling at 45 deg (continuous at the creases)
    z = np.where(u < 30, 0.0, np.where(u < 60, x - 0.6, 0.6 - (x - 1.2)))
    truth = np.where(u < 30, 1, np.where(u < 60, 2, 3))
    rng = np.random.default_rng(seed)
    xyz = np.dstack([x, y, 3.0 + z + rng.normal(0.0, noise, z.shape)])
    normals = {1: np.array([0.0, 0.0, 1.0]), 2: np.array([-1.0, 0.0, 1.0]) / np.sqrt(2),
               3: np.array([1.0, 0.0, 1.0]) / np.sqrt(2)}
    return rs.OrganizedCloud(xyz), truth, normals


def _split_one_region(cloud):
    pipe = rs.Pipeline("lms200")
    labels = np.ones(cloud.shape, np.int32)  # the segmenter saw no crease at all
    fits = {1: FitFailure("plane", "rms over the limit")}
    ranges = cloud.range_image()
    sigma = pipe.sensor.noise.sigma(ranges)
    return refine_regions(cloud, labels, fits, fitter=pipe.fitter, config=pipe.config.refine,
                          sensor=pipe.sensor, ranges=ranges, sigma=sigma, jumps=None, timings={})


def test_three_planes_leaking_into_one_region_come_back_as_three():
    cloud, truth, normals = _folded_strip(noise=0.001)
    labels, fits = _split_one_region(cloud)
    found = {}
    for k in (1, 2, 3):
        ids, counts = np.unique(labels[truth == k], return_counts=True)
        best = ids[np.argmax(counts)]
        assert best > 0, f"plane {k} left unlabelled"
        # most of the surface in one region, and that region mostly this surface
        assert counts.max() >= 0.9 * (truth == k).sum()
        assert (truth[labels == best] == k).mean() >= 0.9
        model = fits[best]
        assert model and model.kind == "plane"
        assert abs(float(model.normal @ normals[k])) >= np.cos(np.radians(1.0))
        found[k] = best
    assert len(set(found.values())) == 3


def test_a_region_of_pure_noise_stays_an_unfitted_failure():
    rng = np.random.default_rng(1)
    v, u = np.mgrid[0:30, 0:30].astype(float)
    xyz = np.dstack([u * 0.02, v * 0.02, 3.0 + rng.uniform(-0.3, 0.3, u.shape)])
    labels, fits = _split_one_region(rs.OrganizedCloud(xyz))
    assert not fits[1]
    assert set(np.unique(labels)) == {1}
