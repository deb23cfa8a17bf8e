"""A simulated depth camera (Kinect-like), ray-cast exactly.

Frame: the camera frame, z forward (optical axis), x right, y down, origin at the
optical centre. Scenes built z-up (x forward, y left, z up) are moved into it with
:func:`camera_pose_scene`.

Noise: Gaussian on depth with ``sigma(z) = noise_coeff * z^2`` (metres), default
``1.425e-3`` - CAPE's Kinect model ``1.425e-6 z^2`` with z in mm. Depths outside
``[min_depth, max_depth]`` (default 0.4 - 8 m) are no return. No mixed pixels.
"""

from __future__ import annotations

import numpy as np

from ..cloud import OrganizedCloud
from .raycast import cast
from .scene import Scene, SyntheticScan

__all__ = ["simulate_depth_camera", "camera_pose_scene", "KINECT_NOISE"]

KINECT_NOISE = 1.425e-3
# Camera axes (x right, y down, z forward) expressed in a z-up world (x forward, y left, z up).
_WORLD_FROM_CAMERA_LEVEL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def camera_pose_scene(scene: Scene, *, position=(0.0, 0.0, 0.0), yaw: float = 0.0, pitch: float = 0.0) -> Scene:
    """Express a z-up scene (x forward, y left, z up) in the frame of a camera.

    The camera sits at ``position`` (world), looks along world +x turned by ``yaw``
    (about +z, positive to the left) and ``pitch`` (positive looking down), no roll.
    """
    cy, sy = np.cos(yaw), np.sin(yaw)
    cp, sp = np.cos(pitch), np.sin(pitch)
    yaw_rot = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    pitch_rot = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])  # about +y, + looks down
    world_from_camera = yaw_rot @ pitch_rot @ _WORLD_FROM_CAMERA_LEVEL
    camera_from_world = world_from_camera.T
    shift = -camera_from_world @ np.asarray(position, dtype=float)
    return scene.transformed(camera_from_world, shift)


def simulate_depth_camera(
    scene: Scene,
    *,
    width: int = 640,
    height: int = 480,
    fx: float = 525.0,
    fy: float = 525.0,
    cx: float = 319.5,
    cy: float = 239.5,
    noise_coeff: float = KINECT_NOISE,
    min_depth: float = 0.4,
    max_depth: float = 8.0,
    seed=0,
) -> SyntheticScan:
    """Render a depth frame of ``scene`` (camera frame: z forward, x right, y down).

    Returns
    -------
    SyntheticScan
        ``cloud`` from :meth:`OrganizedCloud.from_depth` (PinholeGeometry), ``truth_ids``
        (0 = no return) and ``truth`` of the surfaces seen.

    Examples
    --------
    >>> from rangeseg_o3d.synthetic.scene import Scene, room
    >>> scene = camera_pose_scene(Scene(room(first_id=1)), position=(0, 0, 1.0))
    >>> scan = simulate_depth_camera(scene, width=64, height=48, fx=52.5, fy=52.5, cx=31.5, cy=23.5)
    >>> scan.cloud.shape
    (48, 64)
    """
    for name, value in (("width", width), ("height", height)):
        if int(value) != value or value < 1:
            raise ValueError(f"{name} must be a positive integer; got {value}")
    if not (np.isfinite(noise_coeff) and noise_coeff >= 0):
        raise ValueError(f"noise_coeff must be >= 0; got {noise_coeff}")
    if not (0 <= min_depth < max_depth):
        raise ValueError(f"need 0 <= min_depth < max_depth; got {min_depth}, {max_depth}")
    width, height = int(width), int(height)
    u = (np.arange(width, dtype=float) - cx) / fx
    v = (np.arange(height, dtype=float) - cy) / fy
    rays = np.stack(np.broadcast_arrays(u[None, :], v[:, None], np.ones((height, width))), axis=-1)
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    ranges, ids = cast(scene, np.zeros((width * height, 3)), rays.reshape(-1, 3))
    depth = (ranges * rays[..., 2].ravel()).reshape(height, width)
    ids = ids.reshape(height, width)
    rng = np.random.default_rng(seed)
    if noise_coeff > 0:
        finite = np.isfinite(depth)
        noise = rng.normal(0.0, 1.0, size=depth.shape) * noise_coeff * np.where(finite, depth, 0.0) ** 2
        depth = depth + noise
    no_return = ~np.isfinite(depth) | (depth < min_depth) | (depth > max_depth) | (ids == 0)
    depth[no_return] = 0.0
    ids[no_return] = 0
    cloud = OrganizedCloud.from_depth(depth, fx, fy, cx, cy)
    return SyntheticScan(cloud=cloud, truth_ids=ids.astype(np.int32), truth=scene.truth(seen=ids), scene=scene)
