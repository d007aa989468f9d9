"""The one L-BFGS two-loop recursion (gapsweep/gfmd/_lbfgs.py) against the explicit inverse-Hessian update it
stands for (Nocedal & Wright eq. 7.19: ``H <- V^T H V + rho s s^T``, ``V = 1 - rho y s^T``, from ``H0 = gamma P``),
as dense matrices, on random pairs of a random SPD quadratic; and the pair memory's curvature test. In-process."""

from __future__ import annotations

import numpy as np
import pytest

from gapsweep.gfmd._lbfgs import diagonal, remember_pair, two_loop


def _explicit(q: np.ndarray, pairs: list, P: np.ndarray) -> np.ndarray:
    n = q.size
    s, y, r = pairs[-1]
    H = (1.0 / (r * float(y @ P @ y))) * P  # gamma = s.y / <y P y>
    for s, y, r in pairs:
        V = np.eye(n) - r * np.outer(y, s)
        H = V.T @ H @ V + r * np.outer(s, s)
    return H @ q


@pytest.mark.parametrize(("n", "m", "seed"), [(6, 1, 0), (9, 3, 1), (12, 5, 2)])
def test_two_loop_equals_the_explicit_bfgs_matrix(n: int, m: int, seed: int) -> None:
    """``two_loop`` with a diagonal preconditioner (in-place operations, :func:`diagonal`) equals ``H q`` of the
    dense recursion to 1e-10 relative; with new-array operations (the projected minimiser's style) too."""
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((n, n))
    A = A @ A.T + n * np.eye(n)  # the Hessian of a convex quadratic
    pdiag = 1.0 / np.diag(A)
    pairs = []
    for _ in range(m):
        s = rng.standard_normal(n)
        y = A @ s  # exact curvature pairs: s.y > 0
        pairs.append((s, y, 1.0 / float(s @ y)))
    q = rng.standard_normal(n)
    want = _explicit(q, pairs, np.diag(pdiag))
    got = two_loop(q.copy(), pairs, **diagonal(lambda a, b: float(a @ b), pdiag))
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12 * np.abs(want).max())
    got2 = two_loop(q.copy(), pairs, dot=lambda a, b: float(a @ b), axpy=lambda v, a, x: v + a * x,
                    precondition=lambda v: pdiag * v, curvature=lambda y: float(y @ (pdiag * y)),
                    scale=lambda v, c: v * c)
    np.testing.assert_allclose(got2, want, rtol=1e-10, atol=1e-12 * np.abs(want).max())
    assert np.allclose(two_loop(q.copy(), [], **diagonal(lambda a, b: float(a @ b), pdiag)), pdiag * q)


def test_remember_pair_keeps_curvature_pairs_and_drops_the_oldest() -> None:
    s_h, y_h, r_h = [], [], []
    remember_pair(s_h, y_h, r_h, "s0", "y0", -1.0, 2)  # s.y <= 0: not kept
    assert s_h == []
    for i in range(3):
        remember_pair(s_h, y_h, r_h, f"s{i}", f"y{i}", 2.0 + i, 2)
    assert s_h == ["s1", "s2"] and y_h == ["y1", "y2"] and r_h == [1 / 3.0, 1 / 4.0]
