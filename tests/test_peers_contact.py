"""Hard-wall contact against peer codes on identical surfaces (marker ``peers``; skipped where a peer is not
installed). Run in an environment with gapsweep's dependencies and the peers (docs/gfmd.md, "Peers"):

    python -m venv peers && peers/bin/pip install tamaas contactmechanics adhesion surfacetopography pytest
    PYTHONPATH=. peers/bin/python -m pytest -m peers tests/test_peers_contact.py

Both peers solve the same discrete problem (periodic half-space, E*, the same grid) with Polonsky-Keer-type
constrained conjugate gradients at fixed mean pressure; at tight tolerances mean gap, contact area and elastic
energy agree to 1e-6 relative (measured: 1e-11 and better)."""

from __future__ import annotations

import numpy as np
import pytest

from gapsweep.gfmd import solve
from gapsweep.surface import self_affine

pytestmark = [pytest.mark.peers, pytest.mark.validation]

CASES = [(0.8, 1e-3), (0.8, 1e-2), (0.3, 1e-2), (0.3, 1e-1)]


def surface(hurst: float, n: int = 128) -> np.ndarray:
    return self_affine(n, hurst, lambda_l=0.25, lambda_s=4 / n, seed=3)


def quantities(u: np.ndarray, p: np.ndarray, gap: np.ndarray) -> tuple[float, float, float]:
    """(mean gap, contact area, elastic energy per area = <(u - <u>)(p - <p>)>/2)."""
    return float(gap.mean()), float(np.mean(p > 0)), 0.5 * float(np.mean((u - u.mean()) * (p - p.mean())))


def tamaas_hard_wall(h: np.ndarray, sigma0: float, tol: float = 1e-11):
    tamaas = pytest.importorskip("tamaas")
    n = h.shape[0]
    m = tamaas.ModelFactory.createModel(tamaas.model_type.basic_2d, [1.0, 1.0], [n, n])
    m.E, m.nu = 1.0, 0.0  # E* = E / (1 - nu^2)
    tamaas.PolonskyKeerRey(m, h.copy(), tol).solve(sigma0)
    u, p = np.array(m.displacement), np.array(m.traction)
    return quantities(u, p, u - h)


def contactmechanics_hard_wall(h: np.ndarray, sigma0: float):
    pytest.importorskip("ContactMechanics")
    from ContactMechanics import PeriodicFFTElasticHalfSpace
    from ContactMechanics.Systems import NonSmoothContactSystem
    from SurfaceTopography import Topography

    n = h.shape[0]
    system = NonSmoothContactSystem(PeriodicFFTElasticHalfSpace((n, n), 1.0, physical_sizes=(1.0, 1.0)),
                                    Topography(h, (1.0, 1.0)))
    res = system.minimize_proxy(external_force=sigma0, pentol=1e-12 * h.std(), forcetol=1e-12, maxiter=100000)
    assert res.success
    u, p = res.x, res.jac * n * n  # pixel forces -> pressure (box area 1)
    return quantities(u, p, u - (h + res.offset))


@pytest.mark.parametrize(("hurst", "sigma0"), CASES)
@pytest.mark.parametrize("peer", [tamaas_hard_wall, contactmechanics_hard_wall], ids=["tamaas", "contactmechanics"])
@pytest.mark.parametrize("method", ["pcg", "pk"])
def test_hard_wall_agrees_with_peer(peer, hurst: float, sigma0: float, method: str) -> None:
    h = surface(hurst)
    theirs = peer(h, sigma0)
    r = solve(h, sigma0=sigma0, interaction="hard_wall", tol=1e-11, method=method, backend="numpy")
    assert r.converged
    ours = (r.mean_gap, r.contact_area, r.elastic_energy)
    np.testing.assert_allclose(ours, theirs, rtol=1e-6)


def contactmechanics_adhesive(h: np.ndarray, sigma0: float, work: float, rho: float, z0: np.ndarray):
    """Independent solve of the adhesive problem at fixed mean pressure: ContactMechanics' periodic elastic
    half-space (stiffness_q0 = 0: the mean displacement is free) and scipy's L-BFGS-B on the body's surface z,
    energy ``E_el(z) + sum phi(z - h) dA + sigma0 L^2 <z>`` with the exponential cohesive law written out here
    (not gapsweep's class); the same start as gapsweep's."""
    pytest.importorskip("ContactMechanics")
    import scipy.optimize
    from ContactMechanics import PeriodicFFTElasticHalfSpace

    n = h.shape[0]
    sub = PeriodicFFTElasticHalfSpace((n, n), 1.0, physical_sizes=(1.0, 1.0), stiffness_q0=0.0)
    da = 1.0 / n**2

    def fun(x):
        z = x.reshape(n, n)
        e_el, f_el = sub.evaluate(z, pot=True, forces=True)
        s = (z - h) / rho
        ex = np.exp(-s)
        phi = -work * (1 + s) * ex
        dphi = (work / rho) * s * ex  # phi'(g)
        energy = e_el + float(np.sum(phi)) * da + sigma0 * float(np.mean(z))
        grad = -f_el + dphi * da + sigma0 * da
        return energy, grad.ravel()

    sol = scipy.optimize.minimize(fun, z0.ravel(), jac=True, method="L-BFGS-B",
                                  options={"maxiter": 100000, "maxfun": 200000, "ftol": 0.0, "gtol": 1e-15,
                                           "maxcor": 20})
    z = sol.x.reshape(n, n)
    gap = z - h
    s = gap / rho
    p = -(work / rho) * s * np.exp(-s)
    return float(gap.mean()), float(np.mean(gap < rho)), 0.5 * float(np.mean((z - z.mean()) * (p - p.mean()))), p


@pytest.mark.parametrize("sigma0", [1e-3, -2e-4])
def test_adhesive_agrees_with_independent_solver(sigma0: float) -> None:
    """The adhesive law at a compressive and a tensile load: gapsweep's smooth minimiser and an independent
    one (ContactMechanics' half-space + scipy L-BFGS-B) reach the same local minimum from the same start (the
    flat body touching the highest summit): mean gap and elastic energy to 1e-6 relative, same contact area."""
    h = surface(0.8, n=64)
    h = h - h.mean()
    work, rho = 1e-3, 0.004
    r = solve(h, sigma0=sigma0, interaction="adhesive", work=work, rho=rho, tol=1e-11, backend="numpy")
    assert r.converged
    z0 = np.full(h.shape, h.max())
    gap, area, energy, p = contactmechanics_adhesive(h, sigma0, work, rho, z0)
    np.testing.assert_allclose([r.mean_gap, r.elastic_energy], [gap, energy], rtol=1e-6)
    assert r.contact_area == area
    assert abs(p.mean() - sigma0) <= 1e-6 * max(abs(sigma0), work / (np.e * rho))
