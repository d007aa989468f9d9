"""Adhesive law at tensile loads (issue 22, docs/gfmd.md "Tensile loads"): a direct solve follows the load from
zero to the tensile target inside ``solve`` and lands on the equilibrium that a fine load path reaches; beyond
pull-off it reports "detached" with the pull-off bracket; a run whose residual stops moving ends "stalled".
The reference for the equilibria is an independent route through the package, :func:`gfmd.solve_path` with
fine fixed steps (each step warm-started, no continuation inside); the peer comparison (ContactMechanics +
Adhesion + scipy) is in tests/test_peers_adhesion.py. CPU, N = 64: a few seconds."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gapsweep.gfmd import solve, solve_path
from gapsweep.surface import self_affine

N, WORK = 64, 1e-3
RHO = 1.0 / N  # one pixel
MAX_T = WORK / (math.e * RHO)  # largest tensile stress of the law


def surface(seed: int) -> np.ndarray:
    h = self_affine(N, 0.8, lambda_l=0.25, lambda_s=4 / N, seed=seed)
    return h - h.mean()


def adhesive(h: np.ndarray, sigma0: float, **kw):
    return solve(h, sigma0=sigma0, interaction="adhesive", work=WORK, rho=RHO, backend="numpy", **kw)


@pytest.mark.validation
@pytest.mark.parametrize(("seed", "frac"), [(5, 0.2), (5, 0.3), (6, 0.3)])
def test_direct_tensile_solve_finds_the_attached_equilibrium(seed: int, frac: float) -> None:
    """Before issue 22 these direct solves reported "detached" (measured: 8-10 evaluations) although the load
    path reaches an attached equilibrium. Now: converged, and the same equilibrium as a path of 31 fixed steps
    from zero load (mean gap and elastic energy to 1e-7 relative, the same contact area)."""
    h = surface(seed)
    sigma0 = -frac * MAX_T
    r = adhesive(h, sigma0, tol=1e-10)
    assert r.status == "converged" and r.converged
    assert r.diagnostics["continuation_from"] == 0.0 and r.diagnostics["last_attached_load"] == sigma0
    path = solve_path(h, np.linspace(0.0, sigma0, 31), interaction="adhesive", work=WORK, rho=RHO, tol=1e-10,
                      backend="numpy")
    ref = path.results[-1]
    assert not path.stopped and ref.converged and not path.jumps
    np.testing.assert_allclose([r.mean_gap, r.elastic_energy], [ref.mean_gap, ref.elastic_energy], rtol=1e-7)
    assert r.contact_area == ref.contact_area > 0.2
    assert abs(r.pressure.mean() - sigma0) <= 1e-10 * MAX_T


def test_beyond_pull_off_detached_with_bracket() -> None:
    """Beyond pull-off: "detached", never converged; ``last_attached_load`` is an attached equilibrium (a direct
    solve there converges, in contact) and the pull-off lies within ``min_step`` below it: a solve one step
    beyond it detaches. A few hundred evaluations, not max_iter."""
    h = surface(6)
    r = adhesive(h, -0.6 * MAX_T, tol=1e-9)
    assert r.status == "detached" and not r.converged
    last, step = r.diagnostics["last_attached_load"], r.diagnostics["min_step"]
    assert -0.6 * MAX_T < last < 0 and 0 < step <= 1e-3 * MAX_T
    assert r.iterations < 2000
    at = adhesive(h, last, tol=1e-9)
    assert at.converged and at.contact_area > 0
    off = adhesive(h, last - 2 * step, tol=1e-9)
    assert off.status == "detached"
    assert off.diagnostics["last_attached_load"] == pytest.approx(last, abs=2 * step)


def test_warm_start_that_detaches_follows_the_load() -> None:
    """A warm start from a compressive result that detaches at a tensile load is followed down from the initial
    load before "detached" is reported: ``last_attached_load`` (N = 128, seed 5: -0.205 of the largest
    tension) is an equilibrium reached from the same warm start, and the same bracket as the direct solve's."""
    n = 128
    rho = 1.0 / n
    max_t = WORK / (math.e * rho)
    h = self_affine(n, 0.8, lambda_l=0.25, lambda_s=4 / n, seed=5)
    kw = dict(interaction="adhesive", work=WORK, rho=rho, tol=1e-9, backend="numpy")
    r0 = solve(h, sigma0=5e-3, **kw)
    r = solve(h, sigma0=-0.3 * max_t, initial=r0, **kw)
    assert r.status == "detached" and r.diagnostics["continuation_from"] == pytest.approx(5e-3)
    last, step = r.diagnostics["last_attached_load"], r.diagnostics["min_step"]
    assert -0.3 * max_t < last < -0.1 * max_t
    at = solve(h, sigma0=last, initial=r0, **kw)
    assert at.converged and at.contact_area > 0.05
    direct = solve(h, sigma0=-0.3 * max_t, **kw)
    assert direct.status == "detached"
    assert abs(direct.diagnostics["last_attached_load"] - last) <= 2 * step + 1e-3 * max_t


def test_residual_that_stops_moving_is_stalled() -> None:
    """A tolerance below the round-off floor (residual ~1e-14 here): before issue 22 the run spent all of
    max_iter (measured: 3000 evaluations); now it ends "stalled" once residual and energy stop moving."""
    h = surface(5)
    r = adhesive(h, 1e-3, tol=1e-16, max_iter=3000)
    assert r.status == "stalled" and not r.converged
    assert r.residual < 1e-12  # it did reach the floor
    assert r.iterations < 400
