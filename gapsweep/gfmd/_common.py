"""Helpers shared by gfmd's minimisers and its driver (docs/model.md M3): the under-resolution warning, the
choice of array kernels, mode transfer between grids. Imports no minimiser, so none of them imports back."""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from gapsweep.gfmd import _ops
from gapsweep.gfmd._cuda import _CupyOps
from gapsweep.gfmd._ops import _NumbaOps, _Ops

STATUSES = ("converged", "max_iter", "non_finite", "stalled", "detached")


class UnderResolvedWarning(UserWarning):
    """The interaction range ``rho`` is shorter than the grid spacing (M7)."""


def under_resolved(law: Any, shape: tuple[int, ...], length: Any) -> str | None:
    """The text of the :class:`UnderResolvedWarning` for ``law`` on a grid of ``shape`` over the box ``length``
    (a number or ``(Lx, Ly)``), or None when the law's range resolves the grid (docs/model.md M7): every law with
    a range (``law.range()``; exponential and adhesive), every grid shape and boundary. The spacing is the larger
    of ``Lx/nx`` and ``Ly/ny`` (the coarser axis decides)."""
    rng = law.range()
    if rng is None:
        return None
    lx, ly = (length, length) if np.ndim(length) == 0 else (length[0], length[1])
    dx = max(float(lx) / shape[0], float(ly) / shape[1])
    if rng >= dx:
        return None
    return (f"rho/dx = {rng / dx:.3g} < 1 (rho={rng:g}, dx={dx:g}): the interaction range is under-resolved; "
            "the solver still converges but the mean gap carries a discretisation error (refine n)")


# ------------------------------------------------------------------------------------------------ helpers
def _make_ops(xp: Any, n: int) -> _Ops:
    """Kernels for the namespace: numba on the CPU when installed, fused cupy kernels on the GPU (unless
    ``GAPSWEEP_GENERIC_KERNELS=1``), else the generic array code."""
    if os.environ.get("GAPSWEEP_GENERIC_KERNELS") == "1":
        return _Ops(xp, n)
    if xp is np:
        return _NumbaOps(xp, n) if _ops._have_numba() else _Ops(xp, n)
    if xp.__name__ == "cupy":
        return _CupyOps(xp, n)
    return _Ops(xp, n)


def _transfer_modes(u: np.ndarray, n: int) -> np.ndarray:
    """Normalised half spectrum on an ``n`` grid of the displacement ``u`` given on another grid: modes that
    both grids carry are copied, the rest set to zero (surfaces are resolution independent, M2)."""
    m = u.shape[0]
    full = np.fft.fft2(u) / (m * m)
    kmax = (min(m, n) - 1) // 2  # strictly below both Nyquist frequencies
    ks = np.r_[0 : kmax + 1, -kmax:0]
    out = np.zeros((n, n), dtype=np.complex128)
    out[np.ix_(ks % n, ks % n)] = full[np.ix_(ks % m, ks % m)]
    return out[:, : n // 2 + 1]
