"""The distributed solve's lean smooth minimiser (gfmd._lean) on one GPU, one rank (MPI.COMM_SELF): adhesion at
a compressive and a tensile load against the same solve on the CPU (numpy, the same rank count) and against the
single-GPU solve; memory: cupy's pool high-water mark within gfmd.distributed.solve_memory's estimate.
Tolerances: the CPU run of the same iteration to 1e-9 (mean gap relative, contact area), the single-GPU solve
(8 pairs, another iteration) to 1e-9 at tol 1e-11. GPU tests carry the marker ``gpu`` and skip without a GPU,
cupy or mpi4py."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from gapsweep import gfmd
from gapsweep.core import slab
from gapsweep.gfmd import _lean, distributed
from gapsweep.surface import self_affine
from tests.gpu.cuda_skip import cupy_or_skip as _cupy

pytestmark = pytest.mark.gpu




@pytest.mark.parametrize("sigma0", [1e-3, -1e-4])
def test_lean_adhesion_on_gpu(sigma0, monkeypatch):
    cupy = _cupy()
    mpi = pytest.importorskip("mpi4py.MPI")
    comm = mpi.COMM_SELF
    n = 256
    # chunks of 4 rows, as the passes' temporaries are small against the grid at large n (the estimate's case)
    monkeypatch.setattr(slab, "DEFAULT_CHUNK", 4 * n)
    monkeypatch.setitem(_lean.CHUNK, "cupy", 4 * n)
    h = self_affine(n, 0.8, lambda_l=0.25, lambda_s=4.0 / n, rms_slope=1.0, seed=3)
    kw = dict(sigma0=sigma0, interaction="adhesive", work=2e-4, rho=1e-2, tol=1e-11)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cpu = distributed.solve(h, comm=comm, **kw)
        pool = cupy.get_default_memory_pool()
        pool.free_all_blocks()
        hg = cupy.asarray(h)
        gpu = distributed.solve(hg, comm=comm, host=False, **kw)
        peak = pool.total_bytes()
        single = gfmd.solve(hg, **kw)
    assert cpu.status == gpu.status == single.status == "converged"
    assert abs(gpu.mean_gap - cpu.mean_gap) <= 1e-9 * abs(cpu.mean_gap)
    assert abs(gpu.contact_area - cpu.contact_area) <= 1e-9 and 0 < cpu.contact_area < 1
    assert abs(gpu.mean_gap - single.mean_gap) <= 1e-9 * abs(single.mean_gap)
    assert abs(gpu.contact_area - single.contact_area) <= 1e-9
    est = distributed.solve_memory((n, n), 1, "adhesive", tensile=sigma0 < 0)
    # + cuFFT plans and the pool's cached blocks: 109-111 MiB at n = 256 on an H200 (2026-11-26), whatever the grid
    assert peak <= est["bytes_per_rank"] + 128 * 2**20, (peak / est["array_bytes"], est)
    assert np.isfinite(float(gpu.elastic_energy))
