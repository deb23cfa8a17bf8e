"""The ABW structured-light range images with hand-labelled ground truth (SegComp, Hoover
et al. 1996), as converted in ``<repo>/../shared/data/abw`` (see its SOURCES.md).

Each ``abw.test.N.npz`` holds ``xyz`` (512 x 512 x 3, metres, camera at the origin looking
along +z, NaN = no data) and ``gt`` (1..K planar surfaces, 0 = no data or unlabelled).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..cloud import OrganizedCloud
from .datasets import default_data_root

__all__ = ["AbwImage", "abw_images", "load_abw"]


@dataclass(frozen=True)
class AbwImage:
    """One ABW image: its cloud and its ground-truth label image (0 = unlabelled)."""

    name: str
    cloud: OrganizedCloud
    truth_ids: np.ndarray


def load_abw(path) -> AbwImage:
    """Read one converted ABW image.

    Raises
    ------
    FileNotFoundError
        If the file is missing.
    ValueError
        If it lacks ``xyz`` (H, W, 3) or ``gt`` (H, W).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}")
    with np.load(path) as data:
        if "xyz" not in data.files or "gt" not in data.files:
            raise ValueError(f"{path}: expected arrays 'xyz' and 'gt'; got {sorted(data.files)}")
        xyz = np.asarray(data["xyz"], dtype=np.float64)
        gt = np.asarray(data["gt"])
    if xyz.ndim != 3 or xyz.shape[2] != 3 or gt.shape != xyz.shape[:2]:
        raise ValueError(f"{path}: expected xyz (H, W, 3) and gt (H, W); got {xyz.shape} and {gt.shape}")
    name = path.name.removesuffix(".npz")
    return AbwImage(name=name, cloud=OrganizedCloud(xyz), truth_ids=gt.astype(np.int32))


def abw_images(data_root=None) -> list[Path]:
    """Paths of the ABW images present (``abw/abw.test.*.npz``), in image order; [] if none."""
    root = Path(data_root) if data_root is not None else default_data_root()
    found = list((root / "abw").glob("abw.test.*.npz"))

    def number(path: Path) -> int:
        tail = path.name.removesuffix(".npz").rsplit(".", 1)[-1]
        return int(tail) if tail.isdigit() else 10**9

    return sorted(found, key=lambda p: (number(p), p.name))
