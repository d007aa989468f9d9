"""The hard wall's GPU memory plan (``gapsweep.gfmd._cuda.solve_memory``, method "pcg") against the peak of the same
code traced on the CPU: the GPU's loop (``_constrained._RealSpace``) run on numpy through a stand-in of the cuFFT
backend's buffers (``gapsweep.core.fft._CupyBackend``: one C2R input buffer, the product formed in it, C2R into the
caller's array), numpy's transient transform outputs in the role of cuFFT's two work areas. tracemalloc counts every
numpy allocation; the caller's surface is made before tracing starts (as ``heights_on_gpu=False`` leaves it out)."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from gapsweep.core.fft import FFTBackend
from gapsweep.gfmd import _constrained, _grid, solve
from gapsweep.gfmd._cuda import solve_memory
from gapsweep.surfaces import self_affine


class _PlannedNumpy(FFTBackend):
    """numpy with the buffers of gapsweep.core.fft._CupyBackend.convolve (the only transform the GPU's hard-wall
    loop calls): R2C into the one C2R input buffer, the multiplier applied in place, C2R into ``out``."""

    def __init__(self, n: int) -> None:
        super().__init__(n)
        self._cin = np.empty((n, n // 2 + 1), dtype=np.complex128)

    def convolve(self, a, mult, out=None):
        self._cin[...] = np.fft.rfft2(a)  # numpy's transient output: the R2C plan's work area
        self._cin *= mult
        res = np.empty((self.n, self.n)) if out is None else out
        res[...] = np.fft.irfft2(self._cin, s=(self.n, self.n), norm="forward")  # likewise the C2R plan's
        return res


@pytest.mark.parametrize("sigma0", [1e-2, 1e-1])
def test_hard_wall_gpu_memory_plan_matches_traced_peak(monkeypatch, sigma0: float) -> None:
    """Traced peak within 0.25 grid arrays of solve_memory's count without its fragmentation margin (the plan
    before issue 30 traced 13.5 arrays here against 12.5 now), and the solve the same as the CPU's own loop."""
    n = 256
    h = self_affine(n, 0.3, lambda_l=0.25, lambda_s=8 / n, rms_slope=1.0, seed=1)
    kw = dict(sigma0=sigma0, interaction="hard_wall", method="pcg", tol=1e-8, backend="numpy", host=False)
    ref = solve(h, **kw)  # the CPU's spectral loop
    monkeypatch.setattr(_constrained, "_SPECTRAL", False)  # the GPU's loop
    monkeypatch.setattr(_grid, "get_backend", lambda name, size, threads=None: _PlannedNumpy(size))
    solve(h, **kw)  # warm-up (caches)
    tracemalloc.start()
    try:
        r = solve(h, **kw)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert r.converged and r.status == "converged"
    assert r.mean_gap == pytest.approx(ref.mean_gap, rel=1e-6)
    assert r.elastic_energy == pytest.approx(ref.elastic_energy, rel=1e-6)  # <p u>/2 against Parseval
    est = solve_memory(n, interaction="hard_wall", heights_on_gpu=False)
    margin = est["parts"]["margin (memory pool fragmentation)"]
    # whole solves on a GPU hold one half-size real array that this CPU stand-in does not (the memory pool measured
    # it on an H200: benchmarks/results/gfmd/mem_gpu_one.json; solve_memory counts it since issue 39)
    gpu_only = 8 * n * (n // 2 + 1)
    arrays = (est["bytes"] - margin - gpu_only) / (8 * n * n)
    assert abs(peak / (8 * n * n) - arrays) <= 0.25, (peak / (8 * n * n), arrays)
    assert est["arrays"] <= 15.0 and solve_memory(32768, interaction="hard_wall")["bytes"] < 139 * 2**30
