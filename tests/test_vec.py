"""gapsweep.core.vec (the CPU minimisers' level-1 operations without BLAS threads, docs/gfmd.md "CPU threads"):
rdot and axpy against numpy's vdot and the array expression (1e-14 relative; contiguous, strided, real and complex
arrays), and the numpy minimisers of every law make no call to numpy.vdot or scipy's zaxpy (patched to raise), so
OpenBLAS' spinning threads cannot slow a solve on a loaded machine."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg.blas

from gapsweep import gfmd
from gapsweep.core.vec import axpy, rdot
from gapsweep.surfaces.synthetic import self_affine


@pytest.mark.parametrize("shape", [(7, 5), (64, 33), (300, 151)])
def test_rdot_and_axpy_equal_the_plain_operations(shape):
    rng = np.random.default_rng(1)
    a = rng.standard_normal(shape) + 1j * rng.standard_normal(shape)
    b = rng.standard_normal(shape) + 1j * rng.standard_normal(shape)
    ref = np.vdot(a, b).real
    assert rdot(a, b) == pytest.approx(ref, rel=1e-14, abs=1e-14 * np.abs(a).sum())
    col = np.vdot(a[:, 0], b[:, 0]).real  # a strided view
    assert rdot(a[:, 0], b[:, 0]) == pytest.approx(col, rel=1e-13, abs=1e-14 * np.abs(a[:, 0]).sum())
    x, y = a.real.copy(), b.real.copy()
    assert rdot(x, y) == pytest.approx(float(x.ravel() @ y.ravel()), rel=1e-13, abs=1e-14 * np.abs(x).sum())
    for p, q in ((a, b), (x, y)):
        want = q + 0.37 * p
        got = q.copy()
        axpy(0.37, p, got)
        assert np.allclose(got, want, rtol=1e-15, atol=0)


def _raise(*args, **kwargs):
    raise AssertionError("a BLAS level-1 call in a numpy minimiser")


@pytest.mark.parametrize("periodic", [True, False])
@pytest.mark.parametrize("law", [dict(interaction="exponential", gamma0=1e-3, rho=8e-3),
                                 dict(interaction="adhesive", work=2e-4, rho=8e-3),
                                 dict(interaction="hard_wall")])
def test_minimisers_make_no_blas_level1_call(monkeypatch, law, periodic):
    h = self_affine(64, 0.8, lambda_l=0.25, lambda_s=1 / 16, seed=2)
    h = h if periodic else h[:48, :40]
    ref = gfmd.solve(h, sigma0=1e-2, backend="numpy", periodic=periodic, tol=1e-8, **law)
    monkeypatch.setattr(np, "vdot", _raise)
    monkeypatch.setattr(scipy.linalg.blas, "zaxpy", _raise)
    r = gfmd.solve(h, sigma0=1e-2, backend="numpy", periodic=periodic, tol=1e-8, **law)
    assert r.converged and r.mean_gap == ref.mean_gap and r.iterations == ref.iterations
