"""Median time per fit of the plane, sphere and cylinder fitters and the primitive
classifier, on noisy synthetic patches of 200, 1000 and 10000 points.

Usage: python scripts/bench_fitting.py [--repeats 30]
"""

import argparse

import numpy as np

from rangeseg_o3d.fitting import fit_cylinder, fit_plane, fit_primitive, fit_sphere
from _timing import median_seconds  # scripts/_timing.py (scripts/ is on sys.path)


def frame(axis):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    u = np.cross(axis, [1.0, 0, 0] if abs(axis[0]) < 0.9 else [0, 1.0, 0])
    u /= np.linalg.norm(u)
    return axis, u, np.cross(axis, u)


def patches(n, rng, noise=0.005):
    """A plane, a 150 deg cylinder arc and a 150 deg sphere cap, LMS200-like noise."""
    w, u, v = frame((0.2, 0.3, 1.0))
    st = rng.uniform(-0.5, 0.5, (n, 2))
    plane = 2.0 * w + st[:, :1] * u + st[:, 1:] * v + rng.normal(0, noise, (n, 1)) * w
    t = rng.uniform(0, np.radians(150), n)
    radial = np.cos(t)[:, None] * u + np.sin(t)[:, None] * v
    cylinder = (0.3 + rng.normal(0, noise, (n, 1))) * radial + rng.uniform(-0.4, 0.4, (n, 1)) * w + [1, 2, 3]
    cos_t = rng.uniform(np.cos(np.radians(75)), 1, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    sin_t = np.sqrt(1 - cos_t**2)
    dirs = cos_t[:, None] * w + (sin_t * np.cos(phi))[:, None] * u + (sin_t * np.sin(phi))[:, None] * v
    sphere = (0.2 + rng.normal(0, noise, (n, 1))) * dirs + [0, 0.5, 2.5]
    return plane, cylinder, radial, sphere


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=30)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    cases = [
        ("fit_plane", lambda d: fit_plane(d["plane"])),
        ("fit_sphere", lambda d: fit_sphere(d["sphere"])),
        ("fit_cylinder", lambda d: fit_cylinder(d["cylinder"])),
        ("fit_cylinder+normals", lambda d: fit_cylinder(d["cylinder"], d["normals"])),
        ("fit_primitive(plane)", lambda d: fit_primitive(d["plane"])),
        ("fit_primitive(cylinder)", lambda d: fit_primitive(d["cylinder"])),
        ("fit_primitive(sphere)", lambda d: fit_primitive(d["sphere"])),
    ]
    sizes = (200, 1000, 10000)
    print(f"median time per fit over {args.repeats} runs (microseconds)")
    print(f"{'':26s}" + "".join(f"{n:>10d}" for n in sizes))
    data = {}
    for n in sizes:
        plane, cylinder, normals, sphere = patches(n, rng)
        data[n] = {"plane": plane, "cylinder": cylinder, "normals": normals, "sphere": sphere}
    for name, func in cases:
        row = [median_seconds(lambda: func(data[n]), args.repeats, warm=True) * 1e6 for n in sizes]
        print(f"{name:26s}" + "".join(f"{t:10.0f}" for t in row))


if __name__ == "__main__":
    main()
