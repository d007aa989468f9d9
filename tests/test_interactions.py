"""The interaction-law interface of GFMD (docs/gfmd.md, "Interaction laws"): resolution of names and objects,
and the exponential law on it giving today's answers."""

from __future__ import annotations

import numpy as np
import pytest

from gapsweep.gfmd import solve
from gapsweep.gfmd.interactions import Exponential, resolve
from gapsweep.surface import self_affine


def test_exponential_object_equals_name() -> None:
    h = self_affine(64, 0.3, lambda_l=0.25, lambda_s=1 / 16, seed=3)
    a = solve(h, sigma0=1e-2, gamma0=1e-3, rho=0.02, tol=1e-9, backend="numpy")
    b = solve(h, sigma0=1e-2, interaction=Exponential(1e-3, 0.02), tol=1e-9, backend="numpy")
    assert a.converged and b.converged
    assert a.mean_gap == b.mean_gap and a.iterations == b.iterations
    np.testing.assert_array_equal(a.gap, b.gap)


@pytest.mark.validation
def test_exponential_law_functions() -> None:
    law = Exponential(2e-3, 0.05)
    g = np.linspace(-0.1, 0.3, 7)
    # p = -phi', phi'' = -p' by central differences
    d = 1e-6
    np.testing.assert_allclose(law.pressure(g), -(law.energy(g + d) - law.energy(g - d)) / (2 * d), rtol=1e-7)
    np.testing.assert_allclose(law.stiffness(g), -(law.pressure(g + d) - law.pressure(g - d)) / (2 * d), rtol=1e-7)
    assert law.curvature(1e-2) == pytest.approx(1e-2 / 0.05)


@pytest.mark.parametrize(
    ("interaction", "params", "match"),
    [
        ("lennard", {}, "interaction must be one of"),
        ("exponential", {"gamma0": 1e-3}, "needs rho"),
        ("exponential", {"gamma0": 1e-3, "rho": 0.1, "bogus": 1.0}, "got also bogus"),
        (Exponential(1e-3, 0.1), {"rho": 0.1}, "pass rho to it"),
        (3, {}, "interaction must be one of"),
    ],
)
def test_resolve_rejects(interaction, params, match) -> None:
    with pytest.raises(ValueError, match=match):
        resolve(interaction, **params)


def test_solve_requires_law_parameters() -> None:
    with pytest.raises(ValueError, match="needs gamma0"):
        solve(np.zeros((8, 8)), sigma0=1e-2, rho=0.1)
