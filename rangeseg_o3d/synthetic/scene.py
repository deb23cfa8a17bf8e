"""Scene description for synthetic scans: bounded surfaces with integer ids and true models.

Four primitive surfaces are ray-cast exactly (see :mod:`rangeseg_o3d.synthetic.raycast`):

* :class:`Rectangle` - a bounded planar patch (truth: :class:`~rangeseg_o3d.fitting.primitives.Plane`);
* :class:`Disk` - a planar disc, used for cylinder caps (truth: Plane);
* :class:`CylinderSide` - the lateral surface of a finite cylinder (truth: Cylinder);
* :class:`SphereSurface` - a whole sphere (truth: Sphere).

Builders assemble composite objects from them and number their surfaces
consecutively from ``first_id``:

* :func:`room` - floor, ceiling and four walls, each its own id;
* :func:`box` - an axis-aligned-then-yawed box, each face its own id (bottom omitted
  by default because a box standing on the floor never shows it);
* :func:`cylinder` - lateral surface ``first_id``, caps ``first_id + 1`` (at ``base``)
  and ``first_id + 2`` (at the other end) when ``caps=True``; without caps the tube is
  open and its inside is visible through the ends;
* :func:`sphere`, :func:`patch`.

Id 0 is reserved for "nothing" in truth images, so surface ids are positive.
All surfaces are two-sided. Coordinates are metres in whatever frame the sensor
simulator uses (the nodding laser's base frame, or the camera frame);
:meth:`Scene.transformed` moves a scene built in a convenient world frame into it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..fitting.primitives import Cylinder, Plane, Sphere

__all__ = [
    "Rectangle",
    "Disk",
    "CylinderSide",
    "SphereSurface",
    "Scene",
    "SyntheticScan",
    "room",
    "box",
    "cylinder",
    "sphere",
    "patch",
    "rotation_z",
    "rotation_from_to",
]


def _vector(name: str, value) -> np.ndarray:
    arr = np.asarray(value, dtype=float)
    if arr.shape != (3,):
        raise ValueError(f"{name} must be a 3-vector; got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite; got {arr.tolist()}")
    arr = arr.copy()
    arr.setflags(write=False)
    return arr


def _unit(name: str, value) -> np.ndarray:
    arr = _vector(name, value)
    norm = np.linalg.norm(arr)
    if norm < 1e-12:
        raise ValueError(f"{name} must be a non-zero vector; got {arr.tolist()}")
    out = arr / norm
    out.setflags(write=False)
    return out


def _positive(name: str, value) -> float:
    value = float(value)
    if not (np.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be a positive finite number; got {value}")
    return value


def _check_id(surface_id) -> int:
    if isinstance(surface_id, bool) or not isinstance(surface_id, (int, np.integer)):
        raise TypeError(f"surface id must be an int; got {type(surface_id).__name__}")
    if surface_id <= 0:
        raise ValueError(f"surface id must be positive (0 means 'nothing'); got {surface_id}")
    return int(surface_id)


def _check_rotation(rotation) -> np.ndarray:
    rot = np.asarray(rotation, dtype=float)
    if rot.shape != (3, 3):
        raise ValueError(f"rotation must have shape (3, 3); got {rot.shape}")
    if not np.allclose(rot @ rot.T, np.eye(3), atol=1e-9) or np.linalg.det(rot) < 0:
        raise ValueError("rotation must be a proper rotation matrix (orthonormal, det +1)")
    return rot


@dataclass(frozen=True, eq=False)
class Rectangle:
    """Planar rectangle ``center + a*u + b*v`` with ``|a| <= half_u``, ``|b| <= half_v``.

    ``u`` and ``v`` are made orthonormal (``v`` is re-orthogonalised against ``u``);
    the normal is ``u x v``.
    """

    id: int
    center: np.ndarray
    u: np.ndarray
    v: np.ndarray
    half_u: float
    half_v: float

    def __post_init__(self):
        object.__setattr__(self, "id", _check_id(self.id))
        object.__setattr__(self, "center", _vector("center", self.center))
        u = _unit("u", self.u)
        v = _vector("v", self.v)
        v = _unit("v (orthogonalised against u)", v - (v @ u) * u)
        object.__setattr__(self, "u", u)
        object.__setattr__(self, "v", v)
        object.__setattr__(self, "half_u", _positive("half_u", self.half_u))
        object.__setattr__(self, "half_v", _positive("half_v", self.half_v))

    @property
    def normal(self) -> np.ndarray:
        return np.cross(self.u, self.v)

    def truth(self) -> Plane:
        n = self.normal
        return Plane(normal=n, d=float(n @ self.center), rms=0.0, inliers=0)

    def transformed(self, rotation, translation) -> "Rectangle":
        return Rectangle(self.id, rotation @ self.center + translation, rotation @ self.u,
                         rotation @ self.v, self.half_u, self.half_v)


@dataclass(frozen=True, eq=False)
class Disk:
    """Planar disc of ``radius`` around ``center`` with unit ``normal``."""

    id: int
    center: np.ndarray
    normal: np.ndarray
    radius: float

    def __post_init__(self):
        object.__setattr__(self, "id", _check_id(self.id))
        object.__setattr__(self, "center", _vector("center", self.center))
        object.__setattr__(self, "normal", _unit("normal", self.normal))
        object.__setattr__(self, "radius", _positive("radius", self.radius))

    def truth(self) -> Plane:
        return Plane(normal=self.normal, d=float(self.normal @ self.center), rms=0.0, inliers=0)

    def transformed(self, rotation, translation) -> "Disk":
        return Disk(self.id, rotation @ self.center + translation, rotation @ self.normal, self.radius)


@dataclass(frozen=True, eq=False)
class CylinderSide:
    """Lateral surface of a finite cylinder from ``base`` to ``base + length * axis``."""

    id: int
    base: np.ndarray
    axis: np.ndarray
    radius: float
    length: float

    def __post_init__(self):
        object.__setattr__(self, "id", _check_id(self.id))
        object.__setattr__(self, "base", _vector("base", self.base))
        object.__setattr__(self, "axis", _unit("axis", self.axis))
        object.__setattr__(self, "radius", _positive("radius", self.radius))
        object.__setattr__(self, "length", _positive("length", self.length))

    def truth(self) -> Cylinder:
        # The model's point is the middle of the axis segment (nearest the visible surface's centroid
        # in the usual case of a cylinder seen side-on).
        mid = self.base + 0.5 * self.length * self.axis
        return Cylinder(axis=self.axis, point=mid, radius=self.radius, rms=0.0, inliers=0)

    def transformed(self, rotation, translation) -> "CylinderSide":
        return CylinderSide(self.id, rotation @ self.base + translation, rotation @ self.axis,
                            self.radius, self.length)


@dataclass(frozen=True, eq=False)
class SphereSurface:
    """Sphere of ``radius`` around ``center``."""

    id: int
    center: np.ndarray
    radius: float

    def __post_init__(self):
        object.__setattr__(self, "id", _check_id(self.id))
        object.__setattr__(self, "center", _vector("center", self.center))
        object.__setattr__(self, "radius", _positive("radius", self.radius))

    def truth(self) -> Sphere:
        return Sphere(center=self.center, radius=self.radius, rms=0.0, inliers=0)

    def transformed(self, rotation, translation) -> "SphereSurface":
        return SphereSurface(self.id, rotation @ self.center + translation, self.radius)


SURFACE_TYPES = (Rectangle, Disk, CylinderSide, SphereSurface)


class Scene:
    """A set of surfaces with unique positive ids.

    Parameters
    ----------
    surfaces : iterable of Rectangle, Disk, CylinderSide or SphereSurface
        Nested lists (as returned by the builders) are flattened.

    Raises
    ------
    TypeError
        If an element is not a surface.
    ValueError
        If two surfaces share an id.

    Examples
    --------
    >>> scene = Scene(surfaces=[room(first_id=1), sphere((2, 0, 0), 0.3, first_id=7)])
    >>> len(scene), sorted(scene.truth())[:3]
    (7, [1, 2, 3])
    """

    def __init__(self, surfaces):
        flat = list(_flatten(surfaces))
        seen: dict[int, object] = {}
        for surface in flat:
            if not isinstance(surface, SURFACE_TYPES):
                raise TypeError(
                    "scene surfaces must be Rectangle, Disk, CylinderSide or SphereSurface; "
                    f"got {type(surface).__name__}"
                )
            if surface.id in seen:
                raise ValueError(f"surface ids must be unique; id {surface.id} appears twice")
            seen[surface.id] = surface
        self.surfaces: tuple = tuple(flat)

    def __len__(self) -> int:
        return len(self.surfaces)

    def __iter__(self):
        return iter(self.surfaces)

    def __repr__(self) -> str:
        kinds: dict[str, int] = {}
        for s in self.surfaces:
            kinds[type(s).__name__] = kinds.get(type(s).__name__, 0) + 1
        return f"Scene({len(self)} surfaces: {kinds})"

    @property
    def ids(self) -> list[int]:
        return [s.id for s in self.surfaces]

    def next_id(self) -> int:
        """The smallest id greater than every id in use (1 for an empty scene)."""
        return max(self.ids, default=0) + 1

    def truth(self, seen=None) -> dict:
        """``{id: Plane | Sphere | Cylinder}`` with ``rms=0`` and ``inliers=0``.

        With ``seen`` (an array of ids, e.g. a truth image), only the surfaces it contains.
        """
        if seen is None:
            return {s.id: s.truth() for s in self.surfaces}
        present = set(np.unique(np.asarray(seen)).tolist())
        return {s.id: s.truth() for s in self.surfaces if s.id in present}

    def transformed(self, rotation, translation) -> "Scene":
        """The scene moved by ``p -> rotation @ p + translation`` (ids kept)."""
        rot = _check_rotation(rotation)
        shift = _vector("translation", translation)
        return Scene([s.transformed(rot, shift) for s in self.surfaces])

    def __add__(self, other) -> "Scene":
        if not isinstance(other, Scene):
            return NotImplemented
        return Scene(list(self.surfaces) + list(other.surfaces))


def _flatten(items):
    if isinstance(items, SURFACE_TYPES):
        yield items
        return
    if isinstance(items, Scene):
        yield from items.surfaces
        return
    try:
        iterator = iter(items)
    except TypeError:
        raise TypeError(f"expected a surface or a list of surfaces; got {type(items).__name__}") from None
    for item in iterator:
        yield from _flatten(item)


# -- rotations ------------------------------------------------------------------------
def rotation_z(yaw: float) -> np.ndarray:
    """Rotation by ``yaw`` radians about +z."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rotation_from_to(a, b) -> np.ndarray:
    """The smallest rotation taking unit direction ``a`` to unit direction ``b``."""
    a = _unit("a", a)
    b = _unit("b", b)
    v = np.cross(a, b)
    c = float(a @ b)
    if c < -1 + 1e-12:
        # Opposite directions: turn by pi about any axis perpendicular to a.
        helper = np.eye(3)[np.argmin(np.abs(a))]
        axis = np.cross(a, helper)
        axis /= np.linalg.norm(axis)
        return 2.0 * np.outer(axis, axis) - np.eye(3)
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + c)


# -- builders ---------------------------------------------------------------------------
def patch(center, u, v, half_u, half_v, *, first_id: int) -> list[Rectangle]:
    """A single bounded planar patch (see :class:`Rectangle`)."""
    return [Rectangle(first_id, center, u, v, half_u, half_v)]


def room(*, x=(-1.0, 5.0), y=(-2.0, 2.0), z=(-0.5, 2.1), first_id: int = 1) -> list[Rectangle]:
    """Inside of an axis-aligned room.

    Ids: floor ``first_id`` (z = z[0]), ceiling ``+1`` (z = z[1]), walls ``+2`` (x = x[0]),
    ``+3`` (x = x[1]), ``+4`` (y = y[0]), ``+5`` (y = y[1]). Default: a 6 x 4 x 2.6 m room
    seen by a sensor 0.5 m above the floor at the origin.
    """
    (x0, x1), (y0, y1), (z0, z1) = (tuple(map(float, r)) for r in (x, y, z))
    if not (x1 > x0 and y1 > y0 and z1 > z0):
        raise ValueError(f"room bounds must be increasing (lo, hi) pairs; got x={x}, y={y}, z={z}")
    cx, cy, cz = (x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2
    hx, hy, hz = (x1 - x0) / 2, (y1 - y0) / 2, (z1 - z0) / 2
    ex, ey, ez = np.eye(3)
    return [
        Rectangle(first_id, (cx, cy, z0), ex, ey, hx, hy),
        Rectangle(first_id + 1, (cx, cy, z1), ex, ey, hx, hy),
        Rectangle(first_id + 2, (x0, cy, cz), ey, ez, hy, hz),
        Rectangle(first_id + 3, (x1, cy, cz), ey, ez, hy, hz),
        Rectangle(first_id + 4, (cx, y0, cz), ex, ez, hx, hz),
        Rectangle(first_id + 5, (cx, y1, cz), ex, ez, hx, hz),
    ]


def box(center, size, *, yaw: float = 0.0, bottom: bool = False, first_id: int) -> list[Rectangle]:
    """A box of ``size = (sx, sy, sz)`` around ``center``, turned by ``yaw`` about +z.

    Ids from ``first_id``: top, then the faces at -x, +x, -y, +y of the box's own frame,
    then the bottom if ``bottom=True``.
    """
    c = _vector("center", center)
    sx, sy, sz = (_positive("box size", s) for s in np.asarray(size, dtype=float).reshape(3))
    rot = rotation_z(yaw)
    ex, ey, ez = rot.T  # box axes in the scene frame
    faces = [
        Rectangle(first_id, c + ez * sz / 2, ex, ey, sx / 2, sy / 2),
        Rectangle(first_id + 1, c - ex * sx / 2, ey, ez, sy / 2, sz / 2),
        Rectangle(first_id + 2, c + ex * sx / 2, ey, ez, sy / 2, sz / 2),
        Rectangle(first_id + 3, c - ey * sy / 2, ex, ez, sx / 2, sz / 2),
        Rectangle(first_id + 4, c + ey * sy / 2, ex, ez, sx / 2, sz / 2),
    ]
    if bottom:
        faces.append(Rectangle(first_id + 5, c - ez * sz / 2, ex, ey, sx / 2, sy / 2))
    return faces


def cylinder(base, axis, radius: float, length: float, *, caps: bool = True, first_id: int) -> list:
    """A finite cylinder: lateral surface ``first_id``; caps ``first_id + 1`` (at ``base``) and
    ``first_id + 2`` (far end) when ``caps`` is true."""
    side = CylinderSide(first_id, base, axis, radius, length)
    parts: list = [side]
    if caps:
        parts.append(Disk(first_id + 1, side.base, -side.axis, side.radius))
        parts.append(Disk(first_id + 2, side.base + side.length * side.axis, side.axis, side.radius))
    return parts


def sphere(center, radius: float, *, first_id: int) -> list[SphereSurface]:
    """A sphere, one id."""
    return [SphereSurface(first_id, center, radius)]


@dataclass(frozen=True, eq=False)
class SyntheticScan:
    """A simulated scan with its ground truth.

    Attributes
    ----------
    cloud : OrganizedCloud
        The simulated scan, carrying its sensor geometry.
    truth_ids : (H, W) int32
        Id of the surface each pixel saw; 0 = no return, mixed pixel or beyond max range.
    truth : dict[int, Plane | Sphere | Cylinder]
        True model of every surface that appears in ``truth_ids``.
    scene : Scene or None
        The scene that was scanned.
    """

    cloud: object
    truth_ids: np.ndarray
    truth: dict
    scene: Scene | None = None

    def visible_truth(self, min_pixels: int = 1) -> dict:
        """``truth`` restricted to surfaces covering at least ``min_pixels`` pixels."""
        counts = np.bincount(self.truth_ids.ravel(), minlength=max(self.truth, default=0) + 1)
        return {k: m for k, m in self.truth.items() if k < counts.size and counts[k] >= min_pixels}
