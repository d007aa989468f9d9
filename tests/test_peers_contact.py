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

pytestmark = pytest.mark.peers

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
