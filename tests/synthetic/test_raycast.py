"""Ray caster against hand-computed intersections."""

import numpy as np
import pytest

from rangeseg_o3d.synthetic.raycast import cast
from rangeseg_o3d.synthetic.scene import (
    CylinderSide,
    Disk,
    Rectangle,
    Scene,
    SphereSurface,
    box,
    cylinder,
    room,
    rotation_from_to,
    sphere,
)


def _unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_rectangle_hit_and_miss_outside_bounds():
    rect = Rectangle(4, center=(3, 0, 0), u=(0, 1, 0), v=(0, 0, 1), half_u=1.0, half_v=0.5)
    origins = np.zeros((3, 3))
    dirs = _unit([[1, 0, 0], [3, 0.9, 0.3], [3, 1.2, 0]])  # centre, inside corner, outside in u
    r, ids = cast(Scene([rect]), origins, dirs)
    assert r[0] == pytest.approx(3.0, abs=1e-12)
    assert r[1] == pytest.approx(np.linalg.norm([3, 0.9, 0.3]), abs=1e-12)
    assert np.isinf(r[2]) and ids[2] == 0
    assert ids.dtype == np.int32 and list(ids[:2]) == [4, 4]


def test_rectangle_parallel_ray_and_behind_origin_miss():
    rect = Rectangle(1, center=(3, 0, 0), u=(0, 1, 0), v=(0, 0, 1), half_u=1.0, half_v=1.0)
    r, ids = cast(Scene([rect]), np.zeros((2, 3)), [[0, 1, 0], [-1, 0, 0]])
    assert np.all(np.isinf(r)) and np.all(ids == 0)


@pytest.mark.parametrize("origin", [(0, 0, 0), (1, -2, 0.5)])
def test_sphere_nearest_root_and_inside(origin):
    c, radius = np.array([4.0, 1.0, 0.5]), 0.7
    o = np.array(origin, dtype=float)
    d = _unit(c - o)
    r, ids = cast(Scene(sphere(c, radius, first_id=9)), o[None], d[None])
    assert r[0] == pytest.approx(np.linalg.norm(c - o) - radius, abs=1e-12)
    assert ids[0] == 9
    # From inside the sphere the ray exits at the far side.
    r2, _ = cast(Scene(sphere(c, radius, first_id=9)), c[None], [[0, 0, 1]])
    assert r2[0] == pytest.approx(radius, abs=1e-12)


def test_sphere_tangent_and_miss():
    s = Scene(sphere((5, 0, 0), 1.0, first_id=2))
    r, ids = cast(s, [[0, 0, 1], [0, 0, 1.0001]], [[1, 0, 0], [1, 0, 0]])
    assert r[0] == pytest.approx(5.0) and ids[0] == 2
    assert np.isinf(r[1]) and ids[1] == 0


@pytest.mark.parametrize("axis", [(0, 0, 1), (1, 0, 0), (0, 1, 0), (1, 2, 3), (-0.3, 0.2, 1)])
def test_cylinder_any_axis_hits_surface(axis):
    axis = _unit(axis)
    radius, length = 0.4, 2.0
    base = np.array([3.0, 0.5, -0.2]) - axis * length / 2
    side = CylinderSide(5, base, axis, radius, length)
    rng = np.random.default_rng(1)
    # Aim at points on the surface known by construction; visible ones are hit exactly there.
    perp = np.cross(axis, [0.3, 0.5, 0.8])
    perp /= np.linalg.norm(perp)
    perp2 = np.cross(axis, perp)
    ang = rng.uniform(0, 2 * np.pi, 200)
    s = rng.uniform(0.05, length - 0.05, 200)
    targets = base + np.outer(s, axis) + radius * (np.outer(np.cos(ang), perp) + np.outer(np.sin(ang), perp2))
    d = _unit(targets)
    r, ids = cast(Scene([side]), np.zeros((200, 3)), d)
    hits = np.isfinite(r)
    assert hits.all()
    points = d * r[:, None]
    rel = points - base
    radial = rel - np.outer(rel @ axis, axis)
    assert np.allclose(np.linalg.norm(radial, axis=1), radius, atol=1e-9)
    # Either the target itself was hit or it is hidden behind a nearer part of the tube.
    dist_target = np.linalg.norm(targets, axis=1)
    assert np.all(r <= dist_target + 1e-9)
    assert np.all((r < dist_target - 1e-6) | np.isclose(r, dist_target, atol=1e-9))
    assert set(ids.tolist()) == {5}


def test_cylinder_finite_length_and_caps():
    parts = cylinder((3, 0, 0), (0, 0, 1), 0.5, 1.0, caps=True, first_id=10)
    scene = Scene(parts)
    # Above the top: looking down hits the top cap at z = 1.
    r, ids = cast(scene, [[3, 0, 3], [3, 0, 0.5], [0, 0, 1.5]], [[0, 0, -1], [1, 0, 0], [1, 0, 0]])
    assert r[0] == pytest.approx(2.0) and ids[0] == 12
    # From the axis inside the tube the side is hit at the radius.
    assert r[1] == pytest.approx(0.5) and ids[1] == 10
    # Above the finite cylinder: miss.
    assert np.isinf(r[2]) and ids[2] == 0
    assert isinstance(parts[1], Disk) and parts[1].id == 11


def test_nearest_hit_ordering_independent_of_scene_order():
    near = SphereSurface(1, (2, 0, 0), 0.5)
    far = Rectangle(2, (6, 0, 0), (0, 1, 0), (0, 0, 1), 3, 3)
    for order in ([near, far], [far, near]):
        r, ids = cast(Scene(order), [[0, 0, 0], [0, 0, 0]], [[1, 0, 0], _unit([1, 0.5, 0])])
        assert r[0] == pytest.approx(1.5) and ids[0] == 1
        assert r[1] == pytest.approx(np.hypot(6, 3)) and ids[1] == 2


def test_box_faces_each_own_id_with_yaw():
    yaw = np.deg2rad(30)
    faces = box((4, 0, 0), (1, 2, 0.5), yaw=yaw, first_id=20)
    assert [f.id for f in faces] == [20, 21, 22, 23, 24]
    scene = Scene(faces)
    # Looking down onto the top face.
    r, ids = cast(scene, [[4, 0, 2]], [[0, 0, -1]])
    assert r[0] == pytest.approx(1.75) and ids[0] == 20
    # Along the box's -x axis from outside: hits the -x face at distance 2.5 - 0.5.
    ex = np.array([np.cos(yaw), np.sin(yaw), 0])
    o = np.array([4, 0, 0]) - 2.5 * ex
    r, ids = cast(scene, o[None], ex[None])
    assert r[0] == pytest.approx(2.0) and ids[0] == 21
    truth = scene.truth()[21]
    assert abs(abs(truth.normal @ ex) - 1) < 1e-12


def test_room_ids_and_distances():
    scene = Scene(room(first_id=1))
    dirs = np.array([[0, 0, -1], [0, 0, 1], [-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0]], float)
    r, ids = cast(scene, np.zeros((6, 3)), dirs)
    assert ids.tolist() == [1, 2, 3, 4, 5, 6]
    assert np.allclose(r, [0.5, 2.1, 1.0, 5.0, 2.0, 2.0])
    assert set(scene.truth()) == {1, 2, 3, 4, 5, 6}


def test_duplicate_ids_rejected_and_bad_types():
    with pytest.raises(ValueError, match="unique"):
        Scene([sphere((1, 0, 0), 0.2, first_id=1), sphere((2, 0, 0), 0.2, first_id=1)])
    with pytest.raises(TypeError):
        Scene([object()])
    with pytest.raises(ValueError, match="positive"):
        SphereSurface(0, (0, 0, 0), 1.0)
    with pytest.raises(ValueError, match="radius"):
        SphereSurface(1, (0, 0, 0), -1.0)


def test_cast_validates_input():
    scene = Scene(sphere((1, 0, 0), 0.2, first_id=1))
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        cast(scene, np.zeros(3), np.zeros(3))
    with pytest.raises(ValueError, match="shape of origins"):
        cast(scene, np.zeros((2, 3)), np.zeros((3, 3)))
    with pytest.raises(ValueError, match="unit"):
        cast(scene, np.zeros((1, 3)), [[2, 0, 0]])
    with pytest.raises(ValueError, match="finite"):
        cast(scene, [[np.nan, 0, 0]], [[1, 0, 0]])
    with pytest.raises(TypeError):
        cast([1, 2], np.zeros((1, 3)), [[1, 0, 0]])
    r, ids = cast(scene, np.zeros((0, 3)), np.zeros((0, 3)))
    assert r.shape == (0,) and ids.shape == (0,)


def test_transformed_scene_moves_truth():
    scene = Scene(cylinder((0, 0, 0), (0, 0, 1), 0.3, 1.0, caps=False, first_id=1))
    rot = rotation_from_to((0, 0, 1), (1, 0, 0))
    moved = scene.transformed(rot, (0, 0, 2))
    model = moved.truth()[1]
    assert np.allclose(model.axis, [1, 0, 0])
    assert np.allclose(model.point, [0.5, 0, 2])
    with pytest.raises(ValueError, match="rotation"):
        scene.transformed(np.eye(3) * 2, (0, 0, 0))
