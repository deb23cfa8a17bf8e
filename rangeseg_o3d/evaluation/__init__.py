"""Evaluation and benchmarking: how good and how fast a segmentation is.

* :mod:`.metrics`: segmentation quality against ground truth: the Hoover et al. (1996)
  classification (:func:`hoover`), the fitted parameters' errors (:func:`parameter_errors`)
  and both together (:func:`evaluate`); where each missed surface's pixels went
  (:func:`surface_breakdown`); truth relabelled SegComp's way, one id per connected patch
  (:func:`connected_patches`).
* :mod:`.compare`: every segmenter on the same scans (``rangeseg compare``,
  ``scripts/compare.py``): Hoover figures, false fittings, times, markdown and plots.

The sensor matrix the benchmark scans (simulated sensors drawing independent scenes) is
:mod:`rangeseg_o3d.synthetic.matrix`; the timing scripts that print medians are
``scripts/benchmark.py`` (suites, real frames, ``--matrix``) and ``scripts/bench_*.py``.
Names load lazily (PEP 562): importing this package loads neither the pipeline nor numba.
"""

from __future__ import annotations

from .._lazy import lazy_attributes

# public name -> the module that defines it; the modules themselves resolve too (evaluation.compare)
_EXPORTS = {name: "metrics" for name in ("HooverScore", "Evaluation", "RegionError",
                                          "hoover", "evaluate", "parameter_errors",
                                          "surface_breakdown", "connected_patches")}

__all__ = list(_EXPORTS)

__getattr__, __dir__ = lazy_attributes(__name__, _EXPORTS)
