"""Log every stage of a segmentation to a rerun recording.

Entities (one scan at a time, on the sequence timeline given to :func:`log_scan`):

================================  ===================================================
``scan/range``                    DepthImage of the ranges, float32 metres (``meter=1``);
                                  pixels without a return are 0 (rerun's "no depth")
``scan/residual``                 Image (float32) of ``result.stages["residual"]``
``scan/closed``                   Image (float32) of ``result.stages["closed"]``
``scan/edges``                    Image (uint8, 255 = edge) of ``result.stages["edges"]``
``scan/labels``                   SegmentationImage (uint16) + AnnotationContext naming
                                  each region ("plane 3", "cylinder 7 r=0.21 m", ...)
``world``                         the same AnnotationContext, so points and features
                                  show their region's name
``world/points``                  Points3D of the valid points, coloured by region,
                                  ``class_ids`` = region label, plus a ``GridIndex``
                                  archetype with ``row`` and ``col`` per point (int32)
``world/features/<label>``        LineStrips3D (plane boundary rings, holes included),
                                  Cylinders3D (over the axis segment) or Ellipsoids3D,
                                  plus a ``Feature`` archetype with kind, rms, inliers,
                                  n_pixels, the model's parameters, their standard
                                  deviations and the patch's area / extent / height /
                                  angle span / cap
``world``                         Transform3D of the scan's pose (``cloud.pose``: a PCD
                                  VIEWPOINT, an E57 scan pose), identity without one
``timings/<stage>``               Scalars, milliseconds
================================  ===================================================

With ``light=True`` the intermediate images (residual, closed, edges) are not logged, the
points are those of every step-th row and column (at most ``LIGHT_POINTS`` pixels) without
colours (the annotation context colours them by label) or grid indices: the recording keeps
the range, the labels, the points, the features and the timings.

A segmenter that produces no ``residual``/``closed``/``edges`` image simply has no such
entity for that scan (any image from an earlier scan is cleared). Features of an earlier
scan are cleared too, so the viewer never mixes scans.

Static, logged once (``log_static=True``): the default blueprint (:func:`default_blueprint`:
the 3-D view, the labelled image, the range image and the timings), view coordinates
whenever the sensor geometry is known or can be estimated (a pinhole fitted to the points
of a cloud without geometry, e.g. a PCD), ``world/sensor`` (pinhole frustum, or the
outline of a nodding scanner's field of view at 1 m) and a ``legend`` text document
explaining the colours.

Every function takes the recording as its first argument and does nothing when it is
None, so callers need not import rerun; rerun itself is imported only when something is
actually logged.
"""

from __future__ import annotations

import logging
import re
import weakref

import numpy as np

from ..cloud import OrganizedCloud
from ..geometry import NoddingGeometry, PinholeGeometry, nodding_rays
from ..result import Result
from .colors import KIND_HUES, region_colors, region_names
# Re-exported: the CLI imports its rerun helpers from this module.
from .rerun_cli import add_rerun_arguments, finish_recording, recording_from_args
from .shapes import (
    cylinder_span,
    model_inliers,
    plane_outline,
    quaternion_from_z,
    region_points,
)

__all__ = [
    "STAGE_IMAGES",
    "log_scan",
    "log_range",
    "log_stage_images",
    "log_labels",
    "log_points",
    "log_features",
    "log_timings",
    "log_static_context",
    "default_blueprint",
    "annotation_context",
    "add_rerun_arguments",
    "recording_from_args",
    "finish_recording",
]

log = logging.getLogger(__name__)

#: Intermediate images logged under ``scan/<name>`` when the segmenter provides them.
STAGE_IMAGES = ("residual", "closed", "edges")
#: Largest label a SegmentationImage (uint16) and a class id can carry.
MAX_LABEL = np.iinfo(np.uint16).max
#: Most grid pixels whose points a light log keeps (every step-th row and column).
LIGHT_POINTS = 80_000
#: Length (metres) of the rays drawn for a nodding scanner's field of view.
SENSOR_RAY_LENGTH = 1.0

# recording -> fingerprint of the sensor geometry whose static context it holds.
_STATIC_LOGGED: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def _rerun(recording):
    """Import rerun and check ``recording`` is a RecordingStream."""
    import rerun as rr

    if not isinstance(recording, rr.RecordingStream):
        raise TypeError(
            f"recording must be a rerun.RecordingStream or None; got {type(recording).__name__}"
        )
    return rr


def _check_cloud(cloud) -> None:
    if not isinstance(cloud, OrganizedCloud):
        raise TypeError(f"cloud must be an OrganizedCloud; got {type(cloud).__name__}")


def _check_labels(labels, shape: tuple[int, int]) -> np.ndarray:
    labels = np.asarray(labels)
    if labels.shape != tuple(shape):
        raise ValueError(f"labels must have shape {tuple(shape)} (the grid); got {labels.shape}")
    if not np.issubdtype(labels.dtype, np.integer):
        raise ValueError(f"labels must be integers; got dtype {labels.dtype}")
    if labels.size and (labels.min() < 0 or labels.max() > MAX_LABEL):
        raise ValueError(
            f"labels must lie in [0, {MAX_LABEL}]; got [{labels.min()}, {labels.max()}]"
        )
    return labels


def _check_result(result, shape: tuple[int, int]) -> None:
    if not isinstance(result, Result):
        raise TypeError(f"result must be a rangeseg_o3d.Result; got {type(result).__name__}")
    _check_labels(result.labels, shape)
    for name in STAGE_IMAGES:
        image = result.stages.get(name)
        if image is not None and np.shape(image) != tuple(shape):
            raise ValueError(
                f"stage image {name!r} must have shape {tuple(shape)} (the grid); "
                f"got {np.shape(image)}"
            )


def _check_dict(value, name: str, of: str) -> dict:
    if not isinstance(value, dict):
        raise TypeError(f"{name} must be a dict of {of}; got {type(value).__name__}")
    return value


def _entity_part(name: str) -> str:
    """A stage name usable as one entity-path part (no slashes, spaces or quotes)."""
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", str(name)) or "_"


# -- per-stage functions ------------------------------------------------------------


def log_range(recording, cloud: OrganizedCloud, *, entity: str = "scan/range") -> None:
    """Log the range image as a DepthImage in float32 metres (``meter=1``).

    Parameters
    ----------
    recording : rerun.RecordingStream or None
        Nothing is logged when None.
    cloud : OrganizedCloud
    entity : str
        Entity path.
    """
    if recording is None:
        return
    rr = _rerun(recording)
    _check_cloud(cloud)
    ranges = np.asarray(cloud.range_image(), dtype=np.float32)
    # rerun draws depth 0 as "no data"; NaN has no defined meaning there.
    ranges = np.where(np.isfinite(ranges) & (ranges > 0), ranges, 0.0).astype(np.float32)
    recording.log(entity, rr.DepthImage(ranges, meter=1.0, colormap="turbo"))


def _stage_image(image) -> np.ndarray:
    image = np.asarray(image)
    if image.dtype == bool:
        return image.astype(np.uint8) * 255
    image = image.astype(np.float32)
    return np.where(np.isfinite(image), image, 0.0).astype(np.float32)


def log_stage_images(
    recording,
    stages: dict,
    *,
    names=STAGE_IMAGES,
    prefix: str = "scan",
    shape: tuple[int, int] | None = None,
) -> list[str]:
    """Log the intermediate images ``stages[name]`` for each name as ``<prefix>/<name>``.

    Boolean images (the edge mask) become uint8 0/255; numeric ones float32 with NaN
    and inf replaced by 0. A name missing from ``stages`` clears its entity so that the
    image of an earlier scan does not linger.

    Parameters
    ----------
    recording : rerun.RecordingStream or None
    stages : dict of (H, W) arrays
    names : sequence of str
        Which stages to log.
    prefix : str
        Parent entity path.
    shape : (H, W), optional
        Required shape of every image.

    Returns
    -------
    list of str
        Entity paths logged.
    """
    if recording is None:
        return []
    rr = _rerun(recording)
    _check_dict(stages, "stages", "images")
    images = {}
    for name in names:
        if stages.get(name) is None:
            continue
        image = np.asarray(stages[name])
        if image.ndim != 2 or (shape is not None and image.shape != tuple(shape)):
            want = tuple(shape) if shape is not None else "(H, W)"
            raise ValueError(f"stage image {name!r} must have shape {want}; got {image.shape}")
        images[name] = _stage_image(image)
    logged = []
    for name in names:
        entity = f"{prefix}/{_entity_part(name)}"
        if name in images:
            recording.log(entity, rr.Image(images[name]))
            logged.append(entity)
        else:
            recording.log(entity, rr.Clear(recursive=False))
    return logged


def annotation_context(result: Result, colors: np.ndarray | None = None):
    """``rr.AnnotationContext`` naming and colouring every region of ``result``."""
    import rerun as rr

    colors = region_colors(result) if colors is None else colors
    names = region_names(result)
    descriptions = [rr.AnnotationInfo(id=0, label="no region", color=tuple(colors[0]))]
    descriptions += [
        rr.AnnotationInfo(id=lab, label=name, color=tuple(int(c) for c in colors[lab]))
        for lab, name in sorted(names.items())
    ]
    return rr.AnnotationContext(descriptions)


def log_labels(
    recording,
    result: Result,
    *,
    entity: str = "scan/labels",
    colors: np.ndarray | None = None,
    context=None,
) -> None:
    """Log ``result.labels`` as a SegmentationImage with an AnnotationContext on the same entity.

    Parameters
    ----------
    recording : rerun.RecordingStream or None
    result : Result
    entity : str
    colors : (max_label + 1, 3) uint8, optional
        Colour table; :func:`rangeseg_o3d.viz.colors.region_colors` by default.
    context : rr.AnnotationContext, optional
        Prebuilt :func:`annotation_context` (saves building it twice in :func:`log_scan`).
    """
    if recording is None:
        return
    rr = _rerun(recording)
    if not isinstance(result, Result):
        raise TypeError(f"result must be a rangeseg_o3d.Result; got {type(result).__name__}")
    labels = _check_labels(result.labels, np.shape(result.labels)[:2])
    recording.log(
        entity,
        context if context is not None else annotation_context(result, colors),
        rr.SegmentationImage(labels.astype(np.uint16)),
    )


def log_points(
    recording,
    cloud: OrganizedCloud,
    labels,
    *,
    colors: np.ndarray | None = None,
    entity: str = "world/points",
    light: bool = False,
) -> int:
    """Log the valid points as Points3D coloured by region, with their grid row and column.

    ``class_ids`` carry the region label of each point; a ``GridIndex`` archetype carries
    ``row`` and ``col`` (int32), one per point, in row-major grid order.

    Parameters
    ----------
    recording : rerun.RecordingStream or None
    cloud : OrganizedCloud
    labels : (H, W) int array
    colors : (max_label + 1, 3) uint8, optional
        Colour per label; grey shades by label when omitted.
    entity : str

    Returns
    -------
    int
        Number of points logged (the cloud's valid pixels); 0 when ``recording`` is None.
    """
    if recording is None:
        return 0
    rr = _rerun(recording)
    _check_cloud(cloud)
    labels = _check_labels(labels, cloud.shape)
    rows, cols = np.nonzero(cloud.valid)
    point_labels = labels[rows, cols]
    if colors is None:
        colors = np.full((int(labels.max(initial=0)) + 1, 3), 200, dtype=np.uint8)
    colors = np.asarray(colors, dtype=np.uint8)
    if colors.ndim != 2 or colors.shape[1] != 3 or len(colors) <= labels.max(initial=0):
        raise ValueError(
            f"colors must have shape (>= {int(labels.max(initial=0)) + 1}, 3); got {colors.shape}"
        )
    if light:
        # Every step-th row and column (at most LIGHT_POINTS pixels), coloured by the class
        # ids through the AnnotationContext on "world": no per-point colours or grid indices.
        step = max(1, int(np.ceil(np.sqrt(cloud.shape[0] * cloud.shape[1] / LIGHT_POINTS))))
        keep = (rows % step == 0) & (cols % step == 0)
        recording.log(entity, rr.Points3D(cloud.xyz[rows[keep], cols[keep]].astype(np.float32),
                                          class_ids=point_labels[keep].astype(np.uint16)))
        return int(keep.sum())
    positions = cloud.xyz[rows, cols].astype(np.float32)
    recording.log(
        entity,
        rr.Points3D(positions, colors=colors[point_labels], class_ids=point_labels.astype(np.uint16)),
        rr.DynamicArchetype(
            "GridIndex",
            components={"row": rows.astype(np.int32), "col": cols.astype(np.int32)},
        ),
    )
    return int(len(rows))


def _feature_archetype(rr, feat, points: np.ndarray, color, name: str):
    """The rerun archetype drawing ``feat``, or None when there is nothing to draw."""
    model = feat.model
    style = {"colors": [color], "labels": [name], "class_ids": [int(feat.label)]}
    patch = feat.geometry
    if feat.kind == "plane":
        if patch is not None and patch.pieces:
            rings = [np.vstack([ring, ring[:1]]).astype(np.float32)
                     for piece in patch.pieces for ring in piece if len(ring) >= 2]
            return rr.LineStrips3D(rings, **{**style, "colors": [color] * len(rings),
                                             "labels": [name] * len(rings),
                                             "class_ids": [int(feat.label)] * len(rings)})
        outline = plane_outline(points, model)
        return rr.LineStrips3D([outline.astype(np.float32)], **style)
    if feat.kind == "cylinder":
        if patch is not None:
            center, length = patch.segment.mean(axis=0), float(patch.height)
        else:
            center, length = cylinder_span(points, model)
        return rr.Cylinders3D(
            centers=[center],
            lengths=[length],
            radii=[float(model.radius)],
            quaternions=[rr.Quaternion(xyzw=quaternion_from_z(model.axis))],
            **style,
        )
    if feat.kind == "sphere":
        return rr.Ellipsoids3D(
            centers=[model.center],
            half_sizes=[[float(model.radius)] * 3],
            **style,
        )
    log.warning("feature %d has unknown kind %r; not drawn", feat.label, feat.kind)
    return None


def _feature_components(feat) -> dict:
    """What the viewer shows of a feature: kind, fit quality, parameters, their sigmas, patch."""
    components = {"kind": feat.kind, "rms": float(feat.rms), "inliers": int(feat.inliers),
                  "n_pixels": int(feat.n_pixels)}
    for name, value in feat.model.params().items():
        components[name] = np.atleast_1d(np.asarray(value, dtype=np.float64))
    covariance = feat.covariance
    if covariance is not None:
        components["sigma"] = np.sqrt(np.clip(np.diag(covariance), 0, None))
        components["sigma_order"] = " ".join(feat.parameter_names)
    patch = feat.geometry
    if patch is not None:
        for name, value in patch.to_dict().items():
            if name in ("boundary", "other_pieces"):
                continue
            components[name] = np.atleast_1d(np.asarray(value, dtype=np.float64)).ravel()
    return components


def log_features(
    recording,
    cloud: OrganizedCloud,
    result: Result,
    *,
    colors: np.ndarray | None = None,
    entity: str = "world/features",
) -> list[str]:
    """Log each fitted feature as ``<entity>/<label>``, first clearing the previous scan's.

    Planes are drawn as the convex outline of their inliers projected on the plane,
    cylinders with the fitted axis and radius over their inliers' axial extent (centred
    on it), spheres as Ellipsoids3D. Inliers are the region's points within 3 rms of
    the model (all the region's points when fewer than 3 qualify). A feature whose label
    has no valid pixel is skipped with a warning.

    Parameters
    ----------
    recording : rerun.RecordingStream or None
    cloud : OrganizedCloud
    result : Result
    colors : (max_label + 1, 3) uint8, optional
    entity : str
        Parent entity path.

    Returns
    -------
    list of str
        Entity paths logged.
    """
    if recording is None:
        return []
    rr = _rerun(recording)
    _check_cloud(cloud)
    _check_result(result, cloud.shape)
    colors = region_colors(result) if colors is None else colors
    names = region_names(result)
    recording.log(entity, rr.Clear(recursive=True))
    logged = []
    for feat in result.features:
        points = region_points(cloud.xyz, result.labels, feat.label)
        if len(points) == 0:
            log.warning("feature %d has no valid pixel in the labels; not drawn", feat.label)
            continue
        inliers = model_inliers(points, feat.model)
        color = tuple(int(c) for c in colors[feat.label])
        shape = _feature_archetype(rr, feat, inliers, color, names[int(feat.label)])
        if shape is None:
            continue
        path = f"{entity}/{int(feat.label)}"
        details = rr.DynamicArchetype("Feature", components=_feature_components(feat))
        recording.log(path, shape, details)
        logged.append(path)
    return logged


def log_timings(recording, timings: dict, *, prefix: str = "timings") -> list[str]:
    """Log each stage's time as Scalars in milliseconds under ``<prefix>/<stage>``.

    Non-finite or negative times are skipped with a warning (never plotted as garbage).

    Returns
    -------
    list of str
        Entity paths logged.
    """
    if recording is None:
        return []
    rr = _rerun(recording)
    _check_dict(timings, "timings", "seconds")
    logged = []
    for stage, seconds in timings.items():
        try:
            seconds = float(seconds)
        except (TypeError, ValueError):
            seconds = float("nan")
        if not (np.isfinite(seconds) and seconds >= 0):
            log.warning("timing of stage %r is %r; not logged", stage, timings[stage])
            continue
        path = f"{prefix}/{_entity_part(stage)}"
        recording.log(path, rr.Scalars([seconds * 1e3]))
        logged.append(path)
    return logged


# -- static context -----------------------------------------------------------------


def _nodding_fov_strips(geometry: NoddingGeometry) -> list[np.ndarray]:
    """Outline of the scanned field of view at SENSOR_RAY_LENGTH, plus the four corner rays."""
    origins, directions = nodding_rays(geometry)
    ends = origins + SENSOR_RAY_LENGTH * directions
    border = np.concatenate(
        [ends[0, :], ends[:, -1], ends[-1, ::-1], ends[::-1, 0]], axis=0
    )
    corners = [(0, 0), (0, -1), (-1, -1), (-1, 0)]
    rays = [np.stack([origins[r, c], ends[r, c]]) for r, c in corners]
    return [border.astype(np.float32)] + [ray.astype(np.float32) for ray in rays]


def _legend_markdown() -> str:
    kinds = ", ".join(f"{kind}s hue {int(hue)} deg" for kind, hue in KIND_HUES.items())
    return (
        "# rangeseg colours\n\n"
        f"Regions are coloured by the kind of their fitted feature ({kinds}); "
        "unfitted regions are grey; each label keeps its own shade from scan to scan. "
        "Dark grey is no region.\n\n"
        "Names in `scan/labels` and on the points: `plane 3`, `cylinder 7 r=0.21 m`, "
        "`sphere 5 r=0.30 m`, `unfitted 9`.\n\n"
        "`scan/range` is in metres; `timings/*` in milliseconds."
    )


def _geometry_fingerprint(cloud: OrganizedCloud) -> tuple:
    geometry = cloud.geometry
    if isinstance(geometry, NoddingGeometry):
        arrays = (geometry.beam_angles, geometry.tilt_angles, geometry.mount_offset)
        return ("nodding", float(geometry.tilt_sign)) + tuple(a.tobytes() for a in arrays)
    if isinstance(geometry, PinholeGeometry):
        return ("pinhole", geometry.fx, geometry.fy, geometry.cx, geometry.cy, cloud.shape)
    return ("none",)


def default_blueprint():
    """The layout the viewer opens on: the 3-D view beside the labels, the range and the timings."""
    import rerun.blueprint as rrb

    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="/", contents=["world/**"], name="3-D: points and features"),
            rrb.Vertical(
                rrb.Spatial2DView(origin="scan/labels", name="labels"),
                rrb.Spatial2DView(origin="scan/range", name="range (m)"),
                rrb.TimeSeriesView(origin="timings", name="timings (ms)"),
            ),
            column_shares=[3, 2],
        ),
        collapse_panels=True,
    )


def _known_or_estimated_geometry(cloud: OrganizedCloud):
    """The cloud's geometry, else a pinhole fitted to its points (PCD frames), else None."""
    if cloud.geometry is not None:
        return cloud.geometry
    from ..io.datasets import estimate_pinhole

    return estimate_pinhole(cloud.xyz) if cloud.shape[0] > 1 else None


def log_static_context(recording, cloud: OrganizedCloud, *, blueprint: bool = True) -> None:
    """Log, as static data, the blueprint, the view coordinates, the sensor and a colour legend.

    Nodding scans use x forward, y left, z up (RIGHT_HAND_Z_UP) and draw their field of
    view at ``world/sensor``; depth cameras (and clouds whose points fit a pinhole, as a
    PCD frame's do) use the camera frame (RDF) and log a Pinhole. The view coordinates go
    on ``world`` and, when the scan has no pose, on the root the 3-D view looks from.
    """
    if recording is None:
        return
    rr = _rerun(recording)
    _check_cloud(cloud)
    if blueprint:
        recording.send_blueprint(default_blueprint())
    geometry = _known_or_estimated_geometry(cloud)
    coordinates = (rr.ViewCoordinates.RIGHT_HAND_Z_UP if isinstance(geometry, NoddingGeometry)
                   else rr.ViewCoordinates.RDF if isinstance(geometry, PinholeGeometry) else None)
    if coordinates is not None and cloud.pose is None:
        recording.log("/", coordinates, static=True)
    if isinstance(geometry, NoddingGeometry):
        recording.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        recording.log(
            "world/sensor",
            rr.LineStrips3D(_nodding_fov_strips(geometry), colors=[(255, 255, 255)]),
            static=True,
        )
    elif isinstance(geometry, PinholeGeometry):
        height, width = cloud.shape
        recording.log("world", rr.ViewCoordinates.RDF, static=True)
        recording.log(
            "world/sensor",
            rr.Pinhole(
                focal_length=[geometry.fx, geometry.fy],
                principal_point=[geometry.cx, geometry.cy],
                resolution=[width, height],
                camera_xyz=rr.ViewCoordinates.RDF,
                image_plane_distance=SENSOR_RAY_LENGTH,
            ),
            static=True,
        )
    recording.log(
        "legend", rr.TextDocument(_legend_markdown(), media_type="text/markdown"), static=True
    )
    _STATIC_LOGGED[recording] = _geometry_fingerprint(cloud)


# -- everything for one scan ----------------------------------------------------------


def log_scan(
    recording,
    cloud: OrganizedCloud,
    result: Result,
    *,
    scan_index: int,
    timeline: str = "scan",
    log_static: bool = True,
    light: bool = False,
) -> None:
    """Log one scan and its segmentation at ``scan_index`` on the sequence ``timeline``.

    Inputs are validated before anything is logged, so a bad call leaves the recording
    untouched. See the module docstring for the entities.

    Parameters
    ----------
    recording : rerun.RecordingStream or None
        Nothing happens (and rerun is not imported) when None.
    cloud : OrganizedCloud
    result : Result
        Its labels and stage images must have the cloud's grid shape.
    scan_index : int
        Position on the timeline, >= 0.
    timeline : str
        Name of the sequence timeline.
    log_static : bool
        Also log the static context (:func:`log_static_context`) unless this recording
        already holds it for the same sensor geometry, so it is logged once per
        recording however often log_scan is called.
    light : bool
        Leave out the intermediate images (residual, closed, edges), keep the points of
        every step-th row and column only (at most ``LIGHT_POINTS`` pixels: every second of
        a VGA frame) without explicit colours or grid indices (the annotation context
        colours them by label).

    Raises
    ------
    TypeError
        For a recording, cloud or result of the wrong type.
    ValueError
        For a negative or non-integer scan index, or labels/stages of the wrong shape.
    """
    if recording is None:
        return
    _rerun(recording)
    _check_cloud(cloud)
    _check_result(result, cloud.shape)
    if isinstance(scan_index, bool) or not isinstance(scan_index, (int, np.integer)) or scan_index < 0:
        raise ValueError(f"scan_index must be an integer >= 0; got {scan_index!r}")
    if log_static and _STATIC_LOGGED.get(recording) != _geometry_fingerprint(cloud):
        log_static_context(recording, cloud)
    recording.set_time(timeline, sequence=int(scan_index))
    colors = region_colors(result)
    rr = _rerun(recording)
    pose = np.eye(4) if cloud.pose is None else cloud.pose
    recording.log("world", rr.Transform3D(translation=pose[:3, 3], mat3x3=pose[:3, :3]))
    log_range(recording, cloud)
    log_stage_images(recording, {} if light else result.stages, shape=cloud.shape)
    context = annotation_context(result, colors)
    log_labels(recording, result, colors=colors, context=context)
    recording.log("world", context)
    log_points(recording, cloud, result.labels, colors=colors, light=light)
    log_features(recording, cloud, result, colors=colors)
    log_timings(recording, result.timings)
