"""The contact-mechanics challenge (Muser & Dapp, arXiv:1512.02403, 2015, "The contact mechanics challenge:
problem definition"; Muser et al., Tribol. Lett. 65, 118, 2017, "Meeting the contact-mechanics challenge"):
its constants, its spectrum and surfaces drawn from it (docs/challenge.md lists every constant with its source
and what is assumed).

Units: lengths in micrometres, pressures in MPa; then energies per area are MPa um = J/m^2 (1 MPa um = 1 N/m).

The published height map (one realisation, distributed by the organisers on 32768^2 and finer grids) cannot be
fetched from these machines: :func:`surface` draws a new realisation of the same spectrum with gapsweep's
generator (:func:`gapsweep.surfaces.synthetic.self_affine` with the roll-off ``lambda_r``), so statistical
outputs are comparable, realisation-specific ones (the position of a contact patch) are not. A user with the
published files passes them to :func:`gapsweep.surfaces.synthetic.load` (the formats SurfaceTopography reads;
docs/gfmd.md "Surfaces from data") or names them in a job (``[surface] kind = "file"``)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from gapsweep.core import checks as chk
from gapsweep.surfaces.synthetic import continuum_rms_height, self_affine

__all__ = ["CHALLENGE", "mu_rho", "rms_curvature", "surface", "tabor"]

#: the challenge's problem (docs/challenge.md, "Constants": sources and assumptions there)
CHALLENGE: dict[str, float] = {
    "length": 100.0,  # um: linear size of the periodic box (0.1 mm)
    "lambda_r": 20.0,  # um: roll-off wavelength (C(q) constant for q < q_r)
    "lambda_s": 0.1,  # um: short-wavelength cut-off (C(q) = 0 for q > q_s)
    "hurst": 0.8,
    "rms_slope": 1.0,  # g_rms, dimensionless
    "e_star": 25.0,  # MPa: contact modulus E*
    "work": 0.05,  # MPa um = J/m^2: gamma0 = 50 mJ/m^2
    "rho": 2.071e-3,  # um: range of the exponential adhesion (2.071 nm)
    "n_reference": 65536,  # grid side of the reference calculation (pixel L/65536 = 1.526 nm)
}


def surface(n: int, *, seed: int = 0, length: float | None = None, backend: str = "numpy") -> Any:
    """A surface (um) of the challenge's spectrum on ``n x n`` points of the box ``length`` (default 100 um):
    H = 0.8, constant below the roll-off 20 um, cut off at 0.1 um, g_rms = 1 (module docstring: a new
    realisation, not the published one). ``n`` must carry lambda_s (``n > 2 L / lambda_s``: 2001 for the full
    box). A smaller ``length`` keeps the challenge's wavelengths that fit (lambda_r and lambda_s) and is for
    tests only."""
    c = CHALLENGE
    length = c["length"] if length is None else chk.positive(length, "length")
    lambda_r = min(c["lambda_r"], length)
    return self_affine(n, c["hurst"], lambda_l=length, lambda_r=lambda_r, lambda_s=c["lambda_s"], length=length,
                       rms_slope=c["rms_slope"], seed=seed, backend=backend)  # type: ignore[arg-type]


def rms_curvature(hurst: float, *, lambda_l: float, lambda_s: float, lambda_r: float | None = None,
                  rms_slope: float = 1.0) -> float:
    """Continuum rms of the mean curvature ``nabla^2 h / 2`` (1/length) of the spectrum of
    :mod:`gapsweep.surfaces.synthetic` normalised to ``g_rms``: ``kappa^2 / g^2 = (1/4) int C q^5 dq / int C q^3
    dq`` over ``[q_l, q_s]`` (``C ~ q^(-2H-2)``, constant below ``q_r``), by quadrature on 4000 log-spaced
    points (relative error below 1e-6)."""
    ql, qs = 2 * math.pi / lambda_l, 2 * math.pi / lambda_s
    qr = ql if lambda_r is None else 2 * math.pi / lambda_r
    q = np.geomspace(ql, qs, 4000)
    c = np.minimum((q / qr) ** (-2.0 * hurst - 2.0), 1.0)
    trapezoid = getattr(np, "trapezoid", None) or np.trapz  # noqa: NPY201 - numpy < 2 names it trapz
    m3 = trapezoid(c * q**3, q)
    m5 = trapezoid(c * q**5, q)
    return float(rms_slope * math.sqrt(0.25 * m5 / m3))


def tabor(work: float, rho: float, e_star: float, radius: float) -> float:
    """Tabor parameter ``mu_T = (R work^2 / (E*^2 rho^3))^(1/3)`` with the interaction range ``rho`` in place of
    the equilibrium spacing; for a rough surface ``R = 1 / kappa_rms`` (:func:`rms_curvature`), the convention of
    docs/challenge.md (an assumption: the challenge varied rho and named the outcome by the Tabor parameter)."""
    return float((radius * work**2 / (e_star**2 * rho**3)) ** (1.0 / 3.0))


def mu_rho(work: float, rho: float, e_star: float, dx: float) -> float:
    """Resolution measure ``sqrt(max|V''| dx / E*) = sqrt(work dx / (rho^2 E*))`` of the exponential adhesion on
    a pixel ``dx`` (Wang, Zhou & Muser, Lubricants 9, 17, 2021; below about 0.5 resolved). The challenge's own:
    0.84 at dx = 1.526 nm."""
    return float(math.sqrt(work * dx / (rho**2 * e_star)))


def rms_height() -> float:
    """Continuum rms height (um) of the challenge's spectrum: 0.777 um."""
    c = CHALLENGE
    return continuum_rms_height(c["hurst"], lambda_l=c["length"], lambda_s=c["lambda_s"], lambda_r=c["lambda_r"],
                                rms_slope=c["rms_slope"])
