"""Field theory of the mean gap (docs/model.md M4) and the magnification coefficients of the gap distribution (M5).

All lengths and pressures are in absolute model units (docs/model.md M1: box side ``L``, modulus ``E* = e_star``).
Every public function validates its inputs and raises ``ValueError`` naming the argument and its allowed range;
for valid (finite) inputs the results are finite -- no silent NaN.

Main entry points
-----------------
``mean_gap``            field-theory mean gap, ``form="paper"`` (default) or ``form="continuum"`` (M4).
``mean_gap_discrete``   the same cumulant theory summed over the actual Fourier modes of one surface (M4).
``rigid_mean_gap``      exact rigid (u = 0) mean gap of one surface, overflow-safe log-sum-exp (M3, M4).
``drift``/``diffusion`` the Fokker-Planck / SDE coefficients ``D1(zeta)``, ``D2(zeta)`` (M5).
``rigid_gap_density``   the Gaussian low-pressure reference gap distribution (M5).

Numerical method of ``roughness_integral`` (see docs/theory.md for the error bound):
with ``t = ln z`` the integral ``int_1^zeta (eta z/(1+eta z))^2 z^(-2H-1) dz`` becomes
``int_0^{ln zeta} expit(ln eta + t)^2 exp(-2 H t) dt``. The integrand is analytic in the strip
``|Im t| < pi`` (the only singularities are the poles of the logistic function ``expit``), so fixed 20-point
Gauss-Legendre rules on panels of length <= 2 converge geometrically with a provable relative error below
1e-15 for every ``eta``, ``H`` and ``zeta`` -- no branch for small or large ``eta`` and no cancellation
(the integrand is positive, and ``eta z/(1+eta z)`` is evaluated as ``1/(1 + 1/(eta z))``).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike
from scipy.special import logsumexp

from gapsweep.core import checks as chk
from gapsweep.theory import domain, spectrum

__all__ = [
    "diffusion",
    "drift",
    "eta",
    "flat_gap",
    "high_pressure_limit",
    "low_pressure_limit",
    "mean_gap",
    "mean_gap_discrete",
    "mean_gap_spectrum",
    "rigid_gap_density",
    "rigid_mean_gap",
    "roughness_integral",
]

FORMS = ("paper", "continuum")

# Gauss-Legendre order per panel and the longest panel in t = ln z (see module docstring, docs/theory.md).
_GL_ORDER = 20
_PANEL_MAX = 2.0
# Elements processed per block in vectorised evaluations (bounds the temporary (block, nodes) arrays).
_BLOCK = 16384


# --------------------------------------------------------------------------------------------------------------
# validation helpers
# --------------------------------------------------------------------------------------------------------------
def _zeta_array(zeta: ArrayLike, name: str = "zeta") -> np.ndarray:
    z = chk.finite_array(zeta, name)
    if np.any(z < 1.0):
        raise ValueError(f"{name} must be >= 1 (magnification zeta = q/q_l, docs/model.md M2) and finite")
    return z


def _out(a: np.ndarray) -> float | np.ndarray:
    """Return a Python float for 0-d results, the array otherwise."""
    return float(a) if np.ndim(a) == 0 else a


# --------------------------------------------------------------------------------------------------------------
# elementary pieces
# --------------------------------------------------------------------------------------------------------------
def _log_eta(sigma0: np.ndarray, rho: float, lambda_l: float, e_star: float) -> np.ndarray:
    # ln(eta) computed as a difference of logs: eta itself may overflow for sigma0 -> 0.
    return math.log(rho * (2.0 * math.pi / lambda_l) * e_star / 2.0) - np.log(sigma0)


def eta(sigma0: ArrayLike, *, rho: float, lambda_l: float, e_star: float = 1.0) -> float | np.ndarray:
    """Dimensionless pressure parameter ``eta = rho q_l E* / (2 sigma0)``, ``q_l = 2 pi / lambda_l`` (M4).

    Large ``eta`` is low pressure (rigid-like), small ``eta`` high pressure (surface flattened).
    """
    s = chk.positive_array(sigma0, "sigma0")
    rho = chk.positive(rho, "rho")
    lambda_l = chk.positive(lambda_l, "lambda_l")
    e_star = chk.positive(e_star, "e_star")
    return _out(np.exp(_log_eta(s, rho, lambda_l, e_star)))


def flat_gap(sigma0: ArrayLike, *, rho: float, gamma0: float) -> float | np.ndarray:
    """Mean gap of a flat surface, ``rho ln(gamma0 / (rho sigma0))`` [length] (M4, first term).

    Computed as ``rho (ln gamma0 - ln rho - ln sigma0)`` so that no intermediate over- or underflows.
    """
    s = chk.positive_array(sigma0, "sigma0")
    rho = chk.positive(rho, "rho")
    gamma0 = chk.positive(gamma0, "gamma0")
    return _out(rho * (math.log(gamma0) - math.log(rho) - np.log(s)))


def high_pressure_limit(sigma0: ArrayLike, *, rho: float, gamma0: float) -> float | np.ndarray:
    """High-pressure (``eta << 1``) limit of the mean gap: ``g0 -> rho ln(gamma0/(rho sigma0))`` (M4)."""
    return flat_gap(sigma0, rho=rho, gamma0=gamma0)


def low_pressure_limit(sigma0: ArrayLike, *, h_rms: float, rho: float, gamma0: float) -> float | np.ndarray:
    """Low-pressure (``eta >> 1``) limit: ``g0 -> rho ln(gamma0/(rho sigma0)) + h_rms^2 / (2 rho)`` (M4).

    This is also the exact rigid mean gap of a Gaussian surface (``ln<exp(h/rho)> = h_rms^2/(2 rho^2)``).
    ``form="continuum"`` of :func:`mean_gap` tends to it exactly; ``form="paper"`` tends to it with the roughness
    term multiplied by ``1 - zeta_s^(-2H)``.
    """
    h_rms = chk.nonnegative(h_rms, "h_rms")
    rho = chk.positive(rho, "rho")
    return _out(np.asarray(flat_gap(sigma0, rho=rho, gamma0=gamma0)) + h_rms**2 / (2.0 * rho))


# --------------------------------------------------------------------------------------------------------------
# the roughness integral
# --------------------------------------------------------------------------------------------------------------
@lru_cache(maxsize=64)
def _unit_rule(panels: int) -> tuple[np.ndarray, np.ndarray]:
    """Composite Gauss-Legendre rule on [0, 1] with ``panels`` equal panels of ``_GL_ORDER`` nodes each."""
    x, w = np.polynomial.legendre.leggauss(_GL_ORDER)
    j = np.arange(panels)[:, None]
    nodes = ((j + 0.5 * (x[None, :] + 1.0)) / panels).ravel()
    weights = np.broadcast_to(0.5 * w[None, :] / panels, (panels, _GL_ORDER)).ravel().copy()
    nodes.setflags(write=False)
    weights.setflags(write=False)
    return nodes, weights


def _integral_from_log_eta(log_eta: np.ndarray, zeta: np.ndarray, hurst: float) -> np.ndarray:
    """``int_1^zeta (eta z/(1+eta z))^2 z^(-2H-1) dz`` for broadcastable ``ln eta`` and ``zeta`` (>= 1)."""
    log_eta, zeta = np.broadcast_arrays(np.asarray(log_eta, float), np.asarray(zeta, float))
    shape = log_eta.shape
    le = log_eta.ravel()
    lz = np.log(zeta.ravel())
    out = np.empty(le.shape, dtype=float)
    if out.size == 0:
        return out.reshape(shape)
    panels = max(1, math.ceil(float(lz.max()) / _PANEL_MAX))
    nodes, weights = _unit_rule(panels)
    scalar_zeta = bool(np.all(lz == lz[0]))
    if scalar_zeta:
        # One set of nodes for all pressures: z_k and w_k z_k^(-2H) are computed once.
        t = lz[0] * nodes
        wk = (lz[0] * weights) * np.exp(-2.0 * hurst * t)
        log_inv_z = -t
    for i0 in range(0, le.size, _BLOCK):
        sl = slice(i0, i0 + _BLOCK)
        if not scalar_zeta:
            t = lz[sl, None] * nodes[None, :]
            wk = (lz[sl, None] * weights[None, :]) * np.exp(-2.0 * hurst * t)
            log_inv_z = -t
        # u = 1/(eta z) = exp(-ln eta - t); s = eta z/(1 + eta z) = 1/(1 + u) is accurate to a few ulp for any u
        # (u -> inf gives s -> 0 without NaN). The exponent is clipped so exp never overflows.
        with np.errstate(over="ignore", under="ignore"):
            u = np.exp(np.minimum(log_inv_z - le[sl, None], 700.0))
            s = 1.0 / (1.0 + u)
            out[sl] = np.sum(wk * (s * s), axis=-1)
    return out.reshape(shape)


def roughness_integral(eta: ArrayLike, zeta: ArrayLike, hurst: float) -> float | np.ndarray:
    """``I(eta, zeta, H) = int_1^zeta (eta z / (1 + eta z))^2 z^(-2H-1) dz`` (dimensionless, M4).

    Broadcasts over ``eta`` (> 0) and ``zeta`` (>= 1). Relative accuracy better than 1e-13 for
    ``1e-100 < eta < 1e100`` (composite Gauss-Legendre in ``ln z``, see the module docstring).
    Limits: ``I -> eta^2 (zeta^(2-2H) - 1)/(2-2H)`` for ``eta -> 0`` and ``(1 - zeta^(-2H))/(2H)`` for
    ``eta -> inf``.
    """
    e = chk.positive_array(eta, "eta")
    z = _zeta_array(zeta)
    hurst = chk.hurst(hurst)
    return _out(_integral_from_log_eta(np.log(e), z, hurst))


# --------------------------------------------------------------------------------------------------------------
# mean gap: continuum forms
# --------------------------------------------------------------------------------------------------------------
def _check_wavelengths(lambda_l: float, lambda_s: float) -> tuple[float, float]:
    lambda_l = chk.positive(lambda_l, "lambda_l")
    lambda_s = chk.positive(lambda_s, "lambda_s")
    if not lambda_s < lambda_l:
        raise ValueError(f"lambda_s must be < lambda_l, got lambda_s={lambda_s!r}, lambda_l={lambda_l!r}")
    return lambda_l, lambda_s


def mean_gap(
    sigma0: ArrayLike,
    *,
    hurst: float | None = None,
    h_rms: float | None = None,
    rho: float,
    gamma0: float,
    lambda_l: float,
    lambda_s: float | None = None,
    e_star: float = 1.0,
    zeta: ArrayLike | None = None,
    form: str | None = None,
    heights: ArrayLike | None = None,
    length: float | tuple[float, float] = 1.0,
) -> float | np.ndarray:
    """Field-theory mean gap ``g0(sigma0)`` [length] (docs/model.md M4, paper Eq. mean-gap-field).

    ``g0 = rho ln(gamma0/(rho sigma0)) + (P/rho) int_1^zeta (eta z/(1+eta z))^2 z^(-2H-1) dz``, with
    ``eta = rho q_l E*/(2 sigma0)`` and prefactor ``P = H h_rms^2`` (``form="paper"``, default, the paper's
    closed form, which assumes ``zeta_s^(-2H) << 1``) or ``P = H h_rms^2 / (1 - zeta_s^(-2H))``
    (``form="continuum"``, the exact normalisation of a spectrum cut at ``zeta_s = lambda_l/lambda_s``, whose
    low-pressure limit is exactly ``flat + h_rms^2/(2 rho)``).

    ``zeta=None`` integrates up to ``zeta_s``; ``sigma0`` and ``zeta`` broadcast against each other.
    ``h_rms`` is the rms height of the full spectrum (up to ``zeta_s``) in both forms.

    The surface's own spectrum: ``heights=`` (a 2-D map of side ``length``; a pair ``(Lx, Ly)`` for a
    rectangular map) replaces ``hurst``, ``h_rms`` and ``lambda_s``. ``form="continuum"`` (the default then) sums
    the radially averaged PSD (``theory.spectrum.radial``), ``form="discrete"`` every Fourier mode (as
    :func:`mean_gap_discrete`); ``zeta`` is not used.
    """
    if heights is not None:
        form = "continuum" if form is None else form
        if form not in ("continuum", "discrete"):
            raise ValueError(f"form must be 'continuum' or 'discrete' with heights=, got {form!r}")
        if zeta is not None:
            raise ValueError("zeta is not supported with heights= (the spectrum of the map is summed in full)")
        hs = _heights(heights, length)
        sp = spectrum.radial(hs, length) if form == "continuum" else spectrum.from_heights(hs, length)
        _check_domain(sigma0, rho=rho, h_rms=sp.h_rms, g_rms=sp.g_rms, e_star=e_star)
        return mean_gap_spectrum(sigma0, sp, rho=rho, gamma0=gamma0, e_star=e_star)
    form = "paper" if form is None else form
    for name, val in (("hurst", hurst), ("h_rms", h_rms), ("lambda_s", lambda_s)):
        if val is None:
            raise ValueError(f"{name} is required unless heights= gives the surface's own spectrum")
    s = chk.positive_array(sigma0, "sigma0")
    hurst = chk.hurst(hurst)
    h_rms = chk.nonnegative(h_rms, "h_rms")
    rho = chk.positive(rho, "rho")
    gamma0 = chk.positive(gamma0, "gamma0")
    lambda_l, lambda_s = _check_wavelengths(lambda_l, lambda_s)
    e_star = chk.positive(e_star, "e_star")
    if form not in FORMS:
        raise ValueError(f"form must be one of {FORMS}, got {form!r}")
    zeta_s = lambda_l / lambda_s
    z = np.asarray(zeta_s) if zeta is None else _zeta_array(zeta)
    prefactor = hurst * h_rms**2
    if form == "continuum":
        # 1 - zeta_s^(-2H) via expm1: accurate also when zeta_s is close to 1.
        prefactor /= -math.expm1(-2.0 * hurst * math.log(zeta_s))
    integral = _integral_from_log_eta(_log_eta(s, rho, lambda_l, e_star), z, hurst)
    flat = rho * (math.log(gamma0) - math.log(rho) - np.log(s))
    if zeta is None and h_rms > 0.0:
        g_rms = spectrum.self_affine(hurst, lambda_l=lambda_l, lambda_s=lambda_s, rms_height=h_rms).g_rms
        _check_domain(s, rho=rho, h_rms=h_rms, g_rms=g_rms, e_star=e_star)
    return _out(flat + (prefactor / rho) * integral)


#: the field theory's validated domain (docs/theory.md, "Validity", held-out sets against GFMD): within 5 %
#: wherever ``rho/h_rms >= 0.5``, or ``rho/h_rms >= 0.12`` at ``sigma0/(E* g_rms) >= 0.1``; elsewhere up to
#: +209 % off (issue 39: H = 0.9, ``rho/h_rms = 0.05``)
DOMAIN_RHO_OVER_H_RMS = 0.5
DOMAIN_HIGH_PRESSURE = (0.12, 0.1)  # (rho/h_rms, sigma0/(E* g_rms)) both at least


def _check_domain(sigma0: ArrayLike, *, rho: float, h_rms: float, g_rms: float, e_star: float) -> None:
    """Warn once (:class:`gapsweep.theory.domain.PredictorDomainWarning`) if any ``sigma0`` lies outside the
    field theory's validated domain (the constants above)."""
    if not h_rms > 0.0 or not g_rms > 0.0:
        return
    rr = rho / h_rms
    if rr >= DOMAIN_RHO_OVER_H_RMS:
        return
    p = np.asarray(sigma0, float).ravel() / (e_star * g_rms)
    rr_hi, p_hi = DOMAIN_HIGH_PRESSURE
    outside = np.ones(p.shape, bool) if rr < rr_hi else p < p_hi
    if outside.any():
        domain.warn_outside("field theory (mean gap)",
                            f"rho/h_rms = {rr:.3g} < {DOMAIN_RHO_OVER_H_RMS} at {int(outside.sum())} of {p.size} "
                            f"pressures (validated there only for rho/h_rms >= {rr_hi} and "
                            f"sigma0/(E* g_rms) >= {p_hi}; docs/theory.md, 'Validity')", stacklevel=4)


# --------------------------------------------------------------------------------------------------------------
# mean gap: discrete form for one surface, exact rigid limit
# --------------------------------------------------------------------------------------------------------------
def _heights(heights: ArrayLike, length: float | tuple[float, float]) -> np.ndarray:
    """A square map for a scalar ``length`` (the M1 box), any ``nx x ny`` map for ``length = (Lx, Ly)``."""
    if np.ndim(length) == 0:
        return chk.square_heights(heights)
    return spectrum.heights_array(heights)


def mean_gap_spectrum(
    sigma0: ArrayLike, spec: spectrum.Spectrum, *, rho: float, gamma0: float, e_star: float = 1.0
) -> float | np.ndarray:
    """Field-theory mean gap on a spectrum of shells ``(q_k, v_k)`` [length] (M4):

    ``g0 = rho ln(gamma0/(rho sigma0)) + (1/(2 rho)) sum_k v_k (eta zeta_k/(1 + eta zeta_k))^2``, with
    ``eta zeta_k = rho q_k E*/(2 sigma0)``. Vectorised over ``sigma0``.
    """
    s = chk.positive_array(sigma0, "sigma0")
    rho = chk.positive(rho, "rho")
    gamma0 = chk.positive(gamma0, "gamma0")
    e_star = chk.positive(e_star, "e_star")
    le = np.log(s).ravel()
    rough = np.empty(le.shape, dtype=float)
    # ln(1/(eta zeta_k)) = ln sigma0 - ln(rho q_k E*/2)
    log_inv = -np.log(rho * spec.q * e_star / 2.0) if spec.q.size else spec.q
    block = max(1, _BLOCK * 64 // max(1, spec.q.size))
    for i0 in range(0, le.size, block):
        sl = slice(i0, i0 + block)
        with np.errstate(over="ignore", under="ignore"):
            u = np.exp(np.minimum(log_inv[None, :] + le[sl, None], 700.0))
            r = 1.0 / (1.0 + u)
            rough[sl] = (r * r) @ spec.v
    flat = rho * (math.log(gamma0) - math.log(rho) - np.log(s))
    return _out(flat + rough.reshape(s.shape) / (2.0 * rho))


def mean_gap_discrete(
    sigma0: ArrayLike,
    heights: ArrayLike,
    *,
    rho: float,
    gamma0: float,
    lambda_l: float,
    length: float | tuple[float, float] = 1.0,
    e_star: float = 1.0,
) -> float | np.ndarray:
    """Field-theory mean gap summed over the actual Fourier modes of one surface [length] (M4).

    ``g0 = rho ln(gamma0/(rho sigma0)) + (1/(2 rho)) sum_{q != 0} |h~(q)|^2 (eta zeta_q/(1 + eta zeta_q))^2``,
    ``h~ = fft2(h)/(nx ny)`` (M2), ``zeta_q = |q|/q_l``, ``eta = rho q_l E*/(2 sigma0)``. ``lambda_l`` only sets
    the unit of ``zeta`` (``eta zeta_q = rho |q| E*/(2 sigma0)`` does not depend on it).
    The mean gap is measured from the mean plane of ``heights`` (the q = 0 mode is excluded), as everywhere in
    gapsweep (``<h> = 0``, M2). A rectangular ``nx x ny`` map needs ``length = (Lx, Ly)``. Vectorised over
    ``sigma0``.
    """
    s = chk.positive_array(sigma0, "sigma0")
    h = _heights(heights, length)
    rho = chk.positive(rho, "rho")
    gamma0 = chk.positive(gamma0, "gamma0")
    lambda_l = chk.positive(lambda_l, "lambda_l")
    spectrum.lengths(length)
    e_star = chk.positive(e_star, "e_star")
    return mean_gap_spectrum(s, spectrum.from_heights(h, length, lambda_l=lambda_l), rho=rho, gamma0=gamma0,
                             e_star=e_star)


def rigid_mean_gap(heights: ArrayLike, sigma0: ArrayLike, *, rho: float, gamma0: float) -> float | np.ndarray:
    """Exact rigid-limit (u = 0) mean gap of one surface, ``rho ln[(gamma0/(rho sigma0)) <exp(h/rho)>]`` (M3, M4).

    ``heights`` are taken relative to their mean plane (``<h> = 0``, M2), so the result is the mean gap
    ``<g>``. ``ln<exp(h/rho)>`` is evaluated as a log-sum-exp: no overflow or underflow whatever
    ``h_rms/rho`` is (tested at 50 and 1000). Vectorised over ``sigma0``. ``heights`` may have any shape.
    """
    h = chk.finite_array(heights, "heights")  # TypeError for complex heights
    if h.size == 0:
        raise ValueError("heights must not be empty")
    s = chk.positive_array(sigma0, "sigma0")
    rho = chk.positive(rho, "rho")
    gamma0 = chk.positive(gamma0, "gamma0")
    w = (h - h.mean()) / rho
    log_mean_exp = float(logsumexp(w)) - math.log(w.size)
    return _out(rho * (math.log(gamma0) - math.log(rho) - np.log(s) + log_mean_exp))


# --------------------------------------------------------------------------------------------------------------
# Fokker-Planck / SDE coefficients (M5)
# --------------------------------------------------------------------------------------------------------------
def _response_shell(
    zeta: np.ndarray, sigma0: np.ndarray, hurst: float, rho: float, lambda_l: float, e_star: float
) -> np.ndarray:
    """``(eta zeta/(1+eta zeta))^2 zeta^(-2H-1)`` (broadcast), overflow-safe."""
    le = _log_eta(sigma0, rho, lambda_l, e_star)
    with np.errstate(over="ignore", under="ignore"):
        u = np.exp(np.minimum(-np.log(zeta) - le, 700.0))
        r = 1.0 / (1.0 + u)
        return r * r * zeta ** (-2.0 * hurst - 1.0)


def _checked_shell(
    zeta: ArrayLike, sigma0: ArrayLike, hurst: float, h_rms: float, rho: float, lambda_l: float, e_star: float
) -> tuple[float, float, float, np.ndarray]:
    """Validate the arguments ``drift`` and ``diffusion`` share; return ``(hurst, h_rms, rho, response shell)``."""
    z = _zeta_array(zeta)
    s = chk.positive_array(sigma0, "sigma0")
    hurst = chk.hurst(hurst)
    h_rms = chk.nonnegative(h_rms, "h_rms")
    rho = chk.positive(rho, "rho")
    lambda_l = chk.positive(lambda_l, "lambda_l")
    e_star = chk.positive(e_star, "e_star")
    return hurst, h_rms, rho, _response_shell(z, s, hurst, rho, lambda_l, e_star)


def drift(
    zeta: ArrayLike,
    sigma0: ArrayLike,
    *,
    hurst: float,
    h_rms: float,
    rho: float,
    lambda_l: float,
    e_star: float = 1.0,
) -> float | np.ndarray:
    """Drift ``D1(zeta) = d g0/d zeta = (H h_rms^2/rho) (eta zeta/(1+eta zeta))^2 zeta^(-2H-1)`` [length] (M5).

    The derivative of ``mean_gap(..., form="paper")`` with respect to its upper limit ``zeta``.
    Broadcasts over ``zeta`` (>= 1) and ``sigma0``.
    """
    hurst, h_rms, rho, shell = _checked_shell(zeta, sigma0, hurst, h_rms, rho, lambda_l, e_star)
    return _out((hurst * h_rms**2 / rho) * shell)


def diffusion(
    zeta: ArrayLike,
    sigma0: ArrayLike,
    *,
    hurst: float,
    h_rms: float,
    rho: float,
    lambda_l: float,
    e_star: float = 1.0,
    c1: float | None = None,
) -> float | np.ndarray:
    """Diffusion ``D2(zeta) = C1 (eta zeta/(1+eta zeta))^2 zeta^(-2H-1)`` [length^2] (M5).

    ``c1=None`` uses ``C1 = H h_rms^2`` (the variance a roughness shell adds, filtered by the linear response;
    then ``D2 = rho D1``). ``c1`` must be >= 0. Broadcasts over ``zeta`` (>= 1) and ``sigma0``.
    """
    hurst, h_rms, rho, shell = _checked_shell(zeta, sigma0, hurst, h_rms, rho, lambda_l, e_star)
    c = hurst * h_rms**2 if c1 is None else chk.nonnegative(c1, "c1")
    return _out(c * shell)


def rigid_gap_density(
    g: ArrayLike, sigma0: ArrayLike, *, h_rms: float, rho: float, gamma0: float
) -> float | np.ndarray:
    """Low-pressure (rigid, u = 0) reference gap density ``P(g)`` [1/length] (M5).

    In the rigid limit ``g(r) = g0 - h(r)``: for a Gaussian surface ``P(g)`` is a Gaussian of variance
    ``h_rms^2`` centred on the rigid mean gap ``g0 = rho ln(gamma0/(rho sigma0)) + h_rms^2/(2 rho)``, which is
    the exact ``rho ln[(gamma0/(rho sigma0)) <exp(h/rho)>]`` for Gaussian heights and equals the low-pressure
    limit of M4 (and of ``mean_gap(form="continuum")``). Broadcasts over ``g`` and ``sigma0``.
    """
    gg = chk.finite_array(g, "g")
    h_rms = chk.positive(h_rms, "h_rms")
    g0 = np.asarray(low_pressure_limit(sigma0, h_rms=h_rms, rho=rho, gamma0=gamma0))
    x = (gg - g0) / h_rms
    return _out(np.exp(-0.5 * x * x) / (h_rms * math.sqrt(2.0 * math.pi)))
