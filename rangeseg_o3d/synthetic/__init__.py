"""Synthetic scenes, exact ray casting and simulated sensors with ground truth."""

from .depth_camera import camera_pose_scene, simulate_depth_camera
from .lms200 import lms200_row_ranges, nodding_ranges, simulate_lms200
from .raycast import cast
from .suite import default_scene, lms200_suite, rgbd_suite
from .scene import (
    CylinderSide,
    Disk,
    Rectangle,
    Scene,
    SphereSurface,
    SyntheticScan,
    box,
    cylinder,
    patch,
    room,
    rotation_from_to,
    rotation_z,
    sphere,
)

__all__ = [
    "cast",
    "default_scene",
    "lms200_suite",
    "rgbd_suite",
    "simulate_lms200",
    "lms200_row_ranges",
    "nodding_ranges",
    "simulate_depth_camera",
    "camera_pose_scene",
    "SyntheticScan",
    "Scene",
    "Rectangle",
    "Disk",
    "CylinderSide",
    "SphereSurface",
    "room",
    "box",
    "cylinder",
    "sphere",
    "patch",
    "rotation_z",
    "rotation_from_to",
]
