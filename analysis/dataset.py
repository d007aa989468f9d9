"""An ``xarray.Dataset`` view of a store for users' own scripts (dims hurst, rho, sigma0, seed).

Variables (one per method and quantity, NaN where a task is absent or not ``done``):
``gfmd_mean_gap``, ``theory_paper``, ``theory_continuum``, ``theory_discrete``, ``sde_mean_gap``,
``fokker_planck_mean_gap`` (mean gap, length units, docs/model.md M3/M4), ``gfmd_h_rms``, ``gfmd_g_rms``,
``gfmd_residual``, ``gfmd_iterations`` and ``<method>_status`` (string: done / failed / not_converged / pending /
"" for no task). Seed-independent results (paper and continuum theory; SDE without a seeded surface) sit at
every seed their task has, i.e. usually seed 0 only. When a store holds several GFMD grids ``n`` or several
SDE / Fokker-Planck ``C2`` values, choose one with ``n=`` / ``c2=`` (default: the finest grid, the smallest C2).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd
import xarray as xr

__all__ = ["to_dataset"]

_VARS = {
    "gfmd": {"mean_gap": "gfmd_mean_gap", "h_rms": "gfmd_h_rms", "g_rms": "gfmd_g_rms",
             "residual": "gfmd_residual", "iterations": "gfmd_iterations"},
    "theory": {"mean_gap_paper": "theory_paper", "mean_gap_continuum": "theory_continuum",
               "mean_gap_discrete": "theory_discrete", "h_rms": "theory_h_rms"},
    "sde": {"mean_gap": "sde_mean_gap"},
    "fokker_planck": {"mean_gap": "fokker_planck_mean_gap"},
}


def to_dataset(df: pd.DataFrame, *, n: int | None = None, c2: float | None = None) -> xr.Dataset:
    """Dataset with dims (hurst, rho, sigma0, seed) from :func:`gapsweep.store.read` (module docstring).

    Only ``done`` rows fill the numeric variables; the status variables show every task. ``n`` selects the GFMD
    (and discrete theory) grid, ``c2`` the SDE / Fokker-Planck fudge factor; the choices are in ``attrs``.
    """
    need = ("method", "status", "hurst", "rho", "sigma0", "seed")
    missing = [c for c in need if c not in df.columns]
    if missing:
        raise ValueError(f"df lacks the contract column(s) {missing}; see gapsweep.store.read")
    coords = {k: np.sort(df[k].unique()) for k in ("hurst", "rho", "sigma0", "seed")}
    shape = tuple(len(v) for v in coords.values())
    index = {k: {v: i for i, v in enumerate(c)} for k, c in coords.items()}
    attrs: dict[str, Any] = {}
    data: dict[str, Any] = {}
    for method, cols in _VARS.items():
        sub = df[df["method"] == method]
        if sub.empty:
            continue
        if method in ("gfmd", "theory") and "n" in sub and sub["n"].nunique() > 1:
            pick = n if n is not None else int(sub["n"].max())
            if pick not in set(sub["n"].astype(int)):
                raise ValueError(f"n: {method} has grids {sorted(set(sub['n'].astype(int)))}, got n={n}")
            sub = sub[sub["n"] == pick]
            attrs[f"{method}_n"] = pick
        if method in ("sde", "fokker_planck") and "c2" in sub and sub["c2"].nunique() > 1:
            pick_c2 = c2 if c2 is not None else float(sub["c2"].min())
            if not np.isclose(sub["c2"], pick_c2).any():
                raise ValueError(f"c2: {method} has C2 values {sorted(sub['c2'].unique())}, got c2={c2}")
            sub = sub[np.isclose(sub["c2"], pick_c2)]
            attrs[f"{method}_c2"] = pick_c2
        idx = tuple(np.array([index[k][v] for v in sub[k]], dtype=int) for k in ("hurst", "rho", "sigma0", "seed"))
        done = (sub["status"] == "done").to_numpy()
        for col, name in cols.items():
            if col not in sub or not np.isfinite(pd.to_numeric(sub[col], errors="coerce")).any():
                continue
            a = np.full(shape, np.nan)
            vals = pd.to_numeric(sub[col], errors="coerce").to_numpy(float)
            a[tuple(i[done] for i in idx)] = vals[done]
            data[name] = (("hurst", "rho", "sigma0", "seed"), a)
        st = np.full(shape, "", dtype=object)
        st[idx] = sub["status"].astype(str).to_numpy()
        data[f"{method}_status"] = (("hurst", "rho", "sigma0", "seed"), st.astype(str))
    ds = xr.Dataset(data, coords=coords, attrs=attrs)
    for name in ds.data_vars:
        if name.endswith(("mean_gap", "paper", "continuum", "discrete", "h_rms")):
            ds[name].attrs["units"] = "length (box side L = 1)"
    return ds
