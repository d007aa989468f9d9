"""Aggregation over seeds: mean-gap curves with standard errors, and gap histograms merged onto common bins.

Inputs are what ``gapsweep.store.read`` and ``gapsweep.store.read_histograms`` return (the contract columns), never
the HDF5 file, so every function here is testable on a synthetic DataFrame.

Rules (docs/analysis.md):
* Only rows with ``status == "done"`` and a finite value enter a mean. Rows that are ``failed``,
  ``not_converged`` or ``pending`` (and ``done`` rows without a finite value, counted as ``invalid``) are counted
  per group and reported, never averaged in.
* The standard error of the mean is ``s / sqrt(k)`` with the sample standard deviation ``s`` (ddof = 1) over
  the ``k`` seeds; it is NaN (shown as "n/a") when ``k < 2``: one seed carries no scatter information.
* Reduced units follow docs/model.md M1: ``g0 / h_rms`` against ``sigma0 / (E* g_rms)``. The reduced value is formed
  per row (each seed with its own ``h_rms``) before averaging.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

__all__ = [
    "KEYS",
    "SOURCES",
    "STATUSES",
    "HistogramStats",
    "aggregate_histograms",
    "aggregate_mean_gap",
    "long_values",
    "merge_histograms",
    "rebin_density",
    "status_counts",
]

STATUSES = ("done", "failed", "not_converged", "pending")
# Grid point of one curve (c2 separates SDE / Fokker-Planck runs with different fudge factors, n GFMD grids).
# ``job`` (the store's job name, "" when unknown) keeps different surfaces apart, e.g. figure 6's C0-normalised
# surface and figure 2's g_rms = 1 surface at the same (H, rho, sigma0).
KEYS = ("job", "source", "hurst", "rho", "sigma0", "n", "c2")
# One "source" per method and quantity: theory rows carry three forms of the mean gap (docs/model.md M4).
SOURCES = {
    "gfmd": ("gfmd", "mean_gap"),
    "theory:paper": ("theory", "mean_gap_paper"),
    "theory:continuum": ("theory", "mean_gap_continuum"),
    "theory:discrete": ("theory", "mean_gap_discrete"),
    "sde": ("sde", "mean_gap"),
    "fokker_planck": ("fokker_planck", "mean_gap"),
}
_PARAMS = ("h_rms", "g_rms", "e_star", "gamma0", "lambda_l", "lambda_s", "length", "c1")


def _check_frame(df: pd.DataFrame, needed: Iterable[str]) -> None:
    if not isinstance(df, pd.DataFrame):
        raise TypeError(f"df must be a pandas DataFrame (gapsweep.store.read), got {type(df).__name__}")
    missing = [c for c in needed if c not in df.columns]
    if missing:
        raise ValueError(f"df lacks the contract column(s) {missing}; see gapsweep.store.read")


def status_counts(df: pd.DataFrame) -> pd.DataFrame:
    """Rows per method and status (columns: method, done, failed, not_converged, pending, total).

    Unknown status strings get their own column, so nothing is hidden.
    """
    _check_frame(df, ("method", "status"))
    t = pd.crosstab(df["method"].astype(str), df["status"].astype(str))
    for s in STATUSES:
        if s not in t.columns:
            t[s] = 0
    extra = [c for c in t.columns if c not in STATUSES]
    t = t[list(STATUSES) + sorted(extra)]
    t["total"] = t.sum(axis=1)
    return t.reset_index().rename_axis(columns=None)


def long_values(df: pd.DataFrame, sources: Sequence[str] | None = None) -> pd.DataFrame:
    """One row per (task, source): columns task_id, source, status, hurst, rho, sigma0, seed, n, c2, value,
    plus the parameters (h_rms, g_rms, e_star, gamma0, lambda_l, lambda_s, c1) and ``value_reduced``
    (value / h_rms) and ``sigma0_reduced`` (sigma0 / (e_star g_rms)), docs/model.md M1 (``length``: box side L).

    A theory row is repeated for each of its three forms; a form never computed (all NaN for that method) is
    dropped, while single NaNs are kept (and counted as ``invalid`` when the status is ``done``).
    """
    _check_frame(df, ("task_id", "method", "status", "hurst", "rho", "sigma0", "seed", "mean_gap"))
    wanted = list(SOURCES) if sources is None else list(sources)
    for s in wanted:
        if s not in SOURCES:
            raise ValueError(f"sources: unknown source {s!r}; allowed: {', '.join(SOURCES)}")
    parts = []
    for src in wanted:
        method, col = SOURCES[src]
        sub = df[df["method"].astype(str) == method]
        if sub.empty or col not in sub.columns:
            continue
        if method == "theory" and not np.isfinite(pd.to_numeric(sub[col], errors="coerce")).any():
            continue  # this theory form was not requested in the job
        part = pd.DataFrame({
            "task_id": sub["task_id"].to_numpy(),
            "job": sub["job"].astype(str).to_numpy() if "job" in sub else "",
            "source": src,
            "status": sub["status"].astype(str).to_numpy(),
            "hurst": sub["hurst"].to_numpy(float),
            "rho": sub["rho"].to_numpy(float),
            "sigma0": sub["sigma0"].to_numpy(float),
            "seed": sub["seed"].to_numpy(),
            "n": (sub["n"].to_numpy(float) if "n" in sub else np.zeros(len(sub))),
            "c2": (sub["c2"].to_numpy(float) if "c2" in sub else np.full(len(sub), np.nan)),
            "value": pd.to_numeric(sub[col], errors="coerce").to_numpy(float),
        })
        for p in _PARAMS:
            part[p] = sub[p].to_numpy(float) if p in sub else np.nan
        if "message" in sub:
            part["message"] = sub["message"].astype(str).to_numpy()
        parts.append(part)
    if not parts:
        cols = ["task_id", "job", "source", "status", "hurst", "rho", "sigma0", "seed", "n", "c2", "value", *_PARAMS,
                "value_reduced", "sigma0_reduced"]
        return pd.DataFrame({c: pd.Series(dtype=float) for c in cols})
    out = pd.concat(parts, ignore_index=True)
    # The mean gap is only defined for c2 by the SDE / FP; elsewhere c2 is irrelevant: NaN keeps groups together.
    out.loc[~out["source"].isin(["sde", "fokker_planck"]), "c2"] = np.nan
    # The grid size matters for GFMD and the discrete theory only (one surface per grid).
    out.loc[~out["source"].isin(["gfmd", "theory:discrete"]), "n"] = 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        out["value_reduced"] = out["value"] / out["h_rms"]
        out["sigma0_reduced"] = out["sigma0"] / (out["e_star"] * out["g_rms"])
    return out


def aggregate_mean_gap(df: pd.DataFrame, sources: Sequence[str] | None = None) -> pd.DataFrame:
    """Mean over seeds per (job, source, hurst, rho, sigma0, n, c2) of the mean gap (docs/model.md M3/M4).

    Columns: the keys, ``count`` (seeds averaged), ``mean``, ``std``, ``sem`` (absolute units), ``mean_reduced``,
    ``sem_reduced`` (g0 / h_rms), ``sigma0_reduced`` (sigma0/(E* g_rms), mean over the averaged rows), the mean
    parameters (h_rms, g_rms, e_star, gamma0, lambda_l, lambda_s, c1), and the counts ``n_done``, ``n_failed``,
    ``n_not_converged``, ``n_pending``, ``n_invalid`` (done but not finite) and ``n_total``.
    A group whose rows all failed has ``count == 0`` and NaN means: it is listed, not dropped.
    """
    lv = long_values(df, sources)
    keys = list(KEYS)
    if lv.empty:
        return pd.DataFrame(columns=[*keys, "count", "mean", "std", "sem", "mean_reduced", "sem_reduced"])
    ok = (lv["status"] == "done") & np.isfinite(lv["value"]) & np.isfinite(lv["value_reduced"])
    lv = lv.assign(_ok=ok, _invalid=(lv["status"] == "done") & ~ok)
    rows: list[dict[str, Any]] = []
    for key, g in lv.groupby(keys, dropna=False, sort=True):
        good = g[g["_ok"]]
        k = len(good)
        row: dict[str, Any] = dict(zip(keys, key))
        row["count"] = k
        for col, out in (("value", ""), ("value_reduced", "_reduced")):
            v = good[col].to_numpy(float)
            row[f"mean{out}"] = float(v.mean()) if k else math.nan
            std = float(v.std(ddof=1)) if k >= 2 else math.nan
            row[f"std{out}"] = std
            row[f"sem{out}"] = std / math.sqrt(k) if k >= 2 else math.nan
        src = good if k else g
        row["sigma0_reduced"] = float(src["sigma0_reduced"].mean())
        for p in _PARAMS:
            row[p] = float(src[p].mean()) if src[p].notna().any() else math.nan
        st = g["status"].value_counts()
        for s in STATUSES:
            row[f"n_{s}"] = int(st.get(s, 0))
        row["n_invalid"] = int(g["_invalid"].sum())
        row["n_total"] = len(g)
        rows.append(row)
    return pd.DataFrame(rows)


# ---------------------------------------------------------------------------------------------------------
# histograms


class HistogramStats(dict):
    """Merged histogram: keys ``edges``, ``density`` (integrates to 1 over the bins), ``sem`` (per-bin standard
    error of the density), ``sem_kind`` ("seeds" or "poisson"), ``count`` (samples in all merged histograms),
    ``n_hist`` (histograms merged). A dict so that it serialises and prints plainly."""

    @property
    def centres(self) -> np.ndarray:
        e = self["edges"]
        return 0.5 * (e[1:] + e[:-1])


def _check_hist(name: str, edges: Any, density: Any) -> tuple[np.ndarray, np.ndarray]:
    e = np.asarray(edges, dtype=float)
    d = np.asarray(density, dtype=float)
    if e.ndim != 1 or e.size < 2 or not np.all(np.isfinite(e)) or not np.all(np.diff(e) > 0):
        raise ValueError(f"{name}: edges must be a finite, strictly increasing 1-d array of >= 2 values")
    if d.shape != (e.size - 1,):
        raise ValueError(f"{name}: density must have len(edges) - 1 = {e.size - 1} values, got shape {d.shape}")
    if not np.all(np.isfinite(d)) or np.any(d < 0):
        raise ValueError(f"{name}: density must be finite and >= 0")
    return e, d


def rebin_density(edges: np.ndarray, density: np.ndarray, new_edges: np.ndarray) -> np.ndarray:
    """Density on ``new_edges`` from a piecewise-constant density on ``edges``, conserving the mass in every
    overlap exactly (the source density is taken uniform inside each of its bins). Mass outside ``new_edges``
    is lost, so choose ``new_edges`` covering ``edges`` to conserve the total."""
    e, d = _check_hist("rebin_density", edges, density)
    ne = np.asarray(new_edges, dtype=float)
    if ne.ndim != 1 or ne.size < 2 or not np.all(np.diff(ne) > 0):
        raise ValueError("new_edges must be a strictly increasing 1-d array of >= 2 values")
    # Cumulative mass at the source edges, linearly interpolated (exact for piecewise-constant densities).
    cum = np.concatenate([[0.0], np.cumsum(d * np.diff(e))])
    cn = np.interp(ne, e, cum, left=0.0, right=cum[-1])
    return np.diff(cn) / np.diff(ne)


def _common_edges(edge_list: Sequence[np.ndarray], bins: int | None) -> np.ndarray:
    first = edge_list[0]
    if all(e.shape == first.shape and np.allclose(e, first, rtol=0, atol=1e-12 * np.ptp(first)) for e in edge_list):
        return first if bins is None else np.linspace(first[0], first[-1], bins + 1)
    lo = min(float(e[0]) for e in edge_list)
    hi = max(float(e[-1]) for e in edge_list)
    nb = bins if bins is not None else max(e.size - 1 for e in edge_list)
    return np.linspace(lo, hi, nb + 1)


def merge_histograms(hists: Sequence[tuple[Any, Any, Any]], *, edges: Any = None, bins: int | None = None
                     ) -> HistogramStats:
    """Merge normalised histograms ``(edges, density, count)`` of several seeds onto common bins (M5).

    Common bins: the shared edges when all agree (and neither ``edges`` nor ``bins`` is given), else ``edges``,
    else ``bins`` equal bins over the union of the ranges (default: the largest bin count). Each histogram is
    rebinned with :func:`rebin_density` (mass conserving), then pooled weighted by its sample count:
    ``P = sum_i c_i P_i / sum_i c_i`` -- the density of the union of all samples. Histograms with ``count <= 0``
    (e.g. a Fokker-Planck density) get equal weights. Per-bin uncertainty: with >= 2 histograms the standard error
    of the weighted mean from the seed-to-seed scatter (``sem_kind = "seeds"``; this is what counts for GFMD,
    whose pixels are correlated); with one, Poisson ``sqrt(P / (c dx))`` (``sem_kind = "poisson"``, NaN if c = 0).
    """
    if len(hists) == 0:
        raise ValueError("hists: need at least one (edges, density, count) histogram to merge")
    es, ds, cs = [], [], []
    for i, h in enumerate(hists):
        if len(h) != 3:
            raise ValueError(f"hists[{i}]: expected (edges, density, count)")
        e, d = _check_hist(f"hists[{i}]", h[0], h[1])
        es.append(e)
        ds.append(d)
        cs.append(float(h[2]) if h[2] is not None and np.isfinite(float(h[2])) else 0.0)
    ce = np.asarray(edges, dtype=float) if edges is not None else _common_edges(es, bins)
    if ce.ndim != 1 or ce.size < 2 or not np.all(np.diff(ce) > 0):
        raise ValueError("edges must be a strictly increasing 1-d array of >= 2 values")
    rb = np.array([d if (e.shape == ce.shape and np.array_equal(e, ce)) else rebin_density(e, d, ce)
                   for e, d in zip(es, ds)])
    c = np.asarray(cs)
    w = c / c.sum() if np.all(c > 0) else np.full(len(c), 1.0 / len(c))
    dens = w @ rb
    k = len(rb)
    if k >= 2:
        # Standard error of a weighted mean from the scatter: var = sum w_i^2 (x_i - xbar)^2 * k/(k-1).
        sem = np.sqrt(k / (k - 1) * (w[:, None] ** 2 * (rb - dens) ** 2).sum(axis=0))
        kind = "seeds"
    else:
        tot = c.sum()
        sem = np.sqrt(dens / (tot * np.diff(ce))) if tot > 0 else np.full(dens.shape, np.nan)
        kind = "poisson"
    return HistogramStats(edges=ce, density=dens, sem=sem, sem_kind=kind, count=int(c.sum()), n_hist=k)


def aggregate_histograms(df: pd.DataFrame, hists: Mapping[Any, tuple[Any, Any, Any]], *,
                         methods: Sequence[str] = ("gfmd", "sde", "fokker_planck"), bins: int | None = None
                         ) -> dict[tuple, HistogramStats]:
    """Merge the histograms of the ``done`` tasks over seeds for each (method, hurst, rho, sigma0, n, c2).

    Returns ``{(method, hurst, rho, sigma0, n, c2, job): HistogramStats}`` with, besides the merged density, the
    group's parameters (``h_rms``, ``g_rms``, ``e_star``, ``gamma0``, ``lambda_l``, ``lambda_s``, ``mean_gap``
    mean over seeds) and the counts ``n_missing`` (done tasks without a stored histogram) and ``n_not_done``.
    ``n`` is 0 and ``c2`` NaN where they do not apply, as in :func:`aggregate_mean_gap`.
    """
    _check_frame(df, ("task_id", "method", "status", "hurst", "rho", "sigma0"))
    sub = df[df["method"].astype(str).isin(methods)].copy()
    sub["n"] = sub["n"].astype(float) if "n" in sub else 0.0
    sub.loc[sub["method"] != "gfmd", "n"] = 0.0
    sub["c2"] = sub["c2"].astype(float) if "c2" in sub else np.nan
    sub.loc[~sub["method"].isin(["sde", "fokker_planck"]), "c2"] = np.nan
    sub["job"] = sub["job"].astype(str) if "job" in sub else ""
    out: dict[tuple, HistogramStats] = {}
    keys = ["method", "hurst", "rho", "sigma0", "n", "c2", "job"]
    for key, g in sub.groupby(keys, dropna=False, sort=True):
        done = g[g["status"] == "done"]
        have = [hists[t] for t in done["task_id"] if t in hists]
        if not have:
            continue
        st = merge_histograms(have, bins=bins)
        st["n_missing"] = int(len(done) - len(have))
        st["n_not_done"] = int(len(g) - len(done))
        for p in (*_PARAMS, "mean_gap"):
            st[p] = float(done[p].mean()) if p in done and done[p].notna().any() else math.nan
        out[tuple(key)] = st
    return out
