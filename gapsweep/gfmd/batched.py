"""Batched GFMD: many problems of one grid size solved together (docs/gfmd.md, "Batches"; docs/model.md M3).

``solve_batch(problems)`` groups the problems by grid size ``n`` and by the minimiser their interaction law
needs (its ``load_control``); a group whose minimiser has a batched form runs as one stack of ``B x n x n``
arrays, every FFT one batched transform (cuFFT on the GPU, pocketfft on the CPU); other groups are solved one by
one with :func:`gapsweep.gfmd.solve`. Results come back in the order of ``problems``.

The batched "softmax" minimiser (exponential law) is the preconditioned Polak-Ribiere+ CG of
:mod:`gapsweep.gfmd._solvers` step for step, with every scalar decision taken per problem: each problem keeps
its own restart flag, line search (Newton/secant/bisection trials; problems whose search needs more trials
take them while the others wait), iteration count, history and status. A problem that stops (converged,
max_iter, stalled, non_finite) has its fields finished at once and costs no further kernel work: it is parked
(the kernels skip it) and the stack is compacted once a quarter of it is parked, so the number of distinct
stack sizes (each a new batched FFT plan) stays logarithmic. The arithmetic is that of the one-by-one solver
(same formulas, same order), so results agree to round-off and iteration counts agree unless round-off flips
a decision. On the GPU every operation is one fused CUDA pass over the whole stack (``bt_*`` in kernels.cu)
with one host synchronisation for all problems.

Memory: about ``14 n^2 x 8`` bytes per problem in the stack; ``max_batch`` bounds the stack (default: 1/3 of the
free GPU memory, or 16 problems on the CPU).
"""

from __future__ import annotations

import logging
import math
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from gapsweep.core import checks as chk
from gapsweep.core import deadline
from gapsweep.core.fft import BACKENDS, available_backends, get_backend
from gapsweep.gfmd._ops import _is_cupy, _Ops
from gapsweep.gfmd._result import FIELDS, GFMDResult, host_fields, law_result
from gapsweep.gfmd._solvers import _half_q, first_step, search_steps
from gapsweep.gfmd.interactions import Interaction, resolve

__all__ = ["Problem", "solve_batch"]

log = logging.getLogger("gapsweep.gfmd.batched")

_BYTES_PER_POINT = 14 * 8  # real and half-spectrum work arrays per grid point and problem


@dataclass(frozen=True)
class Problem:
    """One GFMD problem of a batch: the rigid surface ``heights`` (``n x n``, numpy or cupy), the mean pressure
    ``sigma0``, the interaction law (a name with its parameters, as for :func:`gapsweep.gfmd.solve`, or an
    :class:`Interaction` object) and an optional warm start ``initial`` (an earlier result or a displacement
    field on any grid, as for ``solve``; default: the linear response of M4)."""

    heights: Any
    sigma0: float
    interaction: str | Interaction = "exponential"
    gamma0: float | None = None
    rho: float | None = None
    initial: Any = None


def solve_batch(problems: Sequence[Problem], *, e_star: float = 1.0, length: float = 1.0, tol: float = 1e-6,
                backend: str = "auto", max_iter: int = 5000, host: bool | tuple[str, ...] = True,
                max_batch: int | None = None) -> list[GFMDResult]:
    """Solve ``problems`` (see the module docstring); arguments as in :func:`gapsweep.gfmd.solve`, common to all.
    ``backend``: "auto" (cupy when cupy is installed and a GPU is present, else numpy), "numpy" or "cupy";
    ``max_batch``: most problems stacked at once. Every input is validated before any work."""
    from gapsweep.gfmd._solve import _MINIMISERS, solve

    e_star = chk.positive(e_star, "e_star")
    length = chk.positive(length, "length")
    tol = chk.positive(tol, "tol")
    if isinstance(max_iter, bool) or not isinstance(max_iter, (int, np.integer)) or max_iter < 1:
        raise ValueError(f"max_iter must be an integer >= 1, got {max_iter!r}")
    if max_batch is not None:
        max_batch = chk.count(max_batch, "max_batch")
    host_fields(host)
    if not isinstance(backend, str) or backend not in ("auto", *BACKENDS):
        raise ValueError(f"backend must be one of {', '.join(map(repr, ('auto', *BACKENDS)))}; got {backend!r}")
    if backend == "auto":
        backend = "cupy" if "cupy" in available_backends() else "numpy"
    if backend == "pyfftw":
        backend = "numpy"  # batched transforms: numpy's pocketfft (pyfftw plans one grid at a time)
    laws, loads, grids, starts = _checked(problems, length)
    groups: dict[tuple[int, str], list[int]] = {}
    for i, law in enumerate(laws):
        groups.setdefault((grids[i], law.load_control), []).append(i)
    out: list[GFMDResult | None] = [None] * len(problems)
    for (n, control), idx in groups.items():
        runner = _BATCHED.get(control)
        if runner is None:  # no batched form for this law's minimiser yet: one by one
            log.info("batch: %d problem(s) with load_control %r solved one by one", len(idx), control)
            if control not in _MINIMISERS:
                raise ValueError(f"no minimiser for load_control {control!r} (interaction {laws[idx[0]].name!r})")
            for i in idx:
                out[i] = solve(problems[i].heights, sigma0=loads[i], interaction=laws[i], e_star=e_star,
                               length=length, tol=tol, backend=backend, max_iter=max_iter, host=host,
                               initial=problems[i].initial)
            continue
        size = max_batch or _default_batch(backend, n)
        for start in range(0, len(idx), size):
            chunk = idx[start:start + size]
            res = runner([problems[i].heights for i in chunk], [laws[i] for i in chunk], [loads[i] for i in chunk],
                         [starts[i] for i in chunk], n=n, e_star=e_star, length=length, tol=tol, backend=backend,
                         max_iter=max_iter, host=host)
            for i, r in zip(chunk, res):
                out[i] = r
    return out  # type: ignore[return-value]


def _checked(problems: Sequence[Problem], length: float) -> tuple[list, list, list, list]:
    """Every problem validated before any work: ``(laws, loads, grid sizes, warm starts)``; warns for each
    under-resolved one (the one-by-one solver's text after the problem's index)."""
    laws, loads, grids, starts = [], [], [], []
    for i, p in enumerate(problems):
        if not isinstance(p, Problem):
            raise TypeError(f"problems[{i}] must be a gfmd.batched.Problem, got {type(p).__name__}")
        shape = getattr(p.heights, "shape", None)
        if shape is None or len(shape) != 2 or shape[0] != shape[1] or shape[0] < 2:
            raise ValueError(f"problems[{i}].heights must be a square n x n array (n >= 2), got shape {shape}")
        law = resolve(p.interaction, gamma0=p.gamma0, rho=p.rho)
        rng = law.range()
        if rng is not None and rng < length / shape[0]:
            from gapsweep.gfmd._common import UnderResolvedWarning

            dx = length / shape[0]
            # the one-by-one solver's text after the problem's index (the sweep stores it in that row)
            warnings.warn(f"problems[{i}]: rho/dx = {rng / dx:.3g} < 1 (rho={rng:g}, dx={dx:g}): the interaction "
                          "range is under-resolved; the solver still converges but the mean gap carries a "
                          "discretisation error (refine n)", UnderResolvedWarning, stacklevel=3)
        laws.append(law)
        loads.append(law.check_load(p.sigma0))
        grids.append(int(shape[0]))
        starts.append(_initial_field(p.initial, i))
    return laws, loads, grids, starts


def _initial_field(initial: Any, i: int) -> np.ndarray | None:
    """The warm-start displacement of problem ``i`` on the host (validated), or None."""
    if initial is None:
        return None
    u0 = initial.displacement if isinstance(initial, GFMDResult) else initial
    if _is_cupy(u0):  # stays on its GPU (validated there); moved to the host only for a change of grid
        import cupy

        ok = u0.ndim == 2 and u0.shape[0] == u0.shape[1] and bool(cupy.all(cupy.isfinite(u0)))
    else:
        u0 = np.asarray(u0, dtype=np.float64)
        ok = u0.ndim == 2 and u0.shape[0] == u0.shape[1] and bool(np.all(np.isfinite(u0)))
    if not ok:
        raise ValueError(f"problems[{i}].initial must be a GFMDResult or a finite square displacement field")
    return u0


def _default_batch(backend: str, n: int) -> int:
    if backend != "cupy":
        return 16
    import cupy

    free, _ = cupy.cuda.runtime.memGetInfo()
    return max(1, int(free / 3 // (_BYTES_PER_POINT * n * n)))


# --------------------------------------------------------------------------------------- batched operations
class _Hosted:
    """The reducer of a stack (the interface of :class:`gapsweep.gfmd._ops._Local`): every local sum or max is
    already a vector of the ``B`` problems' scalars on the arrays' device; it comes back as a host vector."""

    def __init__(self, xp: Any) -> None:
        self.xp = xp

    def sum(self, *values: Any) -> Any:
        out = [_host(self.xp, v) for v in values]
        return out[0] if len(out) == 1 else out

    def max(self, value: Any) -> np.ndarray:
        return _host(self.xp, value)


class _Stack(_Ops):
    """Operations of the batched CG on a stack of ``B`` problems, real ``(B, n, n)`` and half spectra
    ``(B, n, n//2+1)``: the passes of :class:`gapsweep.gfmd._ops._Ops` themselves, over a leading batch axis (its
    four local primitives, sum, max, real dot and Parseval dot, reduce per problem; the reducer :class:`_Hosted`
    brings the ``B`` scalars to the host). Per-problem coefficients are host vectors of length ``B``, broadcast
    as ``(B, 1, 1)`` columns; ``active`` (bool vector) restricts an update to some problems (the passes then run
    on those problems' rows). :meth:`point` and :meth:`accept` are the one-by-one solver's pass sequences
    (trial + expstats; axpy + grad + dot)."""

    def __init__(self, xp: Any, n: int) -> None:
        super().__init__(xp, n, red=_Hosted(xp))

    # -- the local primitives of _Ops, per problem
    def _lsum(self, a) -> Any:
        return a.sum(axis=(1, 2))

    def _lmax(self, a) -> Any:
        return a.max(axis=(1, 2))

    def _lrdot(self, a, b) -> Any:
        return (a * b).sum(axis=(1, 2))

    def _ldot(self, a, b) -> Any:
        return self.weights.stack_dot(a, b)

    # -- transforms and plain reductions of the stack
    def rfft2(self, a):
        return self.xp.fft.rfft2(a, axes=(-2, -1))

    def irfft2(self, a):
        return self.xp.fft.irfft2(a, s=(self.n, self.n), axes=(-2, -1), norm="forward")

    def sums(self, a) -> np.ndarray:
        return self.red.sum(self._lsum(a))

    def maxes(self, a) -> np.ndarray:
        return self.red.max(self._lmax(a))

    def _sel(self, active):
        return slice(None) if active is None or active.all() else self.xp.asarray(np.flatnonzero(active))

    # -- the batched CG's passes
    def point(self, W, d, c, shift, active, Wt, e) -> tuple[np.ndarray, ...]:
        """Trial points of the active problems: ``Wt = W + c d``, ``e = exp(Wt - m)`` with ``m = max(Wt)``
        (``shift`` is a hint that this exact version ignores): :meth:`trial` and :meth:`expstats`; returns
        ``(m, S, s1, s2)`` with ``S = sum e``, ``s1 = sum e d``, ``s2 = sum e d^2`` (entries of inactive problems
        are 0)."""
        xp, sel = self.xp, self._sel(active)
        idx = np.flatnonzero(active)
        whole = isinstance(sel, slice)  # every problem: the passes write into Wt, e themselves
        ds = d[sel]
        wt, ee = (Wt, e) if whole else (xp.empty_like(ds), xp.empty_like(ds))
        mm = self.trial(W[sel], ds, _col(xp, c[idx]), wt)
        out = [np.zeros(len(active)) for _ in range(4)]
        for o, v in zip(out, (mm, *self.expstats(wt, _col(xp, mm), ee, ds))):
            o[idx] = v
        if not whole:
            Wt[sel], e[sel] = wt, ee
        return tuple(out)

    def cg_update(self, G, minv, D, beta, k, X, active=None) -> tuple[np.ndarray, ...]:
        """``D = beta D - M^-1 G`` (active problems); returns ``(<G D>, <kD X>, <kD D>)`` (entries of inactive
        problems undefined)."""
        sel = self._sel(active)
        if isinstance(sel, slice):
            return super().cg_update(G, minv, D, _col(self.xp, beta), k, X)
        Ds = D[sel]
        self._ldirection(G[sel], minv[sel], Ds, _col(self.xp, beta[np.flatnonzero(active)]))
        D[sel] = Ds
        kD = k * D
        return tuple(self.red.sum(self._ldot(G, D), self._ldot(kD, X), self._ldot(kD, D)))

    def accept(self, X, D, alpha, e, c, k, G, G_old, active) -> np.ndarray:
        """Active problems: ``G_old = G``, ``X += alpha D``, ``G = k X - c rfft2(e)`` (0 at q = 0): :meth:`axpy`
        and :meth:`grad`; returns ``<G G>`` of the active problems (in their order)."""
        xp, sel = self.xp, self._sel(active)
        idx = np.flatnonzero(active)
        G_old[sel] = G[sel]
        Xs, Gs = X[sel], G[sel]  # views of X, G for every problem, else copies written back
        self.axpy(Xs, _col(xp, alpha[idx]), D[sel])
        self.grad(Xs, self.rfft2(e[sel]), _col(xp, c[idx]), k, Gs)
        if not isinstance(sel, slice):
            X[sel], G[sel] = Xs, Gs
        return self.dot(Gs, Gs)


class _FusedStack(_Stack):
    """GPU variant of :class:`_Stack`: one fused CUDA pass per operation over the whole stack (the ``bt_*``
    kernels of ``kernels.cu``, problem = ``blockIdx.y``), per-block partials reduced over blocks on the device
    and one device-to-host copy of the ``B`` results, the only host synchronisation. Trial points are shifted by
    a hint (the problem's current max) and redone with their own max only when that lies over 50 away
    (``e <= e^50``: nothing overflows; ``S``, ``s1``, ``s2`` then carry a common factor that cancels in the
    solver, as in :class:`gapsweep.gfmd._cuda._CupyOps`)."""

    def __init__(self, xp: Any, n: int) -> None:
        from gapsweep.gfmd._cuda import _cupy_kernels

        super().__init__(xp, n)
        self.K = _cupy_kernels()
        self.nh = n // 2 + 1
        self._geo = (np.uint32(self.nh), np.int32(self.even))

    def _run(self, name: str, nk: int, mx: int, size: int, B: int, args: tuple) -> np.ndarray:
        xp = self.xp
        gx = int(max(1, min(-(-size // 256), max(8, 4096 // B))))
        part = xp.empty((B, nk, gx), dtype=xp.float64)
        self.K[name]((gx, B), (256,), (*args, np.uint64(size), part))
        res = part.sum(axis=2)
        if mx:
            res[:, 0] = part[:, 0, :].max(axis=1)
        return _host(xp, res)

    def _dev(self, v, dtype=np.float64):
        return self.xp.asarray(np.ascontiguousarray(v, dtype=dtype))

    def point(self, W, d, c, shift, active, Wt, e) -> tuple[np.ndarray, ...]:
        B = W.shape[0]
        shift = np.where(np.isfinite(shift), shift, 0.0)
        act = np.asarray(active, dtype=bool).copy()
        out = np.zeros((B, 4))
        for _ in range(2):
            r = self._run("bt_point", 4, 1, self.n * self.n, B,
                          (W, d, self._dev(c), self._dev(shift), self._dev(act, np.int32), Wt, e))
            out[act] = r[act]
            far = act & np.isfinite(r[:, 0]) & (np.abs(r[:, 0] - shift) > 50.0)
            if not far.any():
                break
            shift = np.where(far, r[:, 0], shift)  # exact shift for those
            act = far
        return out[:, 0], out[:, 1], out[:, 2], out[:, 3]

    def moments(self, e, d) -> tuple[np.ndarray, np.ndarray]:
        r = self._run("bt_moments", 2, 0, self.n * self.n, e.shape[0], (e, d))
        return r[:, 0], r[:, 1]

    def cg_dots(self, G, G_old, minv) -> tuple[np.ndarray, np.ndarray]:
        r = self._run("bt_cgdots", 2, 0, self.n * self.nh, G.shape[0], (minv, G, G_old, *self._geo))
        return r[:, 0], r[:, 1]

    def cg_update(self, G, minv, D, beta, k, X, active=None) -> tuple[np.ndarray, ...]:
        B = D.shape[0]
        act = np.ones(B, dtype=np.int32) if active is None else np.asarray(active, dtype=np.int32)
        r = self._run("bt_cgupdate", 3, 0, self.n * self.nh, B,
                      (D, self._dev(beta), minv, G, k, X, self._dev(act, np.int32), *self._geo))
        return r[:, 0], r[:, 1], r[:, 2]

    def accept(self, X, D, alpha, e, c, k, G, G_old, active) -> np.ndarray:
        B = X.shape[0]
        E = self.rfft2(e)
        act = np.asarray(active, dtype=bool)
        r = self._run("bt_accept", 1, 0, self.n * self.nh, B,
                      (X, D, self._dev(np.where(act, alpha, 0.0)), E, self._dev(np.where(act, c, 0.0)), k, G, G_old,
                       self._dev(act, np.int32), *self._geo))
        return r[act, 0]


def _make_stack(xp: Any, n: int) -> _Stack:
    """Fused kernels on the GPU (unless ``GAPSWEEP_GENERIC_KERNELS=1``), the array code otherwise."""
    import os

    if xp is not np and os.environ.get("GAPSWEEP_GENERIC_KERNELS") != "1":
        return _FusedStack(xp, n)
    return _Stack(xp, n)


def _host(xp, a) -> np.ndarray:
    return np.asarray(a.get() if xp is not np else a, dtype=np.float64)


def _col(xp, v) -> Any:
    """A per-problem host vector as a ``(B, 1, 1)`` device array for broadcasting."""
    return xp.asarray(np.asarray(v, dtype=np.float64)).reshape(-1, 1, 1)


# ------------------------------------------------------------------------------------- softmax (exponential)
class _Batch:
    """The state of one batched CG (:func:`_softmax_batch`): the stack's arrays (slot ``j`` holds problem
    ``ids[j]``) and the per-problem host vectors; the steps of :func:`gapsweep.gfmd._solvers._run_cg` as
    methods, each taken for every problem at once."""

    def __init__(self, xp: Any, ops: _Stack, heights: list, laws: list, sigma0s: list[float], starts: list,
                 n: int, e_star: float, length: float) -> None:
        self.xp, self.ops, self.laws = xp, ops, laws
        B = len(heights)
        h = xp.stack([xp.asarray(hh, dtype=xp.float64) for hh in heights])
        if not bool(xp.all(xp.isfinite(h))):
            bad = [i for i in range(B) if not bool(xp.all(xp.isfinite(h[i])))]
            raise ValueError(f"heights of batch problem(s) {bad} contain NaN or inf")
        self.h = h = h - h.mean(axis=(1, 2), keepdims=True)  # only h - <h> enters the gap (docs/model.md M3)
        self.rho = rho = np.array([law.rho for law in laws])
        self.s0 = s0 = np.array(sigma0s, dtype=np.float64)
        self.k = k = 0.5 * e_star * _half_q(xp, n, length)
        # linear response of M4, per problem as in the one-by-one solver
        Hq = ops.rfft2(h) * (1.0 / (n * n))
        X = (Hq * (_col(xp, s0 / rho) / (k + _col(xp, s0 / rho)))).astype(xp.complex128)
        for j, u0 in enumerate(starts):  # warm starts, as in the one-by-one solver
            if u0 is None:
                continue
            if _is_cupy(u0) and (xp is np or u0.shape[0] != n):
                u0 = u0.get()
            if u0.shape[0] == n:
                X[j] = ops.rfft2(xp.asarray(u0, dtype=xp.float64)[None])[0] * (1.0 / (n * n))
            else:
                from gapsweep.gfmd._common import _transfer_modes

                X[j] = xp.asarray(_transfer_modes(u0, n))
        self.minv = 1.0 / (k + _col(xp, s0 / rho))
        self.minv[:, 0, 0] = 0.0
        X[:, 0, 0] = 0.0
        self.X = X
        self.W = (h - ops.irfft2(X)) * _col(xp, 1.0 / rho)
        self.m = ops.maxes(self.W)
        self.e = xp.exp(self.W - _col(xp, self.m))
        self.S = ops.sums(self.e)
        G = k * X - _col(xp, s0 / self.S) * ops.rfft2(self.e)
        G[:, 0, 0] = 0.0
        self.G = G
        self.r2 = ops.dot(G, G)
        self.G_old = xp.zeros_like(G)
        self.D = xp.zeros_like(X)
        self.Wt, self.et = xp.empty_like(self.W), xp.empty_like(self.e)
        self.ids = list(range(B))  # original index of each slot
        self.nfev = np.ones(B, dtype=np.int64)
        self.history: list[list[float]] = [[] for _ in range(B)]
        self.restart = np.ones(B, dtype=bool)
        self.zg_old = np.zeros(B)
        self.status: list[str | None] = [None] * B
        self.alive = np.ones(B, dtype=bool)  # slots still iterating (the others parked until the next compaction)

    def running(self) -> bool:
        return bool(self.ids) and bool(self.alive.any())

    def finish(self, slots: list[int], done: Any) -> None:
        """Hand the problems in ``slots`` to ``done(slot, problem)`` (their fields and records); park them (the
        kernels skip them) and compact the stack once a quarter of it is parked (a new stack size costs new FFT
        plans: not at every finish)."""
        for j in slots:
            done(j, self.ids[j])
            self.alive[j] = False
        if self.alive.sum() > 0.75 * len(self.ids):
            return
        keep = list(np.flatnonzero(self.alive))
        self.ids = [self.ids[j] for j in keep]
        if not keep:
            return
        sel = np.asarray(keep)
        dsel = self.xp.asarray(sel)
        for name in ("X", "h", "minv", "W", "e", "G", "G_old", "D"):
            setattr(self, name, getattr(self, name)[dsel])
        self.Wt, self.et = self.xp.empty_like(self.W), self.xp.empty_like(self.e)
        for name in ("m", "S", "r2", "rho", "s0", "restart", "zg_old", "nfev", "alive"):
            setattr(self, name, getattr(self, name)[sel])

    def check(self, tol: float, max_iter: int) -> list[int]:
        """``_check`` of ``_run_cg`` per live problem: its residual into its history; the slots that stop."""
        done = []
        for j, i in enumerate(self.ids):
            if not self.alive[j]:
                continue
            r = math.sqrt(max(float(self.r2[j]), 0.0)) / float(self.s0[j])
            self.history[i].append(r)
            st = "non_finite" if not math.isfinite(r) else "converged" if r <= tol else \
                "max_iter" if self.nfev[j] >= max_iter else None
            if st is not None:
                self.status[i] = st
                done.append(j)
        return done

    def direction(self) -> tuple[np.ndarray, ...]:
        """``cg_dots`` and ``cg_update`` per problem (restart along ``-M^-1 G`` where the direction is not one of
        descent); problems without descent stop. Returns ``(zg, phi0p, a, b)``."""
        ops, restart, alive = self.ops, self.restart, self.alive
        nb = len(self.ids)
        zg, zg_cross = ops.cg_dots(self.G, self.G_old, self.minv)
        zg_cross = np.where(restart, 0.0, zg_cross)
        with np.errstate(all="ignore"):  # parked slots may hold anything
            beta = np.where(restart | ~alive, 0.0,
                            np.maximum(0.0, (zg - zg_cross) / np.where(restart, 1.0, self.zg_old)))
        phi0p, a, b = ops.cg_update(self.G, self.minv, self.D, beta, self.k, self.X)
        redo = (phi0p >= 0) & (beta > 0) & alive
        if redo.any():  # not a descent direction (round-off): restart along -M^-1 G
            p2, a2, b2 = ops.cg_update(self.G, self.minv, self.D, np.zeros(nb), self.k, self.X, active=redo)
            phi0p, a, b = np.where(redo, p2, phi0p), np.where(redo, a2, a), np.where(redo, b2, b)
        for j in range(nb):
            if alive[j] and not phi0p[j] < 0:
                self.status[self.ids[j]] = "stalled" if math.isfinite(phi0p[j]) else "non_finite"
        return zg, phi0p, a, b

    def search(self, phi0p: np.ndarray, a: np.ndarray, b: np.ndarray, eta: float) -> tuple[Any, ...]:
        """The line searches of every problem in lockstep (one batched trial pass per round; problems whose
        search needs more trials take them while the others wait). Returns ``(alpha, outcome, mt, St)``:
        ``outcome[j] = (alpha, ok, last)`` of :func:`search_steps`, the accepted points in (Wt, et) with their
        max ``mt`` and sum ``St``."""
        ops, rho, s0 = self.ops, self.rho, self.s0
        nb = len(self.ids)
        d = ops.irfft2(self.D)
        s1, s2 = ops.moments(self.e, d)
        S = self.S
        gens = {j: search_steps(phi0p[j], a[j], b[j], s0[j], rho[j],
                                first_step(phi0p[j], b[j], s0[j] / rho[j], S[j], s1[j], s2[j]), eta)
                for j in range(nb) if self.alive[j] and phi0p[j] < 0}
        alpha = np.zeros(nb)
        outcome: dict[int, tuple[float, bool, bool]] = {}
        pending = set()
        for j, g in gens.items():
            try:
                alpha[j] = g.send(None)
                pending.add(j)
            except StopIteration as stop:
                outcome[j] = stop.value
        mt, St = np.zeros(nb), np.zeros(nb)
        while pending:
            act = np.zeros(nb, dtype=bool)
            act[list(pending)] = True
            mm, SS, t1, t2 = ops.point(self.W, d, -alpha / rho, self.m, act, self.Wt, self.et)
            for j in sorted(pending):
                mt[j], St[j] = mm[j], SS[j]
                try:
                    alpha[j] = gens[j].send((float(mm[j]), float(SS[j]), float(t1[j]), float(t2[j])))
                except StopIteration as stop:
                    outcome[j] = stop.value
                    pending.discard(j)
        # points that the search accepted without evaluating them last: one more trial pass
        again = np.zeros(nb, dtype=bool)
        for j, (al, ok, last) in outcome.items():
            if ok and not last:
                again[j] = True
                alpha[j] = al
        if again.any():
            mm, SS, _, _ = ops.point(self.W, d, -alpha / rho, self.m, again, self.Wt, self.et)
            mt[again], St[again] = mm[again], SS[again]
        return alpha, outcome, mt, St

    def accept(self, zg: np.ndarray, alpha: np.ndarray, outcome: dict, mt: np.ndarray, St: np.ndarray) -> None:
        """Failed searches restart (or stall after a restart); accepted points become the current ones, with
        their gradients."""
        xp, restart = self.xp, self.restart
        nb = len(self.ids)
        for j, (_, ok, _) in outcome.items():
            if not ok:
                if restart[j]:
                    self.status[self.ids[j]] = "stalled"
                else:
                    restart[j] = True
        acc = np.zeros(nb, dtype=bool)
        for j, (al, ok, _) in outcome.items():
            if ok:
                acc[j] = True
                alpha[j] = al
        if not acc.any():
            return
        restart[acc] = False
        self.zg_old[acc] = zg[acc]
        if acc.all():
            self.W, self.e, self.Wt, self.et = self.Wt, self.et, self.W, self.e
        else:
            mask = xp.asarray(acc).reshape(-1, 1, 1)
            self.W, self.e = xp.where(mask, self.Wt, self.W), xp.where(mask, self.et, self.e)
        self.m[acc], self.S[acc] = mt[acc], St[acc]
        with np.errstate(all="ignore"):
            c = self.s0 / self.S
        self.r2[acc] = self.ops.accept(self.X, self.D, alpha, self.e, c, self.k, self.G, self.G_old, acc)
        self.nfev[acc] += 1

    def stopped(self) -> list[int]:
        return [j for j in range(len(self.ids)) if self.alive[j] and self.status[self.ids[j]] is not None]


def _softmax_batch(heights: list, laws: list, sigma0s: list[float], starts: list, *, n: int, e_star: float,
                   length: float, tol: float, backend: str, max_iter: int, host: Any,
                   eta: float = 0.1) -> list[GFMDResult]:
    """Batched "softmax" minimiser (exponential law), CG as :func:`gapsweep.gfmd._solvers._run_cg` (the steps:
    :class:`_Batch`)."""
    t_start = time.perf_counter()
    if backend == "cupy":
        import cupy as xp
    else:
        xp = np
    ops = _make_stack(xp, n)
    bt = _Batch(xp, ops, heights, laws, sigma0s, starts, n, e_star, length)
    results: list[GFMDResult | None] = [None] * len(heights)

    def done(j: int, i: int) -> None:
        results[i] = _softmax_fields(xp, ops, bt.X[j], bt.h[j], laws[i], float(bt.s0[j]), bt.status[i],
                                     int(bt.nfev[j]), bt.history[i], e_star, length, tol, host, t_start)

    while bt.running():
        deadline.check()  # a task time limit ends the batch between iterations
        stop = bt.check(tol, max_iter)
        if stop:
            bt.finish(stop, done)
            if not bt.running():
                break
        zg, phi0p, a, b = bt.direction()
        alpha, outcome, mt, St = bt.search(phi0p, a, b, eta)
        bt.accept(zg, alpha, outcome, mt, St)
        stopped = bt.stopped()
        if stopped:
            bt.finish(stopped, done)
    return results  # type: ignore[return-value]


def _softmax_fields(xp, ops: _Stack, X, h, law, sigma0: float, status: str, nfev: int,
                    history: list[float], e_star: float, length: float, tol: float, host: Any,
                    t_start: float) -> GFMDResult:
    """Fields and record of one finished problem, as at the end of :func:`gapsweep.gfmd._softmax.minimise`."""
    n = ops.n
    rho = law.rho
    with np.errstate(all="ignore"):
        u = ops.irfft2(X[None])[0]
        w = (h - u) * (1.0 / rho)
        m = float(w.max())
        e = xp.exp(w - m)
        S = float(e.sum())
        lse = m + math.log(S / (n * n)) if S > 0 else math.nan
        g0 = law.mean_gap(lse, sigma0)
        p = e * (sigma0 * n * n / S) if S > 0 else e * math.nan
        gap = g0 - rho * w  # the gap of h - <h>: invariant under h -> h + c (docs/model.md M3)
    load_error = abs(float(p.mean()) / sigma0 - 1.0)
    residual = history[-1] if history else math.inf
    fields_ok = math.isfinite(g0) and bool(xp.all(xp.isfinite(gap))) and bool(xp.all(xp.isfinite(p)))
    if not fields_ok:
        status = "non_finite"
    converged = status == "converged" and load_error <= tol and fields_ok
    if status == "converged" and not converged:
        status = "stalled"
    fields = dict(zip(FIELDS, (gap, p, u)))
    wanted = {k: fields[k] for k in host_fields(host) if _is_cupy(fields[k])}
    if wanted:  # pinned, asynchronous copies as in gfmd.solve
        fields.update(get_backend("cupy", n).to_host_many(wanted))
    return law_result(law, t_start, mean_gap=g0, gap=fields["gap"], pressure=fields["pressure"],
                      displacement=fields["displacement"], iterations=nfev, converged=converged, residual=residual,
                      load_error=load_error, method="cg", backend="cupy" if xp is not np else "numpy",
                      status=status, sigma0=sigma0, rho=rho, gamma0=law.gamma0, e_star=e_star, length=length,
                      tol=tol, history=list(history))


# load_control -> batched minimiser; laws with another load_control are solved one by one
_BATCHED = {"softmax": _softmax_batch}
