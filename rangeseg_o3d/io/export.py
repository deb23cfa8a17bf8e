"""Results out to files and Open3D: labels PNG, PLY of points and primitives, JSON, geometries.

- :func:`result_to_open3d`: the points coloured by region (tensor cloud with a ``labels``
  attribute) and one triangle mesh per feature, for ``o3d.visualization.draw`` /
  ``draw_geometries`` and ``o3d.io.write_*``;
- :func:`write_labels_png` / :func:`read_labels_png`: per-pixel labels as a 16-bit PNG;
- :func:`write_ply`: one binary PLY holding the labelled, coloured points and the meshes;
- :func:`write_result_json` / :func:`load_result`: the JSON record and back.

Open3D, OpenCV and mapbox_earcut are imported inside the functions that use them.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .atomic import atomic_write

__all__ = [
    "result_to_open3d",
    "feature_mesh",
    "mesh_arrays",
    "write_labels_png",
    "read_labels_png",
    "write_ply",
    "write_result_json",
    "write_outputs",
    "load_result",
]

#: Facets around a cylinder and a sphere's meshes.
MESH_RESOLUTION = 32


def _check_pair(result, cloud) -> None:
    from ..cloud import OrganizedCloud
    from ..result import Result

    if not isinstance(result, Result):
        raise TypeError(f"result must be a rangeseg_o3d.Result; got {type(result).__name__}")
    if not isinstance(cloud, OrganizedCloud):
        raise TypeError(f"cloud must be an OrganizedCloud; got {type(cloud).__name__}")
    if result.labels.shape != cloud.shape:
        raise ValueError(f"result labels are {result.labels.shape} but the cloud is {cloud.shape}: "
                         "pass the cloud the result was computed from")


def _plane_mesh(feature) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of a plane patch: its boundary rings triangulated (holes kept)."""
    import mapbox_earcut

    from ..patches import plane_basis

    patch = feature.geometry
    u, v = plane_basis(feature.model.normal)
    vertices, triangles, base = [], [], 0
    for piece in (patch.pieces if patch is not None else []):
        rings = [ring for ring in piece if len(ring) >= 3]
        if not rings or len(piece[0]) < 3:
            continue
        stacked = np.concatenate(rings)
        flat = np.stack([stacked @ u, stacked @ v], axis=1)
        ends = np.cumsum([len(ring) for ring in rings]).astype(np.uint32)
        index = mapbox_earcut.triangulate_float64(flat, ends).astype(np.int64).reshape(-1, 3)
        vertices.append(stacked)
        triangles.append(index + base)
        base += len(stacked)
    if not vertices:
        return np.empty((0, 3)), np.empty((0, 3), np.int64)
    return np.concatenate(vertices), np.concatenate(triangles)


def _tube(radius: float, segment: np.ndarray, resolution: int) -> tuple[np.ndarray, np.ndarray]:
    """Open cylinder surface of ``radius`` around ``segment`` (2, 3)."""
    from ..patches import plane_basis

    axis = segment[1] - segment[0]
    e1, e2 = plane_basis(axis / max(np.linalg.norm(axis), 1e-12))
    angles = np.linspace(0.0, 2 * np.pi, resolution, endpoint=False)
    ring = radius * (np.cos(angles)[:, None] * e1 + np.sin(angles)[:, None] * e2)
    vertices = np.concatenate([segment[0] + ring, segment[1] + ring])
    i = np.arange(resolution)
    j = (i + 1) % resolution
    triangles = np.concatenate([np.stack([i, j, i + resolution], axis=1),
                                np.stack([j, j + resolution, i + resolution], axis=1)])
    return vertices, triangles


def _sphere(center: np.ndarray, radius: float, resolution: int) -> tuple[np.ndarray, np.ndarray]:
    """UV sphere: ``resolution // 2`` latitude rings between the poles."""
    n_lat, n_lon = max(resolution // 2, 2), resolution
    theta = np.linspace(0.0, np.pi, n_lat + 1)[1:-1]
    phi = np.linspace(0.0, 2 * np.pi, n_lon, endpoint=False)
    t, p = np.meshgrid(theta, phi, indexing="ij")
    body = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1).reshape(-1, 3)
    vertices = center + radius * np.concatenate([[[0, 0, 1]], body, [[0, 0, -1]]])
    south = len(vertices) - 1
    lon = np.arange(n_lon)
    nxt = (lon + 1) % n_lon
    tris = [np.stack([np.zeros(n_lon, int), 1 + lon, 1 + nxt], axis=1)]
    for k in range(n_lat - 2):
        a, b = 1 + k * n_lon + lon, 1 + k * n_lon + nxt
        tris += [np.stack([a, a + n_lon, b], axis=1), np.stack([b, a + n_lon, b + n_lon], axis=1)]
    last = 1 + (n_lat - 2) * n_lon
    tris.append(np.stack([last + lon, np.full(n_lon, south), last + nxt], axis=1))
    return vertices, np.concatenate(tris)


def mesh_arrays(feature, *, resolution: int = MESH_RESOLUTION) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices (V, 3), triangles (T, 3))`` of a feature's seen surface.

    A plane: its patch triangulated from its boundary (holes and disjoint pieces kept).
    A cylinder: the finite tube spanning its pixels along the axis. A sphere: the whole
    sphere. Features without patch geometry give empty arrays for planes and cylinders.
    """
    if feature.kind == "plane":
        return _plane_mesh(feature)
    if feature.kind == "cylinder":
        patch = feature.geometry
        if patch is None or patch.height <= 0:
            return np.empty((0, 3)), np.empty((0, 3), np.int64)
        return _tube(float(feature.model.radius), patch.segment, resolution)
    if feature.kind == "sphere":
        return _sphere(feature.model.center, float(feature.model.radius), resolution)
    raise ValueError(f"no mesh for a {feature.kind!r} feature")


def feature_mesh(feature, color=None, *, resolution: int = MESH_RESOLUTION):
    """Legacy ``open3d.geometry.TriangleMesh`` of :func:`mesh_arrays`, painted ``color`` (RGB 0..1)."""
    import open3d as o3d

    vertices, triangles = mesh_arrays(feature, resolution=resolution)
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(vertices),
                                     o3d.utility.Vector3iVector(triangles.astype(np.int32)))
    mesh.compute_vertex_normals()
    if color is not None:
        mesh.paint_uniform_color(np.asarray(color, dtype=float))
    return mesh


def _point_table(result, cloud) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``(rows, cols, labels, lut)`` of the cloud's valid pixels and the colour table."""
    from ..viz.colors import region_colors

    rows, cols = np.nonzero(cloud.valid)
    return rows, cols, result.labels[rows, cols].astype(np.int32), region_colors(result)


def result_to_open3d(result, cloud, *, legacy: bool = False) -> list:
    """Open3D geometries of a result: the points coloured by region, then a mesh per feature.

    Parameters
    ----------
    result : rangeseg_o3d.Result
    cloud : OrganizedCloud
        The cloud the result was computed from.
    legacy : bool
        False (default): an ``open3d.t.geometry.PointCloud`` (valid pixels in grid order;
        ``colors`` float32, ``labels`` int32 (N, 1), ``row``/``col``) and
        ``open3d.t.geometry.TriangleMesh`` es, for ``o3d.visualization.draw`` and
        ``o3d.t.io.write_*``. True: legacy ``PointCloud`` (coloured, no labels: the
        legacy type has no custom attributes) and ``TriangleMesh`` es, for
        ``o3d.visualization.draw_geometries`` and ``o3d.io.write_*``.

    Returns
    -------
    list
        ``[points, mesh of result.features[0], mesh of result.features[1], ...]``.
    """
    import open3d as o3d

    from .open3d_conv import to_open3d

    _check_pair(result, cloud)
    rows, cols, labels, lut = _point_table(result, cloud)
    colors = lut[labels].astype(np.float32) / 255.0
    meshes = [feature_mesh(f, lut[f.label] / 255.0 if f.label < len(lut) else None)
              for f in result.features]
    if legacy:
        points = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud.xyz[rows, cols]))
        points.colors = o3d.utility.Vector3dVector(colors.astype(np.float64))
        return [points, *meshes]
    points = to_open3d(cloud)
    points.point.colors = o3d.core.Tensor(colors)
    points.point["labels"] = o3d.core.Tensor(labels[:, None])
    return [points, *(o3d.t.geometry.TriangleMesh.from_legacy(m) for m in meshes)]


# -- files ------------------------------------------------------------------------------

def write_labels_png(labels: np.ndarray, path) -> Path:
    """Write (H, W) labels as a 16-bit grey PNG (0 = in no region), atomically.

    Raises
    ------
    ValueError
        If labels are not 2-D integers in 0..65535 or the suffix is not ``.png``.
    """
    import cv2

    path = Path(path)
    labels = np.asarray(labels)
    if labels.ndim != 2 or not np.issubdtype(labels.dtype, np.integer):
        raise ValueError(f"labels must be a 2-D integer array; got shape {labels.shape}, dtype {labels.dtype}")
    if labels.size and (labels.min() < 0 or labels.max() > 65535):
        raise ValueError(f"labels must lie in 0..65535 for a 16-bit PNG; got {labels.min()}..{labels.max()}")
    if path.suffix.lower() != ".png":
        raise ValueError(f"a labels image must be a .png file; got {path}")
    ok, encoded = cv2.imencode(".png", labels.astype(np.uint16))
    if not ok:
        raise ValueError(f"OpenCV could not encode a {labels.shape} 16-bit PNG")
    with atomic_write(path, "wb") as handle:
        handle.write(encoded.tobytes())
    return path


def read_labels_png(path) -> np.ndarray:
    """(H, W) int32 labels from a PNG written by :func:`write_labels_png`."""
    import cv2

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    image = cv2.imdecode(np.fromfile(path, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None or image.ndim != 2:
        raise ValueError(f"{path}: expected a single-channel PNG of labels; got "
                         f"{'no image' if image is None else f'shape {image.shape}'}")
    return image.astype(np.int32)


def write_ply(path, result, cloud, *, meshes: bool = True) -> Path:
    """One binary PLY: the valid points (colour, ``label``) then every feature's mesh.

    Points are vertices that no face uses; each mesh's vertices carry their feature's
    colour and label, and its triangles are faces. Open3D reads it as a point cloud
    (``o3d.t.io.read_point_cloud``: ``labels`` attribute) or a triangle mesh, MeshLab
    and CloudCompare show points and surfaces together.
    """
    _check_pair(result, cloud)
    path = Path(path)
    if path.suffix.lower() != ".ply":
        raise ValueError(f"a PLY file must end in .ply; got {path}")
    rows, cols, labels, lut = _point_table(result, cloud)
    chunks = [(cloud.xyz[rows, cols], labels)]
    faces = []
    base = len(rows)
    for feat in (result.features if meshes else []):
        vertices, triangles = mesh_arrays(feat)
        if len(triangles) == 0:
            continue
        chunks.append((vertices, np.full(len(vertices), feat.label, np.int32)))
        faces.append(triangles + base)
        base += len(vertices)
    vertex = np.zeros(base, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"),
                                   ("green", "u1"), ("blue", "u1"), ("label", "<i4")])
    points = np.concatenate([c[0] for c in chunks])
    vertex_labels = np.concatenate([c[1] for c in chunks])
    vertex["x"], vertex["y"], vertex["z"] = points.T
    colors = lut[np.clip(vertex_labels, 0, len(lut) - 1)]
    vertex["red"], vertex["green"], vertex["blue"] = colors.T
    vertex["label"] = vertex_labels
    triangles = np.concatenate(faces) if faces else np.empty((0, 3), np.int64)
    face = np.zeros(len(triangles), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    face["n"], face["v"] = 3, triangles
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment rangeseg_o3d: points then feature meshes\n"
        f"element vertex {base}\nproperty float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\nproperty int label\n"
        f"element face {len(triangles)}\nproperty list uchar int vertex_indices\nend_header\n"
    )
    with atomic_write(path, "wb") as handle:
        handle.write(header.encode("ascii"))
        handle.write(vertex.tobytes())
        handle.write(face.tobytes())
    return path


def write_result_json(result, path, **extra) -> Path:
    """Write ``{**extra, **result.to_dict()}`` as JSON, atomically (``extra``: input, config...)."""
    path = Path(path)
    payload = {**extra, **result.to_dict()}
    with atomic_write(path, "w") as handle:
        json.dump(payload, handle, indent=1)
    return path


def write_outputs(result, cloud, *, json_path=None, labels_path=None, ply_path=None,
                  **extra) -> list[Path]:
    """Write the outputs asked for (None = skip): JSON (with ``extra``), labels PNG, PLY.

    Returns the paths written, in that order.
    """
    written = []
    if json_path is not None:
        written.append(write_result_json(result, json_path, **extra))
    if labels_path is not None:
        written.append(write_labels_png(result.labels, labels_path))
    if ply_path is not None:
        written.append(write_ply(ply_path, result, cloud))
    return written


def load_result(path, labels=None):
    """A :class:`~rangeseg_o3d.Result` from its JSON, with labels from a PNG path or an array.

    Raises
    ------
    ValueError
        If the file is not a result record (see :meth:`Result.from_dict`).
    """
    from ..result import Result

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    try:
        data = json.loads(path.read_text())
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ValueError(f"{path}: not a JSON file ({err})") from None
    if isinstance(labels, (str, Path)):
        labels = read_labels_png(labels)
    try:
        return Result.from_dict(data, labels=labels)
    except (KeyError, TypeError, ValueError) as err:
        raise ValueError(f"{path}: not a rangeseg_o3d result record ({err})") from None
