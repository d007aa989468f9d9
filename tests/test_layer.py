"""Elastic layer on a rigid base (``gfmd.solve(..., thickness=t, poisson=nu, bottom=...)``, docs/model.md "Elastic
layer on a rigid base"): the stiffness against a direct solve of the plane-strain boundary-value problem (an
independent method), the half-space limit t -> oo, the thin-layer (Winkler) limit t -> 0 against its closed form,
and the refusals. The comparison with ContactMechanics is in tests/test_peers_layer.py (marker ``peers``)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from gapsweep.gfmd import solve
from gapsweep.gfmd.substrates import layer_factor, stiffness, stiffness_q0
from gapsweep.surface import self_affine


def bvp_stiffness(q: float, t: float, nu: float, bottom: str, young: float = 1.0) -> float:
    """``p~ / u_z~`` at the surface of a layer (plane strain, mode cos(qx)) from the Papkovich-Neuber solution
    ``2 mu u = 4 (1 - nu) B - grad(z B_z + B0)`` with ``B_z, B0 = cos(qx) e^{+-qz}``: four constants fixed by
    the four boundary conditions (surface: sigma_zz = -p, sigma_xz = 0; base: u = 0 (bonded) or u_z = 0,
    sigma_xz = 0 (slip)) in one 4 x 4 linear solve."""
    mu = young / (2 * (1 + nu))
    lam = young * nu / ((1 + nu) * (1 - 2 * nu))

    def fields(s: int, a: float, b: float, z: float) -> np.ndarray:
        e = math.exp(s * q * z)
        f, f1, f2 = e * (a * z + b), e * (s * q * (a * z + b) + a), e * (q * q * (a * z + b) + 2 * s * q * a)
        ux, uz = q * f / (2 * mu), (4 * (1 - nu) * a * e - f1) / (2 * mu)
        div = (1 - 2 * nu) * a * s * q * e / mu
        duz = (4 * (1 - nu) * a * s * q * e - f2) / (2 * mu)
        return np.array([ux, uz, lam * div + 2 * mu * duz, mu * (q * f1 / (2 * mu) - q * uz)])

    basis = [(1, 1.0, 0.0), (1, 0.0, 1.0), (-1, 1.0, 0.0), (-1, 0.0, 1.0)]
    a = np.zeros((4, 4))
    for j, bs in enumerate(basis):
        top, base = fields(*bs, 0.0), fields(*bs, t)
        a[0, j], a[1, j] = top[2], top[3]
        a[2, j], a[3, j] = (base[0], base[1]) if bottom == "bonded" else (base[1], base[3])
    c = np.linalg.solve(a, [-1.0, 0.0, 0.0, 0.0])
    return 1.0 / sum(c[j] * fields(*basis[j], 0.0)[1] for j in range(4))


@pytest.mark.validation
@pytest.mark.parametrize("bottom", ["bonded", "slip"])
@pytest.mark.parametrize("nu", [-0.3, 0.0, 0.25, 0.49])
def test_stiffness_matches_boundary_value_problem(bottom: str, nu: float) -> None:
    e_star = 1.0 / (1 - nu * nu)
    for x in (0.02, 0.17, 0.9, 2.5, 7.0):
        q = 3.0
        want = bvp_stiffness(q, x / q, nu, bottom)
        got = float(stiffness(q, e_star, x / q, nu, bottom))
        assert got == pytest.approx(want, rel=1e-8), (x, got, want)


@pytest.mark.validation
@pytest.mark.parametrize("bottom", ["bonded", "slip"])
def test_stiffness_limits(bottom: str) -> None:
    nu = 0.3
    e_star = 2.5
    # half-space: f -> 1 (exponentially), no overflow at any x
    x = np.array([30.0, 300.0, 1e5])
    np.testing.assert_allclose(layer_factor(x, nu, bottom), 1.0, rtol=1e-11)
    # thin layer: k t -> E* (1 - nu)^2 / (1 - 2 nu) (bonded, confined) or E* (slip), corrections O((q t)^2)
    t = 1e-6
    q = np.array([1e-3, 1.0, 100.0])
    k0 = e_star * (1 - nu) ** 2 / (1 - 2 * nu) if bottom == "bonded" else e_star
    np.testing.assert_allclose(stiffness(q, e_star, t, nu, bottom) * t, k0, rtol=1e-6)
    assert stiffness_q0(e_star, t, nu, bottom) * t == pytest.approx(k0, rel=1e-14)
    young = e_star * (1 - nu * nu)
    if bottom == "bonded":  # the oedometric modulus E (1 - nu) / ((1 + nu)(1 - 2 nu))
        assert k0 == pytest.approx(young * (1 - nu) / ((1 + nu) * (1 - 2 * nu)), rel=1e-14)
    # small-x series and the direct form meet continuously at x = 0.1
    xs = np.array([0.1 - 1e-12, 0.1 + 1e-12])
    f = layer_factor(xs, nu, bottom)
    assert f[0] == pytest.approx(f[1], rel=1e-9)


@pytest.mark.validation
@pytest.mark.parametrize("law", ["hard_wall", "exponential", "adhesive"])
def test_thick_layer_is_the_half_space(law: str) -> None:
    h = self_affine(32, 0.7, lambda_l=0.5, lambda_s=4 / 32, seed=11) * 0.5  # physical units: box 2 x 1.5
    kw = {"hard_wall": {}, "exponential": {"gamma0": 2e-4, "rho": 2e-3}, "adhesive": {"work": 1e-4, "rho": 0.01}}
    h = h[:, :24]
    common = dict(sigma0=0.03, interaction=law, e_star=2.0, length=(2.0, 1.5), tol=1e-9, **kw[law])
    ref = solve(h, **common)
    lay = solve(h, thickness=1e4, poisson=0.3, bottom="bonded", **common)
    assert ref.converged and lay.converged
    assert lay.mean_gap == pytest.approx(ref.mean_gap, rel=1e-6)
    assert lay.contact_area == pytest.approx(ref.contact_area, abs=1.0 / h.size)
    assert lay.substrate["bottom"] == "bonded" and ref.substrate == {}


@pytest.mark.validation
@pytest.mark.parametrize(("bottom", "nu"), [("bonded", 0.35), ("slip", 0.2)])
def test_thin_layer_is_a_winkler_foundation(bottom: str, nu: float) -> None:
    """t << pixel: every pixel a spring of stiffness k0 = k(0) (a Winkler foundation). Closed form: the body's
    undeformed surface at height d, ``p = k0 (h - d)+``, ``<p> = sigma0`` fixes d (bisection), the gap is
    ``(d - h)+`` and the contact ``h > d``."""
    n, length, e_star = 48, 1.0, 1.0
    h = self_affine(n, 0.8, lambda_l=0.5, lambda_s=4 / n, seed=4)
    t = 1e-4 * length / n  # q_max t ~ 1e-3: stiffness within 1e-6 of k0
    k0 = stiffness_q0(e_star, t, nu, bottom)
    sigma0 = 0.05 * k0 * h.std()
    r = solve(h, sigma0=sigma0, interaction="hard_wall", e_star=e_star, thickness=t, poisson=nu, bottom=bottom,
              tol=1e-10, method="pk")
    assert r.converged

    def load(d: float) -> float:
        return float(np.mean(k0 * np.maximum(h - d, 0.0))) - sigma0

    lo, hi = float(h.min()) - 1.0, float(h.max())
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if load(mid) > 0 else (lo, mid)
    d = 0.5 * (lo + hi)
    assert r.contact_area == pytest.approx(float(np.mean(h > d)), abs=1.5 / h.size)
    assert r.mean_gap == pytest.approx(float(np.mean(np.maximum(d - h, 0.0))), rel=1e-4)
    np.testing.assert_allclose(r.pressure, k0 * np.maximum(h - d, 0.0), atol=5e-3 * sigma0)


def test_layer_refusals() -> None:
    h = self_affine(16, 0.8, lambda_l=0.5, lambda_s=4 / 16, seed=1)
    with pytest.raises(ValueError, match="periodic") as e:
        solve(h, sigma0=0.01, interaction="hard_wall", thickness=0.1, poisson=0.3, periodic=False)
    # the refusal says why and how far this layer is from the half-space at the map's longest wavelength: the
    # bonded layer's f(2 pi t / L) against its thin-layer (Winkler) limit k(0) / (E* q / 2), which it approaches
    msg = str(e.value)
    assert "real-space Green's function" in msg
    f = float(layer_factor(2 * math.pi * 0.1 / 2.0, 0.3, "bonded"))
    with pytest.raises(ValueError, match=rf"side 2\) the layer's stiffness is {f:.4g} times") as e:
        solve(h, sigma0=0.01, interaction="hard_wall", thickness=0.1, poisson=0.3, periodic=False, length=(2.0, 1.0))
    winkler = (1 - 0.3) ** 2 / ((1 - 2 * 0.3) * 0.1) / (math.pi / 2.0)  # k(0) / (E* q / 2) at q = 2 pi / 2
    assert 1.0 < f < winkler and f == pytest.approx(winkler, rel=0.2)
    for bad in (0.0, -1.0, math.nan, "1"):
        with pytest.raises(ValueError, match="thickness"):
            solve(h, sigma0=0.01, interaction="hard_wall", thickness=bad, poisson=0.3)
    for bad in (0.5, -1.0, 0.7, math.nan):
        with pytest.raises(ValueError, match="poisson"):
            solve(h, sigma0=0.01, interaction="hard_wall", thickness=0.1, poisson=bad)
    with pytest.raises(ValueError, match="poisson"):
        solve(h, sigma0=0.01, interaction="hard_wall", thickness=0.1)  # bonded needs nu
    with pytest.raises(ValueError, match="bottom"):
        solve(h, sigma0=0.01, interaction="hard_wall", thickness=0.1, poisson=0.3, bottom="glued")
    with pytest.raises(ValueError, match="method"):
        solve(h, sigma0=0.01, interaction="hard_wall", thickness=0.1, poisson=0.3, method="mpcg")
    with pytest.raises(ValueError, match="start"):
        solve(h, sigma0=0.01, gamma0=1e-3, rho=1e-2, thickness=0.1, poisson=0.3, start="coarse")


@pytest.mark.validation
def test_exponential_on_a_layer_two_minimisers_agree() -> None:
    """The exponential law's own minimiser with the layer's stiffness (square grid, CPU) against the generic smooth
    minimiser (L-BFGS on gfmd._smooth, which a rectangular grid takes) on the same square map."""
    from gapsweep.gfmd import _smooth
    from gapsweep.gfmd.interactions import resolve
    from gapsweep.gfmd.substrates import LayerGrid

    h = self_affine(48, 0.7, lambda_l=0.5, lambda_s=4 / 48, seed=13)
    kw = dict(sigma0=0.02, e_star=1.5, length=1.0, tol=1e-9)
    own = solve(h, gamma0=1e-3, rho=3e-2, thickness=0.03, poisson=0.4, **kw)
    law = resolve("exponential", gamma0=1e-3, rho=3e-2)
    grid = LayerGrid(h.shape, 1.0, "numpy", None, False, thickness=0.03, poisson=0.4, bottom="bonded")
    gen = _smooth.minimise(h, law, method="lbfgs", backend="numpy", max_iter=5000, initial=None, threads=None,
                           host=True, t_start=0.0, grid=grid, **kw)
    assert own.converged and gen.converged and own.method != "lbfgs"
    assert own.mean_gap == pytest.approx(gen.mean_gap, rel=1e-6)
    np.testing.assert_allclose(own.pressure, gen.pressure, atol=1e-5 * 0.02 * 50)


@pytest.mark.validation
def test_persson_contact_area_of_a_layer() -> None:
    """Persson's contact area with E* -> E* f(q t): the half-space's for a thick layer; at small loads
    ``A -> sqrt(2/pi) sigma0 / sqrt(V_c)`` with the Winkler variance ``V_c = k(0)^2 h_rms^2`` for a thin one; a
    thinner (stiffer) layer makes less contact; the mean separation is refused."""
    from gapsweep.theory import persson, persson_layer
    from gapsweep.theory import spectrum as spec

    kw = dict(hurst=0.8, lambda_l=0.25, lambda_s=0.01, rms_slope=0.5)
    s = np.array([1e-4, 1e-3, 1e-2])
    half = persson.contact_area(s, **kw)
    for variant in ("persson2001", "yang_persson2008"):
        thick = persson_layer.contact_area(s, thickness=1e6, poisson=0.3, variant=variant, **kw)
        np.testing.assert_allclose(thick, persson.contact_area(s, variant=variant, **kw), rtol=1e-12)
    t, nu = 1e-6, 0.3
    sp = spec.self_affine(0.8, lambda_l=0.25, lambda_s=0.01, rms_slope=0.5)
    k0 = stiffness_q0(1.0, t, nu, "bonded")
    assert persson_layer.full_contact_variance(sp, 1.0, t, nu, "bonded") == pytest.approx(
        (k0 * sp.h_rms) ** 2, rel=1e-4)
    tiny = 1e-6 * k0 * sp.h_rms
    a = persson_layer.contact_area(tiny, thickness=t, poisson=nu, **kw)
    assert a == pytest.approx(math.sqrt(2 / math.pi) * tiny / (k0 * sp.h_rms), rel=1e-6)
    areas = [persson_layer.contact_area(1e-3, thickness=tt, poisson=nu, **kw) for tt in (1e-3, 1e-2, 1e-1, 1.0)]
    assert all(a1 < a2 for a1, a2 in itertools.pairwise(areas)) and areas[-1] <= half[1] * (1 + 1e-12)
    with pytest.raises(ValueError, match="poisson"):
        persson_layer.mean_separation(1e-3, thickness=0.1, **kw)
    with pytest.raises(ValueError, match="poisson"):
        persson_layer.contact_area(1e-3, thickness=0.1, **kw)


@pytest.mark.validation
def test_layer_coarse_start_agrees_with_plain_pk() -> None:
    """N = 256: "auto" (pcg from the coarse-to-fine start solved on the same layer, FFTW spectral loop) against
    the plain Polonsky-Keer iteration from the flat start."""
    h = self_affine(256, 0.8, lambda_l=0.5, lambda_s=8 / 256, seed=21)
    kw = dict(sigma0=0.01, interaction="hard_wall", tol=1e-9, thickness=0.03, poisson=0.45)
    a = solve(h, **kw)
    b = solve(h, method="pk", **kw)
    assert a.converged and b.converged and a.diagnostics["coarse_iterations"]
    assert a.mean_gap == pytest.approx(b.mean_gap, rel=1e-7)
    assert a.contact_area == b.contact_area


@pytest.mark.validation
def test_persson_mean_separation_on_a_layer() -> None:
    """Persson's mean separation with the layer's stiffness (gapsweep.theory.persson_layer; docs/theory.md): the
    half-space's value as t -> oo (continuum spectrum: its closed form against the layer's shell sum; a map's own
    spectrum: the same shells), and against hard-wall GFMD on the same maps (square, and rectangular with a
    rectangular box) on layers of three kinds: within 12 % at every load, where the layer raises GFMD's mean gap
    by up to several times the half-space's (so the half-space's theory would fail the same check)."""
    from gapsweep.theory import persson, persson_layer

    sa = dict(hurst=0.8, lambda_l=0.25, lambda_s=0.01, rms_slope=0.1)
    loads = [1e-4, 1e-3, 1e-2]
    thick = persson_layer.mean_separation(loads, thickness=1e4, poisson=0.3, **sa)
    np.testing.assert_allclose(thick, persson.mean_separation(loads, **sa), rtol=2e-4)
    h = self_affine(64, 0.8, lambda_l=0.5, lambda_s=8 / 64, rms_slope=0.1, seed=11)
    np.testing.assert_allclose(persson_layer.mean_separation(loads, thickness=1e4, bottom="slip", heights=h),
                               persson.mean_separation(loads, heights=h), rtol=1e-9)
    loads = [3e-3, 1e-2, 3e-2]
    rect = self_affine(64, 0.8, lambda_l=0.5, lambda_s=8 / 64, rms_slope=0.1, seed=4)[:, :48]
    for hh, length in ((h, 1.0), (rect, (1.0, 0.75))):
        half = np.array([solve(hh, sigma0=s, interaction="hard_wall", tol=1e-8, length=length).mean_gap
                         for s in loads])
        for kw in (dict(thickness=0.1, poisson=0.3), dict(thickness=0.03, poisson=0.45),
                   dict(thickness=0.03, bottom="slip")):
            g = np.array([solve(hh, sigma0=s, interaction="hard_wall", tol=1e-8, length=length, **kw).mean_gap
                          for s in loads])
            u = persson_layer.mean_separation(loads, heights=hh, length=length, **kw)
            np.testing.assert_allclose(u, g, rtol=0.12, err_msg=str(kw))
            if kw["thickness"] < 0.05:  # the layer matters here: twice the half-space's gap at the top load
                assert g[-1] > 2 * half[-1]
