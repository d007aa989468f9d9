"""The GPU branches of free boundaries (gfmd._free with gfmd._cuda._FreeCupyOps and _PadFFT), of the hard wall's
cuFFT backend (gapsweep.core.fft._CupyBackend.convolve), of the exponential law's fused passes (gfmd._cuda._CupyOps)
and of the batched stack (gfmd.batched._FusedStack) run on the CPU through tests/cupy_shim.py (numpy stand-ins
for cupy, cuFFT's plans and the CUDA kernels, each launch checked against kernels.cu's parameter list): the same
answers as the numpy path, to the solver tolerance. No GPU needed; on a GPU machine tests/gpu/ checks the real
thing."""

from __future__ import annotations

import numpy as np
import pytest

from gapsweep.core import fft
from gapsweep.gfmd import _cuda, solve
from gapsweep.surfaces import self_affine
from tests import cupy_shim


@pytest.fixture
def cp(monkeypatch):
    return cupy_shim.install_fresh(monkeypatch)


def _map(shape: tuple[int, int]) -> np.ndarray:
    h = self_affine(128, 0.8, lambda_l=0.5, lambda_s=8 / 128, seed=5)[: shape[0], : shape[1]]
    return h / h.std() * 0.01


@pytest.mark.parametrize(("law", "kw", "method", "shape"),
                         [("exponential", dict(gamma0=1e-4, rho=2e-3), "lbfgs", (64, 64)),
                          ("exponential", dict(gamma0=1e-4, rho=2e-3), "cg", (64, 48)),
                          ("adhesive", dict(work=1e-4, rho=2e-3), "lbfgs", (64, 48))])
def test_free_smooth_gpu_branch_matches_numpy(cp, law, kw, method, shape) -> None:
    """Square and rectangular maps: converged, mean gap to 1e-9 relative, pressures to 1e-7 of their scale, the
    fused kernels and the 2-D plans actually used (counted)."""
    h = _map(shape)
    common = dict(sigma0=0.01, interaction=law, length=(1.0, shape[1] / shape[0]), tol=1e-9, periodic=False,
                  method=method, **kw)
    ref = solve(h, backend="numpy", **common)
    r = solve(cp.asarray(h), host=False, **common)
    assert type(r.pressure).__module__ == "cupy" and r.converged and ref.converged
    assert r.mean_gap == pytest.approx(ref.mean_gap, rel=1e-9)
    scale = ref.diagnostics["pressure_scale"]
    np.testing.assert_allclose(np.asarray(r.pressure), ref.pressure, rtol=0, atol=1e-7 * scale)
    n = cupy_shim.COUNTS
    assert n["gs_dot"] > r.iterations and n["gs_sumfinite"] >= 2 * r.iterations and n["gs_moments"] >= r.iterations
    assert n["cufft_R2C"] >= r.iterations and n["cufft_C2R"] >= r.iterations  # the padded 2-D plans
    assert n["gapsweep_free_grad"] == r.iterations + 1 or n["gapsweep_free_grad"] == r.iterations


@pytest.mark.parametrize(("periodic", "shape"), [(False, (64, 64)), (False, (64, 48)), (True, (64, 64))])
def test_hard_wall_gpu_branch_matches_numpy(cp, periodic, shape) -> None:
    """Free (2-D plans over the padded buffer) and periodic (the backend's one-buffer convolution) hard wall:
    same contact set and mean gap to 1e-9 as the numpy solve; elastic energy (<p u>/2 here) to 1e-8."""
    h = _map(shape)
    common = dict(sigma0=0.01, interaction="hard_wall", method="pcg", tol=1e-10, periodic=periodic,
                  length=(1.0, shape[1] / shape[0]))
    ref = solve(h, backend="numpy", **common)
    r = solve(cp.asarray(h), host=False, **common)
    assert r.converged and ref.converged and r.backend == "cupy"
    assert r.mean_gap == pytest.approx(ref.mean_gap, rel=1e-9)
    np.testing.assert_array_equal(np.asarray(r.pressure) > 0, ref.pressure > 0)
    assert r.elastic_energy == pytest.approx(ref.elastic_energy, rel=1e-8)
    assert cupy_shim.COUNTS["cufft_C2R"] >= r.iterations


def test_padded_transforms_gpu_branch(cp) -> None:
    """FreeGrid's GPU transforms (one 2-D plan each way over the padded buffer) against the CPU's axis-by-axis
    ones: pad_fwd, pad_inv, pad_sum and the compliance to 1e-12 relative, rectangular map."""
    from gapsweep.gfmd._grid import FreeGrid

    rng = np.random.default_rng(3)
    p = rng.standard_normal((12, 10))
    cpu = FreeGrid(p.shape, (1.0, 0.8), "numpy", 1, False)
    gpu = FreeGrid(p.shape, (1.0, 0.8), "auto", 1, True)
    assert gpu.xp is cp and gpu._padfft() is not None and cpu._padfft() is None
    b_cpu, b_gpu = cpu.pad_fwd(p), gpu.pad_fwd(cp.asarray(p))
    assert b_gpu.shape == b_cpu.shape == (24, 11)
    np.testing.assert_allclose(np.asarray(b_gpu), b_cpu, rtol=0, atol=1e-12 * np.abs(b_cpu).max())
    np.testing.assert_allclose(np.asarray(gpu.pad_inv(b_gpu)), p, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(gpu.pad_sum(b_gpu)), p * (4 * 12 * 10), rtol=0, atol=1e-9)
    u_cpu = cpu.compliance(1.0)(p)
    u_gpu = gpu.compliance(1.0)(cp.asarray(p))
    np.testing.assert_allclose(np.asarray(u_gpu), u_cpu, rtol=0, atol=1e-12 * np.abs(u_cpu).max())


class _Devices:
    """``cupy.cuda.Device`` with a current device that ``with Device(i):`` switches (issue 36): the shim's plain
    stand-in always reads device 0."""

    current = 0

    def __init__(self, index: int | None = None) -> None:
        self.id = _Devices.current if index is None else int(index)
        self.attributes = {"MultiProcessorCount": 4}
        self._prev: list[int] = []

    def __enter__(self) -> _Devices:
        self._prev.append(_Devices.current)
        _Devices.current = self.id
        return self

    def __exit__(self, *exc: object) -> None:
        _Devices.current = self._prev.pop()


def test_plan_caches_keyed_by_device(cp, monkeypatch) -> None:
    """Every cache of cuFFT plans and loaded kernels holds one entry per device (issue 36: a second GPU in the
    same process reused device 0's plans and failed with CUFFT_EXEC_FAILED): two devices get two backends (two
    plan pairs) and two kernel tables; asking again on a device returns its own; a solve on device 1 after one
    on device 0 runs on plans made on device 1 and gives the same answer."""
    monkeypatch.setattr(cp.cuda, "Device", _Devices)
    monkeypatch.setattr(_Devices, "current", 0)
    made: list[int] = []
    real = cupy_shim.get_fft_plan

    def plan(*a, **k):
        made.append(_Devices.current)
        return real(*a, **k)

    import sys

    monkeypatch.setattr(sys.modules["cupyx.scipy.fft"], "get_fft_plan", plan)
    with cp.cuda.Device(0):
        b0 = fft.get_backend("cupy", 16)
        k0 = _cuda._cupy_kernels()
    with cp.cuda.Device(1):
        b1 = fft.get_backend("cupy", 16)
        k1 = _cuda._cupy_kernels()
    assert b0 is not b1 and b0._plans[0] is not b1._plans[0]
    assert k0 is not k1 and k0.keys() == k1.keys()
    assert made == [0, 0, 1, 1]  # R2C and C2R made on each device
    with cp.cuda.Device(0):
        assert fft.get_backend("cupy", 16) is b0 and _cuda._cupy_kernels() is k0
    with cp.cuda.Device(1):
        assert fft.get_backend("cupy", 16) is b1 and _cuda._cupy_kernels() is k1
    # a whole periodic hard-wall solve on each device: its backend comes from that device's entry
    h = _map((32, 32))
    kw = dict(sigma0=0.01, interaction="hard_wall", method="pcg", tol=1e-10, length=1.0)
    results = []
    for dev in (0, 1):
        with cp.cuda.Device(dev):
            made.clear()
            results.append(solve(cp.asarray(h), host=False, **kw))
            assert set(made) <= {dev}
            assert ("cupy", 32, 0, "", dev) in fft._PLANS
    assert results[0].converged and results[1].converged
    assert results[1].mean_gap == results[0].mean_gap


@pytest.mark.parametrize(("kw", "periodic"), [(dict(thickness=0.05, poisson=0.3), True),
                                              (dict(thickness=0.05, poisson=0.3, interaction="exponential",
                                                    gamma0=1e-4, rho=2e-3), True),
                                              (dict(thickness=0.02, bottom="slip", hardness=0.03), True),
                                              (dict(hardness=0.03), True), (dict(hardness=0.03), False)])
def test_layer_and_cap_gpu_branch_matches_numpy(cp, kw, periodic) -> None:
    """The layer's stiffness and the pressure cap through the cupy branch (the same array code, issue 43): the
    numpy solve's mean gap to 1e-9 and its contact set (the exponential law: the CPU's own minimiser with the
    layer's stiffness against the GPU branch's generic L-BFGS; the map centred, as the two minimisers report the
    mean gap of an uncentred map differently)."""
    h = _map((64, 64))
    h = h - h.mean()
    common = dict(sigma0=0.01, interaction="hard_wall", tol=1e-10, periodic=periodic)
    common.update(kw)
    ref = solve(h, backend="numpy", **common)
    r = solve(cp.asarray(h), host=False, **common)
    assert r.converged and ref.converged and r.backend == "cupy"
    assert r.mean_gap == pytest.approx(ref.mean_gap, rel=1e-9)
    if common["interaction"] == "hard_wall":
        np.testing.assert_array_equal(np.asarray(r.pressure) > 0, ref.pressure > 0)
    if "hardness" in kw:
        assert r.plastic_area == ref.plastic_area > 0
        # the sweep's plastic columns (gapsweep.sweep.methods.gfmd) from the field where it lives (cupy here)
        from gapsweep.gfmd._ops import _is_cupy
        from gapsweep.sweep.methods.gfmd import _plastic_values

        assert _is_cupy(r.plastic_displacement)
        got, want = _plastic_values(r), _plastic_values(ref)
        assert got["plastic_area"] == want["plastic_area"]
        for k in ("plastic_displacement_mean", "plastic_displacement_max"):
            assert got[k] == pytest.approx(want[k], rel=1e-6) and want[k] > 0


def test_batch_fused_stack_matches_numpy(monkeypatch) -> None:
    """The batched CG on the GPU's fused stack (gfmd.batched._FusedStack: every pass one bt_* kernel over the
    stack, emulated by the shim and checked against kernels.cu's parameter lists) against the numpy stack:
    same statuses, mean gaps to 1e-10 relative and pressures to 1e-9 of their scale; five problems that stop at
    different iterations (parked, then compacted), each kernel launched."""
    from gapsweep.gfmd import BatchProblem, solve_batch

    cases = [(1, 1e-3, 0.05), (2, 1e-2, 0.05), (3, 1e-1, 0.06), (4, 1e-4, 0.05), (5, 1.0, 0.05)]
    hs = [self_affine(32, 0.3, lambda_l=0.25, lambda_s=4 / 32, seed=s) for s, _, _ in cases]
    ref = solve_batch([BatchProblem(h, s0, gamma0=1e-3, rho=rho) for h, (_, s0, rho) in zip(hs, cases)],
                      tol=1e-10, backend="numpy")
    cp = cupy_shim.install_fresh(monkeypatch, generic_kernels=False)
    res = solve_batch([BatchProblem(cp.asarray(h), s0, gamma0=1e-3, rho=rho) for h, (_, s0, rho) in zip(hs, cases)],
                      tol=1e-10, backend="cupy", host=False)
    assert len({r.iterations for r in ref}) > 1  # problems leave the stack at different iterations
    for r, f in zip(res, ref):
        assert r.status == f.status == "converged" and r.backend == "cupy"
        assert abs(r.mean_gap - f.mean_gap) <= 1e-10 * abs(f.mean_gap)
        p = np.asarray(r.pressure)
        assert np.abs(p - f.pressure).max() <= 1e-9 * np.abs(f.pressure).max()
    for k in ("bt_point", "bt_moments", "bt_cgdots", "bt_cgupdate", "bt_accept"):
        assert cupy_shim.COUNTS[k] > 0, k


@pytest.mark.parametrize("method", ["cg", "lbfgs", "fire"])
def test_exponential_fused_gpu_matches_numpy(monkeypatch, method) -> None:
    """The exponential law on one GPU with the fused kernels (gfmd._cuda._CupyOps: set-up, trial-point, gradient
    and result passes; "cg" runs the chained CG of _solvers, one synchronisation per iteration) through the
    shim against the numpy solve: converged, the same iteration count, mean gap to 1e-10 relative, pressure to
    1e-9 of its scale, on an odd grid too; each pass of the path launched."""
    for n, seed in ((64, 3), (33, 5)):
        h = self_affine(n, 0.8, lambda_l=0.5, lambda_s=4 / n, seed=seed)
        h = h / h.std() * 0.01
        kw = dict(sigma0=0.01, gamma0=1e-4, rho=1e-2, tol=1e-10, method=method)
        ref = solve(h, backend="numpy", **kw)
        cp = cupy_shim.install_fresh(monkeypatch, generic_kernels=False)
        r = solve(cp.asarray(h), host=False, **kw)
        assert r.converged and ref.converged and r.backend == "cupy"
        assert r.iterations == ref.iterations
        assert abs(r.mean_gap - ref.mean_gap) <= 1e-10 * abs(ref.mean_gap)
        assert np.abs(np.asarray(r.pressure) - ref.pressure).max() <= 1e-9 * np.abs(ref.pressure).max()
        used = ["gs_field", "gs_linresp", "gs_point", "gs_grad", "gs_final", "gs_resid"]
        used += ["gs_cgdir", "gs_moments", "gs_trial0"] if method == "cg" else []
        for k in used:
            assert cupy_shim.COUNTS[k] > 0, k
        monkeypatch.undo()
