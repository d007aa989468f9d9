"""A gap-distribution closure with local response and no fitted strength (docs/theory.md, "Gap-distribution
closure").

The M5 process adds, per unit magnification, the gap variance ``2 D2(zeta)`` of one roughness shell filtered by
the linear response ``eta zeta/(1 + eta zeta)``, ``eta = rho q_l E*/(2 sigma0)``: the response of an interface
whose stiffness is the *mean* ``sigma0/rho``. Here the shell rides on a region of gap ``g``, whose local
interfacial stiffness is ``p(g)/rho`` with ``p(g) = (gamma0/rho) exp(-g/rho)``, so

    D2(g, zeta) = C1 (eta(g) zeta / (1 + eta(g) zeta))^2 zeta^(-2H-1)      [length^2],
    eta(g)      = rho q_l E* / (2 p(g)),

and the Ito drift is fixed by the exact identity of M3 instead of a fit: the mean pressure is ``sigma0`` at every
magnification, ``(gamma0/rho) <exp(-g/rho)> = sigma0``, i.e. ``d<exp(-g/rho)>/dzeta = <exp(-g/rho) (D2/rho -
a)>/rho = 0`` for every distribution, which holds if and only if (for all ``P``) ``a(g, zeta) = D2(g, zeta)/rho``
[length per unit zeta]. With ``p(g)`` replaced by ``sigma0`` this is the paper's C2 = 0 process (``D2 = rho D1``).
The repulsion is in the response: small gaps (high local pressure) are stiff and receive little of the finer
roughness. No parameter beyond the model's: ``C1 = H h_rms^2`` as in M5.

Solved by Euler-Maruyama in ``ln zeta`` (numpy; ``n`` realisations, geometric steps ``1 + dzeta``).
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from scipy.special import expit

from gapsweep import _checks as chk

__all__ = ["local_response_samples"]


def local_response_samples(
    sigma0: float,
    *,
    hurst: float,
    h_rms: float,
    rho: float,
    gamma0: float,
    lambda_l: float,
    lambda_s: float,
    e_star: float = 1.0,
    n: int = 200_000,
    dzeta: float = 0.01,
    seed: int = 0,
    local: bool = True,
) -> np.ndarray:
    """Gap samples [length] at ``zeta_s = lambda_l/lambda_s`` of the local-response closure (module docstring).

    Starts at the flat gap ``rho ln(gamma0/(rho sigma0))`` at ``zeta = 1``; ``C1 = H h_rms^2``. Steps are
    geometric, ``zeta_{k+1} = zeta_k (1 + dzeta)``; within a step ``D2`` is taken at the step's midpoint in ``zeta``
    and at the current gap (Ito). Reproducible from ``seed``. ``local=False`` takes ``p(g) = sigma0`` (the
    paper's C2 = 0 process, Gaussian, mean = the paper-form field theory): the baseline.
    """
    s = chk.positive(sigma0, "sigma0")
    hurst = chk.hurst(hurst)
    h_rms = chk.nonnegative(h_rms, "h_rms")
    rho = chk.positive(rho, "rho")
    gamma0 = chk.positive(gamma0, "gamma0")
    lambda_l = chk.positive(lambda_l, "lambda_l")
    lambda_s = chk.positive(lambda_s, "lambda_s")
    e_star = chk.positive(e_star, "e_star")
    n = chk.count(n, "n")
    dzeta = chk.positive(dzeta, "dzeta")
    if not lambda_s < lambda_l:
        raise ValueError(f"lambda_s must be < lambda_l, got lambda_s={lambda_s!r}, lambda_l={lambda_l!r}")
    zeta_s = lambda_l / lambda_s
    steps = max(1, math.ceil(math.log(zeta_s) / math.log1p(dzeta)))
    edges = np.exp(np.linspace(0.0, math.log(zeta_s), steps + 1))
    c1 = hurst * h_rms**2
    # ln eta(g) = ln(rho q_l E*/2) - ln p(g) = ln(rho q_l E*/2) - ln(gamma0/rho) + g/rho
    base = math.log(rho * (2.0 * math.pi / lambda_l) * e_star / 2.0) - math.log(gamma0 / rho)
    rng = np.random.default_rng(seed)
    g_flat = rho * (math.log(gamma0) - math.log(rho) - math.log(s))
    g = np.full(n, g_flat)
    for z0, z1 in itertools.pairwise(edges):
        zm = math.sqrt(z0 * z1)
        # eta zeta / (1 + eta zeta), overflow-free; at the mean pressure for the baseline
        r = expit(base + (g if local else g_flat) / rho + math.log(zm))
        d2 = c1 * r * r * zm ** (-2.0 * hurst - 1.0)
        dz = z1 - z0
        g = g + (d2 / rho) * dz + np.sqrt(2.0 * d2 * dz) * rng.standard_normal(n)
    if not np.all(np.isfinite(g)):
        raise FloatingPointError("local-response closure produced non-finite gaps")
    return g
