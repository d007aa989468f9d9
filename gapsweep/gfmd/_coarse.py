"""Coarse-to-fine start of a distributed solve (docs/gfmd.md, "One solve over several processes", coarse-to-fine
start; nested iteration as in full multigrid).

The problem is solved first on grids ``(nx/2^l, ny/2^l)``, ``l = levels .. 1``, of the same box (the pixel
``2^l`` times larger), each level started from the previous one, and the finest coarse answer starts the
requested grid. Level ``l``'s surface is the spectral truncation of the caller's ``h``: its half-spectrum
coefficients ``h~_l(q) = h~(q)`` for ``|kx| < nx_l/2`` and ``ky < ny_l/2`` (integer wave numbers; the Nyquist
row and column and every shorter wavelength set to 0), ``h_l = irfft2(h~_l)`` on the coarse grid: a surface
band-limited below the coarse Nyquist wavelength ``2 L/nx_l`` is the same continuous surface, sampled coarser.
The state is carried to the next level by zero-padding its spectrum (prolongation: ``z~_{l-1}(q) = z~_l(q)`` on
the shared modes, 0 elsewhere; ``z`` the displacement ``u`` for the exponential law, the body's surface
``z = g0 + u`` for the smooth laws, so the mean gap travels in ``z~(0)``). Coefficients are normalised
(``a~ = rfft2(a)/(nx ny)``), so they carry over between grids unchanged; the interaction law, ``E*``, the load
and the box are the same on every level. Coarse levels stop at ``coarse_tol`` (their answer is only a start);
the requested grid at the caller's ``tol``, so the answer is the plain solve's to that tolerance.

Memory: a coarse level's arrays are ``4^-l`` of the requested grid's; while a level runs, the requested grid
holds only the caller's ``h``; the surface of a level is made through one forward transform of ``h`` (1 array,
freed before the level runs) and the start of the requested grid is one half spectrum, which its minimiser takes
over as its state. The peak is therefore the requested grid's own. Moving coefficients between the layouts of
two grids (each rank holds a block of ``ky`` columns, :mod:`gapsweep.core.slab`) takes point-to-point exchanges
of the shared columns through host buffers, in chunks of at most ``CHUNK`` coefficients."""

from __future__ import annotations

import logging
import math
import warnings
from typing import Any

import numpy as np

from gapsweep.core.slab import SlabFFT

log = logging.getLogger("gapsweep.gfmd")
CHUNK = 1 << 24  # coefficients per host buffer of the layout exchange (256 MiB)
MIN_SIDE = 64  # the coarsest level keeps at least this many pixels per side (automatic levels)
LEVEL_RESIDUAL = 1.0  # a coarse level's answer starts the next only when converged or within this residual


class Start:
    """A start spectrum handed to the requested grid's minimiser (which takes it over: :meth:`take`)."""

    def __init__(self, Z: Any) -> None:
        self._Z = Z

    def take(self) -> Any:
        Z, self._Z = self._Z, None
        return Z


class SelfComm:
    """The communicator of one process (the few methods :mod:`gapsweep.core.slab` calls), so that the
    coarse-to-fine start runs without mpi4py on one process or one GPU (``gfmd.solve(..., start="coarse")``)."""

    def Get_size(self) -> int:  # mpi4py's method names
        return 1

    def Get_rank(self) -> int:
        return 0

    def Allgather(self, send: Any, recv: Any) -> None:
        recv[...] = np.reshape(send, recv.shape)

    def bcast(self, value: Any, root: int = 0) -> Any:
        return value

    def py2f(self) -> int:
        return -1


def auto_levels(shape: tuple[int, int], ranks: int, min_side: int = MIN_SIDE) -> int:
    """Most levels ``l`` with both sides divisible by ``2^l``, the coarse grid at least ``min_side`` per side and
    at least ``2 ranks`` rows and half-spectrum columns (every rank holds some)."""
    nx, ny = shape
    lv = 0
    while True:
        f = 2 ** (lv + 1)
        if nx % f or ny % f or min(nx // f, ny // f) < max(min_side, 2 * ranks):
            return lv
        lv += 1


def check_levels(levels: Any, shape: tuple[int, int], ranks: int) -> int:
    """Checked number of coarse levels (None: :func:`auto_levels`)."""
    if levels is None:
        return auto_levels(shape, ranks)
    if isinstance(levels, bool) or not isinstance(levels, (int, np.integer)) or levels < 0:
        raise ValueError(f"levels must be None or an integer >= 0, got {levels!r}")
    most = auto_levels(shape, ranks, min_side=2)
    if levels > most:
        raise ValueError(f"levels={levels} is too many for a {shape[0]} x {shape[1]} grid on {ranks} ranks: both "
                         f"sides must divide by 2^levels and keep >= {2 * ranks} pixels (at most {most})")
    return int(levels)


def _overlap(a: slice, b: slice, stop: int) -> tuple[int, int]:
    return max(a.start, b.start), min(a.stop, b.stop, stop)


def remap(src: Any, f_src: SlabFFT, f_dst: SlabFFT) -> Any:
    """Half-spectrum coefficients of grid ``f_src`` (this rank's columns ``src``) on grid ``f_dst``'s layout:
    the modes both grids carry below their Nyquist wave numbers (module docstring) copied, every other mode 0.
    Collective over the ranks of the two transforms' (same) communicator."""
    xp, comm = f_dst.xp, f_dst.comm
    size, rank = f_dst.size, f_dst.rank
    (nxs, nys), (nxd, nyd) = f_src.shape, f_dst.shape
    mx, my = min(nxs, nxd) // 2, min(nys, nyd) // 2
    kx_s = np.r_[0:mx, nxs - mx + 1:nxs]
    kx_d = np.r_[0:mx, nxd - mx + 1:nxd]
    dst = xp.zeros(f_dst.spec_shape, dtype=xp.complex128)
    step = max(1, CHUNK // len(kx_s))
    ix_s, ix_d = xp.asarray(kx_s), xp.asarray(kx_d)  # index arrays on the arrays' device
    for d in range(size):
        to, frm = (rank + d) % size, (rank - d) % size
        a0, a1 = _overlap(f_src.col, f_dst.cols[to], my)  # sent: my source columns that `to` holds
        b0, b1 = _overlap(f_src.cols[frm], f_dst.col, my)  # received: `frm`'s source columns that I hold
        # every rank makes the same number of exchanges in this round (the most chunks any rank sends in it), so
        # that the i-th Sendrecv of each rank meets the i-th of its partners
        rounds = max(math.ceil(max(0, min(f_src.cols[q].stop, f_dst.cols[(q + d) % size].stop, my)
                                   - max(f_src.cols[q].start, f_dst.cols[(q + d) % size].start)) / step)
                     for q in range(size))
        for c in range(rounds):
            s0, s1 = a0 + c * step, min(a1, a0 + (c + 1) * step)
            send = np.empty((max(s1 - s0, 0), len(kx_s)), dtype=np.complex128)
            if s1 > s0:
                part = src[s0 - f_src.col.start:s1 - f_src.col.start][:, ix_s]
                send[...] = part.get() if xp is not np else part
            r0, r1 = b0 + c * step, min(b1, b0 + (c + 1) * step)
            if d == 0:
                recv = send
            else:
                recv = np.empty((max(r1 - r0, 0), len(kx_d)), dtype=np.complex128)
                comm.Sendrecv(send, dest=to, recvbuf=recv, source=frm)
            if r1 > r0:
                rows = dst[r0 - f_dst.col.start:r1 - f_dst.col.start]  # a view: the assignment writes dst
                rows[:, ix_d] = xp.asarray(recv)
    return dst


def restrict(h: Any, f_fine: SlabFFT, f_coarse: SlabFFT) -> Any:
    """This rank's rows of the coarse surface ``h_l`` (module docstring) from this rank's rows of ``h``."""
    H = f_fine.rfft2(h)
    H *= 1.0 / (f_fine.shape[0] * f_fine.shape[1])
    Hc = remap(H, f_fine, f_coarse)
    del H
    return f_coarse.irfft2(Hc)


def _record(r: Any, shape: tuple[int, int]) -> dict:
    """The record of a coarse level's result ``r`` (``diagnostics["levels"]``), ``used`` whether it starts the
    next level: a level whose forces are off by more than the pressure scale (a stall, an overflow) starts
    nothing; an unconverged level within it is still a better start than flat (measured at the challenge's
    constants on 32768^2, 2 H200: the exponential 64^2 level at residual 0.46 started a chain that converged in 74
    fine evaluations, dropping it left every level at max_iter: benchmarks/results/distributed/
    h200x2_challenge_32768_before.json, h200x2_challenge_32768_strict.json)."""
    rec = {"shape": [int(shape[0]), int(shape[1])], "evaluations": int(r.iterations), "status": r.status,
           "residual": float(r.residual), "mean_gap": float(r.mean_gap), "contact_area": float(r.contact_area),
           "wall_s": float(r.wall_time)}
    log.info("coarse level %d x %d: %s after %d evaluations, residual %.3g, mean gap %.6g", shape[0], shape[1],
             r.status, r.iterations, r.residual, r.mean_gap)
    ok = math.isfinite(r.mean_gap) and (r.status == "converged" or (
        r.status != "non_finite" and math.isfinite(r.residual) and r.residual <= LEVEL_RESIDUAL))
    rec["used"] = bool(ok)
    return rec


def chain(h: Any, f_fine: SlabFFT, levels: int, solve_level: Any, smooth: bool) -> tuple[Any, list[dict]]:
    """Solve the coarse levels ``levels .. 1`` in turn (``solve_level(h_l, initial)`` returns the level's
    result, ``initial`` None or a :class:`Start`) and return the requested grid's start spectrum (this rank's
    columns, normalised coefficients; the displacement's, or with ``smooth`` the body surface's ``z = g + h``)
    and one record per level. A level whose answer is neither converged nor within :data:`LEVEL_RESIDUAL` is
    dropped (the next starts from the level before it, or flat if there is none; its record says ``used``)."""
    nx, ny = f_fine.shape
    xp = f_fine.xp
    Z, f_prev, records = None, None, []
    for lv in range(levels, 0, -1):
        f = SlabFFT((nx >> lv, ny >> lv), f_fine.comm, backend=f_fine.backend)
        hl = restrict(h, f_fine, f)
        init = None if Z is None else Start(remap(Z, f_prev, f))
        with warnings.catch_warnings():  # a coarse level may resolve the range worse: only a start
            warnings.simplefilter("ignore")
            r = solve_level(hl, init)
        rec = _record(r, (nx >> lv, ny >> lv))
        records.append(rec)
        if rec["used"]:
            z = r.gap + hl if smooth else r.displacement
            Z = f.rfft2(xp.ascontiguousarray(z))
            Z *= 1.0 / ((nx >> lv) * (ny >> lv))
            f_prev = f
        del r, hl
    if Z is None:
        return None, records
    return remap(Z, f_prev, f_fine), records


# ---------------------------------------------------------------------------------------------- one process
def transfer(A: Any, src: tuple[int, int], dst: tuple[int, int], xp: Any = np) -> Any:
    """Normalised half-spectrum coefficients ``A`` of an ``src`` grid (layout ``[kx, ky]``, shape
    ``(nx, ny//2 + 1)``, as :class:`gapsweep.gfmd._grid.Grid`) on the ``dst`` grid: the modes both grids carry
    below their Nyquist wave numbers copied, every other mode 0 (the restriction and prolongation of the module
    docstring; :func:`remap` on one process, without the slab layout). A new array."""
    (nxs, nys), (nxd, nyd) = src, dst
    mx, my = min(nxs, nxd) // 2, min(nys, nyd) // 2
    out = xp.zeros((nxd, nyd // 2 + 1), dtype=xp.complex128)
    out[:mx, :my] = A[:mx, :my]
    if mx > 1:
        out[nxd - mx + 1:, :my] = A[nxs - mx + 1:, :my]
    return out


def _start_field(grid: Any, Z: Any, h: Any, smooth: bool, sink: float) -> Any:
    """The ``initial`` of the plain solve on ``grid`` from the prolonged state spectrum ``Z``: the displacement
    field (exponential law on a square: the softmax minimiser), or for the smooth minimiser the pair
    ``(zero-mean displacement, mean gap)`` of the body surface ``z``, first lifted so that it overlaps ``h`` by at
    most ``sink`` (length units; ``gfmd._lean.lift_out_of_surface``'s safeguard)."""
    z = grid.inv(Z)
    if not smooth:
        return z
    lift = max(0.0, -float((z - h).min()) - sink)
    zm = float(z.mean()) + lift
    return z - float(z.mean()), zm - float(h.mean())


def solve_local(h: np.ndarray, solve: Any, *, length: Any, backend: str, threads: int | None, levels: int,
                smooth: bool, sink: float, level_kw: dict, fine_kw: dict) -> Any:
    """``gfmd.solve(..., start="coarse")`` on one process on the CPU: the chain of :func:`chain` run on the plain
    single-process minimisers and their FFT engine (pyFFTW where installed, the process's FFT backend:
    :class:`gapsweep.gfmd._grid.Grid`) instead of the slab decomposition on numpy's FFT. ``solve(h, initial, kw)``
    is the plain solve (start "flat"); ``level_kw`` its keywords on the coarse levels (``coarse_tol``),
    ``fine_kw`` on the requested grid; ``smooth``: the law runs on the smooth minimiser (the state travels as the
    body surface ``z = g + h``, else as the displacement ``u``); ``sink``: :data:`gfmd._lean.SINK_RANGES` times the
    law's range. Returns the requested grid's result with ``diagnostics["levels"]`` and
    ``diagnostics["coarse_cost"]`` (as the distributed solve's) and ``wall_time`` including the coarse levels.
    Memory: the surface's spectrum and the levels' arrays (``4^-l`` of the grid's) while the levels run, freed
    before the requested grid runs."""
    import time

    from gapsweep.gfmd._grid import Grid

    t0 = time.perf_counter()
    nx, ny = shape = (int(h.shape[0]), int(h.shape[1]))
    fine = Grid(shape, length, backend, threads, False)
    H = fine.fwd(fine.asarray(h))
    Z, prev, records = None, None, []
    for lv in range(levels, 0, -1):
        sh = (nx >> lv, ny >> lv)
        g = Grid(sh, length, backend, threads, False)
        hl = g.inv(transfer(H, shape, sh))
        init = None if Z is None else _start_field(g, transfer(Z, prev, sh), hl, smooth, sink)
        with warnings.catch_warnings():  # a coarse level may resolve the range worse: only a start
            warnings.simplefilter("ignore")
            r = solve(hl, init, level_kw)
        rec = _record(r, sh)
        records.append(rec)
        if rec["used"]:
            z = r.gap + hl if smooth else r.displacement
            Z, prev = g.fwd(np.ascontiguousarray(z)), sh
        del r, hl
    del H
    init = None if Z is None else _start_field(fine, transfer(Z, prev, shape), np.asarray(h, dtype=float), smooth,
                                               sink)
    r = solve(h, init, fine_kw)
    r.diagnostics = {**r.diagnostics, "levels": records, "coarse_cost": sum(
        rec["evaluations"] * rec["shape"][0] * rec["shape"][1] / (nx * ny) for rec in records)}
    r.wall_time = time.perf_counter() - t0
    return r
