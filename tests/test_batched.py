"""Batched GFMD (gapsweep.gfmd.batched, docs/model.md M3) against one-by-one solves on the CPU: the same CG step
for step, so mean gaps and fields agree to round-off and iteration counts are equal; per-problem status; a
finished problem leaves the stack; groups by grid size; bad input. The GPU variant is in tests/gpu."""

from __future__ import annotations

import numpy as np
import pytest

from gapsweep.gfmd import BatchProblem, solve, solve_batch
from gapsweep.surface import self_affine


def _surf(n: int, seed: int) -> np.ndarray:
    return self_affine(n, 0.3, lambda_l=0.25, lambda_s=4.0 / n, seed=seed)


CASES = [(1, 1e-3, 0.02), (2, 1e-2, 0.02), (3, 1e-1, 0.03), (4, 1e-4, 0.02), (5, 1.0, 0.02)]


@pytest.mark.parametrize("generic", ["0", "1"])
def test_batch_matches_one_by_one(generic: str, monkeypatch) -> None:
    # reference: the one-by-one solver with its numba kernels ("0") and with the plain array code ("1")
    monkeypatch.setenv("GAPSWEEP_GENERIC_KERNELS", generic)
    probs = [BatchProblem(heights=_surf(64, s), sigma0=s0, gamma0=1e-3, rho=rho) for s, s0, rho in CASES]
    res = solve_batch(probs, tol=1e-11, backend="numpy")
    iters = set()
    for p, r in zip(probs, res):
        ref = solve(p.heights, sigma0=p.sigma0, gamma0=p.gamma0, rho=p.rho, tol=1e-11, backend="numpy")
        assert r.status == ref.status == "converged" and r.converged
        assert r.iterations == ref.iterations
        iters.add(r.iterations)
        assert abs(r.mean_gap - ref.mean_gap) <= 1e-12 * abs(ref.mean_gap)
        for name in ("gap", "pressure", "displacement"):
            x, y = getattr(ref, name), getattr(r, name)
            assert np.abs(x - y).max() <= 1e-12 * np.abs(x).max(), name
        assert len(r.history) == len(ref.history)
        assert np.allclose(r.history, ref.history, rtol=0, atol=1e-12 * ref.history[0])
        assert (r.sigma0, r.rho, r.gamma0, r.method, r.backend) == (p.sigma0, p.rho, 1e-3, "cg", "numpy")
    assert len(iters) > 1  # the problems finished at different iterations: each left the stack on its own


def test_batch_per_problem_status_and_order() -> None:
    """max_iter stops the slow problems only; grids of two sizes are two groups; results keep the input order."""
    probs = [BatchProblem(heights=_surf(64, 1), sigma0=1e-4, gamma0=1e-3, rho=0.02),
             BatchProblem(heights=_surf(32, 2), sigma0=1e-2, gamma0=1e-3, rho=0.05),
             BatchProblem(heights=_surf(64, 3), sigma0=1.0, gamma0=1e-3, rho=0.02)]
    full = [solve(p.heights, sigma0=p.sigma0, gamma0=p.gamma0, rho=p.rho, tol=1e-10) for p in probs]
    cap = sorted(r.iterations for r in full)[1]  # the middle count: one problem cannot finish
    res = solve_batch(probs, tol=1e-10, max_iter=cap, backend="numpy", max_batch=2)
    for r, f in zip(res, full):
        assert r.n == f.n
        if f.iterations <= cap:
            assert r.status == "converged" and r.iterations == f.iterations
            assert abs(r.mean_gap - f.mean_gap) <= 1e-12 * abs(f.mean_gap)
        else:
            assert r.status == "max_iter" and not r.converged and r.iterations == cap
    assert sum(r.status == "max_iter" for r in res) >= 1


def test_batch_host_fields_and_errors() -> None:
    p = BatchProblem(heights=_surf(32, 1), sigma0=1e-2, gamma0=1e-3, rho=0.05)
    (r,) = solve_batch([p], tol=1e-8, backend="numpy", host=("gap",))
    assert r.converged and isinstance(r.gap, np.ndarray)
    with pytest.raises(ValueError, match="sigma0"):
        solve_batch([p, BatchProblem(heights=_surf(32, 1), sigma0=-1.0, gamma0=1e-3, rho=0.05)])
    with pytest.raises(ValueError, match="square"):
        solve_batch([BatchProblem(heights=np.zeros((4, 5)), sigma0=1e-2, gamma0=1e-3, rho=0.05)])
    with pytest.raises(ValueError, match="NaN"):
        solve_batch([BatchProblem(heights=np.full((8, 8), np.nan), sigma0=1e-2, gamma0=1e-3, rho=0.5)])
    with pytest.raises(ValueError, match="needs rho"):
        solve_batch([BatchProblem(heights=_surf(32, 1), sigma0=1e-2, gamma0=1e-3)])
    with pytest.raises(TypeError, match="Problem"):
        solve_batch([{"heights": _surf(32, 1)}])
    with pytest.raises(ValueError, match="host"):
        solve_batch([p], host=("gaps",))
    with pytest.raises(ValueError, match="max_batch"):
        solve_batch([p], max_batch=0)


def test_batch_warm_start_matches_one_by_one() -> None:
    """``initial`` (a result on the same grid, or a field on a coarser one) as in ``solve``: a pressure chain's
    next step batched across surfaces."""
    hs = [_surf(64, s) for s in (1, 2)]
    first = [solve(h, sigma0=1e-2, gamma0=1e-3, rho=0.02, tol=1e-10) for h in hs]
    coarse = solve(_surf(32, 3), sigma0=1e-2, gamma0=1e-3, rho=0.04, tol=1e-10)
    probs = [BatchProblem(heights=h, sigma0=1.3e-2, gamma0=1e-3, rho=0.02, initial=r) for h, r in zip(hs, first)]
    probs.append(BatchProblem(heights=_surf(64, 3), sigma0=1e-2, gamma0=1e-3, rho=0.04, initial=coarse.displacement))
    res = solve_batch(probs, tol=1e-10, backend="numpy")
    for p, r in zip(probs, res):
        ref = solve(p.heights, sigma0=p.sigma0, gamma0=1e-3, rho=p.rho, tol=1e-10, initial=p.initial)
        cold = solve(p.heights, sigma0=p.sigma0, gamma0=1e-3, rho=p.rho, tol=1e-10)
        assert r.converged and r.iterations == ref.iterations
        assert abs(r.mean_gap - ref.mean_gap) <= 1e-12 * abs(ref.mean_gap)
        assert ref.iterations != cold.iterations or ref.history[0] != cold.history[0]  # the start was used
    with pytest.raises(ValueError, match=r"problems\[0\].initial"):
        solve_batch([BatchProblem(heights=hs[0], sigma0=1e-2, gamma0=1e-3, rho=0.02, initial=np.zeros((4, 5)))])
