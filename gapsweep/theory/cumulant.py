"""Next-order terms of the field theory's cumulant expansion: a computed error indicator (docs/theory.md,
"Next-order terms").

The exact identity of M3 gives ``g0 = rho ln(gamma0/(rho sigma0)) + rho ln<exp(-dg/rho)>`` with ``dg`` the gap
fluctuation. Its cumulant expansion is ``rho ln<exp(-dg/rho)> = sum_n (-1)^n kappa_n / (n! rho^(n-1))``; the
paper's theory keeps ``n = 2`` with the linear response ``dg1`` (Gaussian). The next order in the heights adds

    T = [kappa_2(dg) - kappa_2(dg1)] / (2 rho) - kappa_3(dg) / (6 rho^2) + kappa_4(dg) / (24 rho^3),

with ``dg = dg1 + dg2`` the response to second order (``improved.gap_fluctuations(order=2)``): the
non-Gaussian part that the nonlinear local law (``dg2``) and the finite random-phase surface (``kappa_4``)
produce. ``|T|`` small against the tolerated error means the second-order theory can be trusted; large means
the expansion is not converged, whatever its sign. Lengths in the unit of ``length``.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike
from scipy.special import logsumexp

from gapsweep.core import checks as chk
from gapsweep.theory.improved import gap_fluctuations

__all__ = ["next_order_term", "resummed_term", "trusted"]


def next_order_term(
    sigma0: ArrayLike, heights: ArrayLike, *, rho: float, length: float = 1.0, e_star: float = 1.0
) -> float | np.ndarray:
    """The next-order term ``T`` [length] of the cumulant expansion (module docstring), vectorised over ``sigma0``."""
    s = chk.positive_array(sigma0, "sigma0")
    rho = chk.positive(rho, "rho")
    out = np.empty(s.size)
    for i, si in enumerate(s.ravel()):
        d1 = gap_fluctuations(float(si), heights, rho=rho, length=length, e_star=e_star, order=1)
        d = gap_fluctuations(float(si), heights, rho=rho, length=length, e_star=e_star, order=2)
        c = d - d.mean()
        m2, m3, m4 = (float(np.mean(c**k)) for k in (2, 3, 4))
        k2_1 = float(np.mean((d1 - d1.mean()) ** 2))
        k4 = m4 - 3.0 * m2 * m2
        out[i] = (m2 - k2_1) / (2.0 * rho) - m3 / (6.0 * rho**2) + k4 / (24.0 * rho**3)
    out = out.reshape(s.shape)
    return float(out) if out.ndim == 0 else out


def resummed_term(
    sigma0: ArrayLike, heights: ArrayLike, *, rho: float, length: float = 1.0, e_star: float = 1.0
) -> float | np.ndarray:
    """All orders beyond the paper's: ``rho ln<exp(-dg/rho)> - kappa_2(dg1)/(2 rho)`` [length], ``dg = dg1 + dg2``.

    The truncated ``T`` of :func:`next_order_term` misses the low-pressure failure at large ``h_rms/rho``, where
    the extreme tail of the surface (every cumulant) sets ``<exp(-dg/rho)>``; this resummed form catches it
    (docs/results/predictors.md). It equals ``improved.lme_second_order - mean_gap_discrete``.
    """
    s = chk.positive_array(sigma0, "sigma0")
    rho = chk.positive(rho, "rho")
    out = np.empty(s.size)
    for i, si in enumerate(s.ravel()):
        d1 = gap_fluctuations(float(si), heights, rho=rho, length=length, e_star=e_star, order=1)
        d = gap_fluctuations(float(si), heights, rho=rho, length=length, e_star=e_star, order=2)
        w = -d.ravel() / rho
        lme = rho * (float(logsumexp(w)) - math.log(w.size))
        out[i] = lme - float(np.mean((d1 - d1.mean()) ** 2)) / (2.0 * rho)
    out = out.reshape(s.shape)
    return float(out) if out.ndim == 0 else out


def trusted(
    term: ArrayLike, g0: ArrayLike, h_rms: ArrayLike, *, rel: float = 0.05, abs_frac: float = 0.05
) -> np.ndarray:
    """Verdict of the indicator: ``|T| <= rel |g0|`` where ``|g0| >= h_rms``, else ``|T| <= abs_frac h_rms``
    (the goals of issue 13: 5 % relative, 0.05 h_rms absolute near the zero crossing)."""
    t = np.abs(np.asarray(term, float))
    g = np.abs(np.asarray(g0, float))
    h = chk.positive_array(h_rms, "h_rms")
    return np.where(g >= h, t <= rel * g, t <= abs_frac * h)
