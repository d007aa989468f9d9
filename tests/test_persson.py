"""Tests of gapsweep.theory.persson and .spectrum against analytic limits and independent quadratures."""

from __future__ import annotations

import math

import mpmath as mp
import numpy as np
import pytest
from scipy import integrate, optimize

from gapsweep import surface
from gapsweep.theory import persson as P
from gapsweep.theory import spectrum as spec

SA = dict(hurst=0.8, lambda_l=0.25, lambda_s=2.5e-3)


# ---------------------------------------------------------------------------------------------------- spectrum
@pytest.mark.validation
def test_self_affine_spectrum_moments():
    sp = spec.self_affine(0.3, lambda_l=0.25, lambda_s=2.5e-3, rms_slope=1.0)
    assert sp.g_rms == pytest.approx(1.0, rel=1e-13)
    assert sp.h_rms == pytest.approx(surface.continuum_rms_height(0.3, lambda_l=0.25, lambda_s=2.5e-3), rel=1e-12)
    sp2 = spec.self_affine(0.3, lambda_l=0.25, lambda_s=2.5e-3, rms_height=0.01)
    assert sp2.h_rms == pytest.approx(0.01, rel=1e-13)
    # c0: h_rms^2 = int q C / (2 pi) dq with C = C0 (q/q_l)^(-2H-2)
    ql, qs, H = 2 * math.pi / 0.25, 2 * math.pi / 2.5e-3, 0.3
    ref = integrate.quad(lambda q: q * (q / ql) ** (-2 * H - 2) / (2 * math.pi), ql, qs, limit=200)[0]
    assert spec.self_affine(H, lambda_l=0.25, lambda_s=2.5e-3, c0=1.0).h_rms ** 2 == pytest.approx(ref, rel=1e-9)


@pytest.mark.validation
def test_from_heights_rectangular_moments():
    rng = np.random.default_rng(1)
    h = rng.normal(size=(24, 40))
    sp = spec.from_heights(h, (2.0, 3.0))
    assert sp.h_rms == pytest.approx(h.std(), rel=1e-12)
    # spectral slope: sum q^2 |h~|^2 with q = 2 pi k / L on each axis
    ht = np.fft.fft2(h) / h.size
    qx = 2 * np.pi * np.fft.fftfreq(24, 1 / 24) / 2.0
    qy = 2 * np.pi * np.fft.fftfreq(40, 1 / 40) / 3.0
    g2 = np.sum((qx[:, None] ** 2 + qy[None, :] ** 2) * np.abs(ht) ** 2)
    assert sp.g_rms**2 == pytest.approx(g2, rel=1e-12)
    assert np.all(np.diff(sp.q) > 0)
    rad = spec.radial(surface.self_affine(256, 0.5, lambda_l=0.5, lambda_s=0.02, seed=3), 1.0)
    assert rad.h_rms == pytest.approx(surface.rms_height(surface.self_affine(256, 0.5, lambda_l=0.5,
                                                                            lambda_s=0.02, seed=3)), rel=0.05)


def test_spectrum_bad_input():
    with pytest.raises(ValueError, match="heights"):
        spec.from_heights(np.zeros(5))
    with pytest.raises(ValueError, match="length"):
        spec.from_heights(np.zeros((4, 4)), (1.0, 2.0, 3.0))
    with pytest.raises(ValueError, match="at most one"):
        spec.self_affine(0.5, lambda_l=1, lambda_s=0.1, rms_slope=1, c0=1)


# ---------------------------------------------------------------------------------------------------- area
@pytest.mark.validation
def test_area_small_load_coefficients():
    """A/A0 -> kappa sigma0/(E* g): sqrt(8/pi) (Persson 2001), sqrt(8/pi)/sqrt(gamma) for the corrected forms
    (their variance grows as gamma V_c once A -> 0)."""
    s = 1e-7
    for e_star in (1.0, 3.0):
        a = P.contact_area(s, e_star=e_star, rms_slope=2.0, **SA)
        assert a * e_star * 2.0 / s == pytest.approx(math.sqrt(8 / math.pi), rel=1e-9)
    a = P.contact_area(s, variant="yang_persson2008", **SA)
    assert a / s == pytest.approx(math.sqrt(8 / math.pi / P.GAMMA_YP), rel=1e-4)
    a = P.contact_area(s, variant="wang_muser2017", **SA)
    assert a / s == pytest.approx(math.sqrt(8 / math.pi / P.GAMMA_WM), rel=1e-4)


@pytest.mark.validation
def test_area_full_contact_and_gamma_one():
    for v in P.VARIANTS:
        assert P.contact_area(20.0, variant=v, **SA) == pytest.approx(1.0, abs=1e-12)
    s = np.logspace(-4, 0.5, 10)
    np.testing.assert_allclose(P.contact_area(s, variant="yang_persson2008", gamma=1.0, **SA),
                               P.contact_area(s, **SA), rtol=1e-8)
    a = P.contact_area(s, variant="wang_muser2017", **SA)
    assert np.all(np.diff(a) > 0) and np.all((a > 0) & (a <= 1))


@pytest.mark.validation
def test_area_corrected_against_stepwise_solution():
    """Independent algorithm: march V over V_c in small steps, solving A = erf(sigma0/sqrt(2V)) by brentq each
    step (implicit Euler), for both corrected variants."""
    sp = spec.self_affine(**SA)
    v_c_total = sp.g_rms**2 / 4
    for variant, gam in (("yang_persson2008", 0.42), ("wang_muser2017", 5 / 9)):
        f = (lambda a, g=gam: g + (1 - g) * a * a) if variant == "yang_persson2008" else \
            (lambda a, g=gam: g - 2 / 9 * a * a + (11 / 9 - g) * a**4)
        for s0 in (0.01, 0.2):
            grid = np.concatenate([[0.0], np.geomspace(1e-9, v_c_total, 20000)])
            v, a = 0.0, 1.0
            for dv in np.diff(grid):
                a = optimize.brentq(lambda x, v=v, dv=dv, s0=s0, f=f: x - math.erf(s0 / math.sqrt(2 * (v + dv * f(x)))),
                                    0.0, 1.0)
                v += dv * f(a)
            assert P.contact_area(s0, variant=variant, **SA) == pytest.approx(a, rel=2e-3)


def test_pressure_distribution_normalisation():
    s0 = 0.05
    for v in ("persson2001", "yang_persson2008"):
        tot = integrate.quad(lambda p, v=v: P.pressure_distribution(p, s0, variant=v, **SA), 0, 20, limit=200)[0]
        assert tot == pytest.approx(P.contact_area(s0, variant=v, **SA), rel=1e-8)


def test_persson_bad_input():
    with pytest.raises(ValueError, match="variant"):
        P.contact_area(0.1, variant="gw", **SA)
    with pytest.raises(ValueError, match="sigma0"):
        P.mean_separation(-1.0, **SA)
    with pytest.raises(ValueError, match="gamma"):
        P.mean_separation(0.1, gamma=0.0, **SA)
    with pytest.raises(ValueError, match="heights="):
        P.contact_area(0.1)


# ---------------------------------------------------------------------------------------------------- separation
@pytest.mark.validation
@pytest.mark.parametrize("y", [1e-6, 0.03, 0.7, 1.0, 2.5, 6.0])
@pytest.mark.parametrize("gam", [0.42, 1.0])
def test_separation_kernel_against_mpmath(y, gam):
    # breakpoints above y only, and more of them past y, at 30 digits: [6, 1, 3, inf] integrated back and forth
    # and lost the 1e-17 tail to cancellation (1 % off at y = 6; [6, inf] alone 1e-5), which the default absolute
    # tolerance of approx (1e-12) hid; hence also abs=0
    with mp.workdps(30):
        pts = sorted({y, *[b for b in (1, 3) if b > y], y + 0.5, y + 1, y + 2, y + 4})
        ref = mp.quad(lambda x: (gam + 3 * (1 - gam) * mp.erf(x) ** 2) * mp.exp(-x * x) / x, [*pts, mp.inf])
    assert float(P.separation_kernel(y, gam)) == pytest.approx(float(ref), rel=1e-12, abs=0)


def _u_direct(s0, gam, hurst=0.8, ql=2 * math.pi / 0.25, qs=2 * math.pi / 2.5e-2):
    """Yang-Persson in Persson's own variables: u = sqrt(pi) int dq q^2 C_P w F(sigma0 w), C_P = C/(2 pi)^2,
    normalised to g_rms = 1, with F by scipy quad (independent of the module's quadratures)."""
    m2 = integrate.quad(lambda q: q**3 * (q / ql) ** (-2 * hurst - 2) / (2 * math.pi), ql, qs)[0]
    c0 = 1.0 / m2  # g_rms^2 = int q^3 C / (2 pi) dq = 1

    def cp(q):
        return c0 * (q / ql) ** (-2 * hurst - 2) / (2 * math.pi) ** 2

    def w(q):
        return (math.pi * integrate.quad(lambda k: k**3 * cp(k), ql, q)[0]) ** -0.5

    def F(y):
        return integrate.quad(lambda x: (gam + 3 * (1 - gam) * math.erf(x) ** 2) * math.exp(-x * x) / x,
                              y, np.inf, limit=200)[0]

    return math.sqrt(math.pi) * integrate.quad(lambda q: q**2 * cp(q) * w(q) * F(s0 * w(q)), ql, qs,
                                               limit=200, points=[ql * 1.01, ql * 2])[0]


@pytest.mark.validation
@pytest.mark.parametrize("s0", [1e-3, 0.05])
def test_mean_separation_against_direct_quadrature(s0):
    for gam in (0.42, 1.0):
        got = P.mean_separation(s0, hurst=0.8, lambda_l=0.25, lambda_s=2.5e-2, gamma=gam)
        assert got == pytest.approx(_u_direct(s0, gam), rel=2e-5)


@pytest.mark.validation
def test_mean_separation_small_load_slope():
    """u -> -u0 ln sigma0 + const, u0 = gamma sqrt(pi) int q^2 C_P w dq = gamma sqrt(2/pi) int_0^g ds / q(s)."""
    sp = spec.self_affine(**SA)
    b = 2 - 2 * SA["hurst"]
    ql, qs = sp.q_l, sp.q_s
    inv_q = integrate.quad(lambda s: (ql**b + s * s * (qs**b - ql**b)) ** (-1 / b), 0, 1)[0]
    for gam in (0.42, 1.0):
        u = P.mean_separation([1e-10, 1e-9], gamma=gam, **SA)
        slope = (u[0] - u[1]) / math.log(10.0)
        u0 = gam * math.sqrt(2 / math.pi) * inv_q
        assert slope == pytest.approx(u0, rel=1e-6)


@pytest.mark.validation
def test_mean_separation_large_load_and_single_mode():
    """Full contact: u -> 0 like exp(-y^2); one cosine mode (a single shell): u = sqrt(2/pi) int_0^g F(c/s) ds / q
    exactly, checked against scipy quad."""
    u = P.mean_separation([0.5, 1.0, 2.0], **SA)
    assert np.all(np.diff(u) < 0) and u[-1] < 1e-7 * P.mean_separation(1e-3, **SA)
    assert u[2] / u[1] < u[1] / u[0] < 0.1  # faster than any power of sigma0
    n, amp = 32, 0.01
    x = np.arange(n) / n
    h = amp * np.cos(2 * np.pi * 3 * x)[:, None] * np.ones(n)[None, :]
    q = 2 * np.pi * 3
    g = amp * q / math.sqrt(2)
    for s0 in (0.01, 0.1):
        c = math.sqrt(2) * s0
        ref = math.sqrt(2 / math.pi) / q * integrate.quad(
            lambda s, c=c: float(P.separation_kernel(c / s, 0.42)) if s > 0 else 0.0, 0, g, limit=200)[0]
        assert P.mean_separation(s0, heights=h, lambda_l=1.0) == pytest.approx(ref, rel=1e-8)


def test_gap_distribution_normalised():
    u = np.linspace(0.0, 0.1, 20001)
    for s0 in (1e-3, 0.1):
        dens, w0 = P.gap_distribution(u, s0, **SA)
        assert w0 >= P.contact_area(s0, **SA)
        assert np.all(dens >= 0)
        assert np.trapezoid(dens, u) + w0 == pytest.approx(1.0, abs=1e-6)
    assert np.all(P.gap_distribution(np.array([-1e-3]), 0.01, **SA)[0] == 0.0)


@pytest.mark.validation
@pytest.mark.parametrize("gam", [P.GAMMA_YP, 1.0, P.GAMMA_WM])
def test_separation_table_against_kernels(gam):
    """The spline table of ``y Hk(y)`` (``persson._hk``, issue 39) against the Gauss-Legendre kernels at points
    between its knots, over its whole range and past both ends: within 1e-10 of ``max |y Hk|``."""
    y = np.exp(np.linspace(math.log(P.Y_LO) - 2.0, math.log(P.Y_HI) + 1.0, 4001) + 0.37 * P.TABLE_STEP)
    t_new, t_old = y * P._hk(y, gam), y * P._hk_exact(y, gam)
    assert np.max(np.abs(t_new - t_old)) <= 1e-10 * np.max(np.abs(t_old))


@pytest.mark.validation
@pytest.mark.parametrize("shape,length", [((96, 96), 1.0), ((75, 75), 2.5), ((64, 80), (1.0, 1.25))])
def test_map_predictions_match_per_shell_kernels(shape, length, monkeypatch):
    """Mean separation (discrete shells) and gap distribution (radial PSD) from a map: the spline-table evaluation
    against the earlier one (every shell's kernels by Gauss-Legendre) on square, odd and rectangular maps, low to
    high load: within 1e-9 relative (separation) and 1e-8 relative at every gap (density)."""
    lx = length if np.ndim(length) == 0 else length[0]
    h = surface.self_affine(shape[0], 0.6, lambda_l=lx / 2, lambda_s=lx / 20, rms_slope=1.0, seed=7, length=lx)
    if shape[1] != shape[0]:
        h = np.random.default_rng(8).standard_normal(shape) * 0.01
    s0 = np.array([1e-5, 1e-3, 3e-2, 0.5])
    kw = dict(heights=h, length=length, lambda_l=lx / 2, periodic=True)
    u_new = P.mean_separation(s0, **kw)
    gaps = np.linspace(0.0, 3.0 * float(u_new[1]), 60)
    d_new, a_new = P.gap_distribution(gaps, 1e-2, **kw)
    monkeypatch.setattr(P, "_hk", P._hk_exact)
    u_old = P.mean_separation(s0, **kw)
    d_old, a_old = P.gap_distribution(gaps, 1e-2, **kw)
    np.testing.assert_allclose(u_new, u_old, rtol=1e-9)
    np.testing.assert_allclose(d_new, d_old, rtol=1e-8, atol=0.0)  # pointwise: the spike at u = 0 hides nothing
    assert a_new == pytest.approx(a_old, abs=1e-14)


@pytest.mark.validation
@pytest.mark.parametrize("shape,length", [((48, 48), 1.0), ((45, 45), 3.0), ((40, 56), 2.0)])
def test_discrete_shells_by_bincount_equal_sorted_grouping(shape, length):
    """Square boxes group the discrete shells by the integer ``kx^2 + ky^2`` (a bincount); the shells, their
    power and mean ``|q|`` equal those of the sorted grouping of rounded ``|q|`` (the general path)."""
    h = np.random.default_rng(3).standard_normal(shape)
    q, power, k2 = spec._power_k2(h, length)
    assert k2 is not None
    fast, slow = spec._group_discrete(q, power, 1.0, k2), spec._group_discrete(q, power, 1.0)
    assert fast.q.size == slow.q.size
    np.testing.assert_allclose(fast.q, slow.q, rtol=1e-14)
    np.testing.assert_allclose(fast.v, slow.v, rtol=1e-12)
    assert spec._power_k2(h, (length, 1.1 * length))[2] is None  # a rectangular box: the sorted path
