"""polish.bent_at_border_lines (one side): a curved region whose bend rests on the returns along one side of
it (a laser's column of mixed returns beside a narrow face) is the plane of the rest; a pipe,
which bends on every side, is not; nor is a region whose rest spans two grid lines."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.config import load_config
from rangeseg_o3d.fitting import fit_cylinder, fit_plane
from rangeseg_o3d.fitting.robust import beyond_noise
from rangeseg_o3d.refinement.context import Context
from rangeseg_o3d.refinement.polish import bent_at_border_lines, border_sides, polish_models

SIGMA = 0.01  # the noise_10mm row's range noise
JUMP = 0.3  # m: the range step behind the surface's edge that the mixed returns straddle


def _rays() -> np.ndarray:
    """(40, 40, 3) unit rays from the origin 1 degree apart, the grid's middle on the z axis."""
    focal = 1.0 / np.tan(np.radians(1.0))
    v, u = np.mgrid[0:40, 0:40].astype(float)
    rays = np.dstack([(u - 19.5) / focal, (v - 19.5) / focal, np.ones((40, 40))])
    return rays / np.linalg.norm(rays, axis=2, keepdims=True)


def _context(xyz: np.ndarray) -> Context:
    fitter = rs.Pipeline(load_config("lms200", overrides={"sensor.sigma0": SIGMA})).fitter
    return Context(rs.OrganizedCloud(xyz), fitter, np.full(xyz.shape[:2], SIGMA), 10)


def _bent_by_one_side(ctx: Context, labels: np.ndarray) -> dict:
    """bent_at_border_lines on region 1 with the least-squares cylinder of its returns."""
    return bent_at_border_lines(ctx, labels, {1: fit_cylinder(ctx.xyz[labels.ravel() == 1])}, 1.0)


def _scene(seed: int, kind: str):
    """A wall 7 m away and in front of it (label 1, rows 10-30) one of: ``"face"``, a face whose
    plane is turned 57 degrees from the rays about the vertical, three columns wide (17-19) at
    5.2 m (``"narrow face"``: two columns); ``"pipe"``, an upright pipe of radius 0.2 m whose axis is 4 m away (six columns);
    ``"strip"``, an upright pipe of radius 0.06 m at 5 m (two columns). Each has one column of
    mixed returns beside it on its left, 30-70 % of the way across a range step of ``JUMP`` behind
    its edge along the ray (a jump edge across the beam: a surface just behind it), that the region
    took: ``(context, labels, columns of the surface)``."""
    rng = np.random.default_rng(seed)
    rays = _rays()
    wall = 7.0 / rays[..., 2]
    ranges, labels, rows = wall.copy(), np.zeros((40, 40), np.int32), slice(10, 31)
    if kind in ("face", "narrow face"):
        turn = np.radians(57.0)
        normal = np.array([np.sin(turn), 0.0, np.cos(turn)])
        near = 5.2 * normal[2] / (rays @ normal)  # the plane through (0, 0, 5.2)
        columns = np.arange(17, 20) if kind == "face" else np.arange(17, 19)
    else:
        radius, distance = (0.2, 4.0) if kind == "pipe" else (0.06, 5.0)
        across, depth = rays[..., 0], rays[..., 2]
        a, b = across ** 2 + depth ** 2, -distance * depth
        disc = b * b - a * (distance ** 2 - radius ** 2)
        near = (-b - np.sqrt(np.maximum(disc, 0.0))) / a
        columns = np.flatnonzero(disc[20] > 0)
    ranges[rows, columns[0]:columns[-1] + 1] = near[rows, columns[0]:columns[-1] + 1]
    mixed = columns[0] - 1
    if "face" not in kind:  # beside a limb the mixed return lies beyond the limb's range
        near[:, mixed] = np.sqrt(distance ** 2 - radius ** 2) / rays[:, mixed, 2]
    ranges[rows, mixed] = near[rows, mixed] + rng.uniform(0.3, 0.7, 21) * JUMP
    labels[rows, mixed:columns[-1] + 1] = 1
    xyz = rays * (ranges + rng.normal(0.0, SIGMA, ranges.shape))[..., None]
    return _context(xyz), labels, columns


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_narrow_face_bent_by_one_column_of_mixed_returns_is_the_plane_of_the_rest(seed):
    ctx, labels, columns = _scene(seed, "face")
    idx = np.flatnonzero(labels.ravel())
    points = ctx.xyz[idx]
    cylinder = fit_cylinder(points)
    # the premise: the cylinder explains the region within the range noise, its plane does not
    assert cylinder.kind == "cylinder" and cylinder.radius < 3.0
    assert not beyond_noise(float(cylinder.rms), SIGMA, idx.size)
    assert beyond_noise(float(fit_plane(points).rms), SIGMA, idx.size)
    plane = _bent_by_one_side(ctx, labels)[1]
    assert plane.kind == "plane"
    truth = np.array([np.sin(np.radians(57.0)), 0.0, np.cos(np.radians(57.0))])
    assert abs(plane.normal @ truth) > np.cos(np.radians(3.0))  # the face's plane, from its own columns
    assert plane.rms < 1.2 * SIGMA
    # polish on a laser's single returns gives it that plane; elsewhere it is not asked
    assert polish_models(ctx, labels, {1: cylinder}, resolve_bends=1.0, along_rays=True)[1].kind == "plane"
    assert polish_models(ctx, labels, {1: cylinder}, resolve_bends=1.0)[1].kind == "cylinder"


def test_without_it_polish_keeps_the_face_a_cylinder(monkeypatch):
    # the other tests of polish leave it: its plane is over the threshold (_unbent) and the
    # cylinder within the range noise (_bent_by_border)
    from rangeseg_o3d.refinement import polish

    ctx, labels, _ = _scene(0, "face")
    cylinder = fit_cylinder(ctx.xyz[labels.ravel() == 1])
    monkeypatch.setattr(polish, "bent_at_border_lines", lambda *a, **k: {})
    assert polish_models(ctx, labels, {1: cylinder}, resolve_bends=1.0, along_rays=True)[1].kind == "cylinder"


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_pipe_with_one_column_of_mixed_returns_stays_a_cylinder(seed):
    ctx, labels, columns = _scene(seed, "pipe")
    assert columns.size >= 5  # the premise: the pipe's bend shows over its own columns
    idx = np.flatnonzero(labels.ravel())
    cylinder = fit_cylinder(ctx.xyz[idx])
    assert cylinder.kind == "cylinder" and abs(cylinder.radius - 0.2) < 0.08  # (the mixed column pushes it out)
    assert _bent_by_one_side(ctx, labels) == {}
    polished = polish_models(ctx, labels, {1: cylinder}, resolve_bends=1.0, along_rays=True)[1]
    assert polished.kind == "cylinder" and abs(polished.radius - 0.2) < 0.08


@pytest.mark.parametrize("seed", [0, 1])
def test_two_grid_lines_tell_no_bend_so_a_region_whose_rest_spans_two_is_left_alone(seed, monkeypatch):
    from rangeseg_o3d.refinement import polish

    ctx, labels, columns = _scene(seed, "narrow face")
    assert columns.size == 2  # the premise: two columns of the face, one of mixed returns
    assert fit_cylinder(ctx.xyz[labels.ravel() == 1]).kind == "cylinder"
    assert _bent_by_one_side(ctx, labels) == {}
    # with one line fewer needed, the same region would be the plane of the face's two columns
    monkeypatch.setattr(polish, "BEND_LINES", 2)
    assert _bent_by_one_side(ctx, labels)[1].kind == "plane"


@pytest.mark.parametrize("seed", [0, 1])
def test_a_thin_pipe_whose_front_faces_the_sensor_is_left_alone(seed):
    # two columns of a 0.06 m pipe and one of mixed returns: without them the pipe's columns
    # leave their plane the range noise (its front faces the sensor), not an oblique face's share
    from rangeseg_o3d.refinement.polish import under_range_noise

    ctx, labels, columns = _scene(seed, "strip")
    assert columns.size == 2
    rest = np.zeros((40, 40), bool)
    rest[10:31, columns] = True
    assert fit_plane(ctx.xyz[rest.ravel()]).rms > under_range_noise(SIGMA, int(rest.sum()))
    assert _bent_by_one_side(ctx, labels) == {}


def test_under_range_noise_values():
    from rangeseg_o3d.refinement.polish import under_range_noise

    # 1 - 3 sqrt(2 / 100) = 0.5757..., its root 0.7587...
    assert under_range_noise(0.01, 103) == pytest.approx(0.01 * np.sqrt(1.0 - 3.0 * np.sqrt(0.02)), rel=1e-12)
    assert under_range_noise(0.01, 21) == 0.0  # 1 - 3 sqrt(2 / 18) = 0: no bound
    with pytest.raises(ValueError, match="non-negative"):
        under_range_noise(-0.01, 100)


@pytest.mark.parametrize("wrap_columns", [False, True])
def test_border_sides_pixel_by_pixel(wrap_columns):
    labels = np.random.default_rng(3).integers(0, 3, (6, 7)).astype(np.int32)
    labels[2:5, 0:3] = 1
    labels[3, 6] = 1
    idx = np.flatnonzero(labels.ravel() == 1)
    sides = border_sides(labels, idx, wrap_columns)
    h, w = labels.shape
    for j, i in enumerate(idx):
        r, c = divmod(int(i), w)
        above = r == 0 or labels[r - 1, c] != 1
        below = r == h - 1 or labels[r + 1, c] != 1
        if wrap_columns:
            left, right = labels[r, (c - 1) % w] != 1, labels[r, (c + 1) % w] != 1
        else:
            left = c == 0 or labels[r, c - 1] != 1
            right = c == w - 1 or labels[r, c + 1] != 1
        assert tuple(sides[:, j]) == (above, below, left, right)
    # the seam: (3, 0) and (3, 6) are neighbours on a 360-degree grid only
    j0, j6 = int(np.flatnonzero(idx == 3 * w)[0]), int(np.flatnonzero(idx == 3 * w + 6)[0])
    assert sides[2, j0] == (not wrap_columns) and sides[3, j6] == (not wrap_columns)
    with pytest.raises(ValueError, match="labels must be"):
        border_sides(labels.ravel(), idx, False)
    with pytest.raises(ValueError, match="idx must be"):
        border_sides(labels, idx[:0], False)


@pytest.mark.parametrize("wrap_columns", [False, True])
def test_side_rest_planes_are_the_rests_least_squares_planes(wrap_columns):
    from rangeseg_o3d import kernels

    rng = np.random.default_rng(11)
    labels = rng.integers(0, 4, (9, 12)).astype(np.int32)
    labels[1:8, 0:5] = 1
    labels[2:6, 9:12] = 2
    labels[4, 0] = 2  # (2's pixel across the seam from its others on a 360-degree grid)
    xyz = rng.normal(0.0, 1.0, (labels.size, 3)) + 50.0  # far from the origin: sums about a point of each
    xyz[5] = np.nan  # skipped
    wanted = np.array([False, True, True, False])
    counts, rms = kernels.side_rest_planes(xyz, labels.ravel(), 12, wanted, wrap_columns)
    for k in (1, 2):
        idx = np.flatnonzero(labels.ravel() == k)
        sides = border_sides(labels, idx, wrap_columns)
        for s in range(4):
            rest = idx[~sides[s]]
            rest = rest[np.isfinite(xyz[rest]).all(axis=1)]
            assert counts[k, s] == rest.size
            if rest.size >= 3:
                centred = xyz[rest] - xyz[rest].mean(axis=0)
                expected = np.sqrt(np.linalg.eigvalsh(centred.T @ centred)[0] / rest.size)
                assert rms[k, s] == pytest.approx(expected, rel=1e-8, abs=1e-10)
    assert np.all(counts[[0, 3]] == 0) and np.all(rms[[0, 3]] == 0)
