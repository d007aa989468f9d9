"""One law, one convention (issue 36, item 5; docs/model.md M3 "Mean gap", docs/gfmd.md "Warnings and errors"):
the mean gap and the gap field do not depend on the mean height of the map on any grid shape or boundary; the
same physical problem on a rectangular periodic map and on its square tiling (two different minimisers: the
generic L-BFGS and the exponential law's softmax CG) has the same mean gap; ``UnderResolvedWarning`` for every
law with a range on every grid shape and boundary, once per call or load path; tiny loads on rectangular and odd
grids converge instead of ending "stalled" at 1e-8 .. 1e-6."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from gapsweep.gfmd import BatchProblem, UnderResolvedWarning, solve, solve_batch, solve_path
from gapsweep.surface import self_affine

H = self_affine(32, 0.8, lambda_l=0.5, lambda_s=4 / 32, seed=11, rms_slope=1.0)
EXP = dict(gamma0=1e-4, rho=0.05)
ADH = dict(interaction="adhesive", work=1e-4, rho=0.05)


@pytest.mark.parametrize(("law", "shape", "periodic"), [
    (EXP, "square", True), (EXP, "rect", True), (EXP, "square", False), (EXP, "rect", False),
    (ADH, "square", True), (ADH, "rect", False), (dict(interaction="hard_wall"), "square", True),
])
def test_gap_invariant_under_height_shift(law: dict, shape: str, periodic: bool) -> None:
    """``h -> h + c`` leaves ``mean_gap`` and ``gap`` unchanged (the body follows the surface at fixed load).
    Before: the exponential law on square periodic grids reported ``mean_gap - c``."""
    h, length = (H, 1.0) if shape == "square" else (H[:, :24], (1.0, 0.75))
    a = solve(h, sigma0=0.02, length=length, periodic=periodic, tol=1e-10, **law)
    b = solve(h + 3.7, sigma0=0.02, length=length, periodic=periodic, tol=1e-10, **law)
    assert a.converged and b.converged
    assert abs(a.mean_gap - b.mean_gap) <= 1e-9 * 3.7
    np.testing.assert_allclose(b.gap, a.gap, rtol=0, atol=1e-8)
    assert abs(a.mean_gap - float(np.mean(a.gap))) <= 1e-12


def test_batch_gap_invariant_under_height_shift() -> None:
    probs = [BatchProblem(heights=H + c, sigma0=0.02, **EXP) for c in (0.0, -2.5)]
    a, b = solve_batch(probs, tol=1e-10, backend="numpy")
    one = solve(H, sigma0=0.02, tol=1e-10, backend="numpy", **EXP)
    assert abs(a.mean_gap - b.mean_gap) <= 1e-9 and abs(a.mean_gap - one.mean_gap) <= 1e-9


@pytest.mark.validation
@pytest.mark.parametrize("c", [0.0, 0.9])
def test_rectangle_equals_its_square_tiling(c: float) -> None:
    """A 32 x 16 periodic map on (1, 0.5) and its 2x tiling in y, 32 x 32 on (1, 1), are one physical problem:
    equal mean gaps from the generic L-BFGS (rectangle) and the softmax CG (square), also with the tiled copy
    shifted by ``c`` (the convention) and at a tiny load (where the rectangle stalled before)."""
    rect = H[:, :16]
    tiled = np.concatenate([rect, rect], axis=1) + c
    for s0 in (0.02, 1e-8):
        r = solve(rect, sigma0=s0, length=(1.0, 0.5), tol=1e-9, **EXP)
        s = solve(tiled, sigma0=s0, length=1.0, tol=1e-9, **EXP)
        assert r.converged and s.converged, (r.status, r.residual, s.status)
        assert abs(r.mean_gap - s.mean_gap) <= 1e-8 * EXP["rho"], (s0, r.mean_gap, s.mean_gap)


@pytest.mark.parametrize(("shape", "length"), [((64, 48), (1.0, 0.75)), ((63, 37), (63 / 64, 37 / 64))])
def test_tiny_loads_converge_on_rectangular_and_odd_grids(shape: tuple[int, int], length: tuple) -> None:
    """Before: "stalled" at residual 2e-8 (sigma0 = 1e-7) and 5e-6 (1e-9) although the solver's own residual had
    reached 1e-11: the returned displacement was taken as ``z - g0`` and kept the round-off of ``g0 >> u``."""
    h = self_affine(64, 0.8, lambda_l=0.5, lambda_s=4 / 64, seed=2, rms_slope=1.0)[: shape[0], : shape[1]]
    for s0 in (1e-7, 1e-9):
        for law in (dict(gamma0=1e-4, rho=0.02), dict(interaction="adhesive", work=1e-4, rho=0.02)):
            r = solve(h, sigma0=s0, length=length, tol=1e-8, **law)
            assert r.status == "converged" and r.residual <= 1e-8, (s0, law, r.status, r.residual)
            # force balance from the returned fields, independently (numpy FFT, q != 0)
            nx, ny = shape
            qx = 2 * np.pi * np.fft.fftfreq(nx, length[0] / nx)
            qy = 2 * np.pi * np.fft.fftfreq(ny, length[1] / ny)
            q = np.hypot(qx[:, None], qy[None, :])
            f = 0.5 * q * np.fft.fft2(r.displacement) - np.fft.fft2(r.pressure)
            f[0, 0] = 0
            assert np.sqrt(np.sum(np.abs(f) ** 2)) / (nx * ny) <= 1e-7 * max(s0, r.diagnostics["pressure_scale"])
            free = solve(h, sigma0=s0, length=length, tol=1e-8, periodic=False, **law)  # free boundaries too
            assert free.status == "converged" and free.residual <= 1e-8, (s0, law, free.status, free.residual)


@pytest.mark.parametrize(("law", "shape", "periodic"), [
    (dict(interaction="adhesive", work=1e-4), "square", True), (dict(interaction="adhesive", work=1e-4), "rect", True),
    (dict(interaction="adhesive", work=1e-4), "square", False), (dict(gamma0=1e-4), "rect", True),
    (dict(gamma0=1e-4), "rect", False),
])
def test_under_resolved_warns_for_every_law_and_grid(law: dict, shape: str, periodic: bool) -> None:
    """rho/dx = 0.13 (the issue's adhesive case): warned on every grid shape and boundary, once per call."""
    h, length = (H, 1.0) if shape == "square" else (H[:, :24], (1.0, 0.75))
    rho = 0.13 / 32
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        solve(h, sigma0=0.02, length=length, periodic=periodic, rho=rho, tol=1e-4, max_iter=20, **law)
    under = [w for w in caught if issubclass(w.category, UnderResolvedWarning)]
    assert len(under) == 1 and "rho/dx = 0.13" in str(under[0].message)


def test_under_resolved_once_per_load_path_and_none_when_resolved() -> None:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        solve_path(H, [0.02, 0.01, 0.0, -1e-4], interaction="adhesive", work=1e-4, rho=0.5 / 32, tol=1e-6)
        solve(H, sigma0=0.02, interaction="hard_wall")  # no range: nothing to resolve
        solve(H[:, :24], sigma0=0.02, length=(1.0, 0.75), rho=1.5 / 32, **{"gamma0": 1e-4})
    under = [w for w in caught if issubclass(w.category, UnderResolvedWarning)]
    assert len(under) == 1 and "rho/dx = 0.5" in str(under[0].message)
