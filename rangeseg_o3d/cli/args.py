"""Argument types shared by every ``rangeseg`` command line.

argparse calls a type with the option's text; raising ``argparse.ArgumentTypeError``
turns into ``rangeseg: error: argument --x: <message>`` and exit code 2.
"""

from __future__ import annotations

import argparse
import math

__all__ = ["finite_float", "positive_int", "non_negative_float"]


def finite_float(text: str) -> float:
    """A float that is neither NaN nor infinite (``--faults inf`` is an error, not a value).

    Examples
    --------
    >>> finite_float("0.25")
    0.25
    >>> finite_float("nan")
    Traceback (most recent call last):
    ...
    argparse.ArgumentTypeError: expected a finite number; got 'nan'
    """
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number; got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number; got {text!r}")
    return value


def non_negative_float(text: str) -> float:
    """A finite float >= 0."""
    value = finite_float(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0; got {text!r}")
    return value


def positive_int(text: str) -> int:
    """An integer >= 1 (``--jobs 0`` is an error)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number; got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1; got {text!r}")
    return value
