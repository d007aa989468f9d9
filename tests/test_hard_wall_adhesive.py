"""The challenge's law, a hard wall with exponential adhesion (``interaction="hard_wall_adhesive"``,
gapsweep.gfmd._bounded; docs/gfmd.md "Hard wall with adhesion"), in process: analytic full contact of a
sinusoid (tensile and compressive), the limit ``work -> 0`` against the hard-wall minimiser, the energy and its
gradient by finite differences, the equilibrium re-checked from the returned fields with numpy's own FFT,
detachment beyond the theoretical strength, honest statuses and refusals. Peers: tests/test_peers_challenge.py."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gapsweep.gfmd import solve
from gapsweep.gfmd._bounded import _Lean
from gapsweep.gfmd._grid import Grid
from gapsweep.gfmd.interactions import HardWallAdhesive
from gapsweep.surface import self_affine

LAW = "hard_wall_adhesive"


def rough(nx: int, ny: int, seed: int, h_rms: float = 0.01) -> np.ndarray:
    rng = np.random.default_rng(seed)
    qx = np.fft.fftfreq(nx, 1 / nx)
    qy = np.fft.fftfreq(ny, 1 / ny)
    q = np.hypot(qx[:, None], qy[None, :])
    amp = np.where((q >= 2) & (q <= min(nx, ny) / 4), np.where(q > 0, q, 1.0) ** -1.8, 0.0)
    h = np.fft.ifft2(amp * np.exp(2j * np.pi * rng.random((nx, ny)))).real
    return (h - h.mean()) * (h_rms / h.std())


@pytest.mark.validation
@pytest.mark.parametrize("tensile", [True, False])
def test_sinusoid_in_full_contact_has_the_analytic_pressure(tensile: bool) -> None:
    """h = a cos(2 pi x / Lx) in full contact: p = sigma0 + (E* q / 2) h exactly (the gap vanishes, u = h up to a
    constant), mean gap 0, area 1; full contact holds while the multiplier p + w/rho stays >= 0."""
    nx, ny, lx, ly, e_star, a = 32, 20, 1.0, 0.6, 2.0, 1e-3
    x = np.arange(nx) * lx / nx
    h = np.repeat((a * np.cos(2 * np.pi * x / lx))[:, None], ny, axis=1)
    q = 2 * np.pi / lx
    work, rho = 1e-4, 1e-2  # w/rho = 0.01 > E* q a/2 = 0.0063: full contact survives a tensile load
    amp = e_star * q * a / 2
    sigma0 = (-work / rho + 1.2 * amp) if tensile else 3 * amp
    assert (sigma0 < 0) == tensile
    r = solve(h, sigma0=sigma0, interaction=LAW, work=work, rho=rho, e_star=e_star, length=(lx, ly), tol=1e-11,
              backend="numpy")
    assert r.converged and r.status == "converged", r.status
    assert r.contact_area == 1.0 and r.mean_gap == 0.0
    np.testing.assert_allclose(r.pressure, sigma0 + e_star * q / 2 * h, rtol=0, atol=1e-9 * work / rho)


def test_beyond_the_theoretical_strength_the_body_detaches() -> None:
    """A nearly flat surface holds up to the law's largest tension w/rho (all pixels at g = 0); beyond it there
    is no equilibrium: status "detached", not converged."""
    h = 1e-6 * rough(24, 24, 5)
    work, rho = 1e-4, 1e-2
    held = solve(h, sigma0=-0.9 * work / rho, interaction=LAW, work=work, rho=rho, tol=1e-10, backend="numpy")
    assert held.converged and held.contact_area == 1.0
    off = solve(h, sigma0=-1.1 * work / rho, interaction=LAW, work=work, rho=rho, tol=1e-10, backend="numpy")
    assert off.status == "detached" and not off.converged


@pytest.mark.validation
@pytest.mark.parametrize(("nx", "ny", "sigma0"), [(64, 64, 1e-2), (45, 64, 3e-3)])
def test_vanishing_work_is_the_hard_wall(nx: int, ny: int, sigma0: float) -> None:
    """work -> 0: the law is the hard wall; the mean gap matches the hard-wall minimiser (Polonsky-Keer CG on
    the pressure, an independent algorithm) to 1e-7 and so does the contact area (to one pixel: the rim pixels
    with vanishing pressure may go either way)."""
    h = rough(nx, ny, 7)
    a = solve(h, sigma0=sigma0, interaction=LAW, work=1e-14, rho=1.0 / nx, tol=1e-10, backend="numpy")
    b = solve(h, sigma0=sigma0, interaction="hard_wall", tol=1e-10, backend="numpy", method="pk")
    assert a.converged and b.converged
    assert abs(a.mean_gap - b.mean_gap) <= 1e-7 * b.mean_gap
    assert abs(a.contact_area - b.contact_area) <= 1.0 / (nx * ny)


@pytest.mark.validation
def test_gradient_is_the_derivative_of_the_energy() -> None:
    """The minimiser's gradient G = p_el + V'(g) + sigma0 is dF/dg of its energy per area (central finite
    differences along a random direction, at a random admissible gap, rectangular grid), and the line search's
    energy change (summed term by term) is the difference of the energies."""
    rng = np.random.default_rng(2)
    nx, ny, box = 24, 30, (0.8, 1.0)
    h = rough(nx, ny, 3) + 0.3  # the solver drops the mean of h itself
    law = HardWallAdhesive(2e-4, 0.02)
    g = 0.05 + 0.02 * rng.random((nx, ny))
    d = rng.standard_normal((nx, ny))

    def state(gap):
        st = _Lean(Grid((nx, ny), box, "numpy", None, False), law, h, 1.3, 2)
        st.sigma0 = -3e-3
        st.g[...] = gap
        st.evaluate()
        return st

    st = state(g)
    eps = 1e-6
    fp, fm = state(g + eps * d).f, state(g - eps * d).f
    fd = (fp - fm) / (2 * eps)
    assert abs(fd - float(np.mean(st.G * d))) <= 1e-7 * abs(fd)
    st.d[...] = d
    df, dec = st.trial(eps)  # the line search's energy change agrees with the energies
    assert abs(df - (fp - st.f)) <= 1e-9 * abs(df)
    assert abs(dec - eps * float(np.mean(st.G * d))) <= 1e-9 * abs(dec)  # t = (g + eps d) - g: round-off of g


@pytest.mark.validation
@pytest.mark.parametrize(("nx", "ny", "seed", "sigma0"), [(48, 75, 1, 2e-3), (63, 40, 2, -3e-5), (64, 64, 3, 0.0)])
def test_returned_fields_are_an_equilibrium(nx: int, ny: int, seed: int, sigma0: float) -> None:
    """From the returned fields alone, with numpy's FFT: the elastic pressure of the displacement equals
    p - sigma0 off contact (p = -V'(g)), the contact pressure is >= 0 where g = 0 and <p> = sigma0; odd and
    rectangular grids, tensile, zero and compressive loads."""
    lx, ly, e_star = 1.0, ny / nx, 1.5
    h = rough(nx, ny, seed)
    work, rho = 4e-4 / nx, 1.0 / nx
    r = solve(h, sigma0=sigma0, interaction=LAW, work=work, rho=rho, e_star=e_star, length=(lx, ly), tol=1e-10,
              backend="numpy")
    assert r.converged, r.status
    qx = 2 * np.pi * np.fft.fftfreq(nx, lx / nx)
    qy = 2 * np.pi * np.fft.fftfreq(ny, ly / ny)
    p_el = np.fft.ifft2(0.5 * e_star * np.hypot(qx[:, None], qy[None, :]) * np.fft.fft2(r.displacement)).real
    scale = work / rho
    free = r.gap > 0
    assert 0 < free.mean() < 1
    np.testing.assert_allclose(r.pressure[free], -(work / rho) * np.exp(-r.gap[free] / rho), rtol=1e-12)
    np.testing.assert_allclose(p_el[free], r.pressure[free] - sigma0, rtol=0, atol=1e-8 * scale)
    assert np.all(r.pressure[~free] + work / rho >= -1e-8 * scale)
    assert abs(r.pressure.mean() - sigma0) <= 1e-8 * scale
    # the gap is the surface of the body above the rigid one: g = <g> + u - (h - <h>)
    np.testing.assert_allclose(r.gap, r.mean_gap + r.displacement - (h - h.mean()), rtol=0, atol=1e-12)


@pytest.mark.validation
def test_tensile_load_follows_the_branch_from_zero_load() -> None:
    """A tensile load without ``initial`` is reached by continuation from zero load: the same equilibrium as an
    explicit load path in small steps (gfmd.solve_path, warm starts), and the diagnostics record the path."""
    from gapsweep.gfmd import solve_path

    h = self_affine(64, 0.8, lambda_l=0.25, lambda_s=4 / 64, seed=4)
    h = h * (0.01 / h.std())
    work, rho = 9e-5 / 1.0, 1.0 / 64
    target = -6e-4  # pull-off lies near -8.9e-4 (measured: the continuation detaches there)
    r = solve(h, sigma0=target, interaction=LAW, work=work, rho=rho, tol=1e-10, backend="numpy")
    path = solve_path(h, np.linspace(0.0, target, 9), interaction=LAW, work=work, rho=rho, tol=1e-10,
                      backend="numpy")
    last = path.results[-1]
    assert r.converged and last.converged
    assert r.diagnostics["continuation_steps"] >= 1 and r.diagnostics["last_attached_load"] == target
    assert abs(r.mean_gap - last.mean_gap) <= 1e-7 * last.mean_gap
    assert np.array_equal(r.gap <= 0, last.gap <= 0)


def test_statuses_and_refusals() -> None:
    h = rough(32, 32, 9)
    r = solve(h, sigma0=1e-3, interaction=LAW, work=1e-4, rho=1 / 32, tol=1e-12, max_iter=2, backend="numpy")
    assert r.status == "max_iter" and not r.converged and math.isfinite(r.residual)
    with pytest.raises(ValueError, match="periodic"):
        solve(h, sigma0=1e-3, interaction=LAW, work=1e-4, rho=1 / 32, periodic=False)
    with pytest.raises(ValueError, match="start='coarse' needs a compressive load"):
        solve(h, sigma0=-1e-5, interaction=LAW, work=1e-4, rho=1 / 32, start="coarse")
    with pytest.raises(ValueError, match="memory must be an integer >= 1"):
        solve(h, sigma0=1e-3, interaction=LAW, work=1e-4, rho=1 / 32, memory=0)
    with pytest.raises(ValueError, match="memory: the L-BFGS pairs"):
        solve(h, sigma0=1e-3, interaction="hard_wall", memory=3)
    with pytest.raises(ValueError, match="needs rho"):
        solve(h, sigma0=1e-3, interaction=LAW, work=1e-4)
    with pytest.raises(ValueError, match="work"):
        solve(h, sigma0=1e-3, interaction=LAW, work=-1.0, rho=0.1)
    with pytest.raises(ValueError, match="method"):
        solve(h, sigma0=1e-3, interaction=LAW, work=1e-4, rho=0.1, method="pk")


@pytest.mark.parametrize("shape", [(64, 64), (48, 75)])
def test_gpu_branch_through_the_cupy_shim(monkeypatch, shape: tuple[int, int]) -> None:
    """The minimiser is written once for numpy and cupy arrays: a cupy ``heights`` (tests/cupy_shim.py: numpy
    stand-ins whose module reads "cupy"; square grids through the cuFFT backend, rectangles through cupy.fft) runs
    the cupy branch, continuation to a tensile load included, and returns the numpy answer with the fields left on
    the device. No GPU needed; the real device is not checked here."""
    from tests import cupy_shim

    cp = cupy_shim.install_fresh(monkeypatch, generic_kernels=False)
    h = rough(*shape, 3)
    kw = dict(sigma0=-3e-5, interaction=LAW, work=4e-4 / 64, rho=1 / 64, length=(1.0, shape[1] / shape[0]),
              tol=1e-10)
    a = solve(h, backend="numpy", **kw)
    b = solve(cp.asarray(h), host=False, **kw)
    assert a.converged and b.converged and b.backend == "cupy" and "cupy" in type(b.gap).__module__
    assert abs(a.mean_gap - b.mean_gap) <= 1e-12 * a.mean_gap and a.contact_area == b.contact_area


@pytest.mark.parametrize(("shape", "sigma0", "pairs"), [((128, 128), 1e-3, 10), ((96, 150), 2e-3, 3)])
def test_peak_memory_is_the_plan(monkeypatch, shape: tuple[int, int], sigma0: float, pairs: int) -> None:
    """The traced numpy peak of a one-process solve (numpy FFT, 1024-element chunks) lies between the grid-sized
    parts of gfmd._bounded.memory_plan and the whole plan (fixed-size chunks and numpy's buffers added), in
    arrays of the grid, the caller's surface counted as one: the estimate that guards a run is exact to the
    fixed-size parts. 10 pairs: about 29 arrays (the old minimiser held about 36)."""
    import tracemalloc

    from gapsweep.gfmd import _bounded

    monkeypatch.setattr(_bounded, "_CHUNK", 1024)
    nx, ny = shape
    h = rough(nx, ny, 4)
    kw = dict(sigma0=sigma0, interaction=LAW, work=8e-4 / nx, rho=1 / nx, tol=1e-9, backend="numpy",
              length=(1.0, ny / nx), memory=pairs)
    solve(h, **kw)  # imports and caches outside the trace
    tracemalloc.start()
    base = tracemalloc.get_traced_memory()[0]
    r = solve(h, **kw)
    peak = tracemalloc.get_traced_memory()[1] - base
    tracemalloc.stop()
    plan = _bounded.memory_plan(shape, memory=pairs, backend="numpy", chunk=1024)
    measured = 1.0 + peak / plan["array_bytes"]
    assert r.converged and r.diagnostics["lbfgs_pairs"] == pairs
    assert plan["grid_arrays"] <= measured <= plan["arrays"], (measured, plan)
    assert plan["grid_arrays"] == pytest.approx(9.7 + 2 * pairs, abs=0.1)  # surface, 7.6 of the solver, 2 of numpy FFT
    with pytest.raises(ValueError, match="backend must be"):
        _bounded.memory_plan(shape, 4, backend="cuda")


def test_coarse_start_reaches_the_flat_starts_equilibrium() -> None:
    """``start="coarse"`` (gfmd._coarse: the problem on 64^2 first, the gap of the prolonged body surface starting
    128^2) at mu_rho = 0.5: the plain start's equilibrium (mean gap to 1e-8, the same contact pixels) in fewer fine
    iterations (28 against 37 measured), on one process and on the one-rank slab path (distributed.solve, the
    distributed code) alike. Stronger adhesion (mu_rho = 0.84) lets the coarse levels, whose pixel is larger and
    mu_rho higher, snap into more contact: the fine grid then keeps another equilibrium (docs/gfmd.md "Hard wall
    with adhesion"), so this start is a load path of its own, not a speed-up alone."""
    from gapsweep.gfmd import distributed
    from gapsweep.gfmd._coarse import SelfComm

    n = 128
    h = self_affine(n, 0.8, lambda_l=0.2, lambda_s=8 / n, seed=5)
    h *= 0.01 / h.std()
    rho = 1.0 / n
    kw = dict(sigma0=3e-4, interaction=LAW, work=0.25 * rho, rho=rho, tol=1e-9)
    a = solve(h, backend="numpy", **kw)
    b = solve(h, start="coarse", levels=1, backend="numpy", **kw)
    c = distributed.solve(h, comm=SelfComm(), start="coarse", levels=1, **kw)
    assert a.converged and b.converged and c.converged
    assert [lv["shape"] for lv in b.diagnostics["levels"]] == [[64, 64]]
    assert b.iterations < a.iterations and c.iterations < a.iterations
    assert 0 < a.contact_area < 1
    for r in (b, c):
        assert abs(r.mean_gap / a.mean_gap - 1) <= 1e-8
        assert np.array_equal(r.gap <= 0, a.gap <= 0)
