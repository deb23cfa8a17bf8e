"""Segmentation quality against ground truth: Hoover et al. (1996) metrics and parameter errors.

Hoover metrics (``shared/docs/anchors.md``). With ``O`` the overlap in pixels of a
ground-truth region ``Rm`` (``Pm`` pixels) and a machine region ``Rn`` (``Pn`` pixels),
at tolerance ``T`` in (0.5, 1]:

* correct detection: ``O >= T*Pn`` and ``O >= T*Pm``;
* over-segmentation: one ``Rm`` and ``x >= 2`` machine regions, each ``O_i >= T*Pn_i``,
  ``sum O_i >= T*Pm``;
* under-segmentation: one ``Rn`` and ``x >= 2`` ground-truth regions, each
  ``O_i >= T*Pm_i``, ``sum O_i >= T*Pn``;
* missed: a counted ground-truth region in none of these; noise: a machine region in none.

Choices made here (documented because the paper leaves them open):

* Pixels whose truth id is 0 (no return, mixed pixel) are "don't care": they count in
  neither ``Pm`` nor ``Pn``. A machine region made only of such pixels is ignored.
* Ground-truth regions smaller than ``min_region`` pixels are not counted (not as
  correct, not as missed) and cannot take part in an under-segmentation. A machine
  region at least half of whose pixels lie on such small regions is ignored rather than
  counted as noise: it found something real that the metric does not score.
* Conflicts (a region qualifying for several classifications): every candidate
  classification gets an averaged overlap score, ``(O/Pm + O/Pn) / 2`` for a correct
  pair; ``(sum O_i / Pm + mean O_i / Pn_i) / 2`` for an over-segmentation and the mirror
  image for an under-segmentation. Candidates are accepted greedily from the highest
  score, skipping any that reuses an already classified region, so ties go to the class
  with the higher averaged overlap.

SegComp's compare rules (``count_unlabelled=True``, for real ground truth such as ABW):
overlaps are counted over all pixels, so ``Pn`` is the machine region's whole size and
its pixels on the annotators' unlabelled pixels (truth id 0) count against it (a region
that spills over unlabelled pixels can fall below ``T*Pn``); every machine region is
scored (none ignored; one lying wholly on unlabelled or small ground-truth pixels is noise).

The overlaps come from one contingency table (``np.unique`` over label pairs), so the
cost is linear in pixels; only the (few) regions are looped over.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

__all__ = ["HooverScore", "Evaluation", "RegionError", "hoover", "evaluate", "parameter_errors",
           "surface_breakdown", "connected_patches"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class HooverScore:
    """Hoover classification of one segmentation.

    ``correct`` maps truth id -> machine label; ``over`` truth id -> [labels];
    ``under`` machine label -> [truth ids]; ``missed`` and ``noise`` list ids.
    ``n_truth`` counts the ground-truth regions scored (>= min_region pixels);
    ``n_machine`` the machine regions scored (not ignored).
    """

    n_truth: int
    n_machine: int
    correct: dict = field(default_factory=dict)
    over: dict = field(default_factory=dict)
    under: dict = field(default_factory=dict)
    missed: list = field(default_factory=list)
    noise: list = field(default_factory=list)
    tolerance: float = 0.8
    min_region: int = 60

    @property
    def n_correct(self) -> int:
        return len(self.correct)

    @property
    def n_over(self) -> int:
        return len(self.over)

    @property
    def n_under(self) -> int:
        return len(self.under)

    @property
    def n_missed(self) -> int:
        return len(self.missed)

    @property
    def n_noise(self) -> int:
        return len(self.noise)

    @property
    def percent_correct(self) -> float:
        """100 * correct / n_truth; NaN when no ground-truth region is scored."""
        return 100.0 * self.n_correct / self.n_truth if self.n_truth else float("nan")

    def counts(self) -> dict:
        return {
            "n_truth": self.n_truth,
            "n_machine": self.n_machine,
            "correct": self.n_correct,
            "over": self.n_over,
            "under": self.n_under,
            "missed": self.n_missed,
            "noise": self.n_noise,
        }

    def to_dict(self) -> dict:
        return {
            **self.counts(),
            "percent_correct": self.percent_correct,
            "tolerance": self.tolerance,
            "min_region": self.min_region,
            "pairs": {
                "correct": {int(k): int(v) for k, v in self.correct.items()},
                "over": {int(k): [int(x) for x in v] for k, v in self.over.items()},
                "under": {int(k): [int(x) for x in v] for k, v in self.under.items()},
                "missed": [int(x) for x in self.missed],
                "noise": [int(x) for x in self.noise],
            },
        }


def _check_images(truth_ids, labels) -> tuple[np.ndarray, np.ndarray]:
    t = np.asarray(truth_ids)
    m = np.asarray(labels)
    if t.ndim != 2:
        raise ValueError(f"truth_ids must have shape (H, W); got {t.shape}")
    if m.shape != t.shape:
        raise ValueError(f"labels must have the shape of truth_ids {t.shape}; got {m.shape}")
    for name, arr in (("truth_ids", t), ("labels", m)):
        if not np.issubdtype(arr.dtype, np.integer):
            raise ValueError(f"{name} must be an integer image; got dtype {arr.dtype}")
        if arr.size and arr.min() < 0:
            raise ValueError(f"{name} must be >= 0 (0 = none); got minimum {arr.min()}")
    return t.astype(np.int64, copy=False), m.astype(np.int64, copy=False)


def _overlap_table(t: np.ndarray, m: np.ndarray):
    """Dense overlap matrix between truth ids (rows) and machine labels (columns), care pixels only."""
    care = t > 0
    pairs, counts = np.unique(np.stack([t[care], m[care]]), axis=1, return_counts=True)
    truth_ids = np.unique(pairs[0]) if pairs.size else np.zeros(0, np.int64)
    machine_ids = np.unique(m[m > 0])
    table = np.zeros((truth_ids.size, machine_ids.size), dtype=np.int64)
    truth_size = np.zeros(truth_ids.size, dtype=np.int64)
    if pairs.size:
        rows = np.searchsorted(truth_ids, pairs[0])
        np.add.at(truth_size, rows, counts)
        labelled = pairs[1] > 0
        cols = np.searchsorted(machine_ids, pairs[1][labelled])
        table[rows[labelled], cols] = counts[labelled]
    return truth_ids, machine_ids, table, truth_size


def hoover(truth_ids, labels, *, tolerance: float = 0.8, min_region: int = 60,
           count_unlabelled: bool = False) -> HooverScore:
    """Hoover et al. (1996) classification of a segmentation against ground truth.

    Parameters
    ----------
    truth_ids : (H, W) int, 0 = don't care (no return, mixed pixel).
    labels : (H, W) int, 0 = in no region.
    tolerance : T in (0.5, 1].
    min_region : ground-truth regions with fewer pixels are not scored.
    count_unlabelled : SegComp's rules (module docstring): a machine region's size counts
        all its pixels, truth id 0 included, and no machine region is ignored.

    Returns
    -------
    HooverScore

    Examples
    --------
    >>> t = np.repeat([[1] * 10 + [2] * 10], 10, axis=0)
    >>> hoover(t, t, min_region=1).counts()["correct"]
    2
    """
    if not (0.5 < tolerance <= 1.0):
        raise ValueError(f"tolerance must be in (0.5, 1]; got {tolerance}")
    if int(min_region) != min_region or min_region < 1:
        raise ValueError(f"min_region must be a positive integer; got {min_region}")
    t, m = _check_images(truth_ids, labels)
    truth_ids_, machine_ids, table, p_m = _overlap_table(t, m)
    counted = p_m >= min_region
    if count_unlabelled:
        p_n = np.bincount(np.searchsorted(machine_ids, m[m > 0]), minlength=machine_ids.size)
        ignored = np.zeros(machine_ids.size, dtype=bool)
    else:
        p_n = table.sum(axis=0)
        small_overlap = table[~counted].sum(axis=0)
        ignored = (p_n == 0) | (small_overlap * 2 >= np.maximum(p_n, 1))

    tp_m = tolerance * p_m[:, None]
    tp_n = tolerance * p_n[None, :]
    inside_m = (table >= tp_n) & (table > 0) & ~ignored[None, :]  # machine n mostly inside truth m
    inside_n = (table >= tp_m) & (table > 0) & counted[:, None]  # truth m mostly inside machine n
    with np.errstate(divide="ignore", invalid="ignore"):
        frac_m = np.where(p_m[:, None] > 0, table / p_m[:, None], 0.0)
        frac_n = np.where(p_n[None, :] > 0, table / np.maximum(p_n[None, :], 1), 0.0)

    candidates = []  # (score, kind, truth rows, machine cols)
    for i, j in zip(*np.nonzero(inside_m & inside_n & counted[:, None])):
        candidates.append(((frac_m[i, j] + frac_n[i, j]) / 2, "correct", [i], [j]))
    for i in np.nonzero(counted)[0]:
        cols = np.nonzero(inside_m[i])[0]
        if cols.size >= 2 and table[i, cols].sum() >= tolerance * p_m[i]:
            score = (frac_m[i, cols].sum() + frac_n[i, cols].mean()) / 2
            candidates.append((score, "over", [i], cols.tolist()))
    for j in np.nonzero(~ignored)[0]:
        rows = np.nonzero(inside_n[:, j])[0]
        if rows.size >= 2 and table[rows, j].sum() >= tolerance * p_n[j]:
            score = (frac_n[rows, j].sum() + frac_m[rows, j].mean()) / 2
            candidates.append((score, "under", rows.tolist(), [j]))

    # Highest averaged overlap first; kind order breaks exact ties deterministically.
    rank = {"correct": 0, "over": 1, "under": 2}
    candidates.sort(key=lambda c: (-c[0], rank[c[1]], c[2], c[3]))
    used_t: set[int] = set()
    used_m: set[int] = set()
    correct, over, under = {}, {}, {}
    for _, kind, rows, cols in candidates:
        if used_t.intersection(rows) or used_m.intersection(cols):
            continue
        used_t.update(rows)
        used_m.update(cols)
        tids = [int(truth_ids_[r]) for r in rows]
        mids = [int(machine_ids[c]) for c in cols]
        if kind == "correct":
            correct[tids[0]] = mids[0]
        elif kind == "over":
            over[tids[0]] = mids
        else:
            under[mids[0]] = tids
    missed = [int(truth_ids_[i]) for i in np.nonzero(counted)[0] if i not in used_t]
    noise = [int(machine_ids[j]) for j in np.nonzero(~ignored)[0] if j not in used_m]
    return HooverScore(
        n_truth=int(counted.sum()),
        n_machine=int((~ignored).sum()),
        correct=correct,
        over=over,
        under=under,
        missed=missed,
        noise=noise,
        tolerance=float(tolerance),
        min_region=int(min_region),
    )


def surface_breakdown(truth_ids, labels, score: HooverScore, *, kinds: dict | None = None,
                      parts: int = 5) -> list[dict]:
    """Where the pixels of each scored ground-truth surface that ``score`` does not count as
    correctly detected went: the per-surface view behind the Hoover counts.

    Returns one dict per such surface, in truth-id order: ``truth_id``, ``pixels`` (its
    size), ``status`` (``"missed"``, ``"over"`` or ``"under"``) and ``parts``, its largest
    ``parts`` shares, largest first, each ``(label, kind, pixels, share)``: label 0 (no
    region) has kind ``""`` and share 0; otherwise ``kind`` is ``kinds[label]`` (``"?"``
    when unknown) and ``share`` the fraction of that region's pixels lying on the surface.
    A surface the score ignores (below its ``min_region``) is not listed.

    Examples
    --------
    >>> t = np.repeat([[1] * 10 + [2] * 10], 10, axis=0)
    >>> m = np.ones_like(t)                  # one region over both surfaces
    >>> [(s["truth_id"], s["status"], s["parts"][0][2]) for s in
    ...  surface_breakdown(t, m, hoover(t, m, min_region=1))]
    [(1, 'under', 100), (2, 'under', 100)]
    """
    if parts < 1:
        raise ValueError(f"parts must be at least 1; got {parts}")
    t, m = _check_images(truth_ids, labels)
    kinds = kinds or {}
    status = {int(k): "missed" for k in score.missed}
    status.update({int(k): "over" for k in score.over})
    status.update({int(k): "under" for ids in score.under.values() for k in ids})
    if not status:
        return []
    region_size = np.bincount(m.ravel())
    out = []
    for truth_id in sorted(status):
        on = m[t == truth_id]
        found, counts = np.unique(on, return_counts=True)
        order = np.argsort(-counts, kind="stable")[:parts]
        shares = [(int(found[i]), "" if found[i] == 0 else str(kinds.get(int(found[i]), "?")), int(counts[i]),
                   0.0 if found[i] == 0 else float(counts[i] / region_size[found[i]])) for i in order]
        out.append({"truth_id": truth_id, "pixels": int(on.size), "status": status[truth_id], "parts": shares})
    return out


def connected_patches(truth_ids) -> tuple[np.ndarray, np.ndarray]:
    """Ground truth relabelled SegComp's way: every 4-connected patch of a surface its own id.

    A simulated scene gives a surface one id wherever it shows (a table split by an object
    standing on it is one surface); SegComp's hand-labelled ABW truth gives each connected
    patch its own label. Returns ``(patch_ids, origin)``: ``patch_ids`` (H, W) int32 numbered
    1..n in order of (truth id, patch), 0 where ``truth_ids`` is 0, and ``origin`` (n + 1,)
    the truth id of each patch (``origin[0] = 0``).

    Examples
    --------
    >>> t = np.array([[1, 0, 1], [2, 2, 0]])
    >>> patches, origin = connected_patches(t)
    >>> patches.tolist(), origin.tolist()
    ([[1, 0, 2], [3, 3, 0]], [0, 1, 1, 2])
    """
    import cv2

    t = np.asarray(truth_ids)
    if t.ndim != 2 or not np.issubdtype(t.dtype, np.integer) or (t.size and t.min() < 0):
        raise ValueError(f"truth_ids must be a (H, W) image of ids >= 0; got shape {t.shape}, dtype {t.dtype}")
    patches = np.zeros(t.shape, np.int32)
    origin = [0]
    for truth_id in np.unique(t[t > 0]).tolist():
        n, parts = cv2.connectedComponents((t == truth_id).astype(np.uint8), connectivity=4, ltype=cv2.CV_32S)
        on = parts > 0
        patches[on] = parts[on] + len(origin) - 1
        origin.extend([truth_id] * (n - 1))
    return patches, np.array(origin, dtype=np.int64)


# -- parameter errors -------------------------------------------------------------------
@dataclass(frozen=True)
class RegionError:
    """Parameter errors of one correctly detected region.

    Angles in degrees, lengths in metres; a field that does not apply to the kinds
    involved is None. ``false_fitting`` is true when the fitted kind differs from the truth's.
    """

    truth_id: int
    label: int
    truth_kind: str
    kind: str | None
    false_fitting: bool
    normal_error_deg: float | None = None
    offset_error: float | None = None
    radius_error: float | None = None
    axis_error_deg: float | None = None
    center_error: float | None = None

    def to_dict(self) -> dict:
        return dict(self.__dict__)


def _angle_deg(a, b) -> float:
    """Angle between two lines (sign-free), degrees."""
    cos = abs(float(np.dot(a, b)) / (np.linalg.norm(a) * np.linalg.norm(b)))
    return float(np.degrees(np.arccos(min(1.0, cos))))


def parameter_errors(truth_model, fitted_model) -> dict:
    """Errors of ``fitted_model`` against ``truth_model`` of the same kind.

    plane: ``normal_error_deg`` (sign-free), ``offset_error`` (|d| difference after aligning
    the normals); sphere: ``radius_error``, ``center_error``; cylinder: ``radius_error``,
    ``axis_error_deg``, ``center_error`` = distance from the true axis point to the fitted
    axis line. Returns ``{}`` when the kinds differ.
    """
    if truth_model.kind != fitted_model.kind:
        return {}
    if truth_model.kind == "plane":
        sign = 1.0 if float(truth_model.normal @ fitted_model.normal) >= 0 else -1.0
        return {
            "normal_error_deg": _angle_deg(truth_model.normal, fitted_model.normal),
            "offset_error": abs(sign * float(fitted_model.d) - float(truth_model.d)),
        }
    if truth_model.kind == "sphere":
        return {
            "radius_error": abs(float(fitted_model.radius) - float(truth_model.radius)),
            "center_error": float(np.linalg.norm(fitted_model.center - truth_model.center)),
        }
    rel = truth_model.point - fitted_model.point
    off_axis = rel - (rel @ fitted_model.axis) * fitted_model.axis
    return {
        "radius_error": abs(float(fitted_model.radius) - float(truth_model.radius)),
        "axis_error_deg": _angle_deg(truth_model.axis, fitted_model.axis),
        "center_error": float(np.linalg.norm(off_axis)),
    }


@dataclass(frozen=True)
class Evaluation:
    """Hoover score, per-region parameter errors and the paper's Table 1 columns."""

    hoover: HooverScore
    regions: list
    n_features: int
    unfitted_correct: list

    @property
    def false_fittings(self) -> int:
        return sum(r.false_fitting for r in self.regions)

    def errors(self, name: str, kind: str | None = None) -> np.ndarray:
        """All values of error ``name`` (e.g. ``"radius_error"``), optionally for one truth kind."""
        vals = [getattr(r, name) for r in self.regions if kind is None or r.truth_kind == kind]
        return np.array([v for v in vals if v is not None], dtype=float)

    def table1(self) -> dict:
        """The paper's Table 1 columns: features, under/over-segmentation (count and % of
        extracted features; NaN when no feature was extracted), false fittings."""
        n = self.n_features
        pct = (lambda k: 100.0 * k / n) if n else (lambda k: float("nan"))
        return {
            "features": n,
            "under": self.hoover.n_under,
            "under_pct": pct(self.hoover.n_under),
            "over": self.hoover.n_over,
            "over_pct": pct(self.hoover.n_over),
            "false_fittings": self.false_fittings,
        }

    def to_dict(self) -> dict:
        return {
            "hoover": self.hoover.to_dict(),
            "table1": self.table1(),
            "regions": [r.to_dict() for r in self.regions],
            "unfitted_correct": list(self.unfitted_correct),
        }


def evaluate(scan, result, *, tolerance: float = 0.8, min_region: int = 60) -> Evaluation:
    """Score a pipeline result against a synthetic scan's ground truth.

    Parameters
    ----------
    scan : SyntheticScan (``truth_ids``, ``truth``).
    result : rangeseg_o3d.result.Result (``labels``, ``features`` with ``.label``/``.model``).
    tolerance, min_region : as in :func:`hoover`.

    Returns
    -------
    Evaluation
        For each correct detection: the fitted feature's parameter errors, or a false
        fitting when its kind differs from the truth's kind; correct regions the pipeline
        left unfitted are listed in ``unfitted_correct`` (truth ids).
    """
    for name in ("truth_ids", "truth"):
        if not hasattr(scan, name):
            raise TypeError(f"scan must be a SyntheticScan (with .{name}); got {type(scan).__name__}")
    for name in ("labels", "features"):
        if not hasattr(result, name):
            raise TypeError(f"result must be a Result (with .{name}); got {type(result).__name__}")
    score = hoover(scan.truth_ids, result.labels, tolerance=tolerance, min_region=min_region)
    by_label = {int(f.label): f for f in result.features}
    regions, unfitted = [], []
    for truth_id, label in sorted(score.correct.items()):
        truth_model = scan.truth[truth_id]
        feature = by_label.get(label)
        if feature is None:
            unfitted.append(truth_id)
            continue
        fitted = feature.model
        regions.append(RegionError(
            truth_id=truth_id,
            label=label,
            truth_kind=truth_model.kind,
            kind=fitted.kind,
            false_fitting=fitted.kind != truth_model.kind,
            **parameter_errors(truth_model, fitted),
        ))
    return Evaluation(hoover=score, regions=regions, n_features=len(result.features), unfitted_correct=unfitted)
