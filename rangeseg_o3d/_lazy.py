"""Public names that load on first use (PEP 562), for the package ``__init__`` modules."""

from __future__ import annotations

import importlib
import importlib.util
import sys


def lazy_attributes(package: str, exports: dict[str, str]):
    """Return ``(__getattr__, __dir__)`` for ``package``, whose names load on first use.

    ``exports`` maps a public name to the submodule (relative to ``package``) that defines
    it; any other non-private name that is a submodule (``rs.registry``, ``rs.io``) is
    imported as one. A resolved name is stored in the package so later look-ups skip this.
    """
    namespace = sys.modules[package].__dict__

    def __getattr__(name: str):
        module = exports.get(name)
        if module is not None:
            value = getattr(importlib.import_module(f"{package}.{module}"), name)
        elif not name.startswith("_") and importlib.util.find_spec(f"{package}.{name}") is not None:
            value = importlib.import_module(f"{package}.{name}")
        else:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        namespace[name] = value
        return value

    def __dir__():
        return sorted(set(namespace) | set(exports))

    return __getattr__, __dir__
