"""Free boundaries (``gfmd.solve(..., periodic=False)``, docs/gfmd.md "Periodic or free boundaries"): a finite
map on an elastic half-space, against closed forms (the pixel Green's function against Boussinesq's point load
and a quadrature of it; Hertz), against ContactMechanics' FreeFFTElasticHalfSpace (hard wall, marker ``peers``)
and, for the smooth laws, against a second algorithm (dense compliance matrix by direct summation, Newton).

The peer runs in its own interpreter (it pins its own numpy): ``GAPSWEEP_PEERS_PYTHON=/path/to/python`` with
ContactMechanics installed (``python3 -m venv peers && peers/bin/pip install numpy scipy contactmechanics``), or
ContactMechanics importable here; otherwise the peer test skips."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from gapsweep.gfmd import solve
from gapsweep.gfmd._grid import FreeGrid
from gapsweep.gfmd.interactions import resolve
from gapsweep.reference import boussinesq_point, hertz
from gapsweep.reference import boussinesq_rectangle as boussinesq_pixel
from gapsweep.surface import self_affine
from gapsweep.topography import Topography

PEER = Path(__file__).with_name("peers") / "contactmechanics_free.py"


@pytest.mark.validation
def test_pixel_green_function_is_the_integrated_point_load() -> None:
    """Love's rectangle formula = the Boussinesq kernel 1/(pi E* r) integrated over the pixel (Gauss-Legendre,
    60 x 60 nodes, away from the singularity: 1e-10), and -> 4ab/(pi E* r) far away (O((a/r)^2): 1e-4 at 100
    pixels)."""
    a, b, e_star = 0.5, 0.75, 2.0
    x, w = np.polynomial.legendre.leggauss(60)
    for px, py in ((3.0, 0.0), (2.0, 4.5), (-5.0, 1.0)):
        xs, ys = a * x, b * x  # pixel points
        r = np.hypot(px - xs[:, None], py - ys[None, :])
        quad = a * b * float(np.sum(w[:, None] * w[None, :] * boussinesq_point(r, 1.0, e_star)))
        assert float(boussinesq_pixel(np.array(px), np.array(py), a, b, e_star)) == pytest.approx(quad, rel=1e-10)
    far = float(boussinesq_pixel(np.array(100.0), np.array(30.0), a, b, e_star))
    assert far == pytest.approx(float(boussinesq_point(math.hypot(100.0, 30.0), 4 * a * b, e_star)), rel=1e-4)


@pytest.mark.validation
@pytest.mark.parametrize("path", ["scipy", "array-api", "pyfftw"])
def test_free_compliance_is_the_direct_sum(path: str) -> None:
    """The doubled-grid FFT convolution = the O(N^2) direct sum over the map's pixels (1e-12), rectangular
    map and pixels (nx != ny, dx != dy): no periodic image enters. Three transform paths: scipy (CPU default),
    the namespace's own ``fft`` module without scipy's keywords (what cupy runs), FFTW plans (pyFFTW)."""
    nx, ny, lx, ly = 12, 7, 3.0, 1.4
    if path == "pyfftw":
        pytest.importorskip("pyfftw")
    grid = FreeGrid((nx, ny), (lx, ly), "pyfftw" if path == "pyfftw" else "numpy", None, False)
    if path == "array-api":
        grid._f, grid._kw, grid._ow = np.fft, {}, {}
    assert (grid._plans is not None) == (path == "pyfftw")
    p = np.random.default_rng(1).random((nx, ny))
    u = grid.compliance(2.0)(p)
    dx, dy = lx / nx, ly / ny
    ix, iy = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    direct = np.zeros((nx, ny))
    for i in range(nx):
        for j in range(ny):
            g = boussinesq_pixel((ix - i) * dx, (iy - j) * dy, dx / 2, dy / 2, 2.0)
            direct += p[i, j] * g
    np.testing.assert_allclose(u, direct, rtol=1e-12, atol=1e-14 * np.abs(direct).max())


def hertz_case(nx: int = 256, ny: int = 192, a: float = 50.0, radius: float = 2500.0):
    """Parabolic indenter ``h = -r^2/(2R)`` centred on an ``nx x ny`` map of unit pixels, loaded to the Hertz
    contact radius ``a`` (pixels): ``F = 4 E* a^3/(3R)``, ``p0 = 3F/(2 pi a^2)`` (Johnson Eq. 4.22, E* = 1)."""
    x = np.arange(nx) - nx / 2
    y = np.arange(ny) - ny / 2
    h = -(x[:, None] ** 2 + y[None, :] ** 2) / (2 * radius)
    hz = hertz(radius, 1.0, a=a)
    return h, (float(nx), float(ny)), hz.force / (nx * ny), hz.force, hz.p0


@pytest.mark.validation
@pytest.mark.parametrize("method", ["mpcg", "pk"])
def test_hertz_on_a_free_map(method: str) -> None:
    """Contact radius within 2 % and peak pressure within 3 % of Hertz at a = 50 pixels (the issue's
    acceptance); measured 0.2 % and 2e-5. The peak is also held to 0.5 %, which the periodic solve of the same
    map misses (1.6 %: the images' load)."""
    h, length, sigma0, _, p0 = hertz_case()
    r = solve(h, sigma0=sigma0, interaction="hard_wall", length=length, tol=1e-8, periodic=False, method=method)
    assert r.converged and not r.periodic
    assert float(r.pressure.mean()) == pytest.approx(sigma0, rel=1e-8)  # mean over the map's own area
    a = math.sqrt(np.count_nonzero(r.pressure > 0) / math.pi)
    assert abs(a / 50.0 - 1) < 0.02
    assert abs(float(r.pressure.max()) / p0 - 1) < 0.005
    per = solve(h, sigma0=sigma0, interaction="hard_wall", length=length, tol=1e-8, method=method)
    assert abs(float(per.pressure.max()) / p0 - 1) > 0.01


def test_topography_flag_and_length_are_honoured() -> None:
    h = self_affine(64, 0.8, lambda_l=0.5, lambda_s=0.1, seed=11)[:, :48]
    topo = Topography(h, (2.0, 1.5), "um", periodic=False)
    a = solve(topo, sigma0=0.05, interaction="hard_wall", tol=1e-10)
    b = solve(h, sigma0=0.05, interaction="hard_wall", length=(2.0, 1.5), tol=1e-10, periodic=False)
    c = solve(h, sigma0=0.05, interaction="hard_wall", length=(2.0, 1.5), tol=1e-10)
    assert not a.periodic and a.mean_gap == b.mean_gap and a.contact_area == b.contact_area
    assert abs(c.mean_gap / b.mean_gap - 1) > 1e-3  # the boundary condition matters on this map
    assert solve(topo, sigma0=0.05, interaction="hard_wall", tol=1e-10, periodic=True).mean_gap == c.mean_gap
    with pytest.raises(ValueError, match="length"):
        solve(topo, sigma0=0.05, interaction="hard_wall", length=3.0)
    with pytest.raises(ValueError, match="periodic must be True or False"):
        solve(h, sigma0=0.05, interaction="hard_wall", periodic="no")


def _peer_python() -> str | None:
    env = os.environ.get("GAPSWEEP_PEERS_PYTHON")
    if env:
        return env
    try:
        import ContactMechanics  # noqa: F401
    except ImportError:
        return None
    return sys.executable


CASES = [((96, 64), (1.5, 1.0), 0.8, 0.05), ((64, 64), (1.0, 1.0), 0.3, 0.2), ((80, 120), (0.5, 0.75), 0.8, 0.01),
         ((64, 48), (1.0, 1.0), 0.8, 0.05)]  # the last with rectangular pixels (dx != dy)


@pytest.mark.validation
@pytest.mark.peers
@pytest.mark.parametrize(("shape", "length", "hurst", "sigma0"), CASES)
def test_free_hard_wall_agrees_with_contactmechanics(tmp_path, shape, length, hurst, sigma0) -> None:
    """Identical contact pixels, mean gap to 1e-6 relative and pressures to 1e-6 sigma0 against
    ContactMechanics' FreeFFTElasticHalfSpace + NonSmoothContactSystem at the same total force (non-periodic
    crops of periodic surfaces; rectangular maps, boxes and pixels). Measured: mean gaps to ~1e-12."""
    py = _peer_python()
    if py is None:
        pytest.skip("ContactMechanics not available (set GAPSWEEP_PEERS_PYTHON)")
    parent = self_affine(2 * max(shape), hurst, lambda_l=0.5, lambda_s=8 / (2 * max(shape)), seed=21)
    h = parent[3:3 + shape[0], 5:5 + shape[1]]
    np.savez(tmp_path / "in.npz", h=h, lx=length[0], ly=length[1], sigma0=sigma0, e_star=1.0)
    subprocess.run([py, str(PEER), str(tmp_path / "in.npz"), str(tmp_path / "out.npz")], check=True,
                   capture_output=True)
    peer = np.load(tmp_path / "out.npz")
    assert bool(peer["success"])
    r = solve(h, sigma0=sigma0, interaction="hard_wall", length=length, tol=1e-11, periodic=False)
    assert r.converged
    np.testing.assert_array_equal(r.pressure > 0, peer["p"] > 0)
    assert r.mean_gap == pytest.approx(float(peer["gap"].mean()), rel=1e-6)
    np.testing.assert_allclose(r.pressure, peer["p"], rtol=0, atol=1e-6 * sigma0)


def dense_newton(h: np.ndarray, length, law, sigma0: float, u: np.ndarray, delta: float):
    """Independent solve of a smooth law on a small free map: the dense compliance matrix by direct summation of
    the pixel Green's function, Newton on ``u = K p(delta + u - h)``, ``<p> = sigma0`` (Jacobian from
    ``law.stiffness``), to round-off. Returns ``(u, delta, gap)``."""
    nx, ny = h.shape
    dx, dy = length[0] / nx, length[1] / ny
    ix, iy = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    x, y = ix.ravel() * dx, iy.ravel() * dy
    K = boussinesq_pixel(x[:, None] - x[None, :], y[:, None] - y[None, :], dx / 2, dy / 2, 1.0)
    hv, n = h.ravel(), h.size
    for _ in range(100):
        g = delta + u - hv
        p, kk = law.pressure(g), law.stiffness(g)
        F = np.concatenate([u - K @ p, [p.mean() - sigma0]])
        J = np.zeros((n + 1, n + 1))
        J[:n, :n] = np.eye(n) + K * kk[None, :]
        J[:n, n] = K @ kk
        J[n, :n] = -kk / n
        J[n, n] = -kk.mean()
        step = np.linalg.solve(J, -F)
        u, delta = u + step[:n], delta + step[n]
        if np.abs(step).max() < 1e-14 * (1 + abs(delta)):
            break
    return u, delta, (delta + u - hv).reshape(h.shape)


SMOOTH = [("exponential", dict(gamma0=1e-4, rho=2e-3), 0.01), ("exponential", dict(gamma0=1e-3, rho=5e-3), 0.1),
          ("adhesive", dict(work=1e-4, rho=2e-3), 0.01)]


@pytest.mark.validation
@pytest.mark.parametrize(("name", "kw", "sigma0"), SMOOTH)
def test_smooth_laws_on_a_free_map_agree_with_dense_newton(name, kw, sigma0) -> None:
    """Exponential repulsion and adhesion on a 24 x 16 free map (box 1.5 x 1): mean gap to 1e-8 relative and
    pressures to 1e-7 sigma0 against :func:`dense_newton` (measured: 1e-11 and 1e-10). The exponential law
    (convex, one equilibrium) is solved by Newton from a flat start; the adhesive one (non-convex) from
    gapsweep's answer, which Newton must leave unchanged (it is an equilibrium of the dense equations)."""
    nx, ny, length = 24, 16, (1.5, 1.0)
    h = self_affine(64, 0.8, lambda_l=0.5, lambda_s=0.1, seed=3)[5:5 + nx, 7:7 + ny]
    h = (h - h.mean()) / h.std() * 0.01
    r = solve(h, sigma0=sigma0, interaction=name, length=length, tol=1e-10, periodic=False, **kw)
    assert r.converged and not r.periodic
    assert float(r.pressure.mean()) == pytest.approx(sigma0, rel=1e-9)
    law = resolve(name, **kw)
    if name == "exponential":
        u, delta = np.zeros(h.size), float(h.max())
    else:
        u, delta = r.displacement.ravel().copy(), float(r.diagnostics["approach"])
    _, _, gap = dense_newton(h, length, law, sigma0, u, delta)
    assert r.mean_gap == pytest.approx(float(gap.mean()), rel=1e-8)
    np.testing.assert_allclose(r.pressure, law.pressure(gap), rtol=0, atol=1e-7 * sigma0)


def test_free_exponential_warm_start_and_bad_method() -> None:
    h = self_affine(32, 0.8, lambda_l=0.5, lambda_s=0.2, seed=2)[:20, :12] * 0.1
    a = solve(h, sigma0=0.01, gamma0=1e-4, rho=2e-3, length=(1.0, 0.6), tol=1e-9, periodic=False)
    b = solve(h, sigma0=0.011, gamma0=1e-4, rho=2e-3, length=(1.0, 0.6), tol=1e-9, periodic=False, initial=a)
    c = solve(h, sigma0=0.011, gamma0=1e-4, rho=2e-3, length=(1.0, 0.6), tol=1e-9, periodic=False)
    assert b.converged and c.converged and b.iterations < c.iterations
    assert b.mean_gap == pytest.approx(c.mean_gap, rel=1e-7)
    d = solve(h, sigma0=0.011, gamma0=1e-4, rho=2e-3, length=(1.0, 0.6), tol=1e-9, periodic=False, backend="numpy")
    assert d.converged and d.mean_gap == pytest.approx(c.mean_gap, rel=1e-7)  # scipy transforms = FFTW plans
    with pytest.raises(ValueError, match="with periodic=False"):
        solve(h, sigma0=0.01, gamma0=1e-4, rho=2e-3, periodic=False, method="fire")
    with pytest.raises(ValueError, match="initial must be None or a GFMDResult of a free-boundary"):
        solve(h, sigma0=0.01, gamma0=1e-4, rho=2e-3, periodic=False, initial=np.zeros_like(h))


@pytest.mark.validation
@pytest.mark.parametrize(("name", "kw", "sigma0"), [("exponential", dict(gamma0=1e-4, rho=2e-3), 0.01),
                                                   ("adhesive", dict(work=1e-4, rho=2e-3), 0.01),
                                                   ("adhesive", dict(work=1e-4, rho=2e-3), -2e-5)])
def test_free_cg_agrees_with_lbfgs(name, kw, sigma0) -> None:
    """Method "cg" (nonlinear CG, the GPU's leaner option) ends at the L-BFGS answer of the same free map by the
    same criterion: converged at tol 1e-9, mean gap within 1e-7 relative, pressures within 1e-6 of their scale."""
    h = self_affine(128, 0.8, lambda_l=0.5, lambda_s=8 / 128, seed=5)[:80, 10:70]
    h = h / h.std() * 0.01
    common = dict(sigma0=sigma0, interaction=name, length=(1.0, 0.75), tol=1e-9, periodic=False, **kw)
    a = solve(h, method="lbfgs", **common)
    b = solve(h, method="cg", **common)
    assert a.converged and b.converged and b.method == "cg" and a.method == "lbfgs"
    assert b.residual <= 1e-9 and b.load_error <= 1e-9
    assert b.mean_gap == pytest.approx(a.mean_gap, rel=1e-7)
    scale = a.diagnostics["pressure_scale"]
    np.testing.assert_allclose(b.pressure, a.pressure, rtol=0, atol=1e-6 * scale)
