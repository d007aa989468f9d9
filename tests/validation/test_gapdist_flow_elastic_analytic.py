"""Gap distributions (docs/model.md M5), leakage (M8) and the free surface's elastic response (M3, free
boundaries) against analytic truths:

* the SDE and the Fokker-Planck solver without repulsion (C2 = 0): the gap is then Gaussian with mean
  ``flat + (H h_rms^2/rho) I`` and variance ``2 C1 I``, ``I = int_1^zeta (eta z/(1 + eta z))^2 z^(-2H-1) dz``,
  with ``I`` from scipy's quadrature here (not from gapsweep.theory);
* the Reynolds solve on a uniform channel (``K = g^3/(12 mu)``) and on a sinusoidal one, along the modulation
  (``<g^-3>^-1``, in closed form) and across it (``<g^3>``);
* the free-boundary compliance (the doubled-grid convolution of gapsweep.gfmd._grid.FreeGrid) under a uniform
  pressure on a square against Love's closed form at its centre and a Gauss-Legendre quadrature of
  Boussinesq's point load ``1/(pi E* r)`` outside it.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy import integrate

from gapsweep import flow
from gapsweep.gapdist import fokker_planck, sde
from gapsweep.gfmd._grid import FreeGrid, boussinesq_pixel

pytestmark = pytest.mark.validation


def shell_integral(eta: float, zeta: float, hurst: float) -> float:
    return integrate.quad(lambda t: (eta * math.exp(t) / (1 + eta * math.exp(t))) ** 2 * math.exp(-2 * hurst * t),
                          0.0, math.log(zeta), epsabs=0, epsrel=1e-12, limit=200)[0]


def gaussian_moments(sigma0: float, p: dict) -> tuple[float, float]:
    """Mean and variance of the C2 = 0 gap (M5) with the default ``C1 = H h_rms^2``."""
    eta = p["rho"] * (2 * math.pi / p["lambda_l"]) * p.get("e_star", 1.0) / (2 * sigma0)
    i = shell_integral(eta, p["lambda_l"] / p["lambda_s"], p["hurst"])
    c1 = p["hurst"] * p["h_rms"] ** 2
    mean = p["rho"] * math.log(p["gamma0"] / (p["rho"] * sigma0)) + c1 * i / p["rho"]
    return mean, 2 * c1 * i


# model units (the paper's set, M6) and nm/GPa (a 10 um roll-off, 100 nm cut-off, h_rms 50 nm, E* 100 GPa)
SETS = {
    "model": dict(h_rms=0.01, rho=2e-3, gamma0=1e-3, lambda_l=0.25, lambda_s=2.5e-3, e_star=1.0),
    "GPa_nm": dict(h_rms=50.0, rho=10.0, gamma0=0.1, lambda_l=1e4, lambda_s=100.0, e_star=100.0),
}


@pytest.mark.parametrize("units", sorted(SETS))
@pytest.mark.parametrize("hurst", [0.3, 0.8])
@pytest.mark.parametrize("eta", [1e-3, 1.0, 1e3])
@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_sde_without_repulsion_is_gaussian(units: str, hurst: float, eta: float, dtype: str) -> None:
    """20 000 realisations: the sample mean within 5 standard errors of the analytic mean, the sample variance
    within 5 standard errors (``var sqrt(2/n)``) of ``2 C1 I`` (a 5-sigma Monte-Carlo bound; float32 adds
    ~1e-7 relative). The step size is irrelevant without repulsion (exact shell integrals), so dzeta = 0.5."""
    p = dict(SETS[units], hurst=hurst)
    sigma0 = p["rho"] * (2 * math.pi / p["lambda_l"]) * p["e_star"] / (2 * eta)
    mean, var = gaussian_moments(sigma0, p)
    n = 20_000
    g = sde.gap_samples(sigma0, n=n, dzeta=0.5, steps="log", seed=5, dtype=dtype, **p)
    assert abs(float(g.mean()) - mean) <= 5 * math.sqrt(var / n)
    assert abs(float(g.var()) - var) <= 5 * var * math.sqrt(2.0 / n)


@pytest.mark.parametrize("units", sorted(SETS))
@pytest.mark.parametrize("hurst", [0.2, 0.5, 0.9])
@pytest.mark.parametrize("eta", [1e-3, 0.1, 10.0, 1e4])
def test_fokker_planck_without_repulsion_is_gaussian(units: str, hurst: float, eta: float) -> None:
    """The Fokker-Planck march without repulsion against the analytic Gaussian: mean within 1e-3 standard
    deviations, variance within 1e-2 relative (backward Euler in zeta is first order; the solver's own step
    control targets 1e-2 of the standard deviation), mass conserved to 1e-12."""
    p = dict(SETS[units], hurst=hurst)
    sigma0 = p["rho"] * (2 * math.pi / p["lambda_l"]) * p["e_star"] / (2 * eta)
    mean, var = gaussian_moments(sigma0, p)
    r = fokker_planck.solve(sigma0, n_steps=800, **p)
    assert r.status == "ok" and r.mass_error < 1e-12
    assert r.mean() == pytest.approx(mean, abs=1e-3 * math.sqrt(var))
    assert r.variance() == pytest.approx(var, rel=1e-2, abs=0)


UNITS_FLOW = {"model": (1.0, 1.0, 1e-2), "SI": (1e-3, 2e-3, 5e-6)}  # (length, viscosity, gap): SI: 1 mm, water


@pytest.mark.parametrize("units", sorted(UNITS_FLOW))
@pytest.mark.parametrize("axis", [0, 1])
@pytest.mark.parametrize("periodic", [True, False])
@pytest.mark.parametrize(("nx", "ny"), [(17, 17), (24, 40)])
def test_uniform_channel(units: str, axis: int, periodic: bool, nx: int, ny: int) -> None:
    """A uniform gap: ``K = g^3/(12 mu)`` and the leak rate ``K dp / L`` (plane Poiseuille flow). Tolerance
    1e-9 relative (direct sparse solve)."""
    length, mu, g = UNITS_FLOW[units]
    lx, ly = length, length * ny / nx
    r = flow.solve(np.full((nx, ny), g), length=(lx, ly), axis=axis, viscosity=mu, pressure_drop=3.0,
                   periodic=periodic)
    k = g**3 / (12 * mu)
    assert r.converged and r.percolating
    assert r.conductance == pytest.approx(k, rel=1e-9, abs=0)
    assert r.leak_rate == pytest.approx(k * 3.0 / (lx, ly)[axis], rel=1e-9, abs=0)


def sinus_gap(n: int, across: int, g0: float, e: float, along_flow: bool, axis: int) -> np.ndarray:
    """``g0 (1 + e cos(2 pi x / L))`` at the cell centres, varying along the flow axis or across it."""
    x = (np.arange(n) + 0.5) / n
    prof = g0 * (1 + e * np.cos(2 * np.pi * x))
    vary_axis = axis if along_flow else 1 - axis
    shape = [0, 0]
    shape[vary_axis], shape[1 - vary_axis] = n, across
    return np.broadcast_to(prof.reshape((-1, 1) if vary_axis == 0 else (1, -1)), shape).copy()


@pytest.mark.parametrize("units", sorted(UNITS_FLOW))
@pytest.mark.parametrize("e", [0.2, 0.5, 0.9])
@pytest.mark.parametrize("axis", [0, 1])
@pytest.mark.parametrize("n", [33, 64])
def test_sinusoidal_channel_along_the_flow(units: str, e: float, axis: int, n: int) -> None:
    """A gap modulated along the flow: the cells are in series, so the scheme's ``K`` is exactly
    ``<1/k_i>^-1`` over the cells (two half cells per face, docs/model.md M8), tolerance 1e-9; and that tends to
    the continuum ``<(1 + e cos)^-3>^-1 g0^3/(12 mu)`` with ``<(1 + e cos)^-3> = (2 + e^2) / (2 (1 - e^2)^(5/2))``:
    the midpoint rule of a periodic analytic function converges geometrically, tolerance 1e-4 (measured
    3.6e-5 at e = 0.9 on 33 cells, below 1e-10 in every other case)."""
    length, mu, g0 = UNITS_FLOW[units]
    gap = sinus_gap(n, 5, g0, e, True, axis)
    r = flow.solve(gap, length=length, axis=axis, viscosity=mu, pressure_drop=1.0)
    cells = np.take(gap, 0, axis=1 - axis)
    assert r.conductance == pytest.approx(1.0 / float(np.mean(12 * mu / cells**3)), rel=1e-9, abs=0)
    k = g0**3 / (12 * mu) * 2 * (1 - e * e) ** 2.5 / (2 + e * e)
    assert r.conductance == pytest.approx(k, rel=1e-4, abs=0)


@pytest.mark.parametrize("units", sorted(UNITS_FLOW))
@pytest.mark.parametrize("e", [0.3, 0.95])
@pytest.mark.parametrize("axis", [0, 1])
@pytest.mark.parametrize("periodic", [True, False])
def test_sinusoidal_channel_across_the_flow(units: str, e: float, axis: int, periodic: bool) -> None:
    """A gap modulated across the flow: parallel channels, ``K = <k> = g0^3 (1 + 3 e^2/2) / (12 mu)`` (the
    mean of ``(1 + e cos)^3``; exact on >= 4 cells a period). Tolerance 1e-9."""
    length, mu, g0 = UNITS_FLOW[units]
    gap = sinus_gap(32, 7, g0, e, False, axis)
    r = flow.solve(gap, length=length, axis=axis, viscosity=mu, pressure_drop=1.0, periodic=periodic)
    assert r.conductance == pytest.approx(g0**3 * (1 + 1.5 * e * e) / (12 * mu), rel=1e-9, abs=0)


@pytest.mark.parametrize("axis", [0, 1])
@pytest.mark.parametrize("row", [0, 7, 15])
def test_a_sealed_line_stops_the_leak(axis: int, row: int) -> None:
    """One line of contact across the flow seals it: leak rate exactly 0, not percolating (the exact answer)."""
    gap = np.full((16, 16), 1e-2)
    if axis == 1:
        gap[:, row] = 0.0
    else:
        gap[row, :] = 0.0
    r = flow.solve(gap, axis=axis)
    assert not r.percolating and r.leak_rate == 0.0


def free_displacement(m: int, nx: int, ny: int, dx: float, e_star: float) -> tuple[np.ndarray, slice, slice]:
    """The free surface's displacement under a unit pressure on an m x m block of pixels centred in the map."""
    grid = FreeGrid((nx, ny), (nx * dx, ny * dx), "numpy", None, False)
    p = np.zeros((nx, ny))
    sx = slice((nx - m) // 2, (nx - m) // 2 + m)
    sy = slice((ny - m) // 2, (ny - m) // 2 + m)
    p[sx, sy] = 1.0
    return grid.compliance(e_star)(p), sx, sy


@pytest.mark.parametrize(("m", "nx", "ny"), [(5, 31, 31), (9, 41, 27), (15, 45, 45)])
@pytest.mark.parametrize(("dx", "e_star"), [(1.0, 1.0), (10.0, 70.0)])
def test_free_compliance_under_a_uniform_square(m: int, nx: int, ny: int, dx: float, e_star: float) -> None:
    """Love (1929): the centre of a square of side ``2a`` under a uniform pressure ``p`` sinks by
    ``8 a p ln(1 + sqrt 2) / (pi E*)``; at points outside, the displacement is the point load's
    ``1/(pi E* r)`` integrated over the square (Gauss-Legendre, 40 x 40 nodes per pixel row of the square: exact
    to ~1e-10 at a pixel's distance). Tolerance 1e-9 relative at both (the pixel kernel is the exact integral;
    what is tested is the doubled-grid convolution)."""
    u, sx, sy = free_displacement(m, nx, ny, dx, e_star)
    a = m * dx / 2
    cx, cy = (sx.start + sx.stop - 1) // 2, (sy.start + sy.stop - 1) // 2
    assert float(u[cx, cy]) == pytest.approx(8 * a * math.log(1 + math.sqrt(2)) / (math.pi * e_star), rel=1e-9, abs=0)
    xg, wg = np.polynomial.legendre.leggauss(40)
    # nodes on each pixel of the square separately (the integrand is smooth on each), in units of dx from centre
    centres = (np.arange(m) - (m - 1) / 2) * dx
    xs = (centres[:, None] + 0.5 * dx * xg[None, :]).ravel()
    ws = np.tile(0.5 * dx * wg, m)
    for ix, iy in ((0, 0), (nx - 1, ny - 1), (sx.stop + 1, cy), (cx, sy.start - 2), (sx.stop, sy.stop)):
        px, py = (ix - cx) * dx, (iy - cy) * dx
        r = np.hypot(px - xs[:, None], py - xs[None, :])
        quad = float(np.sum(ws[:, None] * ws[None, :] / (math.pi * e_star * r)))
        assert float(u[ix, iy]) == pytest.approx(quad, rel=1e-9, abs=0), (ix, iy)


@pytest.mark.parametrize(("a", "b"), [(0.5, 0.5), (0.5, 2.0), (3.0, 0.25)])
@pytest.mark.parametrize(("px", "py"), [(0.0, 0.0), (0.3, -0.2), (1.5, 0.0), (-2.0, 3.0), (7.0, 11.0), (40.0, -25.0)])
def test_pixel_kernel_is_the_integrated_point_load(a: float, b: float, px: float, py: float) -> None:
    """Love's rectangle (gapsweep.gfmd._grid.boussinesq_pixel, ``|x'| <= a, |y'| <= b``) against Boussinesq's
    point load ``1/(pi E* r)`` integrated numerically: the rectangle cut at the field point's coordinates into
    up to four sub-rectangles, each integrated by scipy's adaptive dblquad (the field point then lies at a
    corner of a sub-rectangle or outside it, so the integrable 1/r singularity sits at a corner, where the
    adaptive rule converges). Points inside, on the axes and far away; aspect ratios 1 to 12. Tolerance 1e-8
    relative (dblquad's tolerances 1e-11 on an O(1) integral)."""
    e_star = 2.5
    xs = sorted({-a, a, *([px] if -a < px < a else [])})
    ys = sorted({-b, b, *([py] if -b < py < b else [])})
    total = 0.0
    for x0, x1 in itertools.pairwise(xs):
        for y0, y1 in itertools.pairwise(ys):
            val, _ = integrate.dblquad(lambda y, x: 1.0 / (math.pi * e_star * math.hypot(px - x, py - y)),
                                       x0, x1, y0, y1, epsabs=1e-11, epsrel=1e-11)
            total += val
    assert float(boussinesq_pixel(np.float64(px), np.float64(py), a, b, e_star)) == pytest.approx(total, rel=1e-8,
                                                                                                  abs=0)
