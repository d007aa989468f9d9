"""Persson's contact mechanics for a hard wall (no interaction range): contact area, mean separation, pressure and
gap distributions (docs/theory.md, "Persson's theory"; equations and units there).

Notation: ``E*`` is the contact modulus of docs/model.md M1 (the half-space stiffness is ``E* |q| / 2``, the
same as Persson's ``E/(1 - nu^2)``); ``g(q)`` is the rms slope of the roughness resolved up to ``q``
(``g(q)^2 = sum_{q' <= q} q'^2 v(q')``, shells of ``gapsweep.theory.spectrum``), ``g = g(q_s)``. In Persson's
notation ``G(q) = (pi/4)(E*/sigma0)^2 int q'^3 C_P dq' = (E* g(q))^2 / (8 sigma0^2)``, with ``C_P = C/(2 pi)^2``
for the M2 spectrum ``C``. The full-contact pressure variance is ``V_c = E*^2 g^2 / 4``.

Variants of the contact area (``variant``):

``"persson2001"``       ``A/A0 = erf(sigma0 / sqrt(2 V_c)) = erf(sqrt(2) sigma0 / (E* g))`` (Persson 2001).
``"yang_persson2008"``  the pressure variance grows as ``dV = dV_c [gamma + (1 - gamma) A^2]``, ``A = erf(sigma0 /
                        sqrt(2 V))`` (Yang & Persson 2008; ``gamma`` default 0.42).
``"wang_muser2017"``    ``dV = dV_c [gamma - (2/9) A^2 + (11/9 - gamma) A^4]`` (Wang & Muser 2017;
                        ``gamma`` default 5/9).

Mean separation (Persson 2007, with Yang & Persson 2008's elastic-energy correction ``gamma``):
``u = sqrt(pi) int dq q^2 C_P w(q) F(sigma0 w(q) / E*)``, ``w(q) = (pi int q'^3 C_P)^(-1/2) = sqrt(2)/g(q)``,
``F(y) = int_y^inf dx/x [gamma + 3(1 - gamma) erf(x)^2] exp(-x^2)``. In the variable ``s = g(q)`` this is
``u = sqrt(2/pi) int_0^g q(s)^(-1) F(sqrt(2) sigma0 / (E* s)) ds`` (smooth at ``s -> 0``), evaluated exactly per
shell for a discrete spectrum (``q`` constant on a shell). ``gamma = 1`` is Persson (2007).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike
from scipy.integrate import solve_ivp
from scipy.special import erf, exp1

from gapsweep.core import checks as chk
from gapsweep.theory import spectrum as spec

__all__ = [
    "VARIANTS",
    "contact_area",
    "gap_distribution",
    "mean_separation",
    "pressure_distribution",
    "separation_kernel",
]

VARIANTS = ("persson2001", "yang_persson2008", "wang_muser2017")
GAMMA_YP = 0.42
GAMMA_WM = 5.0 / 9.0

_GL_X, _GL_W = np.polynomial.legendre.leggauss(20)
_TAIL = 7.0  # exp(-x^2) integrands are negligible (< 1e-21 relative) beyond y + 7


# --------------------------------------------------------------------------------------------------------------
# spectrum from the keywords
# --------------------------------------------------------------------------------------------------------------
def _map(heights, length, lambda_l, periodic, form: str) -> spec.Spectrum:
    """A map's own spectrum, always through ``spectrum.map_spectrum`` (non-periodic maps handled there; a
    Topography brings its length and periodic flag)."""
    from gapsweep.surfaces.topography import Topography

    if isinstance(heights, Topography):
        return spec.map_spectrum(heights, None if length == 1.0 else length, periodic=periodic,
                                 lambda_l=lambda_l, form=form).spectrum
    if np.ndim(length) == 0:
        heights = chk.square_heights(heights)  # a rectangular map needs length = (Lx, Ly)
    return spec.map_spectrum(heights, length, periodic=periodic, lambda_l=lambda_l, form=form).spectrum


def _spectrum(hurst, lambda_l, lambda_s, rms_slope, rms_height, c0, length, heights,
              periodic=None) -> spec.Spectrum:
    if heights is not None:
        return _map(heights, length, lambda_l, periodic, "discrete")
    if hurst is None or lambda_l is None or lambda_s is None:
        raise ValueError("give hurst, lambda_l and lambda_s (self-affine spectrum) or heights= (a height map)")
    return spec.self_affine(hurst, lambda_l=lambda_l, lambda_s=lambda_s, rms_slope=rms_slope,
                            rms_height=rms_height, c0=c0)


def _gamma(variant: str, gamma: float | None) -> float:
    if variant not in VARIANTS:
        raise ValueError(f"variant must be one of {VARIANTS}, got {variant!r}")
    if gamma is None:
        return {"persson2001": 1.0, "yang_persson2008": GAMMA_YP, "wang_muser2017": GAMMA_WM}[variant]
    g = chk.real(gamma, "gamma")
    if not 0.0 < g <= 11.0 / 9.0:
        raise ValueError(f"gamma must be in (0, 11/9], got {gamma!r}")
    return g


# --------------------------------------------------------------------------------------------------------------
# contact area: dV/dV_c = f(A), a universal ODE in x = V_c / sigma0^2
# --------------------------------------------------------------------------------------------------------------
def _f(variant: str, gamma: float, a: np.ndarray) -> np.ndarray:
    if variant == "yang_persson2008":
        return gamma + (1.0 - gamma) * a * a
    if variant == "wang_muser2017":
        return gamma - (2.0 / 9.0) * a * a + (11.0 / 9.0 - gamma) * a**4
    return np.ones_like(a)


@lru_cache(maxsize=16)
def _variance_solution(variant: str, gamma: float):
    """Dense solution ``y(t) = V/sigma0^2`` of ``dy/dx = f(erf(1/sqrt(2y)))`` in ``t = ln x``, ``y(0) = 0``."""
    t0, t1 = -60.0, 120.0

    def rhs(t, y):
        x = math.exp(t)
        a = math.erf(1.0 / math.sqrt(2.0 * max(y[0], 1e-300)))
        return [x * float(_f(variant, gamma, np.asarray(a)))]

    # y ~ x for x -> 0 (A = 1, f = 1)
    sol = solve_ivp(rhs, (t0, t1), [math.exp(t0)], method="DOP853", rtol=1e-11, atol=1e-300, dense_output=True)
    if not sol.success:
        raise RuntimeError(f"contact-area ODE failed: {sol.message}")
    return sol.sol


def _pressure_variance(sigma0: np.ndarray, v_c: float, variant: str, gamma: float) -> np.ndarray:
    """``V(sigma0)`` [pressure^2] of the variant at full magnification (``V_c`` the full-contact variance)."""
    if variant == "persson2001":
        return np.full_like(sigma0, v_c)
    x = v_c / sigma0**2
    t = np.log(x)
    if np.any(t > 120.0):
        raise ValueError("sigma0 / (E* g_rms) must be >= 1e-26 for the corrected variants")
    y = np.where(t < -60.0, x, 0.0)
    inside = t >= -60.0
    if np.any(inside):
        y[inside] = _variance_solution(variant, gamma)(t[inside])[0]
    return y * sigma0**2


def contact_area(
    sigma0: ArrayLike,
    *,
    hurst: float | None = None,
    lambda_l: float | None = None,
    lambda_s: float | None = None,
    e_star: float = 1.0,
    rms_slope: float | None = None,
    rms_height: float | None = None,
    c0: float | None = None,
    length: float | tuple[float, float] = 1.0,
    variant: str = "persson2001",
    gamma: float | None = None,
    heights: ArrayLike | None = None,
    periodic: bool | None = None,
) -> float | np.ndarray:
    """Relative contact area ``A/A0`` (dimensionless) at mean pressure ``sigma0`` (module docstring).

    The spectrum is the self-affine one of M2 (``hurst``, ``lambda_l``, ``lambda_s`` and one of ``rms_slope``,
    ``rms_height``, ``c0``; default ``rms_slope=1``) or that of ``heights`` (a 2-D map of side ``length``, or a
    Topography), taken by ``spectrum.map_spectrum(heights, length, periodic=periodic)``: ``periodic=None`` uses
    the Topography's flag or the map's edges, False the non-periodic estimator (docs/gfmd.md, "Spectra of
    measured maps"). Only ``g_rms`` enters. Small loads: ``A/A0 -> sqrt(8/pi) sigma0 / (E* g_rms)``
    (persson2001). Vectorised over ``sigma0``.
    """
    s = chk.positive_array(sigma0, "sigma0")
    e_star = chk.positive(e_star, "e_star")
    gam = _gamma(variant, gamma)
    sp = _spectrum(hurst, lambda_l, lambda_s, rms_slope, rms_height, c0, length, heights, periodic)
    v_c = (e_star * sp.g_rms) ** 2 / 4.0
    v = _pressure_variance(s, v_c, variant, gam)
    a = erf(s / np.sqrt(2.0 * v))
    return float(a) if a.ndim == 0 else a


def pressure_distribution(
    p: ArrayLike, sigma0: float, *, variant: str = "persson2001", gamma: float | None = None, e_star: float = 1.0,
    **surface,
) -> float | np.ndarray:
    """Persson's contact-pressure density ``P(p)`` [1/pressure] for ``p > 0``, the diffusion solution with the
    absorbing boundary ``P(0) = 0``: ``P(p) = [N(p; sigma0, V) - N(p; -sigma0, V)]``, ``N`` the normal density,
    ``V`` the pressure variance of ``variant`` (``V_c = E*^2 g^2/4`` for persson2001). ``int_0^inf P dp = A/A0``.
    ``surface``: the spectrum keywords of :func:`contact_area`."""
    pp = chk.finite_array(p, "p")
    s = chk.positive(sigma0, "sigma0")
    e_star = chk.positive(e_star, "e_star")
    gam = _gamma(variant, gamma)
    sp = _spectrum(surface.get("hurst"), surface.get("lambda_l"), surface.get("lambda_s"), surface.get("rms_slope"),
                   surface.get("rms_height"), surface.get("c0"), surface.get("length", 1.0), surface.get("heights"),
                   surface.get("periodic"))
    v = float(_pressure_variance(np.asarray([s]), (e_star * sp.g_rms) ** 2 / 4.0, variant, gam)[0])
    norm = 1.0 / math.sqrt(2.0 * math.pi * v)
    out = norm * (np.exp(-((pp - s) ** 2) / (2 * v)) - np.exp(-((pp + s) ** 2) / (2 * v)))
    out = np.where(pp > 0, out, 0.0)
    return float(out) if out.ndim == 0 else out


# --------------------------------------------------------------------------------------------------------------
# mean separation
# --------------------------------------------------------------------------------------------------------------
def _gl_tail(fun, y: np.ndarray, panels: int = 14) -> np.ndarray:
    """``int_y^{y+7} fun(x) dx`` by composite 20-point Gauss-Legendre (vectorised over ``y``)."""
    y = np.asarray(y, float)
    h = _TAIL / panels
    nodes = (np.arange(panels)[:, None] + 0.5 * (_GL_X[None, :] + 1.0)).ravel() * h
    weights = np.tile(0.5 * _GL_W * h, panels)
    x = y[..., None] + nodes
    return np.sum(fun(x) * weights, axis=-1)


def separation_kernel(y: ArrayLike, gamma: float = GAMMA_YP) -> np.ndarray:
    """``F(y) = int_y^inf dx/x [gamma + 3(1-gamma) erf(x)^2] exp(-x^2)`` (dimensionless), ``y > 0``:
    ``gamma E1(y^2)/2`` plus a smooth remainder by Gauss-Legendre (error < 1e-14)."""
    yy = chk.positive_array(y, "y")
    rest = _gl_tail(lambda x: erf(x) ** 2 * np.exp(-x * x) / x, _near_zero_split(yy))
    rest = rest + _erf2_head(yy)
    return 0.5 * gamma * exp1(yy * yy) + 3.0 * (1.0 - gamma) * rest


def _near_zero_split(y: np.ndarray) -> np.ndarray:
    return np.maximum(y, 1.0)


def _erf2_head(y: np.ndarray) -> np.ndarray:
    """``int_y^max(y,1) erf(x)^2 exp(-x^2)/x dx`` (integrand ~ (4/pi) x near 0: smooth, 20-point GL)."""
    a = np.minimum(y, 1.0)
    half = 0.5 * (1.0 - a)
    x = (a + 1.0)[..., None] * 0.5 + half[..., None] * _GL_X
    f = erf(x) ** 2 * np.exp(-x * x) / x
    return half * np.sum(f * _GL_W, axis=-1)


def _kernel_k(y: np.ndarray, gamma: float) -> np.ndarray:
    """``K(y) = int_y^inf [gamma + 3(1-gamma) erf(x)^2] exp(-x^2) x^(-2) dx``."""
    # gamma part: int_y^inf e^{-x^2}/x^2 = e^{-y^2}/y - sqrt(pi) erfc(y)
    from scipy.special import erfc

    g_part = np.exp(-y * y) / y - math.sqrt(math.pi) * erfc(y)
    lo = np.minimum(y, 1.0)
    half = 0.5 * (1.0 - lo)
    x = (lo + 1.0)[..., None] * 0.5 + half[..., None] * _GL_X
    head = half * np.sum(erf(x) ** 2 * np.exp(-x * x) / x**2 * _GL_W, axis=-1)
    tail = _gl_tail(lambda x: erf(x) ** 2 * np.exp(-x * x) / x**2, np.maximum(y, 1.0))
    return gamma * g_part + 3.0 * (1.0 - gamma) * (head + tail)


def mean_separation(
    sigma0: ArrayLike,
    *,
    hurst: float | None = None,
    lambda_l: float | None = None,
    lambda_s: float | None = None,
    e_star: float = 1.0,
    rms_slope: float | None = None,
    rms_height: float | None = None,
    c0: float | None = None,
    length: float | tuple[float, float] = 1.0,
    variant: str = "persson2001",
    gamma: float = GAMMA_YP,
    heights: ArrayLike | None = None,
    periodic: bool | None = None,
) -> float | np.ndarray:
    """Mean interfacial separation ``u(sigma0)`` [length] of a hard-wall contact (Persson 2007; Yang & Persson 2008).

    ``u = sqrt(2/pi) int_0^g q(s)^(-1) F(sqrt(2) sigma0/(E* s)) ds`` (module docstring), ``gamma`` the
    elastic-energy factor (default 0.42; 1 gives Persson 2007). ``variant`` is accepted for symmetry with
    :func:`contact_area` and validated; the separation uses Persson's 2001 ``P(q)`` inside ``F``, as Yang & Persson
    do. Small loads: ``u -> -u0 ln sigma0 + const`` with ``u0 = gamma sqrt(2/pi) int_0^g q(s)^(-1) ds``.
    Vectorised over ``sigma0``. ``heights``/``periodic``: as in :func:`contact_area`.
    """
    s = chk.positive_array(sigma0, "sigma0")
    e_star = chk.positive(e_star, "e_star")
    _gamma(variant, None)
    gam = chk.real(gamma, "gamma")
    if not 0.0 < gam <= 1.5:
        raise ValueError(f"gamma must be in (0, 1.5], got {gamma!r}")
    sp = _spectrum(hurst, lambda_l, lambda_s, rms_slope, rms_height, c0, length, heights, periodic)
    c = math.sqrt(2.0) * s.ravel() / e_star
    if sp.kind == "continuum":
        out = _u_continuum(c, sp, gam)
    else:
        out = _u_shells(c, sp, gam)
    out = out.reshape(s.shape)
    return float(out) if out.ndim == 0 else out


# The table of ``T(y) = y Hk(y) = F(y) - y K(y)`` (``_hk``): a cubic spline in ``ln y`` on [ln Y_LO, ln Y_HI] with
# knots TABLE_STEP apart. ``T`` is smooth in ``ln y`` (``-gamma ln y + const`` as y -> 0, ``~exp(-y^2)`` beyond 1),
# and the spline's error against the Gauss-Legendre kernels is below 1e-10 of ``max |T|`` (tests/test_persson.py).
# Below Y_LO the kernels are evaluated directly (rare: sigma0 / (E* g) < 1e-8); above Y_HI ``T < 1e-35``: zero.
Y_LO, Y_HI, TABLE_STEP = 1e-8, 9.0, 0.01


@lru_cache(maxsize=8)
def _t_spline(gamma: float):
    from scipy.interpolate import CubicSpline

    t = np.arange(math.log(Y_LO), math.log(Y_HI) + TABLE_STEP, TABLE_STEP)
    y = np.exp(t)
    return CubicSpline(t, separation_kernel(y, gamma) - y * _kernel_k(y, gamma))


def _hk(y: np.ndarray, gamma: float) -> np.ndarray:
    """``Hk(y) = F(y)/y - K(y)`` [1] (``G(s) = int_0^s F(c/s') ds' = c Hk(c/s)``): from the spline of ``y Hk`` (a
    few hundred kernel evaluations once per ``gamma`` instead of ~600 per shell), exact below ``Y_LO``."""
    y = np.asarray(y, float)
    out = np.zeros_like(y)
    mid = (y >= Y_LO) & (y <= Y_HI)
    out[mid] = _t_spline(float(gamma))(np.log(y[mid])) / y[mid]
    low = y < Y_LO
    if np.any(low):
        out[low] = separation_kernel(y[low], gamma) / y[low] - _kernel_k(y[low], gamma)
    return out


def _hk_exact(y: np.ndarray, gamma: float) -> np.ndarray:
    """``Hk`` by the Gauss-Legendre kernels at every point (the earlier evaluation; reference of the table)."""
    return separation_kernel(y, gamma) / y - _kernel_k(y, gamma)


def _u_shells(c: np.ndarray, sp: spec.Spectrum, gamma: float) -> np.ndarray:
    """Exact per shell: ``int_{s_{k-1}}^{s_k} F(c/s) ds = c [Hk(c/s_k) - Hk(c/s_{k-1})]``, ``Hk(y) = F(y)/y - K(y)``
    (``_hk``)."""
    sk = np.sqrt(sp.cumulative_slope2())
    out = np.empty(c.size)
    for i, ci in enumerate(c):
        g_int = ci * _hk(ci / sk, gamma)  # G(s_k) = int_0^{s_k} F(c/s) ds
        seg = np.diff(g_int, prepend=0.0)
        out[i] = math.sqrt(2.0 / math.pi) * np.sum(seg / sp.q)
    return out


def _u_continuum(c: np.ndarray, sp: spec.Spectrum, gamma: float) -> np.ndarray:
    """Gauss-Legendre in ``ln s`` from ``c/8`` (``F(8) ~ 1e-30``) to ``g``, with the exact ``q(s)`` of M2:
    ``g(q)^2 = g^2 (q^b - q_l^b) / (q_s^b - q_l^b)``, ``b = 2 - 2H``."""
    ql, qs, g = float(sp.q_l), float(sp.q_s), sp.g_rms
    b = 2.0 - 2.0 * float(sp.hurst)
    lo = np.log(np.minimum(c / 8.0, g * 0.999))
    hi = math.log(g)
    panels = 60
    nodes = (np.arange(panels)[:, None] + 0.5 * (_GL_X[None, :] + 1.0)).ravel() / panels
    weights = np.tile(0.5 * _GL_W / panels, panels)
    span = hi - lo
    t = lo[:, None] + span[:, None] * nodes[None, :]
    sv = np.exp(t)
    q = (ql**b + (sv / g) ** 2 * (qs**b - ql**b)) ** (1.0 / b)
    f = separation_kernel(c[:, None] / sv, gamma)
    return math.sqrt(2.0 / math.pi) * span * np.sum(weights * sv * f / q, axis=-1)


# --------------------------------------------------------------------------------------------------------------
# gap distribution (Almqvist et al. 2011)
# --------------------------------------------------------------------------------------------------------------
def _u_restricted(c: float, q: np.ndarray, v: np.ndarray, gamma: float) -> float:
    """Mean separation of the shells ``(q, v)`` alone (the per-shell exact form of :func:`_u_shells`)."""
    sk = np.sqrt(np.cumsum(q * q * v))
    g_int = c * _hk(c / sk, gamma)
    seg = np.diff(g_int, prepend=0.0)
    return math.sqrt(2.0 / math.pi) * float(np.sum(seg / q))


def gap_distribution(
    u: ArrayLike,
    sigma0: float,
    *,
    hurst: float | None = None,
    lambda_l: float | None = None,
    lambda_s: float | None = None,
    e_star: float = 1.0,
    rms_slope: float | None = None,
    rms_height: float | None = None,
    c0: float | None = None,
    length: float | tuple[float, float] = 1.0,
    gamma: float = GAMMA_YP,
    heights: ArrayLike | None = None,
    periodic: bool | None = None,
) -> tuple[np.ndarray, float]:
    """Gap (separation) distribution of a hard-wall contact after Almqvist et al. (2011): ``(P(u), A/A0)``.

    ``P(u) = (A(zeta_1)/A0) delta(u) + sum_j [A(zeta_{j-1}) - A(zeta_j)]/A0 * N_mirror(u; u_j, h_j^2)``: the
    area that leaves contact between magnifications ``zeta_{j-1}`` and ``zeta_j`` (Persson 2001 area
    ``A(zeta) = erf(sqrt(2) sigma0/(E* g(zeta)))``) opens with the mean separation ``u_j`` of the roughness
    finer than ``zeta_j`` under the local pressure ``sigma0 A0/A(zeta_j)`` (:func:`mean_separation` of the
    restricted spectrum) and the height variance ``h_j^2`` of that roughness; ``N_mirror(u; m, s^2) =
    N(u; m, s^2) + N(u; -m, s^2)`` on ``u >= 0`` (mass 1). Returns the continuous density [1/length] on ``u``
    and the weight ``A/A0`` of the delta at ``u = 0``; the two integrate to 1. A height map is reduced to its
    radially averaged PSD (``spectrum.map_spectrum(..., form="radial")``, ``periodic`` as in :func:`contact_area`)
    to keep the ``O(shells^2)`` cost small.
    """
    uu = chk.finite_array(u, "u")
    s = chk.positive(sigma0, "sigma0")
    e_star = chk.positive(e_star, "e_star")
    gam = chk.real(gamma, "gamma")
    if not 0.0 < gam <= 1.5:
        raise ValueError(f"gamma must be in (0, 1.5], got {gamma!r}")
    if heights is not None:
        sp = _map(heights, length, lambda_l, periodic, "radial")
    else:
        sp = _spectrum(hurst, lambda_l, lambda_s, rms_slope, rms_height, c0, length, None)
    q, v = sp.q, sp.v
    g = np.sqrt(np.cumsum(q * q * v))
    area = erf(math.sqrt(2.0) * s / (e_star * g))
    prev = np.concatenate([[1.0], area[:-1]])
    d_area = prev - area
    tail_var = np.concatenate([np.cumsum(v[::-1])[::-1][1:], [0.0]])  # variance finer than shell j
    dens = np.zeros_like(uu, dtype=float)
    for j in np.flatnonzero(d_area > 1e-16 * area[0] + 1e-300):
        if tail_var[j] <= 0.0:
            continue  # the last shell: nothing finer, the area it opens has zero separation (added to the delta)
        p_loc = s / area[j]
        m = _u_restricted(math.sqrt(2.0) * p_loc / e_star, q[j + 1:], v[j + 1:], gam)
        sd = math.sqrt(tail_var[j])
        norm = d_area[j] / (sd * math.sqrt(2.0 * math.pi))
        dens += norm * (np.exp(-0.5 * ((uu - m) / sd) ** 2) + np.exp(-0.5 * ((uu + m) / sd) ** 2))
    dens = np.where(uu >= 0, dens, 0.0)
    return dens, float(area[-1] + d_area[-1])
