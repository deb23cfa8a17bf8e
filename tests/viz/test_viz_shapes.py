"""Pure-numpy helpers behind the feature drawings and colours."""

from __future__ import annotations

import numpy as np
import pytest

from rangeseg_o3d import Cylinder, Feature, Plane, Result, Sphere, Unfitted
from rangeseg_o3d.viz.colors import NO_REGION_RGB, hsv_to_rgb, region_colors, region_names
from rangeseg_o3d.viz.shapes import (
    cylinder_span,
    model_inliers,
    plane_outline,
    quaternion_from_z,
)


def _rotate(q, v):
    x, y, z, w = q
    u = np.array([x, y, z])
    return v + 2 * w * np.cross(u, v) + 2 * np.cross(u, np.cross(u, v))


@pytest.mark.parametrize(
    "axis", [[1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, -1], [1, 2, 3], [-0.3, 0.1, -0.9]]
)
def test_quaternion_turns_z_onto_axis(axis):
    q = quaternion_from_z(axis)
    assert np.linalg.norm(q) == pytest.approx(1.0)
    unit = np.asarray(axis, float) / np.linalg.norm(axis)
    np.testing.assert_allclose(_rotate(q, np.array([0.0, 0.0, 1.0])), unit, atol=1e-12)


def test_quaternion_rejects_degenerate_axis():
    with pytest.raises(ValueError, match="finite non-zero"):
        quaternion_from_z([0, 0, 0])
    with pytest.raises(ValueError, match="finite non-zero"):
        quaternion_from_z([np.nan, 0, 1])


def test_plane_outline_of_a_tilted_square_is_its_corners():
    normal = np.array([0.0, 1.0, 1.0]) / np.sqrt(2)
    u = np.array([1.0, 0.0, 0.0])
    v = np.cross(normal, u)
    s, t = np.meshgrid(np.linspace(-1, 1, 9), np.linspace(0, 2, 5))
    d = 0.7
    points = d * normal + s.reshape(-1, 1) * u + t.reshape(-1, 1) * v
    outline = plane_outline(points, Plane(normal=normal, d=d, rms=0.0, inliers=len(points)))
    assert outline.shape == (5, 3)
    np.testing.assert_allclose(outline[0], outline[-1])
    np.testing.assert_allclose(outline @ normal, d, atol=1e-12)
    corners = {tuple(np.round(d * normal + a * u + b * v, 9)) for a in (-1, 1) for b in (0, 2)}
    assert {tuple(np.round(p, 9)) for p in outline[:-1]} == corners


def test_plane_outline_degenerate_inputs():
    plane = Plane(normal=(0, 0, 1), d=1.0, rms=0.0, inliers=3)
    line = np.array([[0, 0, 1], [1, 0, 1], [3, 0, 1.0]])
    outline = plane_outline(line, plane)
    assert outline.shape == (3, 3)  # two extreme points, closed
    assert {tuple(p) for p in outline} == {(0.0, 0.0, 1.0), (3.0, 0.0, 1.0)}
    assert plane_outline(np.empty((0, 3)), plane).shape == (0, 3)
    # Off-plane points are projected onto it.
    assert np.allclose(plane_outline(line + [0, 0, 0.5], plane)[:, 2], 1.0)


def test_cylinder_span_is_centred_on_the_inliers():
    cyl = Cylinder(axis=(0, 0, 1), point=(1, 1, 0), radius=0.5, rms=0.0, inliers=3)
    points = np.array([[1.5, 1, -2.0], [0.5, 1, 4.0], [1, 1.5, 1.0]])
    center, length = cylinder_span(points, cyl)
    np.testing.assert_allclose(center, [1, 1, 1.0])
    assert length == pytest.approx(6.0)
    with pytest.raises(ValueError, match="at least one point"):
        cylinder_span(np.empty((0, 3)), cyl)


def test_model_inliers_drop_outliers_but_never_everything():
    sphere = Sphere(center=(0, 0, 0), radius=1.0, rms=0.01, inliers=4)
    points = np.array([[1, 0, 0], [0, 1.01, 0], [0, 0, -1], [0, 0, 3.0]])
    assert len(model_inliers(points, sphere)) == 3
    far = np.array([[5, 0, 0], [0, 5, 0.0]])
    assert len(model_inliers(far, sphere)) == 2


def test_region_names_and_colours():
    labels = np.array([[0, 1, 2], [3, 4, 9]], dtype=np.int32)
    result = Result(
        labels,
        [
            Feature(1, Plane(normal=(0, 0, 1), d=0, rms=0, inliers=1), 1),
            Feature(2, Cylinder(axis=(0, 0, 1), point=(0, 0, 0), radius=0.214, rms=0, inliers=1), 1),
            Feature(3, Sphere(center=(0, 0, 0), radius=0.3, rms=0, inliers=1), 1),
        ],
        [Unfitted(4, 1, "too few points")],
    )
    assert region_names(result) == {
        1: "plane 1",
        2: "cylinder 2 r=0.21 m",
        3: "sphere 3 r=0.30 m",
        4: "unfitted 4",
        9: "region 9",
    }
    lut = region_colors(result)
    assert lut.shape == (10, 3) and lut.dtype == np.uint8
    assert tuple(lut[0]) == NO_REGION_RGB
    r, g, b = (lut[1:4].astype(int)).T
    assert b[0] > max(r[0], g[0])  # plane: blue
    assert g[1] > max(r[1], b[1])  # cylinder: green
    assert r[2] > max(g[2], b[2])  # sphere: red
    assert lut[4, 0] == lut[4, 1] == lut[4, 2]  # unfitted: grey
    assert len({tuple(c) for c in lut[1:5]}) == 4
    empty = Result(np.zeros((2, 2), np.int32), [])
    assert region_colors(empty).shape == (1, 3) and region_names(empty) == {}


def test_hsv_to_rgb_primaries():
    rgb = hsv_to_rgb([0, 120, 240, 360, 60], 1.0, 1.0)
    assert rgb.tolist() == [[255, 0, 0], [0, 255, 0], [0, 0, 255], [255, 0, 0], [255, 255, 0]]
    assert hsv_to_rgb(200, 0.0, 0.5).tolist() == [128, 128, 128]
