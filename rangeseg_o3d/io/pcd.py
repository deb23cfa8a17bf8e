"""PCD (Point Cloud Library) reading and writing that keeps the organized grid.

Reads versions 0.6 and 0.7 (``VERSION .7`` too), ``DATA ascii``, ``binary`` and
``binary_compressed``. Fields ``x y z`` are required (floats); ``intensity`` and
PCL's packed ``rgb``/``rgba`` colour are kept as such, other fields (normal_*,
curvature...) as the cloud's extras, padding ``_`` is dropped; VIEWPOINT is applied. ``HEIGHT > 1`` gives an (HEIGHT, WIDTH) grid; an unorganized file
(``HEIGHT 1``) gives a (1, N) grid. NaN (or inf) in any of x, y, z marks an
invalid pixel.

Layouts: ``binary`` stores one record per point (fields interleaved);
``binary_compressed`` stores two little-endian uint32 (compressed size,
decompressed size) and an LZF stream whose content is every field's values for
all points, one field after another.
"""

from __future__ import annotations

import logging
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..cloud import OrganizedCloud, check_grid_size
from .atomic import atomic_write
from .lzf import lzf_compress, lzf_decompress

__all__ = ["PcdHeader", "read_pcd", "read_pcd_grid", "read_pcd_fields", "parse_pcd_header",
           "write_pcd", "viewpoint_pose"]

log = logging.getLogger(__name__)

_DATA_KINDS = ("ascii", "binary", "binary_compressed")
_TYPE_CODES = {("F", 4): "f4", ("F", 8): "f8",
               ("I", 1): "i1", ("I", 2): "i2", ("I", 4): "i4", ("I", 8): "i8",
               ("U", 1): "u1", ("U", 2): "u2", ("U", 4): "u4", ("U", 8): "u8"}
_MAX_HEADER_LINES = 64


@dataclass(frozen=True)
class PcdHeader:
    """The parsed header of a PCD file.

    ``fields``, ``sizes``, ``types`` and ``counts`` are parallel tuples;
    ``data_offset`` is the byte offset of the payload in the file.
    """

    version: str
    fields: tuple[str, ...]
    sizes: tuple[int, ...]
    types: tuple[str, ...]
    counts: tuple[int, ...]
    width: int
    height: int
    points: int
    viewpoint: tuple[float, ...]
    data: str
    data_offset: int

    @property
    def dtypes(self) -> tuple[np.dtype, ...]:
        """Little-endian numpy dtype of one element of each field."""
        return tuple(np.dtype("<" + _TYPE_CODES[(t, s)]) for t, s in zip(self.types, self.sizes))

    @property
    def record_size(self) -> int:
        """Bytes per point in the binary layouts."""
        return sum(size * count for size, count in zip(self.sizes, self.counts))


def _ints(key: str, values: list[str], path) -> tuple[int, ...]:
    try:
        return tuple(int(v) for v in values)
    except ValueError:
        raise ValueError(f"{path}: {key} must be integers; got {' '.join(values)!r}") from None


def parse_pcd_header(raw: bytes, path="<bytes>") -> PcdHeader:
    """Parse and check the header at the start of a PCD file's bytes.

    Parameters
    ----------
    raw : bytes
        The file content (only the header part is looked at).
    path : str, optional
        Used in error messages.

    Returns
    -------
    PcdHeader

    Raises
    ------
    ValueError
        On a missing or inconsistent entry (field lists of different lengths,
        unknown TYPE/SIZE, POINTS != WIDTH * HEIGHT, unknown DATA, no x/y/z...).
    """
    entries: dict[str, list[str]] = {}
    offset = 0
    data_kind = None
    for _ in range(_MAX_HEADER_LINES + 1):
        end = raw.find(b"\n", offset)
        if end < 0:
            raise ValueError(f"{path}: header ends before a DATA line")
        line = raw[offset:end].decode("ascii", errors="replace").strip()
        offset = end + 1
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        key = key.upper()
        if key == "DATA":
            data_kind = values[0].lower() if values else ""
            break
        entries[key] = values
    else:
        raise ValueError(f"{path}: no DATA line in the first {_MAX_HEADER_LINES} header lines")

    if data_kind not in _DATA_KINDS:
        raise ValueError(f"{path}: DATA must be one of {_DATA_KINDS}; got {data_kind!r}")
    # PCD 0.5 called the field list COLUMNS.
    fields = tuple(entries.get("FIELDS", entries.get("COLUMNS", [])))
    if not fields:
        raise ValueError(f"{path}: header has no FIELDS line")
    n = len(fields)
    for key in ("SIZE", "TYPE", "WIDTH"):
        if key not in entries:
            raise ValueError(f"{path}: header has no {key} line")
    sizes = _ints("SIZE", entries["SIZE"], path)
    types = tuple(t.upper() for t in entries["TYPE"])
    counts = _ints("COUNT", entries["COUNT"], path) if "COUNT" in entries else (1,) * n
    for key, values in (("SIZE", sizes), ("TYPE", types), ("COUNT", counts)):
        if len(values) != n:
            raise ValueError(f"{path}: {key} has {len(values)} entries but FIELDS has {n}")
    for name, type_, size, count in zip(fields, types, sizes, counts):
        if (type_, size) not in _TYPE_CODES:
            raise ValueError(
                f"{path}: field {name!r} has TYPE {type_} with SIZE {size}, which is not a "
                "valid combination (F 4/8, I or U 1/2/4/8)"
            )
        if count < 1:
            raise ValueError(f"{path}: field {name!r} has COUNT {count}; must be >= 1")
    for axis in ("x", "y", "z"):
        if axis not in fields:
            raise ValueError(f"{path}: FIELDS must include x, y and z; got {' '.join(fields)}")
        if counts[fields.index(axis)] != 1:
            raise ValueError(f"{path}: field {axis} must have COUNT 1; got {counts[fields.index(axis)]}")
        if types[fields.index(axis)] != "F":
            # Integer coordinates are either scaled units the header does not state or
            # float bits mislabelled as integers: either way reading them gives garbage.
            raise ValueError(
                f"{path}: field {axis} must be a float (TYPE F); got TYPE "
                f"{types[fields.index(axis)]}{sizes[fields.index(axis)]}")
    (width,) = _ints("WIDTH", entries["WIDTH"][:1], path) or (0,)
    height = _ints("HEIGHT", entries["HEIGHT"][:1], path)[0] if "HEIGHT" in entries else 1
    if width < 1 or height < 1:
        raise ValueError(f"{path}: WIDTH and HEIGHT must be >= 1; got {width} x {height}")
    points = _ints("POINTS", entries["POINTS"][:1], path)[0] if "POINTS" in entries else width * height
    if points != width * height:
        raise ValueError(
            f"{path}: POINTS is {points} but WIDTH x HEIGHT is {width} x {height} = {width * height}"
        )
    try:
        viewpoint = tuple(float(v) for v in entries.get("VIEWPOINT", "0 0 0 1 0 0 0".split()))
    except ValueError:
        raise ValueError(f"{path}: VIEWPOINT must be 7 numbers; got {entries['VIEWPOINT']}") from None
    return PcdHeader(
        version=" ".join(entries.get("VERSION", ["?"])),
        fields=fields, sizes=sizes, types=types, counts=counts,
        width=width, height=height, points=points, viewpoint=viewpoint,
        data=data_kind, data_offset=offset,
    )


def _unique_names(fields: tuple[str, ...]) -> list[str]:
    # PCL pads records with fields named "_"; numpy needs distinct names.
    seen: dict[str, int] = {}
    names = []
    for name in fields:
        k = seen.get(name, 0)
        seen[name] = k + 1
        names.append(name if k == 0 else f"{name}__{k}")
    return names


def _split_columns(columns: np.ndarray, header: PcdHeader) -> dict[str, np.ndarray]:
    """Cut an (N, total count) float array of ascii values into per-field arrays."""
    out = {}
    start = 0
    for name, dtype, count in zip(_unique_names(header.fields), header.dtypes, header.counts):
        block = columns[:, start:start + count]
        start += count
        # Cast to the declared type: "%.9g" text of a float32 must come back as that float32.
        block = block.astype(dtype)
        out[name] = block[:, 0] if count == 1 else block
    return out


def _read_ascii(payload: bytes, header: PcdHeader, path) -> dict[str, np.ndarray]:
    per_point = sum(header.counts)
    tokens = payload.split()
    if len(tokens) < header.points * per_point:
        raise ValueError(
            f"{path}: DATA ascii holds {len(tokens)} values but {header.points} points x "
            f"{per_point} values = {header.points * per_point} were declared (data shorter than declared)"
        )
    if len(tokens) > header.points * per_point:
        raise ValueError(
            f"{path}: DATA ascii holds {len(tokens)} values, more than the declared "
            f"{header.points} points x {per_point}"
        )
    try:
        values = np.array(tokens, dtype=np.float64)
    except ValueError as err:
        raise ValueError(f"{path}: DATA ascii holds a value that is not a number ({err})") from None
    return _split_columns(values.reshape(header.points, per_point), header)


def _record_dtype(header: PcdHeader) -> np.dtype:
    return np.dtype([
        (name, dtype) if count == 1 else (name, dtype, (count,))
        for name, dtype, count in zip(_unique_names(header.fields), header.dtypes, header.counts)
    ])


def _read_binary(payload: bytes, header: PcdHeader, path) -> dict[str, np.ndarray]:
    need = header.points * header.record_size
    if len(payload) < need:
        raise ValueError(
            f"{path}: DATA binary holds {len(payload)} bytes but {header.points} points x "
            f"{header.record_size} bytes = {need} were declared (data shorter than declared)"
        )
    records = np.frombuffer(payload, dtype=_record_dtype(header), count=header.points)
    return {name: records[name] for name in records.dtype.names}


def _read_compressed(payload: bytes, header: PcdHeader, path) -> dict[str, np.ndarray]:
    if len(payload) < 8:
        raise ValueError(f"{path}: DATA binary_compressed has no size words (only {len(payload)} bytes)")
    compressed_size, raw_size = struct.unpack("<II", payload[:8])
    need = header.points * header.record_size
    if raw_size != need:
        raise ValueError(
            f"{path}: binary_compressed declares {raw_size} decompressed bytes but "
            f"{header.points} points x {header.record_size} bytes = {need}"
        )
    if compressed_size > len(payload) - 8:
        raise ValueError(
            f"{path}: binary_compressed declares {compressed_size} compressed bytes but only "
            f"{len(payload) - 8} follow (data shorter than declared)"
        )
    try:
        raw = lzf_decompress(payload[8:8 + compressed_size], raw_size)
    except ValueError as err:
        raise ValueError(f"{path}: corrupt binary_compressed data: {err}") from None
    out = {}
    start = 0
    for name, dtype, count in zip(_unique_names(header.fields), header.dtypes, header.counts):
        nbytes = header.points * count * dtype.itemsize
        block = np.frombuffer(raw, dtype=dtype, count=header.points * count, offset=start)
        start += nbytes
        out[name] = block if count == 1 else block.reshape(header.points, count)
    return out


_READERS = {"ascii": _read_ascii, "binary": _read_binary, "binary_compressed": _read_compressed}


def read_pcd_fields(path) -> tuple[PcdHeader, dict[str, np.ndarray]]:
    """Read a PCD file into its header and one array per field.

    Each array has length ``POINTS`` (shape (POINTS, COUNT) when COUNT > 1), in
    file order (row-major over the grid). Repeated field names (PCL's ``_``
    padding) get suffixes ``__1``, ``__2``...

    Raises
    ------
    ValueError
        If the header is inconsistent or the data do not match it.
    """
    path = Path(path)
    raw = path.read_bytes()
    header = parse_pcd_header(raw, path)
    check_grid_size(header.height, header.width, source=str(path))  # before any allocation
    fields = _READERS[header.data](raw[header.data_offset:], header, path)
    return header, fields


def read_pcd_grid(path) -> tuple[np.ndarray, np.ndarray | None]:
    """Read a PCD file into its (H, W, 3) float64 points and (H, W) intensity (or None).

    The arrays :func:`read_pcd` wraps in an OrganizedCloud; see there. ``xyz`` is
    read-only (the cloud adopts it without copying); copy it to modify it.
    """
    header, fields = read_pcd_fields(path)
    xyz, intensity, _ = _grid_arrays(header, fields, path)
    return xyz, intensity


def _grid_arrays(header: PcdHeader, fields: dict, path):
    """``(xyz, intensity, valid)``: points float64 (H, W, 3), all-NaN where any coordinate is not finite."""
    shape = (header.height, header.width)
    xyz = np.empty((header.points, 3))  # one float64 copy, no stacked float32 intermediate
    for i, axis in enumerate(("x", "y", "z")):
        xyz[:, i] = fields[axis]
    valid = np.isfinite(xyz[:, 0] + xyz[:, 1] + xyz[:, 2])  # finite only where all three are
    xyz[~valid] = np.nan
    xyz.setflags(write=False)  # read-only and clean: OrganizedCloud adopts it without a copy
    intensity = fields.get("intensity")
    if intensity is not None:
        if intensity.ndim != 1:
            raise ValueError(f"{path}: field intensity must have COUNT 1; got {intensity.shape[1]}")
        intensity = intensity.reshape(shape).copy()
    log.debug("read %s: %s grid, DATA %s", path, shape, header.data)
    return xyz.reshape(shape + (3,)), intensity, valid.reshape(shape)


_COLOUR_FIELDS = ("rgb", "rgba")
_PADDING = "_"


def _unpack_rgb(values: np.ndarray, path) -> np.ndarray:
    """(N, 3) uint8 from PCL's packed colour: the bits 0x00RRGGBB of a 4-byte float or uint."""
    if values.dtype.itemsize != 4 or values.ndim != 1:
        raise ValueError(f"{path}: a colour field must be one 4-byte value per point; got "
                         f"{values.dtype} with shape {values.shape}")
    # 0x00RRGGBB little-endian is the bytes B, G, R, 0: read them in reverse, no arithmetic.
    raw = np.ascontiguousarray(values).astype(values.dtype.newbyteorder("<"), copy=False)
    return np.ascontiguousarray(raw.view(np.uint8).reshape(-1, 4)[:, 2::-1])


def viewpoint_pose(viewpoint) -> np.ndarray | None:
    """The 4x4 sensor -> world transform of a PCD VIEWPOINT (tx ty tz qw qx qy qz); None if identity."""
    tx, ty, tz, qw, qx, qy, qz = (float(v) for v in viewpoint)
    norm = np.sqrt(qw * qw + qx * qx + qy * qy + qz * qz)
    if norm == 0:
        raise ValueError(f"VIEWPOINT quaternion must not be zero; got {viewpoint}")
    qw, qx, qy, qz = qw / norm, qx / norm, qy / norm, qz / norm
    pose = np.eye(4)
    pose[:3, :3] = [
        [1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
        [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
        [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)],
    ]
    pose[:3, 3] = tx, ty, tz
    return None if np.allclose(pose, np.eye(4), atol=1e-12) else pose


def read_pcd(path) -> OrganizedCloud:
    """Read a PCD file into an :class:`OrganizedCloud`.

    The grid is (HEIGHT, WIDTH); an unorganized file (HEIGHT 1) becomes a (1, N)
    grid. Coordinates are taken as stored (PCL files are in metres) and kept as
    float64; non-finite x, y or z marks the pixel invalid (all-NaN). ``intensity``
    becomes ``cloud.intensity``, ``rgb``/``rgba`` (PCL's packed colour) ``cloud.colors``,
    every other field (normals, curvature, labels...) ``cloud.extras[name]``; PCL's
    padding fields ``_`` are dropped. The points are in the sensor's frame (PCL's
    grabbers write them so, z forward) and VIEWPOINT is the sensor's pose in the world
    (OpenNI frames carry ``0 0 0 0 1 0 0``, a half turn about x that puts y up): a
    VIEWPOINT other than the identity becomes ``cloud.pose``, which the rerun log and
    :meth:`OrganizedCloud.world_xyz` apply.

    Raises
    ------
    ValueError
        If the header lies about the data (see :func:`parse_pcd_header`),
        the data are truncated or the LZF stream is corrupt.
    """
    header, fields = read_pcd_fields(path)
    xyz, intensity, valid = _grid_arrays(header, fields, path)
    shape = (header.height, header.width)
    colors, extras = None, {}
    for name, values in fields.items():
        base = name.split("__")[0]
        if base in ("x", "y", "z", "intensity", _PADDING):
            continue
        if base in _COLOUR_FIELDS and colors is None:
            colors = _unpack_rgb(values, path).reshape(shape + (3,))
        else:
            extras[name] = np.asarray(values).reshape(shape + np.asarray(values).shape[1:])
    pose = viewpoint_pose(header.viewpoint)
    # The points are clean float64 and their validity known: the cloud takes both unchecked.
    return OrganizedCloud(xyz, intensity=intensity, colors=colors, extras=extras, pose=pose,
                          _valid=valid)


def _quaternion(rotation: np.ndarray) -> tuple[float, float, float, float]:
    """(qw, qx, qy, qz) of a rotation matrix (the largest-component branch, stable)."""
    m = rotation
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0:
        s = 2 * np.sqrt(1 + trace)
        q = (0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s)
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2 * np.sqrt(1 + m[i, i] - m[j, j] - m[k, k])
        v = np.zeros(3)
        v[i] = 0.25 * s
        v[j] = (m[j, i] + m[i, j]) / s
        v[k] = (m[k, i] + m[i, k]) / s
        q = ((m[k, j] - m[j, k]) / s, *v)
    return tuple(float(x) for x in q)


def write_pcd(cloud: OrganizedCloud, path, *, data: str = "binary", precision: str = "float32") -> Path:
    """Write ``cloud`` as an organized PCD v0.7 file, atomically.

    WIDTH and HEIGHT are the grid's columns and rows; invalid pixels are written
    as NaN. Fields: ``x y z``, ``intensity`` (float32) and ``rgb`` (PCL's packed
    uint) when the cloud has them; a pose is written as VIEWPOINT. Ranges, timestamps, extras and geometry are not written:
    use ``.npz`` to keep them.

    Parameters
    ----------
    cloud : OrganizedCloud
    path : str or os.PathLike
    data : {"binary", "binary_compressed", "ascii"}
        Payload layout. ``binary_compressed``: LZF (liblzf's C code), fields one
        after another.
    precision : {"float32", "float64"}
        Storage type of x, y, z (SIZE 4 or 8). PCL and Open3D tools expect float32.

    Returns
    -------
    pathlib.Path
    """
    if not isinstance(cloud, OrganizedCloud):
        raise TypeError(f"cloud must be an OrganizedCloud; got {type(cloud).__name__}")
    if data not in _DATA_KINDS:
        raise ValueError(f"data must be one of {_DATA_KINDS}; got {data!r}")
    if precision not in ("float32", "float64"):
        raise ValueError(f"precision must be 'float32' or 'float64'; got {precision!r}")
    h, w = cloud.shape
    coord = np.dtype("<f4" if precision == "float32" else "<f8")
    names = ["x", "y", "z"]
    record = [("x", coord), ("y", coord), ("z", coord)]
    if cloud.intensity is not None:
        names.append("intensity")
        record.append(("intensity", np.dtype("<f4")))
    if cloud.colors is not None:
        names.append("rgb")
        record.append(("rgb", np.dtype("<u4")))
    table = np.empty(h * w, dtype=record)
    points = cloud.xyz.reshape(-1, 3)
    viewpoint = "0 0 0 1 0 0 0"
    if cloud.pose is not None:  # the sensor's pose, as PCL stores it
        viewpoint = " ".join(f"{v:.17g}" for v in (*cloud.pose[:3, 3], *_quaternion(cloud.pose[:3, :3])))
    for i, axis in enumerate("xyz"):
        table[axis] = points[:, i]
    if cloud.intensity is not None:
        table["intensity"] = np.asarray(cloud.intensity, dtype=np.float64).ravel()
    if cloud.colors is not None:
        rgb = cloud.colors.reshape(-1, 3).astype(np.uint32)
        table["rgb"] = (rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]
    sizes = " ".join(str(table.dtype[name].itemsize) for name in names)
    header = (
        "# .PCD v0.7 - Point Cloud Data file format\n"
        "VERSION 0.7\n"
        f"FIELDS {' '.join(names)}\n"
        f"SIZE {sizes}\n"
        f"TYPE {' '.join('U' if name == 'rgb' else 'F' for name in names)}\n"
        f"COUNT {' '.join('1' for _ in names)}\n"
        f"WIDTH {w}\nHEIGHT {h}\n"
        f"VIEWPOINT {viewpoint}\n"
        f"POINTS {h * w}\n"
        f"DATA {data}\n"
    )
    path = Path(path)
    with atomic_write(path, "wb") as handle:
        handle.write(header.encode("ascii"))
        if data == "binary":
            handle.write(table.tobytes())
        elif data == "binary_compressed":
            raw = b"".join(np.ascontiguousarray(table[name]).tobytes() for name in names)
            packed = lzf_compress(raw)
            handle.write(struct.pack("<II", len(packed), len(raw)))
            handle.write(packed)
        else:
            columns = np.column_stack([table[name].astype(np.float64) for name in names])
            # repr-precision so that the ascii file round-trips the stored float type exactly.
            fmt = "%.9g" if precision == "float32" else "%.17g"
            np.savetxt(handle, columns, fmt=fmt)
    return path
