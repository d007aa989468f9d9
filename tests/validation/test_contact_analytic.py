"""Hard-wall contact against closed-form solutions (docs/model.md M3, docs/gfmd.md; gapsweep.reference): the
sinusoid in full contact (pressure ``pbar + p* cos``), Westergaard's partial contact, Hertz on a free map, the
pressure cap (plastic) in its elastic and rigid-plastic limits, the elastic layer's stiffness written out here
from Carbone & Mangialardi (2008) rather than taken from gapsweep.gfmd.substrates, and the challenge's hard wall
with adhesion in full contact. Odd, even and rectangular grids, waves along either axis, model units and
GPa/nm. Every case is small (a few ms to ~0.3 s)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gapsweep.gfmd import solve
from gapsweep.reference import hertz, westergaard

pytestmark = pytest.mark.validation

# (e_star, lam, amp): model units, and GPa with nm (E* = 100 GPa, wavelength 2 um, amplitude 20 nm: slope 0.06)
UNITS = {"model": (1.0, 1.0, 0.01), "GPa_nm": (100.0, 2000.0, 20.0)}


def wave(n: int, width: int, amp: float, lam: float, axis: int) -> tuple[np.ndarray, np.ndarray, tuple]:
    """``amp cos(2 pi x / lam)`` on ``n`` pixels along ``axis``, extruded over ``width`` pixels across, its
    coordinate and the box lengths."""
    x = np.arange(n) * (lam / n)
    h = np.repeat((amp * np.cos(2 * np.pi * x / lam))[:, None], width, axis=1)
    length = (lam, width * lam / n)
    if axis == 1:
        return h.T.copy(), x, length[::-1]
    return h, x, length


def profile(field: np.ndarray, axis: int) -> np.ndarray:
    return field[:, 0] if axis == 0 else field[0, :]


@pytest.mark.parametrize("units", sorted(UNITS))
@pytest.mark.parametrize("axis", [0, 1])
@pytest.mark.parametrize("n", [31, 64, 101])
@pytest.mark.parametrize("ratio", [1.0, 1.7, 6.0])
def test_sinusoid_in_full_contact(units: str, axis: int, n: int, ratio: float) -> None:
    """At ``pbar >= p* = pi E* amp / lam`` the wave is in full contact: ``p = pbar + p* cos(2 pi x / lam)``
    exactly (Johnson Eq. 13.11 at a = lam/2), mean gap 0, area 1. Tolerance: 1e-8 p* (the solver's tolerance
    1e-10 on the residual, relative to pbar up to 6 p*, with margin for the pressure's pointwise error)."""
    e_star, lam, amp = UNITS[units]
    pstar = math.pi * e_star * amp / lam
    h, x, length = wave(n, 3, amp, lam, axis)
    r = solve(h, sigma0=ratio * pstar, interaction="hard_wall", e_star=e_star, length=length, tol=1e-10,
              backend="numpy")
    assert r.converged and r.contact_area == 1.0
    assert abs(r.mean_gap) <= 1e-8 * amp
    exact = ratio * pstar + pstar * np.cos(2 * np.pi * x / lam)
    np.testing.assert_allclose(profile(r.pressure, axis), exact, rtol=0, atol=1e-8 * pstar)


@pytest.mark.parametrize("units", sorted(UNITS))
@pytest.mark.parametrize("axis", [0, 1])
@pytest.mark.parametrize("n", [127, 256, 401])
@pytest.mark.parametrize("frac", [0.1, 0.4, 0.8])
@pytest.mark.parametrize("method", ["mpcg", "pk"])  # coarse-to-fine start (the CPU default) and the plain iteration
def test_westergaard_partial_contact(units: str, axis: int, n: int, frac: float, method: str) -> None:
    """Westergaard (Johnson Eqs. 13.11-13.12) at ``pbar = frac p*``: the contact width within 2 pixels (one per
    edge: the discrete contact edge lies within a pixel of the true one) and the pressure within
    0.3/sqrt(m) rms, relative to pbar, with m the contact's width in pixels (an edge placed within a pixel
    moves the square-root edge of the pressure, an rms error of order m^-1/2; measured 0.004-0.16 m^-1/2 and
    edges within 1 pixel on these grids)."""
    e_star, lam, amp = UNITS[units]
    pbar = frac * math.pi * e_star * amp / lam
    h, x, length = wave(n, 2, amp, lam, axis)
    r = solve(h, sigma0=pbar, interaction="hard_wall", e_star=e_star, length=length, tol=1e-10, backend="numpy",
              method=method)
    assert r.converged
    a, p_exact = westergaard(x, pbar, amp, e_star, lam)
    assert abs(r.contact_area - 2 * a / lam) <= 2.0 / n
    p = profile(r.pressure, axis)
    assert np.sqrt(np.mean((p - p_exact) ** 2)) / pbar <= 0.3 / math.sqrt(2 * a / lam * n)
    assert float(p.mean()) == pytest.approx(pbar, rel=1e-9, abs=0)  # the load: the multiplier's constraint


@pytest.mark.parametrize(("nx", "ny", "a_px"), [(96, 96, 12), (97, 75, 12), (128, 96, 16)])
@pytest.mark.parametrize("units", ["model", "GPa_nm"])
@pytest.mark.parametrize("method", ["mpcg", "pk"])  # the coarse-to-fine start and the plain iteration
def test_hertz_on_a_free_map(nx: int, ny: int, a_px: int, units: str, method: str) -> None:
    """A paraboloid on a free (non-periodic) map, pressed by Hertz's force for the contact radius ``a``: the
    contact area within 1.5 pixels of the radius (its perimeter, ``2 pi a`` pixels of area, counts half) and the
    peak pressure within 4 % of ``p0 = 2 E* a / (pi R)`` (the centre pixel samples the pressure at its centre;
    the pixelated edge shifts the load, measured 1-2 % at a = 12-16 pixels)."""
    e_star, scale = (1.0, 1.0) if units == "model" else (70.0, 10.0)  # GPa, nm per pixel
    dx = scale
    radius = 60.0 * a_px * dx
    a = a_px * dx
    hz = hertz(radius, e_star, a=a)
    x = (np.arange(nx) - (nx - 1) / 2) * dx
    y = (np.arange(ny) - (ny - 1) / 2) * dx
    r2 = x[:, None] ** 2 + y[None, :] ** 2
    h = -r2 / (2 * radius)
    lx, ly = nx * dx, ny * dx
    res = solve(h, sigma0=hz.force / (lx * ly), interaction="hard_wall", e_star=e_star, length=(lx, ly),
                periodic=False, tol=1e-9, method=method)
    assert res.converged
    area_px = res.contact_area * nx * ny
    radius_px = math.sqrt(area_px / math.pi)
    assert abs(radius_px - a_px) <= 1.5
    assert float(res.pressure.max()) == pytest.approx(hz.p0, rel=0.04, abs=0)
    assert float(res.pressure.sum()) * dx * dx == pytest.approx(hz.force, rel=1e-8, abs=0)  # the load is imposed


@pytest.mark.parametrize("n", [63, 128])
@pytest.mark.parametrize("frac", [0.3, 0.7])
@pytest.mark.parametrize("units", sorted(UNITS))
def test_plastic_cap_above_the_peak_is_westergaard(n: int, frac: float, units: str) -> None:
    """A hardness above Westergaard's peak pressure never bites: the capped solve is Westergaard's contact (same
    tolerances as test_westergaard_partial_contact) with no plastic area and no plastic displacement."""
    e_star, lam, amp = UNITS[units]
    pbar = frac * math.pi * e_star * amp / lam
    h, x, length = wave(n, 2, amp, lam, 0)
    a, p_exact = westergaard(x, pbar, amp, e_star, lam)
    hard = 1.5 * float(p_exact.max())
    r = solve(h, sigma0=pbar, interaction="hard_wall", hardness=hard, e_star=e_star, length=length, tol=1e-10)
    assert r.converged and r.plastic_area == 0.0
    assert np.abs(r.plastic_displacement).max() <= 1e-12 * amp
    assert abs(r.contact_area - 2 * a / lam) <= 2.0 / n
    assert np.sqrt(np.mean((r.pressure[:, 0] - p_exact) ** 2)) / pbar <= 0.3 / math.sqrt(2 * a / lam * n)


@pytest.mark.parametrize(("nx", "ny"), [(33, 33), (48, 40)])
@pytest.mark.parametrize("load", [0.1, 0.35, 0.7])
@pytest.mark.parametrize("seed", [1, 2])
def test_rigid_plastic_limit_is_the_bearing_area(nx: int, ny: int, load: float, seed: int) -> None:
    """``E* h'_rms / H -> oo`` (docs/model.md, pressure cap): ``p = H`` on the contact, whose area is the
    bearing area ``sigma0/H`` of the surface, the part above the level ``d`` with ``<h > d> = sigma0/H``, and
    the mean gap ``<(d - h)+>`` (computed here by sorting the heights). Tolerance: the area within one pixel
    (the level falls between two heights) and the mean gap within 2 % (the residual elastic compliance at
    E* h'_rms/H = 1e5 and one pixel's rounding)."""
    rng = np.random.default_rng(seed)
    h = rng.standard_normal((nx, ny))  # an uncorrelated surface: any h works in the rigid-plastic limit
    hard = 1.0
    r = solve(h, sigma0=load * hard, interaction="hard_wall", hardness=hard, e_star=1e6, tol=1e-9)
    assert r.converged
    m = nx * ny
    k = int(round(load * m))  # pixels at p = H
    assert abs(r.contact_area * m - k) <= 1
    assert abs(r.plastic_area * m - k) <= 1
    d = np.sort(h.ravel())[::-1][k - 1]  # the level: k pixels at or above it
    hc = h - h.mean()
    d = d - h.mean()
    assert r.mean_gap == pytest.approx(float(np.clip(d - hc, 0, None).mean()), rel=0.02, abs=0)


def layer_factor(x: float, nu: float, bottom: str) -> float:
    """``f(q t)`` of docs/model.md "Elastic layer on a rigid base", written out here (Carbone & Mangialardi
    2008, Eq. A.30, bonded; the slip base's closed form), independent of gapsweep.gfmd.substrates."""
    if bottom == "slip":
        return (math.sinh(2 * x) + 2 * x) / (math.cosh(2 * x) - 1)
    k = 3 - 4 * nu
    return (k * math.cosh(2 * x) + 2 * x * x + 5 - 12 * nu + 8 * nu * nu) / (k * math.sinh(2 * x) - 2 * x)


@pytest.mark.parametrize("bottom", ["bonded", "slip"])
@pytest.mark.parametrize("nu", [0.0, 0.3, 0.49])
@pytest.mark.parametrize("qt", [0.05, 0.5, 2.0, 8.0])
@pytest.mark.parametrize("units", sorted(UNITS))
def test_layer_full_contact_stiffness(bottom: str, nu: float, qt: float, units: str) -> None:
    """A wave in full contact on a layer of thickness ``t``: ``p = pbar + k(q) amp cos(q x)`` with
    ``k = (E* q / 2) f(q t)`` (the layer's surface stiffness). ``q t`` from the Winkler (thin) to the half-space
    (thick) regime; nu up to the nearly incompressible 0.49 (bonded: k grows as 1/(1 - 2 nu)). Tolerance:
    1e-7 of the pressure amplitude (solver tolerance 1e-10 on the residual, relative to pbar)."""
    e_star, lam, amp = UNITS[units]
    q = 2 * math.pi / lam
    t = qt / q
    k = e_star * q / 2 * layer_factor(qt, nu, bottom)
    h, x, length = wave(40, 3, amp, lam, 0)
    pbar = 1.5 * k * amp  # above the amplitude: full contact
    r = solve(h, sigma0=pbar, interaction="hard_wall", e_star=e_star, length=length, thickness=t, poisson=nu,
              bottom=bottom, tol=1e-10)
    assert r.converged and r.contact_area == 1.0
    np.testing.assert_allclose(r.pressure[:, 0], pbar + k * amp * np.cos(q * x), rtol=0, atol=1e-7 * k * amp)


@pytest.mark.parametrize("bottom", ["bonded", "slip"])
@pytest.mark.parametrize("nu", [0.1, 0.45])
def test_thin_layer_q_to_zero_is_its_winkler_stiffness(bottom: str, nu: float) -> None:
    """As ``q t -> 0`` the layer is a Winkler foundation: ``k -> E* (1 - nu)^2 / ((1 - 2 nu) t)`` (bonded: the
    oedometric modulus) or ``E* / t`` (slip): checked on the full-contact pressure amplitude of a wave with
    ``q t = 1e-3`` (the next term is O((q t)^2) relative). Tolerance 1e-4."""
    e_star, lam, amp = 1.0, 1.0, 1e-3
    q = 2 * math.pi / lam
    t = 1e-3 / q
    k_winkler = e_star * (1 - nu) ** 2 / ((1 - 2 * nu) * t) if bottom == "bonded" else e_star / t
    h, x, length = wave(32, 2, amp, lam, 0)
    r = solve(h, sigma0=2 * k_winkler * amp, interaction="hard_wall", e_star=e_star, length=length, thickness=t,
              poisson=nu, bottom=bottom, tol=1e-11)
    assert r.converged and r.contact_area == 1.0
    p1 = 2 * float(np.mean((r.pressure[:, 0] - r.pressure[:, 0].mean()) * np.cos(q * x)))
    assert p1 == pytest.approx(k_winkler * amp, rel=1e-4, abs=0)


@pytest.mark.parametrize(("nx", "ny"), [(32, 20), (27, 9)])
@pytest.mark.parametrize("units", sorted(UNITS))
@pytest.mark.parametrize("load", ["tensile", "compressive"])
def test_hard_wall_adhesive_full_contact(nx: int, ny: int, units: str, load: str) -> None:
    """The challenge's law (M3b) in full contact: ``g = 0`` everywhere, so ``u = h`` up to a constant and
    ``p = sigma0 + (E* q/2) h`` exactly, whatever the (adhesive) load that keeps the multiplier
    ``p + w/rho >= 0``. Tolerance 1e-9 w/rho (solver tolerance 1e-11)."""
    e_star, lam, amp = UNITS[units]
    amp = amp / 10
    h, _, length = wave(nx, ny, amp, lam, 0)
    q = 2 * math.pi / lam
    p1 = e_star * q * amp / 2
    rho = 0.05 * lam  # resolved: rho > dx (M7)
    work = 1.6 * p1 * rho  # w/rho = 1.6 p1: full contact survives a tension up to 0.6 p1
    sigma0 = -0.4 * p1 if load == "tensile" else 3 * p1
    r = solve(h, sigma0=sigma0, interaction="hard_wall_adhesive", work=work, rho=rho, e_star=e_star,
              length=length, tol=1e-11, backend="numpy")
    assert r.converged and r.contact_area == 1.0
    np.testing.assert_allclose(r.pressure, sigma0 + p1 / amp * h, rtol=0, atol=1e-9 * work / rho)
