"""recover_grazing_rings: a face a spinning lidar sees beyond grazing, every step between its
rings a range jump, recovered from the ring arcs no region took; fans of one column and
faces seen less obliquely are not its."""

import numpy as np
import pytest

import rangeseg_o3d as rs
from rangeseg_o3d.config import load_config
from rangeseg_o3d.refinement.context import Context
from rangeseg_o3d.refinement.grazing_rings import recover_grazing_rings, ring_arc_groups
from rangeseg_o3d.scales import GRAZING_TAN, JUMP_SIGMAS

ROW_STEP = np.radians(45.0 / 128)  # a 128 x 2048 spinning lidar's grid
COL_STEP = np.radians(360.0 / 2048)
HEIGHT = 0.21  # the box top lies this far below the sensor
NOISE = 0.01
JUMPS = dict(jump_ratio=ROW_STEP / GRAZING_TAN, jump_min=JUMP_SIGMAS * NOISE)  # scales' jump test for this grid


def _rays(rows: int, cols: int, top_deg: float, first_col: int = 0) -> np.ndarray:
    elevation = np.radians(top_deg) - ROW_STEP * np.arange(rows)[:, None]
    azimuth = COL_STEP * (first_col + np.arange(cols))[None, :]
    return np.dstack(np.broadcast_arrays(np.cos(elevation) * np.cos(azimuth),
                                         np.cos(elevation) * np.sin(azimuth), np.sin(elevation)))


def _scan(seed: int, face: str = "top"):
    """Six rings 4-5.7 degrees below the horizon, 120 columns: rings 2-4 on ``face`` (a box top
    0.21 m below the sensor, 2.2-3 m away, or a wall 3 m ahead), the rest no return;
    ``(cloud, ranges, face mask, context)``."""
    rays = _rays(6, 120, -3.3)
    if face == "top":
        ranges = HEIGHT / -rays[..., 2]
    else:
        ranges = 3.0 / rays[..., 0]
    ranges = ranges + np.random.default_rng(seed).normal(0.0, NOISE, ranges.shape)
    mask = np.zeros(ranges.shape, bool)
    mask[2:5, 10:100] = True
    ranges = np.where(mask, ranges, np.nan)
    cloud = rs.OrganizedCloud(rays * ranges[..., None])
    pipe = rs.Pipeline(load_config("spinning_lidar"))
    ctx = Context(cloud, pipe.fitter, np.full(ranges.shape, NOISE), 20, wrap_columns=True)
    return cloud, ranges, mask, ctx


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_box_top_beyond_grazing_is_recovered_as_its_plane(seed):
    cloud, ranges, mask, ctx = _scan(seed)
    # the premise: every step between the face's rings is a range jump
    steps = np.abs(np.diff(ranges, axis=0))[2:4, 10:100]
    nearer = np.fmin(ranges[2:4, 10:100], ranges[3:5, 10:100])
    assert (steps > np.maximum(JUMPS["jump_min"], JUMPS["jump_ratio"] * nearer)).all()
    labels = np.zeros(ranges.shape, np.int32)
    out, fits = recover_grazing_rings(ctx, labels, {}, ranges=ranges, **JUMPS)
    assert set(fits) == {1} and fits[1].kind == "plane"
    assert (out[mask] == 1).mean() >= 0.95 and (out[~mask] == 0).all()
    assert abs(abs(fits[1].normal[2]) - 1.0) < 1 - np.cos(np.radians(1.0))
    assert abs(abs(fits[1].d) - HEIGHT) < 0.01
    assert (labels == 0).all()  # the input left alone


def test_a_wall_seen_head_on_is_not_this_steps():
    cloud, ranges, mask, ctx = _scan(0, face="wall")
    labels = np.zeros(ranges.shape, np.int32)
    out, fits = recover_grazing_rings(ctx, labels, {}, ranges=ranges, **JUMPS)
    assert out is labels and fits == {}


@pytest.mark.parametrize("seed", [0, 1])
def test_returns_strewn_along_one_column_make_no_face(seed):
    # mixed returns along one azimuth: they lie on the fan of its rays, through the sensor
    rng = np.random.default_rng(seed)
    rays = _rays(40, 8, -3.3)
    ranges = np.full((40, 8), np.nan)
    ranges[:, 3] = rng.uniform(2.0, 6.0, 40)
    cloud = rs.OrganizedCloud(rays * ranges[..., None])
    ctx = Context(cloud, rs.Pipeline(load_config("spinning_lidar")).fitter, np.full(ranges.shape, NOISE), 20,
                  wrap_columns=True)
    labels = np.zeros(ranges.shape, np.int32)
    out, fits = recover_grazing_rings(ctx, labels, {}, ranges=ranges, **JUMPS)
    assert out is labels and fits == {}


def test_ring_arcs_join_across_rings_and_the_seam():
    ranges = np.full((3, 12), np.nan)
    ranges[0, 9:] = 3.0   # one arc over the seam: columns 9-11 and 0-1
    ranges[0, :2] = 3.0
    ranges[1, 10:] = 2.6  # the next ring, a jump nearer, touching it
    ranges[2, 4:7] = 5.0  # an arc apart
    free = np.ones(ranges.shape, bool)
    groups = ring_arc_groups(free, ranges, min_size=3, first_label=7, wrap_columns=True, **JUMPS)
    assert (groups[0, 9:] == 7).all() and (groups[0, :2] == 7).all() and (groups[1, 10:] == 7).all()
    assert (groups[2, 4:7] == 8).all() and (groups[~np.isfinite(ranges)] == 0).all()
    # without the seam the arc is two runs, and only the part the next ring touches joins it
    groups = ring_arc_groups(free, ranges, min_size=3, first_label=1, wrap_columns=False, **JUMPS)
    assert groups[0, 0] == 0 and groups[0, 9] == groups[1, 10] != 0  # columns 0-1: two pixels, under the floor


def test_ring_arc_groups_of_too_few_pixels_are_none():
    ranges = np.full((3, 12), 3.0)
    free = np.zeros(ranges.shape, bool)
    free[0, :2] = True
    assert ring_arc_groups(free, ranges, min_size=3, first_label=1, **JUMPS) is None


def test_ranges_of_another_shape_are_refused():
    cloud, ranges, mask, ctx = _scan(0)
    with pytest.raises(ValueError, match="ranges must have the labels' shape"):
        recover_grazing_rings(ctx, np.zeros(ranges.shape, np.int32), {}, ranges=ranges[:-1], **JUMPS)
