"""Deterministic solver of the gap Fokker-Planck equation of docs/model.md M5.

Equation (magnification ``zeta`` as time, gap ``g`` [length])::

    dP/dzeta = -d/dg [a(g, zeta) P] + D2(zeta) d^2P/dg^2,   a = D1(zeta) + c exp(-g/rho),   c = C2 gamma0/rho,

started from a point mass at the flat-surface gap ``g0(1) = rho ln(gamma0/(rho sigma0))``; ``D1``, ``D2`` from
:mod:`gapsweep.theory`. It is the noise-free reference of :mod:`gapsweep.sde` and a fast path on its own.

Numerics:

* Moving frame ``y = g - g0(zeta) - y_det(zeta)``: ``g0`` (field-theory mean gap, M4) absorbs ``D1`` exactly and
  ``y_det``, the deterministic push of the repulsion (``exp(y_det/rho) = 1 + (c/rho) int_1^zeta exp(-g0/rho)``),
  absorbs the repulsion at ``y = 0``: the drift left is ``u (exp(-y/rho) - 1)`` with ``u = dy_det/dzeta``. At
  high pressure the density is much narrower than ``rho`` and rides on ``y_det``; in a frame without it the
  profile would sweep across the grid and backward Euler would widen it by the numerical diffusion
  ``u^2 dzeta/2`` (2x the sd at sigma0 = 10 on the M7 stiff case).
* Conservative finite volumes on a graded grid in ``y``: cells of ``sd/cells_per_sd`` in the bulk (``sd`` of the
  smallest requested ``zeta``, C2 = 0), ``cells_per_sd`` cells per linearised width in a core around ``y = 0``
  (``dV = 2 D2 dzeta - 2 (u/rho) V dzeta``) and ``rho/cells_per_rho`` in the band the repulsive wall sweeps
  through, growing geometrically in between. Domain: ``+- width_sd`` standard deviations of the C2 = 0
  Gaussian, each end moved by the push that a noise path held there would get (comparison principle).
* Scharfetter-Gummel (exponentially fitted) fluxes, zero flux at both ends, backward Euler in ``zeta``: an
  M-matrix, so the density stays positive and the mass is conserved to rounding whatever the step. Per step the
  diffusion is ``int D2 / dzeta`` (Gauss-Legendre); the exponent of the repulsion is capped at 300 (faster than
  any step can resolve, so nothing physical changes and nothing overflows).
* Steps equidistant in ``s(zeta) = V(zeta)/(2 V_end) + ln(zeta)/(2 ln zeta_end)`` (``V = 2 int D2``): short where
  the variance grows fastest, with the requested magnifications inserted as nodes. Start at the ``zeta`` where
  the spread reaches two cells, from the Gaussian there (exact for C2 = 0).
* Error control: step doubling (the march repeated on every other node) estimates the step error of the mean and
  sd relative to the sd; the steps double while it exceeds ``tol``; status "inaccurate" if it still does.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

import numpy as np
from scipy.linalg.lapack import dgtsv as _gtsv
from scipy.special import ndtr

from gapsweep import theory
from gapsweep.core import checks as chk
from gapsweep.core import deadline
from gapsweep.gapdist.sde import _check_common, _interval_integrals

__all__ = ["FPResult", "solve"]

logger = logging.getLogger("gapsweep.fokker_planck")

_EXP_CAP = 300.0


@dataclass
class FPResult:
    """Solution of the M5 Fokker-Planck equation at the requested magnifications.

    ``zetas`` (n_zeta,), ``g0`` (n_zeta,) field-theory mean gaps [length], ``y_edges``/``y`` (n_cells+1 /
    n_cells) cell edges/centres of the moving frame ``y = g - g0 - offset``, ``density`` (n_zeta, n_cells) cell
    averages [1/length], each integrating to 1. ``offset`` (n_zeta,) is the frame's shift by the repulsion's
    deterministic push relative to the last zeta (0 at the last requested zeta and whenever C2 = 0, so there
    ``g0[-1] + y_edges`` are the edges in ``g``); ``g`` (n_zeta, n_cells) are the cell centres in ``g`` at each
    ``zeta``, :meth:`g_edges` the edges. ``status``: "ok", "domain_too_small" (more than ``edge_tol`` of the
    mass in the outermost cells) or "inaccurate" (``error > tol``); ``mass_error`` is the largest
    ``|sum P dy - 1|`` seen; ``error`` the step-doubling estimate of the zeta-step error of the mean and the
    standard deviation, relative to the standard deviation (max over the requested zetas); ``tol`` the target.
    """

    zetas: np.ndarray
    g0: np.ndarray
    y_edges: np.ndarray
    density: np.ndarray
    n_steps: int
    mass_error: float
    edge_mass: float
    status: str
    wall_time: float
    variance_c2_0: np.ndarray
    offset: np.ndarray | None = None
    error: float = 0.0
    tol: float | None = None

    def __post_init__(self) -> None:
        if self.offset is None:
            self.offset = np.zeros_like(np.asarray(self.g0, dtype=float))

    @property
    def y(self) -> np.ndarray:
        return 0.5 * (self.y_edges[1:] + self.y_edges[:-1])

    @property
    def g(self) -> np.ndarray:
        return (self.g0 + self.offset)[:, None] + self.y[None, :]

    def g_edges(self, zeta: float | None = None) -> np.ndarray:
        """Cell edges in ``g`` [length] at ``zeta`` (default: the last requested)."""
        i = self._index(zeta)
        return self.g0[i] + self.offset[i] + self.y_edges

    @property
    def widths(self) -> np.ndarray:
        return np.diff(self.y_edges)

    def _index(self, zeta: float | None) -> int:
        if zeta is None:
            return len(self.zetas) - 1
        i = int(np.argmin(np.abs(self.zetas - zeta)))
        if not math.isclose(self.zetas[i], zeta, rel_tol=1e-9):
            raise ValueError(f"zeta={zeta!r} was not requested; available: {self.zetas.tolist()}")
        return i

    def at(self, zeta: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(g, density)`` at ``zeta`` (default: the last requested)."""
        i = self._index(zeta)
        return self.g[i], self.density[i]

    def mean(self, zeta: float | None = None) -> float:
        """Mean gap ``<g>`` [length]."""
        i = self._index(zeta)
        return float(self.g0[i] + self.offset[i] + np.sum(self.y * self.density[i] * self.widths))

    def variance(self, zeta: float | None = None) -> float:
        """Variance of the gap [length^2] (cell-average density treated as uniform within each cell)."""
        i = self._index(zeta)
        w, p = self.widths, self.density[i] * self.widths
        m = np.sum(self.y * p)
        return float(np.sum(p * ((self.y - m) ** 2 + w**2 / 12.0)))

    def cdf(self, g: np.ndarray, zeta: float | None = None) -> np.ndarray:
        """Cumulative distribution at gaps ``g`` (piecewise linear inside the cells)."""
        i = self._index(zeta)
        c = np.concatenate(([0.0], np.cumsum(self.density[i] * self.widths)))
        return np.interp(np.asarray(g, dtype=float) - self.g0[i] - self.offset[i], self.y_edges, c, left=0.0,
                         right=c[-1])

    def bin_density(self, edges: np.ndarray, zeta: float | None = None) -> np.ndarray:
        """Average density over the bins ``edges`` [length] (comparable with a histogram on those edges)."""
        edges = np.asarray(edges, dtype=float)
        return np.diff(self.cdf(edges, zeta)) / np.diff(edges)


def _graded_grid(lo: float, hi: float, h_coarse: float, bands: list[tuple[float, float, float]],
                 grading: float, max_cells: int) -> np.ndarray:
    """Edges from ``lo`` to ``hi``: width ``h`` inside each band ``(b0, b1, h)``, growing by ``grading`` away from
    the bands (width ``h + (grading - 1) * distance``), at most ``h_coarse``."""
    bands = [b for b in bands if b[2] < h_coarse]
    if not bands:
        n = max(int(math.ceil((hi - lo) / h_coarse)), 8)
        if n > max_cells:
            raise ValueError(f"grid needs {n} cells (> max_cells={max_cells}); lower cells_per_sd")
        return np.linspace(lo, hi, n + 1)
    edges = [lo]
    y = lo
    while y < hi:
        h = h_coarse
        for b0, b1, hb in bands:
            h = min(h, hb + (grading - 1.0) * max(b0 - y, y - b1, 0.0))
        y = y + h
        edges.append(y)
        if len(edges) > max_cells + 1:
            raise ValueError(f"grid needs more than max_cells={max_cells} cells; lower cells_per_rho or "
                             "cells_per_sd")
    e = np.asarray(edges)
    return lo + (e - lo) * (hi - lo) / (e[-1] - lo)


def _bernoulli(x: np.ndarray) -> np.ndarray:
    """``B(x) = x/(e^x - 1)`` (B(0) = 1), stable for either sign (``B(-x) = x + B(x)``; overflow gives 0)."""
    ax = np.abs(x)
    out = np.ones_like(x)
    nz = ax > 1e-12
    with np.errstate(over="ignore"):
        out[nz] = ax[nz] / np.expm1(ax[nz])
    small = ~nz
    out[small] = 1.0 - 0.5 * ax[small]
    neg = x < 0.0
    out[neg] += ax[neg]
    return out


def solve(sigma0: float, *, hurst: float, h_rms: float, rho: float, gamma0: float, lambda_l: float,
          lambda_s: float, e_star: float = 1.0, zetas: float | np.ndarray | None = None,
          c1: float | None = None, c2: float = 0.0, n_steps: int = 400, cells_per_sd: float = 40.0,
          cells_per_rho: float = 4.0, width_sd: float = 8.0, grading: float = 1.08, max_cells: int = 200_000,
          edge_tol: float = 1e-7, tol: float | None = 0.01, max_steps: int = 6400,
          estimate_error: bool = True) -> FPResult:
    """Solve the M5 Fokker-Planck equation for the gap density at the magnifications ``zetas``.

    ``zetas=None``: ``[zeta_s]`` with ``zeta_s = lambda_l/lambda_s``; ``c1=None``: ``C1 = H h_rms^2``. ``n_steps``
    backward-Euler steps in total (plus the requested nodes). Grid controls: ``cells_per_sd`` (bulk cells per
    final standard deviation), ``cells_per_rho`` (cells per ``rho`` near the wall), ``width_sd``, ``grading``.
    Lengths in the model's units (M1). Needs ``2 int D2 > 0`` (``h_rms > 0`` and ``C1 > 0``).

    Accuracy: ``estimate_error`` repeats the march on every other node (step doubling, 1.5x the work) and
    estimates the step error of the mean and standard deviation relative to the standard deviation; while it
    exceeds ``tol`` the steps are doubled up to ``max_steps``, and a result still above ``tol`` has
    ``status="inaccurate"``. ``tol=None`` accepts any error (the estimate is still reported).
    """
    t_start = time.perf_counter()
    zs = _magnifications(zetas, lambda_l, lambda_s)
    p = _check_common(sigma0, hurst, h_rms, rho, gamma0, lambda_l, lambda_s, e_star, float(zs[-1]), c1, c2)
    n_steps = chk.count(n_steps, "n_steps")
    cells_per_sd = chk.positive(cells_per_sd, "cells_per_sd")
    cells_per_rho = chk.positive(cells_per_rho, "cells_per_rho")
    width_sd = chk.positive(width_sd, "width_sd")
    grading = _grading(grading)
    max_cells = chk.count(max_cells, "max_cells", minimum=8)
    max_steps = chk.count(max_steps, "max_steps")
    tol = None if tol is None else chk.positive(tol, "tol")
    rho_, zeta_end = p["rho"], float(zs[-1])
    coef = dict(hurst=p["hurst"], h_rms=p["h_rms"], rho=rho_, lambda_l=p["lambda_l"], e_star=p["e_star"])
    flat = float(theory.flat_gap(p["sigma0"], rho=rho_, gamma0=p["gamma0"]))

    def d1(x):
        return np.asarray(theory.drift(x, p["sigma0"], **coef))

    def d2(x):
        return np.asarray(theory.diffusion(x, p["sigma0"], c1=p["c1"], **coef))

    # Auxiliary dense log grid: cumulative variance V(z) and mean gap g0(z) (for the grid and the time nodes).
    za = np.unique(np.concatenate((np.exp(np.linspace(0.0, math.log(max(zeta_end, 1.0 + 1e-12)), 2001)), zs)))
    za = za[za <= zeta_end]
    if za.size < 2:  # zeta_end == 1: the point mass itself
        raise ValueError("zetas must contain a magnification > 1 (at zeta = 1 the density is a point mass)")
    va = np.concatenate(([0.0], np.cumsum(2.0 * _interval_integrals(d2, za[:-1], za[1:]))))
    ga = flat + np.concatenate(([0.0], np.cumsum(_interval_integrals(d1, za[:-1], za[1:]))))
    v_end = va[-1]
    if not v_end > 0.0:
        raise ValueError("the Fokker-Planck solver needs a non-zero diffusion (h_rms > 0 and c1 > 0)")
    c = p["c2"] * p["gamma0"] / rho_

    # Deterministic push of the repulsion on the auxiliary grid: y_det solves dy/dz = c exp(-(g0 + y)/rho), so
    # exp(y_det/rho) = 1 + (c/rho) int_1^z exp(-g0/rho) (g0 linear within each interval). The solver's frame
    # moves with g0 + y_det, where the narrow high-pressure density sits still (see _march).
    ydet_a = np.zeros_like(za)
    log_push = np.full(za.size, -np.inf)  # ln((c/rho) int_1^z exp(-g0/rho))
    if c > 0.0:
        dga = np.diff(ga) / rho_
        log_terms = (math.log(c / rho_) + np.log(np.diff(za)) + np.log(_phi(dga)) - ga[:-1] / rho_)
        log_push[1:] = np.logaddexp.accumulate(log_terms)
        ydet_a[1:] = rho_ * np.logaddexp(0.0, log_push[1:])
    # Linearised width in that frame (stiffness k = y_det'/rho): dV = 2 dV_0 - 2 k V dz, exact per interval.
    var_lin = _linear_variance(va, ydet_a / rho_)

    edges = _frame_grid(zs, za, va, ga, ydet_a, log_push, var_lin, c=c, rho=rho_, width_sd=width_sd,
                        cells_per_sd=cells_per_sd, cells_per_rho=cells_per_rho, grading=grading, max_cells=max_cells)
    x = 0.5 * (edges[1:] + edges[:-1])
    h = np.diff(edges)
    n = x.size

    # Start where the C2 = 0 spread is two cells wide at y = 0 (the initial point mass sits there).
    h0 = float(h[np.clip(np.searchsorted(edges, 0.0) - 1, 0, n - 1)])
    z0 = float(np.interp(min((2.0 * h0) ** 2, 0.5 * v_end), va, za))
    z0 = min(z0, float(zs[0])) if zs[0] > 1.0 else z0
    z0 = max(z0, 1.0 + 1e-12 * zeta_end)
    g0_z0 = flat + float(_interval_integrals(d1, np.array([1.0]), np.array([z0]))[0])
    v0 = 2.0 * float(_interval_integrals(d2, np.array([1.0]), np.array([z0]))[0])
    # push of the repulsion at y = 0 over [1, z0] (g0 ~ flat there): the frame's y_det(z0)
    m0 = rho_ * math.log1p(p["c2"] * p["sigma0"] * (z0 - 1.0) / rho_) if c > 0.0 else 0.0
    # Initial Gaussian N(0, v0) in the frame, cell-averaged.
    mass0 = np.diff(ndtr(edges / math.sqrt(v0)))
    mass0 /= mass0.sum()

    out = _early_densities(zs[zs <= z0], za, va, edges, m0, push=p["c2"] * p["sigma0"] if c > 0.0 else 0.0,
                           rho=rho_)

    s_a = 0.5 * va / v_end + 0.5 * np.log(za) / math.log(zeta_end)
    s0 = float(np.interp(z0, za, s_a))
    zs_late = zs[zs > z0]

    def nodes(k_steps: int) -> np.ndarray:
        """Time nodes equidistant in s(z), with the requested zetas inserted."""
        zt = np.interp(np.linspace(s0, 1.0, k_steps + 1), s_a, za)
        zt = np.unique(np.concatenate((zt, zs_late, [z0])))
        zt = zt[zt >= z0]
        zt[-1] = zeta_end
        return zt

    def run(zt: np.ndarray):
        i1 = _interval_integrals(d1, zt[:-1], zt[1:])
        i2 = _interval_integrals(d2, zt[:-1], zt[1:])
        g0t = g0_z0 + np.concatenate(([0.0], np.cumsum(i1)))
        return g0t, _march(zt, g0t, i2, mass0.copy(), m0, edges, c, rho_, zs_late)

    def moments(snaps):
        res = {}
        for zq, (dens, yd) in snaps.items():
            pm = dens * h
            m = float(np.sum(x * pm))
            res[zq] = (m + yd, math.sqrt(float(np.sum(pm * ((x - m) ** 2 + h**2 / 12.0)))))
        return res

    # March with n_steps; estimate the step error by step doubling (the same nodes, every other one), and double
    # the steps while the estimate exceeds tol (backward Euler is first order: error(fine) ~ fine - coarse).
    k_steps = n_steps
    while True:
        deadline.check()  # a task time limit ends the solve between refinements
        zt = nodes(k_steps)
        g0t, (snaps, mass_err, edge_mass) = run(zt)
        err = 0.0
        if estimate_error and zs_late.size and zt.size > 2:
            _g, (snaps_c, _m, _e) = run(zt[_every_other(zt, zs_late)])
            err = _step_error(moments(snaps), moments(snaps_c))
        if tol is None or err <= tol or 2 * k_steps > max_steps:
            break
        logger.debug("fokker_planck: step error %.3g > tol %.3g with %d steps; doubling", err, tol, k_steps)
        k_steps *= 2
    out.update(snaps)
    dens = np.vstack([out[float(zq)][0] for zq in zs])
    ydet_z = np.array([out[float(zq)][1] for zq in zs])
    g0z = np.interp(zs, za, ga)
    g0z[zs >= z0] = np.interp(zs[zs >= z0], zt, g0t)
    var0 = np.interp(zs, za, va)
    # Report y relative to the frame at the last requested zeta, so that y = g - g0 there (as before the frame
    # moved with the repulsion): g = g0 + offset + y with offset = y_det - y_det(zeta_end).
    y_shift = float(ydet_z[-1])
    status = "domain_too_small" if edge_mass > edge_tol else "inaccurate" if tol is not None and err > tol else "ok"
    return FPResult(zetas=zs, g0=g0z, y_edges=edges + y_shift, density=dens, n_steps=zt.size - 1,
                    mass_error=mass_err, edge_mass=edge_mass, status=status, wall_time=time.perf_counter() - t_start,
                    variance_c2_0=var0, offset=ydet_z - y_shift, error=err, tol=tol)


def _magnifications(zetas: float | np.ndarray | None, lambda_l: float, lambda_s: float) -> np.ndarray:
    """The requested magnifications, sorted and unique (default ``[lambda_l/lambda_s]``); each finite and >= 1."""
    zs = np.atleast_1d(np.asarray(lambda_l / lambda_s if zetas is None else zetas, dtype=float))
    if zs.ndim != 1 or zs.size == 0 or not np.all(np.isfinite(zs)):
        raise ValueError(f"zetas must be finite magnifications >= 1, got {zetas!r}")
    if np.any(zs < 1.0):
        raise ValueError(f"zetas must be >= 1 (magnification), got {zs.tolist()}")
    return np.unique(zs)


def _grading(grading: float) -> float:
    """The grid's growth factor between neighbouring cells, > 1."""
    grading = chk.positive(grading, "grading")
    if not grading > 1.0:
        raise ValueError(f"grading must be > 1, got {grading!r}")
    return grading


def _frame_grid(zs: np.ndarray, za: np.ndarray, va: np.ndarray, ga: np.ndarray, ydet_a: np.ndarray,
                log_push: np.ndarray, var_lin: np.ndarray, *, c: float, rho: float, width_sd: float,
                cells_per_sd: float, cells_per_rho: float, grading: float, max_cells: int) -> np.ndarray:
    """Cell edges of the domain in the frame ``y = g - g0 - y_det`` (lengths): +- ``width_sd`` C2 = 0 standard
    deviations, with the repulsion (``c > 0``) the bounds by comparison, a band of ``cells_per_rho`` cells per
    ``rho`` along the repulsion floor and a band resolving the linearised width (auxiliary grid ``za``:
    variance ``va``, mean gap ``ga``, push ``ydet_a``, ``log_push``, linearised variance ``var_lin``)."""
    sd = np.sqrt(va)
    sd_end = math.sqrt(va[-1])
    # the C2 = 0 Gaussian is centred at -y_det
    lo, hi, bands = -width_sd * sd_end, width_sd * sd_end, []
    if c > 0.0:
        with np.errstate(divide="ignore"):
            yw = rho * np.log(c * (za - 1.0) / rho) - ga  # deterministic repulsion floor, g0 frame
        margin = rho * (25.0 + 2.0 * math.log1p(sd_end / rho))
        relevant = yw > -width_sd * sd - margin
        lower = np.maximum(-width_sd * sd, yw - margin) - ydet_a
        upper = width_sd * sd + np.maximum(0.0, 2.0 * yw) - ydet_a
        # Tighter bounds by comparison (g grows with the noise path W): with |W| <= width_sd sd(z) over the
        # history, g >= g0 - w sd + push(W = +w sd) and g <= g0 + w sd + push(W = -w sd), where the push of a
        # path held at g0 + W is rho ln(1 + e^{-W/rho} (c/rho) int exp(-g0/rho)). Both bounds hold; keep the
        # tighter (at high pressure +-2 w sd around y_det instead of the mirror image of the C2 = 0 tail).
        with np.errstate(over="ignore"):
            lower = np.maximum(lower, -width_sd * sd + rho * np.logaddexp(0.0, log_push - width_sd * sd / rho)
                               - ydet_a)
            upper = np.minimum(upper, width_sd * sd + rho * np.logaddexp(0.0, log_push + width_sd * sd / rho)
                               - ydet_a)
        lo = float(np.min(lower))
        hi = max(float(np.max(upper)), float(np.max(width_sd * np.sqrt(var_lin))))
        if np.any(relevant):
            ywf = (yw - ydet_a)[relevant]
            bands.append((float(np.min(ywf)) - margin, float(np.max(ywf)) + 10.0 * rho, rho / cells_per_rho))
    # bulk cells resolve the narrowest requested C2 = 0 density (smallest zeta), within half the cell budget
    sd_min = math.sqrt(float(np.interp(zs[0], za, va))) if zs[0] > 1.0 else sd_end
    h_bulk = max(min(sd_min, sd_end) / cells_per_sd, 2.0 * (hi - lo) / max_cells)
    if c > 0.0:
        # the narrow core: cells_per_sd cells per linearised width at the requested zetas, over +- width_sd widths
        sd_lin = math.sqrt(float(np.min(np.interp(zs[zs > 1.0], za, var_lin)))) if np.any(zs > 1.0) else sd_end
        sd_lin_max = math.sqrt(float(np.max(var_lin)))
        bands.append((-width_sd * sd_lin, width_sd * sd_lin, sd_lin / cells_per_sd))
        lo = min(lo, -width_sd * sd_lin_max)
    return _graded_grid(lo, hi, h_bulk, bands, grading, max_cells)


def _early_densities(zs_early: np.ndarray, za: np.ndarray, va: np.ndarray, edges: np.ndarray, m0: float, *,
                     push: float, rho: float) -> dict[float, tuple[np.ndarray, float]]:
    """``{zeta: (cell-averaged density, y_det)}`` at the magnifications before the march's first node: the C2 = 0
    Gaussian (exact there), shifted by the repulsion's push ``rho ln(1 + push (zeta - 1)/rho)`` at y = 0 (``push``
    = C2 sigma0, 0 without repulsion) relative to the frame's ``m0``."""
    h = np.diff(edges)
    out = {}
    for zq in zs_early:
        vq = float(np.interp(zq, za, va))
        if not vq > 0:
            raise ValueError("zetas must be > 1 (at zeta = 1 the density is a point mass)")
        mq = rho * math.log1p(push * (zq - 1.0) / rho) if push > 0.0 else 0.0
        out[zq] = (np.diff(ndtr((edges - mq + m0) / math.sqrt(vq))) / h, m0)
    return out


def _every_other(zt: np.ndarray, zs_late: np.ndarray) -> np.ndarray:
    """Mask of the coarse march's nodes for step doubling: every other node, the last and the requested ones."""
    keep = np.zeros(zt.size, dtype=bool)
    keep[::2] = True
    keep[-1] = True
    keep[np.isin(zt, zs_late)] = True
    return keep


def _step_error(fine: dict, coarse: dict) -> float:
    """Step-doubling error estimate: the largest difference of the mean and of the standard deviation between
    the fine and the coarse march, relative to the fine standard deviation, over the requested zetas."""
    err = 0.0
    for zq in fine:
        (mf, sf), (mc, sc) = fine[zq], coarse[zq]
        err = max(err, abs(mf - mc) / sf, abs(sf - sc) / sf)
    return err


def _phi(dg: np.ndarray | float) -> np.ndarray:
    """``<exp(-(g - g_k)/rho)>`` over a step in which ``g`` grows linearly by ``dg rho``: ``-expm1(-dg)/dg``."""
    dg = np.asarray(dg, dtype=float)
    small = np.abs(dg) < 1e-12
    with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
        out = np.where(small, 1.0 - 0.5 * dg, -np.expm1(-dg) / np.where(small, 1.0, dg))
    return out


def _linear_variance(va: np.ndarray, kint: np.ndarray) -> np.ndarray:
    """Variance of the linearised frame equation ``dV/dz = dV0/dz - 2 k V`` on the auxiliary grid, with
    ``int k dz`` = ``diff(kint)`` per interval and ``dV0`` the C2 = 0 variance increments (exact for constant k)."""
    out = np.zeros_like(va)
    dv = np.diff(va)
    kk = 2.0 * np.diff(kint)
    decay = np.exp(-kk)
    with np.errstate(divide="ignore", invalid="ignore"):
        gain = np.where(kk > 1e-12, dv * -np.expm1(-kk) / np.where(kk > 1e-12, kk, 1.0), dv)
    for i in range(dv.size):
        out[i + 1] = out[i] * decay[i] + gain[i]
    return out


def _march(zt: np.ndarray, g0t: np.ndarray, i2: np.ndarray, mass: np.ndarray, ydet: float, edges: np.ndarray,
           c: float, rho: float, zs_late: np.ndarray) -> tuple[dict, float, float]:
    """Backward-Euler march over the nodes ``zt`` in the frame ``y = g - g0 - y_det``.

    ``y_det`` is the repulsion's deterministic push, advanced per step exactly for ``g0`` linear in the step:
    ``exp(y_det'/rho) = exp(y_det/rho) + (c/rho) dz phi exp(-g0_k/rho)``. With ``u = (y_det' - y_det)/dz`` the
    drift in the frame is ``u (exp(-y/rho) - 1)``, zero at ``y = 0``: the narrow high-pressure density stays in
    place instead of sweeping across the grid (a moving profile gains the numerical diffusion ``u^2 dz/2`` of
    backward Euler, which made the density 2x too wide). Returns ``({zeta: (density, y_det)}, mass error, edge
    mass)``.
    """
    x = 0.5 * (edges[1:] + edges[:-1])
    h = np.diff(edges)
    delta = np.diff(x)
    n = x.size
    snaps = {}
    mass_err = 0.0
    edge_mass = 0.0
    # node index -> requested zeta (snapshots)
    at = {int(np.argmin(np.abs(zt - zq))): float(zq) for zq in zs_late}
    ones = np.ones(n - 1)
    for k in range(zt.size - 1):
        dz = zt[k + 1] - zt[k]
        dcoef = i2[k] / dz
        # Scharfetter-Gummel flux F = (D/delta) [B(-Pe) P_i - B(Pe) P_{i+1}], in mass variables m = P h
        if c > 0.0:
            dg = (g0t[k + 1] - g0t[k]) / rho
            log_push = math.log(c / rho * dz * float(_phi(dg))) - g0t[k] / rho
            ynew = rho * float(np.logaddexp(ydet / rho, log_push))
            u = (ynew - ydet) / dz
            ydet = ynew
            drift = u * np.expm1(np.minimum(-edges[1:-1] / rho, _EXP_CAP))
            pe = drift * delta / dcoef
            bp = _bernoulli(pe)
            bm = pe + bp  # B(-x) = x + B(x)
        else:
            bp = bm = ones
        cond = dz * dcoef / delta
        right = cond * bm / h[:-1]  # dz x rate i -> i+1 per unit mass in cell i
        left = cond * bp / h[1:]  # dz x rate i+1 -> i per unit mass in cell i+1
        diag = np.ones(n)
        diag[:-1] += right
        diag[1:] += left
        # tridiagonal solve (LAPACK gtsv): lower diagonal -right (column i feeds row i+1), upper -left
        _du2, _d, _du, mass, info = _gtsv(-right, diag, -left, mass, overwrite_b=True)
        tot = mass.sum()
        if info != 0 or not math.isfinite(tot):
            raise FloatingPointError(f"Fokker-Planck step {k} (zeta={zt[k + 1]:.6g}) became non-finite")
        mass_err = max(mass_err, abs(tot - 1.0))
        np.maximum(mass, 0.0, out=mass)  # clears rounding-level negatives only (M-matrix: none beyond that)
        edge_mass = max(edge_mass, float(mass[:2].sum() + mass[-2:].sum()))
        if k + 1 in at:
            snaps[at[k + 1]] = (mass / tot / h, ydet)
    return snaps, mass_err, edge_mass
