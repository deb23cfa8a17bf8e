"""rangeseg_o3d: organized 3-D scans into planes, cylinders and spheres.

Importing this package does not import open3d, rerun or serial; they load where used.
"""

from .cloud import OrganizedCloud
from .config import PipelineConfig, load_config
from .fitting import fit_cylinder, fit_plane, fit_sphere
from .fitting.primitives import Cylinder, FitFailure, Plane, Sphere
from .kinematics import NoddingGeometry, PinholeGeometry
from .pipeline import Pipeline
from .registry import Plugin, Segmentation
from .result import Feature, Result, Unfitted

__all__ = [
    "OrganizedCloud",
    "NoddingGeometry",
    "PinholeGeometry",
    "Pipeline",
    "PipelineConfig",
    "load_config",
    "fit_plane",
    "fit_sphere",
    "fit_cylinder",
    "Plane",
    "Sphere",
    "Cylinder",
    "FitFailure",
    "Feature",
    "Unfitted",
    "Result",
    "Plugin",
    "Segmentation",
]
__version__ = "0.1.0"
