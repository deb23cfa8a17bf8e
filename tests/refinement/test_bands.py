"""bands.line_arms and bands.release_bands: a pipe whose region grew along one row of the wall
above its top (spinning_64x1024 seeds 719, 727, 733: the region's plane under its threshold, a
false fitting) gives that row to the wall's region and becomes its cylinder; a flat face with
the same row, a row no neighbour explains and a region holding a pipe and a piece of a plane
are left as they are."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.config import load_config
from rangeseg_o3d.fitting import fit_plane
from rangeseg_o3d.fitting.primitives import Cylinder, Plane
from rangeseg_o3d.refinement.bands import _sigmas_off, line_arms, release_bands
from rangeseg_o3d.refinement.context import Context
from rangeseg_o3d.refinement.polish import polish_models

SIGMA = 0.015  # the spinning lidar preset's range noise (its plane threshold is twice it)
STEP = 0.35  # degrees between neighbouring rays, as a 1024-column spinning lidar's columns
H, W = 48, 64
TOP = 12  # the pipe's first row; the wall above it ends on row TOP - 1
ARM = 25  # columns the wall's row reaches left of the pipe inside the pipe's region


def _rays() -> np.ndarray:
    """(H, W, 3) unit rays from the origin ``STEP`` degrees apart, the grid's middle on the z axis."""
    focal = 1.0 / np.tan(np.radians(STEP))
    v, u = np.mgrid[0:H, 0:W].astype(float)
    rays = np.dstack([(u - (W - 1) / 2) / focal, (v - (H - 1) / 2) / focal, np.ones((H, W))])
    return rays / np.linalg.norm(rays, axis=2, keepdims=True)


def _scene(seed: int, kind: str = "pipe", wall_depth: float = 4.96, row_depth: float | None = None,
           flat_from: int | None = None):
    """Rows 0..TOP-1: a wall ``wall_depth`` m away (label 2); below it a far wall 6 m away (label 3)
    and in front of it (label 1, rows TOP..H-1) ``"pipe"``, an upright pipe of radius 0.14 m whose
    axis is 5 m away (10 columns), or ``"face"``, a flat face 4.86 m away, 9 columns wide. The
    wall's last row (TOP - 1) over the surface's columns and ``ARM`` columns left of them is in
    region 1 too (its returns ``row_depth`` m away, if given); from row ``flat_from`` (if given)
    the surface's columns are a flat face 5 m away: ``(context, labels, columns of the surface)``."""
    rng = np.random.default_rng(seed)
    rays = _rays()
    ranges, labels = 6.0 / rays[..., 2], np.full((H, W), 3, np.int32)
    if kind == "pipe":
        across, depth = rays[..., 0], rays[..., 2]
        a, b = across ** 2 + depth ** 2, -5.0 * depth
        disc = b * b - a * (5.0 ** 2 - 0.14 ** 2)
        near = (-b - np.sqrt(np.maximum(disc, 0.0))) / a
        columns = np.flatnonzero(disc[30] > 0)
    else:
        near = 4.86 / rays[..., 2]
        columns = np.arange(28, 37)
    body = (slice(TOP, H), slice(columns[0], columns[-1] + 1))
    ranges[body] = near[body]
    labels[body] = 1
    ranges[:TOP] = wall_depth / rays[:TOP, :, 2]
    labels[:TOP] = 2
    row = (TOP - 1, slice(columns[0] - ARM, columns[-1] + 1))
    labels[row] = 1
    if row_depth is not None:
        ranges[row] = row_depth / rays[row][:, 2]
    if flat_from is not None:
        low = (slice(flat_from, H), body[1])
        ranges[low] = 5.0 / rays[low][..., 2]
    xyz = rays * (ranges + rng.normal(0.0, SIGMA, ranges.shape))[..., None]
    fitter = rs.Pipeline(load_config("spinning_lidar")).fitter
    ctx = Context(rs.OrganizedCloud(xyz), fitter, np.full((H, W), SIGMA), 10)
    return ctx, labels, columns


def _fits(ctx, labels) -> dict:
    """Every region's least-squares plane (as the steps before polish leave a pipe's region)."""
    return {k: fit_plane(ctx.xyz[labels.ravel() == k]) for k in (1, 2, 3)}


def test_line_arms_are_the_pixels_with_no_neighbour_across_a_line():
    labels = np.zeros((6, 8), np.int32)
    labels[2:5, 4:7] = 1  # a 3 x 3 body
    labels[1, 0:7] = 1  # a row arm above it, reaching left
    labels[2:5, 7] = 2  # a one-column region of its own
    every = np.arange(labels.size)
    arms = np.zeros(labels.size, bool)
    for k in (1, 2):
        idx = every[labels.ravel() == k]
        arms[idx] = line_arms(labels, idx, False)
    arms = arms.reshape(labels.shape)
    # the arm's pixels left of the body have no neighbour above or below in region 1; the row
    # above the body's columns has the body below it, so it is no arm
    assert arms[1, 0:4].all() and not arms[1, 4:7].any()
    assert not arms[2:5, 4:7].any()
    assert arms[2:5, 7].all()  # a one-column region: no neighbour left or right
    assert arms.sum() == 4 + 3
    # across the seam of a 360-degree grid the first and last columns are neighbours
    seam = np.zeros((3, 4), np.int32)
    seam[:, 0] = seam[:, 3] = 1
    idx = np.flatnonzero(seam.ravel())
    assert line_arms(seam, idx, False).all() and not line_arms(seam, idx, True).any()


def test_line_arms_refuses_a_flat_array_and_pixels_off_the_grid():
    with pytest.raises(ValueError, match=r"\(H, W\) image; got shape \(5,\)"):
        line_arms(np.zeros(5, np.int32), np.arange(5), False)
    with pytest.raises(ValueError, match=r"flat pixels of the 2x3 labels; got 0\.\.6"):
        line_arms(np.zeros((2, 3), np.int32), np.array([0, 6]), False)


def test_release_bands_refuses_bad_input():
    ctx, labels, _ = _scene(0)
    with pytest.raises(ValueError, match="k_sigma must be positive; got 0"):
        release_bands(ctx, labels, _fits(ctx, labels), k_sigma=0.0)
    with pytest.raises(ValueError, match=r"\(H, W\) image; got shape \(3072,\)"):
        release_bands(ctx, labels.ravel(), _fits(ctx, labels), k_sigma=3.0)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_pipe_gives_the_walls_row_back_and_becomes_its_cylinder(seed):
    ctx, labels, columns = _scene(seed)
    fits = _fits(ctx, labels)
    idx = np.flatnonzero(labels.ravel() == 1)
    # the premises: the row is in the region, and the decision on all the region's returns gives
    # no cylinder (the row throws it off)
    assert idx.size == 36 * columns.size + ARM + columns.size
    assert not isinstance(ctx.fitter.fit(ctx.fitter.points(ctx.xyz, idx), resolve_bends=1.0), Cylinder)
    out_labels, out_fits = release_bands(ctx, labels, fits, k_sigma=3.0, resolve_bends=1.0)
    # the row's returns left of the pipe (no pipe below them) went to the wall; the rest is as it was
    arm = np.zeros((H, W), bool)
    arm[TOP - 1, columns[0] - ARM:columns[0]] = True
    assert (out_labels[arm] == 2).all()
    assert np.array_equal(out_labels[~arm], labels[~arm])
    assert labels[arm].sum() == ARM and (labels[arm] == 1).all()  # (the input is not changed)
    model = out_fits[1]
    assert isinstance(model, Cylinder)
    assert model.radius == pytest.approx(0.14, abs=0.015)
    assert abs(model.axis[1]) > 0.99  # upright: the grid's rows run along y
    along = model.axis / np.linalg.norm(model.axis)
    offset = np.array([0.0, 0.0, 5.0]) - model.point
    assert np.linalg.norm(offset - (offset @ along) * along) < 0.03
    # the wall's plane refitted with the row: still its plane, 4.96 m away
    wall = out_fits[2]
    assert isinstance(wall, Plane) and wall.inliers == fits[2].inliers + ARM
    assert abs(wall.normal[2]) > 0.999 and abs(abs(wall.d) - 4.96) < 0.01
    assert out_fits[3] is fits[3]
    # polish keeps the cylinder on the region's final pixels
    assert isinstance(polish_models(ctx, out_labels, out_fits, resolve_bends=1.0, along_rays=True)[1], Cylinder)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_flat_face_keeps_the_row_and_its_plane(seed):
    ctx, labels, _ = _scene(seed, "face")
    fits = _fits(ctx, labels)
    out_labels, out_fits = release_bands(ctx, labels, fits, k_sigma=3.0, resolve_bends=1.0)
    assert out_labels is labels and out_fits is fits


def test_a_row_no_neighbour_explains_stays():
    # the wall above 0.3 m behind the row's returns: the row is none of its
    ctx, labels, _ = _scene(0, wall_depth=5.3, row_depth=4.96)
    fits = _fits(ctx, labels)
    out_labels, out_fits = release_bands(ctx, labels, fits, k_sigma=3.0, resolve_bends=1.0)
    assert out_labels is labels and out_fits is fits


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_body_its_curved_model_does_not_explain_keeps_its_band(seed):
    # the pipe's lowest 12 rows are a flat face 5 m away: no pipe bent by a band
    ctx, labels, _ = _scene(seed, flat_from=36)
    fits = _fits(ctx, labels)
    idx = np.flatnonzero(labels.ravel() == 1)
    body = idx[~line_arms(labels, idx, False)]
    # the premise: without its row the region is decided a cylinder, whose median distance over
    # the noise along the rays is more than one sigma (the guard, not the decision, refuses it)
    decided = ctx.fitter.fit(ctx.fitter.points(ctx.xyz, body), resolve_bends=1.0)
    assert isinstance(decided, Cylinder)
    assert np.median(_sigmas_off(ctx, decided, body)) > 1.2
    out_labels, out_fits = release_bands(ctx, labels, fits, k_sigma=3.0, resolve_bends=1.0)
    assert out_labels is labels and out_fits is fits
