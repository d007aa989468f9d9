"""Calibrate the fudge factors ``C2`` (and optionally ``C1``) of docs/model.md M5 against a gap histogram.

Forward model: :func:`gapsweep.fokker_planck.solve` (noise-free, tens of ms per evaluation), compared with the
histogram by a distance between densities:

* ``"nll"`` (default): multinomial negative log-likelihood per sample, ``-sum_i f_i ln(P_i)``;
* ``"w1"``: Wasserstein-1, ``int |F_model(g) - F_data(g)| dg`` [length] (CDFs piecewise linear);
* ``"l1"``: ``int |p_model - p_data| dg`` on the histogram's bins (dimensionless, in [0, 2]).

``C2`` is searched in ``ln C2`` (bounded scalar minimisation); with ``fit_c1=True`` (``ln C2``, ``ln C1``) by
Nelder-Mead from the ``C2``-only optimum. Uncertainty, given the number of samples behind the histogram
(``count``): the curvature of the multinomial log-likelihood at the optimum (``"curvature"``, cheap: valid for
the ``"nll"`` estimator only, whose error it is) or a parametric bootstrap over multinomial resamples of the
histogram (``"bootstrap"``, any metric). ``uncertainty="auto"`` (default) picks curvature for ``"nll"`` and the
bootstrap for the distances (their scatter is 2-2.5x the likelihood curvature's). The forward model's own
discretisation error (the FP solver's step-doubling estimate, relative to the gap's standard deviation) is
turned into a systematic error of ``C2`` through the sensitivity of the model's mean and standard deviation to
``ln C2`` and added in quadrature (``c2_sys_err``). GFMD gap fields are spatially correlated: pass an effective
``count`` (pixels / correlation area), not the pixel count.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize, minimize_scalar

from gapsweep.core import checks as chk
from gapsweep.gapdist import fokker_planck

__all__ = ["CalibrationResult", "distance", "fit"]

DISTANCES = ("w1", "l1", "nll")
UNCERTAINTIES = ("auto", "curvature", "bootstrap")


@dataclass
class CalibrationResult:
    """Fitted ``c2`` (and ``c1``; ``None`` = the default ``H h_rms^2`` when not fitted), the distance at the
    optimum, 1-sigma uncertainties ``c2_err``/``c1_err`` (NaN when no ``count`` was given; ``c2_err`` is the
    statistical ``c2_stat_err`` and the forward model's systematic ``c2_sys_err`` in quadrature), the model's
    density on the histogram's bins, the number of forward solves, and ``status`` ("ok" | "at_bound" |
    "failed"). ``uncertainty`` is the method used ("curvature" | "bootstrap")."""

    c2: float
    c1: float | None
    distance: float
    c2_err: float
    c1_err: float
    metric: str
    model_density: np.ndarray
    n_evals: int
    status: str
    message: str
    wall_time: float
    bootstrap: np.ndarray = field(default_factory=lambda: np.empty((0, 2)))
    c2_stat_err: float = math.nan
    c2_sys_err: float = math.nan
    uncertainty: str = ""


def _histogram(edges, density) -> tuple[np.ndarray, np.ndarray]:
    e = np.asarray(edges, dtype=float)
    d = np.asarray(density, dtype=float)
    if e.ndim != 1 or e.size < 3 or not np.all(np.isfinite(e)) or np.any(np.diff(e) <= 0):
        raise ValueError("edges must be a 1-D array of >= 3 finite, increasing bin edges")
    if d.shape != (e.size - 1,) or not np.all(np.isfinite(d)) or np.any(d < 0):
        raise ValueError(f"density must be {e.size - 1} finite values >= 0 (one per bin)")
    mass = float(np.sum(d * np.diff(e)))
    if not mass > 0:
        raise ValueError("density must have positive mass")
    return e, d / mass


def distance(model: fokker_planck.FPResult, edges: np.ndarray, density: np.ndarray, metric: str = "w1") -> float:
    """Distance between the FP density (last zeta) and a histogram ``(edges, density)`` (see module doc)."""
    if metric not in DISTANCES:
        raise ValueError(f"metric must be one of {DISTANCES}, got {metric!r}")
    e, d = _histogram(edges, density)
    if metric == "l1":
        return float(np.sum(np.abs(model.bin_density(e) - d) * np.diff(e)))
    if metric == "nll":
        pm = np.maximum(np.diff(model.cdf(e)), 1e-300)
        return float(-np.sum(d * np.diff(e) * np.log(pm)))
    # W1 on the union of the model's cell edges (in g) and the histogram's edges; both CDFs piecewise linear
    gm = model.g_edges()
    grid = np.union1d(gm, e)
    fd = np.interp(grid, e, np.concatenate(([0.0], np.cumsum(d * np.diff(e)))), left=0.0, right=1.0)
    fm = model.cdf(grid)
    diff = np.abs(fm - fd)
    return float(np.sum(0.5 * (diff[1:] + diff[:-1]) * np.diff(grid)))


def fit(edges: np.ndarray, density: np.ndarray, *, sigma0: float, hurst: float, h_rms: float, rho: float,
        gamma0: float, lambda_l: float, lambda_s: float, e_star: float = 1.0, zeta_end: float | None = None,
        c1: float | None = None, fit_c1: bool = False, metric: str = "nll", c2_bounds: tuple[float, float] =
        (1e-3, 10.0), c1_bounds: tuple[float, float] | None = None, count: int | None = None,
        uncertainty: str = "auto", n_boot: int = 20, seed: int = 0, fp_options: dict | None = None
        ) -> CalibrationResult:
    """Fit ``C2`` (and ``C1`` if ``fit_c1``) of the M5 gap SDE/FP so its density at ``zeta_end`` matches a histogram.

    ``edges`` [length], ``density`` [1/length] (renormalised to the mass in the bins). Physical parameters as in
    :func:`gapsweep.fokker_planck.solve` (``zeta_end=None``: ``zeta_s``). ``c1``: fixed ``C1`` (or the start
    value when ``fit_c1``); ``None`` is ``H h_rms^2``. ``count``: samples behind the histogram, needed for
    ``c2_err``/``c1_err``. ``fp_options``: extra keyword arguments of the FP solver (grid, steps).
    """
    t0 = time.perf_counter()
    e, d = _histogram(edges, density)
    uncertainty = _uncertainty_of(metric, uncertainty)
    lo2, hi2 = (chk.positive(c2_bounds[0], "c2_bounds[0]"), chk.positive(c2_bounds[1], "c2_bounds[1]"))
    if not hi2 > lo2:
        raise ValueError(f"c2_bounds must be increasing, got {c2_bounds!r}")
    count = None if count is None else chk.count(count, "count")
    n_boot = chk.count(n_boot, "n_boot", minimum=2)
    c1_start = hurst * h_rms**2 if c1 is None else chk.nonnegative(c1, "c1")
    if fit_c1:
        lo1, hi1 = _c1_range(c1_start, c1_bounds)
    fp_kw = dict(sigma0=sigma0, hurst=hurst, h_rms=h_rms, rho=rho, gamma0=gamma0, lambda_l=lambda_l,
                 lambda_s=lambda_s, e_star=e_star, zetas=None if zeta_end is None else [zeta_end])
    fp_kw.update(fp_options or {})
    evals = [0]

    def model(c2v: float, c1v: float | None) -> fokker_planck.FPResult:
        evals[0] += 1
        r = fokker_planck.solve(c2=c2v, c1=c1v, **fp_kw)
        if r.status != "ok":
            raise RuntimeError(f"Fokker-Planck forward model: {r.status} at c2={c2v:.4g}")
        return r

    def dist(x2: float, c1v: float | None, ed=e, dd=d) -> float:
        return distance(model(math.exp(x2), c1v), ed, dd, metric)

    def fit_once(ed, dd):
        c1_fixed = None if (c1 is None and not fit_c1) else c1_start
        res = minimize_scalar(lambda x: dist(x, c1_fixed, ed, dd), bounds=(math.log(lo2), math.log(hi2)),
                              method="bounded", options={"xatol": 1e-3})
        x2, x1, fval = float(res.x), math.log(c1_start) if c1_start > 0 else 0.0, float(res.fun)
        if fit_c1:
            def f2(v):
                a = min(max(v[0], math.log(lo2)), math.log(hi2))
                b = min(max(v[1], math.log(lo1)), math.log(hi1))
                return dist(a, math.exp(b), ed, dd)

            r2 = minimize(f2, np.array([x2, x1]), method="Nelder-Mead",
                          options={"xatol": 1e-3, "fatol": 1e-9 * max(fval, 1e-30), "maxfev": 200})
            x2 = min(max(float(r2.x[0]), math.log(lo2)), math.log(hi2))
            x1 = min(max(float(r2.x[1]), math.log(lo1)), math.log(hi1))
            fval = float(r2.fun)
        return x2, x1, fval

    try:
        x2, x1, fval = fit_once(e, d)
    except (RuntimeError, ValueError, FloatingPointError) as exc:
        return CalibrationResult(math.nan, None, math.nan, math.nan, math.nan, metric, np.full(d.size, np.nan),
                                 evals[0], "failed", str(exc), time.perf_counter() - t0)
    c2_fit = math.exp(x2)
    c1_fit = math.exp(x1) if fit_c1 else c1
    best = model(c2_fit, c1_fit)
    status, message = "ok", ""
    if abs(x2 - math.log(lo2)) < 2e-3 or abs(x2 - math.log(hi2)) < 2e-3:
        status, message = "at_bound", f"C2 = {c2_fit:.4g} is at the edge of c2_bounds {c2_bounds}"
    c2_err = c1_err = math.nan
    boot = np.empty((0, 2))
    sys_err = _model_error(model, best, x2, c1_fit) * c2_fit
    if count is not None and uncertainty == "curvature":
        c2_err, c1_err = _curvature_errors(model, e, d, count, x2, x1, fit_c1, c1_fit)
        c2_err *= c2_fit
        c1_err = c1_err * math.exp(x1) if fit_c1 else math.nan
    elif count is not None:
        boot = _bootstrap(fit_once, e, d, count, n_boot, seed, fit_c1)
        if len(boot) >= 2:
            c2_err = float(np.std(boot[:, 0], ddof=1))
            c1_err = float(np.std(boot[:, 1], ddof=1)) if fit_c1 else math.nan
    stat_err = c2_err
    c2_err, message = _with_model_error(stat_err, sys_err, message)
    return CalibrationResult(c2_fit, c1_fit, fval, c2_err, c1_err, metric, best.bin_density(e), evals[0], status,
                             message, time.perf_counter() - t0, boot, stat_err, sys_err, uncertainty)


def _with_model_error(stat_err: float, sys_err: float, message: str) -> tuple[float, str]:
    """The error of ``C2``: the statistical and the forward model's systematic error in quadrature (NaN stays
    NaN), and the message noting when the systematic one dominates."""
    if not math.isfinite(stat_err):
        return stat_err, message
    if sys_err > stat_err:
        message = (message + "; " if message else "") + (
            f"forward-model error dominates: systematic {sys_err:.3g} > statistical {stat_err:.3g} "
            "(tighten fp_options['tol'])")
    return math.hypot(stat_err, sys_err), message


def _uncertainty_of(metric: str, uncertainty: str) -> str:
    """The error estimate of a fit: "auto" is the likelihood's curvature for metric "nll", else the bootstrap;
    the curvature is refused for the other metrics."""
    if metric not in DISTANCES:
        raise ValueError(f"metric must be one of {DISTANCES}, got {metric!r}")
    if uncertainty not in UNCERTAINTIES:
        raise ValueError(f"uncertainty must be one of {UNCERTAINTIES}, got {uncertainty!r}")
    if uncertainty == "auto":
        return "curvature" if metric == "nll" else "bootstrap"
    if uncertainty == "curvature" and metric != "nll":
        raise ValueError(f"uncertainty='curvature' is the error of the likelihood fit (metric='nll'), not of "
                         f"metric={metric!r}: use metric='nll' or uncertainty='bootstrap'")
    return uncertainty


def _c1_range(c1_start: float, c1_bounds: tuple[float, float] | None) -> tuple[float, float]:
    """Bounds of a fitted ``C1`` [length^2]: ``c1_bounds``, default a decade either side of the start value."""
    if not c1_start > 0:
        raise ValueError("fit_c1 needs a start value c1 > 0 (or h_rms > 0)")
    lo1, hi1 = c1_bounds if c1_bounds is not None else (c1_start / 10.0, c1_start * 10.0)
    return chk.positive(lo1, "c1_bounds[0]"), chk.positive(hi1, "c1_bounds[1]")


def _bootstrap(fit_once, e: np.ndarray, d: np.ndarray, count: int, n_boot: int, seed: int, fit_c1: bool,
               ) -> np.ndarray:
    """``(n, 2)`` array of ``(C2, C1 or NaN)`` refitted to ``n_boot`` multinomial resamples of ``count`` samples
    of the histogram (seeded); a resample whose fit fails is left out."""
    rng = np.random.default_rng(seed)
    pr = d * np.diff(e)
    rows = []
    for _ in range(n_boot):
        cb = rng.multinomial(count, pr / pr.sum())
        db = cb / (count * np.diff(e))
        try:
            bx2, bx1, _ = fit_once(e, db)
        except (RuntimeError, ValueError, FloatingPointError):
            continue
        rows.append((math.exp(bx2), math.exp(bx1) if fit_c1 else math.nan))
    return np.asarray(rows, dtype=float).reshape(-1, 2)


def _model_error(model, best, x2, c1_fit) -> float:
    """Systematic error of ``ln C2`` from the forward model's discretisation: the FP step-error estimate
    (``best.error``, relative to the gap's sd) divided by the larger sensitivity of the model's mean and sd to
    ``ln C2`` (the moment that pins ``C2`` hardest; central difference, step 0.05)."""
    err = float(getattr(best, "error", 0.0) or 0.0)
    if err == 0.0:
        return 0.0
    h = 0.05
    rp, rm = model(math.exp(x2 + h), c1_fit), model(math.exp(x2 - h), c1_fit)
    sd = math.sqrt(best.variance())
    dm = abs(rp.mean() - rm.mean()) / (2 * h)
    ds = abs(math.sqrt(rp.variance()) - math.sqrt(rm.variance())) / (2 * h)
    sens = max(dm, ds)
    return err * sd / sens if sens > 0 else math.inf


def _curvature_errors(model, e, d, count, x2, x1, fit_c1, c1_fit) -> tuple[float, float]:
    """1-sigma errors of ``ln C2`` (and ``ln C1``) from the Hessian of the multinomial NLL (``count`` samples)."""
    w = d * np.diff(e)

    def nll(a, b):
        r = model(math.exp(a), math.exp(b) if fit_c1 else c1_fit)
        pm = np.maximum(np.diff(r.cdf(e)), 1e-300)
        pm = pm / pm.sum()  # the histogram only sees the bins
        return -count * float(np.sum(w * np.log(pm)))

    h = 0.05
    f0 = nll(x2, x1)
    if not fit_c1:
        f_p, f_m = nll(x2 + h, x1), nll(x2 - h, x1)
        curv = (f_p - 2.0 * f0 + f_m) / h**2
        return (1.0 / math.sqrt(curv) if curv > 0 else math.inf), math.nan
    f = {}
    for i in (-1, 0, 1):
        for j in (-1, 0, 1):
            f[i, j] = f0 if i == j == 0 else nll(x2 + i * h, x1 + j * h)
    hxx = (f[1, 0] - 2 * f0 + f[-1, 0]) / h**2
    hyy = (f[0, 1] - 2 * f0 + f[0, -1]) / h**2
    hxy = (f[1, 1] - f[1, -1] - f[-1, 1] + f[-1, -1]) / (4 * h**2)
    hess = np.array([[hxx, hxy], [hxy, hyy]])
    try:
        cov = np.linalg.inv(hess)
    except np.linalg.LinAlgError:
        return math.inf, math.inf
    if np.any(np.diag(cov) <= 0):
        return math.inf, math.inf
    return float(math.sqrt(cov[0, 0])), float(math.sqrt(cov[1, 1]))
