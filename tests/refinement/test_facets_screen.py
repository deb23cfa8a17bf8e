"""The facets step's compiled pretests (kernels.curved_may_split, kernels.cap_band_most) against
the step's numpy tests: they say "nothing to do" only where the step does nothing."""

import functools
import pickle

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d import kernels
from rangeseg_o3d._numeric import median, rows_at
from rangeseg_o3d.fitting import fit_cylinder
from rangeseg_o3d.fitting.classify import INLIER_FACTOR
from rangeseg_o3d.fitting.primitives import Cylinder, Plane, Sphere
from rangeseg_o3d.fitting.region_fitter import model_table, region_indices
from rangeseg_o3d.fitting.robust import CHI_SQUARE_SIGMAS, beyond_noise
from rangeseg_o3d.refinement import facets
from rangeseg_o3d.refinement.context import Context
from rangeseg_o3d.synthetic.depth_camera import simulate_depth_camera
from rangeseg_o3d.synthetic.scene import Scene, cylinder

PIPE_NOISE = 0.015


_FITTER = rs.Pipeline("lms200").fitter
SCENES = 25


def _pipe(seed: int, caps: bool):
    # a pipe pointing at a camera, capped or not, seen whole in one region (test_facets_caps' scene)
    axis = np.array([0.5, 0.0, -1.0]) / np.hypot(0.5, 1.0)
    scene = Scene([cylinder((-0.4, 0.0, 3.2), axis, 0.15, 1.2, caps=caps, first_id=1)])
    scan = simulate_depth_camera(scene, width=160, height=120, fx=150.0, fy=150.0, cx=79.5, cy=59.5,
                                 noise_coeff=0.0, noise_sigma0=PIPE_NOISE, seed=seed)
    return scan.cloud, (scan.truth_ids > 0).astype(np.int32)


def _crease(rng, degrees: float):
    # two planes meeting at a crease down the middle of a 50 x 60 grid, 1 mm noise
    v, u = np.mgrid[0:50, 0:60].astype(float)
    x, y = u * 0.02, v * 0.02
    z = np.where(u < 30, 0.0, np.tan(np.radians(degrees)) * (x - 0.6))
    return rs.OrganizedCloud(np.dstack([x, y, 3.0 + z + rng.normal(0.0, 0.001, z.shape)]))


def _arc(rng, radius: float):
    # a 70-degree arc of a cylinder (axis along y) on a 50 x 60 grid, 1 mm noise, its grid
    # rows skewed along the axis (no row at one axial coordinate, which an end cap's band takes)
    v, u = np.mgrid[0:50, 0:60].astype(float)
    angle = np.radians(-35.0 + 70.0 * u / 59.0)
    r = radius + rng.normal(0.0, 0.001, u.shape)
    return rs.OrganizedCloud(np.dstack([r * np.sin(angle), v * 0.02 + u * 0.01, 3.0 - r * np.cos(angle)]))


@functools.lru_cache(maxsize=None)
def _scene(seed: int):
    """``(ctx, labels, fits)``: a pipe with or without its end cap, a crease, an arc of a
    cylinder in one region or two (two scenes in five), under a range noise from under to over what the points
    carry, each region with the cylinder (or a sphere) fitted to it, sometimes moved off by a
    few noise sigmas: some regions the step splits, others it leaves."""
    rng = np.random.default_rng(seed)
    kind = min(seed % 5, 3)
    if kind < 2:
        cloud, labels = _pipe(seed, caps=kind == 0)
        noise = PIPE_NOISE * rng.uniform(0.4, 2.0)
    elif kind == 2:
        cloud = _crease(rng, rng.uniform(2.0, 20.0))
        labels = np.ones(cloud.shape, np.int32)
        noise = 0.001 * rng.uniform(0.5, 8.0)
    else:
        cloud = _arc(rng, rng.uniform(0.3, 1.0))
        labels = np.ones(cloud.shape, np.int32)
        if rng.random() < 0.5:
            labels[:, 30:] = 2  # two regions, each with its own model
        noise = 0.001 * rng.uniform(0.7, 2.0)
    xyz = cloud.xyz.reshape(-1, 3)
    fits = {}
    for k in np.unique(labels[labels > 0]).tolist():
        model = fit_cylinder(xyz[labels.ravel() == k])
        if not model:
            continue
        if rng.random() < 0.2:
            model = Cylinder(axis=model.axis, point=model.point, radius=model.radius + rng.normal(0.0, 3.0) * noise,
                             rms=model.rms, inliers=model.inliers)
        elif rng.random() < 0.1:  # a sphere through the region's centre, about as curved
            centre = xyz[labels.ravel() == k].mean(axis=0)
            model = Sphere(center=centre + np.array([0.0, 0.0, model.radius]), radius=model.radius, rms=model.rms,
                           inliers=model.inliers)
        fits[k] = model
    sigma = np.full(cloud.shape, noise) * rng.uniform(0.9, 1.1, cloud.shape) ** (seed % 3 == 0)
    return Context(cloud, _FITTER, sigma, int(rng.choice([10, 20, 40] if kind < 3 else [20, 40]))), labels, fits


def _same(a, b) -> bool:
    labels_a, fits_a = a
    labels_b, fits_b = b
    return (np.array_equal(labels_a, labels_b) and fits_a.keys() == fits_b.keys()
            and all(pickle.dumps(fits_a[k]) == pickle.dumps(fits_b[k]) for k in fits_a))


def test_the_step_gives_the_same_with_and_without_its_pretest(monkeypatch):
    answers = {"nothing": 0, "may, changed": 0, "may, unchanged": 0}
    for seed in range(SCENES):
        ctx, labels, fits = _scene(seed)
        curved = [k for k, m in fits.items() if m and not isinstance(m, Plane)]
        may = facets._may_split(ctx, labels, fits, curved)
        screened = facets.planes_for_curved(ctx, labels, fits)
        with monkeypatch.context() as patch:
            patch.setattr(facets, "_may_split", lambda *args: True)
            patch.setattr(facets, "_no_cap_band", lambda *args: False)
            full = facets.planes_for_curved(ctx, labels, fits)
        assert _same(screened, full), seed
        changed = not _same(full, (labels, fits))
        assert may or not changed, seed  # "nothing" only where the step does nothing
        answers["nothing" if not may else "may, changed" if changed else "may, unchanged"] += 1
    assert min(answers.values()) >= 3, answers  # every kind of answer is asked


@pytest.mark.parametrize("slack", [0.0, facets.SCREEN_SLACK])
def test_a_region_the_pretest_refuses_is_refused_by_each_numpy_test(slack):
    refused = 0
    for seed in range(SCENES):
        ctx, labels, fits = _scene(seed)
        curved = {k: m for k, m in fits.items() if isinstance(m, (Cylinder, Sphere))}
        kinds, params, _ = model_table(curved, max(curved) + 1)
        may = kernels.curved_may_split(labels.ravel().astype(np.int32), ctx.xyz, ctx.sigma, kinds, params,
                                       ctx.min_size, INLIER_FACTOR, CHI_SQUARE_SIGMAS, facets.ANGLE_BINS, facets.CUTS,
                                       facets.PLANES_COVER, facets.CURVED_PARAMETERS["cylinder"] - 3, slack)
        for k, idx in region_indices(labels, only=set(curved)).items():
            if may[k]:
                continue
            refused += 1
            model = curved[k]
            distances = model.distances(rows_at(ctx.xyz, idx))
            rms = float(np.sqrt(np.mean(distances * distances)))
            assert not beyond_noise(rms, median(ctx.sigma[idx]), idx.size), (seed, k)
            assert not facets._holds_another(ctx, model, idx, distances, rms), (seed, k)
            assert facets._two_planes_across_the_axis(ctx, model, idx, distances) == [], (seed, k)
            points = rows_at(ctx.xyz, idx)
            if isinstance(model, Cylinder) and idx.size >= 2 * ctx.min_size:
                assert _cap_band_at_its_offset(ctx, model, idx, points) < ctx.min_size, (seed, k)
    assert refused >= 5


def _cap_band_at_its_offset(ctx, model, idx, points) -> int:
    # the band cap_split's first _likelier_on_plane counts, at the offset its histogram picks
    along = (points - model.point) @ model.axis
    rays = points / np.maximum(np.linalg.norm(points, axis=1, keepdims=True), 1e-12)
    noise = ctx.sigma[idx] * np.abs(rays @ model.axis)
    width = 2.0 * median(noise)
    bins = np.floor((along - along.min()) / width).astype(np.int64)
    offset = median(along[bins == int(np.argmax(np.bincount(bins)))])
    return int(np.count_nonzero(np.abs(along - offset) <= CHI_SQUARE_SIGMAS * np.maximum(noise, 1e-12)))


def test_the_cap_band_bound_is_the_most_intervals_one_offset_meets():
    # slack 0: the sweep's answer is the brute-force count at every interval's start (where
    # the most is met); with the step's slack it is never under numpy's band at any offset,
    # the cap split's own included
    for seed in range(SCENES):
        ctx, labels, fits = _scene(seed)
        for k, idx in region_indices(labels).items():
            model = fits.get(k)
            if not isinstance(model, Cylinder):
                continue
            points = rows_at(ctx.xyz, idx)
            along = (points - model.point) @ model.axis
            rays = points / np.maximum(np.linalg.norm(points, axis=1, keepdims=True), 1e-12)
            reach = CHI_SQUARE_SIGMAS * np.maximum(ctx.sigma[idx] * np.abs(rays @ model.axis), 1e-12)
            exact = kernels.cap_band_most(ctx.xyz, ctx.sigma, idx.astype(np.int64), model.axis, model.point,
                                          CHI_SQUARE_SIGMAS, 0.0)
            starts = along - reach
            brute = max(int(np.count_nonzero(np.abs(along - o) <= reach)) for o in starts)
            assert abs(exact - brute) <= 1, (seed, k, exact, brute)  # (rounding at a shared end)
            bound = kernels.cap_band_most(ctx.xyz, ctx.sigma, idx.astype(np.int64), model.axis, model.point,
                                          CHI_SQUARE_SIGMAS, facets.SCREEN_SLACK)
            assert bound >= brute
            offsets = np.random.default_rng(seed).uniform(along.min(), along.max(), 50)
            assert bound >= max(int(np.count_nonzero(np.abs(along - o) <= reach)) for o in offsets)
            assert bound >= _cap_band_at_its_offset(ctx, model, idx, points)


def test_another_plugins_curved_model_leaves_the_answer_to_the_step():
    ctx, labels, fits = _scene(2)

    class Cone:  # a curved kind the kernels do not know
        kind = "cone"
        rms = 0.001

        def __bool__(self):
            return True

    assert facets._may_split(ctx, labels, {1: Cone()}, [1])
