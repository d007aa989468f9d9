"""The "multiplier" minimiser: hard-wall contact at fixed mean pressure (docs/gfmd.md, "Hard wall").

Minimises the complementary energy ``(1/2) <p K p> - <p h>`` over pressures ``p >= 0`` with ``<p> = sigma0``,
``K`` the half-space compliance ``u~ = p~ / (E* q/2)`` (q != 0). Its gradient is the gap up to a constant; the
mean gap ``g0`` is the multiplier of the load constraint. Algorithm: Polonsky & Keer (Wear 231, 206, 1999),
constrained conjugate gradients on the contact set ``S = {p > 0}`` with the load restored by scaling, overlapping
points re-entering at ``p = -tau k_in g`` (``k_in`` a stiffness where ``tau`` is a number: unit-invariant); written
once for numpy and cupy arrays. Methods: "pk", the plain algorithm (as tamaas' PolonskyKeerRey and ContactMechanics'
constrained_conjugate_gradients); "pcg" (default on the GPU), the same iteration with gapsweep's Fourier
preconditioner: the search direction is built from ``z = P_S M P_S g`` with ``M = K^-1 = E* q/2`` (exact when
everything is in contact; the FFT-based preconditioner of Vollebregt, J. Comput. Phys. 257, 333, 2014, in its
simplest form); "mpcg" (default on the CPU), "pcg" started from the coarse-to-fine pressure of :func:`_coarse_start`
(the coarsened surface solved to ``_COARSE_TOL``, recursively). Cost per iteration, periodic grids on the CPU
(:class:`_InFourier`, ``p~`` kept in Fourier space): ``M g`` ("pcg", one FFT pair), ``t~`` (one forward
transform; the line search's ``<t K t>`` by Parseval, ``t`` made load-neutral in real space), ``u = K p~`` (one
inverse) and the transform of ``p`` only when the projection clipped something: 2.5 pairs. Free boundaries and
the GPU (:class:`_RealSpace`): ``K t`` (one pair), ``M g`` ("pcg", one more), and ``K p`` afresh when the
projection clipped something (else ``u`` follows linearly): 3 pairs. Skipping the fresh ``K p`` (``u`` lagging
by the clipped part, re-synced every few iterations) breaks the constrained CG (issue 30: 1.2-300x the
iterations or no convergence; benchmarks/results/contact/issue30_lag_resync_512.txt).

Convergence (decided on the returned fields, one more FFT pair): force balance ``u = K p`` and ``p = 0`` on the
free surface hold by construction, so the residual is the constraint's violation in units of ``h_rms``:

    residual = max( rms_S(g), max(0, -min_free(g)) ) / h_rms,     g0 = -<u - h>_S,

i.e. the gap left in the contact and the overlap outside it; ``load_error = |<p> - sigma0| / sigma0``. The
diagnostics add ``complementarity = <p |g|> / (sigma0 h_rms)``. The returned gap is exactly 0 on ``S`` (the
contact atom of the gap distribution); its remaining error is what ``residual`` reports. The gap does not
depend on ``<h>`` (the body follows the surface at fixed load); ``mean_gap = <g>``."""

from __future__ import annotations

import logging
import math
import time
from typing import Any

import numpy as np

from gapsweep.core import deadline
from gapsweep.gfmd._constrained_ops import make_ops
from gapsweep.gfmd._grid import FreeGrid, Grid
from gapsweep.gfmd._ops import _is_cupy
from gapsweep.gfmd._result import GFMDResult, fields_to_host, final_status, law_result
from gapsweep.gfmd.interactions.base import Interaction

METHODS = ("pk", "pcg", "mpcg")
# "auto": the least CPU time on the benchmark cases (benchmarks/bench_contact.py, docs/benchmarks.md); on the GPU
# "pcg" stays the default until "mpcg" is timed there (its coarse levels are latency-bound on a GPU).
DEFAULT_METHOD = "mpcg"
DEFAULT_METHOD_GPU = "pcg"
_COARSEST = 128  # "mpcg": smallest grid side of a coarse level
_COARSE_TOL = 1e-2  # "mpcg": tolerance of the coarse levels (a start only; the fine level decides convergence)
_REFRESH = 25  # iterations between fresh K p when the update was unclipped (bounds the drift of u)
# CG restarts (delta = 0) only when more than this fraction of |S| re-entered. Polonsky & Keer restart at every
# re-entry; near convergence a few boundary pixels re-enter almost every iteration, so the preconditioned CG was
# steepest descent there. Measured (tuning: N = 1024, seed 2, H 0.3/0.8; held-out seeds 3-5, H 0.3/0.5/0.8,
# sigma0 5e-3..0.2, periodic 1024 and free 512): 1.06-3.5x fewer fine iterations, same answers to 1.8e-9
# (benchmarks/results/contact/issue39_restart_iters.json); on the tuning surface 0.003-0.03 alike, never
# restarting (1e9) as slow as always restarting.
_KEEP = 0.01
# A solve whose residual found no new minimum in max(_STALL, i) iterations, i the iteration of its lowest one (as
# long without progress as it took to get there, and at least _STALL), starts again once from a uniform pressure
# with the CG restarted at every re-entry (Polonsky & Keer's rule, _KEEP = 0). The rule above can fall into a
# cycle where about half the contact set re-enters and is clipped on alternate steps (an ordinary 2048^2 map at
# sigma0 0.1 from a uniform start: benchmarks/bench_hardwall_cycle.py); once in it, neither restarting the
# directions nor another re-entry stiffness left it. Converging solves had at most 6 (N = 1024) and 14 (N = 4096)
# iterations between new minima at sigma0 0.1-0.2, and the stretch grows with N: hence a window that grows with
# the solve and a floor well above those.
_STALL = 30
# re-entry stiffness in units of pixel_stiffness: 1e-4..0.1 took about the same iterations, 10 ran to max_iter
# (benchmarks/results/contact/issue36_reentry_scale.txt)
_REENTRY = 0.01
_SPECTRAL = True  # periodic grids on the CPU: p~ kept in Fourier space (_InFourier)
log = logging.getLogger("gapsweep.gfmd")


def _violation(g: Any, S: Any, n_s: int, grid: Grid) -> tuple[float, float]:
    """``(rms of g on S, max overlap -min(g) off S)`` (lengths)."""
    xp = grid.xp
    rms = math.sqrt(grid.total(xp.where(S, g * g, 0.0)) / max(n_s, 1))
    off = xp.where(S, xp.inf, g)
    overlap = max(0.0, -grid.amin(off)) if n_s < grid.size else 0.0
    return rms, overlap


def pixel_stiffness(grid: Grid, e_star: float) -> float:
    """``(E*/2) <q>``, the mean of the stiffness ``M = E* q/2`` over the grid's wave vectors (pressure per length):
    the diagonal of ``M`` in real space, the pressure that pushes one pixel out by a unit length. Its wave vectors
    sampled at most 256 a side (the mean of a box of ``|q|``; a scale, not a field)."""
    nx, ny = grid.shape
    kx = np.fft.fftfreq(min(nx, 256)) * (2 * math.pi * nx / grid.lx)
    ky = np.fft.fftfreq(min(ny, 256)) * (2 * math.pi * ny / grid.ly)
    return 0.5 * e_star * float(np.mean(np.sqrt(kx[:, None] ** 2 + ky[None, :] ** 2)))


def coarsen(h: Any, xp: Any) -> Any:
    """``h`` on the ``nx/2 x ny/2`` grid of the same box: its Fourier modes below the coarse Nyquist kept."""
    nx, ny = h.shape
    cx, cy = nx // 2, ny // 2
    hh = xp.fft.rfft2(h) * (1.0 / (nx * ny))
    hc = xp.zeros((cx, cy // 2 + 1), dtype=hh.dtype)
    kx, ky = cx // 2, cy // 2  # coarse Nyquist row/column left at zero (keeps the field real)
    hc[:kx, :ky] = hh[:kx, :ky]
    hc[cx - kx + 1:, :ky] = hh[nx - kx + 1:, :ky]
    return xp.fft.irfft2(hc, s=(cx, cy)) * float(cx * cy)


def _coarse_start(h: Any, law: Interaction, sigma0: float, e_star: float, length: Any, threads: int | None,
                  backend: str, xp: Any, periodic: bool = True) -> tuple[Any, list[int]]:
    """"mpcg": the pressure of the hard-wall problem on the coarsened surface (recursively, to
    ``_COARSE_TOL``), each coarse pixel's pressure copied to its 2 x 2 fine pixels; and the coarse levels'
    iteration counts (coarsest last)."""
    # Free boundaries: 2 x 2 block means (a Fourier cut of a non-periodic map would ring at its edges).
    hc = coarsen(h, xp) if periodic else h.reshape(h.shape[0] // 2, 2, h.shape[1] // 2, 2).mean(axis=(1, 3))
    r = minimise(hc, law, sigma0=sigma0, e_star=e_star, length=length, tol=_COARSE_TOL,
                 method="mpcg", backend=backend, max_iter=2000, initial=None, threads=threads, host=False,
                 t_start=time.perf_counter(), periodic=periodic)
    p = xp.repeat(xp.repeat(r.pressure, 2, axis=0), 2, axis=1)
    return p, [r.iterations, *r.diagnostics.get("coarse_iterations", [])]


def _gap_residual(ops: Any, u: Any, h: Any, p: Any, g: Any, gs: Any, g_ref: float) -> tuple[int, float, float]:
    """``g = u - h - gbar_S``, ``gs = P_S g``; returns ``(|S|, sum_S g^2, residual)`` (see the module docstring)."""
    n_s, s_us = ops.contact_sum(u, h, p)
    ns = max(n_s, 1)
    sg2, gmin_free = ops.gap(u, h, s_us / ns, p, g, gs)
    return ns, sg2, max(math.sqrt(sg2 / ns), max(0.0, -gmin_free)) / g_ref


def _stop(res: float, tol: float, it: int, max_iter: int) -> str | None:
    if not math.isfinite(res):
        return "non_finite"
    if res <= tol:
        return "converged"
    return "max_iter" if it >= max_iter else None


class _RealSpace:
    """The strategy of :func:`_loop` on real-space fields: ``r = K t`` (one FFT pair) for the line search, ``u``
    following it linearly (``u = scale (u - tau r)``) when the projection changed nothing, ``u = K p`` afresh
    (one pair) when it did or every ``_REFRESH`` iterations. Free boundaries and the GPU take it: 3 pairs per
    iteration with the preconditioner."""

    def __init__(self, grid: Grid, compliance: Any) -> None:
        self.grid, self.compliance = grid, compliance
        self.r = grid.xp.zeros(grid.real_shape)
        self.transforms = self.since_fresh = 0

    def start(self, p: Any, out: Any = None) -> Any:
        self.transforms += 2
        return self.compliance(p, out)

    def direction(self, ops: Any, t: Any, z: Any, gs: Any, p: Any, ns: int, sg2: float, delta: float,
                  gz_old: float, precondition: bool) -> tuple[float, float, float]:
        """``t = P_S (z - zbar) + c t`` (``c = delta gz / gz_old``, ``z`` kept load-neutral: zero mean on S);
        returns ``(gz, sum gs t, sum (r - rbar_S) t over S)`` with ``r = K t``."""
        if precondition:
            z_sum, gz = ops.zstats(z, gs, p)
            zbar = z_sum / ns
        else:
            zbar, gz = 0.0, sg2
        ops.direction(t, z, zbar, delta * gz / gz_old, p)
        self.r = self.compliance(t, self.r)
        self.transforms += 2
        r_sum, rt, t_sum, gt = ops.rstats(self.r, t, gs, p)
        rt -= (r_sum / ns) * t_sum  # <(r - rbar_S) t>_S
        return gz, gt, rt

    def step(self, ops: Any, p: Any, u: Any, tau: float, scale: float, changed: bool) -> Any:
        """``p *= scale`` (the load restored) and the displacement of the new ``p``."""
        follow = not changed and self.since_fresh < _REFRESH
        ops.rescale(p, u, self.r, scale, tau, follow)
        if follow:  # K is linear: u = scale (u - tau K t)
            self.since_fresh += 1
            return u
        self.since_fresh = 0  # K p afresh
        self.transforms += 2
        return self.compliance(p, u)


class _Spectral:
    """``p~`` and ``t~`` of :class:`_InFourier` through ``grid.fwd`` / ``grid.inv`` (any periodic grid)."""

    def __init__(self, grid: Grid, kinv_q: Any) -> None:
        self.grid, self.kinv = grid, kinv_q
        self.P = self.T = None

    def refresh(self, p: Any) -> None:
        self.P = self.grid.fwd(p)

    def direction(self, t: Any) -> float:
        self.T = self.grid.fwd(t)
        return self.grid.size * self.grid.dot(self.T, self.kinv * self.T)

    def advance(self, tau: float, scale: float) -> None:
        self.P -= tau * self.T
        self.P *= scale

    def displacement(self, u: Any) -> Any:
        u[...] = self.grid.inv(self.kinv * self.P)
        return u


class _SpectralFFTW(_Spectral):
    """The same through the pyFFTW plans' own buffers and fused numba passes (no temporaries)."""

    def __init__(self, grid: Grid, kinv_q: Any) -> None:
        super().__init__(grid, kinv_q)
        from gapsweep.gfmd._constrained_ops import spectral_kernels

        self.K = spectral_kernels()
        f = grid._fft
        self.f = f
        self.kmul = np.ascontiguousarray(kinv_q * (1.0 / grid.size))  # on the unnormalised spectra
        self.kw = np.ascontiguousarray(grid._w * self.kmul)
        self.P = np.empty_like(f._cout)
        self.T = np.empty_like(f._cout)

    def refresh(self, p: Any) -> None:
        self.f._rin[...] = p
        self.f._fwd.execute()
        self.K.copy_mul(self.P, self.f._cout, self.kmul, self.f._cin)

    def direction(self, t: Any) -> float:
        self.f._rin[...] = t
        self.f._fwd.execute()
        return float(self.K.copy_energy(self.T, self.f._cout, self.kw))

    def advance(self, tau: float, scale: float) -> None:
        self.K.step_mul(self.P, self.T, float(tau), float(scale), self.kmul, self.f._cin)

    def displacement(self, u: Any) -> Any:
        self.f._inv.execute()  # _cin = K p~, written by refresh / advance
        np.copyto(u, self.f._rout)
        return u


def _spectral_state(grid: Grid, kinv_q: Any) -> _Spectral:
    from gapsweep.gfmd._constrained_ops import _have_numba

    fft = getattr(grid, "_fft", None)
    plain = type(grid) is Grid or getattr(grid, "plain_periodic", False)  # a layer's grid too (gfmd.substrates)
    if fft is not None and getattr(fft, "name", "") == "pyfftw" and _have_numba() and plain:
        return _SpectralFFTW(grid, kinv_q)
    return _Spectral(grid, kinv_q)


class _InFourier:
    """The strategy of :func:`_loop` on periodic grids of one CPU process: ``p~`` kept in Fourier space
    (:class:`_Spectral`). The search direction ``t`` is made load-neutral in real space (zero sum on S), so the
    line search needs only ``<t K t> = N <t~ K t~>`` (Parseval, from ``t~``: one forward transform);
    ``p~ <- s (p~ - tau t~)`` when the projection changed nothing, else ``p~`` = the forward transform of the
    projected ``p``; ``u = K p~`` is one inverse transform and exact every iteration. Transforms per iteration:
    2 (``z = M gs``) + 1 (``t~``) + 1 (``u``) + 1 if the projection changed ``p`` (:class:`_RealSpace`: 2 + 2 +
    2)."""

    def __init__(self, grid: Grid, kinv_q: Any) -> None:
        self.grid = grid
        self.sp = _spectral_state(grid, kinv_q)
        self.transforms = self.since_fresh = 0

    def start(self, p: Any, out: Any = None) -> Any:
        self.sp.refresh(p)
        self.transforms += 2
        return self.sp.displacement(self.grid.xp.empty(self.grid.real_shape) if out is None else out)

    def direction(self, ops: Any, t: Any, z: Any, gs: Any, p: Any, ns: int, sg2: float, delta: float,
                  gz_old: float, precondition: bool) -> tuple[float, float, float]:
        """``t = P_S (z + c t)`` less its mean on S (zero sum on S: the step keeps the load), in one pass;
        returns ``(gz, sum gs t, sum t K t)``."""
        z_sum, gz, t_sum, gt_old, g_sum = ops.zstats5(z, t, gs, p)
        c = delta * gz / gz_old
        zbar = (z_sum + c * t_sum) / ns
        ops.direction(t, z, zbar, c, p)
        gt = gz + c * gt_old - zbar * g_sum  # sum gs t
        self.transforms += 1
        return gz, gt, self.sp.direction(t)

    def step(self, ops: Any, p: Any, u: Any, tau: float, scale: float, changed: bool) -> Any:
        p *= scale
        if changed or self.since_fresh >= _REFRESH:
            self.sp.refresh(p)
            self.transforms += 1
            self.since_fresh = 0
        else:
            self.sp.advance(tau, scale)
            self.since_fresh += 1
        self.transforms += 1
        return self.sp.displacement(u)


def _stalled(it: int, it_best: int) -> bool:
    """No new lowest residual since iteration ``it_best`` for ``max(_STALL, it_best)`` iterations (see _STALL)."""
    return it - it_best >= max(_STALL, it_best)


def _loop(grid: Grid, ops: Any, way: Any, h: Any, p: Any, stiff: Any, sigma0: float, tol: float, g_ref: float,
          max_iter: int, history: list[float], k_in: float, restarts: list[int]) -> tuple[Any, Any, int, str, int]:
    """The constrained CG (module docstring) on the strategy ``way`` (:class:`_RealSpace` or
    :class:`_InFourier`: how ``t``'s line search and ``u = K p`` are computed): gap and residual, ``z = P_S M
    P_S g`` (one FFT pair with ``stiff``, else ``z = gs``), the direction and step ``tau``, the projection
    ``p >= 0`` with re-entry, the load restored by scaling; once ``max(_STALL, i)`` iterations pass without a new
    lowest residual (``i`` the iteration of the lowest), one fresh start (its iteration appended to
    ``restarts``). Returns ``(p, u, iterations, status, fft_pairs)``."""
    xp = grid.xp
    t, g, gs = (xp.zeros(grid.real_shape) for _ in range(3))
    z = xp.empty(grid.real_shape) if stiff is not None else None
    delta, gz_old, status, it = 0.0, 1.0, "max_iter", 0
    keep, best, it_best = _KEEP, math.inf, 0
    with np.errstate(all="ignore"):
        u = way.start(p)
        while True:
            deadline.check()  # a task time limit ends the solve between iterations
            ns, sg2, res = _gap_residual(ops, u, h, p, g, gs, g_ref)
            history.append(res)
            stop = _stop(res, tol, it, max_iter)
            if stop:
                status = stop
                break
            if res < best:
                best, it_best = res, it
            elif keep > 0.0 and _stalled(it, it_best):  # a cycle (see _STALL): start again, once
                log.info("hard wall: no progress in %d iterations at iteration %d (residual %.3g): starting "
                         "again from a uniform pressure, the directions restarted at every re-entry", it - it_best, it,
                         res)
                restarts.append(it)
                keep, delta, best = 0.0, 0.0, math.inf
                p[...] = sigma0
                u = way.start(p, u)
                it += 1  # the fresh start counts as one iteration (history keeps one residual per iteration)
                continue
            it += 1
            if stiff is not None:  # z = P_S M P_S g
                z = grid.convolve(gs, stiff, z)
                way.transforms += 2
            else:
                z = gs
            gz, gt, rt = way.direction(ops, t, z, gs, p, ns, sg2, delta, gz_old, stiff is not None)
            gz_old = gz
            if not rt > 0:
                status = "stalled" if math.isfinite(rt) else "non_finite"
                break
            tau = gt / rt
            clipped, n_overlap, p_sum = ops.update(p, t, g, tau, tau * k_in)
            delta = 0.0 if n_overlap > keep * ns else 1.0
            u = way.step(ops, p, u, tau, sigma0 * grid.size / p_sum, bool(clipped or n_overlap))
    return p, u, it, status, (way.transforms + 1) // 2


def minimise(heights: Any, law: Interaction, *, sigma0: float, e_star: float, length: Any, tol: float,
             method: str, backend: str, max_iter: int, initial: Any, threads: int | None, host: Any,
             t_start: float, periodic: bool = True, grid: Grid | None = None) -> GFMDResult:
    """Hard wall ``law`` on the grid ``heights`` (inputs validated by ``gfmd.solve``): periodic, or a finite map
    with free boundaries (``periodic=False``: :class:`FreeGrid`'s compliance, the same iteration). ``grid``: a
    prepared grid (a distributed one: gapsweep.gfmd.distributed; "mpcg" is not offered there)."""
    grid = grid if grid is not None else (Grid if periodic else FreeGrid)(heights.shape, length, backend, threads,
                                                                          _is_cupy(heights))
    if method == "auto":
        method = DEFAULT_METHOD_GPU if grid.backend == "cupy" else DEFAULT_METHOD
    xp = grid.xp
    h, h_rms, g_ref = grid.centred(heights)  # g_ref: h_rms, or the pixel size on a flat map
    with np.errstate(divide="ignore"):
        kinv = 1.0 / ((0.5 * e_star) * grid.q)
    grid.set_mode0(kinv, 0.0)
    kinv_q = kinv  # on the normalised coefficients (grid.fwd / grid.inv)
    kinv = grid.multiplier(kinv)

    def compliance(a: Any, out: Any = None) -> Any:  # u = K a, <u> = 0
        return grid.convolve(a, kinv, out)

    if not periodic:
        compliance = grid.compliance(e_star)  # free boundaries: u = K p on the map, any mean

    coarse_its: list[int] = []
    if initial is None and method == "mpcg" and min(grid.shape) >= 2 * _COARSEST \
            and grid.shape[0] % 2 == 0 and grid.shape[1] % 2 == 0:
        p, coarse_its = _coarse_start(h, law, sigma0, e_star, length, threads, backend, xp, periodic)
        p *= sigma0 / float(p.mean())
    elif initial is None:
        p = xp.full(grid.real_shape, sigma0)
    else:
        p0 = initial.pressure if isinstance(initial, GFMDResult) else initial
        p = xp.maximum(xp.asarray(p0, dtype=xp.float64), 0.0)
        shape_ok = tuple(p.shape) == tuple(grid.real_shape)
        if not grid.agree(shape_ok and bool(xp.all(xp.isfinite(p)))) or not grid.total(p) > 0:
            raise ValueError(f"initial must be a GFMDResult or a finite pressure field of shape {grid.real_shape} "
                             "with a positive sum")
        p *= sigma0 / grid.mean(p)
    history: list[float] = []
    ops = grid.reduce_ops(make_ops(xp))
    precondition = method != "pk"
    stiff = grid.multiplier((0.5 * e_star) * grid.q)  # M = K^-1 = E* q/2, the Fourier preconditioner
    # The re-entry of an overlapping point, p = -tau k_in g: with the preconditioner tau is a number (t a
    # pressure), so k_in must be a stiffness (pressure per length): the pixel stiffness of M; plain PK's tau
    # is one already (t a length).
    k_in = _REENTRY * pixel_stiffness(grid, e_star) if precondition else 1.0
    spectral = _SPECTRAL and periodic and xp is np  # the GPU keeps the real-space loop (fused passes)
    if not spectral:
        del kinv_q  # only the spectral loop reads it (half a grid array: gfmd._cuda.solve_memory)
    way = _InFourier(grid, kinv_q) if spectral else _RealSpace(grid, compliance)
    restarts: list[int] = []
    p, u, it, status, fft_pairs = _loop(grid, ops, way, h, p, stiff if precondition else None, sigma0, tol, g_ref,
                                        max_iter, history, k_in, restarts)
    del way
    with np.errstate(all="ignore"):
        # The returned fields and their residual (issue 9: decided on what is returned); u rewritten in place
        u = compliance(p, u)
        fft_pairs += 2
        S = p > 0
        n_s = grid.count(S)
        g0 = -grid.total(xp.where(S, u - h, 0.0)) / max(n_s, 1)
        g = g0 + u - h
        rms, overlap = _violation(g, S, n_s, grid)
        residual = max(rms, overlap) / g_ref
        complementarity = grid.mean(p * xp.abs(g)) / (sigma0 * g_ref)
        load_error = abs(grid.mean(p) / sigma0 - 1.0)
        if periodic and (xp is np or type(grid) is not Grid):
            elastic = grid.elastic_energy(grid.fwd(u), e_star)
        else:  # (1/2) <p u> = (1/2) <p K p>: no spectrum (the GPU's memory plan, gfmd._cuda.solve_memory)
            elastic = 0.5 * grid.mean(p * u)
        gap = xp.where(S, 0.0, g)  # the contact atom exactly at g = 0
    fields_ok = math.isfinite(residual) and grid.all_finite(p) and grid.all_finite(u)
    status, converged = final_status(status, fields_ok, residual, load_error, tol)
    area = n_s / grid.size
    log.debug("hard wall: %s after %d iterations, residual %.3g, area %.4g", status, it, residual, area)
    gap, p, u = fields_to_host(grid, host, gap, p, u)  # only those asked for
    grid.synchronize()
    diagnostics = {"complementarity": complementarity, "gap_rms_in_contact": rms / g_ref, "overlap": overlap / g_ref,
                   "h_rms": h_rms, "fft_pairs": fft_pairs, "coarse_iterations": coarse_its, "restarted_at": restarts}
    return law_result(law, t_start, mean_gap=grid.mean(gap), gap=gap, pressure=p, displacement=u, iterations=it,
                      converged=converged, residual=residual, load_error=load_error, method=method,
                      backend=grid.backend, status=status, sigma0=sigma0, e_star=e_star, length=length, tol=tol,
                      history=history, contact_area=area, elastic_energy=elastic, diagnostics=diagnostics)
