"""Synthetic scenes, exact ray casting and simulated sensors with ground truth."""

from .raycast import cast
from .scene import (
    CylinderSide,
    Disk,
    Rectangle,
    Scene,
    SphereSurface,
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
