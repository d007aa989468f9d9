"""Shared argument validators of the physics modules (theory, surface, sde, fokker_planck, calibrate, resolution).

Policy (preamble "bad input"): every checker names the argument and the allowed range in its message; a value of
the wrong type (``bool``, ``str``, ``complex``, ``None``, ...) raises ``TypeError``, a number outside the allowed
range (NaN and inf included) raises ``ValueError``. Scalars come back as Python ``float``/``int``, arrays as
float64 ``ndarray``. The job-spec reader :mod:`gapsweep.spec` has its own readers (``SpecError`` with dotted keys).
"""

from __future__ import annotations

import math
import numbers

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["count", "finite_array", "hurst", "nonnegative", "positive", "positive_array", "real", "square_heights"]


def real(x: float, name: str) -> float:
    """``x`` as a Python float; ``TypeError`` unless it is a real number (a 0-d real array counts as one).

    Finiteness is left to the range checks below, so that their message states the whole allowed range.
    """
    if isinstance(x, np.ndarray) and x.ndim == 0:
        x = x[()]
    # bool is an int subclass but never a meaningful physical value; numpy scalars register as numbers.Real
    if isinstance(x, (bool, np.bool_)) or not isinstance(x, numbers.Real):
        raise TypeError(f"{name} must be a real number, got {x!r} ({type(x).__name__})")
    return float(x)


def positive(x: float, name: str) -> float:
    """Finite ``x > 0`` as a float."""
    v = real(x, name)
    if not (math.isfinite(v) and v > 0.0):
        raise ValueError(f"{name} must be finite and > 0, got {x!r}")
    return v


def nonnegative(x: float, name: str) -> float:
    """Finite ``x >= 0`` as a float."""
    v = real(x, name)
    if not (math.isfinite(v) and v >= 0.0):
        raise ValueError(f"{name} must be finite and >= 0, got {x!r}")
    return v


def hurst(h: float, name: str = "hurst") -> float:
    """Hurst exponent ``H`` in the open interval ``(0, 1)`` (docs/model.md M2) as a float."""
    v = real(h, name)
    if not 0.0 < v < 1.0:  # also false for NaN
        raise ValueError(f"{name} must lie in (0, 1), got {h!r}")
    return v


def count(n: int, name: str, minimum: int = 1) -> int:
    """Integer ``n >= minimum`` as an int; an integral float (``3.0``) is accepted, ``2.5`` or ``True`` is not."""
    if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)):
        if isinstance(n, float) and n.is_integer():
            n = int(n)
        else:
            raise TypeError(f"{name} must be an integer, got {n!r}")
    if n < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {n}")
    return int(n)


def finite_array(x: ArrayLike, name: str) -> np.ndarray:
    """``x`` (scalar or array of real numbers) as a finite float64 array of the same shape."""
    what = f"{name} must be a real number or an array of real numbers"
    try:
        a = np.asarray(x)
    except ValueError as exc:  # ragged nesting
        raise TypeError(what) from exc
    if np.iscomplexobj(a):
        raise TypeError(f"{name} must be real, got complex values")
    # strings and booleans are not numbers here, even where numpy would convert them
    if a.dtype.kind not in "iufO":
        raise TypeError(f"{what}, got dtype {a.dtype}")
    try:
        a = a.astype(float, copy=False)
    except (TypeError, ValueError) as exc:  # an object element that float() rejects
        raise TypeError(what) from exc
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite (no NaN or inf)")
    return a


def positive_array(x: ArrayLike, name: str) -> np.ndarray:
    """``x`` as a float64 array of finite values > 0."""
    a = finite_array(x, name)
    if np.any(a <= 0):
        raise ValueError(f"{name} must be finite and > 0")
    return a


def square_heights(heights: ArrayLike, name: str = "heights") -> np.ndarray:
    """Surface heights as a finite, real, square ``(n, n)`` float64 array with ``n >= 2`` (docs/model.md M2 grid)."""
    h = finite_array(heights, name)
    if h.ndim != 2 or h.shape[0] != h.shape[1] or h.shape[0] < 2:
        raise ValueError(f"{name} must be a square 2-D array with n >= 2, got shape {h.shape}")
    return h
