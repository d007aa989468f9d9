"""Deterministic solver of the gap Fokker-Planck equation of docs/model.md M5.

Equation (magnification ``zeta`` as time, gap ``g`` [length])::

    dP/dzeta = -d/dg [a(g, zeta) P] + D2(zeta) d^2P/dg^2,   a = D1(zeta) + C2 (gamma0/rho) exp(-g/rho),

started from a point mass at the flat-surface gap ``g0(1) = rho ln(gamma0/(rho sigma0))``; ``D1``, ``D2`` from
:mod:`gapsweep.theory`. It is the noise-free reference of :mod:`gapsweep.sde` and a fast path on its own.

Numerics:

* Moving frame ``y = g - g0(zeta)`` (``g0`` = field-theory mean gap, M4), which absorbs ``D1`` exactly, so the
  grid only has to hold the spread, not the drift of the mean (which can be many standard deviations).
* Conservative finite volumes on a graded grid in ``y``: cells of ``sd/cells_per_sd`` in the bulk (``sd`` of the
  smallest requested ``zeta``, C2 = 0) and
  ``rho/cells_per_rho`` in the band the repulsive wall sweeps through, growing geometrically in between.
  Domain from the theory: ``+- width_sd`` standard deviations of the C2 = 0 Gaussian, cut below the wall and
  extended above it by the reflected tail.
* Scharfetter-Gummel (exponentially fitted) fluxes, zero flux at both ends, backward Euler in ``zeta``: an
  M-matrix, so the density stays positive and the mass is conserved to rounding whatever the step. Per step the
  diffusion is ``int D2 / dzeta`` (Gauss-Legendre) and the repulsion ``c <exp(-g0/rho)>_step exp(-y/rho)``
  (exponent capped at 300: faster than any step can resolve, so nothing physical changes and nothing overflows).
* Steps equidistant in ``s(zeta) = V(zeta)/(2 V_end) + ln(zeta)/(2 ln zeta_end)`` (``V = 2 int D2``): short where
  the variance grows fastest, with the requested magnifications inserted as nodes. Start at the ``zeta`` where
  the spread reaches two cells, from the Gaussian there (exact for C2 = 0).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_banded
from scipy.special import ndtr

from gapsweep import _checks as chk
from gapsweep import theory
from gapsweep.sde import _check_common, _interval_integrals

__all__ = ["FPResult", "solve"]

_EXP_CAP = 300.0


@dataclass
class FPResult:
    """Solution of the M5 Fokker-Planck equation at the requested magnifications.

    ``zetas`` (n_zeta,), ``g0`` (n_zeta,) field-theory mean gaps [length], ``y_edges``/``y`` (n_cells+1 /
    n_cells) cell edges/centres of the moving frame ``y = g - g0``, ``density`` (n_zeta, n_cells) cell averages
    [1/length], each integrating to 1. ``g`` (n_zeta, n_cells) are the cell centres in ``g`` at each ``zeta``
    (the grid moves with ``g0``). ``status`` is "ok" or "domain_too_small" (more than ``edge_tol`` of the mass in
    the outermost cells); ``mass_error`` is the largest ``|sum P dy - 1|`` seen.
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

    @property
    def y(self) -> np.ndarray:
        return 0.5 * (self.y_edges[1:] + self.y_edges[:-1])

    @property
    def g(self) -> np.ndarray:
        return self.g0[:, None] + self.y[None, :]

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
        return float(self.g0[i] + np.sum(self.y * self.density[i] * self.widths))

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
        return np.interp(np.asarray(g, dtype=float) - self.g0[i], self.y_edges, c, left=0.0, right=c[-1])

    def bin_density(self, edges: np.ndarray, zeta: float | None = None) -> np.ndarray:
        """Average density over the bins ``edges`` [length] (comparable with a histogram on those edges)."""
        edges = np.asarray(edges, dtype=float)
        return np.diff(self.cdf(edges, zeta)) / np.diff(edges)


def _graded_grid(lo: float, hi: float, h_coarse: float, h_fine: float, band: tuple[float, float] | None,
                 grading: float, max_cells: int) -> np.ndarray:
    """Edges from ``lo`` to ``hi``: width ``h_fine`` inside ``band``, growing by ``grading`` up to ``h_coarse``."""
    if band is None or h_fine >= h_coarse:
        n = max(int(math.ceil((hi - lo) / h_coarse)), 8)
        if n > max_cells:
            raise ValueError(f"grid needs {n} cells (> max_cells={max_cells}); lower cells_per_sd")
        return np.linspace(lo, hi, n + 1)
    b0, b1 = band
    edges = [lo]
    y = lo
    while y < hi:
        dist = max(b0 - y, y - b1, 0.0)
        # geometric growth away from the band: width h_f + (grading - 1) * distance
        h = min(h_coarse, h_fine + (grading - 1.0) * dist)
        y = y + h
        edges.append(y)
        if len(edges) > max_cells + 1:
            raise ValueError(f"grid needs more than max_cells={max_cells} cells; lower cells_per_rho")
    e = np.asarray(edges)
    return lo + (e - lo) * (hi - lo) / (e[-1] - lo)


def _bernoulli(x: np.ndarray) -> np.ndarray:
    """``B(x) = x/(e^x - 1)`` (B(0) = 1), stable for x >= 0 (overflow gives 0 correctly)."""
    out = np.ones_like(x)
    nz = x > 1e-12
    with np.errstate(over="ignore"):
        out[nz] = x[nz] / np.expm1(x[nz])
    small = ~nz
    out[small] = 1.0 - 0.5 * x[small]
    return out


def solve(sigma0: float, *, hurst: float, h_rms: float, rho: float, gamma0: float, lambda_l: float,
          lambda_s: float, e_star: float = 1.0, zetas: float | np.ndarray | None = None,
          c1: float | None = None, c2: float = 0.0, n_steps: int = 400, cells_per_sd: float = 40.0,
          cells_per_rho: float = 4.0, width_sd: float = 8.0, grading: float = 1.08, max_cells: int = 200_000,
          edge_tol: float = 1e-7) -> FPResult:
    """Solve the M5 Fokker-Planck equation for the gap density at the magnifications ``zetas``.

    ``zetas=None``: ``[zeta_s]`` with ``zeta_s = lambda_l/lambda_s``; ``c1=None``: ``C1 = H h_rms^2``. ``n_steps``
    backward-Euler steps in total (plus the requested nodes). Grid controls: ``cells_per_sd`` (bulk cells per
    final standard deviation), ``cells_per_rho`` (cells per ``rho`` near the wall), ``width_sd``, ``grading``.
    Lengths in the model's units (M1). Needs ``2 int D2 > 0`` (``h_rms > 0`` and ``C1 > 0``).
    """
    t_start = time.perf_counter()
    zs = np.atleast_1d(np.asarray(lambda_l / lambda_s if zetas is None else zetas, dtype=float))
    if zs.ndim != 1 or zs.size == 0 or not np.all(np.isfinite(zs)):
        raise ValueError(f"zetas must be finite magnifications >= 1, got {zetas!r}")
    if np.any(zs < 1.0):
        raise ValueError(f"zetas must be >= 1 (magnification), got {zs.tolist()}")
    zs = np.unique(zs)
    p = _check_common(sigma0, hurst, h_rms, rho, gamma0, lambda_l, lambda_s, e_star, float(zs[-1]), c1, c2)
    n_steps = chk.count(n_steps, "n_steps")
    cells_per_sd = chk.positive(cells_per_sd, "cells_per_sd")
    cells_per_rho = chk.positive(cells_per_rho, "cells_per_rho")
    width_sd = chk.positive(width_sd, "width_sd")
    grading = chk.positive(grading, "grading")
    if not grading > 1.0:
        raise ValueError(f"grading must be > 1, got {grading!r}")
    max_cells = chk.count(max_cells, "max_cells", minimum=8)
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
    sd = np.sqrt(va)
    sd_end = math.sqrt(v_end)
    c = p["c2"] * p["gamma0"] / rho_

    # Domain and grid in y.
    lo, hi, band = -width_sd * sd_end, width_sd * sd_end, None
    if c > 0.0:
        with np.errstate(divide="ignore"):
            yw = rho_ * np.log(c * (za - 1.0) / rho_) - ga  # deterministic repulsion floor, y frame
        margin = rho_ * (25.0 + 2.0 * math.log1p(sd_end / rho_))
        relevant = yw > -width_sd * sd - margin
        lower = np.maximum(-width_sd * sd, yw - margin)
        upper = width_sd * sd + np.maximum(0.0, 2.0 * yw)
        lo = float(np.min(lower))
        hi = float(np.max(upper))
        if np.any(relevant):
            band = (float(np.min(yw[relevant])) - margin, float(np.max(yw[relevant])) + 10.0 * rho_)
    # bulk cells resolve the narrowest requested density (smallest zeta), within half the cell budget
    sd_min = math.sqrt(float(np.interp(zs[0], za, va))) if zs[0] > 1.0 else sd_end
    h_bulk = max(min(sd_min, sd_end) / cells_per_sd, 2.0 * (hi - lo) / max_cells)
    edges = _graded_grid(lo, hi, h_bulk, rho_ / cells_per_rho, band, grading, max_cells)
    x = 0.5 * (edges[1:] + edges[:-1])
    h = np.diff(edges)
    delta = np.diff(x)
    n = x.size

    # Start where the C2 = 0 spread is two cells wide at y = 0 (the initial point mass sits there).
    h0 = float(h[np.clip(np.searchsorted(edges, 0.0) - 1, 0, n - 1)])
    z0 = float(np.interp(min((2.0 * h0) ** 2, 0.5 * v_end), va, za))
    z0 = min(z0, float(zs[0])) if zs[0] > 1.0 else z0
    z0 = max(z0, 1.0 + 1e-12 * zeta_end)

    # Time nodes equidistant in s(z), with the requested zetas inserted.
    s_a = 0.5 * va / v_end + 0.5 * np.log(za) / math.log(zeta_end)
    s0 = float(np.interp(z0, za, s_a))
    zt = np.interp(np.linspace(s0, 1.0, n_steps + 1), s_a, za)
    zt = np.unique(np.concatenate((zt, zs[zs > z0], [z0])))
    zt = zt[zt >= z0]
    zt[-1] = zeta_end
    i1 = _interval_integrals(d1, zt[:-1], zt[1:])
    i2 = _interval_integrals(d2, zt[:-1], zt[1:])
    # exact (quadrature) values at z0, not interpolated from the auxiliary grid
    g0_z0 = flat + float(_interval_integrals(d1, np.array([1.0]), np.array([z0]))[0])
    g0t = g0_z0 + np.concatenate(([0.0], np.cumsum(i1)))
    v0 = 2.0 * float(_interval_integrals(d2, np.array([1.0]), np.array([z0]))[0])

    # Initial Gaussian N(m0, v0), cell-averaged (m0: the repulsion's push at y = 0 over [1, z0]).
    m0 = rho_ * math.log1p(p["c2"] * p["sigma0"] * (z0 - 1.0) / rho_) if c > 0.0 else 0.0
    cdf = ndtr((edges - m0) / math.sqrt(v0))
    mass = np.diff(cdf)
    mass /= mass.sum()

    def snapshot_density(m):
        return m / h

    out = {}
    for zq in zs:
        if zq <= z0:  # before the first step: the Gaussian (C2 = 0 exact), shifted by the push at y=0
            vq = float(np.interp(zq, za, va))
            mq = rho_ * math.log1p(p["c2"] * p["sigma0"] * (zq - 1.0) / rho_) if c > 0.0 else 0.0
            out[zq] = np.diff(ndtr((edges - mq) / math.sqrt(vq))) / h if vq > 0 else None
    if any(v is None for v in out.values()):
        raise ValueError("zetas must be > 1 (at zeta = 1 the density is a point mass)")

    mass_err = 0.0
    edge_mass = 0.0
    ab = np.zeros((3, n))
    for k in range(zt.size - 1):
        dz = zt[k + 1] - zt[k]
        dcoef = i2[k] / dz
        # Scharfetter-Gummel flux F = (D/delta) [B(-Pe) P_i - B(Pe) P_{i+1}], in mass variables m = P h
        if c > 0.0:
            dg = (g0t[k + 1] - g0t[k]) / rho_
            phi = 1.0 if dg < 1e-12 else -math.expm1(-dg) / dg  # <exp(-(g0 - g0_k)/rho)> over the step
            log_a = math.log(c * phi) - g0t[k] / rho_ - edges[1:-1] / rho_
            pe = np.exp(np.minimum(log_a, _EXP_CAP)) * delta / dcoef
        else:
            pe = np.zeros(n - 1)
        bp = _bernoulli(pe)
        bm = pe + bp  # B(-x) = x + B(x)
        cond = dcoef / delta
        right = cond * bm / h[:-1]  # rate i -> i+1 per unit mass in cell i
        left = cond * bp / h[1:]  # rate i+1 -> i per unit mass in cell i+1
        ab[1, :] = 1.0
        ab[1, :-1] += dz * right
        ab[1, 1:] += dz * left
        ab[0, 1:] = -dz * left  # upper diagonal: column i+1 feeds row i
        ab[2, :-1] = -dz * right  # lower diagonal: column i feeds row i+1
        mass = solve_banded((1, 1), ab, mass, overwrite_ab=False, overwrite_b=True, check_finite=False)
        tot = mass.sum()
        if not math.isfinite(tot):
            raise FloatingPointError(f"Fokker-Planck step {k} (zeta={zt[k + 1]:.6g}) became non-finite")
        mass_err = max(mass_err, abs(tot - 1.0))
        np.maximum(mass, 0.0, out=mass)  # clears rounding-level negatives only (M-matrix: none beyond that)
        edge_mass = max(edge_mass, float(mass[:2].sum() + mass[-2:].sum()))
        zq = zt[k + 1]
        if np.any(np.isclose(zs, zq, rtol=1e-12, atol=0.0)):
            out[float(zs[np.argmin(np.abs(zs - zq))])] = snapshot_density(mass / tot)
    dens = np.vstack([out[float(zq)] for zq in zs])
    g0z = np.interp(zs, za, ga)
    g0z[zs >= z0] = np.interp(zs[zs >= z0], zt, g0t)
    var0 = np.interp(zs, za, va)
    status = "ok" if edge_mass <= edge_tol else "domain_too_small"
    return FPResult(zetas=zs, g0=g0z, y_edges=edges, density=dens, n_steps=zt.size - 1, mass_error=mass_err,
                    edge_mass=edge_mass, status=status, wall_time=time.perf_counter() - t_start,
                    variance_c2_0=var0)
