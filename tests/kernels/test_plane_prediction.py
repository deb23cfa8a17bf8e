"""kernels.plane_prediction_sd: the uncertainty of a least-squares plane carried past its points
(merge._Unions.no_step adds it to a piece apart's scatter)."""

import numpy as np
import pytest


@pytest.mark.slow
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


def test_part_within_step_holds_a_piece_apart_to_its_noise_and_the_planes_reach():
    # A floor patch (20 x 20, 10 mm noise along z, seen head-on from 3 m) and a small piece
    # 0.4 m beyond its edge: at 3 noise sigmas above the plane the piece is within 5 sigmas
    # of its scatter and the plane's uncertainty there; at 8 sigmas it is a step. The
    # piece's own rms is the noise; its summed range noise is 10 mm a point.
    from rangeseg_o3d.kernels import label_moments, part_within_step, plane_prediction_sd

    rng = np.random.default_rng(5)
    sigma = 0.01
    u, v = np.meshgrid(np.linspace(-0.25, 0.25, 20), np.linspace(-0.25, 0.25, 20))
    floor = np.column_stack([u.ravel(), v.ravel(), 3.0 + rng.normal(0, sigma, u.size)])
    big = label_moments(np.ascontiguousarray(floor), np.ones(u.size, np.int32), 2)[1]
    normal, d = np.array([0.0, 0.0, 1.0]), 3.0
    piece_uv = rng.uniform(-0.05, 0.05, (30, 2)) + [0.65, 0.0]

    def piece_at(step):
        points = np.column_stack([piece_uv, np.full(30, d + step)])
        return label_moments(np.ascontiguousarray(points), np.ones(30, np.int32), 2)[1]

    spread = plane_prediction_sd(big, sigma, normal, 0.65, 0.0, 3.0)
    bound = 5.0 * np.hypot(sigma, spread)  # the piece is flat: its noise is its range noise
    for step, within in ((0.6 * bound, True), (1.6 * bound, False), (-1.6 * bound, False)):
        got = part_within_step(piece_at(step), 30 * sigma, 0.0, big, sigma, normal, d, 5.0, 0.1)
        assert got is within, step
    # with no points the piece is never a step
    assert part_within_step(np.zeros(10), 0.0, 0.0, big, sigma, normal, d, 5.0, 0.1)
