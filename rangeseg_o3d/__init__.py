"""rangeseg_o3d: organized 3-D scans into planes, cylinders and spheres.

The public names below load on first use (PEP 562): ``import rangeseg_o3d`` imports
nothing else, and importing one stage module (``rangeseg_o3d.segmentation.residual``, ``.edges``,
``.regions``) loads neither pydantic, yaml nor OpenCV. open3d, rerun and serial load
only where they are used.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ._lazy import lazy_attributes

# public name -> the module that defines it
_EXPORTS = {
    "OrganizedCloud": "cloud",
    "NoddingGeometry": "geometry",
    "PinholeGeometry": "geometry",
    "SphericalGeometry": "geometry",
    "Pipeline": "pipeline",
    "PipelineConfig": "config",
    "load_config": "config",
    "Sensor": "sensor",
    "NoiseModel": "sensor",
    "fit_plane": "fitting",
    "fit_sphere": "fitting",
    "fit_cylinder": "fitting",
    "Plane": "fitting.primitives",
    "Sphere": "fitting.primitives",
    "Cylinder": "fitting.primitives",
    "FitFailure": "fitting.primitives",
    "Feature": "result",
    "Unfitted": "result",
    "Result": "result",
    "Plugin": "registry",
    "Segmentation": "result",
}

__all__ = list(_EXPORTS)
__version__ = "0.1.0"

if TYPE_CHECKING:  # static analysers and IDEs see the names as ordinary imports
    from .cloud import OrganizedCloud
    from .config import PipelineConfig, load_config
    from .fitting import fit_cylinder, fit_plane, fit_sphere
    from .fitting.primitives import Cylinder, FitFailure, Plane, Sphere
    from .geometry import NoddingGeometry, PinholeGeometry, SphericalGeometry
    from .pipeline import Pipeline
    from .registry import Plugin
    from .result import Feature, Result, Segmentation, Unfitted
    from .sensor import NoiseModel, Sensor


__getattr__, __dir__ = lazy_attributes(__name__, _EXPORTS)
