"""The CUDA paths against their CPU counterparts (marker ``gpu``; every test skips without an NVIDIA GPU, so CI
without one stays green). Run on a GPU machine with ``bash scripts/test_gpu.sh`` (= ``pytest -m gpu tests/gpu``).

* SDE on CUDA (both engines: the cupy kernels of gapsweep/gapdist/_sde_cuda.py and the warp kernels) vs the warp kernel
  on the CPU (docs/model.md M5): same seed and realisations, so the same Philox normals. float64 must agree per
  realisation to 1e-9 of the spread (only libm rounding differs); float32 (fast math on the GPU) per
  realisation to 5e-3 of the spread and in distribution (two-sample KS); the device histogram against binning
  the CPU samples; the two CUDA engines against each other.
* cupy GFMD vs numpy GFMD (docs/model.md M3) on the same surface, tol 1e-12: mean gap and fields to 1e-12.
* the batched solver on the GPU vs one-by-one CPU solves: mean gaps and fields to 1e-12, same iteration counts.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.gpu.cuda_skip import cupy_or_skip as _cupy

pytestmark = pytest.mark.gpu

# docs/model.md M6 parameters (g_rms = 1 at H = 0.3), as in tests/test_sde.py
P = dict(hurst=0.3, h_rms=2.34e-3, gamma0=1e-3, lambda_l=0.25, lambda_s=2.5e-3)




def _warp_cuda():
    try:
        import warp as wp

        wp.config.log_level = 30
        wp.init()
        if not wp.is_cuda_available():
            raise RuntimeError("warp sees no CUDA device")
    except Exception as exc:
        pytest.skip(f"no CUDA GPU for warp ({type(exc).__name__}: {exc})")
    return wp


def _surface(n: int, seed: int) -> np.ndarray:
    from gapsweep.surface import self_affine

    return self_affine(n, 0.3, lambda_l=0.25, lambda_s=4.0 / n, seed=seed)


# ------------------------------------------------------------------------------------------------------ SDE
ENGINES = ["cupy", "warp"]  # gapsweep._sde_cuda (default on CUDA when cupy is there) and the warp kernels


def _engine(monkeypatch, engine: str) -> None:
    if engine == "cupy":
        _cupy()
    monkeypatch.setenv("GAPSWEEP_SDE_ENGINE", "auto" if engine == "cupy" else "warp")


@pytest.mark.parametrize("engine", ENGINES)
@pytest.mark.parametrize("case", ["fig6", "stiff"])
def test_sde_cuda_float64_matches_cpu_per_realisation(case: str, engine: str, monkeypatch) -> None:
    _warp_cuda()
    _engine(monkeypatch, engine)
    from gapsweep import sde

    kw = dict(P, rho=2e-3, c2=0.5) if case == "fig6" else dict(P, rho=5e-4, c2=1.0)
    s0 = 1e-4 if case == "fig6" else 1e-2
    common = dict(n=4096, seed=12345, first=10**6, dzeta=0.05, dtype="float64", **kw)
    cpu = sde.gap_samples(s0, device="cpu", **common)
    gpu = sde.gap_samples(s0, device="cuda:0", **common)
    err = np.abs(gpu - cpu).max() / cpu.std()
    assert err <= 1e-9, f"float64 CUDA ({engine}) vs CPU: max |diff| = {err:.3g} of the spread"


@pytest.mark.parametrize("engine", ENGINES)
def test_sde_cuda_float32_matches_cpu(engine: str, monkeypatch) -> None:
    _warp_cuda()
    _engine(monkeypatch, engine)
    from scipy import stats

    from gapsweep import sde
    from gapsweep.gapdist import _sde_kernels

    common = dict(P, rho=2e-3, c2=0.5, n=20_000, seed=7, dzeta=0.01, dtype="float32")
    ref = sde.gap_samples(1e-4, device="cpu", **common)
    variants = ("poly", "div") if engine == "warp" else ("poly",)  # the warp default and its exact log1p
    for variant in variants:
        monkeypatch.setattr(_sde_kernels, "VARIANT", variant)
        gpu = sde.gap_samples(1e-4, device="cuda:0", **common)
        # fast-math intrinsics on the GPU, libm on the CPU: a few 1e-3 of the spread after 9,900 steps
        err = np.abs(gpu - ref).max() / ref.std()
        assert err <= 5e-3, f"{engine}/{variant}: float32 CUDA vs CPU max |diff| = {err:.3g} of the spread"
        # a systematic fast-math shift would show in the mean: seen < 1e-4 (cupy) and 9e-4 (warp) of the spread on
        # an H200, against a Monte Carlo error of the mean of 7e-3 of the spread at this n
        assert abs(gpu.mean() - ref.mean()) <= 2e-3 * ref.std()
        assert stats.ks_2samp(gpu, ref).pvalue > 1e-3
    # the histogram path bins on the device: the counts of binning the CPU samples (up to edge round-off)
    h = sde.gap_histogram_counts(1e-4, bins=50, device="cuda:0", **common)
    c_cpu, _ = np.histogram(ref, bins=h.edges)
    assert h.nonfinite == 0 and h.counts.sum() + h.below + h.above == common["n"]
    assert np.abs(h.counts - c_cpu).sum() <= 20, np.abs(h.counts - c_cpu).sum()
    # non-uniform edges take the binary search
    edges = np.r_[h.edges[:10], h.edges[10::3]]
    h2 = sde.gap_histogram_counts(1e-4, bins=edges, device="cuda:0", **common)
    c2, _ = np.histogram(ref, bins=edges)
    assert np.abs(h2.counts - c2).sum() <= 20


def test_sde_engines_agree(monkeypatch) -> None:
    """The CUDA engine and the warp kernels on CUDA draw the same normals: 10^6 realisations in float32 give the
    same histogram up to a few fast-math round-off bin flips; float64 samples agree to round-off."""
    _warp_cuda()
    _cupy()
    from gapsweep import sde

    kw = dict(P, rho=2e-3, c2=0.5, n=10**6, seed=99, dzeta=0.01, device="cuda:0", bins=200)
    out = {}
    for engine in ENGINES:
        monkeypatch.setenv("GAPSWEEP_SDE_ENGINE", "auto" if engine == "cupy" else "warp")
        out[engine] = sde.gap_histogram_counts(1e-4, **kw)
        kw64 = {k: v for k, v in kw.items() if k != "bins"} | {"n": 5000, "dtype": "float64"}
        out[engine + "64"] = sde.gap_samples(1e-4, **kw64)
    a, b = out["cupy"], out["warp"]
    np.testing.assert_array_equal(a.edges, b.edges)
    assert np.abs(a.counts - b.counts).sum() <= 10, np.abs(a.counts - b.counts).sum()
    x, y = out["cupy64"], out["warp64"]
    assert np.abs(x - y).max() <= 1e-12 * x.std()


# ----------------------------------------------------------------------------------------------------- GFMD
@pytest.mark.parametrize("sigma0", [1e-3, 1e-1])
def test_cupy_gfmd_matches_numpy(sigma0: float) -> None:
    cupy = _cupy()
    from gapsweep.gfmd import solve

    h = _surface(128, 5)
    kw = dict(sigma0=sigma0, gamma0=1e-3, rho=0.01, tol=1e-12)
    a = solve(h, backend="numpy", **kw)
    b = solve(cupy.asarray(h), **kw)
    assert a.converged and b.converged and b.backend == "cupy"
    assert isinstance(b.gap, np.ndarray) and isinstance(b.pressure, np.ndarray)
    rel = abs(a.mean_gap - b.mean_gap) / abs(a.mean_gap)
    assert rel <= 1e-12, f"mean gap: {rel:.3g}"
    for name in ("gap", "pressure", "displacement"):
        x, y = getattr(a, name), getattr(b, name)
        err = np.abs(x - y).max() / np.abs(x).max()
        assert err <= 1e-12, f"{name}: {err:.3g}"


@pytest.mark.parametrize(("interaction", "periodic"), [("exponential", True), ("hard_wall", True),
                                                     ("hard_wall", False)])
def test_gfmd_on_two_devices_one_process(interaction: str, periodic: bool) -> None:
    """issue 36: a solve on device 1 after one on device 0 in the same process (plan caches keyed by device;
    before, cuFFT plans of device 0 ran on device 1: CUFFT_EXEC_FAILED). Both equal the numpy solve to 1e-10.
    Skips with fewer than two GPUs."""
    cupy = _cupy()
    if cupy.cuda.runtime.getDeviceCount() < 2:
        pytest.skip("needs two CUDA devices")
    from gapsweep.gfmd import solve

    h = _surface(64, 7)
    kw = dict(sigma0=1e-2, interaction=interaction, tol=1e-11, periodic=periodic)
    if interaction == "exponential":
        kw.update(gamma0=1e-3, rho=0.01)
    ref = solve(h, backend="numpy", **kw)
    for dev in (0, 1, 0):
        with cupy.cuda.Device(dev):
            r = solve(cupy.asarray(h), **kw)
            cupy.cuda.Device().synchronize()
        assert r.converged and r.backend == "cupy", (dev, r.status)
        assert abs(r.mean_gap - ref.mean_gap) <= 1e-10 * abs(ref.mean_gap), dev


def test_cupy_gfmd_host_fields() -> None:
    """``host`` names the fields copied to the host; the others stay on the GPU, with the same values."""
    cupy = _cupy()
    from gapsweep.gfmd import solve

    h = cupy.asarray(_surface(64, 2))
    kw = dict(sigma0=1e-2, gamma0=1e-3, rho=0.02, tol=1e-10)
    full = solve(h, **kw)
    part = solve(h, host=("gap",), **kw)
    assert isinstance(part.gap, np.ndarray) and isinstance(part.pressure, cupy.ndarray)
    np.testing.assert_array_equal(part.gap, full.gap)
    np.testing.assert_array_equal(cupy.asnumpy(part.pressure), full.pressure)
    with pytest.raises(ValueError, match="host"):
        solve(h, host=("gaps",), **kw)


# -------------------------------------------------------------------------------------------------- batched
@pytest.mark.parametrize("generic", ["0", "1"])
def test_batched_gpu_matches_one_by_one_cpu(generic: str, monkeypatch) -> None:
    """Fused batch kernels ("0") and plain cupy array code ("1") against one-by-one CPU solves."""
    _cupy()
    monkeypatch.setenv("GAPSWEEP_GENERIC_KERNELS", generic)
    from gapsweep.gfmd import batched, solve

    probs = [batched.Problem(heights=_surface(128, seed), sigma0=s0, gamma0=1e-3, rho=rho)
             for seed, s0, rho in ((1, 1e-3, 0.01), (2, 1e-2, 0.01), (3, 1e-1, 0.02), (1, 1.0, 0.01),
                                   (4, 1e-4, 0.01))]
    res = batched.solve_batch(probs, tol=1e-12, backend="cupy")
    monkeypatch.setenv("GAPSWEEP_GENERIC_KERNELS", "0")
    for p, r in zip(probs, res):
        ref = solve(p.heights, sigma0=p.sigma0, gamma0=p.gamma0, rho=p.rho, tol=1e-12, backend="numpy")
        assert r.status == ref.status == "converged"
        # the fused kernels shift exponentials by a guess (round-off differs): a decision may flip near tol
        assert abs(r.iterations - ref.iterations) <= (0 if generic == "1" else 1), (r.iterations, ref.iterations)
        assert abs(r.mean_gap - ref.mean_gap) <= 1e-12 * abs(ref.mean_gap)
        for name in ("gap", "pressure", "displacement"):
            x, y = getattr(ref, name), getattr(r, name)
            assert np.abs(x - y).max() <= 1e-12 * np.abs(x).max(), name


def test_sweep_batched_gpu_equals_unbatched_and_cpu(tmp_path) -> None:
    """The sweep with GFMD on the GPU: batched chains (gapsweep.batching, N <= 1024) equal the one-by-one GPU
    sweep and the CPU sweep (numpy backend) to round-off; same statuses, messages and iteration counts."""
    _cupy()
    from gapsweep import runner, store

    job = """
[job]
name = "gpusweep"
[grid]
hurst = [0.3]
rho = [0.02, 0.01]
sigma0 = [1e-3, 1e-2, 1e-1]
seeds = [0, 1]
[surface]
lambda_l = 0.25
lambda_s = 0.0625
[histogram]
bins = 32
[methods.gfmd]
n = [64, 128]
tol = 1e-10
backend = "BACKEND"
"""
    stores = {}
    for name, backend, batch in (("cpu", "numpy", "off"), ("gpu", "cupy", "off"), ("gpu_batch", "cupy", "auto")):
        js = tmp_path / f"{name}.toml"
        js.write_text(job.replace("BACKEND", backend))
        stores[name] = tmp_path / f"{name}.h5"
        s = runner.run(js, stores[name], progress="none", mpi="off", batch=batch)
        assert s["done"] == 24, s
    rec = __import__("json").loads(store.read_attrs(stores["gpu_batch"])["runs"])[-1]
    assert rec["batch_units"] == 2 and rec["gpus"] == [0]
    assert store.diff(stores["gpu_batch"], stores["gpu"], rtol=1e-10, atol=1e-12) == []
    with store.open_read(stores["gpu_batch"]) as a, store.open_read(stores["cpu"]) as b:
        ra, rb = a["results"][...], b["results"][...]
    assert (ra["iterations"] == rb["iterations"]).all() and (ra["message"] == rb["message"]).all()
    assert np.abs(ra["mean_gap"] - rb["mean_gap"]).max() <= 1e-10 * np.abs(rb["mean_gap"]).max()
