"""Elastic-perfectly-plastic contact (``gfmd.solve(..., interaction="hard_wall", hardness=H)``, docs/gfmd.md
"Plastic contact (pressure cap)"): the limits H -> oo (the elastic hard wall) and rigid-plastic (E* h'/H -> oo:
the bearing-area solution), the KKT conditions on the returned fields, the residual surface of an unloading, the
cap on a layer and with free boundaries, and the refusals. tamaas' KatoSaturated: tests/test_peers_layer.py."""

from __future__ import annotations

import numpy as np
import pytest

from gapsweep.gfmd import residual_surface, solve
from gapsweep.surface import self_affine


def surface(n: int = 64, seed: int = 5, shape: tuple[int, int] | None = None) -> np.ndarray:
    h = self_affine(n, 0.8, lambda_l=0.25, lambda_s=4 / n, seed=seed)
    return h if shape is None else h[: shape[0], : shape[1]]


@pytest.mark.validation
@pytest.mark.parametrize("periodic", [True, False])
def test_large_hardness_is_the_elastic_hard_wall(periodic: bool) -> None:
    h = surface(32, seed=7)
    el = solve(h, sigma0=0.02, interaction="hard_wall", tol=1e-10, periodic=periodic)
    pl = solve(h, sigma0=0.02, interaction="hard_wall", tol=1e-10, periodic=periodic,
               hardness=1.01 * float(el.pressure.max()))
    assert el.converged and pl.converged
    assert pl.plastic_area == 0.0 and np.all(pl.plastic_displacement == 0.0)
    np.testing.assert_allclose(pl.pressure, el.pressure, atol=1e-7 * 0.02)
    assert pl.mean_gap == pytest.approx(el.mean_gap, rel=1e-7)
    assert pl.contact_area == el.contact_area


@pytest.mark.parametrize(("hard", "seed", "shape"), [(0.05, 5, None), (0.1, 8, (48, 40)), (0.3, 2, None)])
def test_kkt_conditions_hold(hard: float, seed: int, shape) -> None:
    h = surface(64, seed, shape)
    sigma0 = 0.02
    r = solve(h, sigma0=sigma0, interaction="hard_wall", hardness=hard, tol=1e-9, length=(1.0, 1.0))
    assert r.converged, r.status
    p = r.pressure
    assert p.min() >= 0 and p.max() <= hard
    assert np.mean(p) == pytest.approx(sigma0, rel=1e-9)
    assert r.plastic_area == pytest.approx(np.mean(p >= hard))
    assert r.plastic_area > 0
    assert r.contact_area >= sigma0 / hard  # the load needs at least this much area at p <= H
    # the body touches the flattened surface h - u_pl: gap 0 on the contact, u_pl > 0 only where p = H
    assert np.all(r.plastic_displacement[p < hard] == 0) and np.all(r.plastic_displacement >= 0)
    assert np.all(r.gap[p > 0] == 0) and np.all(r.gap >= 0)
    assert r.mean_gap == pytest.approx(float(r.gap.mean()))


@pytest.mark.validation
def test_rigid_plastic_limit_is_the_bearing_area() -> None:
    """E* h'_rms / H -> oo: elastic deformation negligible, p = H on the contact, whose area is sigma0 / H: the
    bearing area of the surface, the part above the level d with <h > d> = sigma0 / H; the mean gap <(d - h)+>."""
    h = surface(64, seed=3)
    sigma0, hard = 0.01, 0.05
    r = solve(h, sigma0=sigma0, interaction="hard_wall", hardness=hard, e_star=1e5, tol=1e-8)
    assert r.converged
    d = float(np.quantile(h, 1.0 - sigma0 / hard))
    assert r.contact_area == pytest.approx(sigma0 / hard, abs=2.0 / h.size)
    assert r.plastic_area == pytest.approx(sigma0 / hard, abs=2.0 / h.size)
    assert r.mean_gap == pytest.approx(float(np.mean(np.maximum(d - h, 0.0))), rel=2e-3)
    assert np.sum(r.plastic_displacement) == pytest.approx(np.sum(np.maximum(h - d, 0.0)), rel=2e-3)


@pytest.mark.validation
def test_residual_surface_reloads_elastically() -> None:
    """After unloading, the surface h - u_pl; loaded again to sigma0 it carries the first loading's pressure
    elastically (no further flow): the same pressure field from the elastic hard wall."""
    h = surface(48, seed=9)
    sigma0, hard = 0.02, 0.08
    first = solve(h, sigma0=sigma0, interaction="hard_wall", hardness=hard, tol=1e-10)
    assert first.converged and first.plastic_area > 0.05
    h2 = residual_surface(h, first)
    again = solve(h2, sigma0=sigma0, interaction="hard_wall", tol=1e-10)
    assert again.converged
    np.testing.assert_allclose(again.pressure, first.pressure, atol=1e-6 * hard)
    assert again.mean_gap == pytest.approx(first.mean_gap, rel=1e-6)
    # a lighter second loading stays elastic: under the cap without flow
    light = solve(h2, sigma0=0.5 * sigma0, interaction="hard_wall", hardness=hard, tol=1e-9)
    assert light.converged and light.plastic_area == 0.0
    with pytest.raises(ValueError, match="hardness"):
        residual_surface(h, again)


def test_cap_on_a_layer_and_free_boundaries() -> None:
    h = surface(32, seed=4)
    for kw in ({"thickness": 0.05, "poisson": 0.3}, {"periodic": False}):
        el = solve(h, sigma0=0.02, interaction="hard_wall", tol=1e-10, **kw)
        big = solve(h, sigma0=0.02, interaction="hard_wall", tol=1e-10, hardness=10 * float(el.pressure.max()),
                    **kw)
        np.testing.assert_allclose(big.pressure, el.pressure, atol=1e-7 * 0.02)
        capped = solve(h, sigma0=0.02, interaction="hard_wall", tol=1e-9, hardness=0.4 * float(el.pressure.max()),
                       **kw)
        assert capped.converged and capped.plastic_area > 0 and capped.contact_area > el.contact_area


def test_hardness_refusals() -> None:
    h = surface(32)
    for bad in (0.0, -1.0, np.nan, "2"):
        with pytest.raises(ValueError, match="hardness"):
            solve(h, sigma0=0.01, interaction="hard_wall", hardness=bad)
    with pytest.raises(ValueError, match="exceed"):
        solve(h, sigma0=0.01, interaction="hard_wall", hardness=0.01)
    with pytest.raises(ValueError, match="hard_wall"):
        solve(h, sigma0=0.01, gamma0=1e-3, rho=1e-2, hardness=0.1)
    r = solve(h, sigma0=0.01, interaction="hard_wall", hardness=np.inf)  # no cap: the elastic hard wall
    assert np.isnan(r.plastic_area)


def test_fused_and_generic_passes_agree(monkeypatch) -> None:
    """The numba passes (gfmd._plastic_ops, the CPU default) against the generic array code of gfmd._plastic."""
    h = surface(64, seed=12)
    fused = solve(h, sigma0=0.02, interaction="hard_wall", hardness=0.06, tol=1e-10)
    monkeypatch.setenv("GAPSWEEP_GENERIC_KERNELS", "1")
    generic = solve(h, sigma0=0.02, interaction="hard_wall", hardness=0.06, tol=1e-10)
    assert fused.converged and generic.converged and fused.plastic_area > 0
    np.testing.assert_allclose(fused.pressure, generic.pressure, atol=1e-8 * 0.02)
    assert fused.mean_gap == pytest.approx(generic.mean_gap, rel=1e-8)


def test_displacement_from_the_gap_and_the_plastic_field() -> None:
    """The identity the sweep's kept fields use (gapsweep.sweep.methods.gfmd._keep_fields): with the gap to the
    flattened surface, ``u = gap - (mean_gap - <u_pl>) + (h - <h>) - u_pl``."""
    h = surface(48, seed=6) + 0.3
    r = solve(h, sigma0=0.02, interaction="hard_wall", hardness=0.06, tol=1e-10)
    assert r.converged and r.plastic_area > 0
    u_pl = r.plastic_displacement
    u = r.gap - (r.mean_gap - u_pl.mean()) + (h - h.mean()) - u_pl
    np.testing.assert_allclose(u, r.displacement, atol=1e-9 * h.std())


@pytest.mark.validation
@pytest.mark.parametrize("kw", [{"periodic": False}, {"thickness": 0.03, "poisson": 0.3}])
def test_coarse_start_with_the_cap_agrees_with_plain_pk(kw) -> None:
    """N = 256: "mpcg" (coarse levels of the same substrate: block means for free boundaries, the layer's grid)
    against plain PK from the uniform start."""
    h = self_affine(256, 0.8, lambda_l=0.5, lambda_s=8 / 256, seed=3, rms_slope=0.5)
    a = solve(h, sigma0=0.02, interaction="hard_wall", hardness=0.2, tol=1e-9, **kw)
    b = solve(h, sigma0=0.02, interaction="hard_wall", hardness=0.2, tol=1e-9, method="pk", **kw)
    assert a.converged and b.converged and a.diagnostics["coarse_iterations"]
    assert a.mean_gap == pytest.approx(b.mean_gap, rel=1e-8)
    assert a.plastic_area == b.plastic_area > 0
