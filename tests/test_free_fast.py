"""Free boundaries on the CPU, issue 39: the exponential law's approach eliminated in closed form and the shorter
L-BFGS memory (gapsweep.gfmd._free) against the former path (the approach an unknown of the minimiser, 12 pairs):
the same answers to the solver tolerance on maps of several shapes (odd, rectangular, physical units)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from gapsweep import gfmd
from gapsweep.gfmd import _free
from gapsweep.surfaces.synthetic import self_affine


def _solve(h, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return gfmd.solve(h, periodic=False, **kw)


@pytest.mark.parametrize("shape,length,kw", [
    ((45, 37), (22.5, 18.5), dict(sigma0=20.0, e_star=1000.0, gamma0=50.0, rho=0.5)),  # um, MPa, odd sides
    ((64, 64), (1.0, 1.0), dict(sigma0=0.02, gamma0=1e-4, rho=2e-2)),
    ((48, 80), (0.6, 1.0), dict(sigma0=0.05, gamma0=1e-4, rho=1.5e-2)),
])
def test_eliminated_approach_agrees_with_the_former_path(monkeypatch, shape, length, kw):
    n = max(shape)
    h = self_affine(n, 0.7, lambda_l=0.5, lambda_s=4 / n, rms_slope=0.6, seed=41)[:shape[0], :shape[1]]
    h = h * (length[0] / 0.5 if length[0] > 2 else 1.0)  # the um map: heights of a few um
    tol = 1e-9
    new = _solve(h, length=length, tol=tol, **kw)
    monkeypatch.setattr(_free, "ELIMINATE", False)
    monkeypatch.setattr(_free, "_MEMORY_CPU", 12)
    old = _solve(h, length=length, tol=tol, **kw)
    assert new.converged and old.converged
    assert new.diagnostics["approach"] == pytest.approx(old.diagnostics["approach"], rel=1e-7, abs=1e-9 * kw["rho"])
    assert abs(new.mean_gap / old.mean_gap - 1) <= 1e-7
    np.testing.assert_allclose(new.gap, old.gap, atol=1e-6 * np.abs(old.gap).max())
    np.testing.assert_allclose(new.pressure, old.pressure, atol=1e-6 * np.abs(old.pressure).max())
    assert abs(new.contact_area - old.contact_area) * h.size <= 2
    assert 0 < new.contact_area < 1
    assert new.load_error <= tol  # <p>_map = sigma0 by construction where the approach is eliminated
