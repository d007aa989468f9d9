"""The smooth laws and the challenge's law against analytic results (docs/gfmd.md "Interaction laws",
docs/model.md M3, M3b, "Elastic layer on a rigid base"):

* one small mode under a smooth law is linear: ``u~ = h~ / (1 + k(q) / s)`` with the body's stiffness ``k(q)``
  (half-space ``E* q / 2``; a layer ``(E* q / 2) f(q t)``, f written out in tests/validation/test_contact_analytic)
  and the law's local stiffness ``s = -p'(g0)`` at the flat mean gap ``g0`` (``p(g0) = sigma0``, solved here by
  brentq): the exponential law on layers (``s = sigma0 / rho``), the adhesive (Rose-Smith-Ferrante) law at
  compressive and tensile loads;
* the challenge's hard wall with adhesion in the JKR limit (range a few pixels, Johnson's alpha 0.2-0.3) against
  Johnson's adhesive wave (gapsweep.reference.johnson_wavy_adhesion);
* the exponential law with the coarse-to-fine start converging to Westergaard's hard-wall contact as rho -> 0.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from gapsweep.gfmd import solve
from gapsweep.reference import johnson_wavy_adhesion, westergaard

from .test_contact_analytic import layer_factor

pytestmark = pytest.mark.validation


def wave(n: int, ny: int, amp: float, lam: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    x = np.arange(n) * (lam / n)
    return np.repeat((amp * np.cos(2 * np.pi * x / lam))[:, None], ny, axis=1), x


def first_mode(u: np.ndarray, x: np.ndarray, lam: float) -> float:
    return 2 * float(np.mean(u[:, 0] * np.cos(2 * np.pi * x / lam)))


@pytest.mark.parametrize("bottom", ["bonded", "slip"])
@pytest.mark.parametrize("nu", [0.2, 0.45])
@pytest.mark.parametrize("qt", [0.1, 1.0, 5.0])
@pytest.mark.parametrize("ratio", [0.1, 1.0, 10.0])
def test_exponential_on_a_layer_linear_response(bottom: str, nu: float, qt: float, ratio: float) -> None:
    """The exponential law on a layer, one mode with amp/rho = 1e-3: ``u = amp / (1 + k(q) rho / sigma0)`` with
    ``k(q) rho / sigma0 = ratio``, and the mean gap ``rho ln(gamma0/(rho sigma0)) + (amp - u)^2 / (4 rho)``.
    Tolerances: 1e-5 relative on the amplitude (the O((amp/rho)^2) = 1e-6 nonlinearity and the solver
    tolerance), 1e-9 rho on the mean gap (next term O((amp/rho)^4) rho). 48 x 48 grid (the softmax minimiser)."""
    n, lam, amp, rho, gamma0, e_star = 48, 1.0, 5e-5, 0.05, 1e-3, 1.0
    q = 2 * math.pi / lam
    k = e_star * q / 2 * layer_factor(qt, nu, bottom)
    sigma0 = k * rho / ratio
    h, x = wave(n, n, amp, lam)
    r = solve(h, sigma0=sigma0, gamma0=gamma0, rho=rho, e_star=e_star, thickness=qt / q, poisson=nu, bottom=bottom,
              tol=1e-10)
    assert r.converged
    u_amp = amp / (1 + ratio)
    assert first_mode(r.displacement, x, lam) == pytest.approx(u_amp, rel=1e-5, abs=0)
    g0 = rho * math.log(gamma0 / (rho * sigma0)) + (amp - u_amp) ** 2 / (4 * rho)
    assert r.mean_gap == pytest.approx(g0, abs=1e-9 * rho)


def rsf_pressure(g: float, w: float, rho: float) -> float:
    """Rose-Smith-Ferrante: ``p(g) = -(w g / rho^2) exp(-g / rho)`` (written out here)."""
    return -(w * g / rho**2) * math.exp(-g / rho)


@pytest.mark.parametrize("load", [-0.3, -0.05, 0.2, 2.0])  # sigma0 in units of the largest tension w/(e rho)
@pytest.mark.parametrize("ratio", [0.3, 3.0])
@pytest.mark.parametrize(("nx", "ny"), [(40, 40), (45, 24)])
def test_adhesive_law_linear_response(load: float, ratio: float, nx: int, ny: int) -> None:
    """The adhesive law, one mode with amp/rho = 1e-3, compressive and tensile loads (up to 0.3 of the largest
    tension): the flat gap ``g0`` solves ``p(g0) = sigma0`` on the stable side (``g0 < rho``), the local
    stiffness is ``s = -p'(g0)``, and ``u = amp / (1 + (E* q / 2) / s)``; ``E*`` is chosen so that
    ``(E* q/2)/s = ratio``. Tolerances: amplitude 1e-4 relative (the O(amp/rho) = 1e-3 curvature of the law
    moves the mean gap, and with it s, at second order), mean gap within 1e-5 rho of g0 (its shift is
    O((amp/rho)^2) rho)."""
    lam, rho, w = 1.0, 0.05, 1e-3
    amp = 1e-3 * rho
    tmax = w / (math.e * rho)
    sigma0 = load * tmax
    g0 = brentq(lambda g: rsf_pressure(g, w, rho) - sigma0, -20 * rho, rho)
    s = (w / rho**2) * (1 - g0 / rho) * math.exp(-g0 / rho)  # -p'(g0)
    q = 2 * math.pi / lam
    e_star = 2 * ratio * s / q
    h, x = wave(nx, ny, amp, lam)
    r = solve(h, sigma0=sigma0, interaction="adhesive", work=w, rho=rho, e_star=e_star, length=(lam, lam * ny / nx),
              tol=1e-10)
    assert r.converged
    assert first_mode(r.displacement, x, lam) == pytest.approx(amp / (1 + ratio), rel=1e-4, abs=0)
    assert r.mean_gap == pytest.approx(g0, abs=1e-5 * rho)


@pytest.mark.parametrize("alpha", [0.2, 0.3])
@pytest.mark.parametrize("frac", [0.1, 0.0, -0.05])
def test_hard_wall_adhesive_is_johnson_in_the_jkr_limit(alpha: float, frac: float) -> None:
    """The challenge's law with range rho = 2 dx on a wave of amplitude 0.05 lam (n = 1024: Tabor-like parameter
    large, the JKR limit of Johnson 1995): at ``pbar = frac p*`` (compressive, zero and tensile loads, the
    default continuation from zero load) the contact width is Johnson's ``2 a`` within 16 pixels (the process
    zone of a few rho at each edge; measured up to 12 pixels, as the adhesive law's test in tests/test_contact.py
    allows)."""
    n, lam, amp = 1024, 1.0, 0.05
    pstar = math.pi * amp / lam
    work = alpha**2 * math.pi**2 * amp**2 / (2 * lam)  # Johnson's alpha^2 = 2 lam w / (pi^2 E* D^2)
    curve = johnson_wavy_adhesion(alpha)
    assert frac > curve.pull_off
    h, _ = wave(n, 2, amp, lam)
    r = solve(h, sigma0=frac * pstar, interaction="hard_wall_adhesive", work=work, rho=2 * lam / n,
              length=(lam, 2 * lam / n), tol=1e-9, backend="numpy", max_iter=50000)
    assert r.converged
    psi = curve.half_width(frac)
    assert abs(r.contact_area - 2 * psi / math.pi) <= 16 / n


# (L, rho, gamma0, e_star): model units; nm with GPa (a 1 um box, a 50 nm range, E* = 100 GPa)
UNITS = {"model": (1.0, 0.05, 1e-3, 1.0), "GPa_nm": (1000.0, 50.0, 5.0, 100.0)}


@pytest.mark.parametrize("units", sorted(UNITS))
@pytest.mark.parametrize(("nx", "ny"), [(32, 32), (33, 33), (40, 24)])
@pytest.mark.parametrize(("kx", "ky"), [(1, 0), (0, 1), (1, 1), (2, 3)])
@pytest.mark.parametrize("eta", [0.2, 5.0])
def test_exponential_one_mode_linear_response(units: str, nx: int, ny: int, kx: int, ky: int, eta: float) -> None:
    """The exponential law (M3) on one mode ``amp cos(q.r)`` of any direction, on square, odd and rectangular
    grids (the softmax and the generic minimisers), model units and nm/GPa: ``u = amp / (1 + eta)`` with
    ``eta = rho |q| E* / (2 sigma0)`` (M4's linear response, exact as amp/rho -> 0; amp/rho = 1e-3 here) and the
    mean gap ``rho ln(gamma0/(rho sigma0)) + (amp - u)^2 / (4 rho)``. Tolerances: 1e-5 relative on the
    amplitude, 1e-9 rho on the mean gap (next terms O((amp/rho)^2) and O((amp/rho)^4) rho)."""
    length, rho, gamma0, e_star = UNITS[units]
    lx, ly = length, length * ny / nx
    q = 2 * math.pi * math.hypot(kx / lx, ky / ly)
    sigma0 = rho * q * e_star / (2 * eta)
    amp = 1e-3 * rho
    x = (np.arange(nx) * lx / nx)[:, None]
    y = (np.arange(ny) * ly / ny)[None, :]
    phase = 2 * math.pi * (kx * x / lx + ky * y / ly)
    h = amp * np.cos(phase)
    r = solve(h, sigma0=sigma0, gamma0=gamma0, rho=rho, e_star=e_star, length=(lx, ly), tol=1e-10)
    assert r.converged
    u_amp = 2 * float(np.mean(r.displacement * np.cos(phase)))
    assert u_amp == pytest.approx(amp / (1 + eta), rel=1e-5, abs=0)
    g0 = rho * math.log(gamma0 / (rho * sigma0)) + (amp - amp / (1 + eta)) ** 2 / (4 * rho)
    assert r.mean_gap == pytest.approx(g0, abs=1e-9 * rho)


@pytest.mark.parametrize("frac", [0.3, 0.5, 0.8])
def test_exponential_coarse_start_tends_to_westergaard(frac: float) -> None:
    """As its range rho -> 0 the exponential law is the hard wall (M3): with the coarse-to-fine start on a
    512 x 512 grid (a wave of amplitude 0.05 lam, ``gamma0 = pbar rho``, so that ``p(0) = pbar``), rho from 8 to
    1 pixel, the rms pressure error against Westergaard (relative to pbar) falls by a factor within
    [0.5, 0.75] at each halving of rho (the soft wall rounds the square-root edges over a width of order rho;
    measured 0.60-0.66) and stays below ``2 sqrt(rho/a)`` (measured at most 1.9)."""
    n, lam, amp = 512, 1.0, 0.05
    pbar = frac * math.pi * amp / lam
    h, x = wave(n, n, amp, lam)
    a, p_exact = westergaard(x, pbar, amp, 1.0, lam)
    errors = []
    for pixels in (8, 4, 2, 1):
        rho = pixels * lam / n
        r = solve(h, sigma0=pbar, gamma0=pbar * rho, rho=rho, tol=1e-8, start="coarse")
        assert r.converged and r.diagnostics["levels"]
        err = float(np.sqrt(np.mean((r.pressure[:, 0] - p_exact) ** 2))) / pbar
        assert err <= 2 * math.sqrt(rho / a)
        errors.append(err)
    ratios = np.array(errors[1:]) / np.array(errors[:-1])
    assert np.all((ratios >= 0.5) & (ratios <= 0.75)), ratios
