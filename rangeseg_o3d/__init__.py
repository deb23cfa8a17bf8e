"""rangeseg_o3d: organized 3-D scans into planes, cylinders and spheres.

Importing this package does not import open3d, rerun or serial; they load where used.
"""

from .cloud import OrganizedCloud
from .fitting.models import Cylinder, FitFailure, Plane, Sphere
from .kinematics import NoddingGeometry, PinholeGeometry
from .result import Feature, Result, Unfitted

__all__ = [
    "OrganizedCloud",
    "NoddingGeometry",
    "PinholeGeometry",
    "Plane",
    "Sphere",
    "Cylinder",
    "FitFailure",
    "Feature",
    "Unfitted",
    "Result",
]
__version__ = "0.1.0"
