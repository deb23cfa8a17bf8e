"""Benchmark scenes with ground truth: a default room and suites for the LMS200 and RGB-D presets.

LMS200 scenes are in the nodding laser's base frame (x forward, y left, z up, tilt axis
at the origin); unless a scene says otherwise the floor is 0.5 m below the tilt axis.
RGB-D scenes are built z-up and moved into the camera frame (z forward, x right, y down)
by :func:`~rangeseg_o3d.synthetic.depth_camera.camera_pose_scene`.
Everything is deterministic given ``seed`` (scene ``k`` of a suite uses ``seed + k``).
"""

from __future__ import annotations

import numpy as np

from .depth_camera import camera_pose_scene, simulate_depth_camera
from .lms200 import simulate_lms200
from .scene import Scene, SyntheticScan, box, cylinder, room, sphere

__all__ = ["default_scene", "lms200_scenes", "lms200_suite", "rgbd_scenes", "rgbd_suite"]


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v)


def default_scene() -> Scene:
    """A 6 x 4 x 2.6 m room with two boxes, a vertical cylinder, a tilted cylinder and a sphere.

    Ids: room 1-6 (floor, ceiling, walls -x, +x, -y, +y); box A 7-11; box B 12-16;
    vertical cylinder 17 (caps 18, 19); tilted cylinder 20 (caps 21, 22); sphere 23.
    """
    return Scene([
        room(x=(-1.0, 5.0), y=(-2.0, 2.0), z=(-0.5, 2.1), first_id=1),
        box((2.6, -1.1, -0.1), (0.6, 0.6, 0.8), yaw=0.5, first_id=7),
        box((3.9, 1.2, -0.15), (0.8, 0.5, 0.7), yaw=-0.3, first_id=12),
        cylinder((2.3, 0.9, -0.5), (0, 0, 1), 0.2, 1.4, first_id=17),
        cylinder((3.4, -0.7, -0.35), _unit((0.2, 1.0, 0.5)), 0.2, 1.2, first_id=20),
        sphere((3.2, 0.1, 0.25), 0.3, first_id=23),
    ])


def lms200_scenes() -> list[tuple[str, Scene]]:
    """The scenes of :func:`lms200_suite`, by name."""
    scenes = [("default", default_scene())]
    scenes.append(("long_room", Scene([
        room(x=(-1.0, 7.5), y=(-2.5, 2.5), z=(-0.5, 2.5), first_id=1),
        box((6.5, -1.0, -0.1), (1.0, 0.8, 0.8), yaw=0.2, first_id=7),
        sphere((6.0, 1.0, 0.3), 0.5, first_id=12),
        cylinder((5.0, 0.2, -0.5), (0, 0, 1), 0.3, 1.6, first_id=13),
    ])))
    scenes.append(("boxes_yawed", Scene([
        room(x=(-1.0, 5.5), y=(-2.2, 2.2), z=(-0.5, 2.1), first_id=1),
        box((2.0, -0.8, -0.15), (0.6, 0.5, 0.7), yaw=0.7, first_id=7),
        box((3.3, 0.4, -0.05), (0.7, 0.7, 0.9), yaw=-0.4, first_id=12),
        box((4.4, -1.3, 0.0), (0.6, 0.6, 1.0), yaw=1.2, first_id=17),
    ])))
    scenes.append(("cylinder_vertical", Scene([
        room(x=(-1.0, 5.0), y=(-2.0, 2.0), z=(-0.5, 2.1), first_id=1),
        cylinder((1.6, -0.5, -0.5), (0, 0, 1), 0.3, 1.8, first_id=7),
        cylinder((3.5, 0.9, -0.5), (0, 0, 1), 0.15, 1.5, first_id=10),
    ])))
    scenes.append(("cylinder_along_x", Scene([
        room(x=(-1.0, 6.0), y=(-2.0, 2.0), z=(-0.5, 2.1), first_id=1),
        cylinder((1.5, 0.9, -0.25), (1, 0, 0), 0.25, 3.0, first_id=7),
        cylinder((2.0, -0.9, 0.6), (1, 0, 0), 0.2, 2.5, first_id=10),
    ])))
    scenes.append(("cylinder_along_y", Scene([
        room(x=(-1.0, 5.0), y=(-2.0, 2.0), z=(-0.5, 2.1), first_id=1),
        cylinder((2.5, -1.2, -0.25), (0, 1, 0), 0.25, 2.4, first_id=7),
        cylinder((4.0, -1.0, 0.8), (0, 1, 0), 0.2, 2.0, first_id=10),
    ])))
    scenes.append(("spheres", Scene([
        room(x=(-1.0, 6.5), y=(-2.0, 2.0), z=(-0.5, 2.1), first_id=1),
        sphere((1.3, -0.4, 0.05), 0.15, first_id=7),
        sphere((3.0, 0.8, 0.1), 0.3, first_id=8),
        sphere((5.5, -0.8, 0.4), 0.5, first_id=9),
    ])))
    scenes.append(("tilted_cylinders", Scene([
        room(x=(-1.0, 5.0), y=(-2.0, 2.0), z=(-0.5, 2.1), first_id=1),
        cylinder((2.2, -1.0, -0.3), _unit((0.5, 1.0, 0.6)), 0.2, 1.2, first_id=7),
        cylinder((3.5, 0.5, -0.4), _unit((-0.3, 0.4, 1.0)), 0.25, 1.3, first_id=10),
    ])))
    scenes.append(("near_objects", Scene([
        room(x=(-1.0, 4.0), y=(-1.8, 1.8), z=(-0.5, 2.1), first_id=1),
        box((1.3, -0.6, -0.2), (0.4, 0.4, 0.6), yaw=0.3, first_id=7),
        sphere((1.5, 0.5, 0.0), 0.25, first_id=12),
    ])))
    scenes.append(("corridor_clutter", Scene([
        room(x=(-1.0, 7.0), y=(-1.3, 1.3), z=(-0.5, 2.3), first_id=1),
        box((2.5, -0.9, -0.15), (0.5, 0.6, 0.7), yaw=0.0, first_id=7),
        cylinder((3.5, 0.9, -0.5), (0, 0, 1), 0.2, 1.5, first_id=12),
        sphere((5.0, -0.5, 0.2), 0.35, first_id=15),
        box((6.2, 0.5, -0.1), (0.6, 0.6, 0.8), yaw=0.4, first_id=16),
    ])))
    return scenes


def lms200_suite(seed: int = 0, **simulate_kwargs) -> list[tuple[str, SyntheticScan]]:
    """Simulated LMS200 scans (70 x 131) of :func:`lms200_scenes`; kwargs go to simulate_lms200."""
    return [
        (name, simulate_lms200(scene, seed=seed + k, **simulate_kwargs))
        for k, (name, scene) in enumerate(lms200_scenes())
    ]


def rgbd_scenes() -> list[tuple[str, Scene]]:
    """The scenes of :func:`rgbd_suite` (camera frame)."""
    office = Scene([
        room(x=(-1.0, 5.0), y=(-2.5, 2.5), z=(0.0, 2.7), first_id=1),
        box((2.4, -0.7, 0.35), (0.7, 0.6, 0.7), yaw=0.4, first_id=7),
        box((3.4, 0.9, 0.5), (0.8, 0.5, 1.0), yaw=-0.3, first_id=12),
    ])
    objects = Scene([
        room(x=(-1.0, 5.0), y=(-2.5, 2.5), z=(0.0, 2.7), first_id=1),
        cylinder((2.2, 0.6, 0.0), (0, 0, 1), 0.2, 1.2, first_id=7),
        cylinder((2.6, -1.0, 0.2), (0, 1, 0), 0.2, 1.2, first_id=10),
        sphere((3.0, -0.2, 0.35), 0.35, first_id=13),
    ])
    tunnel = Scene([
        cylinder((-1.0, 0.0, 1.3), (1, 0, 0), 2.0, 12.0, caps=False, first_id=1),
        room(x=(-1.0, 11.0), y=(-1.6, 1.6), z=(0.0, 3.4), first_id=2)[0],
    ])
    return [
        ("rgbd_office", camera_pose_scene(office, position=(0.0, 0.0, 1.3), pitch=0.35)),
        ("rgbd_objects", camera_pose_scene(objects, position=(0.0, 0.0, 1.3), pitch=0.3)),
        ("rgbd_tunnel", camera_pose_scene(tunnel, position=(0.0, 0.0, 1.5), yaw=0.15, pitch=0.1)),
    ]


def rgbd_suite(seed: int = 0, **simulate_kwargs) -> list[tuple[str, SyntheticScan]]:
    """Simulated 640 x 480 depth frames of :func:`rgbd_scenes`; kwargs go to simulate_depth_camera."""
    return [
        (name, simulate_depth_camera(scene, seed=seed + k, **simulate_kwargs))
        for k, (name, scene) in enumerate(rgbd_scenes())
    ]
