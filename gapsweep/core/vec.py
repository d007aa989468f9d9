"""Level-1 vector operations of the minimisers on numpy without BLAS threads, and on cupy as array expressions.

Why not BLAS (``numpy.vdot``, scipy's ``zaxpy``): OpenBLAS runs these on all cores and its threads wait by
spinning, so on a loaded machine (other MPI ranks, a busy CI runner) one ``vdot`` of a 256 x 129 half spectrum
took 12 ms where a single-threaded pass takes 0.03 ms (measured on the project's 2-core VM beside a test suite;
docs/gfmd.md "CPU threads"). ``numpy.einsum`` over the arrays' float64 views and chunked in-place updates stay on
the calling thread and make no grid-sized temporary. ``import gapsweep`` sets no thread count for the process."""

from __future__ import annotations

from typing import Any

import numpy as np

__all__ = ["axpy", "rdot"]

_CHUNK = 1 << 16  # elements per chunk of axpy's in-place update: a temporary of 1 MiB at most


def _flat_float(a: np.ndarray) -> np.ndarray | None:
    """The float64 view of a C-contiguous float64 or complex128 array, flat; None otherwise."""
    if not a.flags.c_contiguous:
        return None
    if a.dtype == np.complex128:
        return a.reshape(-1).view(np.float64)
    if a.dtype == np.float64:
        return a.reshape(-1)
    return None


def rdot(a: Any, b: Any) -> float:
    """``Re sum conj(a) b`` over all elements (for real arrays the plain dot product). numpy: one einsum over the
    float64 views (``Re(conj(a) b) = a_re b_re + a_im b_im``), single-threaded, no temporary; other arrays
    (cupy, strided views): ``vdot`` / the array expression."""
    if isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and a.shape == b.shape:
        fa, fb = _flat_float(a), _flat_float(b)
        if fa is not None and fb is not None and fa.size == fb.size:
            return float(np.einsum("i,i->", fa, fb))
        if np.iscomplexobj(a) or np.iscomplexobj(b):
            return float(np.einsum("i,i->", np.real(a).ravel(), np.real(b).ravel())
                         + np.einsum("i,i->", np.imag(a).ravel(), np.imag(b).ravel()))
        return float(np.einsum("i,i->", a.ravel(), b.ravel()))
    xp = _xp(a)
    return float(xp.vdot(a.ravel(), b.ravel()).real)


def axpy(a: float, x: Any, y: Any) -> None:
    """``y += a x`` in place (``a`` real). numpy, both C-contiguous of one dtype: in chunks of ``_CHUNK``
    elements (a small temporary, no BLAS threads); otherwise the array expression."""
    if isinstance(y, np.ndarray) and isinstance(x, np.ndarray) and x.dtype == y.dtype and x.shape == y.shape \
            and x.flags.c_contiguous and y.flags.c_contiguous:
        fx, fy = x.reshape(-1), y.reshape(-1)
        tmp = np.empty(min(_CHUNK, fx.size), dtype=fx.dtype)
        for i in range(0, fx.size, _CHUNK):
            j = min(i + _CHUNK, fx.size)
            t = tmp[:j - i]
            np.multiply(fx[i:j], a, out=t)
            fy[i:j] += t
        return
    y += a * x


def _xp(a: Any) -> Any:
    if isinstance(a, np.ndarray):
        return np
    import cupy

    return cupy
