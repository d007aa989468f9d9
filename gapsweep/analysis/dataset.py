"""An ``xarray.Dataset`` view of a store for users' own scripts: a thin wrapper of
:func:`gapsweep.store.to_dataset` (dims hurst, rho, sigma0, seed; CF ``units`` and ``long_name``; provenance).

Variables (NaN where a task is absent or not ``done``): ``gfmd_mean_gap``, ``theory_paper``, ``theory_continuum``,
``theory_discrete``, ``sde_mean_gap``, ``fokker_planck_mean_gap`` (mean gap, docs/model.md M3/M4), ``gfmd_h_rms``,
``gfmd_g_rms``, ``gfmd_residual``, ``gfmd_iterations`` and ``<method>_status`` (CF flags: 0 pending, 1 done,
2 failed, 3 not_converged, fill -1 for no task). Seed-independent results (the paper's and the continuum theory,
Fokker-Planck densities) have no ``seed`` dimension and broadcast over every seed. When a store holds several
GFMD grids ``n`` or several SDE / Fokker-Planck ``C2`` values, choose one with ``n=`` / ``c2=`` (default: the
finest grid, the smallest C2).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = ["to_dataset"]


def to_dataset(store: Any, *, n: int | None = None, c2: float | None = None):
    """Dataset of a store given by path (:func:`gapsweep.store.to_dataset`) or by its frame
    (:func:`gapsweep.store.read`, e.g. several stores concatenated)."""
    from gapsweep import dataset

    if isinstance(store, (str, Path)):
        return dataset.to_dataset(store, n=n, c2=c2)
    return dataset.from_frame(store, n=n, c2=c2)
