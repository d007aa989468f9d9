"""Grid size and tolerance for a GFMD run at a requested accuracy (refinement study in
docs/benchmarks_gfmd.md; docs/model.md M2, M3).

The rule is an envelope of the refinement study ``benchmarks/refinement.py`` (same seed on n = 1024 ... 8192 on
an H200, figure-2/3 cases of M6, sigma0 = 1e-4, 1e-2, 1; results in docs/benchmarks_gfmd.md) and was checked on
a second cut-off (lambda_s = L/64, n = 160 ... 1024, CPU). Three empirical laws:

1. Mean gap, discretisation. The grid enters only through the sampling of ``exp((h - u)/rho)``; that field is
   smooth, so the error falls off exponentially with the number of grid points per shortest wavelength
   ``k = lambda_s / dx``. With ``a = g_rms lambda_s / (2 pi rho)`` (the slope-amplitude of the shortest
   wavelength measured in units of ``rho``) the measured errors stay below

       |g0(n) - g0(inf)| / rho  <=  10^(k (C0 + C1 log10 a)),   C0 = -1.02, C1 = 1.48,

   for 0.08 <= a <= 0.8 and 2.5 <= k <= 10 (extrapolated outside; flagged). No trend with sigma0 was resolved
   (the envelope covers sigma0/(E* g_rms) = 1e-4 ... 1).
2. Gap histogram, discretisation (120 bins spanning 1.5 times the gap range): ``L1 = int |P_n - P| dg <=
   0.03 k^-1.5``. This is the quadrature error of the level sets of a smooth field, independent of ``rho``.
3. Solver tolerance (residual of M3 as defined in gapsweep.gfmd): ``|dg0| <= 0.1 rho tol`` and histogram
   ``L1 <= 3 tol`` over all cases and tol = 1e-3 ... 1e-8.

:func:`choose_grid` splits the requested error evenly between discretisation and solver, divides the
discretisation budget by ``safety`` (default 10 for law 1; the largest under-prediction seen on the second
cut-off was a factor 1.1) and by ``hist_safety`` (default 1.5 for law 2), and returns the smallest
FFT-friendly ``n`` (2^a 3^b 5^c, above the Nyquist limit ``2 L/lambda_s``) and the loosest ``tol`` that meet it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from gapsweep.core import checks as chk

__all__ = ["GridChoice", "choose_grid", "predicted_gap_error", "predicted_hist_l1"]

C0, C1 = -1.02, 1.48  # law 1 (envelope of the refinement study)
HIST_C, HIST_P = 0.03, 1.5  # law 2
TOL_GAP, TOL_HIST = 0.1, 3.0  # law 3
A_RANGE = (0.075, 0.85)
K_RANGE = (2.5, 10.3)
SIGMA_RANGE = (1e-4, 1.0)


@dataclass(frozen=True)
class GridChoice:
    """Result of :func:`choose_grid`. Errors are predictions (upper envelopes), lengths in units of L."""

    n: int
    tol: float
    points_per_lambda_s: float
    predicted_gap_error: float
    predicted_hist_l1: float
    extrapolated: bool
    note: str


def _slope_amplitude(lambda_s: float, rho: float, rms_slope: float) -> float:
    return rms_slope * lambda_s / (2 * math.pi * rho)


def predicted_gap_error(n: int, *, lambda_s: float, rho: float, rms_slope: float = 1.0,
                        length: float = 1.0) -> float:
    """Law 1: upper envelope of the mean-gap discretisation error ``|g0(n) - g0(inf)|`` (units of length)."""
    k = chk.positive(lambda_s, "lambda_s") * n / chk.positive(length, "length")
    a = _slope_amplitude(lambda_s, chk.positive(rho, "rho"), chk.positive(rms_slope, "rms_slope"))
    return rho * 10.0 ** (k * (C0 + C1 * math.log10(a)))


def predicted_hist_l1(n: int, *, lambda_s: float, length: float = 1.0) -> float:
    """Law 2: upper envelope of the gap-histogram L1 discretisation error (120 bins over 1.5 x gap range)."""
    k = chk.positive(lambda_s, "lambda_s") * n / chk.positive(length, "length")
    return HIST_C * k ** (-HIST_P)


def _smooth_sizes(lo: int, hi: int) -> list[int]:
    out = set()
    p2 = 1
    while p2 <= hi:
        p3 = p2
        while p3 <= hi:
            p5 = p3
            while p5 <= hi:
                if p5 >= lo and p5 % 2 == 0:
                    out.add(p5)
                p5 *= 5
            p3 *= 3
        p2 *= 2
    return sorted(out)


def choose_grid(
    gap_error: float,
    *,
    lambda_s: float,
    rho: float,
    rms_slope: float = 1.0,
    sigma0: float | None = None,
    e_star: float = 1.0,
    length: float = 1.0,
    hist_l1: float | None = None,
    safety: float = 10.0,
    hist_safety: float = 1.5,
    n_max: int = 65536,
) -> GridChoice:
    """Smallest grid ``n`` and loosest ``tol`` for a GFMD mean gap within ``gap_error`` (absolute, units of
    length) and, if given, a gap histogram within ``hist_l1`` (L1 distance of densities, 0 ... 2).

    ``lambda_s``: short-wavelength cut-off; ``rho``: interaction range; ``rms_slope``: g_rms of the surface;
    ``sigma0``: mean pressure (only checked against the studied range ``1e-4 ... 1`` in units of
    ``E* g_rms``). ``safety`` divides the discretisation budget of the exponential law 1 (cheap: n grows
    only by log(safety)), ``hist_safety`` that of the power law 2. Laws and constants: module docstring.
    Raises ValueError when ``n_max`` does not suffice.
    """
    gap_error = chk.positive(gap_error, "gap_error")
    lambda_s, rho = chk.positive(lambda_s, "lambda_s"), chk.positive(rho, "rho")
    rms_slope, length = chk.positive(rms_slope, "rms_slope"), chk.positive(length, "length")
    safety = chk.positive(safety, "safety")
    hist_safety = chk.positive(hist_safety, "hist_safety")
    if hist_l1 is not None:
        hist_l1 = chk.positive(hist_l1, "hist_l1")
        if hist_l1 >= 2:
            raise ValueError(f"hist_l1 must be < 2 (L1 distance of two densities), got {hist_l1}")
    a = _slope_amplitude(lambda_s, rho, rms_slope)
    notes = []
    extrapolated = not (A_RANGE[0] <= a <= A_RANGE[1])
    if extrapolated:
        notes.append(f"a = g_rms lambda_s/(2 pi rho) = {a:.3g} outside the studied {A_RANGE}")
    if sigma0 is not None:
        s = chk.positive(sigma0, "sigma0") / (chk.positive(e_star, "e_star") * rms_slope)
        if not (SIGMA_RANGE[0] <= s <= SIGMA_RANGE[1]):
            extrapolated = True
            notes.append(f"sigma0/(E* g_rms) = {s:.3g} outside the studied {SIGMA_RANGE}")

    # Solver share: law 3.
    tol = 0.5 * gap_error / (TOL_GAP * rho)
    if hist_l1 is not None:
        tol = min(tol, 0.5 * hist_l1 / TOL_HIST)
    tol = min(tol, 1e-2)
    # Discretisation share: laws 1 and 2 with the safety margin.
    n_nyquist = int(math.floor(2 * length / lambda_s)) + 1
    chosen = None
    for n in _smooth_sizes(n_nyquist, n_max):
        ok = predicted_gap_error(n, lambda_s=lambda_s, rho=rho, rms_slope=rms_slope, length=length) \
            <= 0.5 * gap_error / safety
        if hist_l1 is not None:
            ok = ok and predicted_hist_l1(n, lambda_s=lambda_s, length=length) <= 0.5 * hist_l1 / hist_safety
        if ok:
            chosen = n
            break
    if chosen is None:
        raise ValueError(f"no grid up to n_max={n_max} meets gap_error={gap_error:g}"
                         + (f", hist_l1={hist_l1:g}" if hist_l1 is not None else "")
                         + "; loosen the request or raise n_max")
    k = lambda_s * chosen / length
    if not (K_RANGE[0] <= k <= K_RANGE[1]):
        extrapolated = True
        notes.append(f"lambda_s/dx = {k:.3g} outside the studied {K_RANGE}")
    return GridChoice(
        n=chosen,
        tol=tol,
        points_per_lambda_s=k,
        predicted_gap_error=predicted_gap_error(chosen, lambda_s=lambda_s, rho=rho, rms_slope=rms_slope,
                                                length=length) + TOL_GAP * rho * tol,
        predicted_hist_l1=predicted_hist_l1(chosen, lambda_s=lambda_s, length=length) + TOL_HIST * tol,
        extrapolated=extrapolated,
        note="; ".join(notes),
    )
