"""GPU solver at the limit (issue 22, items 3 and 5): the lean GPU branch of the exponential-law solver
(gfmd/_softmax.py::_solve_lean, fused set-up/result kernels, one gradient array in CG) against the numpy solver,
GPU surfaces against numpy surfaces, and the memory estimate against cupy's measured pool high-water mark.

GPU tests carry the marker ``gpu`` and skip without an NVIDIA GPU (``bash scripts/test_gpu.sh`` runs them); the
argument checks run everywhere."""

from __future__ import annotations

import numpy as np
import pytest

from gapsweep.gfmd._cuda import solve_memory
from gapsweep.surface import self_affine
from tests.gpu.cuda_skip import cupy_or_skip as _cupy


def _surface(n: int, seed: int, hurst: float = 0.3) -> np.ndarray:
    return self_affine(n, hurst, lambda_l=0.25, lambda_s=4.0 / n, seed=seed)


# ------------------------------------------------------------------------------------------- everywhere
def test_solve_memory_arguments() -> None:
    with pytest.raises(ValueError, match="n must be an integer >= 2"):
        solve_memory(1)
    with pytest.raises(ValueError, match="method must be one of"):
        solve_memory(64, method="newton")
    with pytest.raises(ValueError, match="interaction must be one of"):
        solve_memory(64, interaction="adhesive")
    with pytest.raises(ValueError, match="method must be one of 'auto', 'pcg' for interaction 'hard_wall'"):
        solve_memory(64, interaction="hard_wall", method="pk")
    assert solve_memory(64, method="auto") == solve_memory(64, method="cg")
    m = solve_memory(1024)
    assert m["bytes"] == sum(m["parts"].values())
    # the caller's surface is one real n x n array more
    assert m["bytes"] - solve_memory(1024, heights_on_gpu=False)["bytes"] == 8 * 1024 * 1024


def test_surface_backend_argument() -> None:
    with pytest.raises(ValueError, match="backend must be 'numpy' or 'cupy'"):
        self_affine(64, 0.3, lambda_l=0.25, lambda_s=0.1, backend="torch")


# ------------------------------------------------------------------------------------------------- GPU
@pytest.mark.gpu
@pytest.mark.parametrize("n, hurst, seed, amps", [(256, 0.3, 3, "fixed"), (1025, 0.8, 11, "gaussian")])
def test_surface_on_gpu_equals_numpy(n: int, hurst: float, seed: int, amps: str) -> None:
    """Same modes, same coefficients: only the inverse FFT (cuFFT vs pocketfft) rounds differently."""
    cupy = _cupy()
    kw = dict(lambda_l=0.25, lambda_s=5.0 / n, rms_slope=1.0, seed=seed, amplitudes=amps)
    g = self_affine(n, hurst, backend="cupy", **kw)
    assert isinstance(g, cupy.ndarray) and g.shape == (n, n) and g.dtype == cupy.float64
    c = self_affine(n, hurst, **kw)
    assert np.abs(cupy.asnumpy(g) - c).max() <= 1e-13 * np.abs(c).max()


@pytest.mark.gpu
@pytest.mark.parametrize("method, n, sigma0", [("cg", 128, 1e-3), ("cg", 127, 1e-1), ("lbfgs", 128, 1e-2),
                                               ("fire", 96, 1e-2)])
def test_lean_gpu_solver_matches_numpy(method: str, n: int, sigma0: float) -> None:
    """Every result of the GPU branch against the numpy solver at tol 1e-11 (FIRE 1e-10; odd n too: the Parseval
    weights): mean gap to 10 tol, fields and elastic energy to 1e-10, contact area to one grid point."""
    cupy = _cupy()
    from gapsweep.gfmd import solve

    h = _surface(n, 5) + 0.37  # a non-zero mean: the GPU centres inside the W pass, never copying h
    tol = 1e-10 if method == "fire" else 1e-11  # FIRE converges linearly
    kw = dict(sigma0=sigma0, gamma0=1e-3, rho=0.01, tol=tol, method=method, max_iter=20000)
    a = solve(h, backend="numpy", **kw)
    b = solve(cupy.asarray(h), **kw)
    assert a.converged and b.converged and b.backend == "cupy", (a.status, b.status)
    assert abs(a.mean_gap - b.mean_gap) <= 10 * tol * abs(a.mean_gap)
    for name in ("gap", "pressure", "displacement"):
        x, y = getattr(a, name), getattr(b, name)
        assert np.abs(x - y).max() <= 1e-10 * np.abs(x).max(), name
    assert abs(a.elastic_energy - b.elastic_energy) <= 1e-10 * a.elastic_energy
    assert abs(a.contact_area - b.contact_area) <= 2.0 / n**2  # a point exactly at gap = rho may flip
    assert b.residual <= tol and b.load_error <= tol
    if method == "cg":  # one gradient array: the same Polak-Ribiere directions, hence (nearly) the same count
        assert abs(a.iterations - b.iterations) <= 1, (a.iterations, b.iterations)


@pytest.mark.gpu
def test_lean_gpu_warm_start_and_status() -> None:
    """A warm start from a coarser result, and a non-finite surface reported as an error naming heights."""
    cupy = _cupy()
    from gapsweep.gfmd import solve

    h = _surface(128, 2)
    kw = dict(sigma0=1e-2, gamma0=1e-3, rho=0.01, tol=1e-11)
    coarse = solve(h[::2, ::2], backend="numpy", **kw)
    a = solve(h, backend="numpy", initial=coarse, **kw)
    b = solve(cupy.asarray(h), initial=coarse, **kw)
    assert a.converged and b.converged
    assert abs(a.mean_gap - b.mean_gap) <= 1e-11 * abs(a.mean_gap)
    bad = cupy.asarray(h)
    bad[3, 4] = np.nan
    with pytest.raises(ValueError, match="heights contain NaN"):
        solve(bad, **kw)


@pytest.mark.gpu
def test_solve_memory_against_measured_pool() -> None:
    """The estimate (cuFFT work areas calibrated on n = 2048 ... 8192) against cupy's pool high-water mark at
    n = 1536, a size no other test uses (plans and caches are made fresh)."""
    cupy = _cupy()
    from gapsweep.gfmd import solve

    n = 1536
    h = cupy.asarray(_surface(n, 4))
    pool = cupy.get_default_memory_pool()
    for law, kw in (("exponential", dict(gamma0=1e-3, rho=0.01, tol=1e-6)),
                    ("hard_wall", dict(interaction="hard_wall", tol=1e-8))):
        from gapsweep.core import fft

        fft._PLANS.clear()  # plans (and their buffers) made fresh inside the solve
        pool.free_all_blocks()
        base = pool.total_bytes()
        r = solve(h, sigma0=1e-2, host=False, **kw)
        assert r.converged
        used = pool.total_bytes() - base
        del r
        est = solve_memory(n, interaction=law, heights_on_gpu=False)["bytes"]
        assert 0.8 * used <= est <= 1.25 * used, (law, est / 1e6, used / 1e6)


@pytest.mark.gpu
@pytest.mark.parametrize("sigma0", [1e-4, 1e-2, 1.0])
def test_chained_cg_equals_synchronous_cg(sigma0: float, monkeypatch) -> None:
    """The chained CG (one synchronisation per iteration, the first trial's step computed on the device with the
    host's rounding) takes the same steps as the synchronous GPU CG: same evaluation count and history, mean gap
    to 1e-14."""
    cupy = _cupy()
    from gapsweep.gfmd import _cuda, solve

    h = cupy.asarray(_surface(256, 9, hurst=0.8))
    kw = dict(sigma0=sigma0, gamma0=1e-3, rho=0.005, tol=1e-10, host=False)
    a = solve(h, **kw)
    monkeypatch.delattr(_cuda._CupyOps, "chain_read")  # _run_cg falls back to the synchronous loop
    b = solve(h, **kw)
    assert a.converged and b.converged
    assert a.iterations == b.iterations
    np.testing.assert_allclose(a.history, b.history, rtol=1e-9, atol=0)
    assert abs(a.mean_gap - b.mean_gap) <= 1e-14 * abs(a.mean_gap)


@pytest.mark.gpu
@pytest.mark.parametrize("method, shape", [("pcg", (256, 256)), ("pk", (128, 64)), ("mpcg", (256, 256))])
def test_hard_wall_fused_gpu_passes_match_generic(method: str, shape: tuple, monkeypatch) -> None:
    """The fused CUDA passes of the hard wall (gfmd/_cuda.py::_PKCupy) against the generic cupy passes
    (``GAPSWEEP_GENERIC_KERNELS=1``) and the numpy solver: same iterations (+-1: summation order), mean gap to
    1e-9, same contact area."""
    cupy = _cupy()
    from gapsweep.gfmd import solve

    h = self_affine(shape[0], 0.8, lambda_l=0.25, lambda_s=4 / shape[1], seed=6)[:, : shape[1]]
    length = (1.0, shape[1] / shape[0])
    kw = dict(sigma0=2e-2, interaction="hard_wall", tol=1e-10, method=method, length=length)
    a = solve(cupy.asarray(h), **kw)
    monkeypatch.setenv("GAPSWEEP_GENERIC_KERNELS", "1")
    b = solve(cupy.asarray(h), **kw)
    c = solve(h, backend="numpy", **kw)
    assert a.converged and b.converged and c.converged
    assert abs(a.iterations - b.iterations) <= 1, (a.iterations, b.iterations)
    assert abs(a.mean_gap - b.mean_gap) <= 1e-9 * abs(b.mean_gap)
    assert abs(a.mean_gap - c.mean_gap) <= 1e-9 * abs(c.mean_gap)
    assert a.contact_area == b.contact_area == c.contact_area
