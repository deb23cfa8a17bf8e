"""What a pipeline run returns: labels, features, unfitted regions, timings."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .fitting.models import Cylinder, Plane, Sphere

__all__ = ["Feature", "Unfitted", "Result"]


@dataclass(frozen=True, eq=False)
class Feature:
    """A region of the grid and the geometric model fitted to it.

    ``label`` is the region's id in ``Result.labels``; ``kind``, ``rms``, ``inliers`` and the
    model's parameters (``normal``/``d``, ``center``/``radius``, ``axis``/``point``/``radius``)
    are read straight from the model.
    """

    label: int
    model: Plane | Sphere | Cylinder
    n_pixels: int

    @property
    def kind(self) -> str:
        return self.model.kind

    @property
    def rms(self) -> float:
        return float(self.model.rms)

    @property
    def inliers(self) -> int:
        return int(self.model.inliers)

    def __getattr__(self, name):
        # Only reached for names the dataclass lacks: expose the model's parameters.
        if name.startswith("_") or name == "model":
            raise AttributeError(name)
        try:
            return getattr(self.model, name)
        except AttributeError:
            raise AttributeError(
                f"{self.kind} feature has no attribute {name!r}"
            ) from None

    def to_dict(self) -> dict:
        return {
            "label": int(self.label),
            "kind": self.kind,
            "n_pixels": int(self.n_pixels),
            "inliers": self.inliers,
            "rms": self.rms,
            **self.model.params(),
        }


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

    def to_dict(self) -> dict:
        return {
            "shape": list(self.labels.shape),
            "n_regions": int(len(self.features) + len(self.unfitted)),
            "counts": self.counts(),
            "features": [f.to_dict() for f in self.features],
            "unfitted": [u.to_dict() for u in self.unfitted],
            "timings": {k: float(v) for k, v in self.timings.items()},
        }
