"""Point generators with known parameters for the fitting tests (session fixtures returning functions)."""

from pathlib import Path

import numpy as np
import pytest

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data"


def frame(axis):
    """Unit ``axis`` and two unit vectors completing it to an orthonormal frame."""
    axis = np.asarray(axis, float)
    axis = axis / np.linalg.norm(axis)
    helper = np.array([1.0, 0, 0]) if abs(axis[0]) < 0.9 else np.array([0, 1.0, 0])
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    return axis, u, np.cross(axis, u)


def plane_points(rng, normal, d, n=300, size=1.0, noise=0.0):
    """Points on ``normal . p = d`` spread over a ``size`` square, Gaussian noise along the normal."""
    normal, u, v = frame(normal)
    st = rng.uniform(-size / 2, size / 2, (n, 2))
    offset = rng.normal(0, noise, (n, 1)) if noise else np.zeros((n, 1))
    return (d + offset) * normal + st[:, :1] * u + st[:, 1:] * v


def cylinder_points(rng, axis, point, radius, n=300, arc=np.pi, length=1.0, noise=0.0, start=0.0):
    """Points on an arc of ``arc`` radians (starting at angle ``start``) of a cylinder; returns (points, normals)."""
    axis, u, v = frame(axis)
    t = start + rng.uniform(0, arc, n)
    z = rng.uniform(-length / 2, length / 2, n)
    radial = np.cos(t)[:, None] * u + np.sin(t)[:, None] * v
    r = radius + (rng.normal(0, noise, n) if noise else 0.0)
    return np.asarray(point, float) + np.asarray(r)[..., None] * radial + z[:, None] * axis, radial


def sphere_points(rng, center, radius, n=300, cap=np.pi, direction=(0, 0, -1), noise=0.0):
    """Points on a cap of full opening angle ``cap`` radians around ``direction``; returns (points, normals)."""
    w, u, v = frame(direction)
    cos_t = rng.uniform(np.cos(cap / 2), 1.0, n)  # uniform on the cap's area
    sin_t = np.sqrt(1 - cos_t**2)
    phi = rng.uniform(0, 2 * np.pi, n)
    radial = cos_t[:, None] * w + (sin_t * np.cos(phi))[:, None] * u + (sin_t * np.sin(phi))[:, None] * v
    r = radius + (rng.normal(0, noise, n) if noise else 0.0)
    return np.asarray(center, float) + np.asarray(r)[..., None] * radial, radial


def angle_deg(a, b):
    """Angle between two lines (sign-free), degrees."""
    a = np.asarray(a, float) / np.linalg.norm(a)
    b = np.asarray(b, float) / np.linalg.norm(b)
    # atan2 stays exact near 0, where arccos of a dot product loses half the digits
    return float(np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b)), abs(a @ b))))


def line_distance(point, axis, other):
    """Distance of ``other`` from the line through ``point`` along unit-ish ``axis``."""
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    rel = np.asarray(other, float) - point
    return float(np.linalg.norm(rel - (rel @ axis) * axis))


class Synth:
    plane = staticmethod(plane_points)
    cylinder = staticmethod(cylinder_points)
    sphere = staticmethod(sphere_points)
    angle_deg = staticmethod(angle_deg)
    line_distance = staticmethod(line_distance)
    frame = staticmethod(frame)


@pytest.fixture(scope="session")
def synth():
    return Synth


@pytest.fixture(scope="session")
def shared_data():
    if not DATA.is_dir():
        pytest.skip(f"shared data not found at {DATA}")
    return DATA
