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
roughness. No parameter beyond the model's: ``C1 = H h_rms^2 / (1 - zeta_s^(-2H))``, the continuum prefactor of
M4 for a spectrum cut at ``zeta_s``, so that the shells add up to exactly ``h_rms^2`` (the paper's ``H h_rms^2``
leaves the gap variance short by the factor ``1 - zeta_s^(-2H)``: 25 % at H = 0.2, zeta_s = 32; issue 21).

``gap_distribution`` is the multiscale route (docs/theory.md, "Multiscale gap distribution"): GFMD on the coarse
modes (the grid ``improved.hybrid(zeta_c="auto")`` chooses), then, under every coarse pixel, the same local-
response process over the surface's own finer shells, started at the pixel's gap and pressure.

Solved by Euler-Maruyama in ``ln zeta`` (numpy; ``n`` realisations, geometric steps ``1 + dzeta``).
"""

from __future__ import annotations

import itertools
import logging
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.special import expit

from gapsweep.core import checks as chk

__all__ = ["MultiscaleGaps", "gap_distribution", "l1_distance", "local_response_samples", "multiscale_gap_samples"]

log = logging.getLogger("gapsweep.theory.closure")


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

    Starts at the flat gap ``rho ln(gamma0/(rho sigma0))`` at ``zeta = 1``; ``C1 = H h_rms^2/(1 - zeta_s^(-2H))``
    (module docstring; with it the rigid limit has the gap variance ``h_rms^2``). Steps are
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
    c1 = hurst * h_rms**2 / -math.expm1(-2.0 * hurst * math.log(zeta_s))  # continuum prefactor (M4)
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


@dataclass
class MultiscaleGaps:
    """Gap samples of :func:`multiscale_gap_samples` and how they were obtained.

    ``samples`` [length]; ``n_c``, ``k_c``: the coarse GFMD grid and the largest integer wave number it resolves;
    ``shells``: groups of finer shells the process ran over; ``cost``: force evaluations x grid points of the
    coarse solves; ``cost_fraction``: over one full GFMD run on the input grid (estimated, ``improved.hybrid``);
    ``status``: "converged", "l1_not_met" (the self-check below exceeds ``l1_tol``), the hybrid's
    "rtol_not_met", or the coarse solve's failure; ``mean_gap``: the hybrid's mean gap (its error estimate in
    ``mean_gap_error``); ``l1_change``: L1 distance between these samples and those of the same route on the
    ladder's previous (twice coarser) grid (NaN if there was none); ``l1_estimate``: the estimated L1 distance to
    GFMD's histogram, ``L1_SAFETY x l1_change`` (NaN if there was no previous grid; 0 if nothing was left
    unresolved).
    """

    samples: np.ndarray
    n_c: int
    k_c: int
    shells: int
    cost: float
    cost_fraction: float
    status: str
    mean_gap: float
    mean_gap_error: float
    l1_change: float = math.nan
    l1_estimate: float = math.nan


# The self-check's factor: the L1 distance to GFMD estimated as L1_SAFETY x (L1 between the last two coarse grids'
# distributions); chosen on the tuning set of benchmarks/results/bounds/ (bench_bounds.py), reported on its
# held-out set.
L1_SAFETY = 1.5
# Bins of the L1 distances (as the validation: equal bins over the reference's range, mass outside counted fully)
L1_BINS = 80
# The centring table of ``_mean_drift``: start gaps and antithetic paths per start gap. Against a 129 x 65536 table
# on six held-out surfaces at three pressures (benchmarks/bench_multiscale_table.py, results/multiscale_table.json)
# the largest error is 1.8 % of the fine shells' rigid spread at 65 x 1024 (1.5 % at the earlier 65 x 4096; 3.6 %
# at 33 points, where interpolation dominates), at a quarter of the earlier table's cost.
DRIFT_POINTS = 65
DRIFT_PATHS = 1024


def l1_distance(x: ArrayLike, ref: ArrayLike, bins: int = L1_BINS) -> float:
    """L1 distance [1] between the densities of the samples ``x`` and ``ref`` on ``bins`` equal bins over
    ``ref``'s range; the mass of ``x`` outside that range counts fully (0 identical, 2 disjoint)."""
    x = np.asarray(x, float).ravel()
    ref = np.asarray(ref, float).ravel()
    lo, hi = float(ref.min()), float(ref.max())
    if not hi > lo:
        return float(np.mean(x != lo)) * 2.0
    e = np.linspace(lo, hi, bins + 1)
    a = np.histogram(x, bins=e)[0] / x.size
    b = np.histogram(ref, bins=e)[0] / ref.size
    return float(np.sum(np.abs(a - b)) + (1.0 - a.sum()))


def _walk(g: np.ndarray, q: np.ndarray, pw: np.ndarray, rho: float, base: float, rng: np.random.Generator,
          common: bool = False) -> np.ndarray:
    """The local-response process over the shell groups ``(q, pw)`` from the gaps ``g`` (docstring of
    :func:`multiscale_gap_samples`, step 2). ``common=True``: one antithetic set of normals per step, shared by
    every row of ``g`` (shape ``(rows, paths)``; common random numbers for a smooth table in the start gap).

    One step per group: ``r = expit(x)``, ``x = ln(eta_g zeta) = ln(rho |q| E*/2) - ln p(g)`` with
    ``ln p(g) = ln(gamma0/rho) - g/rho`` (no exp: no overflow), then ``g += r (r pw/(2 rho) + sqrt(pw) Z)``, i.e.
    the variance ``v = pw r^2`` and the drift ``v/(2 rho)``. In place on three work arrays (no temporaries), and
    ``expit(x) = (1 + tanh(x/2))/2`` (the same function, a third of scipy's expit's time here)."""
    g = np.array(g, dtype=float)  # a copy: the caller's start gaps stay
    r = np.empty_like(g)
    u = np.empty_like(g)
    half = g.shape[-1] // 2
    z = np.empty(half) if common else u
    for qj, pj in zip(q, pw, strict=True):
        np.multiply(g, 0.5 / rho, out=r)
        r += 0.5 * (base + math.log(qj))
        np.tanh(r, out=r)
        r += 1.0
        r *= 0.5
        rng.standard_normal(out=z)  # into u itself unless common
        if common:
            u[..., :half] = z
            np.negative(z, out=u[..., half:])
        u *= math.sqrt(pj)
        u += (pj / (2.0 * rho)) * r
        u *= r
        g += u
    return g


def _mean_drift(g_start: np.ndarray, q: np.ndarray, pw: np.ndarray, rho: float, base: float,
                rng: np.random.Generator, points: int = DRIFT_POINTS, paths: int = DRIFT_PATHS) -> np.ndarray:
    """``E[g_end | g_start] - g_start`` [length] at every start gap: the process depends on the pixel only through
    its start gap, so a table over ``points`` start gaps (``paths`` antithetic common-random-number paths each;
    Monte-Carlo error about ``std(g_end - g_start)/sqrt(paths)``, smooth in the start gap), linearly
    interpolated."""
    lo, hi = float(g_start.min()), float(g_start.max())
    grid = np.linspace(lo, hi, points) if hi > lo else np.array([lo])
    end = _walk(np.repeat(grid[:, None], paths, axis=1), q, pw, rho, base, rng, common=True)
    return np.interp(g_start, grid, end.mean(axis=1) - grid)


def _level_samples(g_coarse: np.ndarray, shift: float, bracket: float, q: np.ndarray, pw: np.ndarray, rho: float,
                   base: float, samples: int, center: str, rng: np.random.Generator) -> np.ndarray:
    """Samples of one coarse grid: its gap field ``g_coarse`` (with the shift ``shift`` of the unresolved shells
    ``(q, pw)`` and the hybrid's bracket ``bracket``), the process under every (sampled) pixel, then centred."""
    g_pix = np.asarray(g_coarse, float).ravel() - shift  # the bare gap: the pixel's pressure p_c
    target = g_pix + shift - 0.5 * bracket  # a pixel's fine-averaged gap (module docstring, step 3)
    if center == "sample" or g_pix.size <= samples:
        reps = max(1, math.ceil(samples / g_pix.size))
        start, target = np.repeat(g_pix, reps), np.repeat(target, reps)
    else:  # more pixels than samples: a random subset of pixels, one sample each
        pick = rng.choice(g_pix.size, size=samples, replace=False)
        start, target, reps = g_pix[pick], target[pick], 1
    if q.size == 0:
        return start + shift if center != "none" else start
    g = _walk(start.copy(), q, pw, rho, base, rng)
    if center == "pixel":
        g += target - start - _mean_drift(start, q, pw, rho, base, rng)
    elif center == "sample":  # the earlier rule: each pixel's own sample mean (needs many samples per pixel)
        gm = g.reshape(-1, reps)
        gm += (target[::reps] - gm.mean(axis=1))[:, None]
        g = gm.ravel()
    elif center == "mean":
        g += float(np.mean(target)) - float(g.mean())
    return g


def multiscale_gap_samples(
    sigma0: float,
    heights: ArrayLike,
    *,
    rho: float,
    gamma0: float,
    lambda_l: float,
    lambda_s: float | None = None,
    e_star: float = 1.0,
    length: float = 1.0,
    samples: int = 2**17,
    seed: int = 0,
    rtol: float = 0.05,
    max_cost_fraction: float = 0.1,
    tol: float = 1e-8,
    dlnq: float = 0.3,
    center: str = "pixel",
    finest: bool = True,
    l1_tol: float = 0.15,
    check: bool = True,
) -> MultiscaleGaps:
    """Gap samples [length] of the multiscale route (docs/theory.md, "Multiscale gap distribution").

    1. ``improved.hybrid(zeta_c="auto", finest=finest)`` solves GFMD on the modes ``|k| <= k_c`` with the finer
       modes as the renormalised amplitude ``gamma0 exp(Delta/rho)``; ``finest=True`` (default) on the finest
       coarse grid within ``max_cost_fraction`` of full GFMD's cost, because the shape of the distribution at
       high pressure and small ``rho/h_rms`` needs it even where the mean gap has converged (``finest=False``,
       the mean-gap criterion alone, missed L1 = 0.15 there: docs/results/predictors_heldout.md).
       Its pixel ``r`` carries the pressure ``p_c(r)``, i.e. the
       bare gap ``g_c(r) - Delta`` (the gap at which ``(gamma0/rho) exp(-g/rho) = p_c``).
    2. Under every pixel the finer shells of the surface itself (``|h~|^2`` summed per group of width ``dlnq`` in
       ``ln q``, coarse to fine; one step of the process per group: 0.3 by default, chosen on the tuning set of
       benchmarks/results/bounds/ where it met L1 <= 0.15 at 84/84 distributions against 79/84 at the earlier
       0.04, in a quarter of the CPU time, and reported on the held-out set: docs/benchmarks_hybrid.md) are
       added one group at a time with the local response of the gap they ride on
       (M4 with the local stiffness ``p(g)/rho``, as in :func:`local_response_samples`): the variance
       ``v = sum |h~|^2 (eta_g zeta/(1 + eta_g zeta))^2``, ``eta_g zeta = rho |q| E*/(2 p(g))``, and the drift
       ``v/(2 rho)``, which keeps the pixel's pressure ``(gamma0/rho) <exp(-g/rho)>`` exactly (M3 identity:
       ``<exp(-(g + a + sqrt(v) Z)/rho)> = exp(-g/rho)`` iff ``a = v/(2 rho)``). No fitted parameter.

    3. Centring. The coarse solve used the mean-pressure shift ``Delta(sigma0)`` while step 2 adds each pixel's
       local one, so the raw samples disagree with the coarse solve by the hybrid's own error. ``center``:
       "pixel" (default) shifts each pixel's samples by one constant so that their *expected* mean is the
       pixel's coarse gap (the fine modes have zero mean, so a pixel's fine-averaged gap is its coarse gap) less
       half the hybrid's bracket ``shift_error/2`` (the overall mean is then the hybrid's mean gap). The expected
       mean depends on the pixel only through its start gap, so it comes from a table over 65 start gaps (1024
       antithetic common-random-number paths each; ``DRIFT_POINTS``, ``DRIFT_PATHS``), independent of how many
       samples a pixel gets: the fine
       variance is kept in full at any grid size. "sample" is the earlier rule (each pixel's own sample mean,
       which removes the fraction ``1/m`` of the fine variance with ``m`` samples per pixel, all of it at one);
       "mean" shifts all samples by one constant onto the hybrid's mean gap; "none" keeps them (each pixel's
       pressure then stays exactly ``p_c``).

    4. Self-check (``check=True``): the same route from the ladder's previous, twice coarser grid (already
       solved, no extra GFMD), and ``l1_change``, the L1 distance between the two sample sets (80 bins over this
       one's range). ``l1_estimate = L1_SAFETY x l1_change`` estimates the L1 distance to GFMD (the factor chosen
       on the tuning set of benchmarks/results/bounds/); where it exceeds ``l1_tol`` the status is
       "l1_not_met" (where the hybrid's own status is "converged").

    ``lambda_s``: if given, modes finer than it are removed from ``heights`` first. ``samples``: about that many
    (each pixel gets ``ceil(samples / n_c^2)``; with more pixels than samples a random subset of ``samples``
    pixels gets one each; "sample" keeps every pixel). Reproducible from ``seed``.
    """
    from gapsweep.theory import improved

    h = chk.square_heights(heights)
    s = chk.positive(sigma0, "sigma0")
    rho = chk.positive(rho, "rho")
    gamma0 = chk.positive(gamma0, "gamma0")
    lambda_l = chk.positive(lambda_l, "lambda_l")
    length = chk.positive(length, "length")
    e_star = chk.positive(e_star, "e_star")
    samples = chk.count(samples, "samples")
    dlnq = chk.positive(dlnq, "dlnq")
    l1_tol = chk.positive(l1_tol, "l1_tol")
    if center not in ("pixel", "sample", "mean", "none"):
        raise ValueError(f"center must be 'pixel', 'sample', 'mean' or 'none', got {center!r}")
    if lambda_s is not None:
        lambda_s = chk.positive(lambda_s, "lambda_s")
        if not lambda_s < lambda_l:
            raise ValueError(f"lambda_s must be < lambda_l, got lambda_s={lambda_s!r}, lambda_l={lambda_l!r}")
        h = improved._lowpass(h, int(math.floor(length / lambda_s + 1e-9)))
    shells = improved._Shells(h, length)  # one spectrum for the hybrid's ladder and the sampling below
    hyb = improved.hybrid(s, h, zeta_c="auto", rho=rho, gamma0=gamma0, lambda_l=lambda_l, length=length,
                          e_star=e_star, tol=tol, rtol=rtol, max_cost_fraction=max_cost_fraction, finest=finest,
                          _shells=shells)
    if hyb.status not in ("converged", "rtol_not_met"):
        raise RuntimeError(f"multiscale gap distribution: the coarse GFMD solve failed (status {hyb.status!r})")
    base = math.log(rho * e_star / 2.0) - math.log(gamma0 / rho)
    rng = np.random.default_rng(seed)

    def level(k_c: int, res, shift: float, bracket: float) -> tuple[np.ndarray, int]:
        q, pw = improved._grouped(*shells.fine(k_c), dlnq)
        return _level_samples(res.gap, shift, bracket, q, pw, rho, base, samples, center, rng), int(q.size)

    g, groups = level(hyb.k_c, hyb.result, hyb.shift, hyb.shift_error)
    if not np.all(np.isfinite(g)):
        raise FloatingPointError("multiscale gap distribution produced non-finite gaps")
    change = estimate = math.nan
    if groups == 0:
        estimate = 0.0  # nothing left unresolved: the samples are GFMD's own gap field
    elif check and hyb.previous is not None:
        k_p, _, shift_p, err_p, res_p = hyb.previous
        change = l1_distance(level(k_p, res_p, shift_p, err_p)[0], g)
        estimate = L1_SAFETY * change
    status = hyb.status
    if status == "converged" and estimate > l1_tol:
        status = "l1_not_met"
    log.debug("multiscale gaps: n_c=%d k_c=%d groups=%d samples=%d l1_change=%.3g status=%s", hyb.n_c, hyb.k_c,
              groups, g.size, change, status)
    return MultiscaleGaps(g, hyb.n_c, hyb.k_c, groups, hyb.cost, hyb.cost_fraction, status, hyb.mean_gap,
                          hyb.error_estimate, change, estimate)


def gap_distribution(
    sigma0: float,
    heights: ArrayLike,
    *,
    rho: float,
    gamma0: float,
    lambda_l: float,
    lambda_s: float | None = None,
    e_star: float = 1.0,
    length: float = 1.0,
    edges: ArrayLike | None = None,
    bins: int = 200,
    **options,
) -> tuple[np.ndarray, np.ndarray]:
    """Predicted density of GFMD's local gap [1/length] on this surface: ``(edges, density)``, edges [length].

    The histogram of :func:`multiscale_gap_samples` (``options`` are passed to it: ``samples``, ``seed``,
    ``rtol``, ``max_cost_fraction``, ``tol``, ``dlnq``, ``center``) on ``edges`` (default: ``bins`` equal
    bins over the samples' range). Normalised over all samples, so mass outside given ``edges`` is missing
    from the density.
    Measured against GFMD in docs/results/predictors_heldout.md.
    """
    ms = multiscale_gap_samples(sigma0, heights, rho=rho, gamma0=gamma0, lambda_l=lambda_l, lambda_s=lambda_s,
                                e_star=e_star, length=length, **options)
    x = ms.samples
    if edges is None:
        bins = chk.count(bins, "bins")
        lo, hi = float(x.min()), float(x.max())
        e = np.linspace(lo, hi + 1e-9 * (hi - lo + abs(hi)) + 1e-300, bins + 1)  # the maximum in the last bin
    else:
        e = np.asarray(edges, float)
        if e.ndim != 1 or e.size < 2 or not np.all(np.diff(e) > 0):
            raise ValueError("edges must be a strictly increasing 1-D array of at least 2 values")
    counts, _ = np.histogram(x, bins=e)
    return e, counts / (x.size * np.diff(e))
