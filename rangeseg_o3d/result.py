"""What the stages return: a segmenter's Segmentation, the Regions passed between stages, and a run's
Result (labels, features with their patch geometry, unfitted regions, timings)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .fitting.primitives import Cylinder, Plane, Sphere

__all__ = ["Segmentation", "Regions", "Feature", "Unfitted", "Result", "INLIER_SIGMAS", "RESULT_FORMAT"]

#: A pixel is an inlier of its region's model when its orthogonal distance is within this
#: many sensor noise sigmas at its range (the configuration's noise model).
INLIER_SIGMAS = 2.0
#: The ``format`` entry of :meth:`Result.to_dict` (bumped when the layout changes).
RESULT_FORMAT = "rangeseg_o3d.result/2"

_MODELS = {"plane": Plane, "sphere": Sphere, "cylinder": Cylinder}


@dataclass(frozen=True)
class Segmentation:
    """What a segmenter returns.

    labels : (H, W) int32, 0 = in no region, regions numbered 1..n.
    stages : intermediate (H, W) images worth inspecting, e.g. ``residual``, ``closed``, ``edges``.
    timings : seconds per internal stage.
    jumps : (H, W) bool, the depth jumps between neighbouring pixels, which the refinement
        never grows a region across; None when the segmenter finds none.
    """

    labels: np.ndarray
    stages: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    jumps: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class Regions:
    """Regions of a grid and their models, as they pass from stage to stage inside a run.

    labels : (H, W) int32, 0 = in no region.
    models : label -> fitted model, or a falsy FitFailure for a region no model explains
        (a label without an entry has no model yet).
    """

    labels: np.ndarray
    models: dict


@dataclass(frozen=True, eq=False)
class Feature:
    """A region of the grid and the geometric model fitted to it.

    ``label`` is the region's id in ``Result.labels``; ``kind``, ``rms``, ``inliers`` and the
    model's parameters (``normal``/``d``, ``center``/``radius``, ``axis``/``point``/``radius``)
    are read straight from the model. ``inliers`` counts the region's pixels within
    :data:`INLIER_SIGMAS` noise sigmas of the surface.

    The seen part of the surface (:attr:`geometry`) and the parameters' :attr:`covariance`
    are computed on first access from the grid the feature was found in (``source``)
    and cached; their fields read as attributes too: a plane's ``boundary``, ``area``,
    ``centroid``, ``extent``; a cylinder's ``segment``, ``height``, ``angle_span``; a
    sphere's ``cap_axis``, ``cap_angle``, ``cap_area``. See :mod:`rangeseg_o3d.patches`.
    """

    label: int
    model: Plane | Sphere | Cylinder
    n_pixels: int
    source: object = field(default=None, repr=False)  # a patches.PatchSource, or None
    _cache: dict = field(default_factory=dict, repr=False)

    @property
    def kind(self) -> str:
        return self.model.kind

    @property
    def rms(self) -> float:
        return float(self.model.rms)

    @property
    def inliers(self) -> int:
        return int(self.model.inliers)

    @property
    def geometry(self):
        """The seen patch (PlanePatch, CylinderPatch or SpherePatch), or None without a grid."""
        if "geometry" not in self._cache:
            from . import patches

            if self.source is None or self.kind not in ("plane", "cylinder", "sphere"):
                return None
            if self.kind == "plane":
                patch = patches.plane_patch(self.source, self.label, self.model)
            else:
                points = self.source.points(self.label)
                patch = (patches.cylinder_patch(points, self.model) if self.kind == "cylinder"
                         else patches.sphere_patch(points, self.model))
            self._cache["geometry"] = patch
        return self._cache["geometry"]

    @property
    def covariance(self) -> np.ndarray | None:
        """First-order covariance of the model's parameters (order: ``parameter_names``), or None."""
        if "covariance" not in self._cache:
            from . import patches

            if self.source is None or self.kind not in ("plane", "cylinder", "sphere"):
                return None
            self._cache["covariance"] = patches.parameter_covariance(
                self.source.points(self.label), self.model, n_total=self.n_pixels)
        return self._cache["covariance"]

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Order of the parameters in :attr:`covariance`."""
        from .patches import parameter_names

        return parameter_names(self.kind)

    def __getattr__(self, name):
        # Only reached for names the dataclass lacks: the model's parameters, then the patch's.
        if name.startswith("_") or name in ("model", "source"):
            raise AttributeError(name)
        try:
            return getattr(self.model, name)
        except AttributeError:
            pass
        patch = self.geometry
        if patch is not None and hasattr(patch, name):
            return getattr(patch, name)
        extra = "" if patch is not None else " (no patch geometry: the feature has no grid)"
        raise AttributeError(f"{self.kind} feature has no attribute {name!r}{extra}") from None

    def to_dict(self) -> dict:
        out = {
            "label": int(self.label),
            "kind": self.kind,
            "n_pixels": int(self.n_pixels),
            "inliers": self.inliers,
            "rms": self.rms,
            **self.model.params(),
        }
        covariance = self.covariance
        if covariance is not None:
            out["parameter_names"] = list(self.parameter_names)
            out["covariance"] = covariance.tolist()
        patch = self.geometry
        if patch is not None:
            out["geometry"] = patch.to_dict()
        return out

    @classmethod
    def from_dict(cls, data: dict) -> "Feature":
        """The feature :meth:`to_dict` wrote (with its geometry and covariance when stored)."""
        from .patches import patch_from_dict

        kind = data.get("kind")
        if kind not in _MODELS:
            raise ValueError(f"feature kind must be one of {sorted(_MODELS)}; got {kind!r}")
        model_type = _MODELS[kind]
        names = {"plane": ("normal", "d"), "sphere": ("center", "radius"),
                 "cylinder": ("axis", "point", "radius")}[kind]
        missing = [k for k in (*names, "label", "n_pixels", "rms", "inliers") if k not in data]
        if missing:
            raise ValueError(f"{kind} feature record lacks {', '.join(missing)}")
        model = model_type(**{k: data[k] for k in names}, rms=float(data["rms"]),
                           inliers=int(data["inliers"]))
        cache = {}
        if "covariance" in data:
            cache["covariance"] = np.asarray(data["covariance"], dtype=float)
        if "geometry" in data:
            cache["geometry"] = patch_from_dict(kind, data["geometry"])
        return cls(label=int(data["label"]), model=model, n_pixels=int(data["n_pixels"]),
                   _cache=cache)


def counted(n: int, kind: str) -> str:
    """``n`` features of ``kind`` in words: ``"1 sphere"``, ``"2 spheres"``, ``"0 planes"``."""
    return f"{n} {kind}" if n == 1 else f"{n} {kind}s"


def _parameter_text(f: Feature) -> str:
    if f.kind == "plane":
        return f"n=({f.normal[0]:+.3f}, {f.normal[1]:+.3f}, {f.normal[2]:+.3f}) d={f.d:+.3f} m"
    if f.kind == "sphere":
        c = f.center
        return f"c=({c[0]:+.3f}, {c[1]:+.3f}, {c[2]:+.3f}) r={f.radius:.3f} m"
    a, p = f.axis, f.point
    return (f"axis=({a[0]:+.3f}, {a[1]:+.3f}, {a[2]:+.3f}) "
            f"p=({p[0]:+.3f}, {p[1]:+.3f}, {p[2]:+.3f}) r={f.radius:.3f} m")


@dataclass(frozen=True)
class Unfitted:
    """A region no model explained, and why."""

    label: int
    n_pixels: int
    reason: str

    def to_dict(self) -> dict:
        return {"label": int(self.label), "n_pixels": int(self.n_pixels), "reason": self.reason}


@dataclass(frozen=True, eq=False)
class Result:
    """Outcome of :meth:`rangeseg_o3d.Pipeline.run`.

    labels : (H, W) int32, 0 = in no region.
    features : fitted regions, in label order.
    unfitted : regions with no acceptable model.
    timings : seconds per stage (``total`` included).
    stages : intermediate images (``residual``, ``closed``, ``edges``, ...).
    """

    labels: np.ndarray
    features: list[Feature]
    unfitted: list[Unfitted] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    stages: dict[str, np.ndarray] = field(default_factory=dict)

    def feature(self, label: int) -> Feature | None:
        """The feature of region ``label``, or None."""
        for feat in self.features:
            if feat.label == label:
                return feat
        return None

    def counts(self) -> dict[str, int]:
        """Number of features per kind, plus ``unfitted``."""
        out = {"plane": 0, "cylinder": 0, "sphere": 0}
        for feat in self.features:
            out[feat.kind] += 1
        out["unfitted"] = len(self.unfitted)
        return out

    def table(self, *, title: str = "") -> str:
        """A readable table of the features and unfitted regions, with timings."""
        lines = [title] if title else []
        lines.append(f"{'label':>5}  {'kind':<8} {'pixels':>6} {'rms mm':>7}  parameters")
        for f in self.features:
            lines.append(f"{f.label:>5}  {f.kind:<8} {f.n_pixels:>6} {f.rms * 1e3:>7.2f}  {_parameter_text(f)}")
        for u in self.unfitted:
            lines.append(f"{u.label:>5}  {'unfitted':<8} {u.n_pixels:>6} {'':>7}  {u.reason}")
        counts = self.counts()
        lines.append(", ".join(counted(counts[kind], kind) for kind in ("plane", "cylinder", "sphere"))
                     + f", {counts['unfitted']} unfitted")
        lines.append("timings: " + ", ".join(f"{k} {v * 1e3:.2f} ms" for k, v in self.timings.items()))
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """Everything but the per-pixel labels and stage images, as JSON-ready values.

        Each feature carries its model, ``inliers`` (rule in ``inlier_rule``), the
        parameter ``covariance`` and its patch ``geometry`` (computed here if not yet).
        """
        return {
            "format": RESULT_FORMAT,
            "shape": list(self.labels.shape),
            "n_regions": int(len(self.features) + len(self.unfitted)),
            "counts": self.counts(),
            "plane_convention": "normal . p = d, unit normal, d >= 0 (Open3D: [a, b, c, d] = "
                                "[normal, -d])",
            "inlier_rule": f"|distance| <= {INLIER_SIGMAS:g} sigma(range) of the sensor noise model",
            "features": [f.to_dict() for f in self.features],
            "unfitted": [u.to_dict() for u in self.unfitted],
            "timings": {k: float(v) for k, v in self.timings.items()},
        }

    @classmethod
    def from_dict(cls, data: dict, labels: np.ndarray | None = None) -> "Result":
        """The result :meth:`to_dict` wrote; ``labels`` (e.g. the ``--labels`` PNG) are not in it.

        Without ``labels`` the result's labels are all 0 (of the stored shape).

        Raises
        ------
        ValueError
            If ``data`` is not such a record, or ``labels`` has another shape.
        """
        if not isinstance(data, dict) or "features" not in data or "shape" not in data:
            raise ValueError("a result record must be a dict with 'shape' and 'features' "
                             f"(as Result.to_dict writes); got {type(data).__name__}"
                             + (f" with keys {sorted(data)[:8]}" if isinstance(data, dict) else ""))
        shape = tuple(int(s) for s in data["shape"])
        if labels is None:
            labels = np.zeros(shape, np.int32)
        labels = np.asarray(labels)
        if labels.shape != shape:
            raise ValueError(f"labels must have the stored shape {shape}; got {labels.shape}")
        return cls(
            labels=labels.astype(np.int32, copy=False),
            features=[Feature.from_dict(f) for f in data["features"]],
            unfitted=[Unfitted(int(u["label"]), int(u["n_pixels"]), str(u["reason"]))
                      for u in data.get("unfitted", [])],
            timings={k: float(v) for k, v in data.get("timings", {}).items()},
        )

    def to_open3d(self, cloud, *, legacy: bool = False) -> list:
        """Open3D geometries: the points coloured by region, then one mesh per feature.

        See :func:`rangeseg_o3d.io.export.result_to_open3d`.
        """
        from .io.export import result_to_open3d

        return result_to_open3d(self, cloud, legacy=legacy)

    def write_ply(self, path, cloud):
        """One PLY of the labelled, coloured points and every feature's mesh; see
        :func:`rangeseg_o3d.io.export.write_ply`."""
        from .io.export import write_ply

        return write_ply(path, self, cloud)
