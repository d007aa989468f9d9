"""Free boundaries on the GPU (``gfmd.solve(cupy_array, ..., periodic=False)``) against the CPU (marker ``gpu``;
skips without cupy and a GPU): the same discrete problem, so the same answer to the solver tolerance."""

from __future__ import annotations

import numpy as np
import pytest

from gapsweep.gfmd import solve
from gapsweep.surface import self_affine

pytestmark = pytest.mark.gpu
cp = pytest.importorskip("cupy")
try:
    cp.cuda.runtime.getDeviceCount()
except Exception:  # any CUDA failure means: no usable GPU here
    pytest.skip("no usable CUDA device", allow_module_level=True)

CASES = [("hard_wall", {}, 0.05, "pcg"), ("hard_wall", {}, 0.05, "mpcg"),
         ("exponential", dict(gamma0=1e-4, rho=2e-3), 0.01, "auto"), ("adhesive", dict(work=1e-4, rho=2e-3), 0.01,
                                                                         "auto")]


@pytest.mark.parametrize(("law", "kw", "sigma0", "method"), CASES)
def test_free_gpu_matches_cpu(law, kw, sigma0, method) -> None:
    """Rectangular map (Lx != Ly), tol 1e-10: mean gap to 1e-8 relative, contact pixels identical (hard wall),
    pressures to 1e-6 sigma0."""
    h = self_affine(512, 0.8, lambda_l=0.5, lambda_s=8 / 512, seed=5)[:256, 40:232]
    h = h / h.std() * 0.01
    common = dict(sigma0=sigma0, interaction=law, length=(1.0, 0.75), tol=1e-10, periodic=False, method=method, **kw)
    cpu = solve(h, backend="numpy", **common)
    gpu = solve(cp.asarray(h), **common)
    assert cpu.converged and gpu.converged and gpu.backend == "cupy" and not gpu.periodic
    assert gpu.mean_gap == pytest.approx(cpu.mean_gap, rel=1e-8)
    if law == "hard_wall":
        np.testing.assert_array_equal(gpu.pressure > 0, cpu.pressure > 0)
    np.testing.assert_allclose(gpu.pressure, cpu.pressure, rtol=0, atol=1e-6 * sigma0)
