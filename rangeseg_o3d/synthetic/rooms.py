"""Random scenes for the sensor matrix: rooms with boxes, columns, pipes and balls, and
ABW-like tabletops of polyhedra.

Every scene is an independent draw from a numpy Generator, so a benchmark can score a
sensor on as many unseen scenes as it likes (tune for the sensor model, never for a
scene). Frames: rooms are built z-up around a sensor at the origin (x forward, y left);
:func:`random_room` puts the objects in front of the sensor (``around=False``, a
nodding laser or a camera looking along +x) or all around it (``around=True``, a
spinning lidar). :func:`random_tabletop` builds blocks on a table around the origin
(z up); move it into a camera frame with :func:`~rangeseg_o3d.synthetic.depth_camera.camera_pose_scene`.
"""

from __future__ import annotations

import numpy as np

from .scene import Rectangle, Scene, box, cylinder, room, sphere

__all__ = ["oriented_box", "random_room", "random_tabletop", "OBJECT_KINDS"]

#: What :func:`random_room` places: boxes on the floor, floor-to-ceiling columns,
#: horizontal pipes (capped) at any height, balls on the floor.
OBJECT_KINDS = ("box", "column", "pipe", "ball")
# Clearance between objects' footprints and from the walls, metres.
_GAP = 0.15
_WALL_MARGIN = 0.3
_TRIES = 60


def oriented_box(center, size, rotation, *, first_id: int) -> list[Rectangle]:
    """A box of ``size = (sx, sy, sz)`` around ``center`` with its axes turned by ``rotation``.

    All six faces, ids from ``first_id``: +z, -z, -x, +x, -y, +y of the box's own frame.
    """
    rot = np.asarray(rotation, dtype=float)
    if rot.shape != (3, 3):
        raise ValueError(f"rotation must have shape (3, 3); got {rot.shape}")
    c = np.asarray(center, dtype=float)
    sx, sy, sz = (float(s) for s in np.asarray(size, dtype=float).reshape(3))
    ex, ey, ez = rot.T
    return [
        Rectangle(first_id, c + ez * sz / 2, ex, ey, sx / 2, sy / 2),
        Rectangle(first_id + 1, c - ez * sz / 2, ex, ey, sx / 2, sy / 2),
        Rectangle(first_id + 2, c - ex * sx / 2, ey, ez, sy / 2, sz / 2),
        Rectangle(first_id + 3, c + ex * sx / 2, ey, ez, sy / 2, sz / 2),
        Rectangle(first_id + 4, c - ey * sy / 2, ex, ez, sx / 2, sz / 2),
        Rectangle(first_id + 5, c + ey * sy / 2, ex, ez, sx / 2, sz / 2),
    ]


def _rotation(axis, angle: float) -> np.ndarray:
    """Rodrigues' rotation about a unit ``axis``."""
    k = np.asarray(axis, dtype=float)
    k = k / np.linalg.norm(k)
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * kx + (1 - np.cos(angle)) * kx @ kx


class _Footprints:
    """Discs on the floor already taken; a new one must clear them by ``_GAP``."""

    def __init__(self, keep_out: list[tuple[float, float, float]], gap: float = _GAP):
        self.discs = list(keep_out)
        self.gap = gap

    def fits(self, x: float, y: float, r: float) -> bool:
        return all(np.hypot(x - a, y - b) >= r + c + self.gap for a, b, c in self.discs)

    def take(self, x: float, y: float, r: float) -> None:
        self.discs.append((x, y, r))


def _place(rng, footprints: _Footprints, radius: float, sample_xy) -> tuple[float, float] | None:
    for _ in range(_TRIES):
        where = sample_xy()
        if where is None:
            return None
        x, y = where
        if footprints.fits(x, y, radius):
            footprints.take(x, y, radius)
            return x, y
    return None


def random_room(
    rng: np.random.Generator,
    *,
    around: bool = False,
    n_objects: int | None = None,
    sensor_height: tuple[float, float] = (0.4, 0.9),
    max_range: float = 8.0,
) -> Scene:
    """A random room with boxes, columns, pipes and balls, seen by a sensor at the origin.

    Parameters
    ----------
    rng : numpy Generator (the only source of randomness).
    around : False: a room in front of the sensor (x from -1 m to 4.5-7.5 m, objects at
        x >= 1.3 m within +-60 deg of +x); True: the sensor stands inside a 6-16 x 6-12 m
        room and objects surround it (no closer than 1.2 m).
    n_objects : objects to place (default 4-7 in front, 7-12 around); fewer when the room
        is full.
    sensor_height : the sensor's height above the floor is drawn from this range, metres.
    max_range : the room is kept within this distance in front of the sensor.

    Returns
    -------
    Scene
        Room ids 1-6 (floor, ceiling, walls -x, +x, -y, +y as :func:`room`), then the
        objects' surfaces in order of placement.
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy Generator; got {type(rng).__name__}")
    height = rng.uniform(*sensor_height)
    floor = -height
    ceiling = floor + rng.uniform(2.5, 3.2)
    if around:
        x = (-rng.uniform(3.0, 8.0), rng.uniform(3.0, 8.0))
        y = (-rng.uniform(3.0, 6.0), rng.uniform(3.0, 6.0))
        keep_out = [(0.0, 0.0, 1.2)]
        count = int(rng.integers(7, 13)) if n_objects is None else int(n_objects)
    else:
        half_y = rng.uniform(1.8, 3.0)
        depth = min(rng.uniform(4.5, 7.5), np.sqrt(max(max_range**2 - half_y**2, 9.0)))
        x = (-1.0, depth)
        y = (-half_y, half_y)
        keep_out = [(0.0, 0.0, 1.2)]
        count = int(rng.integers(4, 8)) if n_objects is None else int(n_objects)

    def sample_xy(radius):
        # A footprint wider than the room's free floor has no place: None, and the
        # object is skipped (the room is "full" for it) instead of drawing from an
        # empty interval.
        def draw():
            if around:
                low_x, high_x = x[0] + _WALL_MARGIN + radius, x[1] - _WALL_MARGIN - radius
                low_y, high_y = y[0] + _WALL_MARGIN + radius, y[1] - _WALL_MARGIN - radius
                if high_x < low_x or high_y < low_y:
                    return None
                return rng.uniform(low_x, high_x), rng.uniform(low_y, high_y)
            low_x, high_x = 1.3 + radius, x[1] - _WALL_MARGIN - radius
            if high_x < low_x or y[1] - _WALL_MARGIN - radius < 0:
                return None
            px = rng.uniform(low_x, high_x)
            limit = min(y[1] - _WALL_MARGIN - radius, px * np.tan(np.deg2rad(60)))
            return px, rng.uniform(-limit, limit)
        return draw

    surfaces = [room(x=x, y=y, z=(floor, ceiling), first_id=1)]
    next_id = 7
    footprints = _Footprints(keep_out)
    for _ in range(count):
        kind = OBJECT_KINDS[int(rng.integers(len(OBJECT_KINDS)))]
        if kind == "box":
            size = (rng.uniform(0.3, 1.0), rng.uniform(0.3, 1.0), rng.uniform(0.4, 1.2))
            radius = np.hypot(size[0], size[1]) / 2
            where = _place(rng, footprints, radius, sample_xy(radius))
            if where is None:
                continue
            parts = box((*where, floor + size[2] / 2), size, yaw=rng.uniform(0, np.pi), first_id=next_id)
        elif kind == "column":
            radius = rng.uniform(0.12, 0.3)
            where = _place(rng, footprints, radius, sample_xy(radius))
            if where is None:
                continue
            parts = cylinder((*where, floor), (0, 0, 1), radius, ceiling - floor, caps=False, first_id=next_id)
        elif kind == "pipe":
            radius = rng.uniform(0.1, 0.22)
            length = rng.uniform(1.0, 2.5)
            where = _place(rng, footprints, length / 2 + radius, sample_xy(length / 2 + radius))
            if where is None:
                continue
            yaw = rng.uniform(0, np.pi)
            axis = np.array([np.cos(yaw), np.sin(yaw), 0.0])
            z = rng.uniform(floor + radius + 0.3, ceiling - radius - 0.3)
            base = np.array([*where, z]) - axis * length / 2
            parts = cylinder(base, axis, radius, length, first_id=next_id)
        else:
            radius = rng.uniform(0.2, 0.45)
            where = _place(rng, footprints, radius, sample_xy(radius))
            if where is None:
                continue
            parts = sphere((*where, floor + radius), radius, first_id=next_id)
        surfaces.append(parts)
        next_id += len(parts)
    return Scene(surfaces)


def random_tabletop(rng: np.random.Generator, *, n_blocks: int | None = None) -> Scene:
    """Polyhedral blocks on a table top (ABW-like), around the origin, z up.

    The table top (id 1) is a 1.2 x 1.2 m plane at z = 0 with a wall 0.35 m behind the
    blocks (id 2, the background ABW images show); 3-6 blocks of 3-10 cm, each either
    standing (turned about z), tilted (turned 10-35 deg about a horizontal axis, lowest
    corner on the table) or carrying a smaller block on top. Each block is an
    :func:`oriented_box` (six ids; faces hidden inside the table are simply never seen).
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a numpy Generator; got {type(rng).__name__}")
    surfaces = [
        Rectangle(1, (0.0, 0.0, 0.0), (1, 0, 0), (0, 1, 0), 0.6, 0.6),
        Rectangle(2, (0.35, 0.0, 0.3), (0, 1, 0), (0, 0, 1), 0.6, 0.3),
    ]
    next_id = 3
    count = int(rng.integers(3, 7)) if n_blocks is None else int(n_blocks)
    footprints = _Footprints([], gap=0.01)

    def draw():
        return rng.uniform(-0.1, 0.1), rng.uniform(-0.1, 0.1)

    for _ in range(count):
        size = rng.uniform(0.03, 0.10, size=3)
        radius = np.linalg.norm(size) / 2
        where = _place(rng, footprints, radius, draw)
        if where is None:
            continue
        rotation = _rotation((0, 0, 1), rng.uniform(0, np.pi / 2))
        style = rng.uniform()
        if style < 0.35:
            tilt_axis = rotation @ np.array([1.0, 0.0, 0.0])
            rotation = _rotation(tilt_axis, rng.uniform(np.deg2rad(10), np.deg2rad(35))) @ rotation
        corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * size / 2
        lowest = (corners @ rotation.T)[:, 2].min()
        center = np.array([*where, -lowest])
        block = oriented_box(center, size, rotation, first_id=next_id)
        surfaces.append(block)
        next_id += len(block)
        if 0.35 <= style < 0.6:
            top_size = size * rng.uniform(0.4, 0.8, size=3)
            top_rotation = _rotation((0, 0, 1), rng.uniform(0, np.pi / 2)) @ rotation
            top_center = center + rotation[:, 2] * (size[2] / 2 + top_size[2] / 2)
            top = oriented_box(top_center, top_size, top_rotation, first_id=next_id)
            surfaces.append(top)
            next_id += len(top)
    return Scene(surfaces)
