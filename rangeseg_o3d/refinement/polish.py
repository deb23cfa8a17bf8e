"""Step 8, ``polish``: spheres and cylinders are refitted once on their final pixels.

Planes are refitted from moments whenever they change, which costs nothing; the other
kinds keep the parameters of the points they were fitted to until here.
"""

from __future__ import annotations

import numpy as np

from ..fitting.primitives import Plane
from .context import Context

__all__ = ["polish_models"]


def polish_models(ctx: Context, labels: np.ndarray, fits: dict) -> dict:
    """``fits`` with the models moments cannot refit (spheres, cylinders) refitted on the
    pixels of ``labels``.

    Only where the region outgrew the points the model was fitted to by more than 20 %
    (a model's ``inliers`` counts those): a few more pixels move nothing.
    """
    fits = dict(fits)
    sizes = np.bincount(labels.ravel(), minlength=max(fits, default=0) + 1)
    curved = [k for k, m in fits.items()
              if m and not isinstance(m, Plane) and sizes[k] > 1.2 * max(m.inliers, 1)]
    for k, refit in ctx.fitter.refit_regions(ctx.xyz, labels, fits, curved, from_moments=False).items():
        if refit and refit.kind == fits[k].kind:
            fits[k] = refit
    return fits
