"""Comparisons: field theory against GFMD mean gaps (docs/model.md M4), SDE / Fokker-Planck against GFMD gap
histograms (M5), and the parameter regions where the theory agrees with GFMD (M6).

Error measures
--------------
* ``rel_err = (T - G) / |G|`` with ``G`` the GFMD mean over seeds and ``T`` the theory; its standard error by
  first-order propagation, ``sqrt((s_T/|G|)^2 + (T s_G / G^2)^2)``. Positive means the theory overestimates.
* ``red_err = (T - G) / h_rms``: the error on the plotted axis ``g0/h_rms`` (figures 2 to 5).
* Near full contact ``g0`` crosses zero (``rho ln(gamma0/(rho sigma0)) = 0`` at ``sigma0 = gamma0/rho``), where a
  relative error means nothing. Points with ``|G| < ILL_CONDITIONED * h_rms`` are flagged ``ill_conditioned``
  and left out of the agreement regions and verdicts (they are counted and listed, and ``red_err`` still shows
  them).
* Histogram distances on the union of both bin sets, exact for piecewise-constant densities:
  ``L1 = int |P_a - P_b| dg`` (0..2), ``KS = max |F_a - F_b|`` (0..1), ``W1 = int |F_a - F_b| dg`` (a length;
  also reported over ``h_rms``).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from gapsweep import theory
from gapsweep.analysis.aggregate import HistogramStats, rebin_density
from gapsweep.theory.domain import PredictorDomainWarning

__all__ = [
    "ILL_CONDITIONED",
    "THRESHOLDS",
    "agreement_regions",
    "calibrate_c2",
    "histogram_distance",
    "histogram_distances",
    "pressure_trend",
    "theory_vs_gfmd",
]

THRESHOLDS = (0.01, 0.05, 0.10)
ILL_CONDITIONED = 0.25
_FORMS = ("paper", "continuum", "discrete")


def _rk(x: Any) -> float:
    """Matching key for grid values that may come from different stores: 10 significant digits."""
    return float(f"{float(x):.10g}") if x is not None and np.isfinite(float(x)) else math.nan


def _pick_n(g: pd.DataFrame, n: int | None) -> pd.DataFrame:
    """Rows at grid ``n`` (or the finest grid per point when ``n`` is None)."""
    if n is not None:
        return g[g["n"] == n]
    finest = g.groupby(["job", "_h", "_r", "_s"])["n"].transform("max")
    return g[g["n"] == finest]


def theory_vs_gfmd(agg: pd.DataFrame, *, forms: Sequence[str] = _FORMS, gfmd_n: int | None = None) -> pd.DataFrame:
    """Relative error of each theory form against GFMD per (hurst, rho, sigma0), with uncertainty.

    ``agg`` is :func:`analysis.aggregate.aggregate_mean_gap`. GFMD is taken on grid ``gfmd_n`` (default: the finest
    grid of each point); the discrete theory on the same grid when it has it, else on its finest grid.
    Columns: form, hurst, rho, sigma0, sigma0_reduced, h_rms, h_rms_over_rho, n, gfmd, gfmd_sem, gfmd_count,
    gfmd_not_done (failed + not converged + pending + invalid GFMD rows at that point), theory, theory_sem,
    rel_err, rel_err_sem, red_err, red_err_sem, ill_conditioned, then the h_rms bookkeeping:
    ``h_rms`` (and ``h_rms_over_rho``, the reduced axes) is the GFMD surfaces' own (discrete) rms height, mean over
    seeds; ``theory_h_rms`` says which h_rms the ``theory`` column used ("continuum": the spectrum's integral,
    forms paper/continuum, as stored by the theory task; "surface": the discrete form, on the surface's own
    modes, or a job whose surfaces are scaled to the theory's h_rms); ``h_rms_theory`` is that value;
    ``theory_hsurf``/``rel_err_hsurf`` are the same form evaluated with the surfaces' ``h_rms`` (equal to
    ``theory``/``rel_err`` for the discrete form). The verdicts use
    ``rel_err`` (continuum h_rms, as the paper does). Points where GFMD has no finite value are kept with NaN
    errors and ``gfmd_count == 0`` so that a report can list them.
    """
    for f in forms:
        if f not in _FORMS:
            raise ValueError(f"forms: unknown form {f!r}; allowed: {', '.join(_FORMS)}")
    cols = ["form", "job", "hurst", "rho", "sigma0", "sigma0_reduced", "h_rms", "h_rms_over_rho", "n", "gfmd",
            "gfmd_sem", "gfmd_count", "gfmd_not_done", "theory", "theory_sem", "rel_err", "rel_err_sem", "red_err",
            "red_err_sem", "ill_conditioned", "theory_h_rms", "h_rms_theory", "theory_hsurf", "rel_err_hsurf"]
    if agg.empty:
        return pd.DataFrame(columns=cols)
    a = agg.assign(_h=agg["hurst"].map(_rk), _r=agg["rho"].map(_rk), _s=agg["sigma0"].map(_rk))
    gf = _pick_n(a[a["source"] == "gfmd"], gfmd_n)
    rows = []
    for _, g in gf.iterrows():
        key = (g["_h"], g["_r"], g["_s"], g["job"])
        not_done = int(g["n_failed"] + g["n_not_converged"] + g["n_pending"] + g["n_invalid"])
        for form in forms:
            th = a[(a["source"] == f"theory:{form}") & (a["_h"] == key[0]) & (a["_r"] == key[1]) & (a["_s"] == key[2])
                   & (a["job"] == key[3])]
            if th.empty:
                continue
            if form == "discrete":
                same = th[th["n"] == g["n"]]
                th = same if not same.empty else th[th["n"] == th["n"].max()]
            t = th.iloc[0]
            G, sG = float(g["mean"]), float(g["sem"])
            T, sT = float(t["mean"]), float(t["sem"])
            h = float(g["h_rms"]) if np.isfinite(g["h_rms"]) else float(t["h_rms"])
            sG0 = sG if np.isfinite(sG) else 0.0
            sT0 = sT if np.isfinite(sT) else 0.0
            with np.errstate(divide="ignore", invalid="ignore"):
                rel = (T - G) / abs(G) if G != 0 else math.nan
                rel_sem = math.hypot(sT0 / abs(G), T * sG0 / G**2) if G != 0 else math.nan
            if not np.isfinite(sG) and int(g["count"]) < 2:
                rel_sem = math.nan  # one seed: no uncertainty estimate, say so rather than report 0
            red_sem = math.hypot(sT0, sG0) / h if int(g["count"]) >= 2 else math.nan
            rows.append({
                "form": form, "job": g["job"], "hurst": g["hurst"], "rho": g["rho"], "sigma0": g["sigma0"],
                "sigma0_reduced": g["sigma0_reduced"], "h_rms": h, "h_rms_over_rho": h / g["rho"], "n": g["n"],
                "gfmd": G, "gfmd_sem": sG, "gfmd_count": int(g["count"]), "gfmd_not_done": not_done,
                "theory": T, "theory_sem": sT, "rel_err": rel, "rel_err_sem": rel_sem,
                "red_err": (T - G) / h, "red_err_sem": red_sem,
                "ill_conditioned": bool(np.isfinite(G) and abs(G) < ILL_CONDITIONED * h),
                **_with_surface_h_rms(form, t, h, G, T),
            })
    out = pd.DataFrame(rows, columns=cols)
    # Two jobs may hold the same tasks (same content id, e.g. fig2 and fig4_5 at H = 0.3, sigma0 = 0.01): one row.
    out = out.drop_duplicates(["form", "hurst", "rho", "sigma0", "n", "gfmd", "theory"])
    return out.sort_values(["form", "hurst", "rho", "sigma0", "job"], ignore_index=True)


def _with_surface_h_rms(form: str, t: pd.Series, h_surface: float, G: float, T: float) -> dict[str, Any]:
    """The theory of ``form`` with the GFMD surfaces' own h_rms (docs/model.md M4), beside the stored value."""
    if form == "discrete":
        return {"theory_h_rms": "surface", "h_rms_theory": h_surface, "theory_hsurf": T,
                "rel_err_hsurf": (T - G) / abs(G) if G != 0 else math.nan}
    h_th = float(t["h_rms"])
    try:
        with warnings.catch_warnings():
            # this table compares the theory with GFMD everywhere, inside its validated domain and out (that is
            # what it is for); the table keeps h_rms_over_rho and the report's figures mark the panels outside
            # the domain (figures.OUTSIDE_NOTE), so one warning per row would only bury the terminal
            warnings.simplefilter("ignore", PredictorDomainWarning)
            ts = float(theory.mean_gap(float(t["sigma0"]), hurst=float(t["hurst"]), h_rms=h_surface,
                                       rho=float(t["rho"]), gamma0=float(t["gamma0"]), lambda_l=float(t["lambda_l"]),
                                       lambda_s=float(t["lambda_s"]), e_star=float(t["e_star"]), form=form))
    except (ValueError, KeyError, TypeError):
        ts = math.nan
    # a job that fixes the surfaces' rms height (rms_height=...) gives the theory the same number: say so
    label = "surface" if math.isclose(h_th, h_surface, rel_tol=1e-6) else "continuum"
    return {"theory_h_rms": label, "h_rms_theory": h_th, "theory_hsurf": ts,
            "rel_err_hsurf": (ts - G) / abs(G) if G != 0 and np.isfinite(G) else math.nan}


def _tier(err: float, thresholds: Sequence[float]) -> str:
    for t in thresholds:
        if abs(err) <= t:
            return f"<={t * 100:g}%"
    return f">{thresholds[-1] * 100:g}%"


def agreement_regions(cmp: pd.DataFrame, *, form: str = "paper", thresholds: Sequence[float] = THRESHOLDS
                      ) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Where the field theory is within 1 %, 5 %, 10 % of GFMD (M6), against ``h_rms/rho``.

    Returns ``(points, summary)``. ``points``: the rows of ``cmp`` for ``form`` with a ``tier`` column
    ("<=1%", "<=5%", "<=10%", ">10%", "ill-conditioned" or "no GFMD data"). ``summary``, one row per
    (job, hurst, rho) sorted by ``h_rms/rho`` (the job keeps surface families apart: fig-2, fig-4/5 and fig-6
    surfaces differ at the same (hurst, rho)): the number of classified points, of ill-conditioned and
    of missing points, the largest ``|rel_err|`` (continuum h_rms, used by the verdicts) and
    ``max_abs_rel_err_hsurf`` (the surfaces' h_rms), and for each threshold ``t`` the fraction of points
    within ``t`` (``frac_<=t%``) and the smallest
    reduced pressure ``sigma0/(E* g_rms)`` from which on every higher pressure agrees within ``t``
    (``sigma0_from_<=t%``, NaN if even the highest pressure does not).
    """
    th = sorted(float(t) for t in thresholds)
    if not th or th[0] <= 0:
        raise ValueError("thresholds: need at least one positive threshold (fractions, e.g. 0.05 for 5 %)")
    p = cmp[cmp["form"] == form].copy()
    tiers = []
    for _, r in p.iterrows():
        if not np.isfinite(r["rel_err"]):
            tiers.append("no GFMD data")
        elif r["ill_conditioned"]:
            tiers.append("ill-conditioned")
        else:
            tiers.append(_tier(r["rel_err"], th))
    p["tier"] = tiers
    rows = []
    for (job, h, rho), g in p.groupby(["job", "hurst", "rho"], sort=True):
        ok = g[~g["tier"].isin(["no GFMD data", "ill-conditioned"])].sort_values("sigma0")
        row: dict[str, Any] = {"job": job, "hurst": h, "rho": rho, "h_rms_over_rho": float(g["h_rms_over_rho"].mean()),
                               "points": len(ok), "ill_conditioned": int((g["tier"] == "ill-conditioned").sum()),
                               "missing": int((g["tier"] == "no GFMD data").sum()),
                               "max_abs_rel_err": float(ok["rel_err"].abs().max()) if len(ok) else math.nan}
        if "rel_err_hsurf" in ok.columns:
            row["max_abs_rel_err_hsurf"] = float(ok["rel_err_hsurf"].abs().max()) if len(ok) else math.nan
        for t in th:
            within = (ok["rel_err"].abs() <= t).to_numpy()
            row[f"frac_<={t * 100:g}%"] = float(within.mean()) if len(ok) else math.nan
            # The lowest pressure from which on all higher ones agree: scan from the high-pressure end.
            start = math.nan
            for i in range(len(ok) - 1, -1, -1):
                if not within[i]:
                    break
                start = float(ok["sigma0_reduced"].iloc[i])
            row[f"sigma0_from_<={t * 100:g}%"] = start
        rows.append(row)
    summary = pd.DataFrame(rows)
    if not summary.empty:
        summary = summary.sort_values("h_rms_over_rho", ignore_index=True)
    return p.reset_index(drop=True), summary


def pressure_trend(cmp: pd.DataFrame, *, form: str = "paper", min_err: float = 0.01) -> pd.DataFrame:
    """Does the agreement improve with pressure (M6)? One row per surface family (job) and (hurst, rho).

    Over the well-conditioned points with a finite error, Spearman's rank correlation of ``|rel_err|`` (and of
    ``|rel_err_hsurf|``, the error at the surfaces' own h_rms) with ``sigma0``: negative = improves. Rows with
    fewer than 3 points or all errors below ``min_err`` are kept with ``improves`` = NaN (nothing to read).
    Grouping by job keeps the fig-2, fig-4/5 and fig-6 surfaces apart. Columns: job, hurst, rho,
    h_rms_over_rho, points, max_abs_rel_err, spearman, spearman_hsurf, improves.
    """
    from scipy.stats import spearmanr

    cols = ["job", "hurst", "rho", "h_rms_over_rho", "points", "max_abs_rel_err", "spearman", "spearman_hsurf",
            "improves"]
    p = cmp[(cmp["form"] == form) & np.isfinite(cmp["rel_err"]) & ~cmp["ill_conditioned"].astype(bool)]
    rows = []

    def rank_corr(x, y) -> float:
        x, y = np.asarray(x, float), np.asarray(y, float)
        ok = np.isfinite(x) & np.isfinite(y)
        if ok.sum() < 3 or np.ptp(x[ok]) == 0 or np.ptp(y[ok]) == 0:
            return math.nan
        return float(spearmanr(x[ok], y[ok]).statistic)

    for (job, h, rho), g in p.groupby(["job", "hurst", "rho"], sort=True):
        err = g["rel_err"].abs()
        rs = rank_corr(g["sigma0"], err)
        rs_h = rank_corr(g["sigma0"], g["rel_err_hsurf"].abs()) if "rel_err_hsurf" in g else math.nan
        readable = len(g) >= 3 and float(err.max()) > min_err and np.isfinite(rs)
        rows.append({"job": job, "hurst": h, "rho": rho, "h_rms_over_rho": float(g["h_rms_over_rho"].mean()),
                     "points": len(g), "max_abs_rel_err": float(err.max()), "spearman": rs,
                     "spearman_hsurf": rs_h, "improves": (rs < 0) if readable else math.nan})
    return pd.DataFrame(rows, columns=cols)


# ---------------------------------------------------------------------------------------------------------
# histograms


def _abs_linear_integral(d0: np.ndarray, d1: np.ndarray, dx: np.ndarray) -> np.ndarray:
    """Exact ``int |D|`` over intervals on which ``D`` is linear from ``d0`` to ``d1``."""
    a0, a1 = np.abs(d0), np.abs(d1)
    same = d0 * d1 >= 0
    with np.errstate(divide="ignore", invalid="ignore"):
        cross = np.where(a0 + a1 > 0, (d0**2 + d1**2) / (2 * (a0 + a1)), 0.0)
    return dx * np.where(same, 0.5 * (a0 + a1), cross)


def histogram_distance(edges_a: Any, density_a: Any, edges_b: Any, density_b: Any, *, split: float | None = None
                       ) -> dict[str, float]:
    """L1, KS and Wasserstein-1 distances between two normalised histograms (module docstring).

    Both are put on the union of their edges (exact: each density is constant inside its bins). Densities that
    do not integrate to 1 (mass outside the binned range) are compared as given. With ``split`` the L1 distance
    is also split into ``l1_below`` (g < split) and ``l1_above``, so deviations at small gaps can be located.
    """
    ea, da = np.asarray(edges_a, float), np.asarray(density_a, float)
    eb, db = np.asarray(edges_b, float), np.asarray(density_b, float)
    extra = [] if split is None else [float(split)]
    u = np.unique(np.concatenate([ea, eb, extra]))
    pa = rebin_density(ea, da, u)
    pb = rebin_density(eb, db, u)
    dx = np.diff(u)
    fa = np.concatenate([[0.0], np.cumsum(pa * dx)])
    fb = np.concatenate([[0.0], np.cumsum(pb * dx)])
    diff = fa - fb
    l1_bins = np.abs(pa - pb) * dx
    out = {"l1": float(l1_bins.sum()), "ks": float(np.abs(diff).max()),
           "w1": float(_abs_linear_integral(diff[:-1], diff[1:], dx).sum())}
    if split is not None:
        below = u[1:] <= split
        out["l1_below"] = float(l1_bins[below].sum())
        out["l1_above"] = float(l1_bins[~below].sum())
    return out


def histogram_distances(hagg: Mapping[tuple, HistogramStats], *, reference: str = "gfmd") -> pd.DataFrame:
    """Distances of every SDE / Fokker-Planck merged histogram to the GFMD one at the same (hurst, rho, sigma0).

    ``hagg`` is :func:`analysis.aggregate.aggregate_histograms` (keys (method, hurst, rho, sigma0, n, c2, job));
    the GFMD reference is the finest grid of the same job. The L1 distance is split at the GFMD mean gap
    (``l1_below``: small gaps). Columns: method, job, c2, hurst, rho, sigma0, h_rms, l1, ks, w1, w1_over_hrms,
    l1_below, l1_above.
    """
    refs: dict[tuple, tuple[float, HistogramStats]] = {}
    for (m, h, r, s, n, _c2, job), st in hagg.items():
        if m == reference:
            k = (_rk(h), _rk(r), _rk(s), job)
            if k not in refs or n > refs[k][0]:
                refs[k] = (n, st)
    rows = []
    for (m, h, r, s, _n, c2, job), st in hagg.items():
        if m == reference:
            continue
        k = (_rk(h), _rk(r), _rk(s), job)
        if k not in refs:
            continue
        ref = refs[k][1]
        g0 = ref.get("mean_gap", math.nan)
        if not np.isfinite(g0):
            g0 = float((ref.centres * ref["density"] * np.diff(ref["edges"])).sum())
        d = histogram_distance(ref["edges"], ref["density"], st["edges"], st["density"], split=g0)
        hr = ref.get("h_rms", math.nan)
        rows.append({"method": m, "job": job, "c2": c2, "hurst": h, "rho": r, "sigma0": s, "h_rms": hr, **d,
                     "w1_over_hrms": d["w1"] / hr if hr and np.isfinite(hr) else math.nan})
    cols = ["method", "job", "c2", "hurst", "rho", "sigma0", "h_rms", "l1", "ks", "w1", "l1_below", "l1_above",
            "w1_over_hrms"]
    return pd.DataFrame(rows, columns=cols).sort_values(["method", "hurst", "rho", "c2", "sigma0"],
                                                        ignore_index=True)


def calibrate_c2(hagg: Mapping[tuple, HistogramStats], *, metric: str = "w1", reference: str = "gfmd",
                 keys: Sequence[tuple[float, float, float]] | None = None
                 ) -> tuple[pd.DataFrame, dict[tuple, HistogramStats]]:
    """Calibrate ``C2`` (M5) against each merged GFMD histogram with ``gapsweep.calibrate.fit`` (Fokker-Planck
    forward model, ``C1`` at its default ``H h_rms^2``, distance ``metric``); the only call into
    ``gapsweep.calibrate``.

    The physical parameters are the GFMD group's (``h_rms`` measured on the surfaces, mean over seeds). ``keys``
    restricts the calibration to some (hurst, rho, sigma0) or (hurst, rho, sigma0, job). Returns ``(table,
    models)``: ``table`` with columns
    hurst, rho, sigma0, c2, distance, status, message, wall_time (status "unavailable" when gapsweep.calibrate
    cannot be imported); ``models`` maps ``("fp_calibrated", hurst, rho, sigma0, 0.0, c2, job)`` to the calibrated
    model density on the GFMD bins (a :class:`HistogramStats`), ready for :func:`histogram_distances` and
    figure 6. No uncertainty is attached: GFMD pixels are correlated and their effective count is unknown here.
    """
    cols = ["job", "hurst", "rho", "sigma0", "c2", "distance", "status", "message", "wall_time"]
    try:
        from gapsweep import calibrate
    except ImportError as exc:  # the analysis still runs without it; the report says so
        return pd.DataFrame([{"status": "unavailable", "message": str(exc)}], columns=cols), {}
    refs: dict[tuple, tuple[float, HistogramStats]] = {}
    for (m, h, r, s, n, _c2, job), st in hagg.items():
        if m == reference and (keys is None or any(_rk(h) == _rk(k[0]) and _rk(r) == _rk(k[1]) and
                                                   _rk(s) == _rk(k[2]) and (len(k) < 4 or k[3] == job) for k in keys)):
            k = (h, r, s, job)
            if k not in refs or n > refs[k][0]:
                refs[k] = (n, st)
    rows, models = [], {}
    for (h, r, s, job), (_n, st) in sorted(refs.items()):
        try:
            res = calibrate.fit(st["edges"], st["density"], sigma0=float(s), hurst=float(h), h_rms=float(st["h_rms"]),
                                rho=float(r), gamma0=float(st["gamma0"]), lambda_l=float(st["lambda_l"]),
                                lambda_s=float(st["lambda_s"]), e_star=float(st["e_star"]), metric=metric)
        except (ValueError, RuntimeError, FloatingPointError) as exc:
            rows.append({"job": job, "hurst": h, "rho": r, "sigma0": s, "c2": math.nan, "distance": math.nan,
                         "status": "failed", "message": str(exc), "wall_time": math.nan})
            continue
        rows.append({"job": job, "hurst": h, "rho": r, "sigma0": s, "c2": res.c2, "distance": res.distance,
                     "status": res.status, "message": res.message, "wall_time": res.wall_time})
        if res.status != "failed" and np.all(np.isfinite(res.model_density)):
            md = np.clip(np.asarray(res.model_density, float), 0.0, None)
            m = HistogramStats(edges=st["edges"], density=md, sem=np.zeros_like(md), sem_kind="model", count=0,
                               n_hist=1)
            for p in ("h_rms", "g_rms", "e_star", "gamma0", "lambda_l", "lambda_s"):
                m[p] = st.get(p, math.nan)
            m["mean_gap"] = math.nan
            models[("fp_calibrated", h, r, s, 0.0, float(res.c2), job)] = m
    return pd.DataFrame(rows, columns=cols), models
