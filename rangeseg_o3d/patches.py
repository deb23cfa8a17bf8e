"""Patch geometry of fitted regions: plane boundaries and areas, cylinder segments, sphere caps.

The models are infinite (a plane, an infinite cylinder, a whole sphere); the region's pixels
say which part of the surface was seen. Everything here is computed from one region at a
time, on demand (:class:`rangeseg_o3d.Feature` caches it), so segmentation pays nothing for
it:

- a plane's **boundary** is traced on the image grid (OpenCV's border following on the
  region's mask: outer borders and the borders of holes), each traced pixel's point is
  moved onto the plane along its ray (:func:`onto_plane_along_rays`), and the rings are
  polygons in 3-D; the **area** is that of the
  polygons (outer rings minus holes) measured in the plane;
- a cylinder's **axis segment** spans the axial positions of its pixels, its **angle span**
  is the arc they cover (the circle minus the largest angular gap);
- a sphere's **cap** is the cone around the mean direction from the centre that holds its
  pixels.

Every model also gets a first-order **parameter covariance** from its fit:
``rms^2 (J^T J)^-1`` with ``J`` the Jacobian of the orthogonal distances of the region's
points with respect to a minimal set of parameters, mapped to the stored parameters
(plane ``normal, d``; sphere ``center, radius``; cylinder ``axis, point, radius``). It
assumes independent pixel noise, so for smoothed or tile-averaged data it is optimistic.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .fitting.primitives import Cylinder, Plane, Sphere

__all__ = [
    "PatchSource",
    "PlanePatch",
    "CylinderPatch",
    "SpherePatch",
    "plane_patch",
    "onto_plane_along_rays",
    "cylinder_patch",
    "sphere_patch",
    "patch_from_dict",
    "parameter_covariance",
    "parameter_names",
    "plane_basis",
    "trace_rings",
    "occupied_area",
    "to_open3d_plane",
]

#: Points used for covariances and cylinder/sphere extents (an even subsample of the region).
MAX_POINTS = 4000


def plane_basis(normal) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors spanning the plane orthogonal to ``normal`` (right-handed with it)."""
    n = np.asarray(normal, dtype=float)
    # normal x (the axis it is least aligned with), written out: np.cross is slow for one vector
    k = int(np.argmin(np.abs(n)))
    u = np.array([(0.0, n[2], -n[1]), (-n[2], 0.0, n[0]), (n[1], -n[0], 0.0)][k])
    u /= np.sqrt(u @ u)
    v = np.array([n[1] * u[2] - n[2] * u[1], n[2] * u[0] - n[0] * u[2], n[0] * u[1] - n[1] * u[0]])
    return u, v


def to_open3d_plane(plane: Plane) -> np.ndarray:
    """Open3D's plane coefficients ``[a, b, c, d]`` (``a x + b y + c z + d = 0``) of ``plane``.

    Our planes are ``normal . p = d`` with a unit normal and ``d >= 0`` (the normal points
    away from the sensor origin); Open3D's ``segment_plane`` returns ``[a, b, c, d]`` with
    ``a x + b y + c z + d = 0``. So ``[a, b, c] = normal`` and Open3D's ``d`` is ``-d``.

    Examples
    --------
    >>> from rangeseg_o3d import Plane
    >>> to_open3d_plane(Plane(normal=(0, 0, 1), d=2.0, rms=0.0, inliers=0)).tolist()
    [0.0, 0.0, 1.0, -2.0]
    """
    return np.append(plane.normal, -float(plane.d))


# -- where a region's pixels are ---------------------------------------------------------

class PatchSource:
    """The grid a result's features were found in: points and labels, regions found once.

    Parameters
    ----------
    xyz : (H, W, 3) float array, NaN where invalid.
    labels : (H, W) int array, the result's labels (only valid pixels labelled).
    """

    def __init__(self, xyz: np.ndarray, labels: np.ndarray):
        self.xyz = xyz
        self.labels = labels
        self._regions = None

    def indices(self, label: int) -> np.ndarray:
        """Flat pixel indices of region ``label`` (increasing; empty if it has none)."""
        if self._regions is None:
            from .fitting.region_fitter import region_indices

            self._regions = region_indices(self.labels)  # one counting sort for all regions
        return self._regions.get(int(label), np.empty(0, np.int64))

    def mask(self, label: int) -> tuple[tuple[slice, slice], np.ndarray] | None:
        """``(box, mask)``: the region's bounding box (rows, cols) and its pixels in it."""
        idx = self.indices(label)
        if idx.size == 0:
            return None
        width = self.labels.shape[1]
        rows, cols = np.divmod(idx, width)
        r0, c0 = int(rows[0]), int(cols.min())  # indices increase: rows[0] is the top row
        mask = np.zeros((int(rows[-1]) - r0 + 1, int(cols.max()) - c0 + 1), bool)
        mask[rows - r0, cols - c0] = True
        return (slice(r0, r0 + mask.shape[0]), slice(c0, c0 + mask.shape[1])), mask

    def points(self, label: int, max_points: int | None = MAX_POINTS) -> np.ndarray:
        """The region's points (an even subsample of at most ``max_points``), (N, 3)."""
        idx = self.indices(label)
        if max_points is not None and len(idx) > max_points:
            idx = idx[:: -(-len(idx) // max_points)]
        return self.xyz.reshape(-1, 3)[idx]


# -- planes -------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class PlanePatch:
    """The seen part of a plane.

    boundary : list of (K, 3) arrays
        The largest piece's outer ring first, then its holes (rings closed implicitly:
        the last vertex joins the first).
    pieces : list of lists of (K, 3) arrays
        Every connected piece of the region as ``[outer, *holes]``, largest first
        (a merged region can be several disjoint pieces of one plane).
    area : float
        Area of the pieces in the plane (outer rings minus holes), m^2.
    centroid : (3,) float array
        Mean of the region's points projected onto the plane.
    extent_axes : (2, 3) float array
        In-plane principal directions of the region's points.
    extent : (2,) float array
        Lengths of the region along ``extent_axes`` (m).
    extent_center : (3,) float array
        Centre of that oriented rectangle, on the plane.
    """

    boundary: list
    pieces: list
    area: float
    centroid: np.ndarray
    extent_axes: np.ndarray
    extent: np.ndarray
    extent_center: np.ndarray

    def to_dict(self) -> dict:
        return {
            "boundary": [ring.tolist() for ring in self.boundary],
            "other_pieces": [[ring.tolist() for ring in piece] for piece in self.pieces[1:]],
            "area": float(self.area),
            "centroid": self.centroid.tolist(),
            "extent_axes": self.extent_axes.tolist(),
            "extent": self.extent.tolist(),
            "extent_center": self.extent_center.tolist(),
        }


def trace_rings(mask: np.ndarray) -> list[list[np.ndarray]]:
    """Border rings of a boolean mask, as ``[[outer, *holes], ...]`` per connected piece.

    Each ring is a (K, 2) int array of (row, col) pixels of the mask, in order along the
    border (OpenCV's border following, 8-connected pieces; collinear runs are cut to
    their ends). Pieces are sorted by the pixel area of their outer ring, largest first.
    """
    import cv2

    mask = np.ascontiguousarray(mask, dtype=np.uint8)
    contours, hierarchy = cv2.findContours(mask, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE)
    if not contours:
        return []
    parents = hierarchy[0][:, 3]
    pieces: dict[int, list[np.ndarray]] = {}
    for index, contour in enumerate(contours):
        ring = contour[:, 0, ::-1].astype(np.int64)  # OpenCV gives (x, y) = (col, row)
        owner = index if parents[index] < 0 else int(parents[index])
        pieces.setdefault(owner, [None])
        if parents[index] < 0:
            pieces[owner][0] = ring
        else:
            pieces[owner].append(ring)
    ordered = sorted(pieces.values(), key=lambda piece: -abs(_shoelace(piece[0].astype(float))))
    return ordered


def _shoelace(ring: np.ndarray) -> float:
    """Signed area of a 2-D polygon (K, 2)."""
    if len(ring) < 3:
        return 0.0
    x, y = ring[:, 0], ring[:, 1]
    # sum of x_i y_(i+1) - x_(i+1) y_i around the ring (slices: np.roll costs more than the sum)
    inner = float(np.dot(x[:-1], y[1:]) - np.dot(x[1:], y[:-1]))
    return 0.5 * (inner + float(x[-1] * y[0] - x[0] * y[-1]))


#: A border point within this many of its plane's rms of it moves onto the plane along its
#: ray (:func:`onto_plane_along_rays`): an inlier of the fit, as the chi-square tests count it.
ALONG_RAY_RMS = 4.0


def onto_plane_along_rays(points: np.ndarray, plane: Plane) -> np.ndarray:
    """``points`` (N, 3, the sensor's frame) moved onto ``plane``: along their rays from the
    sensor where the point lies within ALONG_RAY_RMS of the plane's rms of it and its ray
    meets the plane in front of the sensor; orthogonally elsewhere.

    A return errs along its ray, so where its ray meets the plane is where it saw the
    surface; moved orthogonally, a return seen near grazing lands off its ray by its error
    times the tangent of the incidence, and the traced border of a box top seen a few degrees
    from grazing folds over itself (its polygon's area then is not the area its mesh
    covers). The rays' central projection onto a plane keeps a ring's order, so a simple
    ring on the grid stays a simple polygon. A point farther off (a mixed return at the
    border) would slide far along a grazing ray: it moves orthogonally, as before."""
    points = np.asarray(points, dtype=float)
    facing = points @ plane.normal
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = plane.d / facing
    lifted = points - np.outer(facing - plane.d, plane.normal)
    near = np.abs(facing - plane.d) <= ALONG_RAY_RMS * float(plane.rms)
    along = np.isfinite(scale) & (scale > 0) & near
    lifted[along] = points[along] * scale[along, None]
    return lifted


def plane_patch(source: PatchSource, label: int, plane: Plane) -> PlanePatch:
    """The :class:`PlanePatch` of region ``label`` of ``source`` for its ``plane``."""
    found = source.mask(label)
    u, v = plane_basis(plane.normal)
    if found is None or not found[1].any():
        empty = np.zeros(3)
        return PlanePatch([], [], 0.0, plane.d * plane.normal, np.stack([u, v]),
                          np.zeros(2), empty)
    box, mask = found
    xyz = source.xyz[box]
    rings_px = trace_rings(mask)

    # Every ring's pixels lifted onto the plane at once.
    pixels = np.concatenate([ring for piece in rings_px for ring in piece])
    lifted = onto_plane_along_rays(xyz[pixels[:, 0], pixels[:, 1]], plane)
    flat2 = np.stack([lifted @ u, lifted @ v], axis=1)
    ends = np.cumsum([len(ring) for piece in rings_px for ring in piece])
    rings3, rings2 = np.split(lifted, ends[:-1]), np.split(flat2, ends[:-1])
    pieces, area, k = [], 0.0, 0
    for piece in rings_px:
        pieces.append(rings3[k:k + len(piece)])
        signed = [abs(_shoelace(ring)) for ring in rings2[k:k + len(piece)]]
        area += signed[0] - sum(signed[1:])
        k += len(piece)
    points = source.points(label)
    centroid = points.mean(axis=0)
    centroid = centroid - (centroid @ plane.normal - plane.d) * plane.normal
    flat = np.stack([(points - centroid) @ u, (points - centroid) @ v], axis=1)
    _, vecs = np.linalg.eigh(np.einsum("ni,nj->ij", flat, flat))  # not BLAS: see parameter_covariance
    axes2 = vecs[:, ::-1].T  # major axis first
    # The extremes along any direction lie on the outer rings: measure the extent there.
    outer = np.concatenate([piece[0] for piece in pieces]) - centroid
    coords = np.stack([outer @ u, outer @ v], axis=1) @ axes2.T
    low, high = coords.min(axis=0), coords.max(axis=0)
    axes = axes2[:, :1] * u + axes2[:, 1:] * v
    center = centroid + ((low + high) / 2) @ axes
    return PlanePatch(
        boundary=pieces[0] if pieces else [],
        pieces=pieces,
        area=max(area, 0.0),
        centroid=centroid,
        extent_axes=axes,
        extent=high - low,
        extent_center=center,
    )


def occupied_area(points: np.ndarray, plane: Plane, cell: float = 0.025) -> float:
    """Area (m^2) of the ``cell``-sized squares of the plane that hold a projected point.

    The yardstick patch areas are checked against (issue 15: 2.5 cm cells).
    """
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    if len(points) == 0:
        return 0.0
    u, v = plane_basis(plane.normal)
    cells = np.floor(np.stack([points @ u, points @ v], axis=1) / cell).astype(np.int64)
    return float(len(np.unique(cells, axis=0))) * cell * cell


# -- cylinders ----------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class CylinderPatch:
    """The seen part of a cylinder.

    segment : (2, 3) float array
        The two ends of the axis segment its pixels span.
    height : float
        Length of that segment (m).
    angle_span : float
        Angle (radians, up to 2 pi) of the arc its pixels cover around the axis.
    arc_mid : (3,) float array
        Unit radial direction of the middle of that arc (orthogonal to the axis).
    """

    segment: np.ndarray
    height: float
    angle_span: float
    arc_mid: np.ndarray

    def to_dict(self) -> dict:
        return {"segment": self.segment.tolist(), "height": float(self.height),
                "angle_span": float(self.angle_span), "arc_mid": self.arc_mid.tolist()}


def _covered_arc(angles: np.ndarray) -> tuple[float, float]:
    """``(span, middle)`` of the arc covered by ``angles`` (radians): the circle minus its largest gap."""
    if len(angles) == 0:
        return 0.0, 0.0
    ordered = np.sort(np.mod(angles, 2 * np.pi))
    gaps = np.diff(np.append(ordered, ordered[0] + 2 * np.pi))
    widest = int(np.argmax(gaps))
    span = 2 * np.pi - float(gaps[widest])
    start = ordered[(widest + 1) % len(ordered)]
    return span, float(start + span / 2)


def cylinder_patch(points: np.ndarray, cylinder: Cylinder) -> CylinderPatch:
    """The :class:`CylinderPatch` of ``cylinder`` seen through ``points`` (N, 3)."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    axis, point = cylinder.axis, cylinder.point
    if len(points) == 0:
        return CylinderPatch(np.stack([point, point]), 0.0, 0.0, plane_basis(axis)[0])
    rel = points - point
    axial = rel @ axis
    e1, e2 = plane_basis(axis)
    span, middle = _covered_arc(np.arctan2(rel @ e2, rel @ e1))
    low, high = float(axial.min()), float(axial.max())
    segment = np.stack([point + low * axis, point + high * axis])
    return CylinderPatch(segment, high - low, span, np.cos(middle) * e1 + np.sin(middle) * e2)


# -- spheres ------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class SpherePatch:
    """The seen cap of a sphere.

    cap_axis : (3,) float array
        Unit direction from the centre to the middle of the cap.
    cap_angle : float
        Half-angle of the cap (radians, up to pi).
    cap_area : float
        Area of the cap, ``2 pi r^2 (1 - cos cap_angle)`` (m^2).
    """

    cap_axis: np.ndarray
    cap_angle: float
    cap_area: float

    def to_dict(self) -> dict:
        return {"cap_axis": self.cap_axis.tolist(), "cap_angle": float(self.cap_angle),
                "cap_area": float(self.cap_area)}


def sphere_patch(points: np.ndarray, sphere: Sphere) -> SpherePatch:
    """The :class:`SpherePatch` of ``sphere`` seen through ``points`` (N, 3)."""
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    rel = points - sphere.center
    norms = np.linalg.norm(rel, axis=1)
    rel = rel[norms > 0] / norms[norms > 0, None]
    if len(rel) == 0:
        return SpherePatch(np.array([0.0, 0.0, -1.0]), 0.0, 0.0)
    mean = rel.mean(axis=0)
    length = np.linalg.norm(mean)
    axis = mean / length if length > 1e-12 else rel[0]
    angle = float(np.arccos(np.clip(rel @ axis, -1.0, 1.0)).max())
    area = 2 * np.pi * float(sphere.radius) ** 2 * (1 - np.cos(angle))
    return SpherePatch(axis, angle, area)


_PATCH_TYPES = {"plane": PlanePatch, "cylinder": CylinderPatch, "sphere": SpherePatch}


def patch_from_dict(kind: str, data: dict):
    """Rebuild a patch from its ``to_dict()`` (as stored in a result's JSON)."""
    if kind == "plane":
        boundary = [np.asarray(ring, dtype=float).reshape(-1, 3) for ring in data["boundary"]]
        pieces = [boundary] + [[np.asarray(r, dtype=float).reshape(-1, 3) for r in piece]
                               for piece in data.get("other_pieces", [])]
        return PlanePatch(boundary, pieces if boundary else [], float(data["area"]),
                          np.asarray(data["centroid"], float), np.asarray(data["extent_axes"], float),
                          np.asarray(data["extent"], float), np.asarray(data["extent_center"], float))
    if kind == "cylinder":
        return CylinderPatch(np.asarray(data["segment"], float), float(data["height"]),
                             float(data["angle_span"]), np.asarray(data["arc_mid"], float))
    if kind == "sphere":
        return SpherePatch(np.asarray(data["cap_axis"], float), float(data["cap_angle"]),
                           float(data["cap_area"]))
    raise ValueError(f"kind must be one of {sorted(_PATCH_TYPES)}; got {kind!r}")


# -- parameter covariance -----------------------------------------------------------------

_PARAMETER_NAMES = {
    "plane": ("nx", "ny", "nz", "d"),
    "sphere": ("cx", "cy", "cz", "radius"),
    "cylinder": ("ax", "ay", "az", "px", "py", "pz", "radius"),
}


def parameter_names(kind: str) -> tuple[str, ...]:
    """Order of the parameters in a ``kind``'s covariance matrix."""
    return _PARAMETER_NAMES[kind]


def _jacobians(points: np.ndarray, model) -> tuple[np.ndarray, np.ndarray]:
    """``(J, B)``: distances' Jacobian in minimal parameters, and minimal -> stored parameters."""
    if isinstance(model, Plane):
        # n' = n + a u + b v, d' = d + e: a unit normal has two degrees of freedom.
        u, v = plane_basis(model.normal)
        jac = np.stack([points @ u, points @ v, -np.ones(len(points))], axis=1)
        lift = np.zeros((4, 3))
        lift[:3, 0], lift[:3, 1], lift[3, 2] = u, v, 1.0
        return jac, lift
    if isinstance(model, Sphere):
        rel = points - model.center
        unit = rel / np.maximum(np.linalg.norm(rel, axis=1), 1e-300)[:, None]
        return np.hstack([-unit, -np.ones((len(points), 1))]), np.eye(4)
    if isinstance(model, Cylinder):
        # axis' = w + a u + b v; point' = p + c u + e v (moved across the axis); r' = r + f.
        w = model.axis
        u, v = plane_basis(w)
        rel = points - model.point
        along = rel @ w
        radial = rel - np.outer(along, w)
        unit = radial / np.maximum(np.linalg.norm(radial, axis=1), 1e-300)[:, None]
        jac = np.stack([-along * (unit @ u), -along * (unit @ v), -(unit @ u), -(unit @ v),
                        -np.ones(len(points))], axis=1)
        lift = np.zeros((7, 5))
        lift[:3, 0], lift[:3, 1], lift[3:6, 2], lift[3:6, 3], lift[6, 4] = u, v, u, v, 1.0
        return jac, lift
    raise TypeError(f"no covariance for a {type(model).__name__}")


def parameter_covariance(points: np.ndarray, model, *, n_total: int | None = None) -> np.ndarray | None:
    """First-order covariance of ``model``'s stored parameters fitted to ``points``.

    Parameters
    ----------
    points : (N, 3) float array
        The region's points (or an even subsample of them).
    model : Plane, Sphere or Cylinder
        Its ``rms`` is taken as the noise of one point.
    n_total : int, optional
        How many points the fit used when ``points`` is a subsample: the information
        grows with the count, so the covariance shrinks by ``N / n_total``.

    Returns
    -------
    (P, P) float array in :func:`parameter_names` order, or None when the points do not
    pin the model down (fewer points than parameters, a degenerate layout).
    """
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    jac, lift = _jacobians(points, model)
    if len(points) < jac.shape[1] + 1:
        return None
    # einsum, not BLAS: a threaded GEMM splits the sum over points differently with the
    # thread count, and a result file must not change in its last digits with it.
    info = np.einsum("ni,nj->ij", jac, jac)
    if n_total is not None and n_total > len(points):
        info *= n_total / len(points)
    try:
        inverse = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return None
    if not np.isfinite(inverse).all() or np.linalg.cond(info) > 1e12:
        return None
    cov = float(model.rms) ** 2 * (lift @ inverse @ lift.T)
    return 0.5 * (cov + cov.T)
