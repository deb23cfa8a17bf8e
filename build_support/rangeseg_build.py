"""PEP 517 build backend: setuptools', plus what compiling the kernels into a wheel needs.

A wheel's build runs ``rangeseg_o3d.pipeline.warm_up()`` (see setup.py), which imports
numba, numpy, scipy (numba's LAPACK), OpenCV, pydantic and PyYAML: they are asked for
when building a wheel only, so an sdist or an editable install does not download them.
``RANGESEG_NO_PRECOMPILE=1`` builds a wheel without compiled kernels and without them.
"""

from __future__ import annotations

import os

from setuptools import build_meta as _setuptools
from setuptools.build_meta import *  # noqa: F403  (the hooks this backend does not change)

KERNEL_BUILD_REQUIRES = ["numpy>=1.24", "scipy>=1.10", "numba>=0.60", "opencv-python-headless>=4.8",
                         "pydantic>=2.5", "PyYAML>=6"]


def get_requires_for_build_wheel(config_settings=None):
    """setuptools' requirements, plus those of the kernel compilation (see the module docstring)."""
    extra = [] if os.environ.get("RANGESEG_NO_PRECOMPILE") else KERNEL_BUILD_REQUIRES
    return _setuptools.get_requires_for_build_wheel(config_settings) + extra
