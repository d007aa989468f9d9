"""A job whose GFMD tasks span 2 GPUs (``[methods.gfmd] distributed = true``, ``backend = "cupy"``, one rank per
GPU) keeping fields: each rank makes its rows of the surface on its GPU (``self_affine_rows``, backend cupy) and
writes its rows of the fields (rank-0 writer: the GPU machines' h5py is serial). The store and the fields equal
those of the same job in one process on one GPU: mean gap and contact area to 1e-9 (relative / absolute), h_rms
and g_rms to 1e-12 relative, the height to 1e-13 of its largest value (cuFFT's 1-D transforms against its 2-D
plan: FFT round-off), the gap, pressure and displacement to 1e-9 of the largest gap or pressure. Skipped without
mpiexec, mpi4py or 2 GPUs."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.gpu.cuda_skip import cupy_or_skip

pytestmark = [pytest.mark.gpu, pytest.mark.skipif(shutil.which("mpiexec") is None, reason="mpiexec not installed")]
ROOT = Path(__file__).resolve().parents[2]

JOB = """
[job]
name = "dist-gpu-fields"
[grid]
hurst = [0.8]
rho = [2e-3]
sigma0 = [1e-2, 1e-1]
seeds = [0]
[surface]
lambda_l = 0.25
lambda_s = 0.0078125
rms_slope = 1.0
[material]
gamma0 = 1e-3
[histogram]
bins = 16
[methods.gfmd]
n = 1024
tol = 1e-10
backend = "cupy"
keep_fields = {fields = ["gap", "pressure", "displacement", "height"]}
"""


def test_distributed_gpu_job_keeps_fields(tmp_path):
    cupy = cupy_or_skip()
    pytest.importorskip("mpi4py")
    pytest.importorskip("xarray", reason="reading kept fields needs the xarray extra")
    pytest.importorskip("h5netcdf", reason="reading kept fields needs the xarray extra (h5netcdf)")
    if cupy.cuda.runtime.getDeviceCount() < 2:
        pytest.skip("needs 2 GPUs")
    from gapsweep import runner, store

    (tmp_path / "one.toml").write_text(JOB)
    (tmp_path / "dist.toml").write_text(JOB.replace('backend = "cupy"\n', 'backend = "cupy"\ndistributed = true\n'))
    runner.run(tmp_path / "one.toml", tmp_path / "one.h5", progress="none", mpi="off")
    env = dict(os.environ, OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1", GAPSWEEP_WRITER="rank0")
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), env.get("PYTHONPATH", "")])
    p = subprocess.run(["mpiexec", "-n", "2", sys.executable, "-m", "gapsweep", "run", str(tmp_path / "dist.toml"),
                        "--store", str(tmp_path / "dist.h5"), "--progress", "log"], env=env, capture_output=True,
                       text=True, timeout=600)
    assert p.returncode == 0, p.stdout + p.stderr
    a, b = (store.read(tmp_path / f"{x}.h5").sort_values("sigma0").reset_index(drop=True) for x in ("one", "dist"))
    assert set(a.status) == set(b.status) == {"done"}
    assert np.all(np.abs(b.mean_gap - a.mean_gap) <= 1e-9 * np.abs(a.mean_gap))
    assert np.all(np.abs(b.contact_area - a.contact_area) <= 1e-9)
    for c in ("h_rms", "g_rms"):
        assert np.all(np.abs(b[c] - a[c]) <= 1e-12 * np.abs(a[c])), c
    fa = {float(d.attrs["sigma0"]): d for d in store.open_fields(tmp_path / "one.h5").values()}
    fb = {float(d.attrs["sigma0"]): d for d in store.open_fields(tmp_path / "dist.h5").values()}
    assert sorted(fa) == sorted(fb) and len(fa) == 2
    for s0, x in fa.items():
        y = fb[s0]
        h = np.abs(x.height.values).max()
        assert np.abs(y.height.values - x.height.values).max() <= 1e-13 * h
        g, pr = np.abs(x.gap.values).max(), np.abs(x.pressure.values).max()
        for v, scale in (("gap", g), ("displacement", g), ("pressure", pr)):
            assert np.abs(y[v].values - x[v].values).max() <= 1e-9 * scale, (s0, v)
