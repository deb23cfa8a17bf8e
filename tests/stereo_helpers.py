"""A stereo camera's view of a pipe (or a board as wide) before a wall, for tests of the steps
that ask plane regions for pipes (bent_planes, curved_pairs)."""

import numpy as np

import rangeseg_o3d as rs
from rangeseg_o3d.synthetic.depth_camera import _unit_noise

COEFF = 0.1 / (640 * 0.05)  # the sensor matrix's stereo row: range sigma per squared metre
SHARE = 1.0 / 9.0  # independent returns a pixel carries over a 3 x 3 matching window


def stereo_pipe_scene(seed, *, radius=0.15, z=6.0, flat=False, rows=160, cols=200, f=1000.0, recede_deg=0.0):
    """A vertical pipe (or, with ``flat``, a board as wide facing the camera) ``z`` m ahead in
    front of a wall at z + 1.5 m; stereo range noise (0.003125 r^2 a sigma) erring together over
    3 x 3 pixels. ``recede_deg`` turns the pipe's axis about the x axis, away from the camera at
    the top, by that angle from the image plane. Returns ``(cloud, sigma, truth)``: 1 the pipe or
    board, 2 the wall."""
    v, u = np.mgrid[0:rows, 0:cols].astype(float)
    rays = np.dstack([(u - cols / 2) / f, (v - rows / 2) / f, np.ones((rows, cols))])
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    wall = (z + 1.5) / rays[..., 2]
    if flat:
        t = z / rays[..., 2]
        hit = np.abs(rays[..., 0] * t) <= radius
    else:  # the ray's entry into the cylinder |(t ray - p) x axis| = r
        axis = np.array([0.0, np.cos(np.radians(recede_deg)), -np.sin(np.radians(recede_deg))])
        across = rays - (rays @ axis)[..., None] * axis
        origin = -np.array([0.0, 0.0, z])
        offset = origin - (origin @ axis) * axis
        a = np.sum(across * across, axis=2)
        b = 2 * across @ offset
        c = offset @ offset - radius ** 2
        disc = b * b - 4 * a * c
        t = (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a)
        hit = disc > 0
    truth = np.where(hit, 1, 2).astype(np.int32)
    ranges = np.where(hit, t, wall)
    sigma = COEFF * ranges ** 2
    noisy = ranges + _unit_noise(np.random.default_rng(seed), ranges.shape, 3) * sigma
    return rs.OrganizedCloud(rays * noisy[..., None]), sigma, truth
