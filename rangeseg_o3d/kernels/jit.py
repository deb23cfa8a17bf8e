"""``numba.njit``, after putting this package's kernel cache locator first (see :mod:`.cache`).

Every module of the package that compiles kernels imports ``njit`` from here, so the
locator is in place before any ``cache=True`` decorator sets up its cache.
"""

from numba import njit

from .cache import install_kernel_cache

install_kernel_cache()

__all__ = ["njit"]
