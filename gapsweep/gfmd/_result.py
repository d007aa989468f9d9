"""Result record of a GFMD run (docs/model.md M3, M5)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gapsweep.gfmd._ops import _is_cupy

FIELDS = ("gap", "pressure", "displacement")


def host_fields(host: Any) -> tuple[str, ...]:
    """The result fields a caller wants on the host: ``True`` all of :data:`FIELDS`, ``False`` none (a cupy
    run keeps them on the GPU), or an iterable of names from :data:`FIELDS` (only those are copied; the others
    stay where they were computed)."""
    if host is True or host is False:
        return FIELDS if host else ()
    if isinstance(host, str) or not hasattr(host, "__iter__"):
        raise ValueError(f"host must be True, False or a list of field names from {FIELDS}, got {host!r}")
    names = tuple(host)
    bad = [k for k in names if k not in FIELDS]
    if bad:
        raise ValueError(f"host: unknown field(s) {bad}; allowed: {', '.join(FIELDS)}")
    return tuple(k for k in FIELDS if k in names)


@dataclass
class GFMDResult:
    """Equilibrium of one GFMD run. Fields are numpy arrays on the host (``n x n``), lengths in units of
    ``length``, pressures in the units of ``sigma0``.

    ``iterations``: force evaluations (= rfft2/irfft2 pairs). ``status``: "converged", "max_iter",
    "non_finite" (a non-finite value appeared; the fields are those of the last finite state) or "stalled"
    (round-off floor: no descent direction left above ``tol``).
    """

    mean_gap: float
    gap: np.ndarray
    pressure: np.ndarray
    displacement: np.ndarray
    iterations: int
    converged: bool
    residual: float
    load_error: float
    wall_time: float
    method: str
    backend: str
    status: str
    sigma0: float = math.nan
    rho: float = math.nan
    gamma0: float = math.nan
    e_star: float = math.nan
    length: float = 1.0
    tol: float = math.nan
    history: list[float] = field(default_factory=list, repr=False)

    @property
    def n(self) -> int:
        return int(self.gap.shape[0])

    def histogram(self, bins: Any = 100, range: tuple[float, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Gap histogram ``(edges, density)`` over the grid (M5); the density integrates to 1 over the bins.
        Binned where the gap lives (GPU for ``host=False`` runs); returned as numpy arrays."""
        if _is_cupy(self.gap):
            import cupy

            if not isinstance(bins, (int, np.integer, str)):
                bins = cupy.asarray(bins)
            density, edges = cupy.histogram(self.gap, bins=bins, range=range, density=True)
            return cupy.asnumpy(edges), cupy.asnumpy(density)
        density, edges = np.histogram(self.gap, bins=bins, range=range, density=True)
        return edges, density
