"""kernels.plane_prediction_sd: the uncertainty of a least-squares plane carried past its points
(merge._Unions.no_step adds it to a piece apart's scatter)."""

import numpy as np


def test_plane_prediction_sd_is_the_spread_of_refitted_planes_offsets():
    # A 20 x 20 patch (0.5 m square, 10 mm noise) fitted again and again: the offsets of its
    # least-squares planes at the centroid and 0.4 m beyond its edge scatter as the formula
    # says (sigma sqrt(1/n + leverage)), and the formula is capped at the rms.
    from rangeseg_o3d.kernels import label_moments, plane_prediction_sd

    rng = np.random.default_rng(3)
    u, v = np.meshgrid(np.linspace(-0.25, 0.25, 20), np.linspace(-0.25, 0.25, 20))
    base = np.column_stack([u.ravel(), v.ravel(), np.full(u.size, 3.0)])
    far, centre = np.array([0.65, 0.0, 3.0]), np.array([0.0, 0.0, 3.0])
    sigma, offsets = 0.01, {"far": [], "centre": []}
    for _ in range(800):
        points = base + np.column_stack([np.zeros((u.size, 2)), rng.normal(0, sigma, u.size)])
        c = points.mean(0)
        normal = np.linalg.svd(points - c)[2][2]
        for name, at in (("far", far), ("centre", centre)):
            offsets[name].append((at - c) @ normal)
    labels = np.ones(u.size, np.int32)
    row = label_moments(np.ascontiguousarray(base + np.column_stack([np.zeros((u.size, 2)), rng.normal(0, sigma, u.size)])),
                        labels, 2)[1]
    normal = np.array([0.0, 0.0, 1.0])
    predicted = {name: plane_prediction_sd(row, sigma, normal, *at) for name, at in (("far", far), ("centre", centre))}
    assert abs(predicted["centre"] - sigma / 20) < 0.02 * sigma / 20
    for name in ("far", "centre"):
        assert abs(np.std(offsets[name]) - predicted[name]) < 0.1 * predicted[name]
    assert predicted["far"] > 4 * predicted["centre"]
    assert plane_prediction_sd(row, sigma, normal, 30.0, 0.0, 3.0) == sigma  # capped far off
