"""Tests of gapsweep.theory (docs/model.md M4, M5) against mpmath, asymptotic expansions and independent methods."""

from __future__ import annotations

import math

import mpmath as mp
import numpy as np
import pytest

from gapsweep import theory as th

# Figure-2 parameters (docs/model.md M6) used as the default physical setting.
P = dict(hurst=0.3, h_rms=0.02, rho=2e-3, gamma0=1e-3, lambda_l=0.25, lambda_s=2.5e-3)
Q_L = 2 * math.pi / P["lambda_l"]


def sigma_for_eta(eta, rho=P["rho"], e_star=1.0):
    """Invert eta = rho q_l E*/(2 sigma0)."""
    return rho * Q_L * e_star / (2.0 * np.asarray(eta, dtype=float))


# ----------------------------------------------------------------------------------------------------------
# high-precision references
# ----------------------------------------------------------------------------------------------------------
def integral_quad(eta, zeta, hurst, dps=30):
    """mpmath.quad of int_1^zeta (eta z/(1+eta z))^2 z^(-2H-1) dz, split around the crossover z = 1/eta."""
    with mp.workdps(dps):
        eta, zeta, hurst = mp.mpf(eta), mp.mpf(zeta), mp.mpf(hurst)

        def f(z):
            return (eta * z / (1 + eta * z)) ** 2 * z ** (-2 * hurst - 1)

        c = 1 / eta
        pts = [mp.mpf(1)] + [p for p in (c / 10, c, 10 * c) if 1 < p < zeta] + [zeta]
        return mp.quad(f, pts)


def integral_hyp2f1(eta, zeta, hurst, dps=80):
    """Closed form eta^2 [F(zeta) - F(1)], F(x) = x^b/b 2F1(2, b; b+1; -eta x), b = 2 - 2H (high precision
    because the two terms cancel for large eta)."""
    with mp.workdps(dps):
        eta, zeta, hurst = mp.mpf(eta), mp.mpf(zeta), mp.mpf(hurst)
        b = 2 - 2 * hurst

        def F(x):
            return x**b / b * mp.hyp2f1(2, b, b + 1, -eta * x)

        return eta**2 * (F(zeta) - F(mp.mpf(1)))


# ----------------------------------------------------------------------------------------------------------
# the roughness integral and mean_gap against mpmath (M7 "extreme eta")
# ----------------------------------------------------------------------------------------------------------
@pytest.mark.validation
@pytest.mark.parametrize("hurst", [0.05, 0.3, 0.8, 0.95])
@pytest.mark.parametrize("zeta", [1.5, 100.0, 1e4])
def test_integral_against_mpmath(hurst, zeta):
    etas = np.logspace(-6, 6, 13)
    got = th.roughness_integral(etas, zeta, hurst)
    ref = np.array([float(integral_quad(e, zeta, hurst)) for e in etas])
    np.testing.assert_allclose(got, ref, rtol=1e-10, atol=0)


@pytest.mark.validation
@pytest.mark.parametrize("eta", [1e-6, 1e-2, 1.0, 1e3, 1e6])
def test_mpmath_references_agree(eta):
    # The quadrature reference itself is checked against the hypergeometric closed form.
    q = integral_quad(eta, 100.0, 0.3, dps=30)
    h = integral_hyp2f1(eta, 100.0, 0.3)
    assert abs(q - h) <= mp.mpf("1e-25") * abs(h)


@pytest.mark.validation
def test_mean_gap_against_mpmath_extreme_pressures():
    # sigma0 from 1e-7 to 10 (docs/model.md M7) at figure-2 parameters, both forms.
    sigma0 = np.logspace(-7, 1, 9)
    zeta_s = P["lambda_l"] / P["lambda_s"]
    for form in ("paper", "continuum"):
        got = th.mean_gap(sigma0, **P, form=form)
        for s, g in zip(sigma0, got):
            with mp.workdps(30):
                eta = mp.mpf(P["rho"]) * mp.mpf(Q_L) / (2 * mp.mpf(s))
                pref = mp.mpf(P["hurst"]) * mp.mpf(P["h_rms"]) ** 2
                if form == "continuum":
                    pref /= 1 - mp.mpf(zeta_s) ** (-2 * mp.mpf(P["hurst"]))
                flat = P["rho"] * mp.log(mp.mpf(P["gamma0"]) / (mp.mpf(P["rho"]) * mp.mpf(s)))
                rough = pref / P["rho"] * integral_quad(eta, zeta_s, P["hurst"])
                ref = flat + rough
            # relative to the size of the terms (the sum may cancel for large sigma0)
            assert abs(g - float(ref)) <= 1e-10 * float(abs(flat) + rough), (form, s)


def test_many_pressures_finite_monotone():
    # 1e5 pressures across M7's extreme range: finite and strictly decreasing mean gap.
    sigma0 = np.logspace(-7, 1, 100_000)
    g = th.mean_gap(sigma0, **P)
    assert g.shape == sigma0.shape
    assert np.all(np.isfinite(g))
    assert np.all(np.diff(g) < 0)


def test_scalar_and_broadcasting():
    g = th.mean_gap(1e-3, **P)
    assert isinstance(g, float)
    sigma0 = np.array([1e-4, 1e-2])[:, None]
    zetas = np.array([1.0, 3.0, 50.0, 100.0])[None, :]
    grid = th.mean_gap(sigma0, **P, zeta=zetas)
    assert grid.shape == (2, 4)
    for i in range(2):
        for j in range(4):
            assert grid[i, j] == pytest.approx(th.mean_gap(sigma0[i, 0], **P, zeta=zetas[0, j]), rel=1e-14)
    # zeta = 1: no roughness, the flat gap exactly
    np.testing.assert_allclose(grid[:, 0], th.flat_gap(sigma0[:, 0], rho=P["rho"], gamma0=P["gamma0"]))


# ----------------------------------------------------------------------------------------------------------
# limits (M4)
# ----------------------------------------------------------------------------------------------------------
@pytest.mark.validation
def test_high_pressure_asymptotics():
    h, z = 0.3, 100.0
    a1 = (z ** (2 - 2 * h) - 1) / (2 - 2 * h)
    a2 = (z ** (3 - 2 * h) - 1) / (3 - 2 * h)
    for eta in (1e-6, 1e-5):
        # I = eta^2 (a1 - 2 eta a2) + O(eta^4 zeta^(4-2H)); remainder ~3 eta^2 zeta^2 relative.
        # rel: that remainder (measured 1.2e-8 and 1.2e-6); abs=0, the values (1e-10, 1e-8) lie near approx's
        # default absolute tolerance 1e-12, which had hidden that rel=1e-7 was too tight at eta = 1e-5
        assert th.roughness_integral(eta, z, h) == pytest.approx(eta**2 * (a1 - 2 * eta * a2), rel=3 * eta**2 * z**2,
                                                                  abs=0)
    # reached: at eta = 1e-6 the mean gap equals the high-pressure limit to 1e-9 of h_rms^2/(2 rho)
    s = sigma_for_eta(1e-6)
    diff = th.mean_gap(s, **P) - th.high_pressure_limit(s, rho=P["rho"], gamma0=P["gamma0"])
    assert 0 < diff < 1e-9 * P["h_rms"] ** 2 / (2 * P["rho"])


@pytest.mark.validation
def test_low_pressure_asymptotics():
    h, z = 0.3, 100.0
    i_inf = (1 - z ** (-2 * h)) / (2 * h)
    b1 = (1 - z ** (-2 * h - 1)) / (2 * h + 1)
    b2 = (1 - z ** (-2 * h - 2)) / (2 * h + 2)
    for eta in (1e4, 1e6):
        # I_inf - I = (2/eta) b1 - (3/eta^2) b2 + O(eta^-3)
        deficit = i_inf - th.roughness_integral(eta, z, h)
        assert deficit == pytest.approx(2 * b1 / eta - 3 * b2 / eta**2, rel=1e-7)
    s = sigma_for_eta(1e6)
    scale = P["h_rms"] ** 2 / (2 * P["rho"])
    low = th.low_pressure_limit(s, h_rms=P["h_rms"], rho=P["rho"], gamma0=P["gamma0"])
    # continuum form reaches the M4 low-pressure limit exactly ...
    assert abs(th.mean_gap(s, **P, form="continuum") - low) < 1e-5 * scale
    # ... the paper form reaches it with the roughness term scaled by (1 - zeta_s^(-2H))
    flat = th.flat_gap(s, rho=P["rho"], gamma0=P["gamma0"])
    paper_low = flat + (1 - z ** (-2 * h)) * scale
    assert abs(th.mean_gap(s, **P, form="paper") - paper_low) < 1e-5 * scale


@pytest.mark.validation
def test_continuum_over_paper_ratio():
    sigma0 = np.logspace(-6, 0, 7)
    flat = th.flat_gap(sigma0, rho=P["rho"], gamma0=P["gamma0"])
    r = (th.mean_gap(sigma0, **P, form="continuum") - flat) / (th.mean_gap(sigma0, **P) - flat)
    expected = 1 / (1 - 100 ** (-0.6))
    np.testing.assert_allclose(r, expected, rtol=1e-12)
    assert expected == pytest.approx(1.0673, abs=1e-4)  # the "6 % apart" of docs/model.md M4


# ----------------------------------------------------------------------------------------------------------
# drift and diffusion (M5)
# ----------------------------------------------------------------------------------------------------------
@pytest.mark.validation
@pytest.mark.parametrize("sigma0", [1e-6, 1e-3, 1e-1, 5.0])
@pytest.mark.parametrize("zeta", [1.5, 10.0, 99.0])
def test_drift_is_derivative_of_mean_gap(sigma0, zeta):
    d = 1e-4 * zeta
    gp = th.mean_gap(sigma0, **P, zeta=zeta + d)
    gm = th.mean_gap(sigma0, **P, zeta=zeta - d)
    kw = {k: P[k] for k in ("hurst", "h_rms", "rho", "lambda_l")}
    d1 = th.drift(zeta, sigma0, **kw)
    # truncation error ~ d^2 f''/6 ~ 1e-8 relative; rounding ~ 1e-16 |g0| / d
    assert (gp - gm) / (2 * d) == pytest.approx(d1, rel=1e-6, abs=1e-12 * abs(gp) / d)


def test_diffusion_default_and_c1():
    kw = {k: P[k] for k in ("hurst", "h_rms", "rho", "lambda_l")}
    zeta = np.linspace(1, 100, 50)
    d1 = th.drift(zeta, 1e-3, **kw)
    np.testing.assert_allclose(th.diffusion(zeta, 1e-3, **kw), P["rho"] * d1, rtol=1e-14)
    c1 = 0.37 * P["hurst"] * P["h_rms"] ** 2
    np.testing.assert_allclose(th.diffusion(zeta, 1e-3, **kw, c1=c1), 0.37 * P["rho"] * d1, rtol=1e-14)
    assert th.diffusion(2.0, 1e-3, **kw, c1=0.0) == 0.0
    with pytest.raises(ValueError, match="c1"):
        th.diffusion(2.0, 1e-3, **kw, c1=-1e-6)


# ----------------------------------------------------------------------------------------------------------
# discrete form for one surface (M4)
# ----------------------------------------------------------------------------------------------------------
def synthetic_surface(n, hurst, lambda_l, lambda_s, c0=1e-6, length=1.0, seed=0):
    """Tiny stand-in for gapsweep.surface: h~ = sqrt(C(q)/A) exp(i phase), Hermitian (M2).

    Returns the surface and the continuum rms height (1/2pi) int q C dq of its spectrum."""
    k = np.fft.fftfreq(n, 1.0 / n)
    q = 2 * np.pi / length * np.hypot(k[:, None], k[None, :])
    ql, qs = 2 * np.pi / lambda_l, 2 * np.pi / lambda_s
    band = (q >= ql) & (q <= qs)
    c = np.zeros_like(q)
    c[band] = c0 * (q[band] / ql) ** (-2 * hurst - 2)
    phase = np.angle(np.fft.fft2(np.random.default_rng(seed).standard_normal((n, n))))  # Hermitian phases
    h = np.fft.ifft2(np.sqrt(c / length**2) * np.exp(1j * phase)).real * n * n
    h_rms_continuum = math.sqrt(c0 * ql**2 * (1 - (lambda_l / lambda_s) ** (-2 * hurst)) / (4 * np.pi * hurst))
    return h, h_rms_continuum


@pytest.mark.validation
def test_discrete_against_real_space_linear_response():
    # Independent route: u~ = h~/(1 + eta zeta_q), then g0 = flat + <(h - u)^2>/(2 rho) in real space.
    n, lam_l = 64, 0.5
    h, _ = synthetic_surface(n, 0.5, lam_l, 4 / n, seed=3)
    h = h + 0.123  # a mean offset must not matter (gap measured from the mean plane)
    sigma0 = np.array([1e-5, 1e-3, 1e-1])
    got = th.mean_gap_discrete(sigma0, h, rho=P["rho"], gamma0=P["gamma0"], lambda_l=lam_l)
    k = np.fft.fftfreq(n, 1.0 / n)
    zq = np.hypot(k[:, None], k[None, :]) * 2 * np.pi / (2 * np.pi / lam_l)
    ht = np.fft.fft2(h)
    ht[0, 0] = 0.0
    for s, g in zip(sigma0, got):
        eta = P["rho"] * (2 * np.pi / lam_l) / (2 * s)
        w = np.fft.ifft2(ht * (eta * zq / (1 + eta * zq))).real  # h - u
        ref = th.flat_gap(s, rho=P["rho"], gamma0=P["gamma0"]) + np.mean(w**2) / (2 * P["rho"])
        assert g == pytest.approx(ref, rel=1e-12)


@pytest.mark.validation
def test_discrete_low_pressure_is_variance():
    # eta -> inf: flat + var(h)/(2 rho) exactly (Parseval).
    h, _ = synthetic_surface(64, 0.3, 0.5, 4 / 64, seed=1)
    s = 1e-12
    got = th.mean_gap_discrete(s, h, rho=P["rho"], gamma0=P["gamma0"], lambda_l=0.5)
    ref = th.flat_gap(s, rho=P["rho"], gamma0=P["gamma0"]) + np.var(h) / (2 * P["rho"])
    assert got == pytest.approx(ref, rel=1e-9)


def _discrete_and_continuum(sigma0, h, hurst, h_rms_c, lam_l, lam_s):
    """Roughness parts ``g0 - flat`` of ``mean_gap_discrete`` on ``h`` and of the continuum form (M4)."""
    flat = th.flat_gap(sigma0, rho=P["rho"], gamma0=P["gamma0"])
    disc = th.mean_gap_discrete(sigma0, h, rho=P["rho"], gamma0=P["gamma0"], lambda_l=lam_l)
    cont = th.mean_gap(sigma0, hurst=hurst, h_rms=h_rms_c, rho=P["rho"], gamma0=P["gamma0"], lambda_l=lam_l,
                       lambda_s=lam_s, form="continuum")
    return disc - flat, cont - flat


@pytest.mark.validation
@pytest.mark.parametrize("hurst", [0.3, 0.8])
def test_discrete_approaches_continuum(hurst):
    # Same spectrum on one grid (n = 512, lambda_s = 4 dx), shortening lambda_l: the lattice sum over modes
    # approaches the continuum integral as k_l = L/lambda_l grows (error ~ k_l^-2).
    n, lam_s = 512, 4 / 512
    sigma0 = np.logspace(-6, 1, 8)
    errors = []
    for k_l, tol in ((4, 0.1), (16, 0.015), (32, 0.004)):
        lam_l = 1.0 / k_l
        h, h_rms_c = synthetic_surface(n, hurst, lam_l, lam_s)
        disc, cont = _discrete_and_continuum(sigma0, h, hurst, h_rms_c, lam_l, lam_s)
        err = float(np.max(np.abs(disc / cont - 1)))
        assert err < tol, (k_l, err)
        errors.append(err)
    assert errors[0] > errors[1] > errors[2]


@pytest.mark.validation
def test_discrete_of_package_surface_approaches_continuum():
    # The same comparison with gapsweep.surface (c0 convention of M2: h~ = sqrt(C/A) exp(i phase)).
    surface = pytest.importorskip("gapsweep.surface")
    hurst, c0, lam_l, lam_s = 0.3, 1e-6, 1 / 16, 4 / 256
    h = surface.self_affine(256, hurst, lambda_l=lam_l, lambda_s=lam_s, c0=c0, seed=5)
    ql = 2 * np.pi / lam_l
    h_rms_c = math.sqrt(c0 * ql**2 * (1 - (lam_l / lam_s) ** (-2 * hurst)) / (4 * np.pi * hurst))
    disc, cont = _discrete_and_continuum(np.logspace(-6, 1, 8), h, hurst, h_rms_c, lam_l, lam_s)
    np.testing.assert_allclose(disc, cont, rtol=0.015)


# ----------------------------------------------------------------------------------------------------------
# exact rigid limit (M3/M4) and the reference gap density (M5)
# ----------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("ratio", [50.0, 1000.0])
def test_rigid_mean_gap_no_overflow(ratio):
    rng = np.random.default_rng(7)
    rho = 1e-3
    h = rng.standard_normal((16, 16))
    h = (h - h.mean()) / h.std() * ratio * rho  # h_rms / rho = ratio; exp(h/rho) up to e^(4 ratio)
    sigma0 = np.array([1e-7, 1e-2, 10.0])
    got = th.rigid_mean_gap(h, sigma0, rho=rho, gamma0=1e-3)
    assert np.all(np.isfinite(got))
    with mp.workdps(30):
        lme = mp.log(mp.fsum(mp.exp(mp.mpf(float(x)) / rho) for x in h.ravel()) / h.size)
        for s, g in zip(sigma0, got):
            ref = rho * (mp.log(mp.mpf("1e-3") / (rho * mp.mpf(s))) + lme)
            assert abs(g - float(ref)) <= 1e-12 * abs(float(ref))


@pytest.mark.validation
def test_rigid_mean_gap_small_roughness_matches_low_pressure():
    # Cumulant expansion: rho ln<exp(h/rho)> = var/(2 rho) + k3/(6 rho^2) + ...; small h/rho -> 2nd cumulant.
    h, _ = synthetic_surface(64, 0.3, 0.5, 4 / 64, seed=2)
    rho = 100 * h.std()
    s = 1e-3
    got = th.rigid_mean_gap(h, s, rho=rho, gamma0=1e-3)
    ref = th.flat_gap(s, rho=rho, gamma0=1e-3) + np.var(h) / (2 * rho)
    assert abs(got - ref) < 0.05 * np.var(h) / (2 * rho)


@pytest.mark.validation
def test_rigid_gap_density_moments():
    kw = dict(h_rms=0.02, rho=2e-3, gamma0=1e-3)
    s = 1e-4
    g0 = th.low_pressure_limit(s, **kw)
    g = np.linspace(g0 - 12 * 0.02, g0 + 12 * 0.02, 20001)
    p = th.rigid_gap_density(g, s, **kw)
    dg = g[1] - g[0]
    assert np.sum(p) * dg == pytest.approx(1.0, rel=1e-10)
    mean = np.sum(g * p) * dg
    assert mean == pytest.approx(g0, rel=1e-10)
    assert np.sum((g - mean) ** 2 * p) * dg == pytest.approx(0.02**2, rel=1e-8)
    # the mean is the exact rigid mean gap of a Gaussian surface: compare with a large Gaussian sample
    h = np.random.default_rng(0).standard_normal(10**6) * 0.02
    h = (h - h.mean()) / h.std() * 0.02
    kw_small = dict(h_rms=0.02, rho=0.04, gamma0=1e-3)  # h_rms/rho = 0.5: sampling noise of <e^{h/rho}> small
    g0_rigid = th.rigid_mean_gap(h, s, rho=0.04, gamma0=1e-3)
    assert g0_rigid == pytest.approx(th.low_pressure_limit(s, **kw_small), abs=2e-3 * 0.02**2 / (2 * 0.04))


# ----------------------------------------------------------------------------------------------------------
# bad inputs
# ----------------------------------------------------------------------------------------------------------
BAD_MEAN_GAP = [
    (dict(sigma0=0.0), "sigma0"),
    (dict(sigma0=-1.0), "sigma0"),
    (dict(sigma0=np.nan), "sigma0"),
    (dict(sigma0=[1e-3, np.inf]), "sigma0"),
    (dict(rho=0.0), "rho"),
    (dict(rho=-1e-3), "rho"),
    (dict(gamma0=0.0), "gamma0"),
    (dict(hurst=0.0), "hurst"),
    (dict(hurst=1.0), "hurst"),
    (dict(hurst=np.nan), "hurst"),
    (dict(h_rms=-0.1), "h_rms"),
    (dict(lambda_s=0.25), "lambda_s"),
    (dict(lambda_s=0.5), "lambda_s"),
    (dict(lambda_l=-0.25), "lambda_l"),
    (dict(lambda_s=0.0), "lambda_s"),
    (dict(e_star=0.0), "e_star"),
    (dict(zeta=0.5), "zeta"),
    (dict(zeta=np.inf), "zeta"),
    (dict(form="exact"), "form"),
]


@pytest.mark.parametrize(("bad", "name"), BAD_MEAN_GAP)
def test_mean_gap_bad_inputs(bad, name):
    kw = dict(P, sigma0=1e-3)
    kw.update(bad)
    sigma0 = kw.pop("sigma0")
    with pytest.raises(ValueError, match=name):
        th.mean_gap(sigma0, **kw)


def test_other_bad_inputs():
    kw = {k: P[k] for k in ("hurst", "h_rms", "rho", "lambda_l")}
    with pytest.raises(ValueError, match="zeta"):
        th.drift(0.9, 1e-3, **kw)
    with pytest.raises(ValueError, match="sigma0"):
        th.diffusion(2.0, -1.0, **kw)
    with pytest.raises(ValueError, match="heights"):
        th.mean_gap_discrete(1e-3, np.zeros((4, 5)), rho=1e-3, gamma0=1e-3, lambda_l=0.25)
    with pytest.raises(ValueError, match="heights"):
        th.mean_gap_discrete(1e-3, np.full((4, 4), np.nan), rho=1e-3, gamma0=1e-3, lambda_l=0.25)
    with pytest.raises(TypeError, match="heights"):
        th.mean_gap_discrete(1e-3, np.zeros((4, 4), complex), rho=1e-3, gamma0=1e-3, lambda_l=0.25)
    with pytest.raises(ValueError, match="length"):
        th.mean_gap_discrete(1e-3, np.zeros((4, 4)), rho=1e-3, gamma0=1e-3, lambda_l=0.25, length=0.0)
    with pytest.raises(ValueError, match="heights"):
        th.rigid_mean_gap(np.array([0.0, np.inf]), 1e-3, rho=1e-3, gamma0=1e-3)
    with pytest.raises(ValueError, match="gamma0"):
        th.rigid_mean_gap(np.zeros(4), 1e-3, rho=1e-3, gamma0=-1.0)
    with pytest.raises(ValueError, match="h_rms"):
        th.rigid_gap_density(0.0, 1e-3, h_rms=0.0, rho=1e-3, gamma0=1e-3)
    with pytest.raises(ValueError, match="eta"):
        th.roughness_integral(0.0, 10.0, 0.3)
    with pytest.raises(ValueError, match="lambda_l"):
        th.eta(1e-3, rho=1e-3, lambda_l=0.0)
    with pytest.raises(TypeError, match="rho"):
        th.flat_gap(1e-3, rho="1e-3", gamma0=1e-3)
