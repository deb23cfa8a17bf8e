"""A simulated depth camera (Kinect-like), ray-cast exactly.

Frame: the camera frame, z forward (optical axis), x right, y down, origin at the
optical centre. Scenes built z-up (x forward, y left, z up) are moved into it with
:func:`camera_pose_scene`.

Noise: Gaussian on depth with ``sigma(z) = noise_coeff * z^2`` (metres), default
``1.425e-3`` - CAPE's Kinect model ``1.425e-6 z^2`` with z in mm. Depths outside
``[min_depth, max_depth]`` (default 0.4 - 8 m) are no return. No mixed pixels.
Options for other depth sensors: a constant term ``noise_sigma0`` (``sigma = sigma0 +
noise_coeff z^2``), noise correlated over ``noise_correlation`` x ``noise_correlation``
pixels (stereo matching averages its disparity over a window, so neighbouring depths err
together), depths quantised to ``depth_step`` metres (an 8-bit structured-light scanner)
and disparities in whole steps, so depths in steps of ``step_quadratic z^2`` (a Kinect v1
measures disparity in 1/8 px: ``1 / (8 f b)`` ~ 2.9e-3 /m). The sensor matrix's Kinect
draws no such steps (:mod:`rangeseg_o3d.synthetic.matrix`).
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


def _unit_noise(rng, shape, correlation: int) -> np.ndarray:
    """Standard normal noise; with ``correlation > 1`` the mean of a box of that size
    (rescaled to unit variance), so neighbouring pixels err together."""
    if correlation == 1:
        return rng.normal(0.0, 1.0, size=shape)
    pad = rng.normal(0.0, 1.0, size=(shape[0] + correlation - 1, shape[1] + correlation - 1))
    summed = np.cumsum(np.cumsum(np.pad(pad, ((1, 0), (1, 0))), axis=0), axis=1)
    k = correlation
    box = summed[k:, k:] - summed[:-k, k:] - summed[k:, :-k] + summed[:-k, :-k]
    return box / k


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
    noise_sigma0: float = 0.0,
    noise_correlation: int = 1,
    depth_step: float = 0.0,
    step_quadratic: float = 0.0,
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
    if not (np.isfinite(noise_sigma0) and noise_sigma0 >= 0):
        raise ValueError(f"noise_sigma0 must be >= 0; got {noise_sigma0}")
    if int(noise_correlation) != noise_correlation or noise_correlation < 1:
        raise ValueError(f"noise_correlation must be a positive integer; got {noise_correlation}")
    if not (np.isfinite(depth_step) and depth_step >= 0):
        raise ValueError(f"depth_step must be >= 0; got {depth_step}")
    if not (np.isfinite(step_quadratic) and step_quadratic >= 0):
        raise ValueError(f"step_quadratic must be a finite number >= 0 (1/m); got {step_quadratic}")
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
    if noise_coeff > 0 or noise_sigma0 > 0:
        finite = np.isfinite(depth)
        unit = _unit_noise(rng, depth.shape, int(noise_correlation))
        # Two terms rather than one sigma: the Kinect-only case stays bit-identical to earlier runs.
        depth = depth + unit * noise_coeff * np.where(finite, depth, 0.0) ** 2 + unit * noise_sigma0
    if depth_step > 0:
        depth = np.round(depth / depth_step) * depth_step
    if step_quadratic > 0:
        # disparity measured in whole steps: 1 / (step_quadratic z) is the disparity in
        # steps (8 f b / z for a 1/8-pixel Kinect), so depth steps by step_quadratic z^2
        with np.errstate(divide="ignore", invalid="ignore"):
            steps = np.round(1.0 / (step_quadratic * depth))
            depth = np.where(np.isfinite(depth) & (depth > 0), 1.0 / (step_quadratic * steps), depth)
    no_return = ~np.isfinite(depth) | (depth < min_depth) | (depth > max_depth) | (ids == 0)
    depth[no_return] = 0.0
    ids[no_return] = 0
    cloud = OrganizedCloud.from_depth(depth, fx, fy, cx, cy)
    return SyntheticScan(cloud=cloud, truth_ids=ids.astype(np.int32), truth=scene.truth(seen=ids), scene=scene)
