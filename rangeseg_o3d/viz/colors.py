"""Region colours and names shared by the rerun log and the PNG panel.

Each region gets a colour from its feature's kind (planes blue, cylinders green,
spheres red, unfitted grey) shaded by its label, so the same label keeps its colour
from scan to scan and neighbouring regions of one kind stay distinguishable.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "KIND_HUES",
    "NO_REGION_RGB",
    "region_kinds",
    "region_names",
    "region_colors",
    "hsv_to_rgb",
]

#: Base hue (degrees) of each feature kind; regions of other kinds are grey.
KIND_HUES = {"plane": 215.0, "cylinder": 120.0, "sphere": 0.0}
#: Colour of label 0 (in no region) and of pixels without a return.
NO_REGION_RGB = (40, 40, 40)

# Golden-ratio sequences spread consecutive labels far apart in shade.
_PHI_1 = 0.6180339887
_PHI_2 = 0.7548776662


def region_kinds(result) -> dict[int, str]:
    """Map each labelled region of ``result`` to its kind.

    Parameters
    ----------
    result : rangeseg_o3d.Result

    Returns
    -------
    dict
        ``label -> "plane" | "cylinder" | "sphere" | "unfitted" | "region"``; "region"
        marks a label present in ``result.labels`` that is neither fitted nor listed as
        unfitted.
    """
    labels = np.asarray(result.labels)
    kinds = {int(lab): "region" for lab in np.unique(labels) if lab > 0}
    for unfit in result.unfitted:
        kinds[int(unfit.label)] = "unfitted"
    for feat in result.features:
        kinds[int(feat.label)] = feat.kind
    return kinds


def _feature_name(feat) -> str:
    if feat.kind in ("cylinder", "sphere"):
        return f"{feat.kind} {feat.label} r={float(feat.radius):.2f} m"
    return f"{feat.kind} {feat.label}"


def region_names(result) -> dict[int, str]:
    """Human-readable name of every region: "plane 3", "cylinder 7 r=0.21 m", "unfitted 9".

    Parameters
    ----------
    result : rangeseg_o3d.Result

    Returns
    -------
    dict
        ``label -> name`` for every label in :func:`region_kinds`.

    Examples
    --------
    >>> import numpy as np
    >>> from rangeseg_o3d import Result, Feature, Sphere
    >>> labels = np.array([[0, 5]], dtype=np.int32)
    >>> sphere = Sphere(center=(0, 0, 1), radius=0.3, rms=0.0, inliers=1)
    >>> region_names(Result(labels, [Feature(5, sphere, 1)]))
    {5: 'sphere 5 r=0.30 m'}
    """
    names = {lab: f"{kind} {lab}" for lab, kind in region_kinds(result).items()}
    for feat in result.features:
        names[int(feat.label)] = _feature_name(feat)
    return names


def hsv_to_rgb(hue_deg, saturation, value) -> np.ndarray:
    """Vectorised HSV -> RGB.

    Parameters
    ----------
    hue_deg, saturation, value : array_like
        Hue in degrees (any real; wrapped), saturation and value in [0, 1].

    Returns
    -------
    (..., 3) uint8 array
    """
    h = (np.asarray(hue_deg, dtype=float) % 360.0) / 60.0
    s = np.clip(np.asarray(saturation, dtype=float), 0.0, 1.0)
    v = np.clip(np.asarray(value, dtype=float), 0.0, 1.0)
    h, s, v = np.broadcast_arrays(h, s, v)
    sector = np.floor(h).astype(int) % 6
    frac = h - np.floor(h)
    p = v * (1.0 - s)
    q = v * (1.0 - frac * s)
    t = v * (1.0 - (1.0 - frac) * s)
    choices_r = np.stack([v, q, p, p, t, v])
    choices_g = np.stack([t, v, v, q, p, p])
    choices_b = np.stack([p, p, t, v, v, q])
    idx = sector[None]
    rgb = np.stack(
        [np.take_along_axis(c, idx, axis=0)[0] for c in (choices_r, choices_g, choices_b)],
        axis=-1,
    )
    return np.round(rgb * 255.0).astype(np.uint8)


def region_colors(result) -> np.ndarray:
    """Colour lookup table indexed by label.

    Parameters
    ----------
    result : rangeseg_o3d.Result

    Returns
    -------
    (max_label + 1, 3) uint8 array
        Row ``k`` is the RGB colour of region ``k``; row 0 is :data:`NO_REGION_RGB`.
    """
    kinds = region_kinds(result)
    top = max(kinds, default=0)
    labels = np.arange(top + 1)
    shade_a = (labels * _PHI_1) % 1.0
    shade_b = (labels * _PHI_2) % 1.0
    hue = np.zeros(top + 1)
    sat = np.zeros(top + 1)
    val = 0.45 + 0.4 * shade_a  # greys for unfitted / unknown regions
    for lab, kind in kinds.items():
        if kind in KIND_HUES:
            hue[lab] = KIND_HUES[kind] + (shade_a[lab] - 0.5) * 50.0
            sat[lab] = 0.55 + 0.45 * shade_b[lab]
            val[lab] = 0.75 + 0.25 * (1.0 - shade_b[lab])
    lut = hsv_to_rgb(hue, sat, val)
    lut[0] = NO_REGION_RGB
    return lut
