"""The elastic layer and the pressure cap against peer codes on surfaces of our own (marker ``peers``; skipped
where a peer is not installed; run as tests/test_peers_contact.py says):

- ContactMechanics' ``PeriodicFFTElasticHalfSpace(shape, young, physical_sizes, thickness=t, poisson=nu)``: a layer
  bonded to its rigid base (Carbone & Mangialardi 2008, Eq. A.30, in its source; docs/model.md), hard wall by
  its constrained CG (``NonSmoothContactSystem.minimize_proxy``): mean gap, contact area and pressure field.
- tamaas 2.9's ``KatoSaturated(model, h - h.max(), tol, H)``: the hard wall with the pressure capped at ``H``:
  pressure field, contact and plastic areas."""

from __future__ import annotations

import numpy as np
import pytest

from gapsweep.gfmd import solve
from gapsweep.surface import self_affine

pytestmark = [pytest.mark.peers, pytest.mark.validation]


@pytest.mark.parametrize(("n", "t", "nu", "sigma0", "seed"), [(64, 0.05, 0.3, 0.01, 5), (48, 0.2, 0.45, 0.03, 6),
                                                              (64, 0.01, 0.0, 0.005, 7)])
def test_layer_agrees_with_contactmechanics(n: int, t: float, nu: float, sigma0: float, seed: int) -> None:
    """Square boxes; the rectangular one in physical units: test_layer_rectangle_in_physical_units."""
    pytest.importorskip("ContactMechanics")
    from ContactMechanics import PeriodicFFTElasticHalfSpace
    from ContactMechanics.Systems import NonSmoothContactSystem
    from SurfaceTopography import Topography

    size = (2.0, 2.0)
    h = 2.0 * self_affine(n, 0.8, lambda_l=0.25, lambda_s=4 / n, seed=seed)
    young = 3.0
    sub = PeriodicFFTElasticHalfSpace((n, n), young, physical_sizes=size, thickness=t, poisson=nu)
    system = NonSmoothContactSystem(sub, Topography(h, size))
    res = system.minimize_proxy(external_force=sigma0 * size[0] * size[1], pentol=1e-12 * h.std(),
                                forcetol=1e-12, maxiter=100000)
    assert res.success
    p = res.jac / (size[0] * size[1] / n**2)  # pixel forces -> pressure
    gap = res.x - (h + res.offset)
    r = solve(h, sigma0=sigma0, interaction="hard_wall", e_star=young / (1 - nu**2), length=size, thickness=t,
              poisson=nu, bottom="bonded", tol=1e-11)
    assert r.converged
    assert r.mean_gap == pytest.approx(float(gap.mean()), rel=1e-7)
    assert r.contact_area == float(np.mean(p > 0))
    np.testing.assert_allclose(r.pressure, p, atol=1e-7 * sigma0)


@pytest.mark.parametrize(("shape", "size", "young", "nu", "hard", "seed"),
                         [((64, 64), (1.0, 1.0), 1.0, 0.0, 0.05, 5), ((64, 64), (1.0, 1.0), 1.0, 0.0, 0.1, 5),
                          ((48, 48), (1.0, 1.0), 1.0, 0.0, 0.2, 11), ((64, 64), (2.0, 2.0), 2.0, 0.3, 0.1, 9),
                          ((64, 48), (1.0, 0.75), 1.0, 0.0, 0.1, 9)])
def test_cap_agrees_with_tamaas_kato_saturated(shape, size, young: float, nu: float, hard: float, seed: int) -> None:
    """Square and rectangular boxes, tamaas' E and nu (E* = E / (1 - nu^2)). (At box sides of 1e-6 tamaas'
    KatoSaturated returns full contact at the same tolerance: its own limit, not compared.)"""
    tamaas = pytest.importorskip("tamaas")
    h = self_affine(max(shape), 0.8, lambda_l=0.25, lambda_s=4 / max(shape), seed=seed)[: shape[0], : shape[1]]
    sigma0 = 0.02
    m = tamaas.ModelFactory.createModel(tamaas.model_type.basic_2d, list(size), list(shape))
    m.E, m.nu = young, nu
    tamaas.KatoSaturated(m, h - h.max(), 1e-12, hard).solve(sigma0)
    p = np.array(m.traction)
    r = solve(h, sigma0=sigma0, interaction="hard_wall", hardness=hard, e_star=young / (1 - nu**2), length=size,
              tol=1e-10)
    assert r.converged
    n = h.size
    np.testing.assert_allclose(r.pressure, p, atol=1e-6 * sigma0)
    assert r.plastic_area == pytest.approx(float(np.mean(p >= hard * (1 - 1e-9))), abs=1.0 / n)
    assert r.contact_area == pytest.approx(float(np.mean(p > 0)), abs=1.0 / n)


def test_layer_rectangle_in_physical_units() -> None:
    """A 64 x 48 map of 64 um x 48 um, heights in m, E = 2 GPa, nu = 0.35, t = 5 um, sigma0 = 2 MPa."""
    pytest.importorskip("ContactMechanics")
    from ContactMechanics import PeriodicFFTElasticHalfSpace
    from ContactMechanics.Systems import NonSmoothContactSystem
    from SurfaceTopography import Topography

    h = self_affine(64, 0.7, lambda_l=0.5, lambda_s=4 / 64, seed=9)[:, :48] * 1e-6
    size = (64e-6, 48e-6)
    young, nu, t, sigma0 = 2e9, 0.35, 5e-6, 2e6
    system = NonSmoothContactSystem(PeriodicFFTElasticHalfSpace(h.shape, young, physical_sizes=size, thickness=t,
                                                                poisson=nu), Topography(h, size))
    res = system.minimize_proxy(external_force=sigma0 * size[0] * size[1], pentol=1e-12 * h.std(),
                                forcetol=1e-12, maxiter=100000)
    assert res.success
    p = res.jac / (size[0] * size[1] / h.size)
    r = solve(h, sigma0=sigma0, interaction="hard_wall", e_star=young / (1 - nu**2), length=size, thickness=t,
              poisson=nu, tol=1e-11)
    assert r.converged
    assert r.mean_gap == pytest.approx(float((res.x - (h + res.offset)).mean()), rel=1e-7)
    np.testing.assert_allclose(r.pressure, p, atol=1e-7 * sigma0)
