"""The slab transform (gapsweep.core.slab.SlabFFT) on one GPU, one rank (MPI.COMM_SELF): the forward transform
against cupy.fft.rfft2 (transposed layout ``[ky, kx]``) and the round trip, on odd, even and rectangular grids,
with the tiled transpose kernel and with cupy's strided copy (the kernel's reference), and in chunks smaller than
the grid. Tolerance: 1e-12 of the largest coefficient (both are cuFFT; only the order of the sums differs).
Several ranks on several GPUs: benchmarks/bench_distributed.py's quick checks."""

from __future__ import annotations

import pytest

from gapsweep.core import slab
from tests.gpu.cuda_skip import cupy_or_skip as _cupy

pytestmark = pytest.mark.gpu


@pytest.mark.parametrize("shape", [(64, 64), (37, 50), (96, 161), (1024, 512)])
@pytest.mark.parametrize("tiled", [True, False])
@pytest.mark.parametrize("chunk", [None, 700])
def test_slab_transform_on_gpu(shape, tiled, chunk, monkeypatch):
    cupy = _cupy()
    mpi = pytest.importorskip("mpi4py.MPI")
    monkeypatch.setattr(slab, "TILED_TRANSPOSE", tiled)
    f = slab.SlabFFT(shape, mpi.COMM_SELF, backend="cupy", chunk=chunk)
    a = cupy.random.default_rng(3).standard_normal(shape)
    A = f.rfft2(a)
    ref = cupy.fft.rfft2(a).T
    scale = float(cupy.abs(ref).max())
    assert float(cupy.abs(A - ref).max()) <= 1e-12 * scale
    back = f.irfft2(A) / a.size
    assert float(cupy.abs(back - a).max()) <= 1e-12 * float(cupy.abs(a).max())
    out = cupy.empty(f.real_shape)
    assert f.irfft2(A, out=out) is out and float(cupy.abs(out / a.size - a).max()) <= 1e-12
